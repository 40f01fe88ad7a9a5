"""Secant stiffness of each experimental DOF from controller-rate feedback (docs/method.md eq. 11, section 5).

Within integration step i+1, iteration j, the secant stiffness of an element is

    k^j_{i+1} = (R^{j-1}_{i+1} - R_i) / (u^{j-1}_{i+1} - u_i)                        (11)

where (u_i, R_i) is the measured state at the end of step i (the *base*) and (u^{j-1}, R^{j-1}) what
was measured after the previous iteration. The measurement comes as controller-rate samples
(1024 Hz) of displacement and force. Three estimators, selected by name:

* ``raw``: the last sample of the iteration. Near a peak, where the increment is of the order of the
  sensor noise and resolution, the quotient spikes (to large or negative values).
* ``average``: the mean of the last ``n_avg`` samples of the iteration, for force and displacement
  (the paper: N_avg = 100 of 2048 samples per step). Averaging dithers the quantisation away.
* ``least_squares``: the slope through the base that fits every sample of the step so far,
  k = sum(du dR) / sum(du^2) with du = u - u_i, dR = R - R_i; suggested for fast test rates,
  where an iteration has few samples. The denominator cannot vanish with noise present.

An estimate is refused (``nan``: the caller keeps its previous stiffness) when the displacement
increment is below ``min_increment`` or the result is not a finite positive number.
"""

from __future__ import annotations

import numbers

import numpy as np

from hsio.errors import ConfigError

METHODS = ("raw", "average", "least_squares")


class SecantEstimator:
    """Secant stiffness per element from samples (n_samples x n_elements, displacement and force).

    Call :meth:`begin_step` with the base state, then :meth:`update` after each iteration with
    that iteration's samples; it returns the measured pair (u, R) per element and the secant k
    (``nan`` where no estimate is possible).
    """

    def __init__(self, method: str = "average", n_avg: int = 100, min_increment: float = 0.0):
        if method not in METHODS:
            raise ConfigError(f"secant stiffness: method must be one of {', '.join(METHODS)}, got {method!r}")
        if isinstance(n_avg, bool) or not isinstance(n_avg, numbers.Integral) or n_avg < 1:
            raise ConfigError(f"secant stiffness: n_avg must be a whole number of samples, at least 1, got {n_avg!r}")
        if isinstance(min_increment, bool) or not isinstance(min_increment, numbers.Real) or not min_increment >= 0:
            raise ConfigError(f"secant stiffness: min_increment must be zero or positive, got {min_increment!r}")
        self.method = method
        self.n_avg = int(n_avg)
        self.min_increment = float(min_increment)
        self.u_base: np.ndarray | None = None
        self.R_base: np.ndarray | None = None
        self._sum_uu = None
        self._sum_uR = None
        self.last_estimate: np.ndarray | None = None

    def begin_step(self, u_base, R_base) -> None:
        """Start a step from the measured base state (u_i, R_i) per element."""
        self.u_base = np.asarray(u_base, dtype=float).copy()
        self.R_base = np.asarray(R_base, dtype=float).copy()
        self._sum_uu = np.zeros_like(self.u_base)
        self._sum_uR = np.zeros_like(self.u_base)

    def pair(self, displacement: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The measured (u, R) per element of one iteration's samples (n x n_elements)."""
        d = np.atleast_2d(np.asarray(displacement, dtype=float))
        f = np.atleast_2d(np.asarray(force, dtype=float))
        if self.method == "raw":
            return d[-1].copy(), f[-1].copy()
        return d[-self.n_avg:].mean(axis=0), f[-self.n_avg:].mean(axis=0)

    def update(self, displacement: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Add one iteration's samples; return the measured pair and the secant k per element."""
        if self.u_base is None:
            raise RuntimeError("secant stiffness: call begin_step() first")
        d = np.atleast_2d(np.asarray(displacement, dtype=float))
        f = np.atleast_2d(np.asarray(force, dtype=float))
        u, R = self.pair(d, f)
        du = u - self.u_base
        if self.method == "least_squares":
            dd = d - self.u_base
            self._sum_uu += np.sum(dd * dd, axis=0)
            self._sum_uR += np.sum(dd * (f - self.R_base), axis=0)
            with np.errstate(divide="ignore", invalid="ignore"):
                k = self._sum_uR / self._sum_uu
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                k = (R - self.R_base) / du
        self.last_estimate = k.copy()  # before refusal: what the quotient gave
        refused = ~np.isfinite(k) | (k <= 0) | (np.abs(du) <= self.min_increment)
        if self.method != "least_squares":
            refused |= du == 0
        k = np.where(refused, np.nan, k)
        return u, R, k


def secant_stiffness(u, R, u_base, R_base) -> np.ndarray:
    """Eq. (11) on exact values (numerical substructures): nan where the increment is zero."""
    u, R = np.asarray(u, dtype=float), np.asarray(R, dtype=float)
    du = u - np.asarray(u_base, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        k = (R - np.asarray(R_base, dtype=float)) / du
    return np.where(np.isfinite(k) & (k > 0) & (du != 0), k, np.nan)
