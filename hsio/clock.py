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
    keep up: a pause, a slow request); the run summary reports it. After an overrun the schedule
    starts again from now, so that the periods missed are not made up in a burst of commands.
    """

    lockstep = False

    def __init__(self, rate_hz: float = CONTROLLER_RATE_HZ):
        super().__init__(rate_hz)
        self._start = time.perf_counter()
        self.overruns = 0

    def tick(self) -> None:
        self.ticks += 1
        due = self._start + self.ticks * self.period_s
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        elif -delay > self.period_s:
            self.overruns += 1
            self._start = time.perf_counter() - self.ticks * self.period_s
