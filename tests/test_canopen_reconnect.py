"""A lost SLCAN-over-TCP link to CANopen drives, as the Modbus TCP link: the driver makes it
again within [driver] retries attempts (reconnect_delay_s x attempt apart), the step in flight
is settled by the drive's clock (its SYNC neither lost nor applied twice) and the run equals the
run without the fault; a link that does not come back stops the run with a clear error, the
recorded steps kept and no hold claimed (docs/canopen.md, "Errors")."""

from __future__ import annotations

import itertools
import threading

import numpy as np
import pytest

from hsio.commands.emulate import bank_from_config
from hsio.experiment import ExperimentStopped
from test_emulate_cli import Emulator
from wire import QUIET_SENSORS, FaultProxy, fault_at, in_process_run, run, write_config

_channels = itertools.count()
DROP_TICK = 300  # a third into the run: 20 periods a step, step 15


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    return write_config(tmp_path_factory.mktemp("reconnect"), duration=0.3, rate=2.0, extra=QUIET_SENSORS)


@pytest.fixture(scope="module")
def reference(cfg, tmp_path_factory):
    """The same run with the drives in this process on python-can's virtual bus."""
    return in_process_run(cfg, tmp_path_factory.mktemp("local") / "run", f"reconnect-ref-{next(_channels)}")


@pytest.fixture
def thread_errors(monkeypatch):
    seen = []
    monkeypatch.setattr(threading, "excepthook", lambda args: seen.append(args.exc_value))
    return seen


@pytest.fixture
def emulated(cfg):
    """`hsio emulate canopen --slcan tcp` in another process, reached through a proxy that can
    cut the link."""
    emu = Emulator("canopen", "--slcan", "tcp", cfg)
    proxy = None
    try:
        port = int(emu.lines["url"].rpartition(":")[2].partition("/")[0])
        proxy = FaultProxy(port)
        yield emu, proxy
    finally:
        if proxy is not None:
            proxy.close()
        emu.stop()


def test_link_lost_mid_run_is_made_again_and_the_run_is_unchanged(monkeypatch, tmp_path, cfg, reference, emulated,
                                                                   thread_errors):
    emu, proxy = emulated
    trigger = fault_at(monkeypatch, DROP_TICK, proxy.drop)
    summary, recorded = run(cfg, tmp_path / "run", url=f"canopen+slcan://127.0.0.1:{proxy.port}/1",
                            driver={"timeout_s": 0.2})
    assert trigger.done
    assert isinstance(summary, dict), summary
    assert proxy.connections >= 2  # the link was made again
    assert summary["steps"] == reference[0]["steps"] > 0
    assert list(recorded.steps["step"]) == list(range(1, summary["steps"] + 1))
    for key in reference[1].steps:
        if key.startswith(("u_", "disp_", "force_", "target_")):  # the step in flight neither lost nor made twice
            assert np.array_equal(recorded.steps[key], reference[1].steps[key]), key
    links = [e for e in recorded.events() if e["kind"] == "link"]  # and the record says when
    assert len(links) == 1 and "the link was made again after 1 reconnection attempt(s)" in links[0]["message"]
    assert thread_errors == []


def test_link_that_does_not_come_back_stops_the_run_with_the_steps_kept(monkeypatch, tmp_path, cfg, emulated,
                                                                       thread_errors):
    emu, proxy = emulated

    def cut_for_good():
        proxy.listener.close()  # nothing listens: every reconnection is refused
        proxy.drop()

    trigger = fault_at(monkeypatch, DROP_TICK, cut_for_good)
    result, recorded = run(cfg, tmp_path / "run", url=f"canopen+slcan://127.0.0.1:{proxy.port}/1",
                           driver={"timeout_s": 0.2, "retries": 2, "reconnect_delay_s": 0.05})
    assert trigger.done
    assert isinstance(result, ExperimentStopped), result
    message = str(result)
    assert "the CAN bus failed" in message and "the adapter or its link is lost" in message, message
    assert "not reconnected after 2 attempt(s)" in message, message
    assert "confirmed by read-back" not in message
    steps = result.result.steps
    assert 5 < steps <= DROP_TICK // 20 + 1
    assert list(recorded.steps["step"]) == list(range(1, steps + 1))
    assert thread_errors == []


@pytest.mark.parametrize("while_down", ["watchdog", "restart"])
def test_a_drive_that_changed_while_the_link_was_down_stops_the_run(monkeypatch, tmp_path, cfg, while_down):
    """The link comes back, but the drive is not as it was left, and what told of it (an EMCY,
    a boot-up message) went with the link: its host watchdog expired (FAULT: an interlock, the
    hold read back) or it restarted (its clock behind the periods run: the state is lost). The
    run stops naming it, the steps made kept."""
    import time

    from hsio.emulators.canopen import slcan_emulator

    emu = slcan_emulator(bank_from_config(cfg, lockstep=True, watchdog_s=0.2 if while_down == "watchdog" else 5.0), "tcp")

    def cut():
        emu.slcan.drop()
        if while_down == "restart":
            time.sleep(0.05)
            emu.restart()

    fault_at(monkeypatch, DROP_TICK, cut)
    try:
        result, recorded = run(cfg, tmp_path / "run", url=emu.url, driver={"timeout_s": 0.2, "reconnect_delay_s": 0.5})
    finally:
        emu.stop()
    assert isinstance(result, ExperimentStopped), result
    message = str(result)
    if while_down == "watchdog":  # read on reconnecting, or (on a loaded machine the watchdog can expire
        # again after the link is back, before the first command) told by the drive's EMCY then
        assert ("no longer OPERATION ENABLED after the link was lost (statusword 0x0208" in message
                or "EMCY 0x8130 (host watchdog expired" in message), message
        assert "the actuators hold (confirmed by read-back)" in message, message
    else:
        assert "it restarted (its boot-up message went with the link)" in message, message
    steps = result.result.steps
    assert 5 < steps <= DROP_TICK // 20 + 1
    assert list(recorded.steps["step"]) == list(range(1, steps + 1))


def test_a_link_lost_while_the_tpdos_are_awaited_is_made_again_before_the_drives_watchdog(tmp_path, cfg, reference):
    """The link goes while the driver awaits the TPDOs of a SYNC the drives took (their answers
    go with the link). The driver sees the bus fail and makes the link again at once, not after
    its 10 s timeout: the drives' 2 s host watchdog does not expire, and the SYNC that arrived is
    not sent again (the run equals the reference)."""
    from hsio.emulators.canopen import slcan_emulator

    emu = slcan_emulator(bank_from_config(cfg, lockstep=True, watchdog_s=2.0), "tcp")
    send, cut = emu._send_tpdos, []

    def answer_or_cut(fault=None):
        if not cut and emu.bank.ticks >= DROP_TICK:
            cut.append(emu.bank.ticks)
            emu.slcan.drop()  # the SYNC was taken (the clock advanced); its answers are lost
            return
        send(fault)

    emu._send_tpdos = answer_or_cut
    try:
        summary, recorded = run(cfg, tmp_path / "run", url=emu.url, driver={"timeout_s": 10.0})
    finally:
        emu.stop()
    assert cut
    assert isinstance(summary, dict), summary
    for key in reference[1].steps:
        if key.startswith(("u_", "disp_", "force_", "target_")):
            assert np.array_equal(recorded.steps[key], reference[1].steps[key]), key
