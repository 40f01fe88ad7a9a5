"""`hsio emulate` and `hsio probe` as separate processes: the lab-like pair over real sockets
and a pseudo-terminal."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from wire import refused_port, write_config

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def hsio(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "hsio.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=ENV, cwd=ROOT)


class Emulator:
    """`hsio emulate ...` in a subprocess; waits (at most ``startup_s``) for its banner and stops
    it with SIGTERM."""

    def __init__(self, *args, startup_s: float = 30.0, argv: list[str] | None = None):
        argv = argv or [sys.executable, "-m", "hsio.cli", "emulate", *map(str, args)]
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV, cwd=ROOT)
        self.lines: dict[str, str] = {}
        self.banner = ""
        try:
            self._read_banner(time.monotonic() + startup_s)
        except BaseException:
            self.proc.kill()
            self.proc.communicate(timeout=10)
            raise

    def _read_banner(self, deadline: float) -> None:
        """Read stdout with select, so the deadline holds even when the process prints nothing."""
        fd = self.proc.stdout.fileno()
        pending = b""
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise RuntimeError(f"emulator did not start in time; it printed {self.banner + pending.decode()!r}")
            ready, _, _ = select.select([fd], [], [], left)
            if not ready:
                continue
            chunk = os.read(fd, 4096)
            if not chunk:
                raise RuntimeError(f"emulator exited: {self.proc.stderr.read().decode()}")
            pending += chunk
            while b"\n" in pending:
                raw, _, pending = pending.partition(b"\n")
                line = raw.decode()
                self.banner += line + "\n"
                key, _, value = line.partition(" ")
                self.lines[key] = value.strip()
                if line.startswith("Ctrl-C"):
                    return

    def stop(self) -> str:
        self.proc.send_signal(signal.SIGTERM)
        out, _ = self.proc.communicate(timeout=10)
        return out.decode()


def test_emulate_modbus_and_run_against_it(tmp_path):
    """`hsio emulate modbus CONFIG` + `hsio run CONFIG` with the modbus+tcp URL = in-process run."""
    emu = Emulator("modbus", "--port", 0, write_config(tmp_path, duration=0.5, name="emulator.toml"))
    try:
        url = emu.lines["url"]  # the port the emulator bound
        assert url.startswith("modbus+tcp://127.0.0.1:") and int(url.rpartition(":")[2]) > 0
        assert emu.lines["axes"] == "C1, C2" and emu.lines["clock"].startswith("lockstep")
        cfg = write_config(tmp_path, duration=0.5, extra=f'url = "{url}"\n')
        wire = hsio("run", cfg, "--out", tmp_path / "wire", "--json")
        assert wire.returncode == 0, wire.stderr
    finally:
        assert "the axes hold" in emu.stop()
    local = hsio("run", write_config(tmp_path, duration=0.5, name="local.toml"), "--out", tmp_path / "local", "--json")
    w, l = json.loads(wire.stdout), json.loads(local.stdout)
    assert w["steps"] == l["steps"] > 0
    for x, y in zip(w["peak_displacement_mm"], l["peak_displacement_mm"]):
        assert x == pytest.approx(y, rel=1e-5)


def test_emulate_modbus_rtu_prints_the_pty_and_probe_reads_without_moving(tmp_path):
    emu = Emulator("modbus-rtu", write_config(tmp_path))
    try:
        path = emu.lines["pty"]
        assert path.startswith("/dev/pts/") and os.path.exists(path)
        url = f"modbus+rtu://{path}"
        for _ in range(2):
            probe = hsio("probe", url, "--json", "--axes", "2", "--requests", "20")
            assert probe.returncode == 0, probe.stderr
            r = json.loads(probe.stdout)
            assert r["clock"] == "lockstep" and r["identity"]["axes"] == 2.0
            assert r["latency"]["requests"] == 20 and 0 < r["latency"]["median_ms"] <= r["latency"]["p99_ms"] <= r["latency"]["max_ms"]
            for axis in r["axes"]:  # never enabled, never advanced, still holding at rest
                assert axis["sequence"] == 0.0 and axis["flags"]["holding"] and not axis["flags"]["enabled"]
                assert abs(axis["displacement_mm"]) < 0.1
            assert "move" not in r
    finally:
        emu.stop()


def test_probe_move_reports_step_and_sine(tmp_path):
    emu = Emulator("modbus", "--port", 0, write_config(tmp_path))
    try:
        url = emu.lines["url"]
        probe = hsio("probe", url, "--move", "--json")
        assert probe.returncode == 0, probe.stderr
        m = json.loads(probe.stdout)["move"]
        # The default emulator: first-order loop with a 20 ms lag -> 10-90 % rise of 2.2 lags.
        assert m["rise_time_s"] == pytest.approx(2.2 * 0.020, abs=0.01)
        assert 0 <= m["overshoot_pct"] < 5
        # A 1 mm, 0.5 Hz sine lags by 20 ms: RMS error about 2 pi f A lag / sqrt 2 = 0.044 mm.
        assert m["rms_tracking_error_mm"] == pytest.approx(0.0444, abs=0.01)
        text = hsio("probe", url)
        assert "latency" in text.stdout and "median" in text.stdout
    finally:
        emu.stop()


def test_emulate_canopen_starts_and_stops(tmp_path):
    emu = Emulator("canopen", "--channel", "cli-bench", write_config(tmp_path))
    try:
        assert emu.lines["url"] == "canopen+virtual://cli-bench/1" and emu.lines["nodes"] == "1..2"
    finally:
        assert "the axes hold" in emu.stop()


def test_probe_of_nothing_fails_clearly():
    with refused_port() as port:
        r = hsio("probe", f"modbus+tcp://127.0.0.1:{port}?timeout_s=0.2")
    assert r.returncode == 2 and "cannot connect" in r.stderr


def test_a_silent_emulator_fails_the_start_up_deadline():
    """The banner wait is bounded even if the process prints nothing (a plain readline() would
    block for ever): a process that sleeps gives up after the deadline."""
    started = time.monotonic()
    with pytest.raises(RuntimeError, match="did not start in time"):
        Emulator(argv=[sys.executable, "-c", "import time; time.sleep(30)"], startup_s=1.0)
    assert time.monotonic() - started < 10


def test_emulate_watch_holding_is_announced_and_reaches_the_controller(tmp_path):
    """--watch-holding: the watchdog also watches holding axes (the strict mode the pause test uses);
    the banner says so, and the flag reaches the controller bank."""
    from hsio.commands.emulate import _bank

    cfg = write_config(tmp_path)
    emu = Emulator("modbus", "--port", 0, "--watchdog-s", 0.5, "--watch-holding", cfg)
    try:
        assert emu.lines["watchdog"] == "0.5 s, holding axes watched too"
    finally:
        emu.stop()
    assert _bank(str(cfg), "lockstep", 0.5, (), None, True).watch_holding
    assert not _bank(str(cfg), "lockstep", 0.5, ()).watch_holding
