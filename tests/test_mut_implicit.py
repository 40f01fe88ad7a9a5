"""ImplicitAlpha (docs/method.md sections 3 and 5, eqs. 7-12): the set-ups it refuses, each with
a ConfigError that names what is wrong, its defaults, and the per-element guards of one step
(fc_force_range, fallback_after) with several elements, where one element's guard must leave
the others alone."""

from __future__ import annotations

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.integrators import ImplicitAlpha
from hsio.interfaces import ControlMode
from hsio.sites.base import Daq

DC, FC = ControlMode.DISPLACEMENT, ControlMode.FORCE


def _alpha(n=1, **kw):
    args = dict(M=np.eye(n) * 0.01, C=np.zeros((n, n)), K_N=None, element_dofs=list(range(n)),
                K_EI=[100.0] * n, dt=0.01)
    args.update(kw)
    return ImplicitAlpha(**args)


# -- refused set-ups -----------------------------------------------------------------------------------
@pytest.mark.parametrize("kw, words", [
    (dict(alpha=-0.34), "alpha must be in [-1/3, 0]"),
    (dict(alpha=-2.0 / 3.0), "alpha must be in [-1/3, 0]"),
    (dict(alpha=0.01), "alpha must be in [-1/3, 0]"),
    (dict(dt=0.0), "dt must be positive"),
    (dict(j_max=0), "j_max (commands per step) must be a whole number in 1..100, got 0"),
    (dict(j_max=101), "j_max (commands per step) must be a whole number in 1..100, got 101"),
    (dict(tol_displacement=-1.0), "tol_displacement must be a number, zero or positive"),
    (dict(tol_force=-1.0), "tol_force must be a number, zero or positive"),
    (dict(tol_force=float("nan")), "tol_force must be a number, zero or positive"),
    (dict(C=np.zeros((2, 2))), "C is (2, 2), M is (1, 1)"),
    (dict(K_N=np.zeros((1, 2))), "K_N is (1, 2), M is (1, 1)"),
    (dict(element_dofs=[1]), "element DOF [1] not all in 0..0"),
    (dict(element_dofs=[-1]), "element DOF [-1] not all in 0..0"),
    (dict(K_EI=[0.0]), "initial stiffness must be positive"),
    (dict(K_EI=[np.nan]), "initial stiffness must be positive"),
    (dict(K_EI=[-2.0]), "initial stiffness must be positive"),
    (dict(K_EI=[1.0, 2.0]), "2 initial stiffnesses for 1 elements"),
    (dict(fc_blend=0.0), "fc_blend must be in (0, 1]"),
    (dict(fc_blend=1.5), "fc_blend must be in (0, 1]"),
    (dict(max_stiffness_ratio=1.0), "max_stiffness_ratio must exceed 1"),
])
def test_refused_setups_name_what_is_wrong(kw, words):
    with pytest.raises(ConfigError) as e:
        _alpha(**kw)
    assert str(e.value).startswith("implicit alpha method: ") and words in str(e.value)


def test_the_limits_of_each_range_are_accepted():
    for kw in (dict(alpha=-1.0 / 3.0), dict(alpha=0.0), dict(tol_displacement=0.0, tol_force=0.0),
               dict(K_EI=[0.5]), dict(fc_blend=1.0), dict(fc_blend=1e-3), dict(max_stiffness_ratio=1.5)):
        _alpha(**kw)
    alg = _alpha(2, element_dofs=[1, 0], K_EI=[0.5, 2.0])
    assert alg.dofs.tolist() == [1, 0]


def test_two_elements_on_one_dof_are_refused():
    with pytest.raises(ConfigError, match="two experimental elements act on the same DOF"):
        _alpha(2, element_dofs=[1, 1])


def test_experimental_stiffness_must_be_diagonal_relative_to_its_size():
    """A diagonal matrix is the vector of its diagonal; an off-diagonal term of 1e-11 of the
    diagonal (here 1e-14 on 1e-3 kN/mm) couples the DOF and is refused."""
    alg = _alpha(2, K_EI=np.diag([1e-3, 2e-3]))
    assert alg.K_EI.tolist() == [1e-3, 2e-3]
    with pytest.raises(ConfigError, match="not diagonal"):
        _alpha(2, K_EI=np.array([[1e-3, 1e-14], [1e-14, 2e-3]]))
    with pytest.raises(ConfigError, match="not diagonal"):
        _alpha(2, K_EI=np.array([[100.0, 1.0], [1.0, 100.0]]))


