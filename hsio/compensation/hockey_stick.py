"""The hockey-stick model of actuator execution error (docs/method.md section 4, eq. 1) and its fit.

Execution error normalised by the stroke, Er = (d_c - d_m) / d_max, against the command
velocity v:

    Er = 0                          if |v| <= a
    Er = sign(v) b (|v| - a)        if |v| >  a                                        (eq. 1)

b d_max is a lag time (s). :func:`fit` finds a and b by nonlinear least squares (the threshold is
a parameter of the fit, not a grid value) and reports their standard deviations from the
Jacobian at the optimum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from hsio.errors import HsioError

D_MAX_MM = 254.0  # the paper's stroke, the normalisation of eq. 1
TOP_BREAKS = 200  # break points of the fit's coarse search among the fastest steps


def excess_velocity(v, a: float):
    """sign(v) max(|v| - a, 0): the part of the velocity beyond the threshold."""
    v = np.asarray(v, dtype=float)
    return np.sign(v) * np.maximum(np.abs(v) - a, 0.0)


def error(v, a: float, b: float):
    """Er of eq. 1 (dimensionless, a fraction of d_max)."""
    return b * excess_velocity(v, a)


def last_velocity(history, t_d: float, order: int = 2) -> float:
    """Velocity at the last of the per-step commands ``history`` (oldest first, up to three used):
    order 1 the mean over the step, order 2 the backward quadratic (see :func:`step_velocity`)."""
    h = list(history)[-3:]
    if len(h) < 2:
        return 0.0
    if order == 1 or len(h) == 2:
        return (h[-1] - h[-2]) / t_d
    return (3.0 * h[2] - 4.0 * h[1] + h[0]) / (2.0 * t_d)


def step_velocity(d, t_d: float, order: int = 1) -> np.ndarray:
    """Command velocity at each step from the per-step commands d (one every t_d).

    order 1 is the paper's v_i = (d_i - d_{i-1}) / t_d (the mean velocity over the step);
    order 2 the backward quadratic (3 d_i - 4 d_{i-1} + d_{i-2}) / (2 t_d), the velocity at the
    end of the step, which the command generator also uses. The first values use fewer points.
    """
    d = np.asarray(d, dtype=float)
    v = np.zeros_like(d)
    if d.size < 2:
        return v
    v[1:] = np.diff(d) / t_d
    if order == 2 and d.size > 2:
        v[2:] = (3.0 * d[2:] - 4.0 * d[1:-1] + d[:-2]) / (2.0 * t_d)
    elif order not in (1, 2):
        raise ValueError(f"velocity order must be 1 or 2, got {order!r}")
    return v


@dataclass(frozen=True)
class HockeyStick:
    """Fitted (or given) parameters of eq. 1, with standard deviations where fitted."""

    a_mm_s: float
    b_s_mm: float
    a_std: float = float("nan")
    b_std: float = float("nan")
    n: int = 0
    rms_residual: float = float("nan")  # of Er (dimensionless)
    d_max_mm: float = D_MAX_MM

    @property
    def lag_s(self) -> float:
        """b d_max: the lag time beyond the threshold."""
        return self.b_s_mm * self.d_max_mm

    def error(self, v):
        return error(v, self.a_mm_s, self.b_s_mm)

    def to_json(self) -> dict:
        out = {"a_mm_s": self.a_mm_s, "b_s_mm": self.b_s_mm, "lag_s": self.lag_s,
               "a_std": self.a_std, "b_std": self.b_std, "n": self.n}
        return {k: (None if isinstance(x, float) and not math.isfinite(x) else x) for k, x in out.items()}


class FitError(HsioError):
    """The data do not determine the hockey stick (too few points or no motion beyond a)."""


def _profile_b(v: np.ndarray, er: np.ndarray, a: float) -> tuple[float, float]:
    """For a fixed threshold a, the least-squares slope b and the sum of squared residuals."""
    x = excess_velocity(v, a)
    xx = float(x @ x)
    if xx <= 0.0:
        return 0.0, float(er @ er)
    b = float(x @ er) / xx
    r = er - b * x
    return b, float(r @ r)


def fit(v, er, d_max_mm: float = D_MAX_MM, a_max: float | None = None) -> HockeyStick:
    """Least-squares fit of a and b of eq. 1 to velocities v (mm/s) and errors Er (fraction of d_max).

    The sum of squares is continuous in a (the model is), so the threshold is found by a bounded
    scalar search on the profile (b solved in closed form for each a) started from the best of
    the sorted |v| break points, and then refined jointly by Gauss-Newton (scipy least_squares).
    Uncertainties: covariance s^2 (J^T J)^-1 at the optimum, s^2 = SSR / (n - 2).
    """
    v = np.asarray(v, dtype=float).ravel()
    er = np.asarray(er, dtype=float).ravel()
    if v.shape != er.shape:
        raise ValueError(f"velocity and error differ in length: {v.size} and {er.size}")
    keep = np.isfinite(v) & np.isfinite(er)
    v, er = v[keep], er[keep]
    n = v.size
    if n < 5:
        raise FitError(f"hockey-stick fit needs at least 5 steps, got {n}")
    speeds = np.abs(v)
    top = float(np.max(speeds))
    if top <= 0.0:
        raise FitError("hockey-stick fit: the command never moves")
    a_hi = min(a_max, top) if a_max is not None else top
    # Coarse start: the SSR at a set of break points (quantiles of |v|, and the fastest 5 % of the
    # steps one by one, at most TOP_BREAKS of them: a threshold that only the fastest steps pass,
    # as in a slow test, has its own minimum there), then a bounded search between neighbours.
    fastest = np.sort(speeds)[int(0.95 * n):]
    fastest = fastest[np.unique(np.linspace(0, fastest.size - 1, min(fastest.size, TOP_BREAKS)).astype(int))]
    grid = np.unique(np.concatenate([[0.0], np.quantile(speeds, np.linspace(0.0, 0.95, 40)), fastest]))
    grid = grid[grid <= a_hi]
    ssr = [_profile_b(v, er, a)[1] for a in grid]
    j = int(np.argmin(ssr))
    lo = grid[max(j - 1, 0)]
    hi = grid[min(j + 1, len(grid) - 1)] if j + 1 < len(grid) else a_hi
    if hi > lo:
        res = scipy.optimize.minimize_scalar(lambda a: _profile_b(v, er, a)[1], bounds=(lo, hi), method="bounded",
                                             options={"xatol": 1e-6 * max(top, 1.0)})
        a0 = float(res.x) if res.fun <= ssr[j] else float(grid[j])
    else:
        a0 = float(grid[j])
    b0, _ = _profile_b(v, er, a0)
    if b0 <= 0.0:
        raise FitError("hockey-stick fit: the error does not grow with velocity (b <= 0); is the run continuous "
                       "(hold_fraction = 0) and uncompensated?")

    def residuals(p):
        return error(v, p[0], p[1]) - er

    def jacobian(p):
        x = excess_velocity(v, p[0])
        da = np.where(np.abs(v) > p[0], -p[1] * np.sign(v), 0.0)
        return np.column_stack([da, x])

    scale = np.array([max(a0, 1.0), b0])
    sol = scipy.optimize.least_squares(residuals, [a0, b0], jac=jacobian, bounds=([0.0, 0.0], [a_hi, np.inf]),
                                       x_scale=scale, method="trf")
    a, b = (float(x) for x in sol.x)
    a = 0.0 if a < 1e-9 * max(top, 1.0) else a  # on the bound: no threshold
    r = sol.fun
    dof = max(n - 2, 1)
    s2 = float(r @ r) / dof
    J = jacobian(sol.x)
    if np.linalg.matrix_rank(J) < 2:
        beyond = speeds[speeds > a]
        raise FitError(f"hockey-stick fit: every step beyond the threshold moves at one speed "
                       f"({float(np.median(beyond)) if beyond.size else top:g} mm/s): eq. 1 fixes only b (|v| - a) "
                       "there, not a and b apart; calibrate on motion at several speeds (a record or a sine)")
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
        a_std, b_std = (float(math.sqrt(max(c, 0.0))) for c in np.diag(cov))
    except np.linalg.LinAlgError:
        a_std = b_std = float("nan")
    return HockeyStick(a, b, a_std, b_std, n, float(math.sqrt(float(r @ r) / n)), d_max_mm)


def from_steps(command_mm, measured_mm, t_d: float, d_max_mm: float = D_MAX_MM, order: int = 1,
               skip: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and Er per step from per-step commands and measurements (the first ``skip`` dropped)."""
    c = np.asarray(command_mm, dtype=float)
    m = np.asarray(measured_mm, dtype=float)
    if c.shape != m.shape:
        raise ValueError(f"command and measured differ in length: {c.size} and {m.size}")
    v = step_velocity(c, t_d, order)
    er = (c - m) / d_max_mm
    return v[skip:], er[skip:]
