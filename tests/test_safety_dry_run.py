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
    assert "wall displacement predicted   166.7" in proc.stdout and "limit +/-127 mm" in proc.stdout
    assert "NS peak 165.334 mm + lag allowance 0.02 s x 68.630 mm/s" in proc.stdout  # the emulated lag
    assert "EXCEEDS at step 599 (t = 2.995 s)" in proc.stdout
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


def test_a_lagging_actuators_command_velocity_is_predicted_with_the_growth_of_its_response(tmp_path):
    """A lag not compensated grows the hybrid response beyond NS, and the commands' velocity with
    it: here (TR 2, ramp-hold 0.3, 20 ms lag) by 11 %, beyond the 5 % margin, so a test let through
    on NS's command velocity alone would be stopped at the velocity limit in the middle of its
    record. The velocity checked grows as the displacement does; the run (overridden, to measure
    the commands) stays within that prediction, above the prediction from NS alone."""
    cfg = tmp_path / "run.toml"
    cfg.write_text('[record]\nsynthetic_duration_s = 4.0\npga_g = 0.6\n[test]\nrate = 2.0\nhold_fraction = 0.3\n'
                   '[emulator]\nlag_s = 0.02\n[output]\nplots = false\n[safety]\noverride = true\nkeys = false\n'
                   'control_socket = false\n')
    summary = runner.run(config.load(cfg), tmp_path / "o")
    assert summary["exit_status"] == 0
    run = Run(tmp_path / "o" / "run.sqlite")
    report = run.meta["dry_run"]
    samples = run.samples()
    for k, name in enumerate(("C1", "C2")):
        measured = float(np.max(np.abs(np.diff(samples[f"cmd_{name}"])))) * 1024.0  # mm/s, the controller's rate
        from_ns = report["peak_command_velocity_mm_s"][k]
        predicted = from_ns * report.get("lag_velocity_factor", [1.0, 1.0])[k]
        assert from_ns < measured <= predicted, (from_ns, measured, predicted)
    assert any("velocity" in line for line in report["exceeded"]), report["exceeded"]  # 507 mm/s > 475 allowed


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


# -- each actuator against its own limits, from the present state ----------------------------------

class _Recorder:
    def __init__(self):
        self.meta, self.events = {}, []

    def write_event(self, *args, **kwargs):
        self.events.append(args)

    def write_meta(self, items):
        self.meta.update(items)


def check_from_present(strokes: dict, standing: dict) -> tuple[_Recorder, list[str]]:
    """The check from the present state of a 1 s validation run over a driver that sets no stroke
    (so each actuator's comes from its controller once open), the actuators with ``strokes`` and
    standing at ``standing`` (mm)."""
    from types import SimpleNamespace

    from hsio.interfaces import Limits

    cfg = config.from_dict({"record": {"synthetic_duration_s": 1.0, "pga_g": 0.6}, "test": {"start": "present"},
                            "hardware": {"url": "modbus+tcp://127.0.0.1:5020"},
                            "output": {"plots": False, "samples": False}})
    s = runner.load_run_structure(cfg)
    ground = runner.build_record(cfg, s)
    _, report = runner.predict(cfg, s, ground)
    assert report.limits["stroke_mm"] is None  # from rest the stroke is not known
    state = {name: {"displacement_mm": d, "force_kN": 0.0} for name, d in standing.items()}
    site = SimpleNamespace(loop=SimpleNamespace(actuators=[SimpleNamespace(name=name, limits=Limits(stroke, 250.0))
                                                           for name, stroke in strokes.items()]))
    recorder, told = _Recorder(), []
    runner._dry_run_from_present(cfg, s, runner.ns_from_present(cfg, s, ground, state), report, site, state,
                                 SafetySettings(), recorder, told.append, None, None)
    return recorder, told


def test_from_the_present_state_each_actuator_is_checked_against_its_own_stroke():
    """C2 standing at 5 mm drives NS to about 12.3 mm on C1 and 13.2 mm on C2. C1's stroke is
    +/-13.5 mm (allowed 12.825 mm at 5 %), C2's +/-50 mm: each within its own. The smaller stroke
    applied to both would refuse C2 (13.2 > 12.825), a run that fits."""
    recorder, told = check_from_present({"C1": 27.0, "C2": 100.0}, {"C1": 0.0, "C2": 5.0})
    present = recorder.meta["dry_run_present"]
    assert not present["refused"], told
    d1, d2 = present["peak_displacement_mm"]
    assert d1 < 12.825 < d2 < 47.5  # the case the smallest stroke would refuse
    assert present["limits_per_actuator"]["C1"]["stroke_mm"] == 27.0
    assert present["limits_per_actuator"]["C2"]["stroke_mm"] == 100.0
    assert "C1 displacement predicted    12.289 mm   limit +/-13.5 mm" in told[0]
    assert "C2 displacement predicted    13.220 mm   limit +/-50 mm" in told[0]
    assert "lag: a driver does not report its actuators' lag" in told[0]


