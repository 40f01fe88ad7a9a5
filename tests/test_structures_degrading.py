"""The peak-oriented degrading specimen in closed form, and the three-storey building in NS."""

from __future__ import annotations

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.ground_motion import synthetic_record
from hsio.api import run_numerical
from hsio.specimens import PeakOriented, make_specimen
from hsio.structures import get_structure

# k0 = 20 kN/mm, F_y = 40 kN (u_y = 2 mm), hardening 3 %: H(a) = 40 + 0.6 (a - 2);
# capping at 10 mm (F_c = 44.8 kN), then -10 %: P(a) = 44.8 - 2 (a - 10), down to 8 kN at 28.4 mm.
PARAMS = {"kind": "peak_oriented", "k0": 20.0, "Fy": 40.0, "u_c": 10.0, "alpha_s": 0.03, "alpha_c": 0.1,
          "residual": 0.2, "gamma": 50.0, "c": 1.0}


def model() -> PeakOriented:
    return make_specimen(PARAMS)


def test_monotonic_backbone():
    expected = {1.0: 20.0, 2.0: 40.0, 6.0: 42.4, 10.0: 44.8, 15.0: 34.8, 28.4: 8.0, 35.0: 8.0}
    for sign in (1.0, -1.0):
        m = model()
        forces = {float(u): m.force(sign * u) for u in np.arange(0.5, 35.01, 0.1).round(1)}
        for u, F in expected.items():
            assert forces[u] == pytest.approx(sign * F, abs=1e-9), (sign, u)
        assert m.strength_factor == 1.0  # no excursion has ended: no deterioration
    m = model()
    for u in (10.0, 15.0):
        m.force(u)
    assert (m.trial(15.5) - m.trial(15.0)) / 0.5 == pytest.approx(-2.0)  # the softening branch


def test_trial_leaves_the_committed_state_and_commit_moves_it():
    m = model()
    for u in (2.0, 6.0):
        m.force(u)
    assert m.trial(8.0) == pytest.approx(43.6)
    assert m.trial(4.0) == pytest.approx(2.4)  # unloading at k0 from (6, 42.4)
    assert m.trial(8.0) == pytest.approx(43.6)  # still from (6, 42.4)
    m.trial(4.0)
    m.commit()
    assert m.trial(6.0) == pytest.approx(42.4)  # reloading from (4, 2.4)
    path = 25 * np.sin(np.linspace(0, 6 * np.pi, 400)) * np.linspace(0.2, 1.0, 400)
    a, b = model(), model()
    for u in path:
        b.trial(u + 3.0)
        b.trial(-u)
        b.trial(u)
        b.commit()
        assert b.force(u) == a.force(u)
    assert a.strength_factor == b.strength_factor < 1.0


def test_strength_and_stiffness_drop_after_an_excursion():
    m = model()
    for u in (2.0, 8.0):
        m.force(u)
    m.force(8.0 - 43.6 / 20.0)  # unloaded to zero force: the first excursion ends
    E1 = 40.0 * 2.0 / 2 + (40.0 + 43.6) / 2 * 6.0 - 43.6**2 / (2 * 20.0)
    s1 = 1 - E1 / (50.0 * 40.0 * 2.0)
    assert m.strength_factor == pytest.approx(s1, rel=1e-12)
    assert m.unloading_stiffness == pytest.approx(20.0 * s1, rel=1e-12)
    # the other way it has not yielded: it goes to the deteriorated envelope -s1 H(8)
    assert m.force(-8.0) == pytest.approx(-s1 * 43.6, rel=1e-12)
    u_zero = -8.0 + s1 * 43.6 / m.unloading_stiffness
    m.force(u_zero)
    s2 = m.strength_factor
    assert s2 < s1
    # peak-oriented: reloading aims at the earlier peak (8 mm), on the deteriorated envelope
    assert m.trial(8.0) == pytest.approx(s2 * 43.6, rel=1e-9)
    assert m.trial(8.0) / (8.0 - u_zero) < 0.5 * 20.0  # reloading far softer than k0


