"""The evaluation criteria J1-J9 of the benchmark (Silva et al. 2020).

Tracking (desired x_t: the numerical substructure's first-floor displacement; measured x_m):

    J1 = (fs^-1 argmax_k R(k)) in ms, R the cross-correlation of x_m against x_t   (time delay)
    J2 = 100 std(x_m - x_t) / std(x_t)                                               (RMS error, %)
    J3 = 100 max|x_m - x_t| / max|x_t|                                               (peak error, %)

Performance, against the reference model's floor displacements x_ref,i:

    J4, J5 = RMS and peak error of floor 1 (x_m against x_ref,1)
    J6, J7 = RMS error of floors 2 and 3 (numerical substructure against x_ref,2 and x_ref,3)
    J8, J9 = peak error of floors 2 and 3
"""

from __future__ import annotations

import numpy as np
from scipy import signal


def delay_ms(x_t: np.ndarray, x_m: np.ndarray, fs: float) -> float:
    """J1: the lag (ms) at which x_m best matches x_t delayed; positive when x_m lags."""
    r = signal.correlate(x_m, x_t, mode="full", method="fft")
    lags = signal.correlation_lags(x_m.size, x_t.size, mode="full")
    return 1e3 * float(lags[int(np.argmax(r))]) / fs


def rms_error(x: np.ndarray, ref: np.ndarray) -> float:
    return 100.0 * float(np.std(x - ref) / np.std(ref))


def peak_error(x: np.ndarray, ref: np.ndarray) -> float:
    return 100.0 * float(np.max(np.abs(x - ref)) / np.max(np.abs(ref)))


def j1_to_j9(x_t: np.ndarray, x_m: np.ndarray, floors: np.ndarray, x_ref: np.ndarray, fs: float) -> list[float]:
    """J1-J9; ``floors`` (n x 3) holds x_m at floor 1 and the numerical floors 2 and 3."""
    return [
        delay_ms(x_t, x_m, fs),
        rms_error(x_m, x_t),
        peak_error(x_m, x_t),
        rms_error(x_m, x_ref[:, 0]),
        peak_error(x_m, x_ref[:, 0]),
        rms_error(floors[:, 1], x_ref[:, 1]),
        rms_error(floors[:, 2], x_ref[:, 2]),
        peak_error(floors[:, 1], x_ref[:, 1]),
        peak_error(floors[:, 2], x_ref[:, 2]),
    ]
