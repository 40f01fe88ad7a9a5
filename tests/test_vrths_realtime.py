"""The periodic real-time loop: counts, pacing, overruns, bounds."""

from __future__ import annotations

import os
import time

import pytest

from hsio.rths.realtime import run_periodic


def test_periodic_loop_paces_and_counts():
    calls = []
    t0 = time.perf_counter()
    timing = run_periodic(calls.append, rate_hz=1024.0, periods=256)
    elapsed = time.perf_counter() - t0
    assert calls == list(range(256)) and timing.periods == 256
    # paced: never before its deadline, so the run cannot be shorter than its periods (a loaded
    # machine can make it longer, which is what the lateness figures report)
    assert timing.lateness_us.min() >= 0.0
    assert 255 / 1024.0 <= elapsed < 10.0
    s = timing.stats()
    assert 0 <= s["p50_us"] <= s["p99_us"] <= s["max_us"]
    assert set(s) >= {"p50_us", "p99_us", "max_us", "overruns_per_10k", "affinity", "sched_fifo"}


def test_slow_work_is_counted_as_overruns_and_the_loop_is_bounded():
    timing = run_periodic(lambda k: time.sleep(0.003), rate_hz=1024.0, periods=10_000, max_seconds=0.2,
                          dedicated_thread=False)
    assert timing.periods < 10_000  # stopped by the time bound
    assert timing.overruns == timing.periods or timing.overruns >= timing.periods - 1
    with pytest.raises(ValueError):
        run_periodic(lambda k: None, periods=0)


def test_a_period_after_an_overrun_reports_the_time_it_lost():
    """Work of 3 ms at 1024 Hz (0.98 ms): each period starts when the last one ends, at least
    3 - 0.98 ms after its own deadline, and says so; the grid then moves, so no burst follows."""
    period_us = 1e6 / 1024.0
    timing = run_periodic(lambda k: time.sleep(0.003), rate_hz=1024.0, periods=20, max_seconds=2.0,
                          dedicated_thread=False)
    assert timing.periods == 20 and timing.overruns >= 19
    assert timing.lateness_us[1:].min() >= 3000.0 - period_us
    assert timing.stats()["p50_us"] >= 3000.0 - period_us

    slow = {3}  # one long period among short ones
    timing = run_periodic(lambda k: time.sleep(0.0025) if k in slow else None, rate_hz=1024.0, periods=8,
                          max_seconds=2.0, dedicated_thread=False)
    assert timing.overruns >= 1 and timing.lateness_us[4] >= 2500.0 - period_us
    assert timing.stats()["max_us"] >= 2500.0 - period_us


def test_a_run_cut_by_its_time_bound_says_how_many_periods_were_asked_for():
    timing = run_periodic(lambda k: time.sleep(0.003), rate_hz=1024.0, periods=10_000, max_seconds=0.05,
                          dedicated_thread=False)
    s = timing.stats()
    assert s["periods"] < s["periods_requested"] == 10_000


@pytest.mark.parametrize("dedicated_thread", [True, False])
def test_an_error_in_the_work_reaches_the_caller_as_it_is(dedicated_thread):
    def work(k):
        if k == 5:
            raise RuntimeError("axis 0 lost")

    with pytest.raises(RuntimeError, match="axis 0 lost"):
        run_periodic(work, rate_hz=1024.0, periods=20, dedicated_thread=dedicated_thread)


@pytest.mark.parametrize("kwargs", [dict(periods=10**12), dict(rate_hz=float("inf")), dict(rate_hz=float("nan")),
                                    dict(max_seconds=float("inf")), dict(max_seconds=-1.0)])
def test_bounds_it_cannot_keep_are_refused(kwargs):
    """10^12 periods (no MemoryError), an infinite or NaN rate, a time bound that is not one."""
    args = dict(rate_hz=1024.0, periods=10, max_seconds=0.02, dedicated_thread=False) | kwargs
    with pytest.raises(ValueError, match="rate_hz must be in"):
        run_periodic(lambda k: None, **args)


def test_no_more_periods_are_recorded_than_fit_in_the_time_bound():
    timing = run_periodic(lambda k: None, rate_hz=1024.0, periods=5_000_000, max_seconds=0.02, dedicated_thread=False)
    assert 0 < timing.periods <= 0.02 * 1024 + 2 and timing.stats()["periods_requested"] == 5_000_000
    assert timing.lateness_us.size == timing.periods


@pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="no scheduling policies on this OS")
def test_the_callers_thread_gets_its_scheduling_back():
    """Without a thread of its own the loop raises the caller's thread to SCHED_FIFO and pins it
    (where permitted); both are given back when it ends."""
    policy, affinity = os.sched_getscheduler(0), os.sched_getaffinity(0)
    timing = run_periodic(lambda k: None, periods=10, dedicated_thread=False, fifo_priority=10, pin_cpu=0)
    if not timing.granted["sched_fifo"]:
        pytest.skip("SCHED_FIFO is not permitted here: nothing to give back")
    assert os.sched_getscheduler(0) == policy and os.sched_getaffinity(0) == affinity


@pytest.mark.parametrize("periods", ["0", "-5", "200000"])
def test_the_jitter_bench_refuses_a_period_count_it_would_not_measure(periods):
    """The table says how many periods it measured: a count outside 100-100,000 is refused, not clamped."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "bench" / "bench_jitter.py"
    proc = subprocess.run([sys.executable, str(script), "--periods", periods], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2 and "give 100 to 100000 periods" in proc.stderr, proc.stderr
