"""alpha-OS (docs/method.md eqs. 3-6) on a linear SDOF whose initial stiffness is its stiffness:
the method is then HHT-alpha, and for alpha = 0 the trapezoidal rule, whose step is an exact
rotation of (u, v / w) by theta = 2 arctan(w dt / 2) and whose discrete energy balance is exact.
Plus the parameters of eq. (5) and the limits of alpha and dt."""

from __future__ import annotations

import numpy as np
import pytest

from hsio.config import DEFAULTS
from hsio.errors import ConfigError
from hsio.integrators import AlphaOS, OperatorSplitting
from hsio.sites import Daq


def test_default_alpha_is_the_run_configuration_default():
    integ = AlphaOS([[1.0]], [[0.0]], [[1.0]], 0.01)
    assert integ.alpha == DEFAULTS["integrator"]["alpha"] == -0.05
    assert integ.beta == pytest.approx(1.05**2 / 4, rel=1e-15) and integ.gamma == pytest.approx(0.55, rel=1e-15)


@pytest.mark.parametrize("alpha", [-1 / 3, -1 / 3 - 1e-13, 0.0, -0.0])
def test_alpha_at_the_ends_of_its_range_is_taken(alpha):
    assert AlphaOS([[1.0]], [[0.0]], [[1.0]], 0.01, alpha).alpha == alpha


@pytest.mark.parametrize("alpha", [-1 / 3 - 1e-9, 1e-12, 0.1, -0.34])
def test_alpha_outside_its_range_is_refused(alpha):
    with pytest.raises(ConfigError, match=r"alpha must be in \[-1/3, 0\]"):
        AlphaOS([[1.0]], [[0.0]], [[1.0]], 0.01, alpha)


@pytest.mark.parametrize("dt", [0.0, -0.01, float("nan")])
def test_a_time_step_not_positive_is_refused(dt):
    with pytest.raises(ConfigError, match="dt must be positive"):
        AlphaOS([[1.0]], [[0.0]], [[1.0]], dt)


def free_vibration(m, k, dt, n, alpha, u0, v0, c=0.0, P=None):
    integ = AlphaOS([[m]], [[c]], [[k]], dt, alpha)
    P = np.zeros((n + 1, 1)) if P is None else P
    s = integ.start(P[0], u0=[u0], v0=[v0], R0=[k * u0])
    out = [(s.u[0], s.v[0], s.a[0])]
    for i in range(n):
        s = integ.step(P[i + 1], lambda u: k * u)
        out.append((s.u[0], s.v[0], s.a[0]))
    return np.array(out).T


def test_alpha_zero_is_an_exact_rotation_by_the_trapezoidal_phase():
    """u_n = u0 cos(n theta) + v0 / w sin(n theta), theta = 2 arctan(w dt / 2), to round-off,
    with a step as long as a fifth of the period."""
    m, k, dt, n = 1.3, 50.0, 0.2, 60
    w = np.sqrt(k / m)
    u, v, a = free_vibration(m, k, dt, n, 0.0, 2.0, 3.0)
    theta = 2 * np.arctan(w * dt / 2) * np.arange(n + 1)
    np.testing.assert_allclose(u, 2.0 * np.cos(theta) + 3.0 / w * np.sin(theta), rtol=0, atol=1e-10)
    np.testing.assert_allclose(v, -2.0 * w * np.sin(theta) + 3.0 * np.cos(theta), rtol=0, atol=1e-9)
    np.testing.assert_allclose(a, -k / m * u, rtol=1e-12, atol=1e-12)


def test_alpha_zero_balances_energy_step_by_step_with_damping_and_load():
    """Trapezoidal rule: Delta(m v^2 / 2 + k u^2 / 2) = Delta u ((P_i + P_i+1) / 2 - c (v_i + v_i+1) / 2)
    exactly, every step."""
    m, k, c, dt, n = 0.8, 30.0, 0.9, 0.03, 200
    t = np.arange(n + 1) * dt
    P = (5.0 * np.sin(7.0 * t) + 2.0 * t)[:, None]
    u, v, _ = free_vibration(m, k, dt, n, 0.0, 0.5, -1.0, c=c, P=P)
    energy = 0.5 * m * v**2 + 0.5 * k * u**2
    work = np.diff(u) * (0.5 * (P[1:, 0] + P[:-1, 0]) - c * 0.5 * (v[1:] + v[:-1]))
    np.testing.assert_allclose(np.diff(energy), work, rtol=0, atol=1e-10 * np.max(energy))
    assert np.max(np.abs(work)) > 1e-3 * np.max(energy)


