"""Feed-forward compensation under mixed control: only the actuators in displacement control are
compensated (docs/compensation.md, docs/force_control.md; docs/method.md sections 4 and 5)."""

import numpy as np
import pytest

from hsio.api import open_site
from hsio.compensation.stage import CompensationSettings, CompensationStage
from hsio.interfaces import ControlMode
from hsio.structures import get_structure

DC, FC = ControlMode.DISPLACEMENT, ControlMode.FORCE
T_D = 0.05
LAG = 0.02


def _stage(mode="offline"):
    b = LAG / 254.0 if mode == "offline" else 0.0
    return CompensationStage(["BF", "IF"], T_D, CompensationSettings(mode=mode, a_mm_s=0.0, b_s_mm=b))


def test_force_controlled_actuator_gets_its_command_unchanged_and_the_other_is_compensated():
    stage = _stage()
    for k in range(3):  # both in DC: a ramp at 2 mm/s, led by L v = 0.04 mm
        d_a = stage.adjust([0.1 * k, 0.1 * k])
    assert d_a == pytest.approx([0.2 + LAG * 2.0, 0.2 + LAG * 2.0])
    d_a = stage.adjust([0.3, 55.0], [True, False])  # IF in force control: a force of 55 kN
    assert d_a[1] == 55.0
    assert d_a[0] == pytest.approx(0.3 + LAG * 2.0)
    row = stage.observe([0.3, 55.0], d_a, [0.3, 0.31], [True, False])
    assert row["er_ca_IF"] is None and row["dc_IF"] is None and row["er_ca_BF"] is not None


def test_history_restarts_after_force_control():
    """Back in DC, the velocity of eq. 2 is taken from displacement commands only, never from the
    force commands in between (a force of 55 kN read as a displacement would lead by metres)."""
    stage = _stage()
    for k in range(3):
        stage.adjust([0.0, 0.1 * k])
    stage.adjust([0.0, 55.0], [True, False])
    first = stage.adjust([0.0, 0.5])
    assert first[1] == 0.5  # one point: no velocity yet
    second = stage.adjust([0.0, 0.6])
    assert second[1] == pytest.approx(0.6 + LAG * 0.1 / T_D)


def test_online_estimator_takes_no_sample_in_force_control():
    stage = _stage("online")
    est = stage.estimators[1]
    for k in range(30):
        d_c = [0.1 * k, 10.0 * k]
        d_a = stage.adjust(d_c, [True, False])
        stage.observe(d_c, d_a, [0.1 * k - 0.004, 0.0], [True, False])
    assert len(est._v) == 0
    assert len(stage.estimators[0]._v) > 0


