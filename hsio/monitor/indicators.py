"""The error monitors of a hybrid test, from the commanded and the measured displacement
(docs/monitor.md section 3).

* tracking error: command minus measurement at the end of each step, e(i) = d_c(i) - d_m(i);
* its amplitude spectrum, over the last samples of the controller (or the last steps);
* the tracking indicator: the signed area swept by the curve of measured against commanded
  displacement,

      TI(n) = 1/2 sum_{i=1..n} ( d_m(i-1) d_c(i) - d_c(i-1) d_m(i) )        (mm^2)

  which is minus the area enclosed counter-clockwise in the (d_c, d_m) plane. A measurement that
  lags its command traces the loop counter-clockwise, so TI falls: over one cycle of
  d_c = A sin(w t), d_m = A sin(w t - phi), TI changes by -pi A^2 sin(phi). A lag adds energy to
  the test (negative damping), so a falling, negative TI warns of a drift toward instability; a
  lead (overshoot) makes it grow.
* margins: how far each channel stands from its limits, as a fraction of the limit.

At the end of each step the monitor takes as d_c the target, the integrator's command to the
actuator before any compensation adjusts it (``target_`` in the record); over controller samples,
the command the controller was given (``cmd_``).
"""

from __future__ import annotations

import numpy as np


def tracking_indicator(command: np.ndarray, measured: np.ndarray, start: float = 0.0,
                       previous: tuple[float, float] | None = None) -> np.ndarray:
    """TI after each of the points of ``command`` and ``measured`` (mm), continuing from ``start``
    (the TI before the first point) and the point ``previous`` = (d_c, d_m) before them (None:
    the first point opens the curve)."""
    dc = np.asarray(command, dtype=float)
    dm = np.asarray(measured, dtype=float)
    if dc.size == 0:
        return np.zeros(0)
    if previous is None:
        pc, pm = dc[:1], dm[:1]
    else:
        pc, pm = np.array([previous[0]]), np.array([previous[1]])
    c0 = np.concatenate([pc, dc[:-1]])
    m0 = np.concatenate([pm, dm[:-1]])
    area = 0.5 * (m0 * dc - c0 * dm)
    area[~np.isfinite(area)] = 0.0
    return start + np.cumsum(area)


def error_spectrum(error: np.ndarray, rate_hz: float, f_max_hz: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    """One-sided amplitude spectrum of ``error`` sampled at ``rate_hz``: (frequency in Hz,
    amplitude in the error's unit), with a Hann window (amplitude corrected by its mean, so a sine
    of amplitude A reads A when its frequency falls on a bin, a multiple of rate_hz / len(error);
    half-way between two bins its peak reads 0.85 A), the mean removed, up to ``f_max_hz``."""
    e = np.asarray(error, dtype=float)
    e = e[np.isfinite(e)]
    if e.size < 8 or rate_hz <= 0:
        return np.zeros(0), np.zeros(0)
    e = e - e.mean()
    w = np.hanning(e.size)
    amplitude = 2.0 * np.abs(np.fft.rfft(e * w)) / w.sum()
    f = np.fft.rfftfreq(e.size, 1.0 / rate_hz)
    keep = f <= f_max_hz
    return f[keep], amplitude[keep]


def margin(value: np.ndarray | float, limit: np.ndarray | float | None) -> np.ndarray | float:
    """1 - |value| / limit: 1 far from the limit, 0 at it, negative beyond (NaN: no limit known);
    ``limit`` may be given per value."""
    if limit is None:
        limit = np.nan
    limit = np.asarray(limit, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(limit > 0, 1.0 - np.abs(value) / np.where(limit > 0, limit, 1.0), np.nan)
    return out if np.ndim(out) else float(out)
