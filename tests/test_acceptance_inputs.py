"""Inputs a lab brings: PEER records (the shared ones and records written here), structure files of
unusual but valid shape checked against closed forms and independent ODE solutions, and bad
inputs refused with exit 2 naming the file, the key or the option."""

from __future__ import annotations

import json
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from click.testing import CliRunner
from scipy.integrate import solve_ivp

import hsio
from hsio import config, runner
from hsio.errors import ConfigError, RecordError
from hsio.ground_motion import G_MM_S2, GroundMotion, read_at2
from hsio.recording import Run
from hsio.structure_file import parse_structure


def write_at2(path: Path, dt: float, accel_g, line4: str | None = None, newline: str = "\n") -> Path:
    lines = ["PEER NGA STRONG MOTION DATABASE RECORD", "written by the test", "ACCELERATION TIME SERIES IN UNITS OF G",
             line4 or f"NPTS= {len(accel_g)}, DT= {dt:.4f} SEC"]
    lines += ["".join(f"{v:16.7E}" for v in accel_g[k:k + 5]) for k in range(0, len(accel_g), 5)]
    path.write_text(newline.join(lines) + newline)
    return path


# An SDOF: m = 0.01 kN s^2/mm, k = 1 kN/mm: w = 10 rad/s; 5 % of critical, mass-proportional.
SDOF = """
[structure]
name = "sdof"
dt = 0.005
[[dof]]
name = "x"
mass = 0.01
[damping]
kind = "mass"
zeta = 0.05
[[experimental]]
dof = "x"
actuator = "act"
model = { kind = "linear", k = 1.0 }
"""
W, ZETA = 10.0, 0.05


def step_response(t: np.ndarray, a_g_g: float) -> np.ndarray:
    """u'' + 2 zeta w u' + w^2 u = -a_g, a_g constant from t = 0, at rest: the closed form."""
    a = a_g_g * G_MM_S2
    wd = W * np.sqrt(1 - ZETA**2)
    decay = np.exp(-ZETA * W * t) * (np.cos(wd * t) + ZETA / np.sqrt(1 - ZETA**2) * np.sin(wd * t))
    return -a / W**2 * (1 - decay)


def reference(M, K, C, iota, t, a_g_g) -> np.ndarray:
    """M u'' + C u' + K u = -M iota a_g(t), a_g linear between samples: an ODE solve, tight."""
    n = M.shape[0]
    Minv_load = -iota  # M^-1 (-M iota)
    Minv = np.linalg.inv(M)

    def rhs(time, y):
        u, v = y[:n], y[n:]
        a_g = np.interp(time, t, a_g_g) * G_MM_S2
        return np.concatenate([v, Minv_load * a_g - Minv @ (C @ v + K @ u)])

    sol = solve_ivp(rhs, (0, t[-1]), np.zeros(2 * n), t_eval=t, rtol=1e-9, atol=1e-9, max_step=t[1] - t[0])
    return sol.y[:n].T


# -- the excitation: sign, units, damping, time steps ----------------------------------------------

def test_a_step_of_ground_acceleration_gives_the_closed_form(tmp_path):
    """A record in g at 0.02 s on a structure at 0.005 s: the relative displacement is negative for
    a positive a_g (u'' + 2 zeta w u' + w^2 u = -a_g), static -a_g / w^2 in mm with a_g in mm/s^2."""
    structure = parse_structure(SDOF, "sdof.toml")
    ground = read_at2(write_at2(tmp_path / "step.AT2", 0.02, np.full(151, 0.1)))  # 3 s
    ns = hsio.run_numerical(structure, ground)
    exact = step_response(ns.t, 0.1)
    assert ns.steps == 600
    assert ns.u[:, 0].min() == pytest.approx(exact.min(), rel=2e-3)  # -18.19 mm: overshoot of -9.81 mm
    assert np.abs(ns.u[:, 0] - exact).max() < 2e-3 * np.abs(exact).max()


