"""Mixed control on stiff specimens: the instruments, the cracking infill, switching thresholds
from the instruments with hysteresis, bumpless switches, non-converged FC steps
(docs/force_control.md; E&M 2007 section 5)."""

import math

import numpy as np
import pytest

from emulators.servo import ServoConfig, ServoController
from hsio.errors import ConfigError
from hsio.integrators import ImplicitAlpha, SwitchingRule
from hsio.interfaces import ControlMode
from hsio.sites.base import Daq
from hsio.specimens import CrackingInfill, Linear, make_specimen, specimen_spec
from hsio.structures import get_structure

DC, FC = ControlMode.DISPLACEMENT, ControlMode.FORCE


# -- instruments -------------------------------------------------------------------------------
def test_sensor_bandwidths_default_to_ideal_sensors():
    c = ServoConfig()
    assert c.force_bandwidth_hz == 0.0 and c.displacement_bandwidth_hz == 0.0
    with pytest.raises(ConfigError):
        ServoConfig(force_bandwidth_hz=-1.0)


def test_load_cell_bandwidth_is_a_first_order_lag():
    """A force step read through a 10 Hz load cell: 1 - exp(-2 pi f t) of it after t."""
    f_c = 10.0
    quiet = dict(noise_mm=0.0, force_noise_kN=0.0, resolution_mm=0.0, force_resolution_kN=0.0)
    ideal = ServoController(Linear(k=100.0), ServoConfig(**quiet))
    slow = ServoController(Linear(k=100.0), ServoConfig(**quiet, force_bandwidth_hz=f_c))
    for ctl in (ideal, slow):
        ctl.d_spec = 1.0
        ctl.force = 100.0
        n = 20
        for _ in range(n):
            ctl._measure()
    t = 20 / slow.config.rate_hz
    assert ideal.measured_force == pytest.approx(100.0)
    assert slow.measured_force == pytest.approx(100.0 * (1 - math.exp(-2 * math.pi * f_c * t)), rel=1e-9)


# -- the cracking infill -----------------------------------------------------------------------
def test_infill_envelope_points():
    m = CrackingInfill()
    u_cr = 60.0 / 122.6
    assert m.initial_stiffness == 122.6
    assert m.backbone(u_cr) == pytest.approx(60.0)
    assert m.backbone(-2.5) == pytest.approx(-85.0)
    assert m.backbone(10.0) == pytest.approx(40.0)
    assert m.backbone(20.0) == pytest.approx(40.0)
    cracked = (m.backbone(2.0) - m.backbone(1.0)) / 1.0
    assert cracked == pytest.approx((85.0 - 60.0) / (2.5 - u_cr))
    assert make_specimen(specimen_spec(m)).backbone(2.0) == m.backbone(2.0)


def test_infill_is_stiff_until_it_cracks_and_degrades_with_cycles():
    m = CrackingInfill()
    assert m.force(0.3) == pytest.approx(122.6 * 0.3)
    F_first = m.force(2.0)
    m.force(1.8)  # unloading: back on a stiff branch
    assert (F_first - m.trial(1.8)) / 0.2 > 50.0
    for _ in range(4):
        m.force(-2.0)
        m.force(2.0)
    assert m.strength_factor < 1.0
    assert m.trial(2.0) < F_first - 1.0


def test_structure_II_infill_ships():
    s = get_structure("structure_II_infill")
    assert [e.K_EI for e in s.experimental] == [7.2, 122.6]


# -- thresholds --------------------------------------------------------------------------------
def test_thresholds_from_instruments():
    """K_f = c s_F / s_u, K_d = K_f / h (without noise s is resolution / sqrt(12): their ratio)."""
    rule = SwitchingRule.from_instruments([7.2, 122.6], 0.025, 0.01, margin=20.0, hysteresis=2.0)
    assert rule.upper.tolist() == pytest.approx([8.0, 8.0])
    assert rule.lower.tolist() == pytest.approx([4.0, 4.0])
    rule = SwitchingRule.from_instruments([2.6], 0.025, 0.01, margin=20.0, noise_mm=0.025 * 3 / 12**0.5)
    assert rule.upper[0] == pytest.approx(8.0 / 10**0.5)  # s_u grows by sqrt(1 + 9)
    with pytest.raises(ConfigError):
        SwitchingRule.from_instruments([2.6], 0.025, 0.01, hysteresis=1.0)


