"""Opening a controller over Modbus or CANopen: the limits come from [driver] or the controller,
never from a guess; the clock is checked before any axis is enabled; a failure while opening
leaves every axis holding; bad [driver] options are refused by name."""

from __future__ import annotations

import logging
import struct

import itertools

import pytest

from hsio.drivers import modbus_map
from hsio.drivers.canopen import CanopenLink
from hsio.drivers.canopen import open_link as canopen_open
from hsio.drivers.modbus import ModbusLink
from hsio.drivers.modbus import open_link as modbus_open
from hsio.commands.emulate import bank_from_config
from hsio.emulators.canopen import OE, CanopenEmulator
from hsio.emulators.modbus import ModbusEmulator
from hsio.clock import LockstepClock, RealTimeClock
from hsio.errors import CommunicationError, ConfigError, LimitError
from wire import write_config

_channels = itertools.count()
NAMES = ["C1", "C2"]
# Limits unlike any default, so that a limit read from the controller cannot pass for a guess.
EMULATOR_LIMITS = "[emulator]\nstroke_mm = 100.0\nforce_limit_kN = 40.0\n"


@pytest.fixture
def cfg(tmp_path):
    return write_config(tmp_path, duration=0.5, extra=EMULATOR_LIMITS)


def canopen_emulator(cfg, **kwargs) -> CanopenEmulator:
    bank = bank_from_config(cfg, lockstep=True, watchdog_s=0)
    return CanopenEmulator(bank, f"hsio-open-{next(_channels)}", **kwargs).start()


def none_enabled(bank) -> bool:
    return all(not bank.flags(k)["enabled"] and bank.controllers[k].holding for k in range(len(bank.controllers)))


def close_all(actuators) -> None:
    for a in actuators:
        a.close()


# -- Modbus ----------------------------------------------------------------------------------------

def test_modbus_limits_are_the_controllers_own(cfg):
    with ModbusEmulator(bank_from_config(cfg, lockstep=True, watchdog_s=0), modbus_map.load()) as emu:
        acts = modbus_open(emu.url, NAMES, LockstepClock())
        try:
            assert (acts[0].limits.stroke_mm, acts[0].limits.force_kN) == (100.0, 40.0)
            with pytest.raises(LimitError, match="beyond the stroke"):
                acts[0].command(50.5)
        finally:
            close_all(acts)


def test_modbus_map_without_limits_needs_them_configured(tmp_path, cfg):
    """A lab map without the stroke and capacity registers: each must come from [driver]."""
    text = "\n".join(line for line in modbus_map.DEFAULT_MAP.read_text().splitlines()
                     if not line.startswith(("stroke_mm ", "force_limit_kN ")))
    path = tmp_path / "lab.toml"
    path.write_text(text)
    lab = modbus_map.load(path)
    assert "stroke_mm" not in lab.info and "force_limit_kN" not in lab.info
    with ModbusEmulator(bank_from_config(cfg, lockstep=True, watchdog_s=0), lab) as emu:
        with pytest.raises(ConfigError, match=r"does not report its stroke.*set \[driver\] stroke_mm"):
            modbus_open(emu.url, NAMES, LockstepClock(), {"map": str(path)})
        with pytest.raises(ConfigError, match=r"does not report its force capacity.*set \[driver\] force_kN"):
            modbus_open(emu.url, NAMES, LockstepClock(), {"map": str(path), "stroke_mm": 80})
        assert none_enabled(emu.bank)
        acts = modbus_open(emu.url, NAMES, LockstepClock(), {"map": str(path), "stroke_mm": 80, "force_kN": 30})
        try:
            assert (acts[1].limits.stroke_mm, acts[1].limits.force_kN) == (80.0, 30.0)
        finally:
            close_all(acts)


def test_modbus_clock_mismatch_enables_nothing(cfg):
    with ModbusEmulator(bank_from_config(cfg, lockstep=True, watchdog_s=0), modbus_map.load()) as emu:
        with pytest.raises(ConfigError, match=r"lockstep.*clock = \"lockstep\""):
            modbus_open(emu.url, NAMES, RealTimeClock())
        assert none_enabled(emu.bank)
        assert emu.context.commands[0]["enable"] == 0.0 and emu.context.commands[1]["enable"] == 0.0


