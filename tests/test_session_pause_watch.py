"""A controller that trips while the run is paused (docs/safety.md section 4): the pause watches
the controllers, tells and records the trip with its time, and a resume waits for the operator's
acknowledgement."""

from __future__ import annotations

import threading
import time

import pytest

from hsio import config, runner
from hsio.experiment import ExperimentStopped
from hsio.recording import Run
from hsio.safety.control import PAUSED, RunControl
from hsio.safety.status import LIMIT_OR_FAULT, exit_status


def _run_stopped_beside(operator, cfg, tmp_path, control, monkeypatch):
    """``hsio run`` of ``cfg`` with ``operator`` (given the site as ``operator.site``) in a thread
    beside it; the run must stop: its ExperimentStopped info."""
    real_open = runner.api.open_site

    def open_site(*args, **kwargs):
        operator.site = real_open(*args, **kwargs)
        return operator.site

    monkeypatch.setattr(runner.api, "open_site", open_site)
    thread = threading.Thread(target=operator, daemon=True)
    thread.start()
    with pytest.raises(ExperimentStopped) as info:
        runner.run(cfg, tmp_path / "o", control=control)
    thread.join(timeout=10)
    return info

def test_a_controller_trip_while_paused_is_told_recorded_and_holds_the_resume(tmp_path, monkeypatch):
    monkeypatch.setattr(RunControl, "WATCH_S", 0.05)
    cfg = config.from_dict({"record": {"duration_s": 1.0}, "output": {"plots": False}})
    control, heard, replies = RunControl(), [], {}
    control.listeners.append(heard.append)

    def operator():
        deadline = time.monotonic() + 60
        while not (control.phase == "HS" and control.step >= 5) and time.monotonic() < deadline:
            time.sleep(0.005)
        control.request_pause("test")
        while control.state != PAUSED and time.monotonic() < deadline:
            time.sleep(0.005)
        site_actuator = operator.site.loop.actuators[0]
        site_actuator.controller.tripped = "oil pressure low"  # the controller trips at its panel
        site_actuator.controller.hold()
        while not control.trips and time.monotonic() < deadline:
            time.sleep(0.005)
        replies["told"] = list(heard)
        replies["resume"] = control.request_resume("test")
        time.sleep(0.2)
        replies["state"] = control.state  # still paused: nothing moved
        replies["ack"] = control.request_ack("test")
        replies["resume2"] = control.request_resume("test")

    info = _run_stopped_beside(operator, cfg, tmp_path, control, monkeypatch)
    told = [line for line in replies["told"] if "controller trip during the pause" in line]
    assert told and "C1: interlock tripped: oil pressure low" in told[0] and "Z)" in told[0]  # UTC time
    assert replies["resume"].startswith("error: not resumed: a controller tripped during the pause")
    assert replies["state"] == PAUSED
    assert replies["ack"] == "ok acknowledged" and replies["resume2"].startswith("ok")
    # resumed on the operator's word against a controller still tripped: its first command stops the run
    assert exit_status(info.value) == LIMIT_OR_FAULT
    events = Run(tmp_path / "o" / "run.sqlite").events()
    kinds = [e["kind"] for e in events]
    assert kinds.index("pause") < kinds.index("controller_trip") < kinds.index("acknowledge") < kinds.index("resume")
    trip = events[kinds.index("controller_trip")]
    assert "oil pressure low" in trip["message"] and trip["step"] == events[kinds.index("pause")]["step"] >= 5


def test_a_resume_is_not_held_without_a_trip():
    control = RunControl()
    assert control.request_ack("test") == "error: no controller trip to acknowledge"


def test_a_controller_that_cannot_be_read_is_one_trip_however_its_error_reads():
    """The error's text varies from one watch to the next (a timeout in ms, a retry count): the
    line is the same, so the pause tells and records it once and one acknowledgement does."""
    from types import SimpleNamespace

    from hsio.control_loop import ControlLoop
    from hsio.errors import CommunicationError

    class Unreadable:
        name, asked = "C1", 0

        def tripped(self):
            self.asked += 1
            raise CommunicationError(f"no reply within {self.asked * 37} ms after {self.asked} retries")

    loop = SimpleNamespace(_lock=threading.Lock(), _paused=True, actuators=[Unreadable()])
    lines = [ControlLoop.watch_controllers(loop) for _ in range(3)]
    assert lines[0] == lines[1] == lines[2] == ["C1: its controller could not be read (CommunicationError)"]
    control, seen = RunControl(), set()
    assert control._watch(lambda: ControlLoop.watch_controllers(loop), seen, None) is True
    assert control._watch(lambda: ControlLoop.watch_controllers(loop), seen, None) is False
    assert len(control.trips) == 1


def test_a_controller_lost_while_paused_is_told_unconfirmed_and_the_run_stays_paused(tmp_path, monkeypatch):
    """The keep-alive of a pause cannot reach a controller (a link lost): the pause tells and
    records it as a trip whose hold cannot be confirmed, and waits for the operator (section 4)
    rather than ending the run on the failed write."""
    from hsio.errors import CommunicationError
    from hsio.safety.status import OPERATOR

    monkeypatch.setattr(RunControl, "WAIT_SLICE_S", 0.01)
    cfg = config.from_dict({"record": {"duration_s": 1.0}, "output": {"plots": False}})
    control, heard, replies = RunControl(), [], {}
    control.listeners.append(heard.append)

    def lost():
        raise CommunicationError("no reply from 127.0.0.1:5020 within 0.2 s")

    def operator():
        deadline = time.monotonic() + 60
        while not (control.phase == "HS" and control.step >= 5) and time.monotonic() < deadline:
            time.sleep(0.005)
        operator.site.loop.actuators[0].keep_alive = lost  # the link to C1's controller goes
        control.request_pause("test")
        while not control.trips and time.monotonic() < deadline:
            time.sleep(0.005)
        replies["resume"] = control.request_resume("test")
        time.sleep(0.1)
        replies["state"] = control.state
        control.request_stop("stopped by the operator")

    info = _run_stopped_beside(operator, cfg, tmp_path, control, monkeypatch)
    assert exit_status(info.value) == OPERATOR  # the operator's stop, not the failed write
    assert len(control.trips) == 1
    assert "C1: its controller could not be reached" in control.trips[0]
    assert "cannot be confirmed" in control.trips[0]
    assert replies["resume"].startswith("error: not resumed") and replies["state"] == PAUSED
    kinds = [e["kind"] for e in Run(tmp_path / "o" / "run.sqlite").events()]
    assert kinds.index("pause") < kinds.index("controller_trip") < kinds.index("stop")