def test_hysteresis_prevents_chattering_on_a_constant_stiffness_branch():
    """A branch of constant stiffness between K_d and K_f read with noise: no mode change at all,
    whichever mode the element is in; one near K_f switches once and stays."""
    rule = SwitchingRule.from_instruments([122.6], 0.025, 0.01, margin=20.0, hysteresis=2.0)  # 8 and 4
    rng = np.random.default_rng(3)
    for start in (DC, FC):
        modes = [start]
        for k in 6.0 + rng.normal(0, 0.5, 500):
            modes = rule.next_modes(modes, np.array([k]), np.zeros(1))
            assert modes == [start]
    modes, changes = [DC], 0
    for k in 8.0 + rng.normal(0, 0.5, 500):  # straddles K_f, far above K_d
        new = rule.next_modes(modes, np.array([k]), np.zeros(1))
        changes += new != modes
        modes = new
    assert changes == 1 and modes == [FC]


# -- non-converged FC steps --------------------------------------------------------------------
class _SofteningSite:
    """One element: stiff (k1) up to u_c, then a much softer branch (k2 < k1 / 2, where the FC
    secant iteration oscillates); exact measurements."""

    def __init__(self, k1=100.0, u_c=0.5, k2=10.0):
        self.k1, self.u_c, self.k2 = k1, u_c, k2
        self.base = (np.zeros(1), np.zeros(1))
        self.last = self.base
        self.sent = []

    def R(self, u):
        return np.where(u < self.u_c, self.k1 * u, self.k1 * self.u_c + self.k2 * (u - self.u_c))

    def u_of(self, F):
        return np.where(F < self.k1 * self.u_c, F / self.k1, self.u_c + (F - self.k1 * self.u_c) / self.k2)

    def committed(self):
        return self.base

    def set_trial(self, commands, modes):
        self.sent.append((commands.copy(), list(modes)))
        u = self.u_of(commands) if modes[0] is FC else np.asarray(commands, dtype=float)
        R = self.R(u)
        du = u - self.base[0]
        k = np.where(du != 0, (R - self.base[1]) / np.where(du != 0, du, 1), np.nan)
        self.last = (u, R)
        self._daq = Daq(u=u, R=R, k=np.where(k > 0, k, np.nan), targets=commands, commands=commands, samples=None)

    def get_daq(self):
        return self._daq

    def commit(self):
        self.base = self.last


def _push(fallback_after):
    site = _SofteningSite()
    alg = ImplicitAlpha(np.eye(1) * 0.01, np.zeros((1, 1)), None, [0], [100.0], 0.01, 0.0, j_max=4,
                        tol_displacement=1e-6, tol_force=1e-6)
    alg.start(np.zeros(1), site)
    return site, alg, alg.step(np.array([400.0]), site, [FC], None, fallback_after)


def test_non_converged_fc_goes_on_in_dc_and_is_reported():
    """A load that takes the element past its stiff branch: the FC secant iteration oscillates
    between the stiff and the soft secant (E&M 2007 eqs. 11-12) and does not converge; with fallback_after = 2 the element's last commands are displacements and the report says so."""
    u_eq = (400.0 - 50.0 + 10.0 * 0.5) / (400.0 + 10.0)  # K* u + R(u) = P, K* = M / (beta dt^2) = 400
    site_off, _, (_, off) = _push(None)
    assert not off.converged and not off.not_converging.any() and off.modes == [FC]
    site, alg, (state, on) = _push(2)
    assert on.not_converging.tolist() == [True] and on.fell_back.tolist() == [True] and on.modes == [DC]
    kinds = [m[0] for _, m in site.sent]
    assert kinds[:2] == [FC, FC] and all(k is DC for k in kinds[2:])
    # the step ends with the specimen near equilibrium (DC iterates there), not where FC oscillated
    assert abs(site.base[0][0] - u_eq) < 0.01
    assert abs(site_off.base[0][0] - u_eq) > 0.1


