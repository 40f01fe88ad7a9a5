"""The dry run before the hydraulics (docs/safety.md section 2)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hsio import api, config, ledger, runner
from hsio.command import PredictorCorrector
from hsio.recording import Run
from hsio.safety.dry_run import check, known_limits, peak_command_velocity, predict
from hsio.safety.settings import SafetySettings
from hsio.safety.status import DryRunRefused

ROOT = Path(__file__).resolve().parents[1]


def el_centro_x35(shared_data: Path, tmp_path: Path) -> Path:
    cfg = tmp_path / "elcentro.toml"
    cfg.write_text(f'[structure]\nname = "structure_I"\n[record]\nfile = "{shared_data / "ground_motions" / "I-ELC180.AT2"}"\n'
                   f"scale = 3.5\n[output]\nplots = false\n")
    return cfg


def test_hsio_check_refuses_el_centro_x35_on_structure_I(shared_data, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "check", str(el_centro_x35(shared_data, tmp_path))],
                          capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "dry run: REFUSED, nothing moved" in proc.stdout
    assert "wall displacement predicted   165.3" in proc.stdout and "limit +/-127 mm" in proc.stdout
    assert "--override-dry-run" in proc.stdout


def test_hsio_run_refuses_before_any_hardware_opens(shared_data, tmp_path, monkeypatch):
    def no_hardware(*args, **kwargs):
        raise AssertionError("the hardware was opened")

    monkeypatch.setattr(api, "open_hardware", no_hardware)
    cfg = config.load(el_centro_x35(shared_data, tmp_path))
    with pytest.raises(DryRunRefused, match="165.3"):
        runner.run(cfg, tmp_path / "o")
    run = Run(tmp_path / "o" / "run.sqlite")
    assert run.summary["exit_status"] == 2 and run.summary["steps"] == 0
    assert run.meta["dry_run"]["refused"] and [e["kind"] for e in run.events()] == ["dry_run", "stop"]


def test_the_peak_velocity_is_that_of_the_command_generator():
    rng = np.random.default_rng(3)
    targets = np.cumsum(rng.normal(0.0, 0.5, 120))
    for hold_fraction in (0.0, 0.5):
        g = PredictorCorrector(0.05, 1 / 1024, 0.0, hold_fraction=hold_fraction)
        peak = 0.0
        for t in targets:
            g.new_target(t)
            for _ in range(1000):
                before = g.command
                peak = max(peak, abs(g.next_sample() - before))
                if g.reached:
                    break
        assert peak_command_velocity(targets, 0.05, 1 / 1024, hold_fraction) == pytest.approx(peak * 1024, rel=1e-12)


def test_velocity_beyond_the_margin_is_refused():
    cfg = config.from_dict({"record": {"duration_s": 2.0}, "test": {"rate": 1.0},
                            "emulator": {"velocity_limit_mm_s": 100.0}})
    s = runner.load_run_structure(cfg)
    _, report = runner.predict(cfg, s, runner.build_record(cfg, s))
    assert report.refused and any("velocity" in e for e in report.exceeded)


def test_unknown_limits_are_named_not_guessed():
    limits, source = known_limits("modbus+tcp://127.0.0.1:5020", {}, {"stroke_mm": 200.0})
    assert limits == {"stroke_mm": 200.0, "force_kN": None, "velocity_mm_s": 500.0} and source == "[driver]"
    cfg = config.from_dict({"record": {"duration_s": 1.0}})
    s = runner.load_run_structure(cfg)
    ns = api.run_numerical(s, runner.build_record(cfg, s))
    report = check(predict(ns, 0.2, 0.5), limits, source, SafetySettings())
    text = report.text()
    assert "not checked: force" in text and "velocity (no" not in text
    assert not report.refused


def test_margins_are_fractions_of_the_limit():
    limits, source = known_limits("emulator://", {"stroke_mm": 50.0}, {})
    cfg = config.from_dict({"record": {"duration_s": 4.0}})
    s = runner.load_run_structure(cfg)
    ns = api.run_numerical(s, runner.build_record(cfg, s))
    p = predict(ns, 0.2, 0.5)
    peak = float(p.displacement.max())
    assert peak < 25.0
    margin_ok = 1.0 - peak / 25.0 - 0.01
    assert not check(p, limits, source, SafetySettings(stroke_margin=margin_ok)).refused
    assert check(p, limits, source, SafetySettings(stroke_margin=margin_ok + 0.02)).refused


def present_run(tmp_path: Path, monkeypatch, standing_mm, override: bool = False):
    """A short validation run with ``start = "present"`` on emulated actuators said to stand at
    ``standing_mm`` (the state read when the hardware opens)."""
    real_state = runner._state
    calls = []

    def standing(site):
        state = real_state(site)
        if not calls and state:
            at = standing_mm if isinstance(standing_mm, dict) else dict.fromkeys(state, standing_mm)
            state = {name: {"displacement_mm": at[name], "force_kN": 0.0} for name in state}
        calls.append(state)
        return state

    monkeypatch.setattr(runner, "_state", standing)
    cfg = config.from_dict({"record": {"synthetic_duration_s": 1.0, "pga_g": 0.6},
                            "test": {"start": "present"}, "output": {"plots": False, "samples": False},
                            "safety": {"override": override}})
    return runner.run(cfg, tmp_path / "o")


def test_present_start_is_checked_from_where_the_actuators_stand(tmp_path, monkeypatch):
    """NS from rest fits the +/-127 mm stroke; standing at 120 mm it does not: refused after the
    present state is read and before the first command."""
    import hsio

    s = hsio.load_structure("validation")
    ns = hsio.run_numerical(s, hsio.synthetic_record(duration_s=1.0, dt=s.dt, pga_g=0.6))
    peak = float(np.max(np.abs(ns.targets)))
    assert 1.0 < peak < 0.95 * 127 < peak + 120.0  # from rest it passes; from 120 mm it cannot
    with pytest.raises(DryRunRefused, match="from the present state") as info:
        present_run(tmp_path, monkeypatch, 120.0)
    assert "EXCEEDS" in str(info.value)
    run = Run(tmp_path / "o" / "run.sqlite")
    assert run.summary["exit_status"] == 2 and run.summary["steps"] == 0
    assert not run.meta["dry_run"]["refused"] and run.meta["dry_run_present"]["refused"]
    assert min(run.meta["dry_run_present"]["peak_displacement_mm"]) >= 120.0  # NS from where it stands


def test_present_offset_of_one_dof_shakes_the_other(tmp_path, monkeypatch):
    """NS from the present state, not a shift per actuator: C1 displaced alone starts a free
    vibration that the stiff coupling spring carries to C2, standing at zero (a shift by C2's own
    offset, 0, would miss it)."""
    with pytest.raises(DryRunRefused):
        present_run(tmp_path, monkeypatch, {"C1": 118.0, "C2": 0.0})
    run = Run(tmp_path / "o" / "run.sqlite")
    rest, present = run.meta["dry_run"]["peak_displacement_mm"], run.meta["dry_run_present"]["peak_displacement_mm"]
    assert present[1] > rest[1] + 20.0, (rest, present)


def test_present_start_within_the_limits_runs(tmp_path, monkeypatch):
    summary = present_run(tmp_path, monkeypatch, 0.0)
    assert summary["exit_status"] == 0 and summary["steps"] > 0
    run = Run(tmp_path / "o" / "run.sqlite")
    assert not run.meta["dry_run_present"]["refused"]


def test_hsio_run_tells_a_refusal_once(tmp_path):
    from click.testing import CliRunner

    from hsio.cli import main

    cfg = tmp_path / "run.toml"
    cfg.write_text('[record]\nduration_s = 2.0\n[test]\nrate = 1.0\n[emulator]\nvelocity_limit_mm_s = 100.0\n'
                   '[output]\nplots = false\n[safety]\nkeys = false\n')
    result = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2, result.output
    assert result.output.count("dry run: REFUSED") == 1, result.output


def test_hsio_check_refuses_a_compensation_that_hsio_run_would_refuse(tmp_path):
    from click.testing import CliRunner

    from hsio.cli import main

    cfg = tmp_path / "eq2.toml"
    cfg.write_text('[structure]\nname = "structure_I"\n[record]\nduration_s = 1.0\n[test]\nrate = 6.25\n'
                   'hold_fraction = 0.0\nn_avg = 1\n[compensation]\nmode = "offline"\na_mm_s = 5.18\n'
                   'b_s_mm = 7.874e-5\nform = "eq2"\n')
    result = CliRunner().invoke(main, ["check", str(cfg)])
    assert result.exit_code == 2, result.output
    assert "[compensation] form = 'eq2' is unstable here" in result.output


def test_a_present_start_checks_the_limits_the_controller_reports(tmp_path):
    """Over a driver without [driver] stroke_mm the dry run from rest cannot check the stroke; once
    the hardware is open the controller has reported it, and the check from the present state
    uses it: a test beyond it is refused before the first command."""
    from hsio.commands.emulate import bank_from_config
    from hsio.drivers import modbus_map
    from hsio.emulators.modbus import ModbusEmulator

    emu_cfg = tmp_path / "emu.toml"
    emu_cfg.write_text("[emulator]\nstroke_mm = 25.0\n")  # +/-12.5 mm; NS predicts about 14.7 mm
    emulator = ModbusEmulator(bank_from_config(emu_cfg, lockstep=True), modbus_map.load()).start()
    try:
        cfg = config.from_dict({"record": {"synthetic_duration_s": 1.0, "pga_g": 0.6}, "test": {"start": "present"},
                                "hardware": {"url": emulator.url, "clock": "lockstep"},
                                "output": {"plots": False, "samples": False},
                                "specimen": {"folder": str(tmp_path / "spec")}})
        with pytest.raises(DryRunRefused, match="stroke_mm, force_kN as the controller reports them") as info:
            runner.run(cfg, tmp_path / "o")
    finally:
        emulator.stop()
    assert "limit +/-12.5 mm" in str(info.value) and "EXCEEDS" in str(info.value)
    run = Run(tmp_path / "o" / "run.sqlite")
    assert run.summary["exit_status"] == 2 and run.summary["steps"] == 0
    assert run.meta["dry_run"]["unchecked"] and not run.meta["dry_run_present"]["unchecked"]
    (row,) = ledger.read(tmp_path / "spec")
    assert row["outcome"] == "refused" and row["dry_run"]["present"]["refused"]  # the check that refused
    assert not row["dry_run"]["refused"]  # from rest it was not


def test_the_dry_run_checks_the_limits_a_driver_will_use():
    """The URL's query wins over [driver] in the driver, and so in the dry run; the velocity
    limit is the driver's own default where neither sets it (not the controller's)."""
    limits, _ = known_limits("modbus+tcp://127.0.0.1:5020?stroke_mm=100&velocity_mm_s=50", {}, {"stroke_mm": 200.0})
    assert limits == {"stroke_mm": 100.0, "force_kN": None, "velocity_mm_s": 50.0}
    limits, _ = known_limits("canopen+slcan://127.0.0.1:5020", {}, {})
    assert limits == {"stroke_mm": None, "force_kN": None, "velocity_mm_s": 500.0}


def test_a_stop_during_the_prediction_from_the_present_state_ends_it_at_once(tmp_path, monkeypatch):
    """The hardware is open while NS runs from the present state (a long record takes a while):
    a stop asked then ends that NS at its next step, holds and closes, before any command."""
    from hsio.safety.control import RunControl
    from hsio.safety.status import OperatorStop
    from hsio.sites.numerical import StandingSite

    control = RunControl()
    real_ns, steps = runner.ns_from_present, []
    real_trial = StandingSite.set_trial

    def counted(self, commands, modes):
        steps.append(1)
        return real_trial(self, commands, modes)

    def stop_first(*args, **kwargs):
        control.request_stop("stopped by SIGTERM during start-up")
        return real_ns(*args, **kwargs)

    monkeypatch.setattr(StandingSite, "set_trial", counted)
    monkeypatch.setattr(runner, "ns_from_present", stop_first)
    cfg = config.from_dict({"record": {"synthetic_duration_s": 2.0}, "test": {"start": "present"},
                            "output": {"plots": False, "samples": False}})
    with pytest.raises(OperatorStop, match="stopped by SIGTERM during start-up"):
        runner.run(cfg, tmp_path / "o", control=control)
    assert len(steps) <= 1  # not the 200 steps of the record
    run = Run(tmp_path / "o" / "run.sqlite")
    assert run.summary["exit_status"] == 5 and run.summary["steps"] == 0
    assert "the actuators hold (confirmed by read-back)" in run.summary["stopped"]


def test_hsio_run_tells_the_hold_of_a_refusal_from_the_present_state(tmp_path, monkeypatch):
    """Refused from the present state, the hardware is open and the axes hold: the operator is
    told so, as the record has it."""
    from click.testing import CliRunner

    from hsio.cli import main

    real_state = runner._state
    monkeypatch.setattr(runner, "_state", lambda site: {name: {"displacement_mm": 120.0, "force_kN": 0.0}
                                                         for name in (real_state(site) or {})})
    cfg = tmp_path / "run.toml"
    cfg.write_text('[record]\nsynthetic_duration_s = 1.0\npga_g = 0.6\n[test]\nstart = "present"\n'
                   '[output]\nplots = false\n[safety]\nkeys = false\n')
    result = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2, result.output
    assert "from the present state" in result.output
    assert "EXCEEDS" in result.output and "the actuators hold (confirmed by read-back)" in result.output


def test_a_prediction_from_the_present_state_that_fails_is_bad_input_named_so(tmp_path, monkeypatch):
    """NS from where the specimen stands that cannot go on (a model that overflows) is bad input
    (exit 2) named as that prediction, as the prediction from rest is; the axes hold, no command."""
    from hsio.sites.numerical import StandingSite

    real_trial, calls = StandingSite.set_trial, []

    def overflows(self, commands, modes):
        calls.append(1)
        if len(calls) > 3:
            raise OverflowError("math range error")
        return real_trial(self, commands, modes)

    monkeypatch.setattr(StandingSite, "set_trial", overflows)
    cfg = config.from_dict({"record": {"synthetic_duration_s": 1.0}, "test": {"start": "present"},
                            "output": {"plots": False, "samples": False}, "safety": {"keys": False}})
    with pytest.raises(Exception) as info:
        runner.run(cfg, tmp_path / "o")
    assert "the prediction from the present state" in str(info.value) and "OverflowError" in str(info.value)
    run = Run(tmp_path / "o" / "run.sqlite")
    assert run.summary["exit_status"] == 2 and run.summary["steps"] == 0
    assert "the actuators hold (confirmed by read-back)" in run.summary["stopped"]
