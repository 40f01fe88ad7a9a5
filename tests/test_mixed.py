"""Mixed DC/FC with switching on emulated hardware: test structure I (pinched wood wall)."""

import sqlite3

import numpy as np
import pytest

from hsio.api import run_numerical, simulate
from hsio.clock import LockstepClock
from hsio.config import from_dict
from hsio.control_loop import ControlLoop
from hsio.emulators.local import open_url
from hsio.errors import ConfigError
from hsio.ground_motion import synthetic_record
from hsio.integrators import SwitchingRule
from hsio.interfaces import ControlMode
from hsio.recording import Recorder, Run
from hsio.result import max_error_pct, mode_switches
from hsio.secant import SecantEstimator
from hsio.sites import ActuatorSite
from hsio.structures import sdof, structure_I

K_F, K_D = 3.12, 2.08  # 1.2 and 0.8 K^EI: unloading 3.9 kN/mm, loading <= 2.6 kN/mm


@pytest.fixture(scope="module")
def mixed_run(tmp_path_factory):
    structure = structure_I()
    ground = synthetic_record(duration_s=4.0, dt=structure.dt, pga_g=0.6, seed=1994)
    ns = run_numerical(structure, ground, "mixed", -0.05)
    clock = LockstepClock()
    actuators = open_url("emulator://", structure.experimental, clock, {})
    loop = ControlLoop(actuators, clock, structure.dt, 10.0, n_avg=4, keep_samples=True, hold_fraction=0.5)
    elements = ActuatorSite(loop, SecantEstimator("average", n_avg=16, min_increment=0.1))
    path = tmp_path_factory.mktemp("mixed") / "run.sqlite"
    recorder = Recorder(path, structure.dof_names, [a.name for a in actuators])
    rule = SwitchingRule([K_F], [K_D])
    try:
        hs = simulate(structure, ground, elements, "mixed", -0.05, recorder, rule=rule, j_max=3,
                      tol_displacement=0.02, tol_force=0.05)
    finally:
        elements.close()
        recorder.close()
    return structure, hs, ns, path


def test_mixed_matches_ns_within_3_percent(mixed_run):
    _, hs, ns, _ = mixed_run
    assert hs.steps == ns.steps == 800
    assert np.max(np.abs(ns.u)) > 30.0  # well into the pinched range
    worst, _ = max_error_pct(hs.u, ns.u)
    assert worst < 3.0


def test_switches_to_fc_on_stiff_unloading_and_back(mixed_run):
    _, hs, ns, _ = mixed_run
    to_fc = [s for s in hs.switches if s.to == "force"]
    to_dc = [s for s in hs.switches if s.to == "displacement"]
    assert len(to_fc) >= 5 and len(to_dc) >= 5
    assert all(s.secant_kN_mm > K_F for s in to_fc)
    assert all(s.secant_kN_mm < K_D for s in to_dc)
    fc = hs.modes[1:, 0] == "force"
    assert 0.1 < fc.mean() < 0.9
    # the FC steps are where the wall is stiff: the numerical model's secant there is the unloading one
    k_ns = ns.secant[1:, 0]
    assert np.mean(k_ns[fc] > K_D) > 0.85
    assert np.mean(k_ns[~fc] < K_F) > 0.5


def test_modes_and_switches_are_recorded(mixed_run):
    structure, hs, _, path = mixed_run
    run = Run(path)
    modes = run.dof("mode", "wall")
    assert set(modes) == {"force", "displacement"}
    assert mode_switches(modes[:, None]) == mode_switches(hs.modes[1:, :1])
    with sqlite3.connect(path) as db:
        its = np.array(db.execute("SELECT iterations_wall FROM implicit ORDER BY step").fetchall(), dtype=float)[:, 0]
    assert len(its) == 800 and its.min() >= 1 and its.max() <= 3


def test_no_command_jump_at_a_switch(mixed_run):
    """After a switch the command starts from the present measurement of the new quantity (a fresh
    generator ramps from there): the first command sample of the next step is within a few
    hundredths (kN or mm) of the last measurement."""
    structure, hs, _, path = mixed_run
    samples = Run(path).samples()
    checked = 0
    for s in hs.switches:
        if s.within_step:
            continue
        k = s.step
        quantity = "force_wall" if s.to == "force" else "disp_wall"
        last_measured = samples[quantity][samples["step"] == k][-1]
        first_command = samples["cmd_wall"][samples["step"] == k + 1][0]
        assert abs(first_command - last_measured) < 0.05, (s, last_measured, first_command)
        checked += 1
    assert checked >= 5


def test_control_loop_switch_is_bumpless():
    structure = sdof(m=0.011, k=2.6, dt=0.005)
    clock = LockstepClock()
    actuators = open_url("emulator://", structure.experimental, clock, {})
    loop = ControlLoop(actuators, clock, structure.dt, 10.0, n_avg=4, keep_samples=True, hold_fraction=0.5)
    for _ in range(6):
        loop.execute(np.array([5.0]))
    before = actuators[0].feedback()
    loop.set_mode(0, ControlMode.FORCE)
    assert actuators[0].mode is ControlMode.FORCE
    assert loop.generators[0].command == pytest.approx(before.force_kN, abs=0.01)
    fb = loop.execute(np.array([before.force_kN]))  # hold the same force
    disp = fb.samples[:, 0, 1]
    assert np.max(np.abs(disp - before.displacement_mm)) < 0.1  # no jolt
    for _ in range(3):  # 1 mm more, in force control (the force loop lags 20 ms)
        fb = loop.execute(np.array([before.force_kN + 2.6]))
    assert fb.displacement[0] == pytest.approx(before.displacement_mm + 1.0, abs=0.1)
    here = actuators[0].feedback()
    loop.set_mode(0, ControlMode.DISPLACEMENT)
    fb = loop.execute(np.array([here.displacement_mm]))
    assert np.max(np.abs(fb.samples[:, 0, 1] - here.displacement_mm)) < 0.1
    loop.close()


def test_run_config_for_mixed(tmp_path):
    cfg = from_dict({"structure": {"name": "structure_I"}, "record": {"synthetic_duration_s": 1.0},
                     "integrator": {"method": "mixed", "K_f": 3.0, "K_d": 2.0}, "test": {"rate": 5.0},
                     "output": {"plots": True}})
    from hsio import runner

    summary = runner.run(cfg, tmp_path)
    assert summary["method"] == "mixed"
    assert summary["thresholds"]["upper"] == [3.0] and summary["thresholds"]["lower"] == [2.0]
    assert "iterations_per_step_mean" in summary and summary["max_error_pct"] < 3.0
    assert (tmp_path / "modes.png").stat().st_size > 10_000
    with pytest.raises(ConfigError, match="method"):
        from_dict({"integrator": {"method": "explicit"}})
    with pytest.raises(ConfigError, match="K_d"):
        from_dict({"integrator": {"method": "mixed", "K_f": 2.0, "K_d": 3.0}})
    with pytest.raises(ConfigError, match="secant"):
        from_dict({"integrator": {"secant": "median"}})