def test_summary_rms_error_is_over_the_steps_in_displacement_control():
    """The summary's RMS execution error of an actuator is taken over its steps in DC only: its
    steps in force control record no error and do not dilute it."""
    stage = _stage()
    for k in range(4):  # BF in DC, 0.2 mm short each step; IF in DC for two steps, then in FC
        dc = [True, k < 2]
        d_c = [0.1 * k, 0.3 if k < 2 else 40.0]
        d_a = stage.adjust(d_c, dc)
        stage.observe(d_c, d_a, [0.1 * k - 0.2, 0.3 - 0.1 * (k < 2)], dc)
        stage.commit()
    used = stage.summary()["actuators"]
    assert used["BF"]["rms_error_mm"] == pytest.approx(0.2)
    assert used["IF"]["rms_error_mm"] == pytest.approx(0.1)
    never = _stage()
    never.observe([0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [True, False])
    never.commit()
    assert never.summary()["actuators"]["IF"]["rms_error_mm"] is None


def test_an_iterated_step_is_one_row_of_its_last_command():
    """The implicit methods send several commands per step: the compensation table keeps one row
    per integration step, numbered as the steps, holding the step's last command (the one the
    steps table records), and the summary's RMS error is over those steps."""
    from hsio.api import simulate
    from hsio.ground_motion import synthetic_record
    from hsio.secant import SecantEstimator

    structure = get_structure("structure_I")
    ground = synthetic_record(duration_s=0.1, dt=structure.dt, pga_g=1.0, seed=3)
    stage = CompensationStage(["wall"], 6.25 * structure.dt,
                              CompensationSettings(mode="offline", a_mm_s=5.18, b_s_mm=7.874e-5))
    rows = []
    stage.sink = lambda step, row: rows.append((step, row))
    with open_site(structure, "emulator://?preset=structure_I", test_rate=6.25, hold_fraction=0.0, n_avg=1,
                   estimator=SecantEstimator("average", 1, 0.1), compensation=stage) as site:
        hs = simulate(structure, ground, site, method="implicit_dc", j_max=3, tol_displacement=0.0)
    assert hs.iterations[1:].sum() > 2 * hs.steps  # several commands per step
    assert [step for step, _ in rows] == list(range(1, hs.steps + 1))
    np.testing.assert_array_equal([row["da_wall"] for _, row in rows], hs.commands[1:, 0])
    error = np.array([row["dc_wall"] for _, row in rows]) - hs.measured_displacement[1:, 0]
    assert stage.summary()["actuators"]["wall"]["rms_error_mm"] == pytest.approx(np.sqrt(np.mean(error ** 2)), rel=1e-3)


def test_mixed_site_compensates_the_displacement_controlled_actuator():
    """On the emulator (20 ms lag), BF in DC ramping while IF holds a force in FC: with offline
    compensation BF lands on its command; without it BF trails by about the lag times the
    velocity (ramp-hold lets it settle part of the way)."""
    structure = get_structure("structure_II_infill")
    options = {"noise_mm": 0.0, "resolution_mm": 0.0, "force_noise_kN": 0.0, "force_resolution_kN": 0.0,
               "lag_s": LAG}
    errors = {}
    for mode in ("off", "offline"):
        stage = _stage(mode) if mode != "off" else None
        with open_site(structure, "emulator://", test_rate=10, hold_fraction=0.0, options=options,
                       compensation=stage) as site:
            v = 2.0  # mm/s of lab time
            for k in range(1, 20):
                site.set_trial([v * T_D * k, 5.0], [DC, FC])
            daq = site.get_daq()
            errors[mode] = abs(v * T_D * 19 - daq.u[0])
            assert daq.R[1] == pytest.approx(5.0, abs=0.5)
    assert errors["off"] == pytest.approx(LAG * v, rel=0.3)
    assert errors["offline"] < 0.1 * errors["off"]


def test_study_runs_mixed_with_online_compensation():
    """`study_mixed.run_case` with a [compensation] table: the uncracked infilled frame (0.6 s),
    mixed with online compensation stays as close to NS as without it, and far below DC's
    k delta_u error (the figures of docs/force_control.md, "With feed-forward compensation")."""
    from hsio import study_mixed
    from hsio.ground_motion import synthetic_record

    structure = get_structure("structure_II_infill")
    ground = synthetic_record(duration_s=0.6, dt=structure.dt, pga_g=0.15, seed=1994)
    rows = {(r.method, comp): r for comp in ("off", "online")
            for r in study_mixed.run_case("s", structure, ground, ("implicit_dc", "mixed"), 0.025, 0.01,
                                          compensation={"mode": comp})}
    for comp in ("off", "online"):
        assert rows[("mixed", comp)].fc_fraction > 0.5
        assert rows[("mixed", comp)].error_pct < 0.5 * rows[("implicit_dc", comp)].error_pct
    with pytest.raises(Exception, match="mode"):
        study_mixed.run_case("s", structure, ground, ("mixed",), 0.025, 0.01, compensation={"mode": "bogus"})


def test_hsio_run_compensates_implicit_and_mixed_runs(tmp_path):
    """`hsio run` with an implicit method takes [compensation] like alpha-OS: on structure I's
    hockey-stick actuator (continuous ramps, TR 6.25) the offline compensation of eq. 2 removes
    most of the execution error d^c - d^m of the uncompensated run in DC (measured: 0.30 -> 0.10 mm
    RMS) and in the DC steps of mixed away from a return from FC (0.24 -> 0.10 mm; the three steps
    after a return, where the command history restarts, are not compensated: 0.6 -> 1.1 mm)."""
    from hsio import config as config_mod
    from hsio import runner
    from hsio.recording import Run

    a, b = 5.18, 7.874e-5  # the emulator preset's hockey stick (docs/compensation.md)
    rms = {}
    for method in ("implicit_dc", "mixed"):
        for mode in ("off", "offline"):
            table = {"mode": mode} if mode == "off" else {"mode": mode, "a_mm_s": a, "b_s_mm": b}
            cfg = config_mod.from_dict({
                "structure": {"name": "structure_I"}, "record": {"pga_g": 1.0, "duration_s": 2.0},
                "integrator": {"method": method, **({"switch_rule": "initial_stiffness"} if method == "mixed" else {})},
                "test": {"rate": 6.25, "hold_fraction": 0.0, "n_avg": 1},
                "emulator": {"preset": "structure_I"}, "compensation": table,
                "output": {"plots": False, "samples": True, "ns": False}})
            out = tmp_path / f"{method}-{mode}"
            summary = runner.run(cfg, out)
            assert summary["exit_status"] == 0 and summary["compensation"]["mode"] == mode
            steps = Run(next(out.glob("*.sqlite"))).steps
            dc = np.asarray(steps["mode_wall"]) == "displacement"
            if method == "mixed":  # K^EI thresholds: the stiff unloading branches in FC, returns to DC
                assert 0.05 < 1.0 - dc.mean() < 0.95, dc.mean()
            settled = dc.copy()
            settled[0] = False
            for i in np.flatnonzero(dc[1:] & ~dc[:-1]) + 1:  # the first steps after a return from FC
                settled[i:i + 3] = False
            error = np.asarray(steps["target_wall"]) - np.asarray(steps["disp_wall"])
            rms[method, mode] = float(np.sqrt(np.mean(error[settled] ** 2)))
    assert rms["implicit_dc", "off"] > 0.2 and rms["mixed", "off"] > 0.2, rms
    for method in ("implicit_dc", "mixed"):
        assert rms[method, "offline"] < 0.5 * rms[method, "off"], rms
