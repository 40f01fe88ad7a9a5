"""Modbus TCP and RTU: the register map, the emulator's server, the driver, hsio run over the wire."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pymodbus.client import ModbusTcpClient

from hsio.drivers import modbus_map
from hsio.drivers.modbus import ModbusLink, open_link
from hsio.commands.emulate import bank_from_config
from hsio.emulators.modbus import ModbusEmulator
from hsio.clock import LockstepClock, RealTimeClock
from hsio.errors import CommunicationError, ConfigError, InterlockError
from wire import QUIET_SENSORS, max_abs_diff, refused_port, run, write_config

FLOAT32_EPS = 2.0 ** -23


@pytest.fixture
def cfg(tmp_path):
    return write_config(tmp_path, duration=1.0)


@pytest.fixture
def tcp_emulator(cfg):
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load()).start()
    yield emu
    emu.stop()


# -- the register map ----------------------------------------------------------------------------

def test_default_map_layout_and_float32_word_order():
    m = modbus_map.load()
    assert m.word_order == "big" and m.readwrite
    reg = m.status.registers["displacement"]
    assert reg.type == "float32" and m.status.address(1, "displacement") == m.status.base + m.status.stride + reg.address
    # 1.5 as IEEE 754 is 0x3FC00000: high word first in "big" order.
    assert m.encode(reg, 1.5) == [0x3FC0, 0x0000]
    assert modbus_map.Register("x", 0).encode(1.5, "little") == [0x0000, 0x3FC0]
    # One contiguous write carries every axis' commands and the clock target.
    start, count = m.command_span(2, with_advance=True)
    assert start == m.lockstep["advance"].address and count == m.command.base + 2 * m.command.stride - start


def test_map_errors_name_the_table_and_register(tmp_path):
    text = modbus_map.DEFAULT_MAP.read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("force        = { offset = 2, type", "force        = { offset = 1, type"))
    with pytest.raises(ConfigError, match=r"bad.toml: \[command\].*overlap"):
        modbus_map.load(bad)
    bad.write_text(text.replace('type = "uint32"', 'type = "uint64"'))
    with pytest.raises(ConfigError, match=r"\[lockstep\].*advance.*type"):
        modbus_map.load(bad)


def _hold_two_axes(url, map_path):
    """Both axes of the emulator at ``url`` (register map ``map_path``) commanded to 0.5 and
    -0.25 mm for 200 lockstep periods; the actuators and their feedback."""
    clock = LockstepClock()
    acts = open_link(url, ["C1", "C2"], clock, {"map": str(map_path)})
    for _ in range(200):
        acts[0].command(0.5)
        acts[1].command(-0.25)
        clock.tick()
    return acts, (acts[0].feedback(), acts[1].feedback())

def test_a_lab_map_with_integer_counts_and_little_word_order(tmp_path, cfg):
    """The map is data: integer registers with scales and the low word first work unchanged."""
    text = modbus_map.DEFAULT_MAP.read_text()
    text = text.replace('word_order = "big"', 'word_order = "little"')
    text = text.replace('displacement = { offset = 0, type = "float32" }', 'displacement = { offset = 0, type = "int32", scale = 1000.0 }')
    text = text.replace('displacement = { offset = 2, type = "float32" }', 'displacement = { offset = 2, type = "int32", scale = 1000.0 }')
    path = tmp_path / "lab.toml"
    path.write_text(text)
    lab = modbus_map.load(path)
    assert lab.encode(lab.command.registers["displacement"], -1.2344) == [(-1234) & 0xFFFF, 0xFFFF]
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), lab).start()
    try:
        acts, fb = _hold_two_axes(emu.url, path)
        # Measured displacement travels as integer micrometres.
        assert fb[0].displacement_mm == pytest.approx(emu.bank.controllers[0].measured_displacement, abs=0.0005)
        assert fb[0].displacement_mm == pytest.approx(0.5, abs=0.05) and fb[1].displacement_mm == pytest.approx(-0.25, abs=0.05)
        assert fb[0].displacement_mm * 1000 == pytest.approx(round(fb[0].displacement_mm * 1000), abs=1e-9)
        for a in acts:
            a.close()
    finally:
        emu.stop()


COMMAND_BLOCK = """displacement = { offset = 0, type = "float32" }  # mm, used in displacement control
force        = { offset = 2, type = "float32" }  # kN, used in force control
mode         = { offset = 4, type = "float32" }  # 0 displacement control, 1 force control
enable       = { offset = 6, type = "float32" }  # 1 follow the command, 0 hold the present position
watchdog     = { offset = 8, type = "float32" }  # host counter, changed at every write"""


