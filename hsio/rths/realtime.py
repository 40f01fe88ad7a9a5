"""A periodic real-time loop for the lab, and its timing statistics.

Each period the loop waits for its deadline in two stages, a sleep until ``spin_s`` before it
and then a busy-wait on ``time.perf_counter_ns`` (the sleep's own wake-up latency is hundreds
of microseconds on a general-purpose kernel; the final busy-wait removes it), then calls
``work(k)``. Deadlines are fixed on a grid from the start, so lateness does not accumulate; a
period whose work ends after the next deadline is an overrun: the next period starts at once,
its lateness counted from its own deadline, and the grid moves to that start rather than bursting
to catch up. With ``dedicated_thread`` the loop runs in a
thread of its own; the garbage collector is paused during the run and the interpreter's thread
switch interval shortened (``switch_interval_s``: another Python thread holding the interpreter
lock, such as an in-process emulator, then hands it over within that time, not the default 5 ms). ``pin_cpu`` asks the kernel
for CPU affinity and ``fifo_priority`` for SCHED_FIFO; each is used only where the OS permits
it, the result says what was granted, and both are given back when the loop ends. Every loop is
bounded in count and in time.
"""

from __future__ import annotations

import gc
import os
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

MAX_RATE_HZ = 100_000.0  # a period of 10 us: shorter than the loop's own overhead
MAX_SECONDS = 86_400.0
MAX_PERIODS = 10_000_000  # 2.7 h at 1024 Hz; two float64 arrays of this length are recorded


@dataclass
class Timing:
    rate_hz: float
    periods: int
    lateness_us: np.ndarray  # start of work minus deadline, per period
    overruns: int  # periods whose work ended after the next deadline
    work_us: np.ndarray
    granted: dict = field(default_factory=dict)
    requested: int = 0  # periods asked for; more than ``periods`` when the time bound cut the run

    def stats(self) -> dict:
        late = self.lateness_us
        return {
            "rate_hz": self.rate_hz,
            "periods": int(self.periods),
            "periods_requested": int(max(self.requested, self.periods)),
            "p50_us": float(np.percentile(late, 50)) if late.size else float("nan"),
            "p99_us": float(np.percentile(late, 99)) if late.size else float("nan"),
            "max_us": float(late.max()) if late.size else float("nan"),
            "overruns_per_10k": 1e4 * self.overruns / max(self.periods, 1),
            "work_p50_us": float(np.percentile(self.work_us, 50)) if self.work_us.size else float("nan"),
            "work_p99_us": float(np.percentile(self.work_us, 99)) if self.work_us.size else float("nan"),
            **self.granted,
        }


def _request_os_help(pin_cpu: int | None, fifo_priority: int | None) -> dict:
    granted = {"affinity": None, "sched_fifo": False}
    if pin_cpu is not None and hasattr(os, "sched_setaffinity"):
        try:
            cpus = sorted(os.sched_getaffinity(0))
            cpu = cpus[pin_cpu % len(cpus)]
            os.sched_setaffinity(0, {cpu})
            granted["affinity"] = cpu
        except OSError:
            pass
    if fifo_priority is not None and hasattr(os, "sched_setscheduler"):
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(fifo_priority))
            granted["sched_fifo"] = True
        except (OSError, PermissionError):
            pass
    return granted


def run_periodic(work, rate_hz: float = 1024.0, periods: int = 10_000, spin_s: float = 0.0003,
                 max_seconds: float = 60.0, dedicated_thread: bool = True, pin_cpu: int | None = None,
                 fifo_priority: int | None = None, switch_interval_s: float = 5e-5) -> Timing:
    """Run ``work(k)`` at ``rate_hz`` (at most MAX_RATE_HZ) for ``periods`` periods (1 to
    MAX_PERIODS; no more are recorded than fit in ``max_seconds``)."""
    if not 0 < rate_hz <= MAX_RATE_HZ or not 1 <= periods <= MAX_PERIODS or not 0 < max_seconds <= MAX_SECONDS:
        raise ValueError(f"rate_hz must be in (0, {MAX_RATE_HZ:g}] Hz, periods in [1, {MAX_PERIODS:g}] and max_seconds "
                         f"in (0, {MAX_SECONDS:g}] s; got {rate_hz!r}, {periods!r}, {max_seconds!r}")
    period_ns = int(round(1e9 / rate_hz))
    spin_ns = int(spin_s * 1e9)
    room = min(periods, int(max_seconds * 1e9) // period_ns + 2)  # deadlines are at least a period apart
    late = np.zeros(room)
    spent = np.zeros(room)
    out: dict = {}

    def body():
        affinity_before = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
        policy_before = (os.sched_getscheduler(0), os.sched_getparam(0)) if hasattr(os, "sched_getscheduler") else None
        out["granted"] = _request_os_help(pin_cpu, fifo_priority)
        gc_was = gc.isenabled()
        gc.disable()
        interval_was = sys.getswitchinterval()
        sys.setswitchinterval(switch_interval_s)
        overruns = 0
        done = 0
        try:
            t0 = time.perf_counter_ns() + period_ns
            limit = t0 + int(max_seconds * 1e9)
            deadline = t0
            behind = False
            for k in range(room):
                now = time.perf_counter_ns()
                if now > limit:
                    break
                wait = deadline - now - spin_ns
                if wait > 0:
                    time.sleep(wait * 1e-9)
                while time.perf_counter_ns() < deadline:
                    pass
                start = time.perf_counter_ns()
                late[k] = (start - deadline) * 1e-3  # a period after an overrun is late by all it lost
                if behind:  # the grid moves to this late start: no burst to catch up
                    deadline = start
                    behind = False
                work(k)
                end = time.perf_counter_ns()
                spent[k] = (end - start) * 1e-3
                done = k + 1
                deadline += period_ns
                if end > deadline:  # overrun: the next period starts at once
                    overruns += 1
                    behind = True
        finally:
            sys.setswitchinterval(interval_was)
            if gc_was:
                gc.enable()
            if affinity_before is not None and out["granted"].get("affinity") is not None:
                try:
                    os.sched_setaffinity(0, affinity_before)
                except OSError:
                    pass
            if policy_before is not None and out["granted"].get("sched_fifo"):
                try:  # the caller's thread is not left at real-time priority
                    os.sched_setscheduler(0, *policy_before)
                except OSError:
                    pass
        out["overruns"], out["done"] = overruns, done

    if dedicated_thread:
        def guarded():
            try:
                body()
            except BaseException as exc:  # handed to the caller, as without the thread
                out["error"] = exc

        t = threading.Thread(target=guarded, name="hsio-rt-loop", daemon=True)
        t.start()
        t.join(max_seconds + 5.0)
        if t.is_alive():
            raise RuntimeError("the real-time loop did not finish in time")
        if "error" in out:
            raise out["error"]
    else:
        body()
    n = out["done"]
    return Timing(rate_hz, n, late[:n], out["overruns"], spent[:n], out["granted"], periods)
