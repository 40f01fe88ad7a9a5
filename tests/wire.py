"""Helpers for the tests over the wire: configurations, a refused port, runs, a fault-injecting proxy."""

from __future__ import annotations

import contextlib
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

import numpy as np

from hsio import config as config_mod
from hsio import runner
from hsio.experiment import ExperimentStopped
from hsio.recording import Run

BASE = """
[record]
duration_s = {duration}
[test]
rate = {rate}
[output]
plots = false
samples = false
[hardware]
clock = "{clock}"
"""

# The emulator's own sensor noise and quantisation off: a run over the wire then differs from the
# in-process run only by the transport's number format (a 0.025 mm quantiser would turn a
# rounding of the transport into a whole step now and then).
QUIET_SENSORS = "[emulator]\nnoise_mm = 0.0\nresolution_mm = 0.0\nforce_noise_kN = 0.0\nforce_resolution_kN = 0.0\n"


def write_config(tmp_path: Path, duration: float = 1.0, rate: float = 20.0, clock: str = "lockstep",
                 extra: str = "", name: str = "run.toml") -> Path:
    path = tmp_path / name
    path.write_text(BASE.format(duration=duration, rate=rate, clock=clock) + extra)
    return path


@contextlib.contextmanager
def refused_port():
    """A local port nobody listens on, for as long as the block runs: it is bound (so no other
    server can take it) but not listening, so a connection to it is refused."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        yield s.getsockname()[1]


def run(config_path: Path, out: Path, url: str | None = None, driver: dict | None = None,
        safety: dict | None = None):
    """hsio run's pipeline in process; returns (summary or the ExperimentStopped, Run)."""
    cfg = config_mod.load(config_path)
    if url is not None:
        cfg["hardware"]["url"] = url
    if driver:
        cfg["driver"].update(driver)
    if safety:
        cfg["safety"].update(safety)
    try:
        result = runner.run(cfg, out)
    except ExperimentStopped as exc:
        result = exc
    return result, Run(out / "run.sqlite")


def in_process_run(config_path: Path, out: Path, channel: str):
    """The run of ``config_path`` against its drives emulated in this process on python-can's
    virtual bus ``channel`` (the reference a run across processes is compared with)."""
    from hsio.commands.emulate import bank_from_config
    from hsio.emulators.canopen import CanopenEmulator

    emu = CanopenEmulator(bank_from_config(config_path, lockstep=True), channel, 1).start()
    try:
        summary, recorded = run(config_path, out, url=emu.url)
    finally:
        emu.stop()
    assert isinstance(summary, dict), summary
    return summary, recorded


def max_abs_diff(a: Run, b: Run, prefix: str = "u_") -> float:
    keys = [k for k in a.steps if k.startswith(prefix)]
    n = min(len(a.steps["step"]), len(b.steps["step"]))
    return max(float(np.max(np.abs(a.steps[k][:n] - b.steps[k][:n]))) for k in keys)