def test_hsio_run_on_the_emulator_gives_the_closed_form(tmp_path):
    """The same SDOF through `hsio run` (structure file, AT2 file, scale, emulated actuator)."""
    (tmp_path / "sdof.toml").write_text(SDOF)
    write_at2(tmp_path / "step.AT2", 0.005, np.full(401, 0.2))
    (tmp_path / "run.toml").write_text('[structure]\nfile = "sdof.toml"\n[record]\nfile = "step.AT2"\nscale = -0.5\n'
                                       '[output]\nplots = false\nsamples = false\n'
                                       '[safety]\nkeys = false\ncontrol_socket = false\n')
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "run", "run.toml", "--out", "out", "--json"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout)["steps"] == 400
    steps = Run(tmp_path / "out" / "run.sqlite").steps
    exact = step_response(steps["time_s"], -0.1)  # 0.2 g x -0.5: the displacement is positive
    assert exact.max() > 18.0
    assert np.abs(steps["u_x"] - exact).max() < 5e-3 * exact.max()


def test_a_harmonic_record_at_another_time_step(tmp_path):
    """Record at 0.01 s, structure at 0.004 s (not a multiple): the record is interpolated, not
    re-timed; the response matches an ODE solve of the interpolated record."""
    text = SDOF.replace("dt = 0.005", "dt = 0.004")
    structure = parse_structure(text, "sdof.toml")
    t_rec = np.arange(301) * 0.01
    a_rec = 0.2 * np.sin(2 * np.pi * 3.0 * t_rec)
    ns = hsio.run_numerical(structure, read_at2(write_at2(tmp_path / "h.AT2", 0.01, a_rec)))
    assert ns.steps == 750
    ref = reference(structure.M, structure.K_init, np.array([[2 * ZETA * W * 0.01]]), np.ones(1), ns.t,
                    np.interp(ns.t, t_rec, a_rec))
    assert np.abs(ns.u - ref).max() < 5e-3 * np.abs(ref).max()


def test_the_shared_records_read_as_their_sources_say(shared_data):
    """NPTS, DT and PGA of every record in shared/data/ground_motions (SOURCES.md)."""
    folder = shared_data / "ground_motions"
    expected = {"RSN1087_NORTHR_TAR090.AT2": (2000, 0.02, 1.77942, 8.36),
                "RSN1087_NORTHR_TAR360.AT2": (2000, 0.02, -0.99024, 10.74),
                "I-ELC180.AT2": (4000, 0.01, -0.31288, 2.15),
                "elCentro.AT2": (1559, 0.02, -0.31882, 2.02)}
    for name, (npts, dt, peak, t_peak) in expected.items():
        g = read_at2(folder / name)
        k = int(np.argmax(np.abs(g.accel_g)))
        assert (g.accel_g.size, g.dt) == (npts, dt), name
        assert g.accel_g[k] == pytest.approx(peak, abs=1e-5) and k * g.dt == pytest.approx(t_peak), name


# -- structures of unusual shape against independent solutions -------------------------------------

FIVE = """
[structure]
dt = 0.002
[[dof]]
name = "a"
mass = 0.02
[[dof]]
name = "b"
mass = 0.02
[[dof]]
name = "c"
mass = 0.015
[[dof]]
name = "d"
mass = 0.01
[[dof]]
name = "e"
mass = 0.01
iota = 0
{damping}
[[spring]]
dof = "a"
k = 40
[[spring]]
dof = "b"
to = "a"
k = 30
[[spring]]
dof = "c"
to = "b"
k = 25
[[spring]]
dof = "d"
to = "c"
k = 20
[[spring]]
dof = "e"
to = "d"
k = 10
[[experimental]]
dof = "c"
actuator = "act"
model = {{ kind = "linear", k = 5.0 }}
"""

FULL_MASS = """
[structure]
dt = 0.002
[[dof]]
name = "x"
[[dof]]
name = "y"
iota = -1
[mass]
matrix = [[0.02, 0.005], [0.005, 0.01]]
{damping}
[[spring]]
dof = "x"
to = "y"
k = 8
[[experimental]]
dof = "y"
model = {{ kind = "linear", k = 3.0 }}
[[numerical]]
dof = "x"
model = {{ kind = "linear", k = 6.0 }}
"""


def rayleigh(M, K, modes, ratios):
    w = np.sqrt(scipy.linalg.eigh(K, M, eigvals_only=True))
    wi, wj = w[modes[0] - 1], w[modes[1] - 1]
    a0, a1 = np.linalg.solve([[1 / (2 * wi), wi / 2], [1 / (2 * wj), wj / 2]], ratios)
    return a0 * M + a1 * K