@pytest.mark.parametrize("kw", [dict(M=np.array([[0.01, 0.001], [0.001, 0.01]])), dict(element_dofs=[1, 0])])
def test_independent_needs_diagonal_matrices_and_element_j_at_dof_j(kw):
    with pytest.raises(ConfigError, match="independent=True needs diagonal M, C, K_N and element j at DOF j"):
        _alpha(2, independent=True, **kw)
    _alpha(2, independent=True)


def test_defaults():
    """Tolerances 1e-10 (iterate to convergence), secants up to 20 K^EI plausible, fc_blend 1 and
    every option off."""
    alg = _alpha()
    assert (alg.tol_displacement, alg.tol_force, alg.max_stiffness_ratio, alg.fc_blend) == (1e-10, 1e-10, 20.0, 1.0)
    assert (alg.blend_dc, alg.reset_at_reversal, alg.independent) == (False, False, False)
    assert alg.anchor_dc.dtype == bool and alg.anchor_dc.all()  # on by default, per element
    assert alg.alpha == 0.0 and alg.j_max == 10


# -- per-element guards within a step -------------------------------------------------------------------
from exact_site import ExactSite as _Site  # noqa: E402


def _two(**kw):
    """Element 0 softens past u = 0.5 (k 100 -> 10: the FC iteration oscillates), element 1 is
    linear (100); both loaded by 400 kN through K* = 400 kN/mm."""
    site = _Site([100.0, 100.0], [0.5, np.inf], [10.0, 100.0])
    alg = _alpha(2, j_max=4, tol_displacement=1e-6, tol_force=1e-6, **kw)
    alg.start(np.zeros(2), site)
    return site, alg


def test_fallback_after_moves_only_the_stuck_element_to_dc():
    site, alg = _two()
    _, rep = alg.step(np.array([400.0, 400.0]), site, [FC, FC], None, 2)
    assert rep.not_converging.tolist() == [True, False] and rep.fell_back.tolist() == [True, False]
    assert rep.modes == [DC, FC]
    assert [m for _, m in site.sent][:2] == [[FC, FC], [FC, FC]]
    assert all(m == [DC, FC] for _, m in site.sent[2:])


def test_fallback_after_j_max_commands_changes_nothing():
    """fallback_after = j_max: no command is left to send in DC, so nothing falls back and the
    step reports FC as it ran (not converged)."""
    site, alg = _two()
    _, rep = alg.step(np.array([400.0, 400.0]), site, [FC, FC], None, 4)
    assert not rep.not_converging.any() and not rep.fell_back.any() and rep.modes == [FC, FC]
    assert all(m == [FC, FC] for _, m in site.sent[1:]) and not rep.converged


def test_a_force_range_guards_only_the_element_outside_it():
    """Element 0 would be commanded beyond its range (DC for the step), element 1 within (FC);
    a DC element is never guarded."""
    site = _Site([100.0, 100.0, 100.0], [np.inf] * 3, [100.0] * 3)
    alg = _alpha(3, j_max=3, tol_displacement=1e-9, tol_force=1e-9)
    alg.start(np.zeros(3), site)
    lo, hi = np.array([-1.0, -500.0, -1.0]), np.array([1.0, 500.0, 1.0])
    _, rep = alg.step(np.array([100.0, 100.0, 100.0]), site, [FC, FC, DC], fc_force_range=(lo, hi))
    assert rep.guarded.tolist() == [True, False, False] and rep.fell_back.tolist() == [True, False, False]
    assert rep.modes == [DC, FC, DC]
    assert all(m == [DC, FC, DC] for _, m in site.sent)
    last = site.sent[-1][0]  # displacements for the DC elements, a force for the FC one
    assert last.tolist() == pytest.approx([rep.u_solution[0], rep.R_solution[1], rep.u_solution[2]], rel=1e-12)


