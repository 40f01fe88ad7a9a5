"""Interlocks of the control loop (docs/safety.md section 3), each tripped on the in-process
emulator: the run stops with exit status 4, the actuators hold (read back), the record is closed
and readable with the trip in its events, and the message says what tripped."""

from __future__ import annotations

import math
import os
import time
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hsio import api
from hsio.emulators.servo import ServoController
from hsio.experiment import ExperimentStopped
from hsio.ground_motion import synthetic_record
from hsio.recording import Recorder, Run
from hsio.safety.settings import SafetySettings
from hsio.safety.status import INTERLOCK, InterlockTrip, exit_status
from hsio.structures import validation

ROOT = Path(__file__).resolve().parents[1]
FAULT_TICK = 800  # controller periods: about a third into the run below


def run_with_fault(tmp_path, emulator: dict | None = None, safety: dict | None = None, fault=None,
                   hook: str = "_measure"):
    """2 s of the validation structure at TR 10 on the in-process emulator, with ``fault(controller)``
    applied after every measurement (or before every controller period, ``hook="step"``) from
    FAULT_TICK on. Returns (result or ExperimentStopped, holding read back, Run)."""
    s = validation()
    g = synthetic_record(duration_s=2.0, dt=s.dt)
    site = api.open_site(s, "emulator://", test_rate=10.0, options=emulator or {},
                         safety=SafetySettings.from_table(safety or {}))
    if fault is not None:
        for actuator in site.loop.actuators:
            controller = actuator.controller
            original = getattr(controller, hook)

            def faulty(controller=controller, original=original):
                if hook == "step" and controller.ticks >= FAULT_TICK:
                    fault(controller)
                original()
                if hook != "step" and controller.ticks >= FAULT_TICK:
                    fault(controller)

            setattr(controller, hook, faulty)
    rec = Recorder(tmp_path / "run.sqlite", s.dof_names, [e.name for e in s.experimental])
    try:
        try:
            out = api.simulate(s, g, site, recorder=rec)
        except ExperimentStopped as exc:
            out = exc
        holding = [a.holding() for a in site.loop.actuators]
    finally:
        rec.close()
        site.close()
    return out, holding, Run(tmp_path / "run.sqlite")


def assert_tripped(out, holding, run, kind: str, words: str):
    assert isinstance(out, ExperimentStopped), out
    assert isinstance(out.cause, InterlockTrip) and out.cause.kind == kind
    assert exit_status(out) == INTERLOCK == 4
    assert words in str(out)
    assert "the actuators hold (confirmed by read-back)" in str(out)
    assert holding == [True, True]
    trips = [e for e in run.events() if e["kind"] == "trip"]
    assert len(trips) == 1 and trips[0]["actuator"] in ("C1", "C2") and words in trips[0]["message"]
    assert any(e["kind"] == "hold" and "confirmed" in e["message"] for e in run.events())
    assert len(run.steps["step"]) == out.result.steps > 5  # the steps made are kept


def test_default_interlocks_do_not_trip_a_normal_run(tmp_path):
    out, holding, run = run_with_fault(tmp_path)
    assert not isinstance(out, ExperimentStopped)
    assert not [e for e in run.events() if e["kind"] == "trip"]


def test_an_actuator_that_stops_following_trips(tmp_path):
    """A servo-valve that barely opens (a lag of 1000 s): the command runs away from the rod."""
    out, holding, run = run_with_fault(tmp_path, {"lag_s": 1000.0},
                                       {"following_error_mm": 2.0, "following_time_s": 0.1})
    assert_tripped(out, holding, run, "following", "does not follow its command")


def test_a_dead_transducer_trips(tmp_path):
    """The specimen's displacement transducer freezes while the actuator moves on."""
    frozen = {}

    def stuck(c):
        c.measured_displacement = frozen.setdefault(id(c), c.measured_displacement)

    out, holding, run = run_with_fault(tmp_path, {}, {"following_error_mm": 1.0, "following_time_s": 0.1}, stuck)
    assert_tripped(out, holding, run, "following", "does not follow its command")


def test_a_second_client_commanding_the_controller_trips(tmp_path):
    """Another program writes its own command (here: hold at zero) every period."""
    def intruder(c):
        c.command = 0.0

    out, holding, run = run_with_fault(tmp_path, {}, {"following_error_mm": 1.0, "following_time_s": 0.1}, intruder,
                                       hook="step")
    assert_tripped(out, holding, run, "following", "does not follow its command")


def test_a_measurement_that_is_not_a_number_trips(tmp_path):
    def nan(c):
        c.measured_force = math.nan

    out, holding, run = run_with_fault(tmp_path, fault=nan)
    assert_tripped(out, holding, run, "not_finite", "not a finite number")
    assert out.result.steps <= FAULT_TICK // 103 + 1  # at the first bad period, not later


def test_an_implausible_jump_trips(tmp_path):
    def jump(c):
        c.measured_displacement += 25.0  # an electrical spike, or a transducer that slipped

    out, holding, run = run_with_fault(tmp_path, fault=jump)
    assert_tripped(out, holding, run, "jump", "jumped by")


