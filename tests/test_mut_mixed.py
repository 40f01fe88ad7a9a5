"""Mixed control (docs/force_control.md; docs/method.md section 5): the switching rule's
thresholds and their refusals, and the guards of ImplicitMethod (fallback_after,
refractory_steps, fc_force_limit, explored_fraction, no_fc_at_reversal) with the records a lab
reads (switches, non-converged steps), each checked against the rule as documented."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.integrators import ImplicitMethod, SwitchingRule
from hsio.interfaces import ControlMode
from hsio.sites.base import Daq

DC, FC = ControlMode.DISPLACEMENT, ControlMode.FORCE


# -- the rule's thresholds -----------------------------------------------------------------------
@pytest.mark.parametrize("upper, lower", [([np.nan], [1.0]), ([2.0], [np.nan]), ([-np.inf], [1.0]),
                                          ([2.0], [np.inf]), ([2.0], [-1.0])])
def test_rule_refuses_thresholds_that_are_not_finite_or_negative(upper, lower):
    with pytest.raises(ConfigError, match="thresholds must be finite"):
        SwitchingRule(np.array(upper), np.array(lower))


def test_an_infinite_upper_threshold_keeps_the_element_in_dc():
    rule = SwitchingRule.from_initial_stiffness([2.0, 2.0], K_f=3.0, K_d=1.0).never_fc([True, False])
    assert rule.upper.tolist() == [np.inf, 3.0] and rule.lower.tolist() == [1.0, 1.0]
    assert rule.next_modes([DC, DC], np.array([1e12, 1e12]), np.zeros(2)) == [DC, FC]


def test_rule_refuses_lower_not_below_upper():
    with pytest.raises(ConfigError, match="below"):
        SwitchingRule(np.array([2.0]), np.array([2.0]))


def test_explicit_thresholds_below_one_kn_per_mm_are_kept():
    """K_f, K_d given (any positive value, e.g. a soft wood wall's 0.5 and 0.2 kN/mm) replace the
    ratios of K^EI; zero means 'from the ratios'."""
    rule = SwitchingRule.from_initial_stiffness([2.0, 4.0], K_f=0.5, K_d=0.2)
    assert rule.upper.tolist() == [0.5, 0.5] and rule.lower.tolist() == [0.2, 0.2]
    rule = SwitchingRule.from_initial_stiffness([2.0, 4.0], ratio_f=1.5, ratio_d=0.5)
    assert rule.upper.tolist() == [3.0, 6.0] and rule.lower.tolist() == [1.0, 2.0]
    assert rule.on == "stiffness"


def test_thresholds_from_instruments_closed_form():
    """K_f = c s_F / s_u with s = sqrt(sigma^2 + delta^2 / 12), K_d = K_f / h (h = 2 unless given:
    the default of docs/config.md's switch_hysteresis); a margin below 1 is allowed (positive)."""
    rule = SwitchingRule.from_instruments([7.2], 0.025, 0.01, margin=3.0)  # no noise: the resolutions' ratio
    assert rule.upper[0] == pytest.approx(3.0 * 0.01 / 0.025)
    assert rule.lower[0] == pytest.approx(rule.upper[0] / 2.0)
    rule = SwitchingRule.from_instruments([7.2, 1.0, 3.0], 0.05, 0.02, margin=0.5, hysteresis=4.0)
    assert rule.upper.tolist() == pytest.approx([0.2] * 3) and rule.lower.tolist() == pytest.approx([0.05] * 3)
    assert rule.on == "stiffness"
    rule = SwitchingRule.from_instruments([7.2], 0.0025, 0.002, margin=5.0, noise_mm=0.01, force_noise_kN=0.002)
    s_u, s_F = math.sqrt(0.01**2 + 0.0025**2 / 12), math.sqrt(0.002**2 + 0.002**2 / 12)
    assert rule.upper[0] == pytest.approx(5.0 * s_F / s_u)  # 1.04 kN/mm
    rule = SwitchingRule.from_instruments([7.2], 0.0, 0.0, noise_mm=0.01, force_noise_kN=0.003)  # noise alone
    assert rule.upper[0] == pytest.approx(0.03 * 0.003 / 0.01)  # the default c


@pytest.mark.parametrize("kwargs", [dict(resolution_mm=0.0), dict(resolution_mm=-0.025),
                                    dict(force_resolution_kN=0.0), dict(force_resolution_kN=-0.01),
                                    dict(noise_mm=-0.01), dict(force_noise_kN=np.nan),
                                    dict(margin=0.0), dict(hysteresis=1.0), dict(hysteresis=0.5)])
def test_instrument_rule_refuses_bad_instruments_with_a_config_error(kwargs):
    """A transducer or load cell with neither resolution nor noise, a negative or undefined one,
    no margin, or no hysteresis: a ConfigError naming the rule (never a ZeroDivisionError or
    thresholds that chatter)."""
    args = dict(K_EI=[7.2], resolution_mm=0.025, force_resolution_kN=0.01, margin=3.0, hysteresis=2.0)
    args.update(kwargs)
    with pytest.raises(ConfigError, match="switching rule"):
        SwitchingRule.from_instruments(**args)


def test_instrument_rule_error_names_what_is_wrong():
    with pytest.raises(ConfigError, match="^switching rule: the transducer and the load cell each need a resolution "
                                          "or a noise above 0$"):
        SwitchingRule.from_instruments([7.2], 0.0, 0.01)
    with pytest.raises(ConfigError, match="^switching rule: resolutions and noises must be zero or positive, margin "
                                          "positive, hysteresis above 1$"):
        SwitchingRule.from_instruments([7.2], -1.0, 0.01)


from exact_site import ExactSite as _Site  # noqa: E402


def _method(n=1, **kw):
    args = dict(M=np.eye(n) * 0.01, C=np.zeros((n, n)), K_N=None, element_dofs=list(range(n)),
                K_EI=[100.0] * n, dt=0.01, alpha=0.0, j_max=4, tol_displacement=1e-9, tol_force=1e-6,
                dof_names=[f"x{e}" for e in range(n)])
    args.update(kw)
    return ImplicitMethod(**args)


def test_mixed_starts_each_element_in_its_rules_mode_at_K_EI():
    """At rest an element is on its initial branch: above K_f it starts in FC, below in DC; a rule
    on the force starts in DC (|R| = 0); the other methods start as their name says."""
    stiff_and_soft = SwitchingRule(np.array([90.0, 150.0]), np.array([50.0, 50.0]))
    m = _method(2, method="mixed", rule=stiff_and_soft)
    assert m.modes == [FC, DC]
    assert m.start(np.zeros(2), _Site([100.0, 100.0]), None).modes == [FC, DC]
    assert _method(1, method="mixed", rule=SwitchingRule(np.array([5.0]), np.array([1.0]), "force")).modes == [DC]
    assert _method(1, method="mixed", rule=SwitchingRule(np.array([np.inf]), np.array([1.0]))).modes == [DC]
    assert _method(1, method="force_control").modes == [FC] and _method(1, method="implicit_dc").modes == [DC]


# -- start and step against the alpha method -------------------------------------------------------
def test_start_is_the_initial_state_of_eq_7():
    """Step 0: v = 0, a_0 = M^-1 (P_0 - R_0) with R_0 the committed force, the secant K^EI, no
    command yet, converged."""
    site = _Site([100.0, 50.0])
    site.base = (np.zeros(2), np.array([1.0, -2.0]))
    m = _method(2, M=np.diag([0.01, 0.02]), method="implicit_dc")
    out = m.start(np.array([3.0, 4.0]), site, None)
    assert out.v.tolist() == [0.0, 0.0] and out.u_pred.tolist() == [0.0, 0.0]
    assert out.a == pytest.approx([(3.0 - 1.0) / 0.01, (4.0 + 2.0) / 0.02])
    assert out.converged is True
    assert out.secant.tolist() == [100.0, 100.0]
    assert out.commands.tolist() == [0.0, 0.0] and out.targets.tolist() == [0.0, 0.0]
    assert out.iterations.tolist() == [0, 0] and out.iterations.dtype.kind == "i"
    assert out.measured_R.tolist() == [1.0, -2.0]
    assert out.u_solution.tolist() == [0.0, 0.0] and out.R_solution.tolist() == [0.0, 0.0]


def _hht_reference(m, c, k, P, dt, alpha):
    """The alpha method (HHT) for one linear DOF in its textbook form: Newmark's relations with
    M a_{n+1} + (1+alpha)(C v_{n+1} + K u_{n+1}) - alpha (C v_n + K u_n) = (1+alpha) P_{n+1} - alpha P_n."""
    beta, gamma = (1 - alpha) ** 2 / 4, 0.5 - alpha
    u, v = 0.0, 0.0
    a = P[0] / m
    out = []
    for n in range(len(P) - 1):
        u_t = u + dt * v + dt**2 * (0.5 - beta) * a
        v_t = v + dt * (1 - gamma) * a
        lhs = m + (1 + alpha) * (c * gamma * dt + k * beta * dt**2)
        rhs = ((1 + alpha) * P[n + 1] - alpha * P[n] - (1 + alpha) * (c * v_t + k * u_t)
               + alpha * (c * v + k * u))
        a_new = rhs / lhs
        u, v, a = u_t + beta * dt**2 * a_new, v_t + gamma * dt * a_new, a_new
        out.append((u, v, a, u_t))
    return np.array(out)


@pytest.mark.parametrize("method", ["implicit_dc", "force_control", "mixed"])
def test_linear_step_outcome_is_the_alpha_method(method):
    """A linear specimen (exact secant) with a numerical spring and damping: u, v, a and the
    predictor of every step are those of the textbook alpha method, whatever the modes."""
    k_e, k_n, mass, c, dt, alpha = 100.0, 30.0, 0.02, 0.3, 0.01, -0.1
    P = 50.0 * np.sin(2 * np.pi * 4.0 * np.arange(41) * dt)
    ref = _hht_reference(mass, c, k_e + k_n, P, dt, alpha)
    site = _Site([k_e])
    rule = SwitchingRule(np.array([90.0]), np.array([50.0]))  # mixed: into FC after the first step
    m = _method(1, M=[[mass]], C=[[c]], K_N=[[k_n]], dt=dt, alpha=alpha, method=method,
                rule=rule if method == "mixed" else None)
    m.start(P[:1], site, None)
    for n in range(1, len(P)):
        out = m.step(P[n:n + 1], site, None, step=n, time_s=n * dt)
        u, v, a, u_t = ref[n - 1]
        scale = np.abs(ref[:, 0]).max()
        assert out.u[0] == pytest.approx(u, abs=1e-9 * scale)
        assert out.v[0] == pytest.approx(v, rel=1e-7, abs=1e-9 * scale / dt)
        assert out.a[0] == pytest.approx(a, rel=1e-7, abs=1e-9 * scale / dt**2)
        assert out.u_pred[0] == pytest.approx(u_t, abs=1e-9 * scale)
        assert out.R[0] == pytest.approx((k_e + k_n) * u, abs=1e-7 * scale * k_e)
        assert out.commands.tolist() == out.targets.tolist() == site.sent[-1][0].tolist()  # what was sent last
    if method == "mixed":
        assert m.modes == [FC]


# -- the options and their defaults -------------------------------------------------------------------
def test_options_reach_the_solver():
    m = _method(1, method="mixed", j_max=7, tol_displacement=0.3, tol_force=0.4, fc_blend=0.5, blend_dc=True,
                anchor_dc=True, reset_at_reversal=True)
    c = m.core
    assert (c.j_max, c.tol_displacement, c.tol_force, c.fc_blend) == (7, 0.3, 0.4, 0.5)
    assert c.blend_dc is True and c.anchor_dc.tolist() == [True] and c.reset_at_reversal is True


def test_defaults_are_those_of_the_integrator_table():
    """Left out, every option is the [integrator] default of docs/config.md: alpha -0.05, j_max 3,
    tolerances 0.02 mm and 0.05 kN, and every guard off ("the defaults are the behaviour without
    these guards")."""
    from hsio.config import DEFAULTS

    d = DEFAULTS["integrator"]
    m = ImplicitMethod(np.eye(1) * 0.01, np.zeros((1, 1)), None, [0], [100.0], 0.01)
    c = m.core
    assert (c.alpha, c.j_max, c.tol_displacement, c.tol_force, c.fc_blend) == \
        (d["alpha"], d["j_max"], d["tol_displacement_mm"], d["tol_force_kN"], d["fc_blend"])
    assert (c.blend_dc, bool(c.anchor_dc.all()), c.reset_at_reversal) == (d["blend_dc"], d["anchor_dc"], False)
    assert m.fallback_after is None and d["fc_fallback_after"] == 0
    assert m.refractory_steps == d["refractory_steps"] == 0
    assert m.explored_fraction is None and m.fc_force_limit is None
    assert m.no_fc_at_reversal is d["no_fc_at_reversal"] is False


@pytest.mark.parametrize("method", ["implicit_dc", "force_control"])
def test_a_rule_given_to_another_method_is_not_used(method):
    """Only ``mixed`` switches: a rule passed to implicit_dc or force_control changes no mode."""
    site = _Site([100.0])
    site.k_seen = [200.0]
    m = _method(1, method=method, rule=SwitchingRule(np.array([150.0]), np.array([50.0])))
    assert m.rule is None and m.thresholds is None
    m.start(np.zeros(1), site, None)
    start = list(m.modes)
    for n in range(1, 4):
        site.k_seen = [200.0 if n % 2 else 20.0]
        out = m.step(np.array([5.0 * n]), site, None, step=n)
        assert out.switches == [] and m.modes == start


def test_switches_name_the_dof_by_number_without_names():
    site = _Site([100.0, 100.0])
    site.k_seen = [None, 200.0]
    m = ImplicitMethod(np.eye(3) * 0.01, np.zeros((3, 3)), None, [0, 2], [100.0, 100.0], 0.01, method="mixed",
                       rule=SwitchingRule(np.array([150.0]), np.array([50.0])))
    m.start(np.zeros(3), site, None)
    out = m.step(np.array([1.0, 0.0, 1.0]), site, None, step=1)
    assert [(s.dof, s.to) for s in out.switches] == [("2", "force")]


# -- switches as recorded --------------------------------------------------------------------------
def test_switch_records_step_time_secant_and_force():
    """The secant read rises above K_f at step 3: the switch to FC is recorded at that step and
    time with the secant and force that decided it; nothing before."""
    site = _Site([100.0])
    m = _method(1, method="mixed", rule=SwitchingRule(np.array([150.0]), np.array([50.0])))
    m.start(np.zeros(1), site, None)
    records = []
    for n in range(1, 6):
        if n == 3:
            site.k_seen = [200.0]
        out = m.step(np.array([10.0 * n]), site, None, step=n, time_s=0.01 * n)
        records += [(n, s, out) for s in out.switches]
    assert len(records) == 1
    n, s, out = records[0]
    assert (n, s.step, s.time_s, s.dof, s.to, s.within_step, s.reason) == (3, 3, 0.03, "x0", "force", False, "rule")
    assert s.secant_kN_mm == 200.0 and s.force_kN == pytest.approx(out.measured_R[0])
    assert out.modes == [DC] and m.modes == [FC]  # the step ran in DC; the next runs in FC
    assert site.mode_changes[-1] == [FC]


# -- fallback_after ----------------------------------------------------------------------------------
def test_fallback_after_is_reported_with_step_time_and_dof():
    """Mixed control, the element in FC after a small first step, then pushed past the stiff branch
    of a softening element (the FC secant iteration oscillates between the stiff and the soft
    secant, E&M 2007 eqs. 11-12): with fallback_after = 2 the step is finished in DC, listed in
    not_converged with its step, time and DOF, and recorded as a within-step switch to DC; without
    it, nothing is listed."""
    for after in (None, 2):
        site = _Site([100.0], u_c=[0.5], k2=[10.0])
        m = _method(1, method="mixed", rule=SwitchingRule(np.array([50.0]), np.array([5.0])), fallback_after=after)
        m.start(np.zeros(1), site, None)
        m.step(np.array([10.0]), site, None, step=6, time_s=0.06)
        assert m.modes == [FC]
        first = len(site.sent)
        out = m.step(np.array([400.0]), site, None, step=7, time_s=0.07)
        within = [s for s in out.switches if s.within_step]
        if after is None:
            assert m.not_converged == [] and within == [] and not out.converged
            continue
        assert m.not_converged == [{"step": 7, "time_s": 0.07, "dof": "x0"}]
        assert [(s.step, s.time_s, s.dof, s.to, s.reason) for s in within] == [(7, 0.07, "x0", "displacement",
                                                                                 "not converging")]
        assert within[0].secant_kN_mm == out.secant[0]
        assert within[0].force_kN == out.measured_R[0]
        kinds = [mo[0] for _, mo in site.sent[first:]]
        assert kinds[:2] == [FC, FC] and all(k is DC for k in kinds[2:])
        assert out.modes == [DC]


# -- refractory_steps --------------------------------------------------------------------------------
def _refractory_run(refractory, soft_step=2, steps=9):
    """One element: its secant reads 200 (above K_f = 150) except in ``soft_step``, where it reads
    20 (below K_d = 50: the FC element falls back to DC within the step). Returns the mode of
    each step's commands (1-based) and the method."""
    site = _Site([100.0])
    site.k_seen = [200.0]
    m = _method(1, method="mixed", rule=SwitchingRule(np.array([150.0]), np.array([50.0])),
                refractory_steps=refractory)
    m.start(np.zeros(1), site, None)
    ran = {}
    for n in range(1, steps + 1):
        site.k_seen = [20.0] if n == soft_step else [200.0]
        first = len(site.sent)
        m.step(np.array([5.0 * n]), site, None, step=n, time_s=0.01 * n)
        ran[n] = site.sent[first][1][0]
    return ran, m


@pytest.mark.parametrize("refractory", [0, 1, 3])
def test_refractory_steps_keep_dc_that_many_steps(refractory):
    """Step 1 runs in DC and switches to FC; step 2 starts in FC and falls back (secant below K_d).
    The element then runs ``refractory_steps`` whole steps in DC (docs/force_control.md, Guards)
    although its secant is above K_f again, and FC after them. Step 3 runs in DC whatever the
    period: the rule itself decided on the soft secant of step 2."""
    ran, _ = _refractory_run(refractory)
    assert ran[1] is DC and ran[2] is FC
    in_dc = [n for n in range(3, 10) if ran[n] is DC]
    assert in_dc == list(range(3, 3 + max(refractory, 1)))
    assert all(ran[n] is FC for n in range(3 + max(refractory, 1), 10))


def test_a_fallback_on_a_soft_secant_says_so():
    site = _Site([100.0])
    site.k_seen = [200.0]
    m = _method(1, method="mixed", rule=SwitchingRule(np.array([150.0]), np.array([50.0])))
    m.start(np.zeros(1), site, None)
    m.step(np.array([5.0]), site, None, step=1)
    site.k_seen = [20.0]
    out = m.step(np.array([10.0]), site, None, step=2)
    assert [(s.within_step, s.to, s.reason) for s in out.switches] == [(True, "displacement", "secant below K_d")]


def test_refractory_period_starts_only_with_a_fallback():
    """An element that never left FC within a step switches to FC as soon as the rule says so,
    whatever refractory_steps."""
    ran, m = _refractory_run(10**6, soft_step=None)
    assert ran[1] is DC and all(ran[n] is FC for n in range(2, 10))


# -- fc_force_limit and explored_fraction ------------------------------------------------------------
def _guard_run(P, **kw):
    """A linear element (exact secant 100) in mixed control with K_d = 50 < K_f = 90 < 100, so that
    the rule puts it in FC from the start; nearly static (a small mass, the alpha method's
    damping of high frequencies). Returns per step (1-based): the mode the step
    entered with, guarded or not (its first command a displacement), R_solution, measured R."""
    site = _Site([100.0])
    m = _method(1, M=[[1e-4]], alpha=-1.0 / 3.0, method="mixed", rule=SwitchingRule(np.array([90.0]), np.array([50.0])),
                **kw)
    m.start(np.zeros(1), site, None)
    rows = []
    for n in range(1, len(P) + 1):
        entered = m.modes[0]
        first = len(site.sent)
        out = m.step(np.array([P[n - 1]]), site, None, step=n, time_s=0.01 * n)
        first_mode = site.sent[first][1][0]
        rows.append((entered, entered is FC and first_mode is DC, out.R_solution[0], out.measured_R[0], out))
    return rows, m


def test_fc_force_limit_runs_a_step_beyond_the_limit_in_dc():
    """FC only while the step's force stays within +/- the limit (both signs); a step beyond it
    runs in DC, is counted, recorded as a within-step switch to DC, and does not start the
    refractory period (FC again from the next step)."""
    P = [2.0, 5.0, 20.0, 5.0, -5.0, -20.0, -5.0, 5.0]
    rows, m = _guard_run(P, fc_force_limit=10.0, refractory_steps=10**6)
    entered = [r[0] for r in rows]
    assert all(e is FC for e in entered)  # K^EI = 100 > K_f: FC from the start
    guarded = [r[1] for r in rows]
    expect = [abs(r[2]) > 10.0 for r in rows]
    assert guarded == expect == [False, False, True, False, False, True, False, False]
    assert m.guarded_steps == 2
    for r in rows:
        within = [s for s in r[4].switches if s.within_step]
        assert [(s.to, s.step) for s in within] == ([("displacement", r[4].switches[0].step)] if r[1] else [])
        assert all(s.reason == "force outside the FC range" for s in within)


def test_explored_fraction_allows_fc_only_inside_rho_times_the_range_carried():
    """explored_fraction rho: a step whose first force command leaves rho times the range of
    measured force carried so far (including zero) runs in DC. The exact secant makes the first
    force command the step's solution, so the rule can be checked from the record."""
    rho = 0.5
    P = [1.0, 3.0, 6.0, 10.0, 9.0, 6.0, 4.0, 1.0, 3.0, -2.0, -8.0, -3.0, -5.0, 2.0, 4.5]
    rows, m = _guard_run(P, explored_fraction=rho)
    lo = hi = 0.0
    checked = 0
    for n, (entered, guarded, R_first, R_meas, _) in enumerate(rows):
        if entered is FC:
            outside = R_first > rho * hi or R_first < rho * lo
            margin = min(abs(R_first - rho * hi), abs(R_first - rho * lo))
            if margin > 0.05:
                assert guarded == outside, (n + 1, R_first, lo, hi)
                checked += 1
        lo, hi = min(lo, R_meas), max(hi, R_meas)
    assert checked >= 10
    assert m.guarded_steps == sum(r[1] for r in rows) > 0
    assert not all(r[1] for r in rows[1:])  # some steps do run in FC


def test_force_limit_and_explored_range_take_the_larger_of_the_two():
    """With both guards, FC where either allows it: inside +/- the limit even where nothing was
    carried yet, and inside rho times the explored range beyond the limit."""
    rho, limit = 0.5, 3.0
    P = [1.0, 12.0, 2.0, 1.0, 0.5, -1.0, -12.0, -4.5, 4.5, 1.0, -7.0]
    rows, _ = _guard_run(P, explored_fraction=rho, fc_force_limit=limit)
    lo = hi = 0.0
    kinds = set()
    for n, (entered, guarded, R_first, R_meas, _) in enumerate(rows):
        if entered is FC:
            outside = R_first > max(rho * hi, limit) or R_first < min(rho * lo, -limit)
            assert guarded == outside, (n + 1, R_first, lo, hi)
            if not guarded and abs(R_first) > limit:
                kinds.add("inside the explored range, beyond the limit")
            if not guarded and (R_first > rho * hi or R_first < rho * lo):
                kinds.add("inside the limit, never carried")
            if guarded:
                kinds.add("guarded")
        lo, hi = min(lo, R_meas), max(hi, R_meas)
    assert len(kinds) == 3, kinds


# -- no_fc_at_reversal ------------------------------------------------------------------------------
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_first_motion_is_not_a_reversal(sign):
    """From rest (and after steps without motion) the first increment is not a reversal: an
    element reading stiffer than K_f switches to FC at the end of that step."""
    site = _Site([100.0])
    m = _method(1, method="mixed", rule=SwitchingRule(np.array([150.0]), np.array([50.0])),
                no_fc_at_reversal=True)
    m.start(np.zeros(1), site, None)
    site.k_seen = [None]  # no motion: no estimate, the secant stays K^EI (below K_f)
    m.step(np.zeros(1), site, None, step=1)
    m.step(np.zeros(1), site, None, step=2)
    assert m.modes == [DC]
    site.k_seen = [200.0]
    out = m.step(np.array([sign * 5.0]), site, None, step=3)
    assert m.modes == [FC] and m.deferred_at_reversal == 0
    assert [(s.step, s.to) for s in out.switches] == [(3, "force")]


def test_unknown_method_is_refused_naming_the_methods():
    with pytest.raises(ConfigError, match="must be one of implicit_dc, force_control, mixed, got 'newmark'"):
        _method(1, method="newmark")


@pytest.mark.parametrize("guard", [{"fallback_after": 2}, {"refractory_steps": 5}, {"explored_fraction": 0.5},
                                   {"fc_force_limit": 10.0}, {"no_fc_at_reversal": True}])
@pytest.mark.parametrize("method", ["implicit_dc", "force_control"])
def test_a_guard_of_mixed_is_refused_with_another_method(method, guard):
    """From Python as from a configuration: force control with fallback_after would fall back to DC
    for good after one step that did not converge, silently changing the method."""
    from hsio.errors import ConfigError
    from hsio.integrators import ImplicitMethod

    with pytest.raises(ConfigError, match=f"{next(iter(guard))}: a guard of method 'mixed', not of '{method}'"):
        ImplicitMethod(np.eye(1), np.zeros((1, 1)), None, [0], [1.0], 0.01, -0.05, method, **guard)
    ImplicitMethod(np.eye(1), np.zeros((1, 1)), None, [0], [1.0], 0.01, -0.05, "mixed", **guard)  # accepted


def test_the_instrument_rule_default_margin_is_the_documented_c():
    """c = 0.03 (docs/force_control.md), the same in the function, the study's recipe and a run
    configuration's switch_margin."""
    from hsio.config import DEFAULTS
    from hsio.integrators import SwitchingRule
    from hsio.study_mixed import Recipe

    assert Recipe().margin == DEFAULTS["integrator"]["switch_margin"] == 0.03
    rule = SwitchingRule.from_instruments([100.0], 0.025, 0.01)
    assert rule.upper[0] == pytest.approx(0.03 * 0.01 / 0.025) and rule.lower[0] == pytest.approx(rule.upper[0] / 2)


def test_fallback_after_zero_is_off_and_j_max_is_refused():
    """fallback_after = 0 is off, as fc_fallback_after = 0 in a run configuration (not a fallback
    after the first FC command); fallback_after = j_max would leave no command for DC, so the
    guard would never act: refused rather than accepted as a guard that does nothing."""
    site = _Site([100.0], u_c=[0.5], k2=[10.0])
    m = _method(1, method="mixed", rule=SwitchingRule(np.array([50.0]), np.array([5.0])), fallback_after=0)
    assert m.fallback_after is None
    m.start(np.zeros(1), site, None)
    m.step(np.array([10.0]), site, None, step=1)
    out = m.step(np.array([400.0]), site, None, step=2)
    assert m.not_converged == [] and [s for s in out.switches if s.within_step] == []
    with pytest.raises(ConfigError, match=r"fallback_after must be None or 0 \(off\), or a whole number of FC "
                                          r"commands below j_max \(4\)"):
        _method(1, method="mixed", fallback_after=4)
