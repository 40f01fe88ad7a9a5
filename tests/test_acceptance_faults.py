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

from hsio.commands.emulate import bank_from_config
from hsio.emulators.canopen import slcan_emulator
from hsio.experiment import ExperimentStopped
from wire import QUIET_SENSORS, fault_at, run, write_config


@pytest.fixture
def thread_errors(monkeypatch):
    """Exceptions that ended a thread (python-can's receive thread, say): each would print a
    traceback on the terminal."""
    seen = []
    monkeypatch.setattr(threading, "excepthook", lambda args: seen.append(args.exc_value))
    return seen


def test_can_adapter_lost_mid_run_is_a_named_link_fault(monkeypatch, tmp_path, thread_errors):
    """The SLCAN adapter's TCP link closes a third into a run with no reconnection allowed
    ([driver] retries = 0; tests/test_canopen_reconnect.py makes it again): the run stops as a
    lost link (CommunicationError naming the CAN bus), no thread dies with a traceback, every
    step made before is in the record and the hold is not claimed (nothing answers to read it
    back)."""
    cfg = write_config(tmp_path, duration=0.5, rate=2.0, extra=QUIET_SENSORS)
    emu = slcan_emulator(bank_from_config(cfg, lockstep=True, watchdog_s=5.0), "tcp")
    try:
        trigger = fault_at(monkeypatch, 300, emu.slcan.drop)  # the adapter's TCP link is cut
        result, recorded = run(cfg, tmp_path / "run", url=emu.url, driver={"timeout_s": 0.2, "retries": 0})
    finally:
        emu.stop()  # closes its SLCAN port too
    assert trigger.done
    assert isinstance(result, ExperimentStopped), result
    message = str(result)
    assert "the CAN bus failed" in message and "the adapter or its link is lost" in message, message
    assert "no reconnection: [driver] retries = 0" in message, message
    assert "unexpected" not in message
    assert "confirmed by read-back" not in message
    assert thread_errors == []
    steps = result.result.steps
    assert 5 < steps < 300 // 20 + 2
    assert list(recorded.steps["step"]) == list(range(1, steps + 1))


# --- hsio serve opensees: a client that trickles its bytes ------------------------------------

def trickle(sock, data: bytes, gap_s: float, limit_s: float) -> float | None:
    """Send ``data`` one byte every ``gap_s`` (each gap shorter than the server's timeout) until
    the server closes the connection; the seconds it took, or None if it still listened after
    ``limit_s``."""
    import socket
    import time

    started = time.monotonic()
    for byte in data:
        try:
            sock.sendall(bytes([byte]))
        except OSError:
            return time.monotonic() - started
        sock.settimeout(gap_s)
        try:
            if sock.recv(1) == b"":
                return time.monotonic() - started
        except (TimeoutError, socket.timeout):
            pass
        except OSError:
            return time.monotonic() - started
        if time.monotonic() - started > limit_s:
            return None
    return None


@pytest.fixture
def opensees_server(tmp_path):
    from test_opensees_support import QUIET, serving
    from test_opensees_support import write_config as serve_config

    with serving(serve_config(tmp_path, "validation", ["C1"], extra="timeout_s = 1.0\n" + QUIET)) as server:
        yield server


def test_a_setup_message_trickled_byte_by_byte_is_dropped_in_time(opensees_server):
    """Each byte within the timeout, the whole setup message not: the connection is refused once
    the timeout (here timeout_s = 1 s) is spent, so a few such clients cannot hold the setup
    slots for minutes; a good client is served afterwards."""
    from hsio.opensees import protocol as p
    from test_opensees_support import RawClient, session_over, wait_for

    c = RawClient(opensees_server.ports[0])
    took = trickle(c.sock, p.element_setup(1).encode(), 0.2, limit_s=4.0)
    c.close()
    assert took is not None and took < 2.5, took
    assert wait_for(lambda: any("no setup message within 1 s ([opensees] timeout_s)" in line
                                for line in opensees_server.lines))
    good = RawClient(opensees_server.ports[0])
    good.setup()
    assert 0.3 < good.step(1.0, 0.01) < 0.9
    good.send(p.DIE)
    good.close()
    assert wait_for(lambda: session_over(opensees_server))


def test_a_message_trickled_byte_by_byte_ends_the_session_in_time(opensees_server):
    """After a good step, a message whose bytes come one by one: the session ends after
    timeout_s (the actuators hold, read back), its committed step kept."""
    from hsio.recording import Run
    from test_opensees_support import RawClient, session_over, wait_for

    c = RawClient(opensees_server.ports[0])
    c.setup()
    c.step(0.5, 0.01)
    took = trickle(c.sock, b"\0" * 8 * c.data_size, 0.2, limit_s=4.0)
    c.close()
    assert took is not None and took < 2.5, took
    assert wait_for(lambda: session_over(opensees_server))
    assert opensees_server.lab.hold_message == "the actuators hold (confirmed by read-back)"
    run = Run(Path(opensees_server.lab.settings.out) / "run.sqlite")
    assert run.summary["steps"] == 1 and "silent for 1 s" in run.summary["end"]


