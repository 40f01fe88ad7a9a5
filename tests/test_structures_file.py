"""Structure files: the shipped structures, damping in closed form, elements between DOF, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.structure_file import MAX_DOF, load_structure, parse_structure, shipped_names
from hsio.structures import get_structure

REPO = Path(__file__).resolve().parents[1]

# The matrices of the paper's structures as hsio built them in code before they became files.
FROZEN = {
    "validation": {
        "dt": 0.01, "dofs": ("C1", "C2"),
        "M": [[0.0017, 0.0], [0.0, 0.0011]],
        "C": [[0.0034435220738933993, 0.0], [0.0, 0.002228161341931023]],
        "K_init": [[50.613, -50.0], [-50.0, 50.536]],
        "K_EI": [[0.613, 0.0], [0.0, 0.536]],
        "K_N": [[50.0, -50.0], [-50.0, 50.0]],
        "experimental": [("C1", 0, {"kind": "linear", "k": 0.613}),
                         ("C2", 1, {"kind": "bilinear_gap", "k1": 0.536, "k2": 2.011, "gap": 10.0})],
        "numerical": [],
    },
    "structure_I": {
        "dt": 0.005, "dofs": ("wall",),
        "M": [[0.011]], "C": [[0.016911534525287764]], "K_init": [[2.6]], "K_EI": [[2.6]], "K_N": [[0.0]],
        "experimental": [("wall", 0, {"kind": "pinched_wood", "k0": 2.6, "F0": 30.0, "r1": 0.05, "r3": 1.5,
                                      "r4": 0.02, "r_pinch": 0.15})],
        "numerical": [],
    },
    "structure_II": {
        "dt": 0.005, "dofs": ("BF", "IF", "BF_mirror"),
        "M": [[0.012, 0.0, 0.0], [0.0, 0.019, 0.0], [0.0, 0.0, 0.012]],
        "C": [[0.08195343985921028, 0.0, 0.0], [0.0, 0.12975961311041626, 0.0], [0.0, 0.0, 0.08195343985921028]],
        "K_init": [[296.2, -289.0, 0.0], [-289.0, 700.6, -289.0], [0.0, -289.0, 296.2]],
        "K_EI": [[7.2, 0.0, 0.0], [0.0, 122.6, 0.0], [0.0, 0.0, 0.0]],
        "K_N": [[289.0, -289.0, 0.0], [-289.0, 578.0, -289.0], [0.0, -289.0, 289.0]],
        "experimental": [("BF", 0, {"kind": "linear", "k": 7.2}), ("IF", 1, {"kind": "linear", "k": 122.6})],
        "numerical": [("BF_mirror", 2, {"kind": "linear", "k": 7.2})],
    },
}


@pytest.mark.parametrize("name", sorted(FROZEN))
def test_shipped_structures_equal_the_paper_structures_in_code(name):
    frozen = FROZEN[name]
    for s in (get_structure(name), load_structure(REPO / "examples" / f"{name}.toml")):
        assert s.name == name and s.dt == frozen["dt"] and s.dof_names == frozen["dofs"]
        for key in ("M", "C", "K_init", "K_EI", "K_N"):
            np.testing.assert_allclose(getattr(s, key), frozen[key], rtol=0, atol=1e-12, err_msg=key)
        assert [(e.name, e.dof, e.specimen) for e in s.experimental] == frozen["experimental"]
        assert [(e.name, e.dof, e.specimen) for e in s.numerical] == frozen["numerical"]
        assert [e.actuator for e in s.experimental] == [e.name for e in s.experimental]
        np.testing.assert_array_equal(s.iota, np.ones(s.n_dof))
        assert s.numerical_assembly().is_linear


def test_shipped_names_and_lookup():
    assert shipped_names()[:3] == ["validation", "structure_I", "structure_II"]
    assert "three_storey" in shipped_names()
    assert load_structure("structure_II").K_N.tolist() == get_structure("structure_II").K_N.tolist()
    with pytest.raises(ConfigError, match="unknown structure 'tower'.*known: validation"):
        load_structure("tower")
    with pytest.raises(ConfigError, match="nowhere.toml: cannot read"):
        load_structure("nowhere.toml")


def structure(tmp_path, body: str, head: str = '[structure]\ndt = 0.01\n', name: str = "s.toml"):
    path = tmp_path / name
    path.write_text(head + body)
    return load_structure(path)


THREE = """
[[dof]]
name = "a"
mass = 1.0
[[dof]]
name = "b"
mass = 2.0
[[dof]]
name = "c"
mass = 1.5
[[experimental]]
dof = "a"
model = { kind = "linear", k = 400.0 }
[[spring]]
dof = "b"
to = "a"
k = 300.0
[[spring]]
dof = "c"
to = "b"
k = 200.0
"""


def modal(s):
    omega, phi = s.modes()
    return omega, phi, np.einsum("ir,ij,js->rs", phi, s.C, phi)


def test_rayleigh_gives_zeta_on_the_two_chosen_modes_and_the_formula_elsewhere(tmp_path):
    s = structure(tmp_path, THREE + "[damping]\nkind = 'rayleigh'\nzeta = 0.04\nmodes = [1, 3]\n")
    omega, _, C = modal(s)
    zeta = np.diag(C) / (2 * omega)
    assert zeta[0] == pytest.approx(0.04, abs=1e-12) and zeta[2] == pytest.approx(0.04, abs=1e-12)
    w1, w3 = omega[0], omega[2]
    a0, a1 = 2 * 0.04 * w1 * w3 / (w1 + w3), 2 * 0.04 / (w1 + w3)
    assert zeta[1] == pytest.approx(a0 / (2 * omega[1]) + a1 * omega[1] / 2, rel=1e-12)
    assert zeta[1] < 0.04  # between the two anchors, Rayleigh damping is lower
    np.testing.assert_allclose(C - np.diag(np.diag(C)), 0, atol=1e-12)  # classical damping


def test_rayleigh_with_a_ratio_per_mode(tmp_path):
    s = structure(tmp_path, THREE + "[damping]\nkind = 'rayleigh'\nzeta = [0.02, 0.06]\nmodes = [1, 2]\n")
    np.testing.assert_allclose(s.damping_ratios()[:2], [0.02, 0.06], atol=1e-12)


def test_modal_damping_gives_each_declared_ratio(tmp_path):
    s = structure(tmp_path, THREE + "[damping]\nkind = 'modal'\nzeta = [0.02, 0.03, 0.07]\n")
    omega, _, C = modal(s)
    np.testing.assert_allclose(np.diag(C) / (2 * omega), [0.02, 0.03, 0.07], atol=1e-12)
    np.testing.assert_allclose(C - np.diag(np.diag(C)), 0, atol=1e-12)
    np.testing.assert_allclose(s.C, s.C.T, atol=1e-12)
    one = structure(tmp_path, THREE + "[damping]\nkind = 'modal'\nzeta = 0.05\n")
    np.testing.assert_allclose(one.damping_ratios(), 0.05, atol=1e-12)


def test_mass_and_stiffness_proportional_damping(tmp_path):
    s = structure(tmp_path, THREE + "[damping]\nkind = 'mass'\nzeta = 0.05\n")
    omega = s.modes()[0]
    np.testing.assert_allclose(s.damping_ratios(), 0.05 * omega[0] / omega, rtol=1e-12)  # zeta on mode 1 only
    s = structure(tmp_path, THREE + "[damping]\nkind = 'stiffness'\nzeta = 0.05\nmodes = [2]\n")
    np.testing.assert_allclose(s.damping_ratios(), 0.05 * omega / omega[1], rtol=1e-12)


def test_influence_vector_and_full_mass_matrix(tmp_path):
    body = THREE.replace('name = "b"\nmass = 2.0', 'name = "b"\nmass = 2.0\niota = 0.0')
    assert structure(tmp_path, body).iota.tolist() == [1.0, 0.0, 1.0]
    full = THREE.replace("mass = 1.0\n", "").replace("mass = 2.0\n", "").replace("mass = 1.5\n", "")
    s = structure(tmp_path, full + "[mass]\nmatrix = [[1.0, 0.1, 0.0], [0.1, 2.0, 0.0], [0.0, 0.0, 1.5]]\n")
    assert s.M.tolist() == [[1.0, 0.1, 0.0], [0.1, 2.0, 0.0], [0.0, 0.0, 1.5]]
    assert s.masses == (1.0, 2.0, 1.5)


def test_a_spring_and_an_element_between_two_dofs(tmp_path):
    s = structure(tmp_path, THREE)
    assert s.K_N.tolist() == [[300.0, -300.0, 0.0], [-300.0, 500.0, -200.0], [0.0, -200.0, 200.0]]
    assert s.K_init[0, 0] == 700.0 and s.K_EI.tolist()[0] == [400.0, 0.0, 0.0]
    body = THREE + '[[numerical]]\nname = "brace"\ndof = "c"\nto = "a"\nmodel = { kind = "bilinear_gap", k1 = 10.0, k2 = 30.0, gap = 2.0 }\n'
    s = structure(tmp_path, body)
    K = s.K_num_init
    assert (K[2, 2], K[0, 0], K[0, 2], K[2, 0], K[1, 1]) == (10.0, 10.0, -10.0, -10.0, 0.0)
    assembly = s.numerical_assembly()
    assert not assembly.is_linear
    u = np.array([1.0, 0.0, 5.0])  # the brace stretches 4 mm: 10 x 4 + 20 x 2 = 80 kN
    R = assembly.trial(u)
    np.testing.assert_allclose(R, s.K_N @ u + np.array([-80.0, 0.0, 80.0]), rtol=1e-12)
    with pytest.raises(ConfigError, match="joins two DOF"):
        s.numerical[0].dof


def test_declared_K_EI_is_what_the_integrator_uses(tmp_path):
    body = THREE.replace('dof = "a"\nmodel', 'dof = "a"\nactuator = "east"\nK_EI = 350.0\nmodel')
    s = structure(tmp_path, body)
    e = s.experimental[0]
    assert (e.K_EI, e.model().initial_stiffness, e.actuator, e.name) == (350.0, 400.0, "east", "a")
    assert s.K_EI[0, 0] == 350.0 and s.K_init[0, 0] == 650.0


BAD = [
    ('[[dof]]\nname = "a"\nmass = 1.0\nweight = 2\n', r"dof\[0\]\.weight: unknown key"),
    ('[[dof]]\nname = "a"\nmass = 0.0\n', r"dof\[0\]\.mass: must be positive"),
    ('[[dof]]\nname = "a"\nmass = -1.0\n', r"dof\[0\]\.mass: must be positive"),
    ('[[dof]]\nname = "a"\nmass = nan\n', r"dof\[0\]\.mass: must be finite"),
    ('[[dof]]\nname = "a"\nmass = inf\n', r"dof\[0\]\.mass: must be finite"),
    ('[[dof]]\nname = "a"\nmass = "heavy"\n', r"dof\[0\]\.mass: must be a number"),
    ('[[dof]]\nname = "a"\n', r"dof\[0\]\.mass: missing"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[dof]]\nname = "a"\nmass = 1.0\n', r"dof\[1\]\.name: DOF 'a' is declared twice"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[experimental]]\ndof = "z"\nmodel = { kind = "linear", k = 1.0 }\n',
     r"experimental\[0\]\.dof: unknown DOF 'z'"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[spring]]\ndof = "a"\nto = "a"\nk = 1.0\n', r"spring\[0\]\.to: .*joins DOF 'a' to itself"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[spring]]\ndof = "a"\nto = "b"\nk = 1.0\n', r"spring\[0\]\.to: unknown DOF 'b'"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[spring]]\ndof = "a"\nk = 1.0\n[damping]\nkind = "rayleigh"\n',
     r"damping\.modes\[1\]: mode 2 does not exist"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[spring]]\ndof = "a"\nk = 1.0\n[damping]\nkind = "mass"\nmodes = [3]\n',
     r"damping\.modes\[0\]: mode 3 does not exist"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[spring]]\ndof = "a"\nk = 1.0\n[damping]\nkind = "viscous"\n', r"damping\.kind: must be one of"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[spring]]\ndof = "a"\nk = 1.0\n[damping]\nzeta = 1.5\n', r"damping\.zeta: .*below 1"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[dof]]\nname = "b"\nmass = 1.0\n[[spring]]\ndof = "a"\nk = 1.0\n[[spring]]\ndof = "b"\n'
     'k = 2.0\n[damping]\nkind = "modal"\nzeta = [0.05, 1.0]\n', r"damping\.zeta\[1\]: .*below 1; got 1\.0$"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[spring]]\ndof = "a"\nk = 1.0\n[damping]\nkind = "modal"\nzeta = [0.1, 0.2]\n',
     r"damping\.zeta: 2 ratios for 1 modes"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[numerical]]\ndof = "a"\nmodel = { kind = "rubber", k = 1.0 }\n',
     r"numerical\[0\]\.model\.kind: unknown specimen model 'rubber'"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[numerical]]\ndof = "a"\nmodel = { kind = "linear", k = 1.0, c = 2.0 }\n',
     r"numerical\[0\]\.model\.c: unknown parameter of 'linear'"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[numerical]]\ndof = "a"\nmodel = { kind = "menegotto_pinto", k0 = 1.0 }\n',
     r"numerical\[0\]\.model\.u_y: missing"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[experimental]]\ndof = "a"\nmodel = { kind = "peak_oriented", k0 = 1.0, Fy = 5.0, u_c = 2.0 }\n',
     r"experimental\[0\]\.model: peak_oriented: u_c must exceed"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[experimental]]\ndof = "a"\nK_EI = -1.0\nmodel = { kind = "linear", k = 1.0 }\n',
     r"experimental\[0\]\.K_EI: must be positive"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[dof]]\nname = "b"\nmass = 1.0\n[[experimental]]\ndof = "a"\nactuator = "x"\n'
     'model = { kind = "linear", k = 1.0 }\n[[experimental]]\ndof = "b"\nactuator = "x"\nmodel = { kind = "linear", k = 1.0 }\n',
     r"experimental\[1\]\.actuator: already used by experimental\[0\]"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[dof]]\nname = "b"\nmass = 1.0\n[[spring]]\ndof = "a"\nk = 1.0\n',
     r"dof\[1\]: DOF 'b' has no stiffness path to the ground"),
    ('[[dof]]\nname = "a"\n[[dof]]\nname = "b"\n[[spring]]\ndof = "a"\nk = 1.0\n[[spring]]\ndof = "b"\nk = 1.0\n'
     '[mass]\nmatrix = [[1.0, 0.5], [0.4, 1.0]]\n', r"mass\.matrix: not symmetric"),
    ('[[dof]]\nname = "a"\n[[dof]]\nname = "b"\n[[spring]]\ndof = "a"\nk = 1.0\n[[spring]]\ndof = "b"\nk = 1.0\n'
     '[mass]\nmatrix = [[1.0, 2.0], [2.0, 1.0]]\n', r"mass\.matrix: not positive definite"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[mass]\nmatrix = [[1.0]]\n', r"dof\[0\]\.mass: give the masses either"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[loads]\nx = 1\n', r"loads: unknown table"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[spring]]\nname = "x"\ndof = "a"\nk = 1.0\n[[numerical]]\nname = "x"\ndof = "a"\n'
     'model = { kind = "linear", k = 1.0 }\n', r"numerical\[0\]\.name: 'x' already names spring\[0\]"),
    ('[dof]\nname = "a"\nmass = 1.0\n', r"dof: must be an array of tables"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[experimental]]\ndof = "a"\nmodel = { kind = "linear", k = 1.0 }\n'
     '[[static]]\nname = "axial"\nforce_kN = 10.0\nramp_s = 1e-300\nmodel = { kind = "linear", k = 5.0 }\n',
     r"static\[0\]\.ramp_s: 1e-300 s is out of bounds: a preload's ramp lasts at least 0\.1 s"),
    ('[[dof]]\nname = "a"\nmass = 1.0\n[[experimental]]\ndof = "a"\nmodel = { kind = "linear", k = 1.0 }\n'
     '[[static]]\nname = "axial"\nforce_kN = 10.0\nramp_s = 7200.0\nmodel = { kind = "linear", k = 5.0 }\n',
     r"static\[0\]\.ramp_s: 7200 s is out of bounds: a preload's ramp lasts at most 3600 s"),
]


@pytest.mark.parametrize("body, message", BAD, ids=[m for _, m in BAD])
def test_every_error_names_the_file_and_the_key(tmp_path, body, message):
    with pytest.raises(ConfigError, match=r"s\.toml: " + message):
        structure(tmp_path, body)


def test_errors_in_the_structure_table(tmp_path):
    body = '[[dof]]\nname = "a"\nmass = 1.0\n[[spring]]\ndof = "a"\nk = 1.0\n'
    with pytest.raises(ConfigError, match=r"s\.toml: structure\.dt: must be positive"):
        structure(tmp_path, body, head="[structure]\ndt = 0.0\n")
    with pytest.raises(ConfigError, match=r"s\.toml: structure\.dt: missing"):
        structure(tmp_path, body, head="[structure]\n")
    with pytest.raises(ConfigError, match=r"s\.toml: structure\.period: unknown key"):
        structure(tmp_path, body, head="[structure]\ndt = 0.01\nperiod = 1\n")
    assert structure(tmp_path, body, name="my_frame.toml").name == "my_frame"
    with pytest.raises(ConfigError, match=r"s\.toml: structure: missing"):
        structure(tmp_path, body, head="")
    assert load_structure("my_frame.toml", relative_to=tmp_path).name == "my_frame"


def test_files_that_are_not_utf8_toml_or_too_big(tmp_path):
    path = tmp_path / "latin1.toml"
    path.write_bytes('[structure]\ndt = 0.01\ndescription = "poutre en b\u00e9ton"\n'.encode("latin-1"))
    with pytest.raises(ConfigError, match=r"latin1\.toml: not UTF-8"):
        load_structure(path)
    with pytest.raises(ConfigError, match=r"x\.toml: not valid TOML"):
        parse_structure(b"[structure\n", "x.toml")
    many = "".join(f'[[dof]]\nname = "d{k}"\nmass = 1.0\n' for k in range(MAX_DOF + 1))
    with pytest.raises(ConfigError, match=rf"big\.toml: dof: {MAX_DOF + 1} entries; at most {MAX_DOF}"):
        parse_structure("[structure]\ndt = 0.01\n" + many, "big.toml")


def test_every_specimen_kind_loads_as_a_numerical_element(tmp_path):
    models = ['{ kind = "linear", k = 2.0 }', '{ kind = "bilinear_gap", k1 = 2.0, k2 = 5.0, gap = 1.0 }',
              '{ kind = "menegotto_pinto", k0 = 2.0, u_y = 1.0, theta = 0.1, n = 2.0 }',
              '{ kind = "pinched_wood", k0 = 2.0, F0 = 10.0 }', '{ kind = "peak_oriented", k0 = 2.0, Fy = 2.0, u_c = 4.0 }']
    body = '[[dof]]\nname = "a"\nmass = 1.0\n[[dof]]\nname = "b"\nmass = 1.0\n[[spring]]\ndof = "a"\nk = 1.0\n'
    for k, m in enumerate(models):
        body += f'[[numerical]]\nname = "n{k}"\ndof = "b"\nto = "a"\nmodel = {m}\n'
    s = structure(tmp_path, body)
    assert s.K_num_init[1, 1] == pytest.approx(10.0) and s.K_num_init[0, 1] == pytest.approx(-10.0)
    assembly = s.numerical_assembly()
    R = assembly.trial(np.array([0.0, 0.1]))
    assert R[1] == pytest.approx(-R[0]) and 0.9 < R[1] < 1.01  # about 10 kN/mm x 0.1 mm


def test_any_bad_value_anywhere_gives_a_config_error_naming_the_file():
    import copy
    import tomllib

    from hsio.structure_file import structure_from_tables

    doc = tomllib.loads((REPO / "hsio" / "library" / "three_storey.toml").read_text())
    places = []  # (path of keys/indices) to every value of the file
    def walk(node, path):
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for key, value in items:
            places.append((*path, key))
            walk(value, (*path, key))
    walk(doc, ())
    bad_values = ["x", -1.0, 0, float("nan"), [], {}, True, [[1.0]], 1e300]
    failures = 0
    for place in places:
        for bad in bad_values:
            mutated = copy.deepcopy(doc)
            node = mutated
            for key in place[:-1]:
                node = node[key]
            node[place[-1]] = bad
            try:
                structure_from_tables(mutated, "b.toml")
            except ConfigError as exc:
                assert str(exc).startswith("b.toml: "), exc
                failures += 1
    assert failures > len(places) * 4  # most substitutions are refused, none with another exception