def test_a_command_write_that_would_cover_unnamed_registers_is_refused(tmp_path, cfg):
    """The commands go in one write: a gap in the block (int16 values at float32 offsets), a
    stride longer than the block or a register the driver does not know would put 0 into a
    controller register the map does not name (or crash the exchange). Refused with the address,
    at load for one axis and at open for the link's axes, before anything is enabled."""
    text = modbus_map.DEFAULT_MAP.read_text()
    assert COMMAND_BLOCK in text
    bad = tmp_path / "lab.toml"
    bad.write_text(text.replace('offset = 0, type = "float32" }  # mm', 'offset = 0, type = "int16", scale = 100.0 }  # mm'))
    with pytest.raises(ConfigError, match=r"lab.toml: \[command\].*covers address 19, which no register"):
        modbus_map.load(bad)
    bad.write_text(text.replace("max_axes = 8", "max_axes = 2").replace(
        COMMAND_BLOCK, COMMAND_BLOCK + '\nspare = { offset = 10, type = "float32" }').replace(
        "base = 18\nstride = 10", "base = 18\nstride = 12"))
    with pytest.raises(ConfigError, match=r"\[command\]: unknown register\(s\) spare"):
        modbus_map.load(bad)
    padded = text.replace("base = 18\nstride = 10", "base = 18\nstride = 12")
    bad.write_text(padded)
    lab = modbus_map.load(bad)  # one axis: contiguous
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), lab).start()
    try:
        with pytest.raises(ConfigError, match=r"write of 2 axis/axes covers address 28"):
            open_link(emu.url, ["C1", "C2"], LockstepClock(), {"map": str(bad)})
        assert all(c["enable"] == 0.0 for c in emu.context.commands)  # nothing was written
    finally:
        emu.stop()


def test_a_lab_map_with_reserved_status_words_runs_on_the_emulator(tmp_path, cfg):
    """Status blocks with reserved words (a stride longer than the block, a gap between values
    such as int16 values at float32 offsets) are read in one request; the emulator answers the
    reserved words with 0, as a controller does, and the run goes through."""
    text = modbus_map.DEFAULT_MAP.read_text()
    text = text.replace("base = 200\nstride = 8", "base = 200\nstride = 11").replace(
        'displacement = { offset = 2, type = "float32" }', 'displacement = { offset = 2, type = "int16", scale = 100.0 }')
    path = tmp_path / "lab.toml"
    path.write_text(text)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load(path)).start()
    try:
        acts, fb = _hold_two_axes(emu.url, path)
        assert fb[0].displacement_mm == pytest.approx(0.5, abs=0.05) and fb[1].displacement_mm == pytest.approx(-0.25, abs=0.05)
        for a in acts:
            a.close()
    finally:
        emu.stop()


def test_integer_registers_too_narrow_for_the_limits_are_refused_at_open(tmp_path, cfg):
    """An int32 displacement at 1e7 counts/mm carries +/-214.7 mm: with a 1000 mm stroke a command
    of 300 mm passes the stroke check and could not be encoded mid-run. Refused at open, naming
    the table, the register and the range, before anything is enabled (a controller of 1000 mm
    stroke, which [driver] stroke_mm repeats)."""
    text = modbus_map.DEFAULT_MAP.read_text()
    path = tmp_path / "lab.toml"
    long = write_config(tmp_path, name="long.toml", extra="[emulator]\nstroke_mm = 1000.0\n")
    for table, offset, scale in (("command", 0, 1e7), ("status", 2, 1e8)):
        path.write_text(text.replace(f'displacement = {{ offset = {offset}, type = "float32" }}',
                                     f'displacement = {{ offset = {offset}, type = "int32", scale = {scale} }}'))
        emu = ModbusEmulator(bank_from_config(long, lockstep=True), modbus_map.load(path)).start()
        try:
            with pytest.raises(ConfigError, match=rf"\[{table}\] displacement \(int32, scale 1e\+0[78]\) carries "
                                                  r"-21[\d.]+\.\.21[\d.]+ mm, less than the half stroke \+/-500 mm"):
                open_link(emu.url, ["C1", "C2"], LockstepClock(), {"map": str(path), "stroke_mm": 1000.0})
            assert all(c["enable"] == 0.0 for c in emu.context.commands)
        finally:
            emu.stop()
    path.write_text(text.replace("[modes]\ndisplacement = 0", "[modes]\ndisplacement = 40000").replace(
        'mode         = { offset = 4, type = "float32" }', 'mode = { offset = 4, type = "int16" }\n#'))
    with pytest.raises(ConfigError, match=r"\[modes\] displacement = 40000 does not fit the \[command\] mode register"):
        modbus_map.load(path)
    path.write_text(text.replace("lockstep = 6", "lockstep = 15").replace(
        'status_word  = { offset = 0, type = "float32" }', 'status_word = { offset = 0, type = "int16" }\n#'))
    with pytest.raises(ConfigError, match=r"\[status_bits\] lockstep = 15 does not fit the \[status\] status_word register"
                                          r".*type = \"uint16\" to use bit 15"):
        modbus_map.load(path)
    path.write_text(text.replace("lockstep = 6", "lockstep = 15").replace(
        'status_word  = { offset = 0, type = "float32" }', 'status_word = { offset = 0, type = "uint16" }\n#'))
    assert modbus_map.load(path).bits["lockstep"] == 15


