"""Faults beyond the fault schedule's own kinds, with other values and moments than the fault
tests: a CAN adapter whose link is lost mid-run, a Modbus controller that stops answering at
the hold, clients of `hsio serve opensees` that misbehave, `hsio probe` against servers that
are not controllers. Each ends as docs/faults.md, docs/canopen.md, docs/opensees.md say: the
documented error naming the cause, the recorded steps kept, no traceback, no hang, and a hold
claimed only when it was read back."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from hsio import api
from hsio.clock import LockstepClock
from hsio.commands.emulate import bank_from_config
from hsio.emulators.canopen import slcan_emulator
from hsio.experiment import ExperimentStopped
from wire import QUIET_SENSORS, AtStep, run, write_config


def fault_at(monkeypatch, tick: int, action) -> AtStep:
    """``action`` once the experiment's lockstep clock reaches ``tick``."""
    trigger = AtStep(tick, action)

    def make_clock():
        clock = LockstepClock()
        clock.attach(trigger)
        return clock

    monkeypatch.setattr(api, "LockstepClock", make_clock)
    return trigger


@pytest.fixture
def thread_errors(monkeypatch):
    """Exceptions that ended a thread (python-can's receive thread, say): each would print a
    traceback on the terminal."""
    seen = []
    monkeypatch.setattr(threading, "excepthook", lambda args: seen.append(args.exc_value))
    return seen


def test_can_adapter_lost_mid_run_is_a_named_link_fault(monkeypatch, tmp_path, thread_errors):
    """The SLCAN adapter's TCP link closes a third into a run: the run stops as a lost link
    (CommunicationError naming the CAN bus), no thread dies with a traceback, every step made
    before is in the record and the hold is not claimed (nothing answers to read it back)."""
    cfg = write_config(tmp_path, duration=0.5, rate=2.0, extra=QUIET_SENSORS)
    emu = slcan_emulator(bank_from_config(cfg, lockstep=True, watchdog_s=5.0), "tcp")
    try:
        trigger = fault_at(monkeypatch, 300, emu.slcan.drop)  # the adapter's TCP link is cut
        result, recorded = run(cfg, tmp_path / "run", url=emu.url, driver={"timeout_s": 0.2, "retries": 1})
    finally:
        emu.stop()  # closes its SLCAN port too
    assert trigger.done
    assert isinstance(result, ExperimentStopped), result
    message = str(result)
    assert "the CAN bus failed" in message and "the adapter or its link is lost" in message, message
    assert "unexpected" not in message
    assert "confirmed by read-back" not in message
    assert thread_errors == []
    steps = result.result.steps
    assert 5 < steps < 300 // 20 + 2
    assert list(recorded.steps["step"]) == list(range(1, steps + 1))

