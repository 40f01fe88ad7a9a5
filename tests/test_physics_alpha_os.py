"""alpha-OS as the experiment loop runs it (E&M 2007, eqs. (3)-(6) and Figure 9),
step by step against eq. (3) solved directly here, with the restoring force of operator
splitting R_{i+1} = R~_{i+1} + K_I (u_{i+1} - u~_{i+1}); the force correction with the measured
displacement; what a run records; the start and the arguments."""

import numpy as np
import pytest

from hsio.api import make_integrator, run_numerical
from hsio.errors import ConfigError
from hsio.experiment import run_steps
from hsio.ground_motion import G_MM_S2, GroundMotion
from hsio.integrators import AlphaOS, OperatorSplitting
from hsio.sites import Daq
from hsio.structures import Damping, ExperimentalElement, Spring, Structure, sdof

M_ = (0.012, 0.008)
K0, U_Y, THETA = 6.0, 5.0, 0.2  # Menegotto-Pinto storey 1 (E&M 2007, eq. (13), n = 1)
K2 = 4.0  # numerical storey 2


def mp_force(u):
    x = u / U_Y
    return K0 * U_Y * (THETA * x + (1 - THETA) * x / (1 + abs(x)))


def two_storey(dt=0.005):
    return Structure(
        "two storeys", ("1", "2"), M_,
        (ExperimentalElement("1", 0, {"kind": "menegotto_pinto", "k0": K0, "u_y": U_Y, "theta": THETA}),),
        springs=(Spring(0, 1, K2),), damping=Damping(0.05, "rayleigh"), dt=dt)


def eq3_reference(M, C, K_I, restoring, P, dt, alpha):
    """Eq. (3) with Newmark's relations, solved for a_{i+1} at each step: the restoring force
    at u_{i+1} is R~_{i+1} + K_I (u_{i+1} - u~_{i+1}), R~ measured at the predictor u~."""
    beta, gamma = (1 - alpha) ** 2 / 4, 0.5 - alpha
    n = M.shape[0]
    u, v = np.zeros(n), np.zeros(n)
    R = restoring(u)
    a = np.linalg.solve(M, P[0] - C @ v - R)
    out = [(u, v, a)]
    for i in range(len(P) - 1):
        u_p = u + dt * v + dt**2 * (0.5 - beta) * a
        v_p = v + dt * (1 - gamma) * a
        R_p = restoring(u_p)
        # M a1 + (1+alpha) C (v_p + gamma dt a1) - alpha C v + (1+alpha)(R_p + K_I beta dt^2 a1) - alpha R
        #   = (1+alpha) P1 - alpha P0
        A = M + (1 + alpha) * gamma * dt * C + (1 + alpha) * beta * dt**2 * K_I
        b = (1 + alpha) * P[i + 1] - alpha * P[i] - (1 + alpha) * C @ v_p + alpha * C @ v - (1 + alpha) * R_p + alpha * R
        a1 = np.linalg.solve(A, b)
        u1, v1 = u_p + beta * dt**2 * a1, v_p + gamma * dt * a1
        R = R_p + K_I @ (u1 - u_p)
        u, v, a = u1, v1, a1
        out.append((u, v, a))
    return [np.array(x) for x in zip(*out)]


@pytest.mark.parametrize("alpha", [0.0, -0.1, -1 / 3])
def test_operator_splitting_is_eq3_step_by_step(alpha):
    dt = 0.005
    s = two_storey(dt)
    t = np.arange(0.0, 1.0 + dt / 2, dt)
    accel_g = 0.3 * np.sin(2 * np.pi * 2.5 * t) * (t < 0.8)
    result = run_numerical(s, GroundMotion("pulse", dt, accel_g), method="alpha_os", alpha=alpha)
    M = np.diag(M_)
    K_I = np.array([[K0 + K2, -K2], [-K2, K2]])
    P = -np.outer(accel_g * G_MM_S2, M @ np.ones(2))

    def restoring(u):
        return np.array([mp_force(u[0]) + K2 * (u[0] - u[1]), K2 * (u[1] - u[0])])

    u, v, a = eq3_reference(M, s.C, K_I, restoring, P, dt, alpha)
    assert np.max(np.abs(u[:, 0])) > 2 * U_Y  # well into the nonlinear range
    scale = np.max(np.abs(u))
    assert np.max(np.abs(result.u - u)) < 1e-9 * scale
    assert np.max(np.abs(result.v - v)) < 1e-9 * np.max(np.abs(v))
    assert np.max(np.abs(result.a - a)) < 1e-9 * np.max(np.abs(a))


