"""Pauses in the record (docs/safety.md section 4): one asked during the prediction (NS) holds
before the first step and is recorded there; one a resume cancels before it took effect is
recorded as cancelled; the time spent paused is not counted as the host's slowness."""

from __future__ import annotations

import re
import threading
import time

from hsio import config, runner
from hsio.recording import Run
from hsio.safety.control import PAUSED, RunControl

SHORT = {"record": {"duration_s": 0.3}, "output": {"plots": False}}


def _during_ns(monkeypatch, action):
    """Call ``action`` as the run's prediction (NS) begins."""
    real = runner.api.run_numerical

    def run_numerical(*args, **kwargs):
        action()
        return real(*args, **kwargs)

    monkeypatch.setattr(runner.api, "run_numerical", run_numerical)


def _resume_when_paused(control: RunControl, after_s: float = 0.0) -> threading.Thread:
    def resume():
        deadline = time.monotonic() + 30
        while control.state != PAUSED and time.monotonic() < deadline:
            time.sleep(0.002)
        time.sleep(after_s)
        control.request_resume("test")

    thread = threading.Thread(target=resume, daemon=True)
    thread.start()
    return thread


def test_a_pause_asked_during_ns_holds_before_the_first_step_and_is_recorded(tmp_path, monkeypatch):
    control, heard = RunControl(), []
    control.listeners.append(heard.append)
    _during_ns(monkeypatch, lambda: control.request_pause("test"))
    thread = _resume_when_paused(control)
    runner.run(config.from_dict(SHORT), tmp_path / "o", control=control)
    thread.join(timeout=10)
    events = [e for e in Run(tmp_path / "o" / "run.sqlite").events() if e["kind"] in ("pause", "resume")]
    assert [(e["kind"], e["step"]) for e in events] == [("pause", 0), ("resume", 0)]
    assert "paused after step 0: the actuators hold (confirmed by read-back)" in events[0]["message"]
    assert not any("no actuators to hold" in line for line in heard)  # not a pause of NS, with nothing held


def test_a_pause_cancelled_by_a_resume_before_it_took_effect_is_recorded(tmp_path, monkeypatch):
    control = RunControl()

    def ask_and_cancel():
        control.request_pause("socket")
        control.request_resume("socket")

    _during_ns(monkeypatch, ask_and_cancel)
    runner.run(config.from_dict(SHORT), tmp_path / "o", control=control)
    events = Run(tmp_path / "o" / "run.sqlite").events()
    assert [e["kind"] for e in events if e["kind"] in ("pause", "resume")] == []  # nothing was held
    (cancelled,) = [e for e in events if e["kind"] == "pause_cancelled"]
    assert "cancelled by a resume (socket) before it took effect" in cancelled["message"]
    assert "phase NS" in cancelled["message"] and "nothing was held" in cancelled["message"]


def test_the_rate_warning_does_not_count_the_pause_as_the_hosts_time(tmp_path, monkeypatch):
    """A host that missed the controller's rate (its clock's overruns) in a run paused for 0.4 s:
    the warning's wall time leaves the pause out and says so."""
    control, told = RunControl(), []
    control.request_pause("test")  # before the run: it holds before the first step
    thread = _resume_when_paused(control, after_s=0.4)
    real_open = runner.api.open_site

    def open_site(*args, **kwargs):
        site = real_open(*args, **kwargs)
        site.loop.clock.overruns = 10 ** 9  # every period late
        return site

    monkeypatch.setattr(runner.api, "open_site", open_site)
    summary = runner.run(config.from_dict(SHORT), tmp_path / "o", control=control, notify=told.append)
    thread.join(timeout=10)
    (warning,) = [line for line in told if "did not keep the controller's rate" in line]
    took, paused = re.search(r"the test took ([0-9.e+-]+) s \(not counting ([0-9.e+-]+) s of pause\)", warning).groups()
    assert float(paused) >= 0.4
    assert float(took) <= summary["wall_time_s"] - 0.4 + 1e-3
