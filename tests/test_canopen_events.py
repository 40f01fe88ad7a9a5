"""CANopen drive events the run must weigh (docs/canopen.md, "EMCY" and "Mode confirmation"):
a warning EMCY from a drive that stays enabled, an EMCY with the drive in fault, and a switch of
the mode of operation the drive does not take."""

from __future__ import annotations

import itertools
import logging
import time

import pytest

from hsio.clock import LockstepClock
from hsio.commands.emulate import bank_from_config
from hsio.drivers import canopen_od as cod
from hsio.drivers.canopen import open_link, parse_url
from hsio.emulators.canopen import FAULT, CanopenEmulator
from hsio.errors import ConfigError, InterlockError
from hsio.interfaces import ControlMode
from wire import QUIET_SENSORS, write_config

_channels = itertools.count()


@pytest.fixture
def drive(tmp_path):
    emu = CanopenEmulator(bank_from_config(write_config(tmp_path, extra=QUIET_SENSORS), lockstep=True),
                          f"hsio-events-{next(_channels)}").start()
    yield emu
    emu.stop()


def until(condition, what: str, timeout_s: float = 10.0) -> None:
    """Wait, bounded, for a frame on the virtual bus to have been taken in (``condition``)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"{what}: not received within {timeout_s} s"
        time.sleep(0.002)


def periods(clock, acts, n):
    for _ in range(n):
        for a in acts:
            fb = a.feedback()
            a.command(fb.force_kN if a.mode is ControlMode.FORCE else fb.displacement_mm)
        clock.tick()


def test_a_warning_emcy_from_a_drive_that_stays_enabled_is_printed_once_and_the_run_goes_on(drive, caplog):
    clock = LockstepClock()
    acts = open_link(drive.url, ["C1", "C2"], clock)
    try:
        periods(clock, acts, 5)
        node = acts[1].link.drives[1]
        asked, sdo_read = [], node.sdo_read
        node.sdo_read = lambda index, *args, **kw: asked.append(index) or sdo_read(index, *args, **kw)
        with caplog.at_level(logging.WARNING, logger="hsio.drivers.canopen"):
            for _ in range(3):
                drive.axes[1].warn(0x4210)
                until(lambda: node.emcy, "the warning EMCY")
                periods(clock, acts, 5)
        assert node.warnings == {0x4210: 3}
        assert asked.count(0x6041) == 1  # the statusword by SDO at the first EMCY only; then the cyclic one
        said = [r.getMessage() for r in caplog.records if "EMCY 0x4210" in r.getMessage()]
        assert len(said) == 1 and "node 2" in said[0] and "temperature" in said[0] and "the run goes on" in said[0]
        assert drive.axes[1].statusword() & 0x6F == 0x27  # it did stay enabled
    finally:
        for a in acts:
            a.close()


def test_a_warning_class_emcy_from_a_drive_in_fault_stops_the_run(drive):
    clock = LockstepClock()
    acts = open_link(drive.url, ["C1", "C2"], clock)
    try:
        periods(clock, acts, 5)
        axis = drive.axes[0]
        with drive.bank.lock:
            axis.state = FAULT  # an over-temperature trip: the drive faults, then tells why
            axis.apply_targets()
        axis.node.emcy.send(0x4310, 0x09, b"\0" * 5)
        until(lambda: acts[0].link.drives[0].emcy, "the EMCY")
        with pytest.raises(InterlockError, match=r"node 1: EMCY 0x4310 \(Temperature\)"):
            periods(clock, acts, 5)
    finally:
        acts[0].link.close()


def test_an_emcy_outside_the_warning_classes_stops_the_run_even_with_the_drive_enabled(drive):
    clock = LockstepClock()
    acts = open_link(drive.url, ["C1"], clock)
    try:
        periods(clock, acts, 5)
        drive.axes[0].warn(0x3210)  # over-voltage, the drive still enabled: not a warning class
        until(lambda: acts[0].link.drives[0].emcy, "the EMCY")
        with pytest.raises(InterlockError, match=r"node 1: EMCY 0x3210 \(Voltage\)"):
            periods(clock, acts, 5)
    finally:
        acts[0].link.close()


def test_a_lab_lists_its_drive_s_own_warning_codes(drive):
    clock = LockstepClock()
    acts = open_link(drive.url, ["C1"], clock, {"emcy_warnings": "0xFF01, 0x3210"})
    try:
        drive.axes[0].warn(0xFF01)
        drive.axes[0].warn(0x3210)
        until(lambda: len(acts[0].link.drives[0].emcy) == 2, "both EMCYs")
        periods(clock, acts, 5)
        assert acts[0].link.drives[0].warnings == {0xFF01: 1, 0x3210: 1}
    finally:
        for a in acts:
            a.close()
    for bad in ("0x0000", "warm", "0x10000"):
        with pytest.raises(ConfigError, match="emcy_warnings"):
            parse_url("canopen+virtual://x/1", {"emcy_warnings": bad})


def test_a_drive_that_ignores_the_mode_switch_stops_the_run_naming_the_actuator_and_modes(drive):
    drive.ignore_mode.add(1)
    clock = LockstepClock()
    acts = open_link(drive.url, ["C1", "C2"], clock, {"timeout_s": 0.1})
    try:
        periods(clock, acts, 5)
        acts[0].set_mode(ControlMode.FORCE)  # an honest drive: taken
        assert acts[0].link.drives[0].sdo_read(0x6061) == cod.CST
        periods(clock, acts, 5)
        with pytest.raises(InterlockError, match=r"actuator 'C2' .* node 2: force control \(10 \(CYCLIC SYNCHRONOUS "
                                                 r"TORQUE\)\) asked for, but the mode display 0x6061 shows 8 "
                                                 r"\(CYCLIC SYNCHRONOUS POSITION\)"):
            acts[1].set_mode(ControlMode.FORCE)
    finally:
        acts[0].link.close()


def test_a_drive_that_changes_its_mode_on_its_own_stops_the_next_period(drive):
    clock = LockstepClock()
    acts = open_link(drive.url, ["C1"], clock)
    try:
        periods(clock, acts, 5)
        axis = drive.axes[0]
        with drive.bank.lock:
            axis.mode = cod.CST  # switched by its panel or another master
        axis.send_tpdo1()
        until(lambda: acts[0].link.drives[0].node.tpdo_values.get(0x6061) == cod.CST, "the TPDO1")
        with pytest.raises(InterlockError, match=r"node 1: mode display 0x6061 shows 10 .* while the driver commands 8"):
            periods(clock, acts, 5)
    finally:
        acts[0].link.close()


def test_a_drive_that_faults_after_a_warning_is_stopped_naming_that_warning(drive):
    """A warning EMCY taken while the drive stayed enabled, then the drive faults with no EMCY of
    its own: the stop names the warning that came before."""
    clock = LockstepClock()
    acts = open_link(drive.url, ["C1"], clock)
    try:
        periods(clock, acts, 5)
        node = acts[0].link.drives[0]
        drive.axes[0].warn(0x4210)
        until(lambda: node.emcy, "the warning EMCY")
        periods(clock, acts, 5)
        assert node.warnings == {0x4210: 1}
        axis = drive.axes[0]
        with drive.bank.lock:
            axis.state = FAULT
            axis.apply_targets()
        axis.send_tpdo1()
        until(lambda: node.node.tpdo_values.get(0x6041, 0x27) & 0x6F != 0x27, "the statusword of the fault")
        with pytest.raises(InterlockError, match=r"node 1 left OPERATION ENABLED .* without an EMCY \(its last EMCY, "
                                                 r"0x4210, [0-9.]+ s earlier, was taken as a warning"):
            periods(clock, acts, 20)
    finally:
        acts[0].link.close()
