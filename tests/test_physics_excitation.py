"""The ground excitation P = -M iota a_g (E&M 2007, eq. (3)) against
independent references: the closed-form response of an undamped SDOF to a constant ground
acceleration, scipy's solution of a 2-DOF shear building, and the energy balance of a nonlinear
elastic SDOF."""

import numpy as np
import pytest
import scipy.integrate

from hsio.api import run_numerical
from hsio.experiment import excitation
from hsio.ground_motion import G_MM_S2, GroundMotion
from hsio.structures import Damping, ExperimentalElement, Spring, Structure, sdof


def constant_ground(a_g: float, dt: float, duration: float) -> GroundMotion:
    n = int(round(duration / dt)) + 1
    return GroundMotion("constant", dt, np.full(n, a_g))


def test_excitation_is_minus_mass_times_ground_acceleration():
    s = Structure("two", ("a", "b"), (0.002, 0.003),
                  (ExperimentalElement("a", 0, {"kind": "linear", "k": 1.0}),), (Spring(0, 1, 2.0),), dt=0.01)
    ground = GroundMotion("ramp", 0.01, np.array([0.0, 0.1, -0.2, 0.3]))
    t, P = excitation(s, ground)
    assert np.allclose(t, [0.0, 0.01, 0.02, 0.03])
    expected = -np.outer(ground.accel_g * G_MM_S2, [0.002, 0.003])
    assert np.allclose(P, expected, rtol=1e-14, atol=0)


@pytest.mark.parametrize("method", ["alpha_os", "implicit_dc"])
def test_sdof_at_rest_under_constant_ground_acceleration_matches_closed_form(method):
    """u(t) = -(m a_g / k)(1 - cos w t): the mass first moves against the ground acceleration."""
    m, k = 0.011, 2.6
    a_g = 0.1  # g, from t = 0 on
    dt = 0.001
    structure = sdof(m=m, k=k, zeta=0.0, dt=dt)
    result = run_numerical(structure, constant_ground(a_g, dt, 1.0), method=method, alpha=0.0)
    w = np.sqrt(k / m)
    static = m * a_g * G_MM_S2 / k
    exact = -static * (1.0 - np.cos(w * result.t))
    u = result.u[:, 0]
    assert u.min() == pytest.approx(-2 * static, rel=1e-6)  # peak displacement 2 m a_g / k, negative
    assert u.max() <= 1e-9
    # Average acceleration elongates the period by about (w dt)^2 / 12: measured 2.8e-4 of m a_g / k.
    assert np.max(np.abs(u - exact)) < 6e-4 * static


def test_two_dof_shear_building_under_a_record_matches_scipy():
    """M u'' + C u' + K u = -M iota a_g, integrated by scipy (DOP853) with the same M, C, K."""
    m1, m2, k1, k2 = 0.012, 0.008, 6.0, 4.0
    dt = 0.001
    s = Structure(
        "shear building", ("floor 1", "floor 2"), (m1, m2),
        (ExperimentalElement("storey 1", 0, {"kind": "linear", "k": k1}),),
        springs=(Spring(0, 1, k2),), damping=Damping(0.03, "rayleigh"), dt=dt)
    t = np.arange(0.0, 1.5 + dt / 2, dt)
    accel_g = 0.2 * np.sin(2 * np.pi * 3.0 * t) * np.exp(-1.5 * t)
    result = run_numerical(s, GroundMotion("pulse", dt, accel_g), method="alpha_os", alpha=0.0)

    M = np.diag([m1, m2])
    K = np.array([[k1 + k2, -k2], [-k2, k2]])
    C = s.C
    Minv = np.linalg.inv(M)

    def rhs(time, y):
        a_g = 0.2 * np.sin(2 * np.pi * 3.0 * time) * np.exp(-1.5 * time) * G_MM_S2
        x, v = y[:2], y[2:]
        return np.concatenate([v, Minv @ (-M @ np.ones(2) * a_g - C @ v - K @ x)])

    sol = scipy.integrate.solve_ivp(rhs, (0.0, t[-1]), np.zeros(4), t_eval=t, method="DOP853", rtol=1e-10, atol=1e-12)
    ref = sol.y[:2].T
    peak = np.max(np.abs(ref))
    assert peak > 5.0
    # measured: 2.3e-4 of the peak
    assert np.max(np.abs(result.u - ref)) < 5e-4 * peak
    # the first motion is opposite to the ground's first acceleration (positive)
    first = np.flatnonzero(np.abs(ref[:, 1]) > 0.01 * peak)[0]
    assert result.u[first, 1] < 0 and ref[first, 1] < 0