def modal(M, K, ratios):
    w2, phi = scipy.linalg.eigh(K, M)
    Mphi = M @ phi
    return Mphi @ np.diag(2 * np.asarray(ratios) * np.sqrt(w2)) @ Mphi.T


CASES = {
    "five, Rayleigh on modes 2 and 3": (FIVE, '[damping]\nkind = "rayleigh"\nzeta = [0.03, 0.04]\nmodes = [2, 3]',
                                        lambda M, K: rayleigh(M, K, (2, 3), (0.03, 0.04))),
    "five, modal ratios": (FIVE, '[damping]\nkind = "modal"\nzeta = [0.01, 0.02, 0.03, 0.04, 0.05]',
                           lambda M, K: modal(M, K, [0.01, 0.02, 0.03, 0.04, 0.05])),
    "five, stiffness on mode 3": (FIVE, '[damping]\nkind = "stiffness"\nzeta = 0.02\nmodes = [3]',
                                  lambda M, K: 2 * 0.02 / np.sqrt(scipy.linalg.eigh(K, M, eigvals_only=True)[2]) * K),
    "five, no damping": (FIVE, "[damping]\nzeta = 0", lambda M, K: np.zeros_like(M)),
    "full mass matrix, Rayleigh": (FULL_MASS, "[damping]\nzeta = 0.05",
                                   lambda M, K: rayleigh(M, K, (1, 2), (0.05, 0.05))),
}


@pytest.mark.parametrize("case", CASES)
def test_unusual_structures_match_an_independent_solution(case):
    """NS of a structure file against an ODE solve with M, K and C built here from the file's
    numbers: the excitation direction (iota 0 and -1), the element on a DOF other than the first,
    springs between DOFs, a full mass matrix, each kind of damping."""
    template, damping, damping_matrix = CASES[case]
    structure = parse_structure(template.format(damping=damping), "s.toml")
    n = structure.n_dof
    if n == 5:
        M = np.diag([0.02, 0.02, 0.015, 0.01, 0.01])
        K = np.zeros((5, 5))
        for i, k in enumerate([40, 30, 25, 20, 10]):
            K[i, i] += k
            if i:
                K[i - 1, i - 1] += k
                K[i, i - 1] -= k
                K[i - 1, i] -= k
        K[2, 2] += 5.0  # the experimental element on DOF c, to the ground
        iota = np.array([1.0, 1, 1, 1, 0])
    else:
        M = np.array([[0.02, 0.005], [0.005, 0.01]])
        K = np.array([[8.0 + 6.0, -8.0], [-8.0, 8.0 + 3.0]])
        iota = np.array([1.0, -1.0])
    C = damping_matrix(M, K)
    np.testing.assert_allclose(structure.M, M)
    np.testing.assert_allclose(structure.K_init, K)
    np.testing.assert_allclose(structure.C, C, atol=1e-12 * np.abs(K).max())
    t = np.arange(1501) * structure.dt
    a_g = 0.1 * np.sin(2 * np.pi * 1.3 * t) + 0.05 * np.sin(2 * np.pi * 4.1 * t)
    ns = hsio.run_numerical(structure, GroundMotion("two sines", structure.dt, a_g))
    ref = reference(M, K, C, iota, t, a_g)
    peak = np.abs(ref).max(axis=0)
    assert np.all(np.abs(ns.u - ref).max(axis=0) < 0.012 * peak), case


def test_rayleigh_on_modes_2_and_3_gives_the_declared_ratios():
    s = parse_structure(FIVE.format(damping='[damping]\nzeta = [0.03, 0.04]\nmodes = [2, 3]'), "s.toml")
    zeta = s.damping_ratios()
    np.testing.assert_allclose(zeta[1:3], [0.03, 0.04], rtol=1e-10)
    assert np.all(zeta >= 0)


def test_rayleigh_damping_that_would_be_negative_on_a_mode_is_refused():
    """zeta 3 % and 6 % on modes 2 and 3 (4.99 and 7.84 Hz): a0 < 0 gives mode 1 -0.46 %, a C that
    feeds energy into it."""
    text = FIVE.format(damping='[damping]\nzeta = [0.03, 0.06]\nmodes = [2, 3]')
    with pytest.raises(ConfigError, match=r"s\.toml: damping\.zeta: .*mode 1 .*negative damping ratio \(-0\.45"):
        parse_structure(text, "s.toml")


