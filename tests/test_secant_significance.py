"""FC's secant beyond the instruments' noise (docs/method.md eq. 11a): an estimate of eq. (11) within
z sigma_k of the secant in use is turned away for an element in FC, the estimates turned away are
pooled until the secant is next set; a softening over a large increment is taken at once."""

from types import SimpleNamespace

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.integrators import ImplicitAlpha, SwitchingRule
from hsio.integrators.implicit import SECANT_Z as Z, samples_averaged
from hsio.integrators.mixed import instrument_uncertainty
from hsio.interfaces import ControlMode
from hsio.secant import SecantEstimator, secant_stiffness
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
    assert rule.uncertainty == ((0.01, 0.001), (0.001, 0.001))  # (noise, resolution) of each
    assert rule.never_fc([True]).uncertainty == rule.uncertainty
    assert SwitchingRule.from_initial_stiffness([K0]).uncertainty is None


@pytest.mark.parametrize("bad", [(0.0, 0.0), (-0.01, 0.001), (float("nan"), 0.001), "x", (0.01,),
                                 ((0.01, -0.001), 0.001), ((0.0, 0.0), (0.0, 0.0)), ((0.01, 0.001, 0.1), 0.001)])
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
    assert made["force_control"] == made["mixed"] == ((0.01, 0.001), (0.001, 0.001))


# Instruments with noise only: sigma_k of eq. (11a) in closed form, sigma^2 (1/n_end + 1/n_base) per channel.
NOISE_U, NOISE_F = 0.01, 0.001


class _Site:
    """A one-DOF specimen read noise-free, its secant from the committed point (eq. 11): a subclass
    gives ``read(commands)``, the (displacement, force, command) it shows for a force command."""

    def __init__(self, k, estimator=None, base=(0.0, 0.0)):
        self.k = k
        self.estimator = estimator if estimator is not None else SecantEstimator("average", 16)
        self._base = (np.array([base[0]]), np.array([base[1]]))

    def committed(self):
        return self._base

    def set_trial(self, commands, modes):
        u, R, shown = self.read(np.array(commands, dtype=float))
        self._last = (u, R)
        self._daq = Daq(u, R, secant_stiffness(u, R, *self._base), shown, shown)

    def get_daq(self):
        return self._daq

    def commit(self):
        self._base = self._last


class _FromBase(_Site):
    """A linear specimen of stiffness ``k`` standing at a nonzero base (1 mm, 3 kN), its readings
    noise-free; the estimator ``estimator`` (16-sample averages unless given)."""

    U0, R0 = 1.0, 3.0

    def __init__(self, k, estimator=None):
        super().__init__(k, estimator, (self.U0, self.R0))

    def read(self, R):
        return self._base[0] + (R - self._base[1]) / self.k, R, R


def _quasi_static(uncertainty, **kw):
    """A single DOF whose inertia is negligible: the FC command of a step is the load P."""
    return ImplicitAlpha([[1e-12]], [[0.0]], None, [0], [K0], 0.005, 0.0, j_max=3, tol_displacement=1e-12,
                         tol_force=1e-12, secant_uncertainty=uncertainty, **kw)


def _k_at(z, dR, n_end, n_base):
    """The specimen's stiffness whose estimate from an increment dR lies z sigma_k below K0, the
    secant in use at which sigma_k is evaluated (eq. 11a); du = dR / k."""
    var_u, var_F = NOISE_U**2 * (1 / n_end + 1 / n_base), NOISE_F**2 * (1 / n_end + 1 / n_base)
    k = K0
    for _ in range(200):  # fixed point of k = K0 - z K0 sqrt(var_u k^2 / dR^2 + var_F / dR^2)
        k = K0 * (1 - z * np.sqrt(var_u * k**2 + var_F) / dR)
    return k


@pytest.mark.parametrize("z, taken", [(Z - 0.1, False), (Z + 0.1, True)])
def test_the_first_step_from_a_nonzero_base_just_within_and_just_beyond_z_sigma(z, taken):
    # the first step's base is one feedback sample: sigma^2 (1/16 + 1) per channel, increments from the base
    dR = 0.3
    site = _FromBase(_k_at(z, dR, 16, 1))
    integ = _quasi_static((NOISE_U, NOISE_F))
    integ.start(np.array([site.R0]), site)
    integ.step(np.array([site.R0 + dR]), site, [FC])
    assert bool(integ.k[0] == pytest.approx(site.k)) is taken and bool(integ.k[0] == K0) is not taken
    assert taken or integ.secant_refused[0] >= 1  # the estimate turned away, counted


