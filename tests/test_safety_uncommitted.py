"""The step a run stops in the middle of (docs/safety.md section 1): its controller-rate samples up
to the stop are kept in the record's uncommitted tables, never as a step, so a lab sees what the
actuators did before an interlock tripped while a resume, the summaries, diagnose and the monitor
see whole steps only."""

from __future__ import annotations

import json
import sqlite3
import numpy as np
import pytest

from hsio import api, config, runner
from hsio.errors import RecordError
from hsio.experiment import ExperimentStopped
from hsio.ground_motion import synthetic_record
from hsio.recording import Recorder, Run
from hsio.safety import resume
from hsio.safety.settings import SafetySettings
from hsio.safety.status import INTERLOCK, exit_status
from hsio.structures import validation

FAULT_TICK = 800  # controller periods: in the middle of a step (103 periods a step below)


def watched(site, fault=None):
    """Each emulated controller of ``site`` logs, after every period, its lab time, the command it
    was given and what it measured; ``fault(controller)`` is applied after every measurement from
    FAULT_TICK on. Returns the logs, one list per actuator."""
    logs = []
    for actuator in site.loop.actuators:
        c = actuator.controller
        log: list[tuple] = []
        measure, step = c._measure, c.step

        def faulty(c=c, measure=measure):
            measure()
            if fault is not None and c.ticks >= FAULT_TICK:
                fault(c)

        def logged(c=c, step=step, log=log):
            given = c.command  # the host's command for this period (a trip in it holds, changing it)
            step()
            log.append((c.time_s, given, c.measured_displacement, c.measured_force))

        c._measure, c.step = faulty, logged
        logs.append(log)
    return logs


def tripped_run(tmp_path, emulator: dict, safety: dict, fault=None, recorder_class=Recorder):
    """2 s of the validation structure at TR 10 on the in-process emulator until it trips."""
    s = validation()
    g = synthetic_record(duration_s=2.0, dt=s.dt)
    site = api.open_site(s, "emulator://", test_rate=10.0, options={"noise_mm": 0.0, "force_noise_kN": 0.0, **emulator},
                         safety=SafetySettings.from_table(safety))
    logs = watched(site, fault)
    rec = recorder_class(tmp_path / "run.sqlite", s.dof_names, [e.name for e in s.experimental])
    try:
        with pytest.raises(ExperimentStopped) as info:
            api.simulate(s, g, site, recorder=rec)
        holding = [a.holding() for a in site.loop.actuators]
    finally:
        rec.close()
        site.close()
    return info.value, holding, logs, site.zero, Run(tmp_path / "run.sqlite")


def assert_samples_are_the_emulators(samples, logs, zero):
    """Every uncommitted sample is what the emulated controllers were given and measured in that
    period, at that lab time."""
    for j, (name, log) in enumerate(zip(("C1", "C2"), logs)):
        by_time = {t: row for t, *row in log}
        for t, cmd, disp, force in zip(samples["lab_time_s"], samples[f"cmd_{name}"], samples[f"disp_{name}"],
                                       samples[f"force_{name}"]):
            command, measured, measured_force = by_time[t]
            assert cmd + zero[j] == pytest.approx(command, abs=1e-12)
            assert disp + zero[j] == pytest.approx(measured, abs=1e-12)
            assert force == pytest.approx(measured_force, abs=1e-12)


def test_a_following_error_trip_keeps_the_samples_of_its_step_up_to_the_trip(tmp_path):
    """A servo-valve that barely opens: the trip comes in the middle of a step; the record's
    steps end before it, and the unfinished step's samples end at the trip's period."""
    stop, holding, logs, zero, run = tripped_run(tmp_path, {"lag_s": 1000.0},
                                                 {"following_error_mm": 2.0, "following_time_s": 0.1})
    assert exit_status(stop) == INTERLOCK and holding == [True, True]
    assert "the actuators hold (confirmed by read-back)" in str(stop)
    (trip,) = [e for e in run.events() if e["kind"] == "trip"]
    last = int(run.steps["step"][-1])
    assert last == stop.result.steps and trip["step"] == last + 1
    steps, samples = run.uncommitted()
    assert steps["step"].tolist() == [last + 1] and steps["committed"].tolist() == [0]
    assert steps["time_s"][0] == pytest.approx((last + 1) * validation().dt)
    assert "interlock (following)" in steps["cause"][0]
    assert steps["stop_lab_time_s"][0] == trip["time_s"]
    n = int(steps["n_samples"][0])
    assert n == len(samples["k"]) and 1 < n < 103  # part of a step, not a whole one
    assert samples["k"].tolist() == list(range(n)) and set(samples["step"]) == {last + 1}
    # the samples run from the last committed step's end to the trip, one controller period apart
    committed = run.samples()
    period = 1.0 / 1024.0
    assert samples["lab_time_s"][0] == pytest.approx(committed["lab_time_s"][-1] + period, abs=1e-12)
    assert np.allclose(np.diff(samples["lab_time_s"]), period, atol=1e-12)
    assert samples["lab_time_s"][-1] == trip["time_s"]  # the period that tripped is the last one kept
    # at that period the following error is what the trip reported
    error = samples["cmd_C1"][-1] - samples["disp_C1"][-1]
    assert f"command - measured = {error:.3f} mm" in trip["message"]
    assert abs(error) > 2.0 and abs(samples["cmd_C1"][-2] - samples["disp_C1"][-2]) > 2.0
    assert_samples_are_the_emulators(samples, logs, zero)
    # the step's trial is recorded: the commands head for it
    target = steps["target_C1"][0]
    assert abs(target - samples["cmd_C1"][-1]) < abs(target - samples["cmd_C1"][0])
    # whole steps only elsewhere: the samples table ends with the last committed step
    assert committed["step"].max() == last
    assert len(run.steps["step"]) == last


