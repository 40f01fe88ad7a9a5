"""Mode confirmation over Modbus (docs/modbus.md, "Mode confirmation"): after a switch between
displacement and force control, the status word's force_mode bit must show the new mode."""

from __future__ import annotations

import logging

import pytest

from hsio.clock import LockstepClock, RealTimeClock
from hsio.commands.emulate import bank_from_config
from hsio.drivers import modbus_map
from hsio.drivers.modbus import MODE_READS, open_link
from hsio.emulators.modbus import ModbusEmulator
from hsio.errors import InterlockError
from hsio.interfaces import ControlMode
from wire import QUIET_SENSORS, write_config


def periods(clock, acts, n, value=None):
    """n periods: every axis commanded (its present measurement unless ``value``), then read."""
    shown = []
    for _ in range(n):
        for a in acts:
            fb = a.feedback()
            here = fb.force_kN if a.mode is ControlMode.FORCE else fb.displacement_mm
            a.command(here if value is None else value)
        clock.tick()
        if a.link.confirms_mode:
            shown.append([a.link.map.bit(a.link.status[a.axis]["status_word"], "force_mode") for a in acts])
    return shown


def test_an_honest_controller_shows_each_switch_at_the_next_read(tmp_path):
    """The emulator reports the mode its axis runs in: force_mode set from the first read after
    the write that carried force control, clear again after the switch back; the run goes on."""
    emu = ModbusEmulator(bank_from_config(write_config(tmp_path, extra=QUIET_SENSORS), lockstep=True),
                         modbus_map.load()).start()
    try:
        clock = LockstepClock()
        acts = open_link(emu.url, ["C1", "C2"], clock)
        assert periods(clock, acts, 5) == [[False, False]] * 5
        for _ in range(3):
            acts[1].set_mode(ControlMode.FORCE)
            assert periods(clock, acts, 3 * MODE_READS) == [[False, True]] * (3 * MODE_READS)
            assert emu.bank.controllers[1].mode is ControlMode.FORCE
            acts[1].set_mode(ControlMode.DISPLACEMENT)
            assert periods(clock, acts, 3 * MODE_READS) == [[False, False]] * (3 * MODE_READS)
    finally:
        emu.stop()


def test_a_controller_that_ignores_the_switch_stops_the_run_naming_the_axis_and_modes(tmp_path):
    emu = ModbusEmulator(bank_from_config(write_config(tmp_path, extra=QUIET_SENSORS), lockstep=True),
                         modbus_map.load()).start()
    emu.context.ignore_mode.add(1)
    try:
        clock = LockstepClock()
        acts = open_link(emu.url, ["C1", "C2"], clock)
        periods(clock, acts, 5)
        acts[1].set_mode(ControlMode.FORCE)
        with pytest.raises(InterlockError, match=r"actuator 'C2' \(axis 1\) .*force control asked for, but the "
                                                 r"controller reports displacement control .*did not take the mode switch"):
            periods(clock, acts, 3 * MODE_READS)
        assert emu.bank.controllers[1].mode is ControlMode.DISPLACEMENT  # it did ignore it
    finally:
        emu.stop()


def test_the_switch_is_confirmed_within_the_timeout_in_real_time(tmp_path):
    """Real time: a switch the controller ignores stops the run once both MODE_READS reads and
    timeout_s have passed, not at the first read that still shows the old mode."""
    bank = bank_from_config(write_config(tmp_path, extra=QUIET_SENSORS, clock="realtime"), lockstep=False)
    emu = ModbusEmulator(bank, modbus_map.load()).start()
    emu.context.ignore_mode.add(0)
    try:
        clock = RealTimeClock()
        acts = open_link(emu.url, ["C1"], clock, {"timeout_s": 0.5})
        periods(clock, acts, 5)
        acts[0].set_mode(ControlMode.FORCE)
        done = 0
        with pytest.raises(InterlockError, match=r"actuator 'C1' \(axis 0\) .*force control asked for"):
            for done in range(1, 2000):
                periods(clock, acts, 1)
        # Not after MODE_READS reads (done would be MODE_READS + 1): after 0.5 s, about 500 periods at
        # 1024 Hz, far more than 4 x MODE_READS even on a machine slowed down several times.
        assert done > 4 * MODE_READS
    finally:
        emu.stop()


def test_a_map_without_a_force_mode_bit_loads_and_says_once_that_the_mode_is_not_confirmed(tmp_path, caplog):
    text = "\n".join(line for line in modbus_map.DEFAULT_MAP.read_text().splitlines()
                     if not line.startswith("force_mode"))
    path = tmp_path / "no_force_mode.toml"
    path.write_text(text)
    regmap = modbus_map.load(path)
    assert "force_mode" not in regmap.bits
    emu = ModbusEmulator(bank_from_config(write_config(tmp_path, extra=QUIET_SENSORS), lockstep=True), regmap).start()
    emu.context.ignore_mode.add(0)
    try:
        clock = LockstepClock()
        with caplog.at_level(logging.WARNING, logger="hsio.drivers.modbus"):
            acts = open_link(emu.url, ["C1"], clock, {"map": str(path)})
            acts[0].set_mode(ControlMode.FORCE)
            periods(clock, acts, 3 * MODE_READS)  # not checked: the run goes on
            assert emu.bank.controllers[0].mode is ControlMode.DISPLACEMENT
        said = [r.getMessage() for r in caplog.records if "force_mode" in r.getMessage()]
        assert len(said) == 1 and "not confirmed" in said[0]
    finally:
        emu.stop()


def test_a_mixed_run_whose_controller_ignores_the_switch_stops_with_its_steps_and_the_axes_holding(tmp_path):
    """Through hsio run's pipeline: the wall's switch to force control is not taken, the run
    stops at that switch with the steps so far recorded, and every axis holds."""
    from test_force_control_wire import mixed_config
    from wire import run

    from hsio.experiment import ExperimentStopped

    cfg = mixed_config(tmp_path)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load()).start()
    emu.context.ignore_mode.update(range(len(emu.bank.controllers)))
    try:
        result, recorded = run(cfg, tmp_path / "wire", url=emu.url)
        assert isinstance(result, ExperimentStopped)
        assert "did not take the mode switch" in str(result)
        assert len(recorded.steps["step"]) == result.result.steps > 0
        assert all(c.holding and c.mode is ControlMode.DISPLACEMENT for c in emu.bank.controllers)
    finally:
        emu.stop()
