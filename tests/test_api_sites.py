"""The Python API keeps a site to the test it was opened for (docs/api.md): simulate refuses a
structure the site was not opened for and a second record started from rest on a site whose
actuators stand where the first left them; open_site refuses a compensation stage built for
another step duration; a ready integrator is not silently given options it would not read; the
integrator's settings are refused outside a run configuration's bounds."""

from __future__ import annotations

import numpy as np
import pytest

import hsio
from hsio.compensation.stage import CompensationSettings, CompensationStage
from hsio.errors import ConfigError
from hsio.sites import NumericalSite


def test_simulate_refuses_a_structure_the_site_was_not_opened_for():
    validation = hsio.load_structure("validation")
    ground = hsio.synthetic_record(duration_s=0.3, dt=validation.dt, seed=7)
    with hsio.open_site(hsio.load_structure("structure_II"), "emulator://", test_rate=5) as site:
        start = [a.controller.d_rod for a in site.loop.actuators]
        with pytest.raises(ConfigError, match=r"the site was opened for structure 'structure_II' \(actuators BF, IF, "
                                              r"dt 0.005 s\), not for 'validation'.*nothing moved"):
            hsio.simulate(validation, ground, site)
        assert [a.controller.d_rod for a in site.loop.actuators] == start


def test_a_second_record_on_a_site_that_has_run_starts_from_where_it_stands():
    s = hsio.load_structure("structure_I")
    quake = hsio.synthetic_record(duration_s=0.5, dt=s.dt, pga_g=1.5, seed=3)
    still = hsio.GroundMotion("still", s.dt, [0.0] * 21)
    with hsio.open_site(s, "emulator://", test_rate=200) as site:
        first = hsio.simulate(s, quake, site)
        where = float(first.measured_displacement[-1, 0])
        assert abs(where) > 1.0  # the first record left the specimen away from rest
        with pytest.raises(ConfigError, match=r'start="present" goes on from there.*nothing moved'):
            hsio.simulate(s, still, site)
        assert site.loop.actuators[0].controller.d_rod == pytest.approx(where, abs=0.05)
        second = hsio.simulate(s, still, site, start="present")
        assert float(second.measured_displacement[0, 0]) == pytest.approx(where, abs=0.05)


def test_a_compensation_stage_for_another_step_duration_is_refused():
    s = hsio.load_structure("structure_I")
    settings = CompensationSettings(mode="offline", a_mm_s=0.0, b_s_mm=0.02 / 254.0)
    wrong = CompensationStage(["wall"], 10 * 6.25 * s.dt, settings)
    with pytest.raises(ConfigError, match=r"built for t_d = 0.3125 s.*6.25 x 0.005 s = 0.03125 s"):
        hsio.open_site(s, "emulator://", test_rate=6.25, hold_fraction=0.0, compensation=wrong)
    right = CompensationStage(["wall"], 6.25 * s.dt, settings)
    with hsio.open_site(s, "emulator://", test_rate=6.25, hold_fraction=0.0, compensation=right):
        pass


def test_a_compensation_stage_naming_other_actuators_is_refused():
    """The stage's names say which actuator each column compensates: names in another order (or
    of another structure) would compensate the wrong actuator, so they are refused."""
    s = hsio.load_structure("structure_II")
    settings = CompensationSettings(mode="offline", a_mm_s=0.0, b_s_mm=0.02 / 254.0, actuators=["BF"])
    swapped = CompensationStage(["IF", "BF"], 6.25 * s.dt, settings)
    with pytest.raises(ConfigError, match=r"stage names the actuators IF, BF; the loop drives BF, IF"):
        hsio.open_site(s, "emulator://", test_rate=6.25, hold_fraction=0.0, compensation=swapped)
    with hsio.open_site(s, "emulator://", test_rate=6.25, hold_fraction=0.0,
                        compensation=CompensationStage(["BF", "IF"], 6.25 * s.dt, settings)):
        pass


def test_options_beside_a_ready_integrator_are_refused():
    s = hsio.load_structure("validation")
    ground = hsio.synthetic_record(duration_s=0.2, dt=s.dt)
    ready = hsio.make_integrator(s, "alpha_os")

    with pytest.raises(ConfigError, match="j_max given beside a ready integrator"):
        hsio.simulate(s, ground, NumericalSite.of(s), integrator=ready, j_max=99)
    with pytest.raises(ConfigError, match="alpha given beside a ready integrator"):
        hsio.simulate(s, ground, NumericalSite.of(s), alpha=-0.1, integrator=ready)
    with pytest.raises(ConfigError, match="method given beside a ready integrator"):
        hsio.simulate(s, ground, NumericalSite.of(s), method="implicit_dc", integrator=ready)
    assert np.all(np.isfinite(hsio.simulate(s, ground, NumericalSite.of(s), integrator=ready).u))


