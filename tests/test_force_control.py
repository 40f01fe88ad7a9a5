"""Implicit force control (E&M 2007 eqs. 7-12) and its agreement with DC for linear specimens."""

import numpy as np
import pytest

from hsio.emulators.local import open_url
from hsio.clock import LockstepClock
from hsio.control_loop import ControlLoop
from hsio.errors import ConfigError
from hsio.api import run_numerical, simulate
from hsio.ground_motion import GroundMotion, synthetic_record
from hsio.integrators import ImplicitAlpha, SwitchingRule
from hsio.interfaces import ControlMode
from hsio.secant import SecantEstimator, secant_stiffness
from hsio.sites import ActuatorSite, Daq, NumericalSite
from hsio.sites.numerical import displacement_for_force
from hsio.specimens import Linear, PinchedWood
from hsio.structures import NumericalElement, Structure, sdof, structure_II

FC, DC = ControlMode.FORCE, ControlMode.DISPLACEMENT
QUIET = "emulator://?noise_mm=0&force_noise_kN=0&resolution_mm=0&force_resolution_kN=0"


def relative(u, ref):
    return float(np.max(np.abs(u - ref)) / np.max(np.abs(ref)))


def from_rest(ground):
    """The record with a_g(0) = 0, so that every integrator starts from the same state of rest
    (alpha-OS keeps v~_0 = v_0 and R~_0 = R_0, consistent only when a_0 = 0)."""
    accel = ground.accel_g.copy()
    accel[0] = 0.0
    return GroundMotion(ground.name, ground.dt, accel)


def linear_case():
    structure = sdof(m=0.011, k=2.6, zeta=0.05, dt=0.005)
    ground = from_rest(synthetic_record(duration_s=2.0, dt=0.005, pga_g=0.4, seed=7))
    return structure, ground


def force_rule(ns):
    peak = float(np.max(np.abs(ns.R)))
    return SwitchingRule([0.5 * peak], [0.25 * peak], on="force")


def test_linear_numerical_dc_fc_mixed_agree_with_alpha_os():
    structure, ground = linear_case()
    reference = run_numerical(structure, ground, "alpha_os", -0.1)
    runs = {}
    for method in ("implicit_dc", "force_control", "mixed"):
        rule = force_rule(reference) if method == "mixed" else None
        runs[method] = simulate(structure, ground, NumericalSite.of(structure), method, -0.1, rule=rule,
                                j_max=10, tol_displacement=1e-12, tol_force=1e-12)
        assert relative(runs[method].u, reference.u) < 1e-12, method  # measured 1.2e-13
    assert np.all(runs["force_control"].modes[1:, 0] == "force")
    mixed = runs["mixed"]
    assert len(mixed.switches) >= 4
    assert {"force", "displacement"} <= set(mixed.modes[1:, 0])
    # a linear element's secant is exact: one command per step
    assert np.all(runs["force_control"].iterations[1:] == 1)


def test_linear_emulated_noise_free_dc_fc_mixed_agree():
    structure, ground = linear_case()
    ns = simulate(structure, ground, NumericalSite.of(structure), "implicit_dc", -0.05,
                  j_max=10, tol_displacement=1e-12, tol_force=1e-12)
    for method in ("implicit_dc", "force_control", "mixed"):
        clock = LockstepClock()
        actuators = open_url(QUIET, structure.experimental, clock, {})
        loop = ControlLoop(actuators, clock, structure.dt, 5.0, n_avg=4, keep_samples=True, hold_fraction=0.5)
        elements = ActuatorSite(loop, SecantEstimator("average", n_avg=8))
        try:
            hs = simulate(structure, ground, elements, method, -0.05, rule=force_rule(ns) if method == "mixed" else None,
                          j_max=4, tol_displacement=1e-9, tol_force=1e-9)
        finally:
            elements.close()
        assert relative(hs.u, ns.u) < 1e-6, method
        if method != "implicit_dc":
            assert np.any(hs.modes[1:, 0] == "force")
            fc = hs.modes[:, 0] == "force"
            # in FC steps the actuator was commanded in kN: the targets are the forces solved for
            assert np.allclose(hs.targets[fc, 0], hs.R_solution[fc, 0], rtol=1e-6, atol=1e-9)


class Probe:
    """A numerical linear element that records the commands the integrator sends."""

    def __init__(self, k):
        self.spec = Linear(k)
        self._base = (np.zeros(1), np.zeros(1))
        self._last = self._base
        self.sent = []

    def committed(self):
        return self._base

    def set_trial(self, commands, modes):
        self.sent.append((float(commands[0]), modes[0]))
        if modes[0] is FC:
            R = np.array(commands, dtype=float)
            u = R / self.spec.k
        else:
            u = np.array(commands, dtype=float)
            R = self.spec.k * u
        self._last = (u, R)
        self._daq = Daq(u, R, secant_stiffness(u, R, *self._base), np.array(commands), np.array(commands))

    def get_daq(self):
        return self._daq

    def commit(self):
        self._base = self._last


