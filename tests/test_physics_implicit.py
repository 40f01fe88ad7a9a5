"""The implicit alpha method by secant iteration (E&M 2007, eqs. (7)-(12) and
Figure 11) against a small site of linear springs whose secant estimate can be made to
spike: the step's solution is the alpha method's (computed here by alpha-OS with the exact
stiffness, which for a linear system is the same method), an implausible secant is refused, and
an FC element that softens within a step goes on in DC."""

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.integrators import AlphaOS, ImplicitAlpha, ImplicitMethod, SwitchingRule
from hsio.interfaces import ControlMode
from hsio.sites import Daq

DC = ControlMode.DISPLACEMENT
FC = ControlMode.FORCE


class SpringSite:
    """One linear spring per element (stiffness ``k``). ``spikes`` maps (step, trial) to a secant
    estimate reported in place of the measured one. Every trial is logged."""

    def __init__(self, k, spikes=None):
        self.k = np.asarray(k, dtype=float)
        self.spikes = dict(spikes or {})
        self._committed = (np.zeros(self.k.size), np.zeros(self.k.size))
        self.step = 1
        self.trial = 0
        self.log = []  # (step, trial, commands, modes)
        self._daq = None

    def committed(self):
        return self._committed

    def set_trial(self, commands, modes):
        commands = np.asarray(commands, dtype=float).copy()
        fc = np.array([m is FC for m in modes])
        u = np.where(fc, commands / self.k, commands)
        R = np.where(fc, commands, self.k * commands)
        u_b, R_b = self._committed
        with np.errstate(divide="ignore", invalid="ignore"):
            k = (R - R_b) / (u - u_b)
        self.trial += 1
        spike = self.spikes.get((self.step, self.trial))
        if spike is not None:
            k = np.where(np.isnan(spike), np.nan, np.asarray(spike, dtype=float))
        self.log.append((self.step, self.trial, commands, list(modes)))
        self._daq = Daq(u=u, R=R, k=k, targets=commands, commands=commands)

    def get_daq(self):
        return self._daq

    def set_modes(self, modes):
        self.modes = list(modes)
        return []

    def commit(self):
        self._committed = (self._daq.u.copy(), self._daq.R.copy())
        self.step += 1
        self.trial = 0


M2 = np.diag([0.011, 0.007])
C2 = np.array([[0.02, -0.005], [-0.005, 0.015]])
K_N2 = np.array([[1.5, -1.5], [-1.5, 1.5]])
K_EI2 = np.array([2.6, 1.8])
LOADS = [np.array([0.0, 0.0]), np.array([3.0, -1.0]), np.array([4.0, 2.0]), np.array([-1.0, 2.5]), np.array([0.5, 0.0])]


def reference(k_site, alpha, dt, loads=LOADS):
    """The alpha method on the linear structure K = K_N + diag(k_site): alpha-OS with the exact
    stiffness as its implicit part."""
    K = K_N2 + np.diag(k_site)
    integ = AlphaOS(M2, C2, K, dt, alpha)
    integ.start(loads[0])
    return [integ.step(P, lambda u: K @ u).u for P in loads[1:]]


def run(k_site, modes, spikes=None, j_max=10, alpha=-0.1, dt=0.01, fallback_below=None, **kw):
    site = SpringSite(k_site, spikes)
    integ = ImplicitAlpha(M2, C2, K_N2, [0, 1], K_EI2, dt, alpha, j_max=j_max, tol_displacement=1e-11,
                          tol_force=1e-11, **kw)
    integ.start(LOADS[0], site)
    out = [integ.step(P, site, list(modes), fallback_below) for P in LOADS[1:]]
    return out, site


