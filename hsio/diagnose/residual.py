"""What the model cannot explain: the sensor floor and the structure left in a residual.

* The sensor floor is what no model of the actuator can predict: the transducer's noise and
  its quantisation. It is estimated from the data in three ways: the quantisation step q
  (the spacing of the recorded values; its error has an RMS of q / sqrt(12)), the still
  parts of the record (the measurement's scatter while the command rests) and the
  high-frequency content of the residual (white noise of RMS s gives second differences of
  RMS s sqrt(6), while a smooth model error gives almost none). The floor is the largest of
  the high-frequency and quantisation estimates, and never below the arithmetic's own floor,
  PRECISION times the measurement's range (a noise-free record of the model itself leaves
  rounding errors of about 1e-15 of it, and the fits converge to about 1e-10 of it: no model
  error; the finest transducer, a 24-bit converter, resolves 6e-8 of its range).
* The structure of a residual r (measured - model, on the samples the fit did not see):
  spectral lines (a narrow peak of the amplitude spectrum standing well above its
  neighbourhood, with its frequency and sinusoidal amplitude), a slow trend (least-squares
  slope of r against time over the whole record) and the share of r that the velocity, the
  acceleration and the force explain together (the R^2 of a linear regression on them).

A residual reaches the floor when its RMS is within FLOOR_FACTOR floors and it holds no line
and no trend.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, signal

FLOOR_FACTOR = 1.5  # a residual above this many floors is "well above the floor"
LINE_PROMINENCE = 25.0  # a line's spectral density over the median of its neighbourhood
TREND_FLOORS = 2.0  # a trend is reported when it moves the residual by this many floors over the record
PRECISION = 1e-8  # the least floor, as a share of the measurement's range: below it an error is rounding


def precision_floor(measured: np.ndarray) -> float:
    """The least error a model can be said to leave: PRECISION times the range of ``measured``."""
    return PRECISION * float(np.ptp(measured)) if measured.size else 0.0


@dataclass
class Floor:
    sensor_floor_mm: float
    quantisation_mm: float
    still_rms_mm: float | None  # None: the command never rests long enough
    high_frequency_rms_mm: float

    def to_json(self) -> dict:
        return {"sensor_floor_mm": self.sensor_floor_mm, "quantisation_mm": self.quantisation_mm,
                "still_rms_mm": self.still_rms_mm, "high_frequency_rms_mm": self.high_frequency_rms_mm}


@dataclass
class Structure:
    rms_test_mm: float
    lines: list[dict] = field(default_factory=list)  # {"hz", "amplitude_mm"}
    trend_mm_per_s: float = 0.0
    trend_significant: bool = False
    r2_motion: float = 0.0  # share of the residual's variance that v, a and F explain linearly
    correlations: dict = field(default_factory=dict)

    @property
    def structured(self) -> bool:
        """A line or a trend stands out of the noise."""
        return bool(self.lines) or self.trend_significant


def quantisation_step(x: np.ndarray) -> float:
    """The spacing of the recorded values (0 when they do not sit on a grid)."""
    d = np.abs(np.diff(x))
    d = d[d > 1e-12 * max(np.max(np.abs(x)), 1.0)]
    if d.size < 10:
        return 0.0
    q = float(np.percentile(d, 1))
    ratio = d / q
    on_grid = np.mean(np.abs(ratio - np.round(ratio)) < 0.05)
    return q if on_grid > 0.9 else 0.0


def still_rms(command: np.ndarray, measured: np.ndarray, dt: float, window_s: float = 0.25) -> float | None:
    """The median RMS scatter of the measurement in windows where the command does not move."""
    w = max(int(round(window_s / dt)), 20)
    rms = []
    for start in range(0, command.size - w, w):
        c = command[start:start + w]
        if np.ptp(c) <= 1e-9 * max(np.max(np.abs(command)), 1.0):
            m = measured[start:start + w]
            rms.append(float(np.std(m)))
    return float(np.median(rms)) if len(rms) >= 2 else None


def high_frequency_rms(residual: np.ndarray) -> float:
    """The RMS of the white part of a residual, from its second differences (robust: median
    absolute deviation, so that a few large errors do not count as noise)."""
    d2 = np.diff(residual, 2)
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


def sensor_floor(command: np.ndarray, measured: np.ndarray, residual: np.ndarray, dt: float) -> Floor:
    q = quantisation_step(measured)
    hf = high_frequency_rms(residual)
    still = still_rms(command, measured, dt)
    return Floor(max(hf, q / math.sqrt(12.0), precision_floor(measured)), q, still, hf)


def spectral_lines(r: np.ndarray, dt: float, floor_mm: float, lowest_hz: float = 0.5) -> list[dict]:
    """Narrow peaks of the residual's spectrum: frequency (centroid of the peak) and amplitude
    of the sinusoid (A^2 / 2 = the peak's power above its neighbourhood)."""
    fs = 1.0 / dt
    nper = int(min(r.size, 2 ** int(np.log2(max(4.0 * fs, 64)))))
    if nper < 64:
        return []
    f, p = signal.welch(r - r.mean(), fs=fs, nperseg=nper)
    df = f[1] - f[0]
    background = ndimage.median_filter(p, size=41, mode="nearest")
    peaks, _ = signal.find_peaks(p, distance=5)
    lines = []
    for k in peaks:
        if f[k] < lowest_hz or p[k] < LINE_PROMINENCE * background[k]:
            continue
        span = slice(max(k - 3, 0), k + 4)
        excess = np.clip(p[span] - background[span], 0.0, None)
        amplitude = math.sqrt(2.0 * float(np.sum(excess)) * df)
        if amplitude < floor_mm:
            continue
        hz = float(np.sum(f[span] * excess) / max(np.sum(excess), 1e-300))
        lines.append({"hz": hz, "amplitude_mm": amplitude})
    lines.sort(key=lambda line: -line["amplitude_mm"])
    return lines[:5]


def trend(residual: np.ndarray, dt: float) -> float:
    """Least-squares slope of a residual against time (mm/s)."""
    t = np.arange(residual.size) * dt
    return float(np.polyfit(t, residual, 1)[0])


def structure(residual: np.ndarray, n_held: int, dt: float, floor_mm: float, velocity: np.ndarray,
              force: np.ndarray | None) -> Structure:
    """The structure of ``residual`` (whole record; samples from ``n_held`` on are the scoring block)."""
    held = residual[n_held:]
    slope = trend(residual, dt)
    duration = residual.size * dt
    acceleration = np.gradient(velocity, dt)
    regressors = {"velocity": velocity[n_held:], "acceleration": acceleration[n_held:]}
    if force is not None:
        regressors["force"] = force[n_held:]
    corr = {}
    columns = [np.ones(held.size)]
    for name, x in regressors.items():
        s = np.std(x)
        corr[name] = float(np.corrcoef(held, x)[0, 1]) if s > 0 and np.std(held) > 0 else 0.0
        if s > 0:
            columns.append((x - x.mean()) / s)
    a = np.column_stack(columns)
    coef, *_ = np.linalg.lstsq(a, held, rcond=None)
    var = float(np.var(held))
    r2 = 1.0 - float(np.var(held - a @ coef)) / var if var > 0 else 0.0
    return Structure(float(np.sqrt(np.mean(held**2))), spectral_lines(held, dt, floor_mm), float(slope),
                     bool(abs(slope) * duration > TREND_FLOORS * floor_mm), float(max(r2, 0.0)), corr)


def remains(s: Structure, floor: Floor) -> str:
    """A sentence on what the residual still holds."""
    parts = []
    for line in s.lines:
        parts.append(f"a line at {line['hz']:.2f} Hz of {line['amplitude_mm']:.4f} mm")
    if s.trend_significant:
        parts.append(f"a trend of {1e3 * s.trend_mm_per_s:.4g} um/s")
    if s.r2_motion > 0.2:
        strongest = max(s.correlations, key=lambda k: abs(s.correlations[k]))
        parts.append(f"a part that follows the motion ({100 * s.r2_motion:.0f} % of its variance; strongest with "
                     f"the {strongest}, r = {s.correlations[strongest]:+.2f})")
    head = f"scoring-block RMS {s.rms_test_mm:.4f} mm against a sensor floor of {floor.sensor_floor_mm:.4f} mm"
    if not parts:
        return head + "; no line, trend or correlation with the motion stands out (broadband)"
    return head + "; it holds " + ", ".join(parts)
