"""FC's secant beyond the instruments' noise (docs/method.md eq. 11a): an estimate of eq. (11) within
z sigma_k of the secant in use is refused for an element in FC; a softening is taken at once."""

from types import SimpleNamespace

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.integrators import ImplicitAlpha, SwitchingRule
from hsio.integrators.mixed import instrument_uncertainty
from hsio.interfaces import ControlMode
from hsio.secant import secant_stiffness
from hsio.sites import Daq

FC, DC = ControlMode.FORCE, ControlMode.DISPLACEMENT
K0 = 3.0
S_U, S_F = instrument_uncertainty(0.001, 0.01), instrument_uncertainty(0.001, 0.001)  # the emulator's 0.01 mm noise


class _Specimen:
    """A linear specimen whose transducer reads ``gain`` times the displacement (a noise-sized
    error at the study's 0.1 mm increments); 16 samples averaged at each end, as the study's estimator."""

    def __init__(self, k, gain=1.0):
        self.k, self.gain = k, gain
        self.estimator = SimpleNamespace(method="average", n_avg=16)
        self._base = (np.zeros(1), np.zeros(1))
        self._last = self._base

    def committed(self):
        return self._base

    def set_trial(self, commands, modes):
        c = np.array(commands, dtype=float)
        u, R = (c / self.k, c) if modes[0] is FC else (c, self.k * c)
        u = self.gain * u
        self._last = (u, R)
        self._daq = Daq(u, R, secant_stiffness(u, R, *self._base), c, c)

    def get_daq(self):
        return self._daq

    def commit(self):
        self._base = self._last


def _one_step(site, mode, uncertainty):
    """One step of a single DOF from rest whose FC command is about 0.3 kN (0.1 mm on K0)."""
    integ = ImplicitAlpha([[0.01]], [[0.0]], None, [0], [K0], 0.005, 0.0, j_max=3, tol_displacement=1e-12,
                          tol_force=1e-12, secant_uncertainty=uncertainty)
    integ.start(np.zeros(1), site)
    P = 0.3 * (integ.K_star[0, 0] / K0 + 1.0)  # eq. (12) from rest: R^1 = 0.3 kN
    integ.step(np.array([P]), site, [mode])
    return integ


def test_sigma_k_of_eq_11a():
    integ = ImplicitAlpha([[1.0]], [[0.0]], None, [0], [K0], 0.01, secant_uncertainty=(S_U, S_F))
    # 16-sample averages at both ends, du = 0.1 mm, dR = 0.2854 kN: sigma_k / k = sqrt(2/16) hypot(s_u/du, s_F/dR)
    rel = np.sqrt(2 / 16) * np.hypot(S_U / 0.1, S_F / 0.2854)
    assert rel == pytest.approx(0.0354, abs=5e-4)  # the 3.5 % scatter at 0.1 mm
    assert not integ.significant([2.854], [K0], [0.1], [0.2854], 16)[0]  # -4.9 %: within 3 sigma
    assert integ.significant([2.854], [K0], [1.0], [2.854], 16)[0]  # the same change from a 1 mm increment
    assert integ.significant([0.7 * K0], [K0], [0.1], [0.21], 16)[0]  # a 30 % softening
    assert not integ.significant([0.7 * K0], [K0], [0.0], [0.0], 16)[0]  # no increment: nothing known


def test_fc_secant_ignores_a_noise_sized_error():
    site = _Specimen(K0, gain=1.05)  # the estimate reads 2.857 kN/mm: -4.8 %, as the noise gives at 0.1 mm
    assert _one_step(site, FC, (S_U, S_F)).k[0] == K0
    assert _one_step(_Specimen(K0, gain=1.05), FC, None).k[0] == pytest.approx(K0 / 1.05)  # unknown: as before


def test_fc_secant_takes_a_softening_at_once():
    integ = _one_step(_Specimen(0.7 * K0), FC, (S_U, S_F))
    assert integ.k[0] == pytest.approx(0.7 * K0)


def test_dc_takes_every_estimate():
    integ = _one_step(_Specimen(K0, gain=1.05), DC, (S_U, S_F))
    assert integ.k[0] == pytest.approx(K0 / 1.05)
    assert integ.secant_refused == 0


def test_the_rule_built_from_instruments_carries_their_uncertainty():
    rule = SwitchingRule.from_instruments([K0], 0.001, 0.001, noise_mm=0.01, force_noise_kN=0.001)
    assert rule.uncertainty == pytest.approx((S_U, S_F))
    assert rule.never_fc([True]).uncertainty == rule.uncertainty
    assert SwitchingRule.from_initial_stiffness([K0]).uncertainty is None


@pytest.mark.parametrize("bad", [(0.0, 0.0), (-0.01, 0.001), (float("nan"), 0.001), "x", (0.01,)])
def test_secant_uncertainty_is_checked(bad):
    with pytest.raises(ConfigError, match="secant_uncertainty"):
        ImplicitAlpha([[1.0]], [[0.0]], None, [0], [K0], 0.01, secant_uncertainty=bad)


def test_the_study_gives_fc_its_instruments_and_leaves_dc_alone():
    from hsio import study_mixed

    s = study_mixed.infill_sdof(3.0)
    recipe = study_mixed.Recipe(max_hysteretic_ratio=0.0)
    made = {m: study_mixed.make_method(s, m, 0.001, 0.001, recipe, 0.01, 0.001).core.secant_uncertainty
            for m in study_mixed.METHODS}
    assert made["implicit_dc"] is None
    assert made["force_control"] == pytest.approx((S_U, S_F)) and made["mixed"] == pytest.approx((S_U, S_F))