@pytest.mark.parametrize("z, taken", [(Z - 0.1, False), (Z + 0.1, True)])
@pytest.mark.parametrize("estimator, n", [(SecantEstimator("average", 16), 16), (SecantEstimator("raw"), 1)])
def test_a_later_step_just_within_and_just_beyond_z_sigma_for_n_16_and_n_1(z, taken, estimator, n):
    dR = 0.3
    site = _FromBase(_k_at(z, dR, n, n), estimator)
    integ = _quasi_static((NOISE_U, NOISE_F))
    integ.start(np.array([site.R0]), site)
    integ.state.i = 1  # a later step: both ends averaged alike
    integ.step(np.array([site.R0 + dR]), site, [FC])
    assert bool(integ.k[0] == pytest.approx(site.k)) is taken and bool(integ.k[0] == K0) is not taken
    if n == 16 and taken:  # the same estimate read from single samples lies within Z sigma_k
        raw = _FromBase(site.k, SecantEstimator("raw"))
        integ = _quasi_static((NOISE_U, NOISE_F))
        integ.start(np.array([raw.R0]), raw)
        integ.state.i = 1
        integ.step(np.array([raw.R0 + dR]), raw, [FC])
        assert integ.k[0] == K0


def test_samples_averaged_by_each_estimator():
    assert samples_averaged(SimpleNamespace(estimator=SecantEstimator("average", 16))) == 16
    assert samples_averaged(SimpleNamespace(estimator=SecantEstimator("raw", 16))) == 1
    assert samples_averaged(SimpleNamespace(estimator=SecantEstimator("least_squares", 16))) == 1
    assert samples_averaged(SimpleNamespace()) == 1


def test_quantisation_is_not_averaged_down():
    integ = ImplicitAlpha([[1.0]], [[0.0]], None, [0], [K0], 0.01, secant_uncertainty=((0.0, 0.01), (0.0, 0.001)))
    one, sixteen = (integ.sigma_k([K0], [0.1], [0.3], n)[0] for n in (1, 16))
    assert sixteen == pytest.approx(one)
    assert one == pytest.approx(K0 * np.hypot(0.01 / 0.1, 0.001 / 0.3) * np.sqrt(2 / 12))
    noisy = ImplicitAlpha([[1.0]], [[0.0]], None, [0], [K0], 0.01, secant_uncertainty=((0.01, 0.01), (0.0, 0.0)))
    # per end sigma^2 / n + delta^2 / 12
    assert noisy.sigma_k([K0], [0.1], [0.3], 16)[0] == pytest.approx(K0 * np.sqrt(2 * (1e-4 / 16 + 1e-4 / 12)) / 0.1)


class _Quantised(_Site):
    """A linear specimen of stiffness ``k`` read noise-free by a transducer of resolution 0.001 mm
    and a load cell of 0.001 kN, 16 samples averaged."""

    def read(self, c):
        return np.round(c / self.k / 0.001) * 0.001, np.round(c / 0.001) * 0.001, c


def test_a_softening_over_small_increments_is_taken_from_the_estimates_pooled():
    # 0.01 mm on K0 per step: each estimate of a 30 % softer specimen lies within Z sigma_k of K0
    site = _Quantised(0.7 * K0)
    integ = _quasi_static(((0.01, 0.001), (0.001, 0.001)))
    integ.start(np.zeros(1), site)
    sigma = integ.sigma_k([0.7 * K0], [0.03 / (0.7 * K0)], [0.03], 16)[0]
    assert 0.3 * K0 < Z * sigma  # alone, no estimate would be taken
    for i in range(30):
        integ.step(np.array([0.03 * (i + 1)]), site, [FC])
    assert integ.k[0] == pytest.approx(0.7 * K0, rel=0.03)
    assert integ.secant_refused[0] > 0


@pytest.mark.parametrize("z, step", [(3.0, 7), (Z, 12)])
def test_a_softening_over_small_increments_is_taken_in_the_step_the_docs_give(z, step):
    """docs/method.md and docs/force_control.md: a 30 % softening read in 0.014 mm increments
    (sigma_k / k about 25 % each) is taken from the pool in the twelfth step at z = 4, the seventh
    at z = 3."""
    site = _Quantised(0.7 * K0)
    integ = _quasi_static(((0.01, 0.001), (0.001, 0.001)), secant_z=z)
    integ.start(np.zeros(1), site)
    sigma = integ.sigma_k([0.7 * K0], [0.03 / (0.7 * K0)], [0.03], 16)[0]
    assert sigma / (0.7 * K0) == pytest.approx(0.25, abs=0.005)
    taken = None
    for i in range(30):
        integ.step(np.array([0.03 * (i + 1)]), site, [FC])
        if taken is None and integ.k[0] != K0:
            taken = i + 1
    assert taken == step