def test_lockstep_controller_at_another_loop_rate_is_refused_before_enabling(tmp_path):
    """In lockstep each tick is one period of the controller and of the experiment (1024 Hz): a
    controller whose rate_hz register says 2048 Hz would run its time at half the experiment's.
    Modbus reads the rate and refuses at open, enabling nothing; the CANopen drive has no rate
    object, so its emulator refuses such a lockstep clock itself."""
    cfg = write_config(tmp_path, extra="[emulator]\nrate_hz = 2048\n")
    with ModbusEmulator(bank_from_config(cfg, lockstep=True, watchdog_s=0), modbus_map.load()) as emu:
        with pytest.raises(ConfigError, match=r"lockstep at 2048 Hz .*experiment at 1024 Hz"):
            modbus_open(emu.url, NAMES, LockstepClock())
        assert none_enabled(emu.bank)
    with pytest.raises(ConfigError, match=r"rate_hz = 2048 in lockstep"):
        CanopenEmulator(bank_from_config(cfg, lockstep=True), f"hsio-open-rate-{next(_channels)}")


# -- CANopen -----------------------------------------------------------------------------------------

def test_canopen_limits_are_the_drives_own(cfg):
    emu = canopen_emulator(cfg)
    try:
        acts = canopen_open(emu.url, NAMES, LockstepClock())
        assert (acts[0].limits.stroke_mm, acts[0].limits.force_kN) == (100.0, pytest.approx(40.0))
        close_all(acts)
    finally:
        emu.stop()


def test_canopen_force_capacity_beyond_int16_is_refused_at_open(tmp_path):
    """A drive rated 5 kN carries at most 32767 per mille = 163.835 kN: a capacity of 250 kN
    (the drive's own, or configured as the drive's) is refused at open, by name, and nothing is
    enabled; a capacity within the range, tighter than the drive's, works."""
    cfg = write_config(tmp_path, duration=0.5, extra="[emulator]\nstroke_mm = 100.0\nforce_limit_kN = 250.0\n")
    emu = canopen_emulator(cfg, rated_force_N=5000)
    try:
        with pytest.raises(ConfigError, match=r"force capacity 250 kN \(the max torque 0x6072\).*0x6076.*163.835"):
            canopen_open(emu.url, NAMES, LockstepClock())
        with pytest.raises(ConfigError, match=r"force capacity 250 kN \(\[driver\] force_kN\).*0x6076.*163.835"):
            canopen_open(emu.url, NAMES, LockstepClock(), {"force_kN": 250})
        assert none_enabled(emu.bank) and all(a.state != OE for a in emu.axes)
        clock = LockstepClock()
        acts = canopen_open(emu.url, NAMES, clock, {"force_kN": 150})
        try:
            assert acts[0].drive.rated_N == 5000.0
            assert acts[0].drive.permille(150.0) == 30000
            with pytest.raises(LimitError, match="beyond the int16 range"):
                acts[0].drive.permille(170.0)
        finally:
            close_all(acts)
    finally:
        emu.stop()


def test_canopen_stroke_beyond_the_int32_target_position_is_refused_at_open(cfg):
    """At 1e8 counts per mm the int32 target position 0x607A carries +/-21.47 mm: a 254 mm
    stroke would let a 25 mm command pass the stroke check and fail to encode mid-run. Refused
    at open, naming the object and the reach, before anything is enabled. (A drive that reports
    neither its scaling nor software limits: both come from [driver].)"""
    emu = canopen_emulator(cfg, position_limits_mm=(0.0, 0.0))
    for axis in emu.axes:
        del axis.node.object_dictionary[0x6093]
    try:
        with pytest.raises(ConfigError, match=r"half stroke 127 mm \(\[driver\] stroke_mm\) at 1e\+08 counts per mm "
                                              r"is beyond .*0x607A.*21.4748 mm"):
            canopen_open(emu.url, NAMES, LockstepClock(), {"counts_per_mm": 1e8, "stroke_mm": 254.0})
        assert none_enabled(emu.bank) and all(a.state != OE for a in emu.axes)
    finally:
        emu.stop()


def test_canopen_drive_without_software_limits_needs_stroke_configured(cfg):
    emu = canopen_emulator(cfg, position_limits_mm=(0.0, 0.0))
    try:
        with pytest.raises(ConfigError, match=r"0x607D.*0/0.*set \[driver\] stroke_mm"):
            canopen_open(emu.url, NAMES, LockstepClock())
        assert none_enabled(emu.bank)
        acts = canopen_open(emu.url, NAMES, LockstepClock(), {"stroke_mm": 60})
        assert acts[0].limits.stroke_mm == 60.0
        close_all(acts)
    finally:
        emu.stop()


