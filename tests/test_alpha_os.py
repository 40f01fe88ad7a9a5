"""alpha-OS (docs/method.md eqs. 3-6) against closed-form responses and scipy's solution."""

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from hsio.errors import ConfigError
from hsio.integrators import AlphaOS


def integrate_linear(M, C, K, dt, P, alpha, u0=None, v0=None):
    """Run alpha-OS on a linear structure whose whole stiffness is K (R = K u)."""
    integ = AlphaOS(M, C, K, dt, alpha)
    n = np.atleast_2d(M).shape[0]
    u0 = np.zeros(n) if u0 is None else np.asarray(u0, float)
    integ.start(P[0], u0=u0, v0=v0, R0=np.atleast_2d(K) @ u0)
    out = [u0]
    for i in range(len(P) - 1):
        out.append(integ.step(P[i + 1], lambda u: np.atleast_2d(K) @ u).u)
    return np.array(out)


@pytest.mark.parametrize("alpha", [0.0, -0.1, -1 / 3])
def test_sdof_damped_free_vibration_matches_closed_form(alpha):
    m, k, zeta = 1.0, 4 * np.pi**2, 0.05  # unit period
    w = np.sqrt(k / m)
    wd = w * np.sqrt(1 - zeta**2)
    c = 2 * zeta * w * m
    dt, n = 0.002, 1500  # 3 periods
    u0, v0 = 10.0, 0.0
    u = integrate_linear([[m]], [[c]], [[k]], dt, np.zeros((n, 1)), alpha, [u0], [v0])[:, 0]
    t = np.arange(n) * dt
    exact = np.exp(-zeta * w * t) * (u0 * np.cos(wd * t) + (v0 + zeta * w * u0) / wd * np.sin(wd * t))
    assert np.max(np.abs(u - exact)) < 3e-4 * u0  # measured 1.5e-4 (alpha = -1/3)


def test_second_order_accuracy():
    m, k = 1.0, 4 * np.pi**2
    errors = []
    for dt in (0.01, 0.005, 0.0025):
        n = int(round(2.0 / dt)) + 1
        u = integrate_linear([[m]], [[0.0]], [[k]], dt, np.zeros((n, 1)), -0.1, [1.0])[:, 0]
        t = np.arange(n) * dt
        errors.append(np.max(np.abs(u - np.cos(2 * np.pi * t))))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all(ratios > 3.5), f"halving dt should divide the error by about 4, got {ratios}"


def test_two_dof_undamped_matches_modal_closed_form():
    M = np.diag([0.0017, 0.0011])
    K = np.array([[0.613 + 5.0, -5.0], [-5.0, 0.536 + 5.0]])
    u0 = np.array([10.0, -4.0])
    w2, phi = scipy.linalg.eigh(K, M)  # phi^T M phi = I
    w = np.sqrt(w2)
    dt = 2 * np.pi / w.max() / 200
    n = int(round(0.62 / dt))
    u = integrate_linear(M, np.zeros((2, 2)), K, dt, np.zeros((n, 2)), 0.0, u0)
    t = np.arange(n) * dt
    q0 = phi.T @ M @ u0
    exact = (phi @ (q0[:, None] * np.cos(np.outer(w, t)))).T
    assert np.max(np.abs(u - exact)) < 0.008 * np.max(np.abs(u0))  # measured 0.0038


def test_two_dof_earthquake_matches_scipy_solve_ivp():
    M = np.diag([0.0017, 0.0011])
    K = np.array([[0.613 + 50.0, -50.0], [-50.0, 0.536 + 50.0]])
    C = 0.05 * M + 0.0005 * K
    dt, n = 0.0005, 4001
    t = np.arange(n) * dt
    ag = 3000.0 * np.sin(2 * np.pi * 2.0 * t) * np.exp(-t)  # mm/s^2
    P = -np.outer(ag, M @ np.ones(2))
    u = integrate_linear(M, C, K, dt, P, -0.05)
    Minv = np.linalg.inv(M)

    def rhs(time, y):
        x, v = y[:2], y[2:]
        p = -M @ np.ones(2) * 3000.0 * np.sin(2 * np.pi * 2.0 * time) * np.exp(-time)
        return np.concatenate([v, Minv @ (p - C @ v - K @ x)])

    sol = scipy.integrate.solve_ivp(rhs, (0, t[-1]), np.zeros(4), t_eval=t, method="DOP853", rtol=1e-10, atol=1e-12)
    peak = np.max(np.abs(sol.y[:2]))
    assert np.max(np.abs(u - sol.y[:2].T)) < 3e-4 * peak  # measured 1.5e-4


def test_operator_splitting_uses_measured_force_not_stiffness():
    """With a softer specimen than K_init, alpha-OS follows the specimen's force (explicit part)."""
    m, k_init = 1.0, 4 * np.pi**2
    integ = AlphaOS([[m]], [[0.0]], [[k_init]], 0.01, -0.05)
    integ.start(np.array([0.0]), u0=[1.0], R0=[0.5 * k_init])
    s = integ.step(np.array([0.0]), lambda u: 0.5 * k_init * u)
    # Softer restoring force -> smaller deceleration than with the stiff K_init alone.
    integ2 = AlphaOS([[m]], [[0.0]], [[k_init]], 0.01, -0.05)
    integ2.start(np.array([0.0]), u0=[1.0], R0=[k_init])
    s2 = integ2.step(np.array([0.0]), lambda u: k_init * u)
    assert s.a[0] > s2.a[0]


def test_alpha_outside_range_is_refused():
    with pytest.raises(ConfigError, match="alpha"):
        AlphaOS([[1.0]], [[0.0]], [[1.0]], 0.01, alpha=-0.5)