def test_sixteen_bit_watchdog_and_sequence_registers_wrap(tmp_path, cfg):
    """A lab map with a uint16 host watchdog counter, an int16 sequence and a uint16 boot id: the
    counter wraps at 65536 and the sequence at 32768, at both ends of the wire, and the lockstep
    check follows; the boot id (for restart detection) is served and read."""
    text = modbus_map.DEFAULT_MAP.read_text()
    text = text.replace('watchdog     = { offset = 8, type = "float32" }', 'watchdog     = { offset = 8, type = "uint16" }\n#')
    text = text.replace("base = 18\nstride = 10", "base = 18\nstride = 9")
    text = text.replace('sequence     = { offset = 6, type = "float32" }', 'sequence     = { offset = 6, type = "int16" }')
    text = text.replace('boot_id        = { address = 6,  type = "float32" }', 'boot_id = { address = 6, type = "uint16" }')
    path = tmp_path / "lab.toml"
    path.write_text(text)
    bank = bank_from_config(cfg, lockstep=True)
    emu = ModbusEmulator(bank, modbus_map.load(path)).start()
    try:
        for tick in (10000, 20000, 30000, 32760):
            bank.advance_to(tick)
        clock = LockstepClock()
        acts = open_link(emu.url, ["C1", "C2"], clock, {"map": str(path)})
        link = acts[0].link
        for c in link.commands:
            c["watchdog"] = 65530.0
        for _ in range(20):
            acts[0].command(0.1)
            acts[1].command(0.0)
            clock.tick()
        assert link.ticks == 32780 and link.status[0]["sequence"] == 12.0
        assert link.boot_id == emu.bank.boot_id % 65536  # a uint16 boot id, served and read
        assert link.commands[0]["watchdog"] == 14.0 and emu.context.commands[0]["watchdog"] == 14.0
        for a in acts:
            a.close()
    finally:
        emu.stop()


# -- hsio run over the wire ----------------------------------------------------------------------

def test_run_over_modbus_tcp_lockstep_equals_in_process(tmp_path):
    """Lockstep: the same run to float32 resolution (commands and measurements cross as float32)."""
    cfg = write_config(tmp_path, duration=1.0, extra=QUIET_SENSORS)
    tcp_emulator = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load()).start()
    try:
        local, a = run(cfg, tmp_path / "local")
        wire, b = run(cfg, tmp_path / "wire", url=tcp_emulator.url)
    finally:
        tcp_emulator.stop()
    assert wire["steps"] == local["steps"] == 100
    peak = max(local["peak_displacement_mm"])
    assert peak > 0.5
    # float32 carries 24 bits: relative resolution 2^-23 ~ 1.2e-7; the run may add a few roundings.
    assert max_abs_diff(a, b) <= 100 * FLOAT32_EPS * peak
    assert max_abs_diff(a, b, "force_") <= 100 * FLOAT32_EPS * max(np.max(np.abs(a.steps[k])) for k in a.steps if k.startswith("force_"))
    # One request per controller period: the emulator's clock advanced exactly as the run's.
    ticks = tcp_emulator.bank.ticks
    assert ticks > 50 * wire["steps"]
    assert ticks <= tcp_emulator.context.requests <= ticks + 50  # one request per controller period


