"""Python-API arguments are checked where they are given: a bad one is a ConfigError or a
RecordError naming the argument and its value, never a numpy/scipy/sqlite error later."""

import sqlite3

import numpy as np
import pytest

from hsio.errors import ConfigError, RecordError
from hsio.ground_motion import GroundMotion, read_at2, synthetic_record
from hsio.recording import RecordExistsError, Recorder, Run
from hsio.structures import Damping, ExperimentalElement, Structure, sdof

LINEAR = {"kind": "linear", "k": 1.0}


def wall(name="x", dof=0):
    return ExperimentalElement(name, dof, LINEAR)


def one(**kw):
    args = dict(name="s", dof_names=("x",), masses=(1.0,), experimental=(wall(),), damping=Damping(0.05, "mass"))
    args.update(kw)
    return Structure(**args)


def two(**kw):
    args = dict(name="s", dof_names=("x", "y"), masses=(1.0, 1.0), experimental=(wall("x", 0), wall("y", 1)))
    args.update(kw)
    return Structure(**args)


@pytest.mark.parametrize("build, match", [
    (lambda: sdof(zeta=-0.5), r"damping.zeta: must not be negative, got -0.5"),
    (lambda: sdof(zeta=float("nan")), r"damping.zeta: must be finite, got nan"),
    (lambda: sdof(k=-1), r"initial stiffness must be positive, got -1"),
    (lambda: sdof(dt=float("inf")), r"dt: must be finite, got inf"),
    (lambda: sdof(dt="0.01"), r"dt: must be a number, got '0.01'"),
    (lambda: sdof(specimen="linear"), r"specimen must be a table .*got 'linear'"),
    (lambda: ExperimentalElement("a", 0, LINEAR, K_EI_declared=-1.0), r"'a': K_EI_declared: must be positive, got -1.0"),
    (lambda: ExperimentalElement("a", 0, LINEAR, K_EI_declared=float("nan")), r"K_EI_declared: must be finite, got nan"),
    (lambda: ExperimentalElement("a", 0.0, LINEAR), r"'a': dof: must be a DOF index .*got 0.0"),
    (lambda: one(masses=("1",)), r"masses\[0\]: must be a number, got '1'"),
    (lambda: one(masses=None), r"masses: must be a tuple .*got None"),
    (lambda: one(experimental=wall()), r"experimental: must be a tuple of ExperimentalElement"),
    (lambda: one(influence=("a",)), r"influence\[0\]: must be a number, got 'a'"),
    (lambda: one(influence=(float("nan"),)), r"influence\[0\]: must be finite, got nan"),
    (lambda: two(mass_matrix=((1.0, 0.5), (0.0, 1.0))), r"mass_matrix: not symmetric"),
    (lambda: two(mass_matrix=((1.0, 2.0), (2.0, 1.0))), r"mass_matrix: not positive definite"),
    (lambda: two(dof_names=("x", "x")), r"dof_names\[1\]: DOF 'x' is declared twice"),
])
def test_a_structure_built_in_code_gets_the_structure_file_checks(build, match):
    with pytest.raises(ConfigError, match=match):
        build()


def test_a_structure_built_in_code_that_the_file_checks_pass_is_unchanged():
    s = sdof(m=1.0, k=4 * np.pi**2, zeta=0.02)
    assert s.natural_frequencies_hz()[0] == pytest.approx(1.0, rel=1e-12)
    assert s.damping_ratios()[0] == pytest.approx(0.02, rel=1e-12)
    M = two(mass_matrix=[[2.0, 0.5], [0.5, 1.0]]).M
    assert np.array_equal(M, [[2.0, 0.5], [0.5, 1.0]])


@pytest.mark.parametrize("kw, match", [
    (dict(dof_names=["a-b", "a_b"], actuator_names=["x"]), r"dof_names: 'a_b' and 'a-b'"),
    (dict(dof_names=["a"], actuator_names=["x", "x"]), r"actuator_names: 'x' twice"),
    (dict(dof_names=["a", "pred_a"], actuator_names=["x"]), r"column 'u_pred_a' twice"),
    (dict(dof_names=["a"], actuator_names=["x"], meta={"k": np.zeros(2)}), r"meta\['k'\] cannot be recorded as JSON"),
])
def test_a_recorder_refused_leaves_nothing_behind_and_the_fixed_call_works(tmp_path, kw, match):
    path = tmp_path / "run.sqlite"
    with pytest.raises(RecordError, match=match):
        Recorder(path, **kw)
    assert list(tmp_path.iterdir()) == []
    Recorder(path, ["a"], ["x"], {"k": [0.0, 0.0]}).close()
    with pytest.raises(RecordExistsError, match="never overwritten"):
        Recorder(path, ["a"], ["x"])


def test_a_recorder_given_a_directory_says_so(tmp_path):
    with pytest.raises(RecordError, match="is a directory"):
        Recorder(tmp_path, ["a"], ["x"])


def test_run_names_the_path_of_what_is_no_record(tmp_path):
    with pytest.raises(RecordError, match="no such run file"):
        Run(tmp_path / "missing.sqlite")
    with pytest.raises(RecordError, match="is a directory"):
        Run(tmp_path)
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"not a database " * 100)
    with pytest.raises(RecordError, match="junk.sqlite: not an hsio run record"):
        Run(junk)
    other = tmp_path / "other.sqlite"
    db = sqlite3.connect(other)
    db.execute("CREATE TABLE x (a)")
    db.commit()
    db.close()
    with pytest.raises(RecordError, match="other.sqlite: not an hsio run record"):
        Run(other)


GROUND = GroundMotion("g", 0.01, np.sin(np.arange(101) * 0.1))