def test_a_cycle_in_small_steps_in_closed_form():
    """k0 = 8, F_y = 8 (u_y = 1), hardening 1/8 of k0, E_t = 50 x 8 x 1 = 400 kN mm; loaded to
    3 mm in steps of 0.25 mm, unloaded in steps through its zero-force point (1.75 mm), reloaded
    the other way: the excursion's energy is the area of the loop by the trapezoids of its
    steps; the other way it has not yielded, so reloading runs on the line from the zero-force
    point to the deteriorated yield point (where k0 a = s H(a)) and then on s H."""
    m = make_specimen({**PARAMS, "k0": 8.0, "Fy": 8.0, "u_c": 5.0, "alpha_s": 0.125})
    H = lambda a: 8.0 + 1.0 * (a - 1.0)  # noqa: E731  hardening line, alpha_s k0 = 1 kN/mm
    for k in range(1, 13):  # 0.25 .. 3 mm on the backbone
        u = 0.25 * k
        assert m.force(u) == pytest.approx(8.0 * u if u <= 1.0 else H(u), abs=1e-12)
    for u in (2.75, 2.5, 2.25, 2.0):  # unloading at k0 from (3, 10)
        assert m.force(u) == pytest.approx(10.0 - 8.0 * (3.0 - u), abs=1e-12)
    assert m.strength_factor == 1.0  # the excursion goes on while the force has not reached zero
    assert m.force(1.75) == 0.0  # it ends at the zero-force point, the other one begins
    # the loop: 4 (elastic) + 18 (hardening) - 6.25 (unloading) = 15.75 kN mm, all dissipated
    s = 1.0 - 15.75 / 400.0
    F = m.force(1.5)
    assert m.strength_factor == pytest.approx(s, rel=1e-12)
    assert m.unloading_stiffness == pytest.approx(8.0 * s, rel=1e-12)
    a_y = s * 8.0 * (1.0 - 0.125) / (8.0 * (1.0 - 0.125 * s))  # 8 a = s H(a)
    assert 8.0 * a_y == pytest.approx(s * H(a_y), rel=1e-12)
    line = lambda u: -8.0 * a_y * (u - 1.75) / (-a_y - 1.75)  # noqa: E731
    assert F == pytest.approx(line(1.5), rel=1e-12)
    for u in (1.0, 0.0, -0.75):
        assert m.force(u) == pytest.approx(line(u), rel=1e-12)
    for u in (-1.0, -1.5, -2.0):  # beyond the deteriorated yield point: on s H
        assert m.force(u) == pytest.approx(-s * H(-u), rel=1e-12)
    for u in (-1.5, -1.0):  # unloading at 8 s towards the zero-force point -2 + 9 s / (8 s) = -0.875
        assert m.force(u) == pytest.approx(-9.0 * s + 8.0 * s * (u + 2.0), rel=1e-12)
    # the second excursion's energy: its loop by the trapezoids of its steps, less the elastic energy
    # left at its last step (the model's eq.: E_i = W - F^2 / (2 k_u))
    us = [1.75, 1.5, 1.0, 0.0, -0.75, -1.0, -1.5, -2.0, -1.5, -1.0]
    Fs = [0.0] + [line(u) for u in us[1:5]] + [-s * H(-u) for u in us[5:8]] + [-9.0 * s + 8.0 * s * (u + 2.0) for u in us[8:]]
    W = sum(0.5 * (F0 + F1) * (u1 - u0) for u0, u1, F0, F1 in zip(us, us[1:], Fs, Fs[1:]))
    E_2 = W - Fs[-1] ** 2 / (2.0 * 8.0 * s)
    s2 = s * (1.0 - E_2 / (400.0 - 15.75))
    F = m.force(0.0)  # past -0.875: the third excursion, reloading towards the largest earlier one (3 mm)
    assert m.strength_factor == pytest.approx(s2, rel=1e-12)
    peak_line = lambda u: 10.0 * s2 * (u + 0.875) / (3.0 + 0.875)  # noqa: E731  to (3, s2 H(3))
    assert F == pytest.approx(peak_line(0.0), rel=1e-12)
    assert m.force(1.0) == pytest.approx(peak_line(1.0), rel=1e-12)
    assert m.force(3.0) == pytest.approx(10.0 * s2, rel=1e-12)
    assert m.force(3.25) == pytest.approx(s2 * H(3.25), rel=1e-12)  # on, and now beyond, the peak


