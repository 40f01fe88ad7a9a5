"""A measured actuator record: command, measured displacement and optional force, uniformly sampled."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hsio.errors import RecordError


@dataclass(frozen=True)
class ActuatorRecord:
    """``command_mm[k]`` is the command in force during sample k, ``measured_mm[k]`` the
    displacement measured at its end (mm); ``force_kN`` the measured force or None."""

    source: str
    dt: float
    command_mm: np.ndarray
    measured_mm: np.ndarray
    force_kN: np.ndarray | None = None

    def __post_init__(self):
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise RecordError(f"{self.source}: sampling interval must be positive, got {self.dt!r}")
        arrays = {"command_mm": self.command_mm, "measured_mm": self.measured_mm}
        if self.force_kN is not None:
            arrays["force_kN"] = self.force_kN
        n = None
        for name, values in arrays.items():
            a = np.asarray(values, dtype=float)
            if a.ndim != 1:
                raise RecordError(f"{self.source}: {name} must be one-dimensional")
            bad = np.flatnonzero(~np.isfinite(a))
            if bad.size:
                raise RecordError(f"{self.source}: {name} sample {bad[0]} is {a[bad[0]]!r}")
            if n is None:
                n = a.size
            elif a.size != n:
                raise RecordError(f"{self.source}: {name} has {a.size} samples, command_mm has {n}")
            object.__setattr__(self, name, a)
        if n < 100:
            raise RecordError(f"{self.source}: needs at least 100 samples, has {n}")

    @property
    def n(self) -> int:
        return self.command_mm.size

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.dt

    @property
    def time_s(self) -> np.ndarray:
        return np.arange(self.n) * self.dt

    @property
    def duration_s(self) -> float:
        return self.n * self.dt

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

