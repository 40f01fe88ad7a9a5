"""Experimental setups against closed-form geometry: forward, inverse, forces, linearised form."""

import math

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.setups import Factors, PlanarActuator, PlanarSetup, inverted_v_brace, one_actuator, three_actuators, two_actuators


def test_one_actuator_at_an_angle_in_closed_form():
    L, angle = 1500.0, 30.0
    setup = one_actuator(L, angle)
    a = math.radians(angle)
    for u in (-200.0, -3.0, 0.0, 0.7, 250.0):
        stroke = math.hypot(L * math.cos(a) + u, L * math.sin(a)) - L
        assert setup.strokes([u])[0] == pytest.approx(stroke, abs=1e-10)
        assert setup.basic_displacements([stroke])[0] == pytest.approx(u, abs=1e-9)
        # the actuator's force resolved on x: f cos(phi), phi its present angle
        cos_phi = (L * math.cos(a) + u) / (stroke + L)
        assert setup.basic_forces([10.0], [u])[0] == pytest.approx(10.0 * cos_phi, rel=1e-12)
    # linearised: stroke = cos(angle) u
    assert setup.linearised_strokes([1.0])[0] == pytest.approx(math.cos(a), rel=1e-12)


def test_two_actuators_translation_and_large_rotation():
    L, h = 1000.0, 400.0
    setup = two_actuators(L, h)
    for ux, theta in ((5.0, 0.0), (0.0, 0.01), (-30.0, 0.3), (60.0, -0.6)):
        s_lower = math.hypot(L + ux, 0.0) - L
        upper = np.array([ux - h * math.sin(theta), h * math.cos(theta)])
        s_upper = math.hypot(upper[0] + L, upper[1] - h) - L
        np.testing.assert_allclose(setup.strokes([ux, theta]), [s_lower, s_upper], atol=1e-10)
        np.testing.assert_allclose(setup.basic_displacements(setup.strokes([ux, theta])), [ux, theta], atol=1e-9)


def test_three_actuators_round_trip_and_virtual_work():
    setup = three_actuators(1200.0, 600.0)
    rng = np.random.default_rng(4)
    for _ in range(20):
        d = rng.uniform([-80, -40, -0.4], [80, 40, 0.4])
        np.testing.assert_allclose(setup.basic_displacements(setup.strokes(d)), d, atol=1e-9)
        # virtual work: f . ds = q . dd for a small motion about d
        f = rng.uniform(-50, 50, 3)
        q = setup.basic_forces(f, d)
        dd = rng.normal(size=3) * 1e-6
        ds = setup.strokes(d + dd) - setup.strokes(d - dd)
        assert f @ ds == pytest.approx(q @ (2 * dd), rel=1e-5)


def test_inverted_v_brace_apex():
    leg, angle = 2000.0, 40.0
    setup = inverted_v_brace(leg, angle)
    a = math.radians(angle)
    ux, uy = 12.0, -3.0
    left = math.hypot(leg * math.sin(a) + ux, leg * math.cos(a) + uy) - leg
    right = math.hypot(-leg * math.sin(a) + ux, leg * math.cos(a) + uy) - leg
    np.testing.assert_allclose(setup.strokes([ux, uy]), [left, right], atol=1e-10)
    np.testing.assert_allclose(setup.basic_displacements([left, right]), [ux, uy], atol=1e-9)
    # equal tension in both legs pulls the apex straight down
    q = setup.basic_forces([5.0, 5.0], [0.0, 0.0])
    assert q[0] == pytest.approx(0.0, abs=1e-12) and q[1] == pytest.approx(2 * 5.0 * math.cos(a), rel=1e-12)


def test_linearised_form_agrees_to_second_order():
    setup = three_actuators(1000.0, 500.0)
    d = np.array([1.0, -0.5, 0.002])
    errors = []
    for scale in (1.0, 0.1, 0.01):
        exact, linear = setup.strokes(scale * d), setup.linearised_strokes(scale * d)
        errors.append(np.max(np.abs(exact - linear)))
    assert errors[1] / errors[0] == pytest.approx(0.01, rel=0.05)  # O(d^2)
    assert errors[2] < 1e-7