def test_force_range_is_closed():
    """A first force command exactly at hi (or lo) is inside the range."""
    def first_force(rng):
        site = _Site([100.0], [np.inf], [100.0])
        alg = _alpha(1, j_max=3, tol_displacement=1e-9, tol_force=1e-9)
        alg.start(np.zeros(1), site)
        _, rep = alg.step(np.array([sign * 100.0]), site, [FC], fc_force_range=rng)
        return rep

    for sign in (1.0, -1.0):
        R = first_force(None).R_solution[0]
        assert not first_force((np.array([min(R, -R)]), np.array([max(R, -R)]))).guarded[0]
        tight = (np.array([R if sign < 0 else -1e9]), np.array([R if sign > 0 else 1e9]))
        assert not first_force(tight).guarded[0]
        inside = (np.array([R + 1e-9 if sign < 0 else -1e9]), np.array([R - 1e-9 if sign > 0 else 1e9]))
        assert first_force(inside).guarded[0]


# -- the complementary estimate and the reset at a reversal --------------------------------------------
class _BiasedSite(_Site):
    """A linear element (k = 100) read by a transducer with an offset ``bias`` (mm); the load cell
    is exact. ``estimate=False``: eq. (11) refused every time (k = nan)."""

    def __init__(self, bias=0.0, estimate=True):
        super().__init__([100.0], [np.inf], [100.0])
        self.bias, self.estimate = bias, estimate

    def set_trial(self, commands, modes):
        super().set_trial(commands, modes)
        d = self._daq
        u = d.u + self.bias
        with np.errstate(invalid="ignore", divide="ignore"):
            k = (d.R - self.base[1]) / (u - self.base[0]) if self.estimate else np.full(1, np.nan)
        self.last = (u, d.R)
        self._daq = Daq(u=u, R=d.R, k=k, targets=d.targets, commands=d.commands, samples=None)


def _first_force_command(alg, P_next: float, k: float, R_b: float, u_b: float) -> float:
    """Eq. (12) on one DOF without a numerical spring, alpha = 0, C = 0 (eq. 10: P* = P + K* u_pred):
    {K*/k + 1} R = P* + K*/k R_b - K* u_b."""
    K_star = alg.K_star[0, 0]
    u_pred, _ = alg.predict()
    P_star = P_next + K_star * u_pred[0]
    return (P_star + K_star / k * R_b - K_star * u_b) / (K_star / k + 1.0)


@pytest.mark.parametrize("lam", [0.1, 0.5])
def test_fc_base_is_the_complementary_estimate(lam):
    """fc_blend lambda < 1: the next FC step starts from u_b = u_s + lambda (u_meas - u_s), u_s the
    base moved along the secant to the measured force; its first force command is eq. (12) with
    that base: {K*/k + (1+alpha)} R = P* + K*/k R_b - K* u_b (one DOF, no numerical spring)."""
    site = _BiasedSite(bias=0.05, estimate=False)  # the secant stays K^EI: u_s is the true displacement
    alg = _alpha(1, j_max=1, fc_blend=lam, tol_force=1e-9)
    alg.start(np.zeros(1), site)
    _, rep = alg.step(np.array([40.0]), site, [FC])
    k, u_m, R_m = rep.k[0], rep.measured_u[0], rep.measured_R[0]
    u_s = 0.0 + (R_m - 0.0) / k
    u_b = u_s + lam * (u_m - u_s)
    expected = _first_force_command(alg, 60.0, k, R_m, u_b)
    n = len(site.sent)
    alg.step(np.array([60.0]), site, [FC])
    assert site.sent[n][0][0] == pytest.approx(expected, rel=1e-12)
    assert abs(u_m - u_s) > 1e-3  # the offset matters: lambda changes the command


