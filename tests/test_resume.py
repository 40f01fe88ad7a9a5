"""Resume after SIGKILL (docs/safety.md section 8): `hsio run` killed at random steps of a lockstep
run over Modbus TCP against `hsio emulate` in another process, resumed each time; the final record
equals that of an uninterrupted run. CI kills twice; with HSIO_SLOW=1 also five times."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hsio import config as config_mod
from hsio import runner
from hsio.commands.emulate import bank_from_config
from hsio.drivers import modbus_map
from hsio.emulators.modbus import ModbusEmulator
from hsio.recording import Run
from hsio.safety import socket as control_socket
from test_emulate_cli import Emulator
from wire import QUIET_SENSORS, write_config

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
# 100 steps of TR 5 (51 controller periods, one Modbus request each): what is asserted (every step
# once, the same values) does not depend on the test rate, the wall time does
RATE = 5.0


def config_for(tmp_path: Path, url: str, name: str) -> Path:
    path = write_config(tmp_path, duration=1.0, rate=RATE, extra=QUIET_SENSORS, name=name)
    path.write_text(path.read_text().replace("[hardware]\n", f'[hardware]\nurl = "{url}"\n'))
    return path


def step_of(out: Path) -> int:
    try:
        status = control_socket.send(out / "control.sock", "status", timeout_s=0.5)
    except OSError:
        return -1
    return int(status.rpartition(" ")[2]) if "phase HS" in status else -1


def kill_at(argv: list[str], out: Path, step: int, cwd: Path) -> None:
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV, cwd=cwd)
    try:
        deadline = time.monotonic() + 180
        while proc.poll() is None and time.monotonic() < deadline and step_of(out) < step:
            time.sleep(0.005)
        assert proc.poll() is None, "the run ended before it could be killed"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()


def uninterrupted(tmp_path: Path, emu_cfg: Path) -> Run:
    """The reference: the same run, never interrupted, in this process against the same emulated
    controller (lockstep, noise-free: the result does not depend on the process it runs in)."""
    emulator = ModbusEmulator(bank_from_config(emu_cfg, lockstep=True), modbus_map.load()).start()
    try:
        summary = runner.run(config_mod.load(config_for(tmp_path, emulator.url, "ref.toml")), tmp_path / "ref")
    finally:
        emulator.stop()
    assert summary["exit_status"] == 0
    return Run(tmp_path / "ref" / "run.sqlite")


@pytest.mark.parametrize("kills", [2, pytest.param(5, marks=pytest.mark.slow)])
def test_killed_and_resumed_run_equals_the_uninterrupted_one(tmp_path, kills):
    """`hsio run` killed with SIGKILL at ``kills`` random steps (the first kill ends `hsio run`,
    the others `hsio resume`), resumed after each, then resumed to the end."""
    rng = random.Random(2026)
    emu_cfg = write_config(tmp_path, duration=1.0, rate=RATE, extra=QUIET_SENSORS, name="emu.toml")
    a = uninterrupted(tmp_path, emu_cfg)
    emulator = Emulator("modbus", "--port", 0, emu_cfg)
    try:
        cfg = config_for(tmp_path, emulator.lines["url"], "run.toml")
        out = tmp_path / "killed"
        at = sorted(rng.sample(range(10, 90), kills))
        kill_at([sys.executable, "-m", "hsio.cli", "run", str(cfg), "--out", str(out)], out, at[0], tmp_path)
        for step in at[1:]:
            kill_at([sys.executable, "-m", "hsio.cli", "resume", str(out)], out, step, tmp_path)
        proc = subprocess.run([sys.executable, "-m", "hsio.cli", "resume", str(out)], capture_output=True, text=True,
                              timeout=300, env=ENV, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
    finally:
        emulator.stop()
    b = Run(out / "run.sqlite")
    np.testing.assert_array_equal(b.steps["step"], a.steps["step"])  # every step once, in order
    assert len(a.steps["step"]) == 100
    worst = max(float(np.max(np.abs(a.steps[k] - b.steps[k]))) for k in a.steps if k.startswith(("u_", "r_")))
    print(f"resume: killed at steps >= {at}; max |resumed - uninterrupted| {worst:.2e}")
    assert worst < 1e-3
    assert [e["kind"] for e in b.events()].count("resume") == kills
    assert b.summary["exit_status"] == 0