@pytest.mark.parametrize("options, says", [
    ({"j_max": 2.5}, "j_max (commands per step) must be a whole number in 1..100, got 2.5"),
    ({"j_max": 10**6}, "must be a whole number in 1..100"),
    ({"tol_force": "0.05"}, "tol_force must be a number, zero or positive"),
    ({"refractory_steps": -1}, "refractory_steps must be a whole number of steps"),
    ({"explored_fraction": 5.0}, "explored_fraction must be None (off) or a number in (0, 1]"),
    ({"fallback_after": 50}, "fallback_after must be None or 0 (off), or a whole number of FC commands below j_max (3)"),
    ({"fallback_after": 3}, "fallback_after must be None or 0 (off), or a whole number of FC commands below j_max (3)"),
])
def test_integrator_settings_outside_the_run_bounds_are_refused(options, says):
    with pytest.raises(ConfigError) as refused:
        hsio.make_integrator(hsio.load_structure("structure_I"), "mixed", **options)
    assert says in str(refused.value)


@pytest.mark.parametrize("call, says", [
    (lambda V, G: hsio.open_site(V, None), "open_site: hardware must be a URL string"),
    (lambda V, G: hsio.open_site(V, options=[1]), "open_site: options must be a dict"),
    (lambda V, G: hsio.open_site(V, estimator="average"), "open_site: estimator must be a hsio.secant.SecantEstimator"),
    (lambda V, G: hsio.open_site(V, compensation="offline"), "open_site: compensation must be a"),
    (lambda V, G: hsio.open_site(V, safety="off"), "open_site: safety must be a"),
    (lambda V, G: hsio.open_site("validation"), "open_site: structure must be a hsio.Structure (hsio.load_structure("),
    (lambda V, G: hsio.make_integrator("validation"), "make_integrator: structure must be a hsio.Structure"),
    (lambda V, G: hsio.run_numerical("validation", G), "run_numerical: structure must be a hsio.Structure"),
    (lambda V, G: hsio.simulate(V, G, None), "simulate: site must be a site from hsio.open_site"),
    (lambda V, G: hsio.simulate(V, G, NumericalSite.of(V), integrator="alpha_os"), "integrator must be an integrator from make_integrator"),
    (lambda V, G: hsio.make_integrator(V, "mixed", rule={"K_f": 1.0}), "rule must be a hsio.integrators.SwitchingRule"),
])
def test_arguments_of_the_wrong_kind_are_named(call, says):
    V = hsio.load_structure("validation")
    G = hsio.synthetic_record(duration_s=0.2, dt=V.dt)
    with pytest.raises(ConfigError) as refused:
        call(V, G)
    assert says in str(refused.value)


def test_max_error_pct_takes_results_and_refuses_histories_that_are_not_finite():
    V = hsio.load_structure("validation")
    G = hsio.synthetic_record(duration_s=0.2, dt=V.dt)
    ns = hsio.run_numerical(V, G)
    assert hsio.max_error_pct(ns, ns) == (0.0, [0.0, 0.0])
    bad = ns.u.copy()
    bad[3, 0] = np.nan
    with pytest.raises(hsio.HsioError, match="not finite"):
        hsio.max_error_pct(bad, ns.u)


@pytest.mark.parametrize("url", ["emulator://?stroke_mm=500&stroke_mm=20",
                                 "modbus+tcp://127.0.0.1:1?timeout_s=1&timeout_s=2"])
def test_a_url_setting_given_twice_is_refused_not_settled_by_order(url):
    with pytest.raises(ConfigError, match="given more than once"):
        hsio.open_site(hsio.load_structure("validation"), url)


def test_a_refusal_before_any_motion_leaves_the_site_usable_from_rest():
    s = hsio.load_structure("validation")
    ground = hsio.synthetic_record(duration_s=0.2, dt=s.dt)
    with hsio.open_site(s, "emulator://") as site:
        with pytest.raises(ConfigError, match="start must be 'rest' or 'present'"):
            hsio.simulate(s, ground, site, start="bogus")
        assert len(hsio.simulate(s, ground, site).t) == len(ground.accel_g)


def test_recorder_names_that_differ_only_in_case_are_refused_and_leave_no_file(tmp_path):
    from hsio.errors import RecordError
    from hsio.recording import Recorder

    with pytest.raises(RecordError, match="column names ignoring case"):
        Recorder(tmp_path / "r.sqlite", ["a", "A"], ["C1"])
    with pytest.raises(RecordError, match="column names ignoring case"):
        Recorder(tmp_path / "r.sqlite", ["a"], ["C1", "c1"])
    assert list(tmp_path.iterdir()) == []
    Recorder(tmp_path / "r.sqlite", ["a"], ["C1"]).close()
