"""Faults on the Modbus link: dropped link, late and corrupted replies, a silent or restarted
controller, out-of-range commands, malformed frames. The run holds, reconnects, or stops with a
clear error, and every recorded step stays recorded."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from hsio.drivers import modbus_map
from hsio.commands.emulate import bank_from_config
from hsio.emulators.modbus import ModbusEmulator
from hsio.experiment import ExperimentStopped
from wire import FaultProxy, fault_at, max_abs_diff, run, write_config

FLOAT32_EPS = 2.0 ** -23
FAULT_TICK = 3000  # about a third into the run


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    return write_config(tmp_path_factory.mktemp("cfg"), duration=1.0)


# The host watchdog of the emulated controller: longer than a reconnect after a dropped link
# (gaps of 250-280 ms were measured on a loaded 2-core machine), so the faults below test the
# driver's retries, not the watchdog.
WATCHDOG_S = 2.0
SILENT_WATCHDOG_S = 0.3  # the silent-controller test waits for this one to expire


def start_emulator(cfg, watchdog_s: float = WATCHDOG_S) -> ModbusEmulator:
    return ModbusEmulator(bank_from_config(cfg, lockstep=True, watchdog_s=watchdog_s), modbus_map.load()).start()


@pytest.fixture
def emulator(cfg, request):
    emu = start_emulator(cfg, getattr(request, "param", WATCHDOG_S))
    yield emu
    emu.stop()


@pytest.fixture
def proxy(emulator):
    p = FaultProxy(emulator.port)
    yield p
    p.close()


@pytest.fixture(scope="module")
def reference(cfg, tmp_path_factory):
    return run(cfg, tmp_path_factory.mktemp("local") / "run")


def same_run(reference, b) -> bool:
    summary, a = reference
    return max_abs_diff(a, b) <= 100 * FLOAT32_EPS * max(summary["peak_displacement_mm"])


def assert_stopped_with_steps_kept(result, recorded, pattern: str) -> None:
    assert isinstance(result, ExperimentStopped), result
    assert pytest.approx(0) != len(result.result.t)
    msg = str(result)
    import re
    assert re.search(pattern, msg), msg
    assert "steps recorded" in msg
    steps = result.result.steps
    assert steps > 5
    assert len(recorded.steps["step"]) == steps  # every step made is in the record


def test_dropped_link_reconnects_and_the_run_is_unchanged(monkeypatch, tmp_path, cfg, proxy, reference):
    trigger = fault_at(monkeypatch, FAULT_TICK, proxy.drop)
    summary, b = run(cfg, tmp_path / "wire", url=f"modbus+tcp://127.0.0.1:{proxy.port}", driver={"timeout_s": 0.2})
    assert trigger.done and proxy.connections >= 2
    assert summary["steps"] == reference[0]["steps"]
    assert same_run(reference, b)
    links = [e for e in b.events() if e["kind"] == "link"]  # the record says so, at the step it happened
    assert len(links) == 1 and f"127.0.0.1:{proxy.port}: the link was made again after 1" in links[0]["message"]
    assert "link" in b.steps["flags"][list(b.steps["step"]).index(links[0]["step"])]
    assert not [e for e in reference[1].events() if e["kind"] == "link"]


def test_reply_later_than_the_timeout_is_retried(monkeypatch, tmp_path, cfg, proxy, reference):
    fault_at(monkeypatch, FAULT_TICK, lambda: proxy.delay_next(0.5))
    summary, b = run(cfg, tmp_path / "wire", url=f"modbus+tcp://127.0.0.1:{proxy.port}", driver={"timeout_s": 0.15})
    assert proxy.connections >= 2  # the late reply was abandoned with its connection
    assert summary["steps"] == reference[0]["steps"] and same_run(reference, b)


def test_corrupted_reply_is_rejected_and_retried(monkeypatch, tmp_path, cfg, proxy, reference):
    fault_at(monkeypatch, FAULT_TICK, proxy.corrupt_next)
    summary, b = run(cfg, tmp_path / "wire", url=f"modbus+tcp://127.0.0.1:{proxy.port}", driver={"timeout_s": 0.15})
    assert summary["steps"] == reference[0]["steps"] and same_run(reference, b)


@pytest.mark.parametrize("emulator", [SILENT_WATCHDOG_S], indirect=True)
def test_silent_controller_stops_the_run_with_a_clear_error(monkeypatch, tmp_path, cfg, emulator, proxy):
    def go_silent():
        proxy.blackhole = True

    fault_at(monkeypatch, FAULT_TICK, go_silent)
    result, recorded = run(cfg, tmp_path / "wire", url=f"modbus+tcp://127.0.0.1:{proxy.port}",
                           driver={"timeout_s": 0.1, "retries": 1})
    assert_stopped_with_steps_kept(result, recorded, r"no valid answer after 2 attempt\(s\) with a 0.1 s timeout")
    # The controller, silent host or not, holds (its short watchdog expires).
    time.sleep(SILENT_WATCHDOG_S + 0.2)
    assert all(c.holding for c in emulator.bank.controllers)


def test_restarted_controller_is_detected_and_the_run_stops(monkeypatch, tmp_path, cfg, emulator):
    port = emulator.port
    fresh = {}

    def restart():
        emulator.stop()
        fresh["emu"] = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load(), port=port).start()

    fault_at(monkeypatch, FAULT_TICK, restart)
    try:
        result, recorded = run(cfg, tmp_path / "wire", url=emulator.url, driver={"timeout_s": 0.2, "reconnect_delay_s": 0.2})
        assert_stopped_with_steps_kept(result, recorded, "the controller restarted")
    finally:
        if "emu" in fresh:
            fresh["emu"].stop()


def test_out_of_range_command_is_refused_and_the_actuators_hold(tmp_path, cfg, emulator):
    # The dry run would refuse this test before anything moves: overridden, the command is refused.
    result, recorded = run(cfg, tmp_path / "wire", url=emulator.url, driver={"stroke_mm": 1.0},
                           safety={"override": True})
    assert_stopped_with_steps_kept(result, recorded, r"beyond the stroke \(\+/-0.5 mm\); not sent")
    assert all(c.holding for c in emulator.bank.controllers)
    assert all(abs(c.command) <= 0.5 for c in emulator.bank.controllers)  # nothing beyond was sent


def test_malformed_frames_do_not_disturb_the_controller(monkeypatch, tmp_path, cfg, emulator, reference):
    answers = []

    def garbage():
        for junk in (b"\x00\x01\x00\x00\x00\x02\x01", b"\xff" * 40, b"\x00\x07\x00\x00\x00\x06\x01\x63\x00\x00\x00\x01"):
            with socket.create_connection(("127.0.0.1", emulator.port), timeout=0.5) as s:
                s.sendall(junk)
                s.settimeout(0.2)
                try:
                    answers.append(s.recv(256))
                except (TimeoutError, OSError):
                    answers.append(b"")

    sender = threading.Thread(target=garbage)  # another client sends junk while the run goes on
    fault_at(monkeypatch, FAULT_TICK, sender.start)
    summary, b = run(cfg, tmp_path / "wire", url=emulator.url)
    sender.join(timeout=5)
    assert len(answers) == 3
    assert answers[2][7] & 0x80 and answers[2][8] == 1  # unknown function 0x63: exception 1 (illegal function)
    assert summary["steps"] == reference[0]["steps"] and same_run(reference, b)


def test_a_reply_of_another_size_to_the_boot_id_read_is_a_failed_attempt(monkeypatch, cfg, emulator):
    """After a reconnection the driver reads the controller's boot id. A reply with another number
    of registers (a late answer to the request before the reconnection, as over a loaded serial
    line) is not the boot id: that attempt fails and the next one is made, instead of decoding it
    (struct: "unpack requires a buffer of 4 bytes") and stopping the run on an unexpected error."""
    from pymodbus.exceptions import ConnectionException

    from hsio.clock import LockstepClock
    from hsio.drivers.modbus import open_link

    acts = open_link(emulator.url, ["C1", "C2"], LockstepClock(), {"timeout_s": 0.2, "retries": 3,
                                                                   "reconnect_delay_s": 0.01})
    link = acts[0].link
    try:
        boot = link.map.info["boot_id"]
        assert boot.words == 2 and link.boot_id is not None
        client_class = type(link.client)
        real = client_class.read_holding_registers
        left = {"drop": 1, "short": 1}

        def read(self, address, count=1, **kwargs):
            if left["drop"]:  # the request in flight: the link drops
                left["drop"] -= 1
                raise ConnectionException("link dropped")
            if address == boot.address and left["short"]:  # the boot id read after the reconnection
                left["short"] -= 1
                return real(self, address, count=1, **kwargs)  # one register where two were asked
            return real(self, address, count=count, **kwargs)

        monkeypatch.setattr(client_class, "read_holding_registers", read)
        rr = link.request("read_holding_registers", boot.address, count=boot.words, what="read of the boot id")
        assert len(rr.registers) == boot.words and left == {"drop": 0, "short": 0}
        assert link.reconnects == 2  # the short reply cost one attempt
    finally:
        monkeypatch.undo()
        link.close()