@pytest.mark.parametrize("build, match", [
    (lambda: synthetic_record(seed="abc"), r"seed must be a whole number from 0, got 'abc'"),
    (lambda: synthetic_record(seed=1.5), r"seed must be a whole number from 0, got 1.5"),
    (lambda: synthetic_record(seed=-1), r"seed must be a whole number from 0, got -1"),
    (lambda: synthetic_record(f_g_hz=0), r"f_g_hz = 0.0 Hz must be positive"),
    (lambda: synthetic_record(dt=0.01, f_g_hz=60.0), r"f_g_hz = 60.0 Hz .* Nyquist .* 50 Hz"),
    (lambda: synthetic_record(pga_g="0.3"), r"pga_g must be a finite number, got '0.3'"),
    (lambda: synthetic_record(pga_g=-0.3), r"pga_g must be positive, got -0.3"),
    (lambda: synthetic_record(zeta_g="0.6"), r"zeta_g must be a finite number, got '0.6'"),
    (lambda: synthetic_record(zeta_g=-0.5), r"zeta_g must be positive .*got -0.5"),
    (lambda: synthetic_record(duration_s="1"), r"duration_s must be a finite number, got '1'"),
    (lambda: GROUND.truncated(None), r"g: cut duration_s must be a finite number, got None"),
    (lambda: GROUND.truncated("0.02"), r"g: cut duration_s must be a finite number, got '0.02'"),
    (lambda: GROUND.resampled(None), r"g: time step dt must be a finite number, got None"),
    (lambda: GROUND.resampled("x"), r"g: time step dt must be a finite number, got 'x'"),
    (lambda: GROUND.resampled(np.array([0.01])), r"g: time step dt must be a finite number"),
    (lambda: GroundMotion("g", np.array([0.01, 0.02]), np.zeros(3)), r"g: time step must be positive"),
    (lambda: GroundMotion("g", 0.01, np.array([1 + 1j, 0, 0])), r"g: the accelerations must be real"),
    (lambda: read_at2(None), r"read_at2: path must be a file path, got None"),
    (lambda: read_at2(3), r"read_at2: path must be a file path, got 3"),
])
def test_ground_motion_arguments_are_checked(build, match):
    with pytest.raises(RecordError, match=match):
        build()


def test_numpy_numbers_are_taken_as_numbers():
    assert GroundMotion("g", np.float64(0.01), [0.0, 1.0]).resampled(np.float64(0.005)).accel_g.size == 3
    assert synthetic_record(duration_s=1.0, dt=0.01, seed=np.int64(3)).pga_g == pytest.approx(0.3)


def test_make_method_checks_recipe_ns_and_its_structure():
    from hsio.api import run_numerical
    from hsio.structures import get_structure
    from hsio.study_mixed import Recipe, infill_sdof, make_method

    structure = infill_sdof(7.2)
    with pytest.raises(ConfigError, match=r"Recipe: max_hysteretic_ratio must be a number in \[0, 100\], got -1"):
        Recipe(max_hysteretic_ratio=-1)
    with pytest.raises(ConfigError, match=r"Recipe: hysteresis must be a number in \[1.0001, 100\], got 1.0"):
        Recipe(hysteresis=1.0)
    with pytest.raises(ConfigError, match=r"Recipe: margin must be a number in \[0.01, 1000\], got 2000"):
        Recipe(margin=2000.0)  # the bounds of [integrator] switch_margin (hsio.config.BOUNDS)
    with pytest.raises(ConfigError, match=r"ns must be the Result .*got str 'x'"):
        make_method(structure, "mixed", 0.0025, 0.002, ns="x")
    with pytest.raises(ConfigError, match=r"recipe must be a Recipe .*\{'margin': 5.0\}"):
        make_method(structure, "mixed", 0.0025, 0.002, recipe={"margin": 5.0})
    other = get_structure("validation")
    ns = run_numerical(other, synthetic_record(duration_s=0.2, dt=other.dt, seed=1))
    with pytest.raises(ConfigError, match=r"ns is the NS of structure 'validation' \(DOFs \['C1', 'C2'\]"):
        make_method(structure, "mixed", 0.0025, 0.002, ns=ns)
    # same DOFs, channels and dt, another infill: its NS predicts nothing about this one's cracking
    bare, infill = get_structure("structure_II"), get_structure("structure_II_infill")
    ns_bare = run_numerical(bare, synthetic_record(duration_s=0.1, dt=bare.dt, seed=1))
    with pytest.raises(ConfigError, match=r"ns is the NS of structure 'structure_II' .*not of structure 'structure_II_infill'"):
        make_method(infill, "mixed", 0.025, 0.01, ns=ns_bare)


@pytest.mark.parametrize("method", ["implicit_dc", "force_control", "mixed"])
@pytest.mark.parametrize("argument, value", [("force_resolution_kN", float("nan")), ("resolution_mm", -0.1),
                                             ("noise_mm", "0.01"), ("force_noise_kN", True)])
def test_make_method_refuses_instruments_that_are_not_readings(method, argument, value):
    """An instrument value that is not a number zero or positive is refused naming it with every
    method: a NaN force resolution would otherwise leave force control taking every estimate of
    eq. (11) as if the instruments were unknown."""
    from hsio.study_mixed import infill_sdof, make_method

    given = {"resolution_mm": 0.025, "force_resolution_kN": 0.01, argument: value}
    with pytest.raises(ConfigError, match=f"{argument} must be a number, zero or positive"):
        make_method(infill_sdof(7.2), method, **given)


def test_fc_vs_dc_refuses_no_theta():
    from hsio.study import fc_vs_dc

    with pytest.raises(ConfigError, match="theta_values must be a non-empty list"):
        fc_vs_dc(theta_values=[])
