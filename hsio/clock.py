"""Controller-rate clocks: lockstep (advanced by the experiment) or real time.

The experiment calls :meth:`Clock.tick` once per controller period (1/1024 s by default).

* :class:`LockstepClock` advances every attached device (an emulated controller, in process or
  over the wire) by one period and returns at once: fast, deterministic runs for CI.
* :class:`RealTimeClock` sleeps until the next period is due: devices run their own loops.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from typing import Protocol

CONTROLLER_RATE_HZ = 1024.0
# A real-time run (or probe move) warns when more than this fraction of its periods overran.
OVERRUN_WARNING = 0.01
# A period starts late (it misses its deadline) when it starts more than this fraction of a
# period after it was due: half a period is as late as a command sample may be and still be
# nearer its own period than the next.
LATE_FRACTION = 0.5
# Lateness is kept as a histogram in steps of 1/LATENESS_BINS_PER_PERIOD of a period, up to
# LATENESS_PERIODS periods (the last bin holds all beyond): bounded memory on any run.
LATENESS_BINS_PER_PERIOD = 64
LATENESS_PERIODS = 4


class Steppable(Protocol):
    """A device whose clock the experiment advances (an emulator in lockstep)."""

    def advance(self, ticks: int) -> None: ...


class Clock(ABC):
    """A controller-rate clock. ``ticks`` counts periods since start."""

    def __init__(self, rate_hz: float = CONTROLLER_RATE_HZ):
        if not rate_hz > 0:
            raise ValueError(f"clock rate must be positive, got {rate_hz!r}")
        self.rate_hz = float(rate_hz)
        self.period_s = 1.0 / self.rate_hz
        self.ticks = 0

    @property
    def now_s(self) -> float:
        return self.ticks * self.period_s

    @abstractmethod
    def tick(self) -> None:
        """Let one controller period pass."""

    def attach(self, device: Steppable) -> None:
        """Register a device that must be advanced with the clock (lockstep only)."""


class LockstepClock(Clock):
    """Advanced by the experiment: each tick steps every attached device by one period."""

    lockstep = True

    def __init__(self, rate_hz: float = CONTROLLER_RATE_HZ):
        super().__init__(rate_hz)
        self._devices: list[Steppable] = []

    def attach(self, device: Steppable) -> None:
        if device not in self._devices:
            self._devices.append(device)

    def tick(self) -> None:
        for device in self._devices:
            device.advance(1)
        self.ticks += 1


class RealTimeClock(Clock):
    """Wall-clock periods: :meth:`tick` sleeps until the next period is due.

    ``overruns`` counts periods that started late by more than one period (the host could not
    keep up: a pause, a slow request); the run summary reports it. After an
    overrun the schedule starts again from now, so that the periods missed are not made up in a
    burst of commands.

    Every tick also measures how late its period starts (when :meth:`tick` returns, after the
    sleep, against the time it was due): ``late`` counts the periods that start more than
    :data:`LATE_FRACTION` of a period late (a loop late by 60 % of a period every tick misses
    every deadline and never overruns), ``max_late_s`` is the largest lateness and
    :meth:`lateness` gives these with the 99th percentile.

    ``now`` and ``sleep`` are the clock and the sleep it uses (``time.perf_counter`` and
    ``time.sleep``; a test passes its own).
    """

    lockstep = False

    def __init__(self, rate_hz: float = CONTROLLER_RATE_HZ, now=time.perf_counter, sleep=time.sleep):
        super().__init__(rate_hz)
        self._now, self._sleep = now, sleep
        self._start = now()
        self.overruns = 0
        self.late = 0
        self.max_late_s = 0.0
        self._bins = [0] * (LATENESS_BINS_PER_PERIOD * LATENESS_PERIODS + 1)

    def tick(self) -> None:
        self.ticks += 1
        due = self._start + self.ticks * self.period_s
        delay = due - self._now()
        if delay > 0:
            self._sleep(delay)
        elif -delay > self.period_s:
            self.overruns += 1
            self._start = self._now() - self.ticks * self.period_s
        self._count(self._now() - due)

    def _count(self, late_s: float) -> None:
        """One period that started ``late_s`` after it was due (<= 0: on time)."""
        late_s = max(late_s, 0.0)
        if late_s > LATE_FRACTION * self.period_s:
            self.late += 1
        self.max_late_s = max(self.max_late_s, late_s)
        self._bins[min(int(late_s / self.period_s * LATENESS_BINS_PER_PERIOD), len(self._bins) - 1)] += 1

    def lateness(self) -> dict:
        """Lateness of the period starts so far: the periods, how many started more than
        ``late_fraction`` of a period late (``late``) and more than one whole period behind their
        work (``overruns``), the largest lateness and the 99th percentile (s; the upper edge of
        its 1/64-period bin, None beyond 4 periods: JSON has no infinity)."""
        total = sum(self._bins)
        p99 = 0.0
        if total:
            need, seen = 0.99 * total, 0
            for k, count in enumerate(self._bins):
                seen += count
                if seen >= need:
                    p99 = (k + 1) / LATENESS_BINS_PER_PERIOD * self.period_s if k < len(self._bins) - 1 else None
                    break
        return {"periods": total, "late": self.late, "late_fraction": LATE_FRACTION, "overruns": self.overruns,
                "max_late_s": self.max_late_s, "p99_late_s": p99}