def test_canopen_asymmetric_software_limits_give_the_smaller_side(cfg):
    """Limits -30..+45 mm: hsio's stroke is centred on zero, so +/-30 mm; 31 mm is refused."""
    emu = canopen_emulator(cfg, position_limits_mm=(-30.0, 45.0))
    try:
        acts = canopen_open(emu.url, NAMES, LockstepClock())
        try:
            assert acts[0].limits.half_stroke_mm == pytest.approx(30.0)
            with pytest.raises(LimitError, match="beyond the stroke"):
                acts[0].command(31.0)
        finally:
            close_all(acts)
    finally:
        emu.stop()
    emu = canopen_emulator(cfg, position_limits_mm=(5.0, 45.0))
    try:
        with pytest.raises(ConfigError, match=r"0x607D 5000\.\.45000 counts do not contain zero"):
            canopen_open(emu.url, NAMES, LockstepClock())
    finally:
        emu.stop()


def test_canopen_clock_mismatch_enables_nothing(cfg):
    emu = canopen_emulator(cfg)
    try:
        with pytest.raises(ConfigError, match=r"clock = \"lockstep\""):
            canopen_open(emu.url, NAMES, RealTimeClock())
        assert none_enabled(emu.bank) and all(a.state != OE for a in emu.axes)
    finally:
        emu.stop()


def test_canopen_failure_part_way_disables_the_drives_already_enabled(cfg):
    """Node 2 fails while being enabled (it lacks 0x6077): node 1, enabled before, is disabled."""
    emu = canopen_emulator(cfg)
    try:
        del emu.axes[1].node.object_dictionary[0x6077]
        with pytest.raises(CommunicationError, match=r"node 2: SDO read of torque actual value.*aborted"):
            canopen_open(emu.url, NAMES, LockstepClock())
        assert emu.axes[0].state != OE and none_enabled(emu.bank)
    finally:
        emu.stop()


# -- [driver] options ---------------------------------------------------------------------------------

BAD_OPTIONS = [
    ("stroke_mm", 0), ("stroke_mm", -5.0), ("stroke_mm", "nan"), ("force_kN", -1), ("force_kN", "inf"),
    ("velocity_mm_s", 0), ("timeout_s", 0), ("timeout_s", 1e6), ("retries", -1), ("retries", 2.5),
    ("retries", 100), ("stroke_mm", True), ("force_kN", "lots"),
]


@pytest.mark.parametrize("key, value", BAD_OPTIONS)
def test_bad_driver_options_are_refused_by_name(key, value):
    for make in (lambda: ModbusLink("modbus+tcp://127.0.0.1:1", 1, {key: value}),
                 lambda: CanopenLink("canopen+virtual://bus/1", 1, {key: value})):
        with pytest.raises(ConfigError, match=rf"\[driver\] for .*: {key} must be"):
            make()


@pytest.mark.parametrize("url, key", [
    ("modbus+tcp://127.0.0.1:1?reconnect_delay_s=-1", "reconnect_delay_s"),
    ("modbus+tcp://127.0.0.1:1?device_id=300", "device_id"),
    ("modbus+tcp://127.0.0.1:1?baudrate=0", "baudrate"),
    ("canopen+virtual://bus/1?heartbeat_ms=70000", "heartbeat_ms"),
    ("canopen+virtual://bus/1?bitrate=5", "bitrate"),
])
def test_bad_driver_options_in_the_url_are_refused_by_name(url, key):
    link = ModbusLink if url.startswith("modbus") else CanopenLink
    with pytest.raises(ConfigError, match=rf"{key} must be"):
        link(url, 1)


# -- configured limits against the controller's ---------------------------------------------------

def test_modbus_configured_limits_wider_than_the_controllers_are_refused_tighter_taken(cfg):
    """The controller reports 100 mm and 40 kN: [driver] stroke_mm = 1000 would make every check
    on the host judge against +/-500 mm, beyond the actuator; refused at open, naming the key
    and both values, nothing enabled. Tighter values are software limits, taken as given."""
    with ModbusEmulator(bank_from_config(cfg, lockstep=True, watchdog_s=0), modbus_map.load()) as emu:
        with pytest.raises(ConfigError, match=r"\[driver\] stroke_mm = 1000 mm is wider than the stroke the controller "
                                              r"reports, 100 mm \(its stroke_mm info register\)"):
            modbus_open(emu.url, NAMES, LockstepClock(), {"stroke_mm": 1000})
        with pytest.raises(ConfigError, match=r"\[driver\] force_kN = 40.5 kN is wider than the force capacity the "
                                              r"controller reports, 40 kN \(its force_limit_kN info register\)"):
            modbus_open(emu.url, NAMES, LockstepClock(), {"stroke_mm": 100, "force_kN": 40.5})
        assert none_enabled(emu.bank)
        acts = modbus_open(emu.url, NAMES, LockstepClock(), {"stroke_mm": 60, "force_kN": 40})
        try:
            assert (acts[0].limits.stroke_mm, acts[0].limits.force_kN) == (60.0, 40.0)
            with pytest.raises(LimitError, match="beyond the stroke"):
                acts[0].command(30.5)  # inside the controller's 50 mm, beyond the configured 30 mm
        finally:
            close_all(acts)