class LaggingSite:
    """A linear specimen (k) whose measured displacement falls short of the target by ``lag``."""

    def __init__(self, k, lag):
        self.k, self.lag = k, lag
        self.n_elements = 1
        self.late_steps, self.lab_time_s = 0, None

    def set_trial(self, commands, modes):
        target = np.asarray(commands, dtype=float)
        u = (1 - self.lag) * target
        self._daq = Daq(u=u, R=self.k * u, k=np.full(1, self.k), targets=target.copy(), commands=target.copy())

    def get_daq(self):
        return self._daq

    def committed(self):
        return np.zeros(1), np.zeros(1)

    def commit(self):
        pass

    def take_samples(self):
        return None


def test_measured_force_is_brought_to_the_target_with_the_measured_displacement():
    """R~ = R_measured + K^EI (u~ - u_measured): with K^EI the specimen's stiffness, a 20 % short
    actuator gives the same response as a perfect one; without the correction it does not."""
    s = sdof(m=0.011, k=2.6, zeta=0.05, dt=0.005)
    t = np.arange(0.0, 0.5 + 0.0025, 0.005)
    ground = GroundMotion("pulse", 0.005, 0.2 * np.sin(2 * np.pi * 3 * t))
    exact = run_numerical(s, ground, alpha=-0.05)
    corrected = run_steps(s, ground, make_integrator(s, "alpha_os", -0.05), LaggingSite(2.6, 0.2))
    assert np.max(np.abs(corrected.u - exact.u)) < 1e-12 * np.max(np.abs(exact.u))
    assert np.allclose(corrected.measured_displacement[1:, 0], 0.8 * corrected.targets[1:, 0], rtol=1e-14)
    raw = run_steps(s, ground, make_integrator(s, "alpha_os", -0.05, correct_measured_displacement=False),
                    LaggingSite(2.6, 0.2))
    assert np.max(np.abs(raw.u - exact.u)) > 0.05 * np.max(np.abs(exact.u))


def test_a_run_records_the_state_predictor_targets_and_measurements():
    """Undamped SDOF under a constant ground acceleration a_g from rest: v = -(a_g / w) sin w t,
    a = -a_g cos w t; the target of each step is the predictor u~ and the restoring force R~ = k u~."""
    m, k, a_g, dt = 0.011, 2.6, 0.1, 0.001
    n = 501
    result = run_numerical(sdof(m=m, k=k, zeta=0.0, dt=dt), GroundMotion("constant", dt, np.full(n, a_g)), alpha=0.0)
    w = np.sqrt(k / m)
    ag = a_g * G_MM_S2
    t = result.t
    assert result.method == "alpha_os" and len(t) == n
    assert np.max(np.abs(result.v[:, 0] + ag / w * np.sin(w * t))) < 1e-3 * ag / w
    assert np.max(np.abs(result.a[:, 0] + ag * np.cos(w * t))) < 1e-3 * ag
    assert result.a[0, 0] == pytest.approx(-ag, rel=1e-14)  # M a_0 = P_0 at rest
    assert result.u_pred[0, 0] == 0.0
    beta = 0.25
    u_pred = result.u[:-1] + dt * result.v[:-1] + dt**2 * (0.5 - beta) * result.a[:-1]
    assert np.allclose(result.u_pred[1:], u_pred, rtol=1e-12, atol=1e-15)
    assert np.allclose(result.targets[1:], result.u_pred[1:], rtol=0, atol=0)
    assert np.allclose(result.commands[1:], result.u_pred[1:], rtol=0, atol=0)
    assert np.allclose(result.measured_displacement[1:], result.u_pred[1:], rtol=0, atol=0)
    assert np.allclose(result.measured_force[1:], k * result.u_pred[1:], rtol=1e-14, atol=0)
    assert np.allclose(result.R[1:], k * result.u_pred[1:], rtol=1e-14, atol=0)
    assert np.allclose(result.u_solution, result.u, rtol=0, atol=0)
    assert result.iterations[0, 0] == 0 and np.all(result.iterations[1:] == 1)
    assert np.all(result.converged)
    assert np.all(np.isnan(result.secant)) and np.all(np.isnan(result.R_solution))
    assert set(result.modes.ravel()) == {"displacement"}