def test_first_force_command_is_eq_12_and_secant_is_eq_11():
    m, c, k_true, k_ei, dt, alpha = 0.011, 0.02, 2.0, 2.6, 0.005, -0.2
    integ = ImplicitAlpha([[m]], [[c]], None, [0], [k_ei], dt, alpha, j_max=10, tol_displacement=1e-12, tol_force=1e-12)
    probe = Probe(k_true)
    P0, P1 = np.array([0.3]), np.array([0.5])
    integ.start(P0, probe)
    s = integ.state
    beta, gamma = (1 - alpha) ** 2 / 4, 0.5 - alpha
    K_star = m / (beta * dt**2) + (1 + alpha) * gamma * c / (beta * dt)  # eq. (8)
    u_pred = s.u + dt * s.v + dt**2 * (0.5 - beta) * s.a
    v_pred = s.v + dt * (1 - gamma) * s.a
    P_star = (1 + alpha) * P1 - alpha * P0 - (1 + alpha) * c * v_pred + alpha * c * s.v + K_star * u_pred + alpha * s.R  # eq. (10)
    R1 = (P_star + K_star / k_ei * 0.0 - K_star * 0.0) / (K_star / k_ei + (1 + alpha))  # eq. (12), from rest
    state, report = integ.step(P1, probe, [FC])
    assert probe.sent[0][0] == pytest.approx(float(R1[0]), rel=1e-12)
    assert report.k[0] == pytest.approx(k_true, rel=1e-12)  # eq. (11) after the first iteration
    assert report.converged
    # converged: eq. (7) holds with the true element
    assert K_star * state.u[0] + (1 + alpha) * k_true * state.u[0] == pytest.approx(float(P_star[0]), rel=1e-10)


def test_two_dof_with_numerical_spring_matches_dc():
    """Structure II (two physical frames linked by numerical slab springs): FC = DC when linear."""
    structure = structure_II()
    ground = from_rest(synthetic_record(duration_s=1.0, dt=structure.dt, pga_g=0.3, seed=3))
    dc = simulate(structure, ground, NumericalSite.of(structure), "implicit_dc", -0.05, j_max=10,
                  tol_displacement=1e-12, tol_force=1e-12)
    fc = simulate(structure, ground, NumericalSite.of(structure), "force_control", -0.05, j_max=10,
                  tol_displacement=1e-12, tol_force=1e-12)
    os_ = run_numerical(structure, ground, "alpha_os", -0.05)
    assert relative(fc.u, dc.u) < 1e-12  # measured 3e-15 (round-off)
    assert relative(dc.u, os_.u) < 1e-12


def test_setups_outside_the_method_are_refused():
    with pytest.raises(ConfigError, match="not diagonal"):
        ImplicitAlpha(np.eye(2), np.zeros((2, 2)), None, [0, 1], [[2.0, -0.5], [-0.5, 2.0]], 0.01)
    with pytest.raises(ConfigError, match="same DOF"):
        ImplicitAlpha(np.eye(2), np.zeros((2, 2)), None, [0, 0], [1.0, 1.0], 0.01)
    with pytest.raises(ConfigError, match="alpha"):
        ImplicitAlpha(np.eye(1), np.zeros((1, 1)), None, [0], [1.0], 0.01, alpha=0.2)
    base = sdof(dt=0.01)
    nonlinear = Structure(name="x", dof_names=("a", "b"), masses=(1.0, 1.0), experimental=base.experimental,
                          numerical=(NumericalElement("n", 1, {"kind": "pinched_wood", "k0": 1.0, "F0": 1.0}),),
                          dt=0.01)
    ground = synthetic_record(duration_s=0.5, dt=0.01, seed=1)
    with pytest.raises(ConfigError, match="linear numerical elements only"):
        simulate(nonlinear, ground, NumericalSite.of(nonlinear), "force_control")
    clock = LockstepClock()
    actuators = open_url(QUIET, base.experimental, clock, {})
    loop = ControlLoop(actuators, clock, base.dt, 5.0, keep_samples=False)
    with pytest.raises(ConfigError, match="samples"):
        ActuatorSite(loop, SecantEstimator())
    loop.close()


def test_displacement_for_force_on_a_path_dependent_specimen():
    wall = PinchedWood(k0=2.6, F0=30.0)
    wall.force(20.0)  # load into the nonlinear range
    u_c, F_c = 20.0, wall._F
    for target in (F_c - 10.0, 0.0, -5.0):
        u = displacement_for_force(wall, target, u_c, F_c, 2.6)
        assert wall.trial(u) == pytest.approx(target, abs=1e-9)
        assert wall._u == u_c  # the committed specimen is untouched
