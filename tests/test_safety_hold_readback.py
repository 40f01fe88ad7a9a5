"""The hold read back over the wire (docs/safety.md section 3): Modbus from the controller's
status word (holding bit set, enabled bit clear), CANopen from the statusword 0x6041. "The
actuators hold" is said only when the controller says so; an axis that another client puts
back into motion after the hold is reported as not holding."""

from __future__ import annotations

import contextlib
import struct
import time

import can
import pytest
from pymodbus.client import ModbusTcpClient

from hsio.clock import LockstepClock, RealTimeClock
from hsio.commands.emulate import bank_from_config
from hsio.drivers import canopen as canopen_driver
from hsio.drivers import modbus_map
from hsio.drivers.modbus import open_link as open_modbus
from hsio.emulators.canopen import CanopenEmulator
from hsio.emulators.faults import parse as parse_faults
from hsio.emulators.modbus import ModbusEmulator
from hsio.experiment import ExperimentStopped
from hsio.safety.hold import read_back
from wire import QUIET_SENSORS, run, write_config

_channels = iter(range(10**6))


def command_a_while(actuators, clock, value=0.5, periods=40):
    for _ in range(periods):
        for a in actuators:
            a.command(value)
        clock.tick()
        actuators[0].feedback()


@contextlib.contextmanager
def held_over_modbus(tmp_path):
    """A real-time Modbus emulator and its two actuators, commanded a while (following, checked)
    and then held: yields (emulator, actuators)."""
    cfg = write_config(tmp_path, clock="realtime")
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=False, watchdog_s=0), modbus_map.load()).start()
    try:
        clock = RealTimeClock()
        actuators = open_modbus(emu.url, ["C1", "C2"], clock)
        command_a_while(actuators, clock)
        assert [a.holding() for a in actuators] == [False, False]  # enabled, following
        for a in actuators:
            a.hold()
        yield emu, actuators
        for a in actuators:
            a.close()
    finally:
        emu.stop()


def test_modbus_hold_is_read_back_from_the_status_word(tmp_path):
    with held_over_modbus(tmp_path) as (emu, actuators):
        report = read_back(actuators)
        assert report.confirmed and report.message == "the actuators hold (confirmed by read-back)"
        # Another client enables axis 0 again (enable register of axis 0: 18 + 6): the read-back
        # says so, and the message is a warning, not a hold.
        other = ModbusTcpClient("127.0.0.1", port=emu.port)
        assert other.connect()
        assert not other.write_registers(24, other.convert_to_registers(1.0, other.DATATYPE.FLOAT32),
                                         device_id=1).isError()
        other.close()
        report = read_back(actuators)
        assert report.states == {"C1": False, "C2": True} and not report.confirmed
        assert "WARNING: C1 did not confirm the hold" in report.message


@pytest.mark.parametrize("word, mode, holds", [
    (0x1237, 8, False),  # operation enabled, cyclic synchronous position, bit 12 set: follows its targets
    (0x0237, 8, True),  # operation enabled, bit 12 clear: halted, holding
    (0x1237, 10, False),  # cyclic synchronous torque: the same meaning of bit 12
    (0x0237, 10, True),
    (0x1237, 1, None),  # profile position: bit 12 is set-point acknowledge, cannot tell
    (0x0237, 1, None),
    (0x0237, None, None),  # mode unknown
    (0x0233, 1, True),  # switched on (any mode)
    (0x0207, 1, True),  # quick stop active
    (0x0208, 1, True),  # fault
    (0x0240, 8, None),  # switch on disabled: power stage off, cannot tell
    (0x0231, 8, None),  # ready to switch on
    (0x0200, 8, None),  # not ready to switch on
])
def test_cia402_statusword_read_back(word, mode, holds):
    assert canopen_driver.statusword_holds(word, mode) is holds


class ObjectsByIndex:
    """A drive whose SDO reads answer from a table (index -> value), counting the reads."""

    def __init__(self, objects: dict):
        self.objects, self.reads = objects, []

    def sdo_read(self, index, sub=0, what=""):
        self.reads.append(index)
        return self.objects[index]


@pytest.mark.parametrize("objects, holds, reads", [
    ({0x6041: 0x0237, 0x6061: 8}, True, [0x6041, 0x6061]),
    ({0x6041: 0x1237, 0x6061: 1}, None, [0x6041, 0x6061]),  # profile position: set-point acknowledged
    ({0x6041: 0x0237, 0x6061: 1}, None, [0x6041, 0x6061]),
    ({0x6041: 0x0233}, True, [0x6041]),  # switched on: the mode does not matter, not read
])
def test_canopen_holding_reads_the_mode_while_operation_is_enabled(objects, holds, reads):
    actuator = canopen_driver.CanopenActuator.__new__(canopen_driver.CanopenActuator)
    actuator.drive = ObjectsByIndex(objects)
    assert actuator.holding() is holds and actuator.drive.reads == reads