class _Bilinear(_Site):
    """Loads at ``k`` and unloads at K0 from the last committed point, noise-free, 16 samples averaged."""

    def read(self, R):
        u0, R0 = self._base
        dR = R - R0
        return u0 + dR / np.where(dR * np.sign(R0 if R0[0] else 1.0) >= 0, self.k, K0), R, R


def test_an_uninformative_estimate_at_a_reversal_does_not_block_the_reset():
    # loads at 0.5 K0 (taken: a large increment), then reverses by 0.3 N: sigma_k far above |k|
    site = _Bilinear(0.5 * K0)
    integ = _quasi_static(((0.01, 0.001), (0.001, 0.001)), reset_at_reversal=True)
    integ.start(np.zeros(1), site)
    for P in (0.3, 0.6):
        integ.step(np.array([P]), site, [FC])
    assert integ.k[0] == pytest.approx(0.5 * K0)
    integ.step(np.array([0.5997]), site, [FC])
    assert integ.secant_refused[0] > 0  # the unloading estimate is turned away ...
    assert integ.k[0] == K0 and integ.reversal_resets == 1  # ... and the unloading branch starts at K^EI


def test_each_step_reports_the_estimates_turned_away():
    site = _Specimen(K0, gain=1.05)
    integ = ImplicitAlpha([[0.01]], [[0.0]], None, [0], [K0], 0.005, 0.0, j_max=3, tol_displacement=1e-12,
                          tol_force=1e-12, secant_uncertainty=(S_U, S_F))
    integ.start(np.zeros(1), site)
    _, report = integ.step(np.array([0.3 * (integ.K_star[0, 0] / K0 + 1.0)]), site, [FC])
    assert report.secant_refused.tolist() == integ.secant_refused.tolist() and report.secant_refused[0] > 0


def test_the_method_carries_the_count_and_force_control_its_instruments():
    from hsio.api import make_integrator
    from hsio.runner import secant_instruments

    from hsio.study_mixed import infill_sdof

    s = infill_sdof(3.0)
    assert make_integrator(s, "force_control").secant_refused is None  # the rule off: nothing to count
    assert make_integrator(s, "force_control", secant_uncertainty=(S_U, S_F)).secant_refused == [0]
    known = {"switch_resolution_mm": 0.001, "switch_force_resolution_kN": 0.002, "switch_noise_mm": 0.01,
             "switch_force_noise_kN": 0.0}
    assert secant_instruments(known, None) == ((0.01, 0.001), (0.0, 0.002))
    assert secant_instruments(dict.fromkeys(known, 0.0), None) is None  # not known: every estimate taken
    emulated = secant_instruments(dict.fromkeys(known, 0.0), {"noise_mm": 0.02})
    assert emulated[0][0] == 0.02


def test_a_displacement_read_by_an_external_instrument_counts_one_reading_of_it():
    integ = _quasi_static((NOISE_U, NOISE_F))
    averaged = integ.sigma_k([K0], [0.1], [0.3], 16)[0]
    lvdt = integ.sigma_k([K0], [0.1], [0.3], 16, external=[(0.02, 0.01)])[0]
    # one reading at each end: 2 (sigma^2 + delta^2 / 12), whatever the estimator averages; its
    # force one sample of the load cell at each end, the last period's (the one the reading pairs with)
    assert lvdt == pytest.approx(K0 * np.sqrt(2 * (0.02**2 + 0.01**2 / 12) / 0.1**2 + 2 * NOISE_F**2 / 0.3**2))
    assert lvdt > 5 * averaged
    # a step: Z + 0.1 sigma_k of the averaged transducer is taken with it, turned away on the instrument's reading
    dR = 0.3
    for instruments, taken in (([None], True), ([(0.02, 0.01)], False)):
        site = _FromBase(_k_at(Z + 0.1, dR, 16, 16))
        site.displacement_instruments = instruments
        integ = _quasi_static((NOISE_U, NOISE_F))
        integ.start(np.array([site.R0]), site)
        integ.state.i = 1
        integ.step(np.array([site.R0 + dR]), site, [FC])
        assert bool(integ.k[0] == K0) is not taken