@pytest.mark.parametrize("alpha", [-0.05, -0.2, -1 / 3])
def test_negative_alpha_is_hht_and_dissipates(alpha):
    """With K_init the whole stiffness, alpha-OS is HHT-alpha:
    M a_i+1 + (1+alpha)(C v_i+1 + K u_i+1) - alpha (C v_i + K u_i) = (1+alpha) P_i+1 - alpha P_i,
    checked step by step; undamped, the energy then only decreases."""
    m, k, c, dt, n = 1.1, 40.0, 0.3, 0.05, 120
    t = np.arange(n + 1) * dt
    P = (3.0 * np.cos(5.0 * t))[:, None]
    u, v, a = free_vibration(m, k, dt, n, alpha, 1.0, 2.0, c=c, P=P)
    lhs = m * a[1:] + (1 + alpha) * (c * v[1:] + k * u[1:]) - alpha * (c * v[:-1] + k * u[:-1])
    rhs = (1 + alpha) * P[1:, 0] - alpha * P[:-1, 0]
    np.testing.assert_allclose(lhs, rhs, rtol=0, atol=1e-10 * np.max(np.abs(rhs)))
    beta, gamma = (1 - alpha) ** 2 / 4, 0.5 - alpha
    np.testing.assert_allclose(u[1:], u[:-1] + dt * v[:-1] + dt**2 * ((0.5 - beta) * a[:-1] + beta * a[1:]), atol=1e-12)
    np.testing.assert_allclose(v[1:], v[:-1] + dt * ((1 - gamma) * a[:-1] + gamma * a[1:]), atol=1e-12)
    u, v, _ = free_vibration(m, k, dt, n, alpha, 1.0, 2.0)
    energy = 0.5 * m * v**2 + 0.5 * k * u**2
    assert energy[-1] < energy[0]


class ShortSite:
    """Two specimens that reach 0.9 of each target plus 0.01 mm and resist with 3 u and 5 u."""

    def __init__(self):
        self.targets = None

    def set_trial(self, targets, modes):
        self.targets = np.array(targets, dtype=float)

    def get_daq(self):
        u = 0.9 * self.targets + 0.01
        return Daq(u=u, R=np.array([3.0, 5.0]) * u, k=np.full(2, np.nan), targets=self.targets.copy(),
                   commands=self.targets.copy())

    def commit(self):
        pass


class NumericalPart:
    K_N = np.array([[1.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])

    def trial(self, u):
        return self.K_N @ u

    def commit(self):
        pass


@pytest.mark.parametrize("dofs", [[2, 0], [1, 1]])
@pytest.mark.parametrize("K_EI", [[2.0, 4.0], [[2.0, 0.5], [0.7, 4.0]]])
def test_operator_splitting_brings_each_measured_force_to_its_target(dofs, K_EI):
    """R~ at the element's DOF = R_measured + K^EI (u~ - u_measured), per channel or as a matrix
    product, summed where two elements share a DOF, plus the numerical part's force at u~."""
    M, C, K_init = np.diag([1.0, 2.0, 1.5]), 0.1 * np.eye(3), 10.0 * np.eye(3)
    method = OperatorSplitting(M, C, K_init, 0.02, -0.1, dofs, K_EI)
    site, spring = ShortSite(), NumericalPart()
    method.start(np.array([1.0, -2.0, 3.0]), site, spring)
    for P in ([0.5, -1.0, 2.0], [0.0, 1.0, 0.0]):
        u_pred, _ = method.core.predict()
        out = method.step(np.array(P), site, spring)
        targets = u_pred[dofs]
        u_meas = 0.9 * targets + 0.01
        K = np.asarray(K_EI)
        F = np.array([3.0, 5.0]) * u_meas + (K @ (targets - u_meas) if K.ndim == 2 else K * (targets - u_meas))
        R = spring.K_N @ u_pred
        for d, f in zip(dofs, F):
            R[d] += f
        np.testing.assert_array_equal(site.targets, targets)
        np.testing.assert_allclose(out.R, R, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(out.u_pred, u_pred, rtol=0, atol=0)
        assert np.all(out.iterations == 1) and np.abs(targets).min() > 0