@pytest.mark.parametrize("modes", [(DC, DC), (FC, FC), (DC, FC)])
def test_converged_steps_are_the_alpha_methods_solution(modes):
    k_site = np.array([1.3, 2.7])  # one softer, one stiffer than K^EI
    out, _ = run(k_site, modes)
    for (state, report), u_ref in zip(out, reference(k_site, -0.1, 0.01)):
        assert report.converged
        assert np.allclose(state.u, u_ref, rtol=1e-9, atol=1e-12)
        assert np.allclose(report.k, k_site, rtol=1e-9)
        assert np.allclose(state.R, (K_N2 + np.diag(k_site)) @ state.u, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("modes", [(DC, DC), (FC, FC)])
def test_a_secant_spike_on_the_last_iteration_is_refused(modes):
    """j_max = 2: the second measurement spikes to 100 K^EI; the step keeps the first secant."""
    k_site = np.array([1.3, 2.7])
    spikes = {(1, 2): 100 * K_EI2}
    out, site = run(k_site, modes, spikes, j_max=2)
    ref = reference(k_site, -0.1, 0.01)
    for (state, report), u_ref in zip(out, ref):
        assert np.allclose(report.k, k_site, rtol=1e-9)
        assert np.allclose(state.u, u_ref, rtol=1e-9, atol=1e-12)


def test_a_spike_within_the_step_changes_no_command():
    """A spike on iteration 2 of 10: every command after it is still the converged one."""
    k_site = np.array([1.3, 2.7])
    out, site = run(k_site, (FC, DC), {(1, 2): np.array([100 * K_EI2[0], np.nan])})
    state, report = out[0]
    commands = [c for step, trial, c, m in site.log if step == 1]
    assert report.converged and report.iterations.tolist() == [2, 2]
    assert len(commands) == 2  # the first guess (K^EI), then the converged solution only
    assert np.allclose(state.u, reference(k_site, -0.1, 0.01)[0], rtol=1e-9, atol=1e-12)


def test_secant_up_to_the_plausibility_ratio_is_accepted():
    """A stiffening element at 3 K^EI is real, not a spike: it is used (ratio 20 by default); with
    the ratio at 2 it is refused and the iteration stays on K^EI."""
    k_site = 3.0 * K_EI2
    out, _ = run(k_site, (DC, DC))
    assert np.allclose(out[-1][1].k, k_site, rtol=1e-9)
    assert np.allclose(out[-1][0].u, reference(k_site, -0.1, 0.01)[-1], rtol=1e-9, atol=1e-12)
    out, _ = run(k_site, (DC, DC), max_stiffness_ratio=2.0)
    assert np.allclose(out[-1][1].k, K_EI2, rtol=0)
    out, _ = run(k_site, (DC, DC), max_stiffness_ratio=3.0 * (1 + 1e-12))
    assert np.allclose(out[-1][1].k, k_site, rtol=1e-9)
    with pytest.raises(ConfigError, match="max_stiffness_ratio"):
        ImplicitAlpha(M2, C2, K_N2, [0, 1], K_EI2, 0.01, max_stiffness_ratio=1.0)


def test_fc_element_falls_back_to_dc_within_the_step_when_it_softens():
    """fallback_below 0.8 K^EI: element 0 (secant 0.5 K^EI) goes on in DC from its second trial;
    element 1 (0.9 K^EI) stays in FC; the step converges to the alpha method's solution."""
    k_site = np.array([0.5, 0.9]) * K_EI2
    out, site = run(k_site, (FC, FC), fallback_below=0.8 * K_EI2)
    state, report = out[0]
    assert report.fell_back.tolist() == [True, False]
    assert report.modes == [DC, FC]
    step1 = [(trial, m) for step, trial, c, m in site.log if step == 1]
    assert step1[0][1] == [FC, FC]
    assert all(m == [DC, FC] for trial, m in step1[1:])
    assert report.converged
    assert np.allclose(state.u, reference(k_site, -0.1, 0.01)[0], rtol=1e-9, atol=1e-12)
    # each step starts again in the modes it is given
    for _, r in out[1:]:
        assert r.fell_back.tolist() == [True, False]


def test_a_fall_back_needs_a_command_left_to_send_in_dc():
    """The secant that shows the specimen softer than fallback_below arrives with the measurement
    of a command: with j_max = 1 that was the step's only command, sent in FC, so the step is
    reported in FC (the mode its command was sent in, its target a force) and not as fallen back;
    with j_max = 2 the second command goes in DC and the step is reported so."""
    k_site = np.array([0.5, 0.9]) * K_EI2
    out, site = run(k_site, (FC, FC), j_max=1, fallback_below=0.8 * K_EI2)
    assert all(r.modes == [FC, FC] and not r.fell_back.any() for _, r in out)
    assert all(m == [FC, FC] for *_, m in site.log)
    out, site = run(k_site, (FC, FC), j_max=2, fallback_below=0.8 * K_EI2)
    for step, (_, r) in enumerate(out, start=1):
        assert r.modes == [DC, FC] and r.fell_back.tolist() == [True, False]
        assert [m for s, trial, c, m in site.log if s == step] == [[FC, FC], [DC, FC]]


def test_without_fallback_an_fc_element_stays_in_fc():
    k_site = np.array([0.5, 0.9]) * K_EI2
    out, site = run(k_site, (FC, FC))
    assert all(r.modes == [FC, FC] and not r.fell_back.any() for _, r in out)
    assert all(m == [FC, FC] for *_, m in site.log)
    out, site = run(k_site, (FC, FC), fallback_below=0.4 * K_EI2)  # not soft enough to fall back
    assert all(r.modes == [FC, FC] and not r.fell_back.any() for _, r in out)


def test_mixed_method_falls_back_within_the_step_and_reports_the_switch():
    """Mixed control, thresholds 1.2 and 0.8 K^EI: a stiff element (1.5 K^EI) goes to FC after the
    first step; when the specimen softens to 0.5 K^EI the element falls back to DC inside the step
    (reported as a switch within the step) and the step converges to the alpha method's solution."""
    site = SpringSite([1.5 * K_EI2[0], 1.0 * K_EI2[1]])
    method = ImplicitMethod(M2, C2, K_N2, [0, 1], K_EI2, 0.01, -0.1, "mixed",
                            SwitchingRule.from_initial_stiffness(K_EI2), ("a", "b"), j_max=10,
                            tol_displacement=1e-11, tol_force=1e-11)
    method.start(LOADS[0], site, None)
    out = method.step(LOADS[1], site, None, 1, 0.01)
    assert out.modes == [DC, DC] and method.modes == [FC, DC]
    assert [(s.dof, s.to, s.within_step) for s in out.switches] == [("a", "force", False)]
    site.k = np.array([0.5 * K_EI2[0], K_EI2[1]])  # the element softens
    out = method.step(LOADS[2], site, None, 2, 0.02)
    assert [(s.dof, s.to, s.within_step) for s in out.switches] == [("a", "displacement", True)]
    assert out.modes == [DC, DC] and method.modes == [DC, DC]
    step2 = [m for step, trial, c, m in site.log if step == 2]
    assert step2[0] == [FC, DC] and all(m == [DC, DC] for m in step2[1:])
    assert out.converged


def test_independent_dofs_stop_iterating_on_their_own_convergence():
    """independent=True: several SDOF side by side (diagonal M, C), each element converging on its
    own: the one whose spring equals K^EI needs one command, the other two."""
    M, C = np.diag([0.011, 0.007]), np.diag([0.02, 0.01])
    k_site = np.array([K_EI2[0], 0.6 * K_EI2[1]])
    loads = [np.zeros(2), np.array([3.0, -1.0]), np.array([4.0, 2.0]), np.array([-1.0, 2.5])]
    site = SpringSite(k_site)
    integ = ImplicitAlpha(M, C, None, [0, 1], K_EI2, 0.01, -0.1, j_max=10, tol_displacement=1e-11,
                          tol_force=1e-11, independent=True)
    integ.start(loads[0], site)
    ref = AlphaOS(M, C, np.diag(k_site), 0.01, -0.1)
    ref.start(loads[0])
    for i, P in enumerate(loads[1:]):
        state, report = integ.step(P, site, [FC, DC])
        u_ref = ref.step(P, lambda u: k_site * u).u
        assert report.converged
        assert np.allclose(state.u, u_ref, rtol=1e-9, atol=1e-12)
        assert np.allclose(state.R, k_site * state.u, rtol=1e-9, atol=1e-12)
        assert np.allclose(report.measured_u, site.get_daq().u, rtol=0, atol=1e-12)
        if i == 0:
            assert report.iterations.tolist() == [1, 2]
    assert integ.state.i == 3


def test_report_holds_the_last_commands_and_measurements():
    k_site = np.array([1.3, 2.7])
    out, site = run(k_site, (FC, DC), j_max=10)
    for step, (state, report) in enumerate(out, start=1):
        last = [c for s, t, c, m in site.log if s == step][-1]
        assert np.array_equal(report.commands, last)
        assert report.commands[0] == pytest.approx(report.R_solution[0], rel=1e-12)  # FC: the force
        assert report.commands[1] == pytest.approx(report.u_solution[1], rel=1e-12)  # DC: the displacement
        assert report.measured_u[0] == pytest.approx(last[0] / k_site[0], rel=1e-12)
        assert report.measured_R[1] == pytest.approx(last[1] * k_site[1], rel=1e-12)


def test_one_command_per_step_when_j_max_is_one():
    k_site = np.array([1.3, 2.7])
    out, site = run(k_site, (DC, DC), j_max=1)
    state, report = out[0]
    assert report.iterations.tolist() == [1, 1] and not report.converged
    assert len([1 for s, *_ in site.log if s == 1]) == 1
    # the step is accepted on the secant measured by that one command: the exact solution here
    assert np.allclose(state.u, reference(k_site, -0.1, 0.01)[0], rtol=1e-9, atol=1e-12)


def test_zero_tolerance_converges_when_the_command_repeats_exactly():
    k_site = np.array([1.3, 2.7])
    site = SpringSite(k_site)
    integ = ImplicitAlpha(M2, C2, K_N2, [0, 1], K_EI2, 0.01, -0.1, j_max=10, tol_displacement=0.0, tol_force=0.0)
    integ.start(LOADS[0], site)
    _, report = integ.step(LOADS[1], site, [DC, DC])
    assert report.converged and report.iterations.tolist() == [2, 2]


def test_a_secant_at_exactly_the_plausibility_limit_is_used():
    k_site = np.array([1.3, 2.7])
    limit = 20.0 * K_EI2
    out, _ = run(k_site, (DC, DC), {(1, 2): limit}, j_max=2)
    assert np.array_equal(out[0][1].k, limit)


def test_a_soft_dc_element_does_not_fall_back():
    k_site = np.array([0.5, 0.5]) * K_EI2
    out, site = run(k_site, (FC, DC), fallback_below=0.8 * K_EI2)
    assert out[0][1].fell_back.tolist() == [True, False] and out[0][1].modes == [DC, DC]


def test_start_from_a_displaced_moving_state():
    site = SpringSite([1.3, 2.7])
    site._committed = (np.array([0.4, -0.2]), np.array([0.52, -0.54]))
    integ = ImplicitAlpha(M2, C2, K_N2, [0, 1], K_EI2, 0.01, -0.1)
    u0, v0, P0 = np.array([0.4, -0.2]), np.array([5.0, -3.0]), np.array([1.0, 0.5])
    s = integ.start(P0, site, u0=u0, v0=v0)
    R0 = np.array([0.52, -0.54]) + K_N2 @ u0
    assert s.i == 0 and np.array_equal(s.u_pred, u0) and np.array_equal(s.v, v0)
    assert np.allclose(s.R, R0, rtol=1e-14)
    assert np.allclose(s.a, np.linalg.solve(M2, P0 - C2 @ v0 - R0), rtol=1e-12)
    with pytest.raises(ConfigError, match="3 modes for 2 elements"):
        integ.step(P0, site, [DC, DC, DC])


def test_converged_steps_on_a_nonlinear_spring_solve_eq7():
    """A Menegotto-Pinto SDOF (E&M 2007, eq. (13)) in DC and FC: each converged step solves
    eq. (7), K* u + (1+alpha) R(u) = P*, here by a scalar root search on the spring itself."""
    import scipy.optimize

    from hsio.sites import NumericalSite
    from hsio.specimens import make_specimen

    m, c, alpha, dt = 0.011, 0.02, -0.1, 0.01
    spec = {"kind": "menegotto_pinto", "k0": 2.6, "u_y": 2.0, "theta": 0.2}
    spring = make_specimen(spec)
    beta, gamma = (1 - alpha) ** 2 / 4, 0.5 - alpha
    K_star = m / (beta * dt**2) + (1 + alpha) * gamma * c / (beta * dt)
    loads = [0.0] + [6.0 * np.sin(2 * np.pi * 2.0 * i * dt) for i in range(1, 30)]
    for mode in (DC, FC):
        site = NumericalSite([make_specimen(spec)])
        integ = ImplicitAlpha([[m]], [[c]], None, [0], [2.6], dt, alpha, j_max=50, tol_displacement=1e-12,
                              tol_force=1e-12)
        integ.start(np.array([0.0]), site)
        u, v, a, R = 0.0, 0.0, 0.0, 0.0
        peak = 0.0
        for i in range(1, len(loads)):
            state, report = integ.step(np.array([loads[i]]), site, [mode])
            u_p, v_p = u + dt * v + dt**2 * (0.5 - beta) * a, v + dt * (1 - gamma) * a
            P_star = (1 + alpha) * loads[i] - alpha * loads[i - 1] - (1 + alpha) * c * v_p + alpha * c * v + K_star * u_p + alpha * R
            u1 = scipy.optimize.brentq(lambda x: K_star * x + (1 + alpha) * spring.trial(x) - P_star, -100, 100, xtol=1e-14)
            a1 = (u1 - u_p) / (beta * dt**2)
            u, v, a, R = u1, v_p + gamma * dt * a1, a1, spring.trial(u1)
            assert report.converged
            assert state.u[0] == pytest.approx(u, rel=1e-9, abs=1e-12)
            assert state.R[0] == pytest.approx(R, rel=1e-9, abs=1e-12)
            peak = max(peak, abs(u))
        assert peak > 2 * 2.0  # beyond u_y: the secant is far from K^EI