def test_the_site_knows_which_instrument_reads_each_displacement():
    from test_instruments_external import WALL
    from hsio.structure_file import parse_structure

    text = WALL.format(source='displacement_from = "lvdt"').replace('element = "wall"',
                                                                      'element = "wall"\nnoise = 0.02\nresolution = 0.01')
    structure = parse_structure(text, "wall.toml")
    with hsio_open_site(structure) as site:
        assert site.displacement_instruments == [(0.02, 0.01)]
    with hsio_open_site(parse_structure(WALL.format(source=""), "wall.toml")) as site:
        assert site.displacement_instruments == [None]


def hsio_open_site(structure):
    import hsio

    return hsio.open_site(structure, "emulator://", test_rate=20, estimator=SecantEstimator("average", 16, 0.1))


def test_an_estimate_pulled_low_and_one_pulled_high_are_judged_alike():
    """sigma_k is the secant in use's, not the estimate's: with the load cell's noise alone, an
    estimate just within Z s below K0 and one as far above are both turned away (judged at the
    estimate, the low one would carry a smaller sigma and be taken, the high one not: a secant
    drifting soft)."""
    dR = 0.01
    s = np.sqrt(2 * NOISE_F**2 / 16) / dR  # sigma_k / K0 from the load cell alone: 3.5 %
    eps = 0.97 * Z * s  # past Z s / (1 + Z s) (taken if judged at the low estimate), within Z s
    assert Z * s / (1 + Z * s) < eps < Z * s
    for k in (K0 * (1 - eps), K0 * (1 + eps)):
        site = _FromBase(k)
        integ = _quasi_static((0.0, NOISE_F))
        integ.start(np.array([site.R0]), site)
        integ.state.i = 1
        integ.step(np.array([site.R0 + dR]), site, [FC])
        assert integ.k[0] == K0 and integ.secant_refused[0] >= 1, k


def test_an_external_instrument_stating_no_noise_counts_as_the_transducer():
    """An [[instrument]] without noise or resolution (on hardware they are not emulation settings
    that were given): its readings are not taken as exact, the transducer's uncertainty stands."""
    integ = _quasi_static((NOISE_U, NOISE_F))
    stated = integ.sigma_k([K0], [0.1], [0.3], 16, external=[(0.0, 0.0)])[0]
    # the transducer's averaged uncertainty; the force one sample at each end, as with any instrument
    assert stated == pytest.approx(K0 * np.sqrt(2 * NOISE_U**2 / 16 / 0.1**2 + 2 * NOISE_F**2 / 0.3**2))


def test_the_force_paired_with_an_external_reading_counts_one_sample_at_each_end():
    """The load cell's noise alone: an element read by an external instrument takes the last
    period's force at each end, not an average of 16, so its sigma_k is sqrt(16) times as large;
    the element beside it, on its own transducer, keeps the averaged one."""
    integ = _quasi_static((0.0, NOISE_F))
    sigma = integ.sigma_k([K0, K0], [0.1, 0.1], [0.3, 0.3], 16, external=[(0.0, 0.0), None])
    averaged = K0 * np.sqrt(2 * NOISE_F**2 / 16) / 0.3
    assert sigma[1] == pytest.approx(averaged)
    assert sigma[0] == pytest.approx(4 * averaged)


def test_fc_on_a_record_with_one_estimate_3_3_sigma_off_keeps_its_secant():
    """The study's specimen at 7.2 kN/mm on the 2 s record of seed 11 (0.0025 mm transducer, 0.002
    kN load cell; linear all through: NS peaks at 0.999 of the cracking force): at step 137 one
    estimate reads 6.386 kN/mm, 3.3 sigma_k below the secant. Taken, FC follows it and ends 36 %
    off NS; at Z = 4 it is turned away and FC is within about 1 %."""
    from hsio import study_mixed

    (row,) = study_mixed.grid(stiffnesses=(7.2,), resolutions=(0.0025,), force_resolutions=(0.002,), seed=11,
                              methods=("force_control",))
    assert row.error_pct < 3.0 and row.secant_refused >= 1


def test_the_run_summary_names_the_z_the_secant_rule_uses(tmp_path, capsys):
    """`hsio run` prints the estimates turned away with the z they were judged at (SECANT_Z)."""
    from hsio import config, runner
    from hsio.cli import _print_summary

    cfg = config.from_dict({"structure": {"name": "validation"}, "record": {"synthetic_duration_s": 0.2},
                            "integrator": {"method": "force_control"}, "output": {"plots": False},
                            "safety": {"keys": False}})
    summary = runner.run(cfg, tmp_path / "run")
    assert summary["secant_refused"] is not None
    _print_summary(summary)
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("FC secant"))
    assert f"within {Z:g} sigma_k of the secant in use" in line, line