def test_a_stroke_trip_of_the_controller_keeps_the_period_that_went_beyond(tmp_path):
    """The controller's own stroke interlock: the transducer reads 130 mm on a +/-127 mm stroke
    at FAULT_TICK; the controller trips and refuses the next command. The last uncommitted sample
    is that reading, at that period's lab time."""

    def beyond(c):
        c.measured_displacement = 130.0

    stop, holding, logs, zero, run = tripped_run(tmp_path, {}, {"jump_mm": 1000.0, "following_error_mm": 1000.0},
                                                 beyond)
    assert "beyond the stroke" in str(stop) and holding == [True, True]
    assert "the actuators hold (confirmed by read-back)" in str(stop)
    steps, samples = run.uncommitted()
    assert len(steps["step"]) == 1 and steps["step"][0] == run.steps["step"][-1] + 1
    assert samples["lab_time_s"][-1] == pytest.approx(FAULT_TICK / 1024.0, abs=1e-12)
    assert samples["disp_C1"][-1] + zero[0] == 130.0 and samples["disp_C2"][-1] + zero[1] == 130.0
    assert abs(samples["disp_C1"][-2]) < 20.0  # the period before read the rod where it was
    assert_samples_are_the_emulators(samples, logs, zero)
    assert "beyond the stroke" in steps["cause"][0]


def test_ctrl_c_in_the_middle_of_a_step_keeps_its_samples_and_the_commands_of_its_last_period(tmp_path):
    """Ctrl-C while the controllers run period FAULT_TICK + 1 (lockstep): the samples measured
    before it are kept, and that period's commands, sent but never measured, close them with
    NaN measurements."""
    s = validation()
    g = synthetic_record(duration_s=2.0, dt=s.dt)
    site = api.open_site(s, "emulator://", test_rate=10.0, options={"noise_mm": 0.0, "force_noise_kN": 0.0})
    logs = watched(site)
    c = site.loop.actuators[0].controller
    step = c.step
    given = []

    def interrupted():
        if c.ticks == FAULT_TICK:
            given.extend(a.controller.command for a in site.loop.actuators)  # before the hold changes them
            raise KeyboardInterrupt
        step()

    c.step = interrupted
    rec = Recorder(tmp_path / "run.sqlite", s.dof_names, [e.name for e in s.experimental])
    try:
        with pytest.raises(ExperimentStopped) as info:
            api.simulate(s, g, site, recorder=rec)
        holding = [a.holding() for a in site.loop.actuators]
    finally:
        rec.close()
        site.close()
    assert isinstance(info.value.cause, KeyboardInterrupt) and holding == [True, True]
    run = Run(tmp_path / "run.sqlite")
    steps, samples = run.uncommitted()
    assert "interrupted (Ctrl-C)" in steps["cause"][0]
    assert samples["lab_time_s"][-2] == FAULT_TICK / 1024.0 and samples["lab_time_s"][-1] == (FAULT_TICK + 1) / 1024.0
    assert np.isnan([samples["disp_C1"][-1], samples["force_C2"][-1]]).all()
    assert np.isfinite([samples["cmd_C1"][-1], samples["cmd_C2"][-1]]).all()  # both went out
    assert_samples_are_the_emulators({key: v[:-1] for key, v in samples.items()}, logs, site.zero)
    # the last period's commands are those the controllers were given (C1's never ran it)
    assert [samples["cmd_C1"][-1], samples["cmd_C2"][-1]] == given