def test_canopen_configured_limits_wider_than_the_drives_are_refused_tighter_taken(cfg):
    """The drive's software position limits 0x607D (+/-50 mm) and max torque 0x6072 (40 kN)
    bound what [driver] may set; asymmetric limits -30..+45 mm bound the stroke to 60 mm."""
    emu = canopen_emulator(cfg)
    try:
        with pytest.raises(ConfigError, match=r"node 1: \[driver\] stroke_mm = 101 mm is wider than the stroke the "
                                              r"controller reports, 100 mm \(its software position limits 0x607D"):
            canopen_open(emu.url, NAMES, LockstepClock(), {"stroke_mm": 101})
        with pytest.raises(ConfigError, match=r"\[driver\] force_kN = 41 kN is wider .* 40 kN \(its max torque 0x6072"):
            canopen_open(emu.url, NAMES, LockstepClock(), {"force_kN": 41})
        assert none_enabled(emu.bank) and all(a.state != OE for a in emu.axes)
        acts = canopen_open(emu.url, NAMES, LockstepClock(), {"stroke_mm": 10, "force_kN": 20})
        try:
            assert (acts[0].limits.stroke_mm, acts[0].limits.force_kN) == (10.0, 20.0)
        finally:
            close_all(acts)
    finally:
        emu.stop()
    emu = canopen_emulator(cfg, position_limits_mm=(-30.0, 45.0))
    try:
        with pytest.raises(ConfigError, match=r"stroke_mm = 70 mm is wider .* 60 mm .*-30\.\.45 mm"):
            canopen_open(emu.url, NAMES, LockstepClock(), {"stroke_mm": 70})
        assert none_enabled(emu.bank)
    finally:
        emu.stop()


def test_canopen_counts_per_mm_configured_is_taken_over_the_drives_position_factor(cfg, caplog):
    """A drive left at the position factor 1/1 (its positions in encoder increments) reports 1
    count per mm: the operator's [driver] counts_per_mm states the rig's 1000, and is taken, the
    difference logged with both figures; the drive's software limits 0x607D (+/-50 000 counts)
    are read with it as +/-50 mm. The same value as the drive's is taken without a word."""
    emu = canopen_emulator(cfg)
    for axis in emu.axes:
        axis.node.data_store.setdefault(0x6093, {})[1] = struct.pack("<I", 1)
    try:
        with caplog.at_level(logging.WARNING, logger="hsio.drivers.canopen"):
            acts = canopen_open(emu.url, NAMES, LockstepClock(), {"counts_per_mm": 1000.0})
        try:
            assert acts[0].drive.counts_per_mm == 1000.0
            assert acts[0].limits.stroke_mm == pytest.approx(100.0)
            assert any("counts_per_mm = 1000 is taken; the drive's position factor 0x6093 (1/1) would give 1 counts "
                       "per mm" in r.getMessage() for r in caplog.records)
        finally:
            close_all(acts)
    finally:
        emu.stop()
    emu = canopen_emulator(cfg)
    try:
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="hsio.drivers.canopen"):
            acts = canopen_open(emu.url, NAMES, LockstepClock(), {"counts_per_mm": 1000.0})
        try:
            assert acts[0].drive.counts_per_mm == 1000.0
            assert not [r for r in caplog.records if "counts_per_mm" in r.getMessage()]
        finally:
            close_all(acts)
    finally:
        emu.stop()


def test_hsio_run_with_a_stroke_wider_than_the_controllers_exits_2_before_anything_moves(tmp_path, cfg):
    """`hsio run` with [driver] stroke_mm = 1000 against a controller that reports 100 mm: exit
    status 2, no traceback, the key and both values named; no axis was ever enabled."""
    import subprocess
    import sys

    with ModbusEmulator(bank_from_config(cfg, lockstep=True, watchdog_s=0), modbus_map.load()) as emu:
        run_cfg = write_config(tmp_path, duration=0.5, name="wide.toml",
                               extra=f'url = "{emu.url}"\n[driver]\nstroke_mm = 1000.0\n')
        proc = subprocess.run([sys.executable, "-m", "hsio.cli", "run", str(run_cfg), "--out", str(tmp_path / "out")],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2, proc.stderr[-2000:]
        assert "Traceback" not in proc.stderr
        assert "[driver] stroke_mm = 1000 mm is wider than the stroke the controller reports, 100 mm" in proc.stderr
        assert none_enabled(emu.bank) and all(c["enable"] == 0.0 for c in emu.context.commands)