def test_from_the_present_state_a_refusal_names_the_actuator_its_limit_the_prediction_and_the_step():
    with pytest.raises(DryRunRefused) as info:
        check_from_present({"C1": 25.0, "C2": 100.0}, {"C1": 0.0, "C2": 5.0})
    text = str(info.value)
    assert "C1 displacement predicted    12.289 mm   limit +/-12.5 mm, margin 5%: allowed 11.875 mm  EXCEEDS " \
           "at step 17 (t = 0.170 s)" in text, text
    assert "C2 displacement predicted    13.220 mm   limit +/-50 mm, margin 5%: allowed 47.500 mm  ok" in text
    assert "stroke_mm, force_kN as the controller reports them, each actuator's own" in text


def test_actuators_are_found_by_name_else_by_place():
    """An element's actuator may be named apart from the element: then its place tells it."""
    from types import SimpleNamespace

    from hsio.interfaces import Limits
    from hsio.safety.dry_run import Prediction, actuator_limits

    p = Prediction(("wall", "B"), np.array([1.0, 1.0]), np.array([1.0, 1.0]), np.array([1.0, 1.0]), 10)
    opened = [SimpleNamespace(name="A1", limits=Limits(10.0, 20.0, 30.0)),
              SimpleNamespace(name="B", limits=Limits(40.0, 50.0, 60.0))]
    tables = actuator_limits(p, {"stroke_mm": None, "force_kN": None, "velocity_mm_s": 5.0}, opened)
    assert tables == [{"stroke_mm": 10.0, "force_kN": 20.0, "velocity_mm_s": 5.0},
                      {"stroke_mm": 40.0, "force_kN": 50.0, "velocity_mm_s": 5.0}]


# -- the actuator's lag and the compensation's lead ------------------------------------------------

def lagging(stroke_mm: float, compensation: bool) -> config.RunConfig:
    """4 s of validation in continuous motion (TR 6.25) on an emulated actuator lagging by 30 ms,
    noise free, margins 0 (the stroke itself is the allowance), compensated or not."""
    tables = {"record": {"synthetic_duration_s": 4.0, "pga_g": 0.6}, "test": {"rate": 6.25, "hold_fraction": 0.0},
              "emulator": {"lag_s": 0.03, "noise_mm": 0.0, "resolution_mm": 0.0, "force_noise_kN": 0.0,
                           "force_resolution_kN": 0.0, "stroke_mm": stroke_mm},
              "safety": {"stroke_margin": 0.0}, "output": {"plots": False, "samples": False}}
    if compensation:
        tables["compensation"] = {"mode": "offline", "b_s_mm": 0.03 / 254.0, "a_mm_s": 0.0}
    return config.from_dict(tables)


def peak_sent(cfg) -> tuple[float, str]:
    """The run on the emulator: its largest |command sent| and how it stopped ("" if it did not)."""
    from hsio.experiment import ExperimentStopped

    s = runner.load_run_structure(cfg)
    stage = runner.compensation_stage(cfg, s) if cfg["compensation"]["mode"] != "off" else None
    with api.open_site(s, "emulator://", test_rate=6.25, hold_fraction=0.0, options=cfg["emulator"],
                       compensation=stage) as site:
        try:
            hs, stopped = api.simulate(s, runner.build_record(cfg, s), site), ""
        except ExperimentStopped as exc:
            hs, stopped = exc.result, str(exc)
    return float(np.max(np.abs(hs.commands))), stopped


def test_the_compensated_commands_are_predicted_not_the_targets():
    """The lead form sends d^a = d^c + L (|v| - a) sign(v), beyond the NS targets. On a stroke of
    +/-20.64 mm NS's targets fit (20.59 mm) and the commands sent do not: the dry run refuses,
    and the run let through is stopped by the command limit."""
    cfg = lagging(41.28, compensation=True)
    s = runner.load_run_structure(cfg)
    ns, report = runner.predict(cfg, s, runner.build_record(cfg, s))
    assert float(np.max(np.abs(ns.targets))) < 20.64  # NS alone fits
    assert report.refused and report.exceeded[0].startswith("C1 displacement"), report.text()
    assert "commands compensated with lead 0.03 s" in report.text()
    sent, stopped = peak_sent(lagging(100.0, compensation=True))
    assert sent > 20.64 and sent == pytest.approx(report.prediction.displacement[0], rel=2e-3)
    _, stopped = peak_sent(cfg)
    assert "beyond the stroke" in stopped