# --- the emulated Modbus controller's late reply ----------------------------------------------

def test_a_late_reply_does_not_apply_its_write_late(tmp_path):
    """delay:S holds the reply, not the write (docs/faults.md): a host that gave up on a late
    reply and then told the axis to hold finds it holding; the late write is not applied after
    the hold (it would re-enable the axis towards a stale command)."""
    import time

    from pymodbus.client import ModbusTcpClient
    from pymodbus.exceptions import ModbusException

    from hsio.drivers import modbus_map
    from hsio.emulators.faults import parse
    from hsio.emulators.modbus import ModbusEmulator

    bank = bank_from_config(write_config(tmp_path), lockstep=True, watchdog_s=0.0)
    emu = ModbusEmulator(bank, modbus_map.load(), faults=parse("delay@0:0.8")).start()
    regmap = emu.map
    enable = regmap.command.registers["enable"]
    address = regmap.command.address(0, "enable")
    clients = [ModbusTcpClient("127.0.0.1", port=emu.port, timeout=0.2, retries=0) for _ in range(2)]
    try:
        late, host = clients
        late.connect()
        try:  # the first request: its reply comes 0.8 s late, after the client's 0.2 s
            reply = late.write_registers(address, regmap.encode(enable, 1.0), device_id=regmap.device_id)
            assert reply.isError()
        except ModbusException:
            pass
        late.close()
        host.connect()
        assert not host.write_registers(address, regmap.encode(enable, 0.0), device_id=regmap.device_id).isError()
        time.sleep(1.0)  # the late reply is long due
        flags = bank.flags(0)
        assert flags["holding"] and not flags["enabled"], flags
    finally:
        for c in clients:
            c.close()
        emu.stop()


def test_a_stuck_transducer_lasts_whole_ticks():
    """stuck:N counts controller ticks: a fraction is refused by name (0.5 would have frozen the
    reading for no tick at all, a fault counted as injected that did nothing)."""
    from hsio.emulators.faults import parse
    from hsio.errors import ConfigError

    with pytest.raises(ConfigError, match=r"'stuck@100:0\.5': '0\.5' is not a whole number"):
        parse("stuck@100:0.5")
    schedule = parse("stuck@100:3")
    schedule.due(100)  # falls due: armed for the bank
    readings = [schedule.measured(0, tick, float(tick)) for tick in range(100, 105)]
    assert readings == [100.0, 100.0, 100.0, 103.0, 104.0]


def test_a_server_started_again_on_its_records_folder_goes_on_numbering(tmp_path):
    """The records of an earlier server (run.sqlite, run-2.sqlite) and a journal left beside a
    missing run-3.sqlite: the first client of a new server is served, its session recorded in
    run-4.sqlite, the earlier files untouched."""
    from hsio.recording import Run
    from test_opensees_support import QUIET, one_step_session, serving
    from test_opensees_support import write_config as serve_config

    config = serve_config(tmp_path, "validation", ["C1"], extra="timeout_s = 2.0\n" + QUIET)
    records = tmp_path / "records"
    records.mkdir()
    earlier = {name: f"earlier {name}".encode() for name in ("run.sqlite", "run-2.sqlite", "run-3.sqlite-wal")}
    for name, content in earlier.items():
        (records / name).write_bytes(content)
    with serving(config) as server:
        one_step_session(server)
        assert not any("cannot open" in line for line in server.lines), server.lines
    assert Run(records / "run-4.sqlite").summary["steps"] == 1
    assert not (records / "run-3.sqlite").exists()
    assert {name: (records / name).read_bytes() for name in earlier} == earlier


def test_a_controller_gone_between_sessions_is_not_reported_holding(tmp_path):
    """A session over Modbus ends with the hold read back; the controller then goes away and the
    next client's session cannot open the actuators. The server goes on listening, and what it
    says of the hold (its stop line) does not claim the earlier session's read-back."""
    from hsio.drivers import modbus_map
    from hsio.emulators.modbus import ModbusEmulator
    from test_opensees_support import QUIET, RawClient, one_step_session, serving, wait_for
    from test_opensees_support import write_config as serve_config

    emu = ModbusEmulator(bank_from_config(write_config(tmp_path), lockstep=True, watchdog_s=5.0),
                         modbus_map.load()).start()
    hardware = f'[hardware]\nclock = "lockstep"\nurl = "{emu.url}"\n[driver]\ntimeout_s = 0.2\nretries = 1\n'
    config = serve_config(tmp_path, "validation", ["C1"], extra="timeout_s = 2.0\n" + QUIET + hardware)
    try:
        with serving(config) as server:
            one_step_session(server)
            assert server.lab.hold_message == "the actuators hold (confirmed by read-back)"
            emu.stop()
            late = RawClient(server.ports[0])
            late.setup()
            assert late.answered_as_stopped(pending=False)  # no session: NaN to every request, closed on DIE
            late.close()
            assert wait_for(lambda: any("cannot open the actuators" in line for line in server.lines))
            assert "confirmed" not in server.lab.hold_message
            assert server.lab.hold_message.startswith("the hold could not be read back: opening the actuators")
    finally:
        emu.stop()