def test_run_over_modbus_rtu_pty_lockstep_equals_in_process(tmp_path):
    cfg = write_config(tmp_path, duration=0.3, rate=5.0, extra=QUIET_SENSORS)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load(), transport="rtu").start()
    try:
        assert emu.path.startswith("/dev/pts/")
        local, a = run(cfg, tmp_path / "local")
        wire, b = run(cfg, tmp_path / "wire", url=emu.url)
        assert wire["steps"] == local["steps"] == 30
        assert max_abs_diff(a, b) <= 100 * FLOAT32_EPS * max(local["peak_displacement_mm"])
    finally:
        emu.stop()


def test_modbus_rtu_parity_and_stop_bits_reach_the_serial_client():
    """A controller framed 8E1 (the Modbus standard's default for RTU) or 8N2: the [driver] table
    or the URL's query sets the serial client's parity and stop bits; a bad value is refused by
    name. (A pseudo-terminal takes no parity, so this is checked on the client, unopened.)"""
    link = ModbusLink("modbus+rtu:///dev/ttyUSB0?baudrate=19200&parity=E", 1)
    params = link.client.comm_params
    assert (params.baudrate, params.parity, params.stopbits, params.bytesize) == (19200, "E", 1, 8)
    params = ModbusLink("modbus+rtu:///dev/ttyUSB0", 1, {"stopbits": 2}).client.comm_params
    assert (params.parity, params.stopbits) == ("N", 2)
    with pytest.raises(ConfigError, match=r"parity must be one of N, E, O.*got 'X'"):
        ModbusLink("modbus+rtu:///dev/ttyUSB0?parity=X", 1)
    with pytest.raises(ConfigError, match=r"stopbits must be a whole number in 1..2"):
        ModbusLink("modbus+rtu:///dev/ttyUSB0", 1, {"stopbits": 3})


def test_run_over_modbus_tcp_real_time_within_tracking_tolerance(tmp_path):
    """Real time: the emulator runs its own 1024 Hz loop; HS over TCP matches in-process HS
    within the tracking tolerance (a few tracking-error RMS)."""
    cfg = write_config(tmp_path, duration=1.0, rate=3.0, clock="realtime")
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=False), modbus_map.load()).start()
    try:
        local, a = run(write_config(tmp_path, duration=1.0, rate=3.0, name="ls.toml"), tmp_path / "local")
        wire, b = run(cfg, tmp_path / "wire", url=emu.url)
        assert wire["steps"] == local["steps"]
        peak = max(local["peak_displacement_mm"])
        tracking = max(wire["rms_tracking_error_mm"])
        assert max_abs_diff(a, b) <= max(5 * tracking, 0.02 * peak), (max_abs_diff(a, b), tracking, peak)
        assert wire["max_error_pct"] < 5.0
    finally:
        emu.stop()


def test_more_axes_than_the_controller_serves_is_a_clear_error(tcp_emulator):
    """The controller reports its axes (info register): asking for more is refused by name at
    open, before the status read would meet unmapped registers (exception 2)."""
    with pytest.raises(ConfigError, match=r"3 axes asked for, but the controller serves 2 \(its axes register\)"):
        open_link(tcp_emulator.url, ["C1", "C2", "C3"], LockstepClock())
    assert all(c["enable"] == 0.0 for c in tcp_emulator.context.commands)


def test_a_controller_whose_clock_does_not_run_stops_a_real_time_run(tmp_path):
    """A lockstep emulator driven with [driver] lockstep = "off": nothing advances its clock, the
    actuators never move, and with the measured-displacement correction a linear specimen would
    give HS == NS exactly (a perfect-looking run on stale measurements). The frozen sequence
    register stops the run, the actuators hold, and the steps made are recorded."""
    cfg = write_config(tmp_path, duration=0.5, rate=2.0, clock="realtime",
                       extra=QUIET_SENSORS + "[safety]\ndry_run = false\n")
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load()).start()
    try:
        result, rec = run(cfg, tmp_path / "frozen", url=emu.url, driver={"lockstep": "off"})
    finally:
        emu.stop()
    assert not isinstance(result, dict), result
    assert "the controller's clock does not run: its sequence register stayed at 0" in str(result)
    assert "the actuators hold (confirmed by read-back)" in str(result)
    assert 0 < len(rec.steps["step"]) < 50 and emu.bank.ticks == 0