@pytest.mark.parametrize("reading, expected_u_b", [
    (0.02, 0.1 * 0.02),  # within 5 s_u + delta_u of rest (0.0867 mm): the initial state, the reading weighted by lambda
    (-0.09, -0.09),  # beyond it: the specimen is not where the state says; the reading
])
def test_the_first_fc_base_is_the_initial_state_when_the_reading_at_rest_is_within_the_noise(reading, expected_u_b):
    """The transducer zeroed at rest reads one noisy sample there; an FC element whose first base
    were that sample would keep its noise as an offset of the specimen for as long as lambda takes
    to correct it (1 / lambda steps). With the instruments known (noise 0.01 mm, resolution
    0.025 mm: s_u = 0.0123 mm) the first base is u0 + lambda (reading - u0)."""
    site = _Site([100.0], [np.inf], [100.0])
    site.base = (np.array([reading]), np.zeros(1))
    alg = _alpha(1, j_max=1, fc_blend=0.1, tol_force=1e-9, secant_uncertainty=((0.01, 0.025), (0.01, 0.01)))
    alg.start(np.zeros(1), site)
    expected = _first_force_command(alg, 40.0, 100.0, 0.0, expected_u_b)
    alg.step(np.array([40.0]), site, [FC])
    assert site.sent[0][0][0] == pytest.approx(expected, rel=1e-12)
    unknown = _alpha(1, j_max=1, fc_blend=0.1, tol_force=1e-9)  # the instruments not known: the reading
    site = _Site([100.0], [np.inf], [100.0])
    site.base = (np.array([reading]), np.zeros(1))
    unknown.start(np.zeros(1), site)
    expected = _first_force_command(unknown, 40.0, 100.0, 0.0, reading)
    unknown.step(np.array([40.0]), site, [FC])
    assert site.sent[0][0][0] == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("reading, expected_R_b", [
    (0.04, 0.1 * 0.04),  # within 5 s_F + delta_F of rest (0.062 kN): the state's force, the reading weighted by lambda
    (-0.5, -0.5),  # beyond it (a preload, an offset): the reading
])
def test_the_first_fc_base_force_is_the_state_at_rest_when_the_reading_is_within_the_noise(reading, expected_R_b):
    """The load cell zeroed at rest reads one noisy sample there; an FC element whose first base
    force were that sample would apply its noise as a force on the specimen (moving it by noise / k)
    until the complementary estimate corrects it. With the instruments known (load cell noise
    0.01 kN, resolution 0.01 kN: s_F = 0.0104 kN) the first base force is the initial state's,
    0 at rest, plus lambda (reading - 0)."""
    site = _Site([100.0], [np.inf], [100.0])
    site.base = (np.zeros(1), np.array([reading]))
    alg = _alpha(1, j_max=1, fc_blend=0.1, tol_force=1e-9, secant_uncertainty=((0.01, 0.025), (0.01, 0.01)))
    alg.start(np.zeros(1), site)
    expected = _first_force_command(alg, 40.0, 100.0, expected_R_b, 0.0)
    alg.step(np.array([40.0]), site, [FC])
    assert site.sent[0][0][0] == pytest.approx(expected, rel=1e-12)
    dc = _alpha(1, j_max=1, fc_blend=0.1, tol_force=1e-9, secant_uncertainty=((0.01, 0.025), (0.01, 0.01)))
    site = _Site([100.0], [np.inf], [100.0])
    site.base = (np.zeros(1), np.array([reading]))
    dc.start(np.zeros(1), site)
    K_star = dc.K_star[0, 0]
    P_star = 40.0 + K_star * dc.predict()[0][0]
    dc.step(np.array([40.0]), site, [DC])  # a DC element keeps the pair it reads: K* u + reading + k u = P*
    assert site.sent[0][0][0] == pytest.approx((P_star - reading) / (K_star + 100.0), rel=1e-12)


def test_a_guarded_step_restarts_the_complementary_estimate_from_the_measurement():
    """An FC element guarded into DC for a step (its force outside the range) runs that step from
    its measured displacement, and the complementary estimate it carries into the next FC step is
    built from that base, u_s = u_meas + (R_m - R_meas) / k, not from the estimate it had before
    (which FC on a stale secant may have carried far from the specimen: a cracked infill)."""
    site = _BiasedSite(bias=0.0, estimate=False)
    lam = 0.1
    alg = _alpha(1, j_max=1, fc_blend=lam, tol_force=1e-9)
    alg.start(np.zeros(1), site)
    alg.step(np.array([40.0]), site, [FC])
    alg._u_fc = alg._u_fc + 0.3  # an estimate that has drifted 0.3 mm from the specimen
    u_base, R_base = (float(x[0]) for x in site.committed())
    _, rep = alg.step(np.array([50.0]), site, [FC], fc_force_range=(np.array([-1.0]), np.array([1.0])))
    assert rep.guarded[0] and rep.modes == [DC]
    assert site.sent[-1][0][0] == pytest.approx(rep.u_solution[0], rel=1e-12)
    k, u_m, R_m = rep.k[0], rep.measured_u[0], rep.measured_R[0]
    u_s = u_base + (R_m - R_base) / k
    expected_u_b = u_s + lam * (u_m - u_s)
    expected = _first_force_command(alg, 60.0, k, R_m, expected_u_b)
    n = len(site.sent)
    alg.step(np.array([60.0]), site, [FC])
    assert site.sent[n][0][0] == pytest.approx(expected, rel=1e-9)
    assert abs(expected_u_b - u_m) < 0.05  # the drift of 0.3 mm is gone