def test_modbus_hold_read_back_leaves_the_cyclic_status_alone(tmp_path):
    """The read-back is a read of its own: the next feedback() reads the controller again (it
    does not return the read-back's status, older by then)."""
    with held_over_modbus(tmp_path) as (emu, actuators):
        a = actuators[0]
        a.feedback()
        assert a.holding() is True
        time.sleep(0.05)  # the controller's clock runs on
        with emu.bank.lock:
            ticks = emu.bank.ticks
        assert a.feedback().time_s * a.link.rate_hz >= ticks  # read after `ticks`, not at the read-back


def test_modbus_hold_read_back_after_lockstep_was_lost(tmp_path):
    """A lockstep exchange that failed half way (the host's tick count one ahead of the
    controller's, as after a trip) does not stop the read-back: the controller holds, and says so."""
    cfg = write_config(tmp_path, extra=QUIET_SENSORS)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load()).start()
    try:
        clock = LockstepClock()
        actuators = open_modbus(emu.url, ["C1", "C2"], clock)
        command_a_while(actuators, clock)
        for a in actuators:
            a.hold()
        actuators[0].link.ticks += 1
        report = read_back(actuators)
        assert report.confirmed, report.message
        for a in actuators:
            a.close()
    finally:
        emu.stop()


def test_canopen_hold_is_read_back_from_the_statusword(tmp_path):
    cfg = write_config(tmp_path, clock="realtime")
    channel = f"hsio-hold-{next(_channels)}"
    emu = CanopenEmulator(bank_from_config(cfg, lockstep=False, watchdog_s=0), channel).start()
    try:
        clock = RealTimeClock()
        actuators = canopen_driver.open_link(emu.url, ["C1", "C2"], clock)
        command_a_while(actuators, clock)
        assert [a.holding() for a in actuators] == [False, False]
        for a in actuators:
            a.hold()
        report = read_back(actuators)
        assert report.confirmed, report.message
        # Another node on the bus sends node 1 a controlword without halt (RPDO1): it follows again.
        with can.Bus(interface="virtual", channel=channel) as bus:
            bus.send(can.Message(arbitration_id=0x201, data=struct.pack("<Hb", 0x000F, 8), is_extended_id=False))
            deadline = time.monotonic() + 2.0
            while actuators[0].holding() and time.monotonic() < deadline:
                time.sleep(0.01)
        report = read_back(actuators)
        assert report.states == {"C1": False, "C2": True}
        assert "WARNING: C1 did not confirm the hold" in report.message
        for a in actuators:
            a.close()
    finally:
        emu.stop()


@pytest.mark.parametrize("protocol", ["modbus", "canopen"])
def test_after_a_trip_the_hold_is_confirmed_over_the_wire(tmp_path, protocol):
    """A servo-valve failure trips the controller mid-run: the run stops, and the message says
    the actuators hold because the controller read back so."""
    cfg = write_config(tmp_path, duration=0.6, extra=QUIET_SENSORS)
    bank = bank_from_config(cfg, lockstep=True)
    faults = parse_faults("valve@300")
    if protocol == "modbus":
        emu = ModbusEmulator(bank, modbus_map.load(), faults=faults).start()
    else:
        emu = CanopenEmulator(bank, f"hsio-hold-{next(_channels)}", faults=faults).start()
    try:
        result, recorded = run(cfg, tmp_path / "o", url=emu.url)
    finally:
        emu.stop()
    assert isinstance(result, ExperimentStopped), result
    assert "the actuators hold (confirmed by read-back)" in str(result), str(result)
    assert 0 < len(recorded.steps["step"]) < 60


def test_hsio_serve_says_the_actuators_hold_only_when_read_back(tmp_path):
    """`hsio serve opensees` over Modbus TCP: the session's end reads the hold back."""
    from hsio.opensees import protocol as p
    from test_opensees_support import RawClient, serving, session_over, wait_for
    from test_opensees_support import write_config as serve_config

    emu = ModbusEmulator(bank_from_config(write_config(tmp_path, duration=0.3), lockstep=True), modbus_map.load()).start()
    try:
        config = serve_config(tmp_path, "validation", ["C1"],
                              extra=f'[hardware]\nurl = "{emu.url}"\nclock = "lockstep"\n')
        with serving(config) as server:
            c = RawClient(server.ports[0])
            try:
                c.setup()
                c.step(0.5, 0.01)
                c.send(p.DIE)
            finally:
                c.close()
            assert wait_for(lambda: session_over(server))
            assert server.lab.hold_message == "the actuators hold (confirmed by read-back)", server.lines
            assert any(line.endswith("the actuators hold (confirmed by read-back)") for line in server.lines)
    finally:
        emu.stop()