# -- structure files refused, naming the file and the key -------------------------------------------

HEAD = '[structure]\ndt = 0.005\n[[dof]]\nname = "x"\nmass = 0.01\n'


def test_a_model_parameter_is_never_the_model_state():
    """`diagnosed` keeps its state in `_state` / `_trial`: a file giving them is refused before the
    run (it would stop at the first step), and the missing-parameter message names the required."""
    with pytest.raises(ConfigError, match=r"s\.toml: experimental\[0\]\.model\._state: unknown parameter"):
        parse_structure(HEAD + '[[experimental]]\ndof = "x"\nmodel = { kind = "diagnosed", k = 1.0, _state = 1.0 }\n',
                        "s.toml")
    with pytest.raises(ConfigError, match=r"model\.k: missing: 'diagnosed' needs k \(optional: c, ") as info:
        parse_structure(HEAD + '[[experimental]]\ndof = "x"\nmodel = { kind = "diagnosed" }\n', "s.toml")
    assert "_state" not in str(info.value)


def test_a_non_symmetric_mass_matrix_is_named_with_plain_numbers():
    text = ('[structure]\ndt = 0.005\n[[dof]]\nname = "x"\n[[dof]]\nname = "y"\n[mass]\n'
            'matrix = [[1.0, 0.5], [0.4, 1.0]]\n')
    with pytest.raises(ConfigError) as info:
        parse_structure(text, "s.toml")
    assert str(info.value) == "s.toml: mass.matrix: not symmetric: [0][1] = 0.5 but [1][0] = 0.4"


BAD_STRUCTURES = {
    "mass = -0.01": (HEAD.replace("0.01", "-0.01"), "dof[0].mass: must be positive"),
    "mass = 0": (HEAD.replace("0.01", "0"), "dof[0].mass: must be positive"),
    "mass = nan": (HEAD.replace("0.01", "nan"), "dof[0].mass: must be finite"),
    "singular mass matrix": ('[structure]\ndt = 0.005\n[[dof]]\nname = "x"\n[[dof]]\nname = "y"\n[mass]\n'
                             'matrix = [[1.0, 1.0], [1.0, 1.0]]\n', "mass.matrix: not positive definite"),
    "unknown key": (HEAD + 'colour = "red"\n', "dof[0].colour: unknown key"),
    "wrong type": (HEAD.replace("0.005", '"0.005"'), "structure.dt: must be a number"),
    "duplicated DOF": (HEAD + '[[dof]]\nname = "x"\nmass = 0.01\n', "dof[1].name: DOF 'x' is declared twice"),
    "element on an unknown DOF": (HEAD + '[[experimental]]\ndof = "y"\nmodel = { kind = "linear", k = 1.0 }\n',
                                  "experimental[0].dof: unknown DOF 'y'"),
    "mode beyond the DOFs": (HEAD + '[damping]\nkind = "mass"\nmodes = [2]\n',
                             "damping.modes[0]: mode 2 does not exist"),
    "empty file": ("", "structure: missing"),
}


@pytest.mark.parametrize("case", BAD_STRUCTURES)
def test_hsio_check_refuses_a_bad_structure_file_naming_file_and_key(tmp_path, case):
    text, message = BAD_STRUCTURES[case]
    if "[[experimental]]" not in text:
        text += '[[experimental]]\ndof = "x"\nmodel = { kind = "linear", k = 1.0 }\n'
    (tmp_path / "frame.toml").write_text(text)
    (tmp_path / "run.toml").write_text('[structure]\nfile = "frame.toml"\n')
    from hsio.cli import main

    result = CliRunner().invoke(main, ["check", str(tmp_path / "run.toml")])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert f"frame.toml: {message}" in result.output


# -- records refused ---------------------------------------------------------------------------------

def test_a_record_shorter_than_one_time_step_of_the_structure_is_named(tmp_path):
    structure = parse_structure(SDOF, "sdof.toml")
    ground = read_at2(write_at2(tmp_path / "tiny.AT2", 0.001, np.array([0.1, 0.2])))
    with pytest.raises(RecordError, match=r"tiny\.AT2: the record lasts 0\.001 s .*shorter than one time step "
                                          r"0\.005 s of the structure"):
        hsio.run_numerical(structure, ground)