def test_reset_at_reversal_only_at_a_reversal():
    """reset_at_reversal with every estimate refused and the secant stale (10 against K^EI = 100):
    a step without any increment, the first loading from rest (either sign) and small force
    increments in one direction are no reversal; the first step whose force increment changes sign
    is, and K^EI is the secant from then on."""
    for sign in (1.0, -1.0):
        site = _BiasedSite(estimate=False)
        alg = _alpha(1, M=np.eye(1) * 1e-6, j_max=2, fc_blend=0.5, tol_force=1e-9,
                     reset_at_reversal=True)  # nearly static: the force follows the load
        alg.start(np.zeros(1), site)
        alg.k = np.array([10.0])
        for P in (0.0, 0.3, 0.6, 0.9):
            alg.step(np.array([sign * P]), site, [FC])
            assert alg.reversal_resets == 0 and alg.k[0] == 10.0
        for P in (0.5,):  # the force goes back
            alg.step(np.array([sign * P]), site, [FC])
        assert alg.reversal_resets == 1 and alg.k[0] == 100.0


@pytest.mark.parametrize("tol_force, commands", [(1.0, 1), (1e-9, 2)])
def test_fc_converges_on_the_force_tolerance(tol_force, commands):
    """An FC element whose secant starts 5 % above its stiffness: the solution on the exact secant
    of eq. (11), measured after the first command, differs from that command by 0.8 kN. Within
    tol_force of it the step has converged after one command, whatever the (tiny) displacement
    tolerance; with a tiny force tolerance the new force is sent and repeats."""
    site = _Site([100.0], [np.inf], [100.0])
    alg = _alpha(1, K_EI=[105.0], j_max=5, tol_displacement=1e-12, tol_force=tol_force)
    alg.start(np.zeros(1), site)
    _, rep = alg.step(np.array([100.0]), site, [FC])
    assert 1e-3 < abs(rep.R_solution[0] - site.sent[0][0][0]) < 1.0
    assert rep.converged and rep.iterations.tolist() == [commands] and len(site.sent) == commands


def test_a_mass_matrix_that_is_not_square_is_refused():
    from hsio.errors import ConfigError
    from hsio.integrators.implicit import ImplicitAlpha

    with pytest.raises(ConfigError, match=r"M must be a square matrix, got shape \(1, 2\)"):
        ImplicitAlpha([[1.0, 0.0]], np.zeros((1, 1)), None, [0], [1.0], 0.01)


def test_an_fc_element_guarded_in_its_first_step_runs_it_from_the_pair_it_reads():
    """Guarded into DC (its first force command outside the range), the first step starts from
    its measurement: the displacement and the force it reads, as a DC element's line passes
    through the measurement; not the force of the state at rest (the FC base, lambda-weighted)."""
    reading = 0.04  # within 5 s_F + delta_F of rest: FC would base at 0.1 x 0.04
    site = _Site([100.0], [np.inf], [100.0])
    site.base = (np.zeros(1), np.array([reading]))
    alg = _alpha(1, j_max=1, fc_blend=0.1, tol_force=1e-9, secant_uncertainty=((0.01, 0.025), (0.01, 0.01)))
    alg.start(np.zeros(1), site)
    K_star = alg.K_star[0, 0]
    P_star = 40.0 + K_star * alg.predict()[0][0]
    _, rep = alg.step(np.array([40.0]), site, [FC], fc_force_range=(np.array([5.0]), np.array([6.0])))
    assert list(rep.guarded) == [True]
    assert site.sent[0][0][0] == pytest.approx((P_star - reading) / (K_star + 100.0), rel=1e-12)