# -- bumpless switches -------------------------------------------------------------------------
@pytest.mark.parametrize("order", [(DC, FC), (FC, DC)])
def test_switch_does_not_jolt(order):
    """At a switch the command starts from the measurement; over the next 100 ms the measured
    force and displacement stay within a few noise standard deviations plus one resolution
    step of where they were (holding the new command)."""
    c = ServoConfig(resolution_mm=0.025, noise_mm=0.01, force_resolution_kN=0.01, force_noise_kN=0.01, seed=5)
    ctl = ServoController(CrackingInfill(), c)
    first, second = order
    ctl.set_mode(first)
    target = 0.3 if first is DC else 0.3 * 122.6
    ctl.set_command(target)
    ctl.advance(600)
    window = 100
    before_u = np.mean([(ctl.advance(1), ctl.measured_displacement)[1] for _ in range(window)])
    before_F = np.mean([(ctl.advance(1), ctl.measured_force)[1] for _ in range(window)])
    ctl.set_mode(second)
    assert ctl.command == (ctl.measured_force if second is FC else ctl.measured_displacement)
    samples = []
    for _ in range(int(0.1 * c.rate_hz)):
        ctl.advance(1)
        samples.append((ctl.measured_displacement, ctl.measured_force))
    u, F = np.array(samples).T
    # displacement: the transducer's noise and resolution; force: those times the stiffness
    # in DC (the rod loop dithers within its resolution), the load cell's own in FC
    du = 4 * c.noise_mm + 2 * c.resolution_mm
    dF = 122.6 * du if second is DC else 122.6 * du + 4 * c.force_noise_kN
    assert np.max(np.abs(u - before_u)) <= du
    assert np.max(np.abs(F - before_F)) <= dF


# -- no switch to FC at a reversal ---------------------------------------------------------------
class _LinearSite:
    """One linear element, exact; the secant is reported as ``k_seen`` (what the rule reads)."""

    def __init__(self, k=100.0):
        self.k, self.k_seen = k, k
        self.base = self.last = (np.zeros(1), np.zeros(1))

    def committed(self):
        return self.base

    def set_modes(self, modes):
        return []

    def set_trial(self, commands, modes):
        u = commands / self.k if modes[0] is FC else np.asarray(commands, dtype=float)
        self.last = (u, self.k * u)
        self._daq = Daq(u=u, R=self.k * u, k=np.array([self.k_seen]), targets=commands, commands=commands,
                        samples=None)

    def get_daq(self):
        return self._daq

    def commit(self):
        self.base = self.last


def _free_vibration(guard, stiff_from=None, steps=40):
    from hsio.integrators import ImplicitMethod

    site = _LinearSite()
    rule = SwitchingRule(np.array([150.0]), np.array([50.0]))
    m = ImplicitMethod(np.eye(1) * 0.01, np.zeros((1, 1)), None, [0], [100.0], 0.005, 0.0, "mixed", rule,
                       no_fc_at_reversal=guard)
    m.start(np.zeros(1), site, None)
    us, modes = [], []
    for i in range(1, steps):
        if stiff_from is not None and i >= stiff_from:
            site.k_seen = 200.0  # the element now reads stiffer than K_f
        out = m.step(np.array([30.0]), site, None, step=i)  # a step load: oscillation about 0.3 mm
        us.append(out.u[0])
        modes.append(m.modes[0])
    return np.array(us), modes, m


@pytest.mark.parametrize("guard", [False, True])
def test_no_switch_to_fc_at_a_reversal(guard):
    """The secant read rises above K_f exactly at the step where the motion reverses: without the
    guard the element switches there; with it the switch waits one step and is counted."""
    us, _, _ = _free_vibration(False)
    du = np.diff(np.concatenate([[0.0], us]))
    r = int(np.flatnonzero(du[1:] * du[:-1] < 0)[0]) + 2  # the step (1-based) whose increment reverses
    _, modes, m = _free_vibration(guard, stiff_from=r)
    if guard:
        assert modes[r - 1] is DC and modes[r] is FC and m.deferred_at_reversal == 1
    else:
        assert modes[r - 1] is FC and m.deferred_at_reversal == 0


