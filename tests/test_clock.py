"""The real-time clock's count of late periods, on an injected clock (no wall time measured)."""

from __future__ import annotations

import pytest

from hsio.clock import LATE_FRACTION, RealTimeClock

RATE = 1024.0
P = 1.0 / RATE


class FakeTime:
    """A clock whose sleeps wake ``oversleep`` (s) late and whose work per tick takes ``work``."""

    def __init__(self, oversleep: float = 0.0):
        self.t = 100.0
        self.oversleep = oversleep

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds + self.oversleep


def ticking(fake: FakeTime, n: int, work=lambda k: 0.0) -> RealTimeClock:
    clock = RealTimeClock(RATE, now=fake.now, sleep=fake.sleep)
    for k in range(n):
        fake.t += work(k)
        clock.tick()
    return clock


def test_a_loop_late_by_60_percent_of_every_period_is_counted_late_and_never_overruns():
    fake = FakeTime(oversleep=0.6 * P)
    clock = ticking(fake, 1000)
    assert clock.overruns == 0  # never a whole period behind
    assert clock.late == 1000  # but every period started 0.6 of a period late
    report = clock.lateness()
    assert report["max_late_s"] == pytest.approx(0.6 * P)
    assert 0.6 * P <= report["p99_late_s"] <= 0.6 * P + P / 64  # the upper edge of its 1/64-period bin
    assert report["periods"] == 1000 and report["late_fraction"] == LATE_FRACTION == 0.5


def test_lateness_within_the_fraction_is_on_time():
    clock = ticking(FakeTime(oversleep=0.4 * P), 1000)
    assert clock.late == 0 and clock.overruns == 0
    assert clock.lateness()["p99_late_s"] == pytest.approx(0.4 * P, abs=P / 64)


def test_work_longer_than_a_period_is_an_overrun_and_the_schedule_starts_again():
    """One tick whose work lasts 2.5 periods: an overrun, a late period; the schedule then starts
    from now, so the next periods are on time (no burst of commands to make the missed ones up)."""
    fake = FakeTime()
    clock = ticking(fake, 100, work=lambda k: 2.5 * P if k == 50 else 0.0)
    assert clock.overruns == 1 and clock.late == 1
    assert clock.max_late_s == pytest.approx(1.5 * P)
    before = fake.t
    clock.tick()
    assert fake.t - before == pytest.approx(P)  # a whole period's sleep: back on the schedule


def test_the_99th_percentile_is_of_the_periods_not_of_the_worst():
    """1 % of the periods start 0.9 of a period late, the others on time: p99 stays in the first
    bin, max says 0.9 of a period, and the late ones are counted."""
    fake = FakeTime()
    clock = RealTimeClock(RATE, now=fake.now, sleep=fake.sleep)
    for k in range(1000):
        fake.oversleep = 0.9 * P if k % 100 == 99 else 0.0
        clock.tick()
    report = clock.lateness()
    assert report["periods"] == 1000 and report["late"] == 10 and report["overruns"] == 0
    assert report["p99_late_s"] <= P / 64 and report["max_late_s"] == pytest.approx(0.9 * P)


def test_a_99th_percentile_beyond_the_histogram_is_none_in_valid_json():
    """Every period 5 periods late: beyond the histogram's 4 periods, p99 is None (null in
    summary.json; JSON has no infinity)."""
    import json

    fake = FakeTime()
    clock = RealTimeClock(RATE, now=fake.now, sleep=fake.sleep)
    for _ in range(200):
        fake.oversleep = 5 * P
        clock.tick()
    report = clock.lateness()
    assert report["p99_late_s"] is None
    json.loads(json.dumps(report, allow_nan=False))