def test_force_drop_of_a_failing_specimen_trips(tmp_path):
    """The force envelope falls below half of its peak: the specimen failed."""
    def failing(c):
        c.measured_force *= 0.2

    out, holding, run = run_with_fault(tmp_path, fault=failing,
                                       safety={"force_drop_fraction": 0.5, "force_drop_window_s": 0.3,
                                               "jump_kN": 1000.0})
    assert_tripped(out, holding, run, "force_drop", "the specimen failed")


def test_warning_bands_are_recorded_and_do_not_trip(tmp_path):
    out, holding, run = run_with_fault(tmp_path, safety={"warning_fraction": 0.05})
    assert not isinstance(out, ExperimentStopped)
    warnings = [e for e in run.events() if e["kind"] == "warning"]
    assert warnings and all("beyond 5% of the limit" in e["message"] for e in warnings)
    assert any("warning" in (flags or "") for flags in run.steps["flags"])


def test_hsio_run_exits_4_on_an_interlock(tmp_path):
    cfg = tmp_path / "lag.toml"
    cfg.write_text("[record]\nduration_s = 2.0\n[test]\nrate = 10.0\n[output]\nplots = false\n"
                   "[emulator]\nlag_s = 1000.0\n[safety]\nfollowing_error_mm = 2.0\nfollowing_time_s = 0.1\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "run", str(cfg), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    assert proc.returncode == 4, proc.stderr
    assert "interlock (following)" in proc.stderr and "the actuators hold (confirmed by read-back)" in proc.stderr
    run = Run(tmp_path / "o" / "run.sqlite")
    assert run.summary["exit_status"] == 4 and run.summary["outcome"] == "stopped by an interlock"
    assert [e["kind"] for e in run.events()][-3:] == ["trip", "hold", "stop"]


def test_holding_reads_back_none_by_default():
    from hsio.interfaces import Actuator

    assert Actuator.holding(object()) is None


class _Axis:
    name = "C1"

    def __init__(self):
        from hsio.interfaces import Limits

        self.limits = Limits()


def _cycles(monitor, t0, t1, pause_at=None, pause_s=0.0, skip=True):
    """A specimen's force 10 sin(2 pi t) kN (one cycle per second of lab time) checked every
    1/1024 s from t0 to t1; with ``pause_at``, a pause of ``pause_s`` of lab time (no check) there."""
    from hsio.interfaces import ControlMode, Feedback

    dt, t, shift = 1.0 / 1024, t0, 0.0
    while t < t1:
        if pause_at is not None and shift == 0.0 and t >= pause_at:
            shift = pause_s
            if skip:
                monitor.skip(pause_s)
        f = 10.0 * math.sin(2 * math.pi * t)
        monitor.check(t + shift, [0.0], [Feedback(0.0, f, t + shift)], [ControlMode.DISPLACEMENT])
        t += dt


def test_the_lab_time_of_a_pause_does_not_count_in_the_force_drop_window():
    """Paused where the force is near zero for longer than the window: on resume the envelope would
    hold only that small force, and a specimen that is fine would trip as failed."""
    from hsio.safety.interlocks import InterlockMonitor

    settings = SafetySettings.from_table({"force_drop_fraction": 0.5, "force_drop_window_s": 1.5})
    _cycles(InterlockMonitor([_Axis()], settings), 0.0, 6.0, pause_at=2.0, pause_s=5.0)  # no trip
    with pytest.raises(InterlockTrip, match="the specimen failed"):  # the same run, the pause counted
        _cycles(InterlockMonitor([_Axis()], settings), 0.0, 6.0, pause_at=2.0, pause_s=5.0, skip=False)
    with pytest.raises(InterlockTrip, match="the specimen failed"):  # a force that does drop still trips
        monitor = InterlockMonitor([_Axis()], settings)
        _cycles(monitor, 0.0, 2.0, pause_at=1.0, pause_s=5.0)
        from hsio.interfaces import ControlMode, Feedback

        for k in range(2 * 1024):  # after the pause the force stays at 0.1 kN: the specimen failed
            t = 7.0 + k / 1024
            monitor.check(t, [0.0], [Feedback(0.0, 0.1, t)], [ControlMode.DISPLACEMENT])


def test_a_real_time_pause_tells_the_interlocks_how_long_it_lasted():
    s = validation()
    site = api.open_site(s, "emulator://", clock="realtime", test_rate=10.0,
                         safety=SafetySettings.from_table({"force_drop_fraction": 0.5}))
    skipped = []
    site.loop.monitor.skip = skipped.append
    try:
        site.loop.pause()
        started = site.loop.clock.now_s
        time.sleep(0.3)
        site.loop.resume()
        lasted = site.loop.clock.now_s - started
    finally:
        site.close()
    # lab time in controller periods, as the clock counted them over the pause (a loaded machine ticks
    # fewer than the 0.3 s slept)
    assert len(skipped) == 1 and 0 < skipped[0] and lasted - 0.05 <= skipped[0] <= lasted + 0.01