def test_a_record_with_more_values_than_npts_is_refused_at_the_first_extra_value(tmp_path):
    path = write_at2(tmp_path / "long.AT2", 0.01, np.zeros(12), line4="NPTS= 7, DT= .0100 SEC")
    with pytest.raises(RecordError, match=r"long\.AT2:6: header says NPTS = 7, file holds more values"):
        read_at2(path)


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
def test_a_bad_value_is_named_by_its_line_whatever_the_line_endings(tmp_path, newline):
    path = tmp_path / "g.AT2"
    path.write_text(newline.join(["PEER", "x", "ACCELERATION IN UNITS OF G", "NPTS= 4, DT= .0100 SEC", "", "0.1 0.2",
                                  "", "0.3 x", ""]), newline="")
    with pytest.raises(RecordError, match=r"g\.AT2:8: 'x' is not a number"):
        read_at2(path)


def test_a_record_file_takes_the_memory_of_its_bytes_not_of_the_bound(tmp_path):
    """4 MB of blank lines after the values: read with the memory of the file (never the 200 MB
    bound reserved up front, never a string per line): a file near the bound cannot exhaust memory."""
    path = tmp_path / "g.AT2"
    path.write_bytes(b"PEER\nx\nACCELERATION IN UNITS OF G\nNPTS= 2, DT= .0100 SEC\n 0.1 -0.1\n" + b"\n" * 4_000_000)
    tracemalloc.start()
    try:
        assert read_at2(path).accel_g.tolist() == [0.1, -0.1]
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 3 * path.stat().st_size


def test_a_scale_of_zero_is_refused():
    with pytest.raises(ConfigError, match=r"run\.toml: \[record\] scale = 0 would run the record as zeros"):
        config.from_dict({"record": {"scale": 0.0}}, "run.toml")
    assert config.from_dict({"record": {"scale": -0.17}}, "run.toml")["record"]["scale"] == -0.17


def test_a_cut_longer_than_a_shared_record_is_refused(shared_data):
    cfg = config.from_dict({"record": {"file": str(shared_data / "ground_motions" / "elCentro.AT2"),
                                       "duration_s": 31.5}}, "run.toml")
    with pytest.raises(ConfigError, match=r"duration_s = 31\.5 s is longer than the record 'elCentro\.AT2' \(31\.16 s\)"):
        runner.build_record(cfg, parse_structure(SDOF, "sdof.toml"))


# -- command-line options ----------------------------------------------------------------------------

def test_bench_vrths_refuses_a_duration_beyond_the_record(shared_data):
    if not (shared_data / "vrths" / "benchmark.json").is_file():
        pytest.skip("no vRTHS benchmark data")
    from hsio.commands.bench import bench

    result = CliRunner().invoke(bench, ["vrths", "--case", "1", "--controller", "pi-lead", "--duration", "1e6",
                                        "--data", str(shared_data / "vrths")])
    assert result.exit_code == 2
    assert "--duration" in result.output and "longer than the record" in result.output


@pytest.mark.parametrize("option, value", [("--stiffness", "0"), ("--stiffness", "-7.2"), ("--stiffness", "1e300"),
                                           ("--resolution", "0"), ("--force-resolution", "-0.02")])
def test_study_mixed_refuses_a_grid_value_out_of_bounds(option, value):
    from hsio.commands.study import study

    result = CliRunner().invoke(study, ["mixed", option, value])
    assert result.exit_code == 2
    assert option in result.output and "out of bounds" in result.output


@pytest.mark.parametrize("args, message", [(["--margin", "0.5"], "--margin = 0.5 is out of bounds"),
                                           (["--margin", "0"], "--margin = 0 is out of bounds"),
                                           (["--command-scale", "0"], "--command-scale = 0 would read")])
def test_diagnose_refuses_a_margin_below_one_and_a_zero_scale(tmp_path, args, message):
    from hsio.commands.diagnose import diagnose

    path = tmp_path / "r.csv"
    path.write_text("time_s,command_mm,measured_mm\n0,0,0\n")
    result = CliRunner().invoke(diagnose, [str(path), *args])
    assert result.exit_code == 2
    assert message in result.output