def test_factors_scale_displacements_and_forces():
    lab = one_actuator(1000.0, 0.0)
    model = one_actuator(1000.0, 0.0, Factors(displacement=2.0, force=-4.0))
    assert model.strokes([10.0])[0] == pytest.approx(lab.strokes([5.0])[0], abs=1e-12)
    assert model.basic_displacements(lab.strokes([5.0]))[0] == pytest.approx(10.0, abs=1e-9)
    assert model.basic_forces([3.0], [10.0])[0] == pytest.approx(-12.0, rel=1e-12)
    with pytest.raises(ConfigError, match="magnitude"):
        Factors(force=0.0)


@pytest.mark.parametrize("table, words", [
    ({"kind": "two_actuators", "length_mm": 1500.0, "spacing_mm": 500.0, "factors": {"displacement": 1e-300}},
     "rig.setup.factors: setup factors: displacement must be a number of magnitude 1e-06 to 1e\\+06"),
    ({"kind": "two_actuators", "length_mm": 1500.0, "spacing_mm": 500.0, "factors": {"force": -1e300}},
     "rig.setup.factors: setup factors: force must be a number of magnitude"),
    ({"kind": "two_actuators", "length_mm": 1e308, "spacing_mm": 500.0}, "rig.setup: two actuators: .* at most 1e\\+06"),
    ({"kind": "one_actuator", "length_mm": 1500.0, "angle_deg": 1e20}, "rig.setup: one actuator: angle_deg must be within"),
])
def test_setup_sizes_beyond_a_rig_are_refused_by_name(table, words):
    """A factor of 1e-300 would overflow the Jacobian into a singular matrix, and a length of 1e308
    would make the pins seem to coincide: each is refused by its name."""
    from hsio.setups import make_setup

    n = 1 if table["kind"] == "one_actuator" else 2
    with pytest.raises(ConfigError, match=words):
        make_setup(table, n, "rig.setup")


def test_a_missing_key_is_named_where_the_kind_has_no_default_for_it():
    """``angle_deg`` defaults to 0 for one actuator (along its DOF); an inverted V has no such
    default (its legs would stand on top of each other) and without it is refused by name."""
    from hsio.setups import make_setup

    assert make_setup({"kind": "one_actuator", "length_mm": 1000.0}, 1).strokes([1e-6])[0] == pytest.approx(1e-6)
    with pytest.raises(ConfigError, match=r"^rig\.setup\.angle_deg: missing \(setup 'inverted_v_brace' needs "
                                          r"leg_length_mm, angle_deg\)"):
        make_setup({"kind": "inverted_v_brace", "leg_length_mm": 1000.0}, 2, "rig.setup")


def test_bad_geometry_is_refused():
    with pytest.raises(ConfigError, match="singular"):
        PlanarSetup(("ux", "theta"), (PlanarActuator("a", (-1000.0, 0.0)), PlanarActuator("b", (-2000.0, 0.0))))
    with pytest.raises(ConfigError, match="cannot control"):
        PlanarSetup(("ux", "uy"), (PlanarActuator("a", (-1000.0, 0.0)),))
    with pytest.raises(ConfigError, match="no length"):
        PlanarSetup(("ux",), (PlanarActuator("a", (0.0, 0.0)),))
    with pytest.raises(ConfigError, match="strokes"):
        two_actuators(1000.0, 400.0).basic_displacements([1.0])


@pytest.mark.parametrize("factor", [1.0, 1000.0, 0.001])
def test_conditioning_is_judged_in_the_lab_whatever_the_model_scale(factor):
    # one actuator at angle a from its DOF moves cos(a) mm of stroke per mm: 88.5 deg (0.026) is
    # accepted, 89.7 deg (0.0052) is nearly square to the DOF and refused, at every model scale
    assert one_actuator(1000.0, 88.5, Factors(displacement=factor)).n_basic == 1
    with pytest.raises(ConfigError, match="singular or nearly"):
        one_actuator(1000.0, 89.7, Factors(displacement=factor))