class FaultProxy:
    """A TCP proxy between a client and a server that can drop, delay or corrupt the traffic.

    ``drop()`` closes every open connection (the client sees a dropped link); ``delay_next(s)``
    holds the next reply for ``s`` seconds; ``corrupt_next()`` flips the bytes of the next reply;
    ``blackhole = True`` swallows every reply (a controller that went silent); ``silent_after = N``
    passes the first N replies and swallows every later one (silent from a known moment).
    """

    def __init__(self, target_port: int, host: str = "127.0.0.1"):
        self.target = (host, target_port)
        self.listener = socket.socket()
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind((host, 0))
        self.listener.listen(8)
        self.port = self.listener.getsockname()[1]
        self.pairs: list[tuple[socket.socket, socket.socket]] = []
        self.lock = threading.Lock()
        self.delay_s = 0.0
        self.corrupt = False
        self.blackhole = False
        self.silent_after: int | None = None
        self.replies = 0
        self.connections = 0
        self._stop = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        self.listener.settimeout(0.1)
        while not self._stop.is_set():
            try:
                client, _ = self.listener.accept()
            except (TimeoutError, OSError):
                continue
            try:
                server = socket.create_connection(self.target, timeout=1.0)
            except OSError:
                client.close()
                continue
            for s in (client, server):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self.lock:
                self.pairs.append((client, server))
                self.connections += 1
            threading.Thread(target=self._pipe, args=(client, server, False), daemon=True).start()
            threading.Thread(target=self._pipe, args=(server, client, True), daemon=True).start()

    def _pipe(self, src: socket.socket, dst: socket.socket, reply: bool) -> None:
        src.settimeout(None)
        while True:
            try:
                data = src.recv(4096)
            except OSError:
                break
            if not data:
                break
            if hasattr(socket, "TCP_QUICKACK"):  # ack at once, as the emulators do: a sender's Nagle waits for it
                try:
                    src.setsockopt(socket.IPPROTO_TCP, socket.TCP_QUICKACK, 1)
                except OSError:
                    pass
            if reply:
                self.replies += 1
                if self.silent_after is not None and self.replies > self.silent_after:
                    self.blackhole = True
                if self.blackhole:
                    continue
                if self.delay_s:
                    d, self.delay_s = self.delay_s, 0.0
                    time.sleep(d)
                if self.corrupt:
                    self.corrupt = False
                    data = bytes(b ^ 0x5A for b in data)
            try:
                dst.sendall(data)
            except OSError:
                break
        for s in (src, dst):
            try:
                s.close()
            except OSError:
                pass

    def drop(self) -> None:
        with self.lock:
            pairs, self.pairs = self.pairs, []
        for pair in pairs:
            for s in pair:
                try:
                    s.shutdown(socket.SHUT_RDWR)
                    s.close()
                except OSError:
                    pass

    def delay_next(self, seconds: float) -> None:
        self.delay_s = seconds

    def corrupt_next(self) -> None:
        self.corrupt = True

    def close(self) -> None:
        self._stop.set()
        self.drop()
        self.listener.close()


class AtStep:
    """Calls ``action`` once when the lockstep clock reaches ``tick`` (a device on the clock)."""

    def __init__(self, tick: int, action):
        self.tick, self.action, self.ticks, self.done = tick, action, 0, False

    def advance(self, n: int) -> None:
        self.ticks += n
        if not self.done and self.ticks >= self.tick:
            self.done = True
            self.action()


def fault_at(monkeypatch, tick: int, action) -> AtStep:
    """``action`` once the experiment's lockstep clock reaches ``tick`` (every clock the run
    makes from now on carries the trigger)."""
    from hsio import api
    from hsio.clock import LockstepClock

    trigger = AtStep(tick, action)

    def make_clock():
        clock = LockstepClock()
        clock.attach(trigger)
        return clock

    monkeypatch.setattr(api, "LockstepClock", make_clock)
    return trigger

def terminate(proc: subprocess.Popen, timeout_s: float = 20.0) -> None:
    """SIGTERM (a run or server holds and closes its record), then SIGKILL if it lingers."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


def stopped_run(tmp_path: Path, at_step: int = 10, extra: str = "", config_path: Path | None = None,
                ground=None, out: Path | None = None) -> Path:
    """A short run on the emulator stopped by the operator at step ``at_step``: a record that
    `hsio resume` can continue (``extra``: tables added to the configuration; or ``config_path``
    to run; ``ground``: a record given in code). Returns its folder."""
    from hsio.safety.control import RunControl

    control, steps = RunControl(), []

    def stop_at(n):
        steps.append(n)
        if len(steps) == at_step:
            control.request_stop("stopped by the test")

    out = out or tmp_path / "run"
    config_path = config_path or write_config(tmp_path, duration=0.5, rate=5.0, extra=extra)
    try:
        runner.run(config_mod.load(config_path), out, stop_at, ground=ground, control=control)
    except ExperimentStopped:
        return out
    raise AssertionError(f"the run was not stopped at step {at_step}")