def test_an_uncompensated_lag_is_allowed_for():
    """Not compensated, the 30 ms lag makes the hybrid response outgrow NS (about 3 % here): on a
    stroke of +/-21 mm NS fits (20.59 mm) and the run is stopped at the stroke; the allowance
    L |v|_max (0.03 s x 63.5 mm/s) refuses it first."""
    cfg = lagging(42.0, compensation=False)
    s = runner.load_run_structure(cfg)
    ns, report = runner.predict(cfg, s, runner.build_record(cfg, s))
    assert float(np.max(np.abs(ns.targets))) < 21.0
    assert report.refused, report.text()
    assert "lag allowance 0.03 s x 63.5" in report.text()
    sent, _ = peak_sent(lagging(100.0, compensation=False))
    assert 21.0 < sent <= report.prediction.displacement[0] + report.prediction.lag_allowance()[0]
    _, stopped = peak_sent(cfg)
    assert "beyond the stroke" in stopped


def test_the_lead_form_on_a_ramp():
    """A ramp at v beyond a: every command leads by L (v - a); below a, none."""
    from hsio.safety.dry_run import compensated

    t_d, v = 0.1, 50.0
    ramp = v * t_d * np.arange(10)
    np.testing.assert_allclose(compensated(ramp, t_d, 0.02, 5.0)[2:], ramp[2:] + 0.02 * (v - 5.0))
    np.testing.assert_allclose(compensated(ramp, t_d, 0.02, 60.0), ramp)


def test_the_online_lead_is_bounded_by_what_it_can_reach():
    from hsio.compensation.stage import CompensationSettings
    from hsio.safety.dry_run import actuator_lag

    online = CompensationSettings.from_table({"mode": "online", "actuators": ["C2"]})
    lag = actuator_lag("emulator://", {"lag_s": 0.02}, online, ["C1", "C2"], steps=25)
    np.testing.assert_allclose(lag.lead_s, [0.0, 0.015])  # 3 updates of 5 ms
    np.testing.assert_allclose(lag.lag_s, [0.02, 0.005])  # what the lead leaves
    lag = actuator_lag("emulator://", {"lag_s": 0.02}, online, ["C1", "C2"], steps=100000)
    np.testing.assert_allclose(lag.lead_s, [0.0, 0.1])  # lag_max_s
    lag = actuator_lag("modbus+tcp://127.0.0.1:5020", {}, None, ["C1", "C2"])
    np.testing.assert_allclose(lag.lag_s, [0.0, 0.0])  # a driver's lag is not known


def test_the_lag_allowance_is_at_most_the_peak():
    """A lag far longer than the motion (an actuator that does not follow, stopped by the tracking
    interlock) allows at most the peak itself, not L |v|_max (1000 s x 19 mm/s = 19 m)."""
    from hsio.safety.dry_run import ActuatorLag, Prediction

    zero = np.zeros(2)
    p = Prediction(["C1", "C2"], np.array([11.7, 4.0]), zero, zero, 100, dt=0.01, step_velocity=np.array([18.9, 0.1]),
                   lag=ActuatorLag(np.array([1000.0, 0.02]), zero, zero, "test"))
    np.testing.assert_allclose(p.lag_allowance(), [11.7, 0.002])


def test_each_actuator_s_own_compensation_is_predicted():
    """[compensation.by_actuator]: each actuator's own a and b give its lead (b d_max) and
    threshold; the lag left is its own less that lead."""
    from hsio.compensation.stage import CompensationSettings
    from hsio.safety.dry_run import actuator_lag

    settings = CompensationSettings.from_table({"mode": "offline", "by_actuator": {
        "C1": {"a_mm_s": 1.0, "b_s_mm": 0.02 / 254.0}, "C2": {"a_mm_s": 2.0, "b_s_mm": 0.01 / 254.0}}})
    lag = actuator_lag("emulator://", {"lag_s": 0.03}, settings, ["C1", "C2"], 100)
    np.testing.assert_allclose(lag.lead_s, [0.02, 0.01])
    np.testing.assert_allclose(lag.a_mm_s, [1.0, 2.0])
    np.testing.assert_allclose(lag.lag_s, [0.01, 0.02])