# -- DC with a refused secant estimate ---------------------------------------------------------
class _RefusingSite(_SofteningSite):
    """The softening element read by an estimator that refuses every secant (increments below its
    min_increment): the DAQ gives the measured pair but k = nan."""

    def set_trial(self, commands, modes):
        super().set_trial(commands, modes)
        self._daq = Daq(u=self._daq.u, R=self._daq.R, k=np.full(1, np.nan), targets=commands, commands=commands,
                        samples=None)


@pytest.mark.parametrize("anchor", [True, False])
def test_dc_force_comes_from_the_measurement_when_the_secant_is_refused(anchor):
    """Past the stiff branch with the initial secant kept (every estimate refused): anchored at
    the measurement, the accepted force is the specimen's force at the accepted displacement; the
    line through the base extrapolates the stiff branch and overestimates it several times."""
    site = _RefusingSite()
    alg = ImplicitAlpha(np.eye(1) * 0.01, np.zeros((1, 1)), None, [0], [100.0], 0.01, 0.0, j_max=4,
                        tol_displacement=1e-9, tol_force=1e-6, anchor_dc=anchor)
    alg.start(np.zeros(1), site)
    state, report = alg.step(np.array([400.0]), site, [DC])
    u = report.u_solution[0]
    assert u > 0.5  # past the stiff branch
    true_R = float(site.R(np.array([u]))[0])
    if anchor:
        assert report.R_solution[0] == pytest.approx(true_R, rel=0.02)
        assert state.u[0] * 400.0 + true_R == pytest.approx(400.0, rel=0.02)  # eq. (7) with the specimen's force
    else:
        assert report.R_solution[0] > 1.5 * true_R


# -- the secant at a reversal --------------------------------------------------------------------
class _StiffSiteNoEstimate(_LinearSite):
    """A linear element of stiffness K^EI whose increments are all below the estimator's
    min_increment: eq. (11) never gives a secant (as on the stiff unloading branch of the cracked
    infill with a 0.025 mm transducer)."""

    def set_trial(self, commands, modes):
        super().set_trial(commands, modes)
        self._daq = Daq(u=self._daq.u, R=self._daq.R, k=np.array([np.nan]), targets=commands, commands=commands,
                        samples=None)


def _oscillate_fc(reset, stale_after=None, steps=40):
    site = _StiffSiteNoEstimate(k=100.0)
    alg = ImplicitAlpha(np.eye(1) * 0.01, np.zeros((1, 1)), None, [0], [100.0], 0.005, 0.0, j_max=3,
                        tol_displacement=1e-6, tol_force=1e-3, fc_blend=0.01, reset_at_reversal=reset)
    alg.start(np.zeros(1), site)
    us, errors = [], []
    for i in range(1, steps):
        alg.step(np.array([30.0]), site, [FC])  # a step load: free oscillation about 0.3 mm
        if i == stale_after:
            alg.k = np.array([10.0])  # stale: as if the last estimate came from a soft branch
        us.append(site.base[0][0])
        errors.append(abs(alg._u_fc[0] - site.base[0][0]))
    return np.array(us), np.array(errors), alg


@pytest.mark.parametrize("reset", [False, True])
def test_stale_soft_secant_is_reset_to_k_ei_at_a_reversal(reset):
    """FC with the complementary base (fc_blend 0.01) on a stiff element whose increments are
    too small for eq. (11) (as on the unloading branch of the cracked infill): with the secant left
    at a soft value (10 against 100 kN/mm) at a peak, every change of force moves the base ten times
    too far. With ``reset_at_reversal`` the reversal of the measured force sets it back to K^EI
    and the base stays on the specimen."""
    us, _, _ = _oscillate_fc(False)
    peak = int(np.argmax(us)) + 1  # the step at the first peak (the force still rising)
    _, errors, alg = _oscillate_fc(reset, stale_after=peak)
    after = errors[peak:]
    if reset:
        assert alg.k[0] == 100.0 and alg.reversal_resets == 1
        assert np.max(after) < 0.01
    else:
        assert alg.k[0] == 10.0 and alg.reversal_resets == 0
        assert np.max(after) > 1.0