def menegotto_pinto_energy(u, k0, u_y, theta):
    """The strain energy of the n = 1 Menegotto-Pinto spring (E&M 2007, eq. (13)), integrated in
    closed form: k0 u_y^2 [theta x^2 / 2 + (1 - theta)(|x| - ln(1 + |x|))], x = u / u_y."""
    x = np.abs(np.asarray(u) / u_y)
    return k0 * u_y**2 * (theta * x**2 / 2 + (1 - theta) * (x - np.log1p(x)))


def test_energy_balance_of_a_nonlinear_elastic_sdof_under_a_record():
    """Input energy -int m a_g v dt = kinetic + damping + strain energy (alpha = 0, small dt)."""
    m, k0, u_y, theta, zeta = 0.011, 2.6, 20.0, 0.3, 0.05
    dt = 0.002
    structure = sdof(m=m, zeta=zeta, dt=dt, specimen={"kind": "menegotto_pinto", "k0": k0, "u_y": u_y, "theta": theta})
    t = np.arange(0.0, 3.0 + dt / 2, dt)
    accel_g = 0.4 * np.sin(2 * np.pi * 1.5 * t) * np.exp(-0.8 * t)
    result = run_numerical(structure, GroundMotion("pulse", dt, accel_g), method="implicit_dc", alpha=0.0)
    u, v = result.u[:, 0], result.v[:, 0]
    assert np.max(np.abs(u)) > 2 * u_y  # well into the nonlinear range
    c = structure.C[0, 0]
    a_g = accel_g * G_MM_S2

    def cumulative(f):
        return np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * dt)])

    E_input = cumulative(-m * a_g * v)
    E_kinetic = 0.5 * m * v**2
    E_damping = cumulative(c * v**2)
    E_strain = menegotto_pinto_energy(u, k0, u_y, theta)
    balance = E_input - (E_kinetic + E_damping + E_strain)
    assert E_input.max() > 10.0  # kN mm
    # measured: 7.5e-5 of the peak input energy
    assert np.max(np.abs(balance)) < 1.5e-4 * E_input.max()


class FailingSite:
    """Specimen models that fail on the trial of step ``fail_at`` with ``error``."""

    def __init__(self, structure, fail_at, error):
        from hsio.sites import NumericalSite

        self.inner = NumericalSite.of(structure)
        self.fail_at, self.error = fail_at, error
        self.trials = 0
        self.held = False
        self.late_steps, self.lab_time_s = 0, None

    def committed(self):
        return self.inner.committed()

    def set_trial(self, commands, modes):
        self.trials += 1
        if self.trials == self.fail_at:
            raise self.error
        self.inner.set_trial(commands, modes)

    def get_daq(self):
        return self.inner.get_daq()

    def commit(self):
        self.inner.commit()

    def set_modes(self, modes):
        return self.inner.set_modes(modes)

    def take_samples(self):
        return None

    def hold(self):
        self.held = True


@pytest.mark.parametrize("error, reason", [
    (ValueError("boom"), r"step 5 \(t = 0\.050 s\): unexpected ValueError\('boom'\)"),
    (KeyboardInterrupt(), r"run stopped at step 5 \(t = 0\.050 s\): interrupted \(Ctrl-C\)"),
])
def test_a_run_that_stops_keeps_every_step_made_and_holds(error, reason):
    from hsio.api import make_integrator
    from hsio.experiment import ExperimentStopped, run_steps

    structure = sdof(m=0.011, k=2.6, zeta=0.05, dt=0.01)
    ground = constant_ground(0.1, 0.01, 0.2)
    full = run_numerical(structure, ground, alpha=-0.05)
    site = FailingSite(structure, 5, error)
    with pytest.raises(ExperimentStopped, match=reason) as stopped:
        run_steps(structure, ground, make_integrator(structure, "alpha_os", -0.05), site)
    result = stopped.value.result
    assert site.held
    assert len(result.t) == 5 and np.array_equal(result.u, full.u[:5])
    assert np.array_equal(result.t, full.t[:5])
    assert result.stopped and "4 steps recorded" in str(stopped.value)
    assert full.stopped == "" and len(full.t) == 21
