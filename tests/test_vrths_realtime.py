"""The periodic real-time loop: counts, pacing, overruns, bounds."""

from __future__ import annotations

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
