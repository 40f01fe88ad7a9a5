"""A measured actuator record: command, measured displacement and optional force, uniformly sampled."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hsio.errors import RecordError


MIN_SAMPLES = 100
MAX_MAGNITUDE = 1e6  # mm or kN: a kilometre, a giganewton; larger is no transducer's reading (wrong scale or column)


def checked_channels(record, names: tuple[str, ...]) -> None:
    """Check a record's sampling interval and channels (``names``; None skipped): each one-dimensional,
    finite, within MAX_MAGNITUDE and as long as the first, at least MIN_SAMPLES; store them as
    float arrays."""
    if not (math.isfinite(record.dt) and record.dt > 0):
        raise RecordError(f"{record.source}: sampling interval must be positive, got {record.dt!r}")
    n = None
    for name in names:
        values = getattr(record, name)
        if values is None:
            continue
        a = np.asarray(values, dtype=float)
        if a.ndim != 1:
            raise RecordError(f"{record.source}: {name} must be one-dimensional")
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise RecordError(f"{record.source}: {name} sample {bad[0]} is {a[bad[0]]!r}")
        huge = np.flatnonzero(np.abs(a) > MAX_MAGNITUDE)
        if huge.size:
            raise RecordError(f"{record.source}: {name} sample {huge[0]} is {a[huge[0]]:g}, beyond {MAX_MAGNITUDE:g} "
                              "(mm or kN): no transducer reads that; check the column and its scale")
        if n is None:
            n = a.size
        elif a.size != n:
            raise RecordError(f"{record.source}: {name} has {a.size} samples, {names[0]} has {n}")
        object.__setattr__(record, name, a)
    if n < MIN_SAMPLES:
        raise RecordError(f"{record.source}: needs at least {MIN_SAMPLES} samples, has {n}")


class Sampled:
    """Time base of a uniformly sampled record (``dt`` and ``n`` given by the record)."""

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.dt

    @property
    def time_s(self) -> np.ndarray:
        return np.arange(self.n) * self.dt

    @property
    def duration_s(self) -> float:
        return self.n * self.dt


@dataclass(frozen=True)
class ActuatorRecord(Sampled):
    """``command_mm[k]`` is the command in force during sample k, ``measured_mm[k]`` the
    displacement measured at its end (mm); ``force_kN`` the measured force or None;
    ``controller_dt`` the servo loop's period (s) when it is known (hsio/diagnose/loop_rate.py),
    None when the record's rate is taken as the loop's."""

    source: str
    dt: float
    command_mm: np.ndarray
    measured_mm: np.ndarray
    force_kN: np.ndarray | None = None
    controller_dt: float | None = None

    def __post_init__(self):
        checked_channels(self, ("command_mm", "measured_mm", "force_kN"))

    @property
    def n(self) -> int:
        return self.command_mm.size

    @property
    def loop_dt(self) -> float:
        """The period the model steps at: the controller's, else the record's."""
        return self.controller_dt if self.controller_dt is not None else self.dt

    def command_velocity(self) -> np.ndarray:
        """Backward difference of the command, mm/s (E&M 2007, section 4: v_i = (d_i - d_{i-1}) / t_d)."""
        v = np.empty(self.n)
        v[0] = 0.0
        v[1:] = np.diff(self.command_mm) / self.dt
        return v

    def smoothed_velocity(self, width_s: float = 0.005) -> np.ndarray:
        """Central difference of the command over about ``width_s`` (mm/s): readable where the
        recorded command is a staircase (a controller updating it slower than the DAQ samples)."""
        h = max(1, int(round(0.5 * width_s / self.dt)))
        c = np.pad(self.command_mm, h, mode="edge")
        return (c[2 * h:] - c[:-2 * h]) / (2 * h * self.dt)