def test_elastic_cycles_dissipate_nothing_and_deteriorate_nothing():
    """Cycles within the yield displacement (2 mm) stay on k0 and end excursion after excursion
    with no energy dissipated: the strength and the unloading stiffness stay as they were."""
    m = model()
    for u in 1.9 * np.sin(np.linspace(0.0, 20 * np.pi, 801)):
        assert m.force(u) == pytest.approx(20.0 * u, abs=1e-9)
    assert m.strength_factor == 1.0 and m.unloading_stiffness == 20.0


def test_deterioration_accumulates_until_the_energy_capacity_is_spent():
    m = make_specimen({**PARAMS, "gamma": 10.0})
    factors = []
    for amplitude in [12.0] * 8:
        for u in np.linspace(0, amplitude, 30).tolist() + np.linspace(amplitude, -amplitude, 60).tolist() + np.linspace(-amplitude, 0, 30).tolist():
            m.force(u)
        factors.append(m.strength_factor)
    assert all(b < a for a, b in zip(factors, factors[1:]))
    assert factors[-1] < 0.01  # the capacity E_t = 10 F_y u_y is long spent


def test_a_spent_specimen_jittering_about_its_zero_force_point_keeps_a_force():
    # Once the energy capacity is spent every zero crossing takes 99.9 % off the unloading
    # stiffness; the transducer's noise about the zero-force point crosses it every few samples.
    m = make_specimen({**PARAMS, "gamma": 1.0})
    for u in np.linspace(0, 20, 40).tolist() + np.linspace(20, -20, 80).tolist() + np.linspace(-20, 20, 80).tolist():
        m.force(u)
    u_zero = 20.0 - m.force(20.0) / m.unloading_stiffness
    rng = np.random.default_rng(7)
    forces = [m.force(u) for u in u_zero + 0.01 * rng.standard_normal(1000)]
    assert np.all(np.isfinite(forces))
    assert m.unloading_stiffness >= 1e-9 * PARAMS["k0"]


@pytest.mark.parametrize("bad", [{"k0": 0.0}, {"Fy": -1.0}, {"u_c": 1.0}, {"alpha_s": 1.0}, {"residual": 1.2}, {"gamma": 0.0}])
def test_bad_parameters(bad):
    with pytest.raises(ConfigError, match="peak_oriented"):
        make_specimen({**PARAMS, **bad})


def test_three_storey_building_periods_and_NS_peaks():
    s = get_structure("three_storey")
    np.testing.assert_allclose(1 / s.natural_frequencies_hz(), [0.4544, 0.1825, 0.1239], atol=5e-4)
    np.testing.assert_allclose(s.damping_ratios()[[0, 2]], 0.05, atol=1e-12)
    assert s.experimental[0].actuator == "act1" and s.experimental_dofs == [0]
    assert s.iota.tolist() == [1.0, 1.0, 1.0]
    ground = synthetic_record(duration_s=20.0, dt=s.dt, pga_g=0.4, seed=1994)
    ns = run_numerical(s, ground, "alpha_os", -0.05)
    drift = np.abs(np.diff(np.column_stack([np.zeros(len(ns.u)), ns.u]), axis=1)).max(axis=0)
    # the first storey passes its capping point (21 mm) at the design level; storeys 2-3 stay elastic
    assert 21.0 < drift[0] < 30.0
    assert drift[1] * 50.0 < 600.0 and drift[2] * 35.0 < 400.0
    assert np.abs(ns.measured_force).max() == pytest.approx(434, abs=5)