def test_start_takes_initial_velocity_damping_and_restoring_force():
    m, c, k = 2.0, 0.3, 50.0
    integ = AlphaOS([[m]], [[c]], [[k]], 0.01, -0.1)
    s = integ.start(np.array([4.0]), u0=[0.5], v0=[3.0], R0=[k * 0.5])
    assert s.i == 0
    assert s.a[0] == pytest.approx((4.0 - c * 3.0 - k * 0.5) / m, rel=1e-14)
    assert s.u_pred[0] == 0.5 and s.v_pred[0] == 3.0
    s1 = integ.step(np.array([4.0]), lambda u: k * u)
    assert s1.i == 1 and integ.step(np.array([4.0]), lambda u: k * u).i == 2


@pytest.mark.parametrize("alpha", [-0.1, -1 / 3])
def test_a_start_away_from_rest_is_eq3_from_the_first_step(alpha):
    """A linear SDOF released from u_0 = 1 mm (a_0 = -k u_0 / m, not zero), as a run with
    ``start = "present"`` begins: with K_init = k operator splitting is exact, so every step must
    satisfy eq. (3) with v_0 and R_0 = k u_0 as given, the first one included."""
    m, c, k, dt = 0.01, 0.02, 4.0, 0.005
    beta, gamma = (1 - alpha) ** 2 / 4, 0.5 - alpha
    core = AlphaOS([[m]], [[c]], [[k]], dt, alpha)
    core.start(np.zeros(1), u0=[1.0], v0=[0.0], R0=[k * 1.0])
    u, v, a = 1.0, 0.0, -k / m
    for _ in range(40):
        s = core.step(np.zeros(1), lambda x: k * x)
        u_p, v_p = u + dt * v + dt**2 * (0.5 - beta) * a, v + dt * (1 - gamma) * a
        # m a1 + (1+alpha) c v1 - alpha c v + (1+alpha) k u1 - alpha k u = 0 with Newmark's u1, v1
        a1 = (alpha * c * v + alpha * k * u - (1 + alpha) * (c * v_p + k * u_p)) / (
            m + (1 + alpha) * (gamma * dt * c + beta * dt**2 * k))
        u, v, a = u_p + beta * dt**2 * a1, v_p + gamma * dt * a1, a1
        assert s.u[0] == pytest.approx(u, rel=1e-12, abs=1e-13) and s.v[0] == pytest.approx(v, rel=1e-12, abs=1e-11)


def test_operator_splitting_arguments_are_checked():
    M, C, K = [[1.0]], [[0.0]], [[1.0]]
    with pytest.raises(ConfigError, match="alpha"):
        OperatorSplitting(M, C, K, 0.01, 0.05, [0], [1.0])
    with pytest.raises(ConfigError, match="alpha"):
        AlphaOS(M, C, K, 0.01, -0.34)
    AlphaOS(M, C, K, 0.01, -1 / 3)
    AlphaOS(M, C, K, 0.01, 0.0)
    with pytest.raises(ConfigError, match="dt must be positive"):
        AlphaOS(M, C, K, 0.0)
    with pytest.raises(RuntimeError, match="start"):
        AlphaOS(M, C, K, 0.01).predict()