def test_an_emulator_on_ipv6_loopback_gives_a_url_the_driver_opens(cfg):
    """Bound to ::1, the emulator's URL puts the address in brackets (RFC 3986), and the driver
    connects with it."""
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load(), host="::1").start()
    try:
        assert emu.url == f"modbus+tcp://[::1]:{emu.port}"
        acts = open_link(emu.url, ["C1", "C2"], LockstepClock())
        assert acts[0].link.info["axes"] == 2.0
        for a in acts:
            a.close()
    finally:
        emu.stop()


def test_clock_mismatch_is_a_clear_error(cfg, tcp_emulator):
    with pytest.raises(ConfigError, match="lockstep"):
        open_link(tcp_emulator.url, ["C1", "C2"], RealTimeClock())


# -- a third-party client --------------------------------------------------------------------------

def test_third_party_client_reads_and_commands(cfg):
    """pymodbus's own client, no hsio code: read measured displacement, write a command."""
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=False, watchdog_s=0), modbus_map.load()).start()
    try:
        c = ModbusTcpClient("127.0.0.1", port=emu.port)
        assert c.connect()
        F32 = ModbusTcpClient.DATATYPE.FLOAT32
        # axis 0: command block at 18 (displacement 18, force 20, mode 22, enable 24, watchdog 26)
        regs = c.convert_to_registers(2.0, F32) + c.convert_to_registers(0.0, F32) \
            + c.convert_to_registers(0.0, F32) + c.convert_to_registers(1.0, F32)
        assert not c.write_registers(18, regs, device_id=1).isError()
        deadline = time.monotonic() + 5.0  # a 20 ms lag settles in 0.3 s of the controller's own loop,
        while True:                         # which a loaded machine may run late (it never catches up)
            time.sleep(0.1)
            rr = c.read_holding_registers(202, count=2, device_id=1)  # axis 0 measured displacement
            d = c.convert_from_registers(rr.registers, F32)
            if abs(d - 2.0) <= 0.1 or time.monotonic() > deadline:
                break
        assert d == pytest.approx(2.0, abs=0.1)
        # Out of range (beyond +/-127 mm): exception 3, nothing applied, the axis keeps its command.
        bad = c.write_registers(18, c.convert_to_registers(500.0, F32), device_id=1)
        assert bad.isError() and bad.exception_code == 3
        assert emu.bank.controllers[0].command == pytest.approx(2.0)
        # Status registers are read only: exception 2.
        ro = c.write_registers(202, c.convert_to_registers(1.0, F32), device_id=1)
        assert ro.isError() and ro.exception_code == 2
        c.close()
    finally:
        emu.stop()


def test_modbus_exception_becomes_a_clear_error(cfg, tcp_emulator):
    link = ModbusLink(tcp_emulator.url, 2)
    link.open(enable=False)
    with pytest.raises(CommunicationError, match=r"Modbus exception 2 \(illegal data address\)"):
        link.request("write_registers", 200, [0, 0], what="write to the status block")
    link.close()


def test_watchdog_holds_the_axis_and_the_driver_says_so(cfg):
    bank = bank_from_config(cfg, lockstep=False, watchdog_s=0.5)  # a margin for a loaded machine's stalls
    emu = ModbusEmulator(bank, modbus_map.load()).start()
    try:
        clock = RealTimeClock()
        acts = open_link(emu.url, ["C1", "C2"], clock)
        for _ in range(50):
            for a in acts:
                a.command(0.2)
            clock.tick()
            acts[0].feedback()
        time.sleep(1.5)  # the host goes silent
        assert bank.axes[0].watchdog_expired and bank.controllers[0].holding
        acts[0].link.read_status()
        with pytest.raises(InterlockError, match="watchdog expired"):
            acts[0].command(0.3)
    finally:
        emu.stop()


def test_connect_to_nothing_is_a_clear_error():
    with refused_port() as port, pytest.raises(CommunicationError, match="cannot connect"):
        open_link(f"modbus+tcp://127.0.0.1:{port}", ["a"], LockstepClock(), {"timeout_s": 0.2})


