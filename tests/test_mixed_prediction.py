"""The NS prediction that mixed control's instruments rule reads (docs/force_control.md, "FC only
where NS predicts an elastic specimen"): the hysteretic ratio against closed forms, and which
elements of the shipped structures it keeps in DC."""

import numpy as np
import pytest

from hsio import study_mixed as sm
from hsio.api import run_numerical
from hsio.errors import ConfigError
from hsio.ground_motion import synthetic_record
from hsio.integrators.mixed import hysteretic_ratio, predicted_elastic
from hsio.structures import get_structure


def elastic_perfectly_plastic(u, K, u_y):
    R, r, previous = [], 0.0, 0.0
    for x in u:
        r = float(np.clip(r + K * (x - previous), -K * u_y, K * u_y))
        previous = x
        R.append(r)
    return np.array(R)


@pytest.mark.parametrize("K, u_y, u_max", [(2.0, 1.0, 3.0), (120.0, 0.5, 0.8), (7.2, 0.49, 2.5)])
def test_an_elastic_perfectly_plastic_cycle_has_its_closed_form(K, u_y, u_max):
    """Loaded to u_max, then once round -u_max and back: dissipated 2 F_y (u_max - u_y) on the
    way up and 4 F_y (u_max - u_y) per loop; the ratio (2 + 8) u_y (u_max - u_y) / u_max^2."""
    u = np.concatenate([np.linspace(0, u_max, 2001), np.linspace(u_max, -u_max, 4001)[1:],
                        np.linspace(-u_max, u_max, 4001)[1:]])
    eta = hysteretic_ratio(u, elastic_perfectly_plastic(u, K, u_y), K)
    assert eta == pytest.approx(10 * u_y * (u_max - u_y) / u_max**2, rel=1e-6)


def test_an_elastic_element_dissipates_nothing():
    rng = np.random.default_rng(5)
    u = np.concatenate([[0.0], np.cumsum(rng.normal(0, 0.1, 3000))])  # from rest
    assert hysteretic_ratio(u, 7.2 * u, 7.2) == pytest.approx(0.0, abs=1e-12)  # linear: exactly 0
    stiffening = 7.2 * u + 20.0 * np.maximum(np.abs(u) - 1.0, 0.0) * np.sign(u)  # a gap that closes
    assert hysteretic_ratio(u, stiffening, 7.2) <= 1e-12  # elastic: nothing dissipated
    assert hysteretic_ratio(np.zeros(10), np.zeros(10), 7.2) == 0.0  # at rest


def test_a_coupled_linear_element_dissipates_nothing_and_a_diverged_ns_is_not_elastic():
    """Two basic DOFs with a coupled K^EI (a column's shear and rotation): the element's total work
    against its K^EI matrix, not each DOF's alone. NaN in NS: infinite, never taken for elastic."""
    K = np.array([[10.0, -4.0], [-4.0, 3.0]])
    rng = np.random.default_rng(8)
    u = np.vstack([[0.0, 0.0], np.cumsum(rng.normal(0, 0.1, (2000, 2)), axis=0)])
    assert hysteretic_ratio(u, u @ K, K) == pytest.approx(0.0, abs=1e-9)
    assert hysteretic_ratio(np.array([0.0, np.nan, 1.0]), np.array([0.0, 1.0, 2.0]), 2.0) == np.inf
    assert not hysteretic_ratio([0.0, 1.0], [0.0, np.inf], 2.0) < 0.1


def test_the_wall_and_a_cracked_infill_stay_in_dc_the_linear_frame_does_not():
    wall = get_structure("structure_I")
    ns = run_numerical(wall, synthetic_record(duration_s=2.0, dt=wall.dt, pga_g=0.05, seed=3), "mixed")
    assert predicted_elastic(ns, wall, 0.1).tolist() == [False]  # pinched wood dissipates from the start
    frame = get_structure("structure_II_infill")
    for pga, expected in ((0.05, [True, True]), (0.25, [True, False])):  # BF linear; IF cracks at 0.25 g
        ns = run_numerical(frame, synthetic_record(duration_s=4.0, dt=frame.dt, pga_g=pga, seed=1994), "mixed")
        assert predicted_elastic(ns, frame, 0.1).tolist() == expected


def test_the_studys_mixed_method_needs_the_prediction():
    structure = get_structure("structure_II")
    with pytest.raises(ConfigError, match="give ns="):
        sm.make_method(structure, "mixed", 0.025, 0.01)
    method = sm.make_method(structure, "mixed", 0.025, 0.01, sm.Recipe(max_hysteretic_ratio=0.0))
    assert np.all(np.isfinite(method.rule.upper))


def test_once_ns_predicts_one_element_to_dissipate_no_element_goes_to_fc():
    """structure_II_infill at 0.25 g: NS cracks the infill; the linear bare frame stays in DC too."""
    from hsio.integrators import SwitchingRule

    frame = get_structure("structure_II_infill")
    rule = SwitchingRule.from_instruments([7.2, 122.6], 0.025, 0.01, noise_mm=0.01, force_noise_kN=0.01)
    cracked = run_numerical(frame, synthetic_record(duration_s=4.0, dt=frame.dt, pga_g=0.25, seed=1994), "mixed")
    assert rule.elastic_only(cracked, frame, 0.1).upper.tolist() == [np.inf, np.inf]
    elastic = run_numerical(frame, synthetic_record(duration_s=4.0, dt=frame.dt, pga_g=0.05, seed=1994), "mixed")
    assert rule.elastic_only(elastic, frame, 0.1).upper.tolist() == rule.upper.tolist()
