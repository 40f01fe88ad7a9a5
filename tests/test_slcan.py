"""CANopen across processes: `hsio emulate canopen --slcan pty|tcp` serves the drives as a
Lawicel (SLCAN) adapter; `hsio run` in another process reaches them through python-can's slcan
interface, as it would a USB-CAN adapter. The result equals the run with the emulator in the
same process on python-can's virtual bus, step for step."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from hsio.commands.emulate import bank_from_config
from hsio.emulators.canopen import CanopenEmulator, SlcanPort
from hsio.recording import Run
from test_emulate_cli import Emulator, hsio
from wire import QUIET_SENSORS, in_process_run, run, write_config

_channels = itertools.count()


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    return write_config(tmp_path_factory.mktemp("slcan"), duration=0.5, rate=4.0, extra=QUIET_SENSORS)


@pytest.fixture(scope="module")
def in_process(cfg, tmp_path_factory):
    return in_process_run(cfg, tmp_path_factory.mktemp("local") / "run", f"slcan-ref-{next(_channels)}")


@pytest.mark.parametrize("kind", ["pty", "tcp"])
def test_run_across_processes_equals_in_process(cfg, in_process, tmp_path, kind):
    emu = Emulator("canopen", "--slcan", kind, cfg)
    try:
        url = emu.lines["url"]
        assert url.startswith("canopen+slcan://" + ("127.0.0.1:" if kind == "tcp" else "/dev/pts/"))
        run_cfg = tmp_path / "run.toml"
        run_cfg.write_text(cfg.read_text().replace('clock = "lockstep"', f'clock = "lockstep"\nurl = "{url}"'))
        proc = hsio("run", run_cfg, "--out", tmp_path / "o", "--json")
    finally:
        emu.stop()
    assert proc.returncode == 0, proc.stderr
    summary, local = in_process
    across = Run(tmp_path / "o" / "run.sqlite")
    assert json.loads(proc.stdout)["steps"] == summary["steps"] > 0
    for key in local.steps:
        if key.startswith(("u_", "disp_", "force_", "target_")):
            assert np.array_equal(across.steps[key], local.steps[key]), key


def test_slcan_tcp_listens_on_loopback_only():
    with pytest.raises(ValueError, match="loopback"):
        SlcanPort("tcp", host="0.0.0.0")


def test_scaling_is_never_guessed(tmp_path):
    """A drive without the position factor 0x6093 or the feed constant 0x6092 needs [driver]
    counts_per_mm; with it set, the run goes on."""
    from hsio.clock import LockstepClock
    from hsio.drivers.canopen import open_link
    from hsio.errors import ConfigError

    emu = CanopenEmulator(bank_from_config(write_config(tmp_path), lockstep=True), f"slcan-noscale-{next(_channels)}", 1).start()
    try:
        for axis in emu.axes:
            del axis.node.object_dictionary[0x6093]
        with pytest.raises(ConfigError, match="no position scaling.*counts_per_mm"):
            open_link(emu.url, ["C1", "C2"], LockstepClock(), {})
        actuators = open_link(emu.url, ["C1", "C2"], LockstepClock(), {"counts_per_mm": 1000})
        assert actuators[0].drive.counts_per_mm == 1000.0
        for a in actuators:
            a.close()
    finally:
        emu.stop()


def test_scaling_from_the_feed_constant_counts_the_gear_ratio(tmp_path):
    """Without 0x6093, counts per mm = encoder increments per motor revolution (0x608F) x motor
    revolutions per shaft revolution (gear ratio 0x6091) / feed per shaft revolution (0x6092):
    4000 x 5 / 20 mm = 1000 counts per mm, the emulated drive's 1 um count. Without the gear
    ratio the driver would read every position 5 times too large."""
    from canopen.objectdictionary import datatypes as dt

    from hsio.clock import LockstepClock
    from hsio.drivers import canopen_od as cod
    from hsio.drivers.canopen import open_link

    emu = CanopenEmulator(bank_from_config(write_config(tmp_path), lockstep=True), f"slcan-gear-{next(_channels)}", 1).start()
    try:
        for axis in emu.axes:
            dictionary = axis.node.object_dictionary
            del dictionary[0x6093]
            for index, members in ((0x608F, [4000, 1]), (0x6091, [5, 1]), (0x6092, [20, 1])):
                dictionary.add_object(cod._record(f"0x{index:04X}", index, [(f"sub {k}", dt.UNSIGNED32, "ro", v)
                                                                           for k, v in enumerate(members, 1)]))
        clock = LockstepClock()
        actuators = open_link(emu.url, ["C1", "C2"], clock, {})
        assert actuators[0].drive.counts_per_mm == pytest.approx(1000.0)
        for _ in range(200):
            for a in actuators:
                a.command(0.5)
            clock.tick()
        fb = actuators[0].feedback()
        assert fb.displacement_mm == pytest.approx(emu.bank.controllers[0].measured_displacement, abs=1e-3)
        for a in actuators:
            a.close()
    finally:
        emu.stop()


@pytest.mark.parametrize("garbage", [
    bytes([0x01, 0x03, 0x00, 0x00, 0x00, 0x02, 0xC4, 0x0B]) + b"\r",  # a Modbus RTU request: not ASCII
    b"tZZZ5\r",  # a frame whose id is not hexadecimal
    b"t12\r",  # a frame cut short
    b"x" * 600,  # a run of bytes without a line end
])
def test_a_line_that_is_not_slcan_does_not_stop_the_emulated_adapter(cfg, in_process, tmp_path, garbage, monkeypatch):
    """A client that writes what is not SLCAN to the emulated adapter (a Modbus RTU driver pointed
    at the wrong port, noise) has that line dropped; the adapter keeps serving the drives, and the
    next run through it equals the in-process run, with no thread ended by an exception."""
    import socket
    import threading

    from hsio.emulators.canopen import slcan_emulator

    ended = []
    monkeypatch.setattr(threading, "excepthook", lambda args: ended.append(args.exc_value))
    emu = slcan_emulator(bank_from_config(cfg, lockstep=True), "tcp")
    try:
        with socket.create_connection((emu.slcan.host, emu.slcan.port), timeout=2.0) as s:
            s.sendall(garbage)
        summary, recorded = run(cfg, tmp_path / "run", url=emu.url)
    finally:
        emu.stop()
    assert ended == []
    assert isinstance(summary, dict), summary
    np.testing.assert_array_equal(recorded.steps["u_C1"], in_process[1].steps["u_C1"])


@pytest.mark.parametrize("kind", ["pty", "tcp"])
def test_an_adapter_nobody_listens_to_neither_blocks_its_drives_nor_its_stop(cfg, kind):
    """With no client on the SLCAN port, what the drives send (heartbeats, replies to a client
    gone) is lost, as on a cable nobody reads: their writes never block on a full
    pseudo-terminal, and stopping the emulator (`hsio emulate`'s SIGTERM) returns at once."""
    import threading
    import time

    from hsio.emulators.canopen import slcan_emulator

    emu = slcan_emulator(bank_from_config(cfg, lockstep=True), kind, heartbeat_ms=0)
    frames = 20_000  # 22 bytes each on the line: far beyond a pseudo-terminal's buffer
    sender = threading.Thread(target=lambda: [emu.network.send_message(0x181, bytes(8)) for _ in range(frames)],
                              daemon=True)
    sender.start()
    sender.join(20.0)
    stopper = threading.Thread(target=emu.stop, daemon=True)
    started = time.monotonic()
    stopper.start()
    stopper.join(10.0)
    assert not sender.is_alive(), "the drives' writes blocked on a port nobody reads"
    assert not stopper.is_alive() and time.monotonic() - started < 10.0


@pytest.mark.parametrize("args, words", [
    (["--slcan", "pty", "--port", "5000"], "--port 5000 is the TCP port of --slcan tcp; it is not used with --slcan pty"),
    (["--channel", "bus", "--port", "5000"], "--port 5000 is the TCP port of --slcan tcp; it is not used without --slcan"),
    (["--slcan", "tcp", "--channel", "bus"], "--channel 'bus' is not used with --slcan tcp"),
    (["--slcan", "pty", "--interface", "socketcan"], "--interface 'socketcan' is not used with --slcan pty"),
    (["--slcan", "tcp", "--interface", "virtual"], "--interface 'virtual' is not used with --slcan tcp"),
])
def test_an_option_the_canopen_emulator_would_not_use_is_refused(monkeypatch, args, words):
    """`hsio emulate canopen` refuses, before it builds anything, an option its other options
    leave unused (a port the pseudo-terminal never opens), rather than ignoring it."""
    from click.testing import CliRunner

    import hsio.commands.emulate as emulate_command
    from hsio.cli import main

    monkeypatch.setattr(emulate_command, "bank_from_config", lambda *a, **k: pytest.fail("the emulator was built"))
    result = CliRunner().invoke(main, ["emulate", "canopen", *args])
    assert result.exit_code == 2, result.output
    assert words in " ".join(result.output.split()), result.output
