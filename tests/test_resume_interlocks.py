"""The interlocks' running state across `hsio resume` (docs/safety.md section 8): the force-drop
interlock judges the resumed steps against the peak force the specimen reached before the stop."""

from __future__ import annotations

import threading
import time

import pytest

from hsio import api, config, runner
from hsio.experiment import INTERLOCK_TABLE, ExperimentStopped
from hsio.recording import Run
from hsio.safety import resume
from hsio.safety.control import RunControl
from hsio.safety.status import INTERLOCK, OPERATOR, exit_status

SAFETY = {"force_drop_fraction": 0.25, "force_drop_window_s": 6.0, "jump_kN": 1000.0}


def stopped_run(tmp_path, stop_at: int):
    """The default structure, 3 s of record at TR 10, the operator's stop after step ``stop_at``."""
    cfg = config.from_dict({"record": {"duration_s": 3.0}, "test": {"rate": 10.0}, "output": {"plots": False},
                            "safety": SAFETY, "emulator": {"noise_mm": 0.0, "force_noise_kN": 0.0}})
    control = RunControl()

    def operator():
        deadline = time.monotonic() + 60
        while not (control.phase == "HS" and control.step >= stop_at) and time.monotonic() < deadline:
            time.sleep(0.002)
        control.request_stop("stopped by the test")

    threading.Thread(target=operator, daemon=True).start()
    with pytest.raises(ExperimentStopped) as info:
        runner.run(cfg, tmp_path / "o", control=control)
    assert exit_status(info.value) == OPERATOR
    return tmp_path / "o"


def weakened(monkeypatch, most_kN: float):
    """Every site opened from here on measures at most ``most_kN`` of the specimen's force: a
    specimen that failed while the run stood still."""
    real_open = api.open_site

    def open_site(*args, **kwargs):
        site = real_open(*args, **kwargs)
        for actuator in site.loop.actuators:
            c, measure = actuator.controller, actuator.controller._measure

            def weak(c=c, measure=measure):
                measure()
                c.measured_force = max(-most_kN, min(most_kN, c.measured_force))

            c._measure = weak
        return site

    monkeypatch.setattr(api, "open_site", open_site)


def test_a_drop_after_a_resume_is_judged_against_the_peak_before_the_stop(tmp_path, monkeypatch):
    out = stopped_run(tmp_path, stop_at=100)
    run = Run(out / "run.sqlite")
    table = run.table(INTERLOCK_TABLE)
    peaks = [float(table[f"peak_force_kN_{name}"][-1]) for name in ("C1", "C2")]
    assert min(peaks) > 0.5  # the specimen carried force before the stop
    weakened(monkeypatch, 0.1)  # failed: at most 0.1 kN from the resume on
    heard = []
    with pytest.raises(ExperimentStopped) as info:
        resume.resume(out, notify=heard.append, max_gap_mm=1000.0)
    assert exit_status(info.value) == INTERLOCK
    assert "force_drop" in str(info.value) and "the specimen failed" in str(info.value)
    assert any("the force-drop interlock goes on from the peaks the run reached" in line for line in heard)
    (trip,) = [e for e in Run(out / "run.sqlite").events() if e["kind"] == "trip"]
    assert any(f"of the peak {peak:.3f} kN" in trip["message"] for peak in peaks)  # the peak before the stop


def test_a_resumed_specimen_that_keeps_its_strength_does_not_trip(tmp_path):
    out = stopped_run(tmp_path, stop_at=100)
    summary = resume.resume(out, max_gap_mm=1000.0)
    assert summary["exit_status"] == 0