def test_basic_dofs_must_be_distinct_names_of_the_pose():
    for basic in (("ux", "ux"), ("ux", "w"), ()):
        with pytest.raises(ConfigError, match="distinct names"):
            PlanarSetup(basic, (PlanarActuator("a", (-1000.0, 0.0)), PlanarActuator("b", (0.0, -1000.0))))


def test_three_actuators_in_closed_form():
    L, b = 1200.0, 600.0  # horizontal actuator pinned at the control point, verticals b either side of it
    setup = three_actuators(L, b)
    for ux, uy, theta in ((20.0, 0.0, 0.0), (0.0, -15.0, 0.0), (0.0, 0.0, 0.05), (30.0, 10.0, -0.2)):
        c, s = math.cos(theta), math.sin(theta)
        left, right = (np.array([ux + x * c, uy + x * s]) for x in (-b, b))  # the platen's pins, rotated
        expected = [math.hypot(L + ux, uy) - L,
                    math.hypot(left[0] + b, left[1] + L) - L,
                    math.hypot(right[0] - b, right[1] + L) - L]
        np.testing.assert_allclose(setup.strokes([ux, uy, theta]), expected, atol=1e-9)
    # small motions: x drives the horizontal actuator alone, y both verticals alike, a rotation
    # (counter-clockwise positive) lowers the left vertical and lifts the right by b theta
    np.testing.assert_allclose(setup.linearised_strokes([1.0, 0.0, 0.0]), [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(setup.linearised_strokes([0.0, 1.0, 0.0]), [0.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(setup.linearised_strokes([0.0, 0.0, 1e-3]), [0.0, -b * 1e-3, b * 1e-3], atol=1e-9)


def test_jacobian_matches_finite_differences_at_a_large_rotation():
    setup = three_actuators(1000.0, 500.0)
    d = np.array([40.0, -20.0, 0.5])
    h = np.array([1e-4, 1e-4, 1e-7])
    numeric = np.column_stack([(setup.strokes(d + e) - setup.strokes(d - e)) / (2 * e.sum()) for e in np.diag(h)])
    np.testing.assert_allclose(setup.jacobian(d), numeric, rtol=1e-6, atol=1e-9)


def test_builders_refuse_non_positive_dimensions_by_name():
    for build, args in ((one_actuator, (0.0,)), (two_actuators, (1000.0, 0.0)), (two_actuators, (0.0, 400.0)),
                        (three_actuators, (1000.0, 0.0)), (three_actuators, (-1.0, 500.0)),
                        (inverted_v_brace, (0.0, 40.0)), (inverted_v_brace, (1000.0, 90.0))):
        with pytest.raises(ConfigError, match="positive|angle_deg"):
            build(*args)
    assert one_actuator(1000.0).linearised_strokes([1.0])[0] == pytest.approx(1.0, rel=1e-12)  # along x by default


def test_a_pose_near_or_past_a_singular_one_is_named():
    """One actuator 500 mm long at 80 degrees: square to x at u = -L cos(80) = -86.8 mm. Past that
    the stroke grows again, so the strokes of u = -100 mm are those of a mirror pose on the side
    of rest, u = -2 L cos(80) + 100 = -73.6 mm: the inverse cannot tell them apart, and the
    setup names both poses as ones its actuators cannot drive the element to."""
    L, a = 500.0, math.radians(80.0)
    setup = one_actuator(L, 80.0)
    mirror = -2 * L * math.cos(a) + 100.0
    assert setup.strokes([-100.0])[0] == pytest.approx(setup.strokes([mirror])[0], abs=1e-9)
    assert setup.basic_displacements(setup.strokes([-100.0]))[0] == pytest.approx(mirror, abs=1e-6)
    # conditioning at u in closed form: |cos phi(u)| = |L cos a + u| / |B - A|
    for u in (-86.0, -50.0, 0.0, 100.0):
        cos_phi = abs(L * math.cos(a) + u) / math.hypot(L * math.cos(a) + u, L * math.sin(a))
        assert setup.conditioning([u]) == pytest.approx(cos_phi, rel=1e-12)
    assert "hardly move" in setup.pose_problem([-85.0])  # |cos phi| = 0.0036
    assert "past a singular" in setup.pose_problem([-100.0])  # |cos phi| = 0.027, but on the far side
    for u in (-80.0, 0.0, 120.0):
        assert setup.pose_problem([u]) == ""
    # two actuators: the upper one square to the platen's rotation at theta = pi / 2
    column = two_actuators(1500.0, 500.0)
    assert column.pose_problem([0.0, 0.3]) == ""
    assert column.pose_problem([0.0, math.pi / 2]) != ""


def test_actuators_turned_through_their_reaction_pins_are_refused():
    """Two actuators 300 mm long with the platen moved 594.6 mm towards them: both have passed
    through their reaction pins and point the other way, so the Jacobian's sign is as at rest, and
    their strokes (-5.4 and -1.0 mm) are those of a pose near rest, which the inverse returns. The
    pose is refused, naming an actuator; so are the three-actuator joint's legs pushed past their
    pins, and an actuator swung exactly square to its line at rest."""
    column = two_actuators(300.0, 800.0)
    far = np.array([-594.642925, 5.42970665e-03])
    strokes = column.strokes(far)
    assert np.max(np.abs(strokes)) < 6.0
    near = column.basic_displacements(strokes)
    assert abs(near[0]) < 6.0 and np.allclose(column.strokes(near), strokes, atol=1e-9)
    assert column.pose_problem(near) == ""
    assert "actuator 'lower' would turn through square" in column.pose_problem(far)
    joint = three_actuators(1000.0, 400.0)
    assert "would turn through square" in joint.pose_problem([-987.2, -1016.8, -0.0573])
    side = one_actuator(1000.0, 0.0)
    assert "would turn through square" in side.pose_problem([-1000.0 - 1e-9])
    # a pose turned by less than a quarter turn from the line at rest still stands
    assert column.pose_problem([-100.0, 0.05]) == ""


def test_the_inverse_starts_from_the_commanded_pose():
    """Far from rest the same strokes can have two poses: the joint at (-58, -690.4 mm, 0.7 rad)
    has the strokes of one near (-117, -765 mm, 0.84 rad), with an actuator past its pin, where
    Newton from the linearised guess lands. From the commanded pose (``guess``, as the site
    gives it) the inverse returns the pose commanded; from a guess that leads nowhere the actuators
    can drive to, it falls back to the linearised guess."""
    joint = three_actuators(1000.0, 400.0)
    d = np.array([-58.0, -690.4, 0.7])
    assert joint.pose_problem(d) == ""
    strokes = joint.strokes(d)
    other = joint.basic_displacements(strokes)
    assert np.max(np.abs(other - d)) > 50.0
    np.testing.assert_allclose(joint.strokes(other), strokes, atol=1e-9)
    near = d + np.array([0.5, -0.5, 1e-3])  # the measured pose is near the commanded one
    np.testing.assert_allclose(joint.basic_displacements(strokes, guess=near), d, rtol=1e-9, atol=1e-9)
    # the actuators stayed at rest while the trial asked for d: read back as rest, not a twin of rest
    np.testing.assert_allclose(joint.basic_displacements(np.zeros(3), guess=d), 0.0, atol=1e-9)
    # and the map of a structure's setups passes each element's commanded channels on
    from hsio.sites.setup_map import SetupMap

    class Element:
        name, actuator_names = "joint", ["h", "l", "r"]

        def make_setup(self):
            return joint

    smap = SetupMap([Element()])
    np.testing.assert_allclose(smap.basic(strokes, np.zeros(3), guess=near)[0], d, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(smap.basic(strokes, np.zeros(3))[0], other, rtol=1e-9)