def test_a_serial_port_that_does_not_open_is_named_with_the_reason(tmp_path):
    """pymodbus only logs why a serial port did not open; the error names the port, its settings
    and pyserial's reason (here: no such device), not a TCP "connection refused"."""
    missing = tmp_path / "ttyUSB9"
    with pytest.raises(CommunicationError, match=rf"serial port '{missing}' with baudrate 9600, parity E, stop bits "
                                                 r"1: .*No such file or directory") as exc:
        open_link(f"modbus+rtu://{missing}?baudrate=9600&parity=E", ["a"], LockstepClock())
    assert "refused" not in str(exc.value)


def test_bad_driver_options_are_refused():
    with pytest.raises(ConfigError, match="unknown key 'timeout'"):
        ModbusLink("modbus+tcp://127.0.0.1:1", 1, {"timeout": 1})
    with pytest.raises(ConfigError, match="timeout_s must be positive"):
        ModbusLink("modbus+tcp://127.0.0.1:1?timeout_s=0", 1)
    assert math.isfinite(ModbusLink("modbus+tcp://127.0.0.1:1?timeout_s=0.3", 1).timeout_s)


def test_a_real_time_run_over_a_link_slower_than_the_period_warns(tmp_path):
    """Modbus RTU at 9600 baud takes about 9 ms a request, nine controller periods: the real-time
    schedule cannot be kept. The run completes, counts the overruns in its summary and says so."""
    from hsio import config as config_mod
    from hsio import runner

    cfg = write_config(tmp_path, duration=0.03, rate=2.0, clock="realtime",
                       extra=QUIET_SENSORS + "[safety]\ndry_run = false\n")
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=False), modbus_map.load(), transport="rtu", baudrate=9600).start()
    lines: list[str] = []
    try:
        run_cfg = config_mod.load(cfg)
        run_cfg["hardware"]["url"] = emu.url
        summary = runner.run(run_cfg, tmp_path / "slow", notify=lines.append)
    finally:
        emu.stop()
    assert summary["steps"] == 3 and summary["clock_overruns"] > 0.5 * 3 * 0.02 * 1024
    lateness = summary["clock_lateness"]  # every overrun is also a late period, past half of one
    assert lateness["overruns"] == summary["clock_overruns"] and lateness["late"] >= lateness["overruns"]
    assert lateness["max_late_s"] > 1 / 1024
    warning = [line for line in lines if "did not keep the controller's rate" in line]
    assert warning and f"{summary['clock_overruns']} of" in warning[0] and "TR 2" in warning[0]


def test_a_register_in_a_status_blocks_padding_is_served_as_mapped(tmp_path, cfg):
    """A lab map may put a controller-wide register in the padding of a status block (stride 10
    for a block of 8 words): the emulator serves it as the map names it, and only the words no
    register names as reserved (0)."""
    text = modbus_map.DEFAULT_MAP.read_text()
    text = text.replace("base = 200\nstride = 8", "base = 200\nstride = 10").replace(
        'force_limit_kN = { address = 10, type = "float32" }', 'force_limit_kN = { address = 208, type = "float32" }')
    path = tmp_path / "lab.toml"
    path.write_text(text)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load(path)).start()
    try:
        acts = open_link(emu.url, ["C1", "C2"], LockstepClock(), {"map": str(path)})
        try:
            assert acts[0].limits.force_kN == pytest.approx(emu.bank.controllers[0].config.force_limit_kN)
        finally:
            for a in acts:
                a.close()
    finally:
        emu.stop()


def test_a_watchdog_trip_on_a_map_without_its_time_does_not_name_a_time(tmp_path, cfg):
    """A lab map without the `watchdog_s` info register: the trip is reported without a made-up
    "0 s" (the controller's watchdog time is not known to the driver)."""
    text = modbus_map.DEFAULT_MAP.read_text()
    text = text.replace('watchdog_s     = { address = 12, type = "float32" }', "")
    path = tmp_path / "lab.toml"
    path.write_text(text)
    bank = bank_from_config(cfg, lockstep=False, watchdog_s=0.5)
    emu = ModbusEmulator(bank, modbus_map.load(path)).start()
    try:
        clock = RealTimeClock()
        acts = open_link(emu.url, ["C1", "C2"], clock, {"map": str(path)})
        for _ in range(20):
            for a in acts:
                a.command(0.1)
            clock.tick()
        time.sleep(1.2)  # the host goes silent
        assert bank.axes[0].watchdog_expired
        acts[0].link.read_status()
        with pytest.raises(InterlockError, match="watchdog expired") as err:
            acts[0].command(0.2)
        assert " 0 s" not in str(err.value) and "does not report" in str(err.value)
    finally:
        emu.stop()
