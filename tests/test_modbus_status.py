"""The status block of a Modbus controller read two ways (docs/modbus.md): taken by the cyclic
exchange (the feedback, with the lockstep check) or looked at only (the hold read-back)."""

from __future__ import annotations

import contextlib

import pytest

from hsio.clock import LockstepClock
from hsio.commands.emulate import bank_from_config
from hsio.drivers import modbus_map
from hsio.drivers.modbus import open_link
from hsio.emulators.modbus import ModbusEmulator
from hsio.errors import CommunicationError
from wire import write_config


def test_a_look_at_the_status_decodes_what_the_exchange_takes_and_leaves_it(tmp_path):
    emu = ModbusEmulator(bank_from_config(write_config(tmp_path), lockstep=True), modbus_map.load()).start()
    try:
        clock = LockstepClock()
        acts = open_link(emu.url, ["C1", "C2"], clock)
        link = acts[0].link
        for _ in range(40):
            acts[0].command(0.5)
            acts[1].command(-0.25)
            clock.tick()
        taken, fresh = [dict(st) for st in link.status], list(link.fresh)
        assert taken[0]["sequence"] == link.ticks and taken[0]["displacement"] > 0 > taken[1]["displacement"]
        # The controller steps only when told to (lockstep): a second read finds the same block.
        assert link.peek_status() == taken
        assert link.status == taken and link.fresh == fresh  # a look only
        link.read_status()
        assert link.status == taken and link.fresh == [True, True]
        link.ticks += 1  # the host a tick ahead of the controller: lockstep lost
        with pytest.raises(CommunicationError, match="lockstep lost"):
            link.read_status()
        assert link.peek_status() == taken  # the look makes no check of the sequence
    finally:
        emu.stop()


@contextlib.contextmanager
def flag_on_demand(tmp_path, axis: int, flag: str, value, read: bool):
    """A lockstep Modbus emulator whose axis ``axis`` shows status ``flag`` = ``value`` while the
    yielded switch is on; yields (switch, period, actuators C1 and C2): ``period(x)`` commands x
    to both, ticks, and (``read``) reads both back."""
    emu = ModbusEmulator(bank_from_config(write_config(tmp_path), lockstep=True), modbus_map.load()).start()
    flags, switch = emu.bank.flags, {"on": False}
    emu.bank.flags = lambda k: {**flags(k), flag: value} if k == axis and switch["on"] else flags(k)
    try:
        clock = LockstepClock()
        acts = open_link(emu.url, ["C1", "C2"], clock)

        def period(x):
            for a in acts:
                a.command(x)
            clock.tick()
            if read:
                for a in acts:
                    a.feedback()

        yield switch, period, acts
    finally:
        emu.stop()


def test_an_axis_that_stops_following_without_a_latch_bit_stops_the_run(tmp_path):
    """A controller that clears an axis' enabled bit on its own (a stop at its panel, hydraulics
    off) with neither the interlock nor the watchdog bit set: the next command stops with an
    InterlockError naming the actuator. An axis the host held and enables again (a pause) is
    not taken for one: its enabled bit is awaited afresh."""
    from hsio.errors import InterlockError

    with flag_on_demand(tmp_path, 1, "enabled", False, read=True) as (dropped, period, acts):
        for _ in range(10):
            period(0.1)
        for a in acts:  # a pause: held, then enabled again, the bit shown one exchange later
            a.hold()
        dropped["on"] = True
        period(0.1)
        dropped["on"] = False
        for _ in range(10):
            period(0.1)
        dropped["on"] = True
        with pytest.raises(InterlockError, match=r"actuator 'C2' .*no longer follows the commands"):
            for _ in range(10):
                period(0.1)


def test_a_restart_is_seen_in_the_sequence_register_without_a_boot_id(tmp_path):
    """A lab map without the boot_id register: a controller that restarts in real time is told by
    its sequence register going back (a counter wraps only forwards), and the run stops with
    ControllerRestartedError instead of re-enabling a controller whose state was lost."""
    from hsio.clock import RealTimeClock
    from hsio.emulators.faults import parse
    from hsio.errors import ControllerRestartedError
    from wire import QUIET_SENSORS

    text = "\n".join(line for line in modbus_map.DEFAULT_MAP.read_text().splitlines() if not line.startswith("boot_id"))
    path = tmp_path / "no_boot_id.toml"
    path.write_text(text)
    regmap = modbus_map.load(path)
    assert "boot_id" not in regmap.info
    bank = bank_from_config(write_config(tmp_path, extra=QUIET_SENSORS), lockstep=False)
    emu = ModbusEmulator(bank, regmap, faults=parse("restart@300")).start()
    try:
        clock = RealTimeClock()
        acts = open_link(emu.url, ["C1", "C2"], clock, {"map": str(path), "timeout_s": 0.1})
        with pytest.raises(ControllerRestartedError, match="sequence register went back"):
            for _ in range(3000):
                for a in acts:
                    a.command(0.5)
                clock.tick()
                [a.feedback() for a in acts]
        assert bank.restarts == 1
    finally:
        emu.stop()


def test_a_command_the_controller_refuses_by_its_status_bit_stops_the_run(tmp_path):
    """A controller that refuses a command by setting its refused bit (no exception response):
    the axis goes on with an older command, so the next command stops with an InterlockError
    naming the actuator, instead of the run going on until the following error is caught."""
    from hsio.errors import InterlockError

    with flag_on_demand(tmp_path, 0, "refused", True, read=False) as (refusing, period, _):
        for _ in range(10):
            period(0.1)
        refusing["on"] = True
        period(0.1)  # the status of this exchange shows the refusal
        with pytest.raises(InterlockError, match=r"actuator 'C1' .*refused the last command"):
            period(0.1)


@pytest.mark.parametrize("garbled", [float("nan"), float("inf"), -1.0, 2.5])
def test_a_status_word_that_is_not_a_bit_field_is_a_named_communication_error(tmp_path, garbled):
    """A float32 status word that reads NaN, infinite, negative or fractional (a garbled reply, a
    map with the wrong type) names the axis and the value, on the cyclic read and on the hold
    read-back alike, rather than failing inside the bit test."""
    emu = ModbusEmulator(bank_from_config(write_config(tmp_path), lockstep=True), modbus_map.load()).start()
    value, bad = emu.context._value, {"on": False}
    emu.context._value = lambda kind, axis, reg: garbled if bad["on"] and axis == 1 and reg.name == "status_word" \
        and kind == "status" else value(kind, axis, reg)
    try:
        clock = LockstepClock()
        acts = open_link(emu.url, ["C1", "C2"], clock)
        bad["on"] = True
        with pytest.raises(CommunicationError, match=r"axis 1: status word .* is not a bit field"):
            for _ in range(3):
                for a in acts:
                    a.command(0.1)
                clock.tick()
        with pytest.raises(CommunicationError, match=r"axis 1: status word .* is not a bit field"):
            acts[0].holding()
    finally:
        emu.stop()