class FullDisk(Recorder):
    """A recorder whose disk is full for the uncommitted tables alone."""

    def write_uncommitted(self, *args, **kwargs):
        self.db.execute("SAVEPOINT uncommitted")
        self.db.execute("CREATE TABLE uncommitted_steps (stop INTEGER)")
        self.db.execute("ROLLBACK TO uncommitted")
        self.db.execute("RELEASE uncommitted")
        raise RecordError(f"{self.path}: the samples of the unfinished step could not be written (database or disk is full)")


def test_a_failed_write_of_the_unfinished_step_hides_neither_the_trip_nor_the_hold(tmp_path):
    stop, holding, _, _, run = tripped_run(tmp_path, {"lag_s": 1000.0},
                                           {"following_error_mm": 2.0, "following_time_s": 0.1}, recorder_class=FullDisk)
    assert exit_status(stop) == INTERLOCK and holding == [True, True]
    assert "does not follow its command" in str(stop)
    assert "the actuators hold (confirmed by read-back)" in str(stop)
    assert "the samples of the unfinished step" in str(stop) and "could not be recorded" in str(stop)
    kinds = [e["kind"] for e in run.events()]
    assert "trip" in kinds and "hold" in kinds and "stop" in kinds
    assert len(run.steps["step"]) == stop.result.steps > 5
    assert run.uncommitted() == ({}, {})


def test_the_write_undoes_only_its_own_rows(tmp_path):
    """A write of the unfinished step that fails (here: rows of the wrong width) undoes its own
    rows and tables only: an event written before it, not yet committed, is kept."""
    rec = Recorder(tmp_path / "run.sqlite", ["x"], ["C1"])
    rec.write_event(2.0, 4, "trip", "C1", "tripped", commit=False)
    with pytest.raises(RecordError, match="unfinished step 4"):
        rec.write_uncommitted(4, 0.04, 2.0, "stop", [1.0], np.zeros((2, 2, 3)))  # two actuators' worth
    rec.close()
    run = Run(tmp_path / "run.sqlite")
    assert [e["message"] for e in run.events()] == ["tripped"]
    assert run.uncommitted() == ({}, {})


def test_a_resume_of_a_tripped_record_ignores_its_unfinished_step(tmp_path, monkeypatch):
    """A run that a second client's commands trip in the middle of a step, resumed without the
    intruder: the resumed run makes the tripped step again, commits every step once, and the
    unfinished step stays where it was, apart from the steps."""
    cfg = config.from_dict({"record": {"duration_s": 1.5}, "test": {"rate": 10.0}, "output": {"plots": True},
                            "safety": {"following_error_mm": 1.0, "following_time_s": 0.05},
                            "emulator": {"noise_mm": 0.0, "force_noise_kN": 0.0}})
    real_open = api.open_site

    def intruded(*args, **kwargs):
        site = real_open(*args, **kwargs)

        def intruder(c):
            c.command = 0.0

        for actuator in site.loop.actuators:
            c, step = actuator.controller, actuator.controller.step

            def stepped(c=c, step=step):
                if c.ticks >= FAULT_TICK:
                    intruder(c)
                step()

            c.step = stepped
        return site

    monkeypatch.setattr(api, "open_site", intruded)
    with pytest.raises(ExperimentStopped) as info:
        runner.run(cfg, tmp_path / "o")
    assert exit_status(info.value) == INTERLOCK
    out = tmp_path / "o"
    run = Run(out / "run.sqlite")
    tripped_at = int(run.steps["step"][-1]) + 1
    steps, samples = run.uncommitted()
    assert steps["step"].tolist() == [tripped_at] and len(samples["k"]) > 1
    assert str(out / "stop.png") in json.loads((out / "summary.json").read_text())["plots"]  # the last samples, drawn
    monkeypatch.setattr(api, "open_site", real_open)
    summary = resume.resume(out, max_gap_mm=1000.0)
    assert summary["exit_status"] == 0
    run = Run(out / "run.sqlite")
    n = len(run.steps["step"])
    assert run.steps["step"].tolist() == list(range(1, n + 1)) and n == int(1.5 / validation().dt)
    committed = run.samples()
    assert sorted(set(committed["step"].tolist())) == list(range(1, n + 1))
    again = committed["step"] == tripped_at
    assert 1 < again.sum() and not np.isin(committed["lab_time_s"][again], samples["lab_time_s"]).all()
    assert run.uncommitted()[0]["step"].tolist() == [tripped_at]  # still there, still not committed
    db = sqlite3.connect(out / "run.sqlite")
    try:
        assert db.execute("SELECT COUNT(*) FROM steps WHERE step = ?", (tripped_at,)).fetchone()[0] == 1
    finally:
        db.close()
