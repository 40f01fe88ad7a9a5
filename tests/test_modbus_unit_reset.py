"""Modbus: the emulators answer only their unit id and ignore broadcasts (TCP and RTU); the
interlock-reset register and the documented reset procedure (docs/modbus.md)."""

from __future__ import annotations

import pytest
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from hsio.clock import LockstepClock
from hsio.drivers import modbus_map
from hsio.drivers.modbus import ModbusLink, open_link
from hsio.commands.emulate import bank_from_config
from hsio.emulators.modbus import ModbusEmulator
from hsio.errors import InterlockError, ModbusExceptionError
from wire import write_config


@pytest.fixture(params=["tcp", "rtu"])
def emulator(tmp_path, request):
    emu = ModbusEmulator(bank_from_config(write_config(tmp_path), lockstep=True, watchdog_s=0.0), modbus_map.load(),
                         request.param).start()
    yield emu
    emu.stop()


def client_for(emu):
    if emu.transport == "tcp":
        c = ModbusTcpClient("127.0.0.1", port=emu.port, timeout=0.3, retries=0)
    else:
        c = ModbusSerialClient(emu.path, baudrate=emu.baudrate, timeout=0.3, retries=0)
    assert c.connect()
    return c


def test_only_the_unit_id_is_answered(emulator):
    c = client_for(emulator)
    try:
        assert c.read_holding_registers(0, count=2, device_id=1).registers == [16256, 0]
        for other in (2, 17, 247):
            with pytest.raises(Exception):  # no answer: a timeout
                rr = c.read_holding_registers(0, count=2, device_id=other)
                if rr.isError():
                    raise RuntimeError("an error reply")
        assert emulator.context.ignored >= 3
    finally:
        c.close()


def test_broadcast_motion_commands_are_ignored(emulator):
    """A write to unit 0 (broadcast) must not move an axis: enable + a displacement command and
    a clock advance, sent to everyone, change nothing."""
    regmap = emulator.map
    c = client_for(emulator)
    try:
        words = regmap.pack_commands([{"displacement": 5.0, "force": 0.0, "mode": 0.0, "enable": 1.0, "watchdog": 1.0}],
                                     7, regmap.command_span(1, True))
        start = regmap.command_span(1, True)[0]
        try:
            c.write_registers(start, words, device_id=0, no_response_expected=True)
        except Exception:
            pass
        import time

        time.sleep(0.2)
        bank = emulator.bank
        assert bank.ticks == 0 and not bank.axes[0].enabled and bank.controllers[0].command == 0.0
        assert emulator.context.commands[0]["enable"] == 0.0
        assert emulator.context.ignored >= 1  # it did arrive, and was ignored
    finally:
        c.close()


def trip(emu, axis=0):
    c = emu.bank.controllers[axis]
    c.tripped = "displacement 130.000 mm beyond the stroke (+/-127.0 mm)"
    c.hold()


def test_interlock_reset_procedure(tmp_path):
    """docs/modbus.md "Interlock reset": after a trip the run stops with InterlockError; the
    operator removes the cause, the host holds every axis and writes 1 to the reset register;
    then the axes can be enabled again."""
    emu = ModbusEmulator(bank_from_config(write_config(tmp_path), lockstep=True, watchdog_s=0.0), modbus_map.load()).start()
    try:
        clock = LockstepClock()
        actuators = open_link(emu.url, ["C1", "C2"], clock)
        actuators[0].command(0.0)
        actuators[1].command(0.0)
        clock.tick()
        trip(emu)
        actuators[0].command(0.0)
        actuators[1].command(0.0)
        clock.tick()
        with pytest.raises(InterlockError, match="interlock tripped"):
            actuators[0].command(0.0)
        link = actuators[0].link
        # refused while the cause persists (a measurement beyond the stroke)
        emu.bank.controllers[0].measured_displacement = 130.0
        with pytest.raises(ModbusExceptionError) as refused:
            link.reset_interlock()
        assert refused.value.code == 4
        emu.bank.controllers[0].measured_displacement = 0.0
        link.reset_interlock()
        assert not emu.bank.controllers[0].tripped
        assert not any(link.map.bit(st["status_word"], "interlock") for st in link.status)
        link.enable()
        actuators[0].command(0.0)
        actuators[1].command(0.0)
        clock.tick()
        assert emu.bank.axes[0].enabled
        for a in actuators:
            a.close()
    finally:
        emu.stop()


def test_reset_refused_while_an_axis_is_enabled(tmp_path):
    emu = ModbusEmulator(bank_from_config(write_config(tmp_path), lockstep=True, watchdog_s=0.0), modbus_map.load()).start()
    try:
        c = ModbusTcpClient("127.0.0.1", port=emu.port, timeout=0.5, retries=0)
        c.connect()
        emu.bank.axes[0].enabled = True
        reg = emu.map.reset["interlock"]
        rr = c.write_registers(reg.address, emu.map.encode(reg, 1.0), device_id=1)
        assert rr.isError() and rr.exception_code == 4
        rr = c.write_registers(reg.address, emu.map.encode(reg, 2.0), device_id=1)
        assert rr.isError() and rr.exception_code == 3
        c.close()
    finally:
        emu.stop()


def test_typed_errors_carry_the_code(tmp_path):
    """Control flow tests the type and code: a read of an unmapped register is code 2."""
    emu = ModbusEmulator(bank_from_config(write_config(tmp_path), lockstep=True, watchdog_s=0.0), modbus_map.load()).start()
    try:
        link = ModbusLink(emu.url, 1, {})
        link._connect()
        with pytest.raises(ModbusExceptionError) as exc:
            link.request("read_holding_registers", 150, count=2, what="read of nothing")
        assert exc.value.code == 2
        link.close()
    finally:
        emu.stop()


def test_probe_resets_the_interlock(tmp_path):
    from test_emulate_cli import Emulator, hsio

    emu = Emulator("modbus", "--port", 0, "--watchdog-s", "0", write_config(tmp_path))
    try:
        r = hsio("probe", emu.lines["url"], "--reset-interlock", "--json", "--axes", "2", "--requests", "5")
        assert r.returncode == 0, r.stderr
        assert '"interlock_reset": true' in r.stdout
        r = hsio("probe", emu.lines["url"], "--reset-interlock", "--axes", "2", "--requests", "5")
        assert r.returncode == 0, r.stderr
        assert "reset      the latched interlocks are cleared" in r.stdout  # the text report says so too
    finally:
        emu.stop()


def test_an_info_register_that_answers_device_failure_is_not_taken_as_absent(tmp_path):
    """Only exception 2 (illegal data address) means "no such register". A controller that
    answers the boot id with exception 4 (device failure) stops the opening, named, before any
    axis is enabled: taken as absent, the run would go on without restart detection."""
    from pymodbus.constants import ExcCodes

    from hsio.clock import LockstepClock
    from hsio.drivers.modbus import open_link

    emu = ModbusEmulator(bank_from_config(write_config(tmp_path), lockstep=True), modbus_map.load())
    boot = emu.map.info["boot_id"].address
    served = emu.context.async_getValues

    async def failing(device_id, func_code, address, count=1):
        if address == boot:
            return ExcCodes.DEVICE_FAILURE
        return await served(device_id, func_code, address, count)

    emu.context.async_getValues = failing
    emu.start()
    try:
        with pytest.raises(ModbusExceptionError, match=r"read of boot_id answered with Modbus exception 4") as exc:
            open_link(emu.url, ["C1"], LockstepClock())
        assert exc.value.code == 4
        assert not any(a.enabled for a in emu.bank.axes)
    finally:
        emu.stop()
