"""Signs of a rig on the other side of its specimen (docs/setups.md): ``mirror = true`` is the
rig as drawn reflected left to right, so that the model's pose (u, theta) is the drawn rig's
(-u, -theta); a negative displacement factor (with a negative force factor) turns the rig half a
turn in the plane, (u, theta) -> (-u, theta). Each is checked against the same rig written out
pin by pin: strokes, the rotation measured back, and the basic forces."""

import math

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.setups import Factors, PlanarActuator, PlanarSetup, make_setup, three_actuators, two_actuators

L, H = 1500.0, 500.0


def _same(setup, explicit, d, f):
    np.testing.assert_allclose(setup.strokes(d), explicit.strokes(d), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(setup.jacobian(d), explicit.jacobian(d), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(setup.basic_displacements(explicit.strokes(d)), d, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(setup.basic_forces(f, d), explicit.basic_forces(f, d), rtol=1e-12)
    assert setup.pose_problem(d) == explicit.pose_problem(d) == ""


@pytest.mark.parametrize("d", [np.array([20.0, 0.01]), np.array([-150.0, 0.6])])
def test_two_actuators_on_the_other_side_of_a_column(d):
    # actuators to the right of the column, pushing its top and the beam H above it
    explicit = PlanarSetup(("ux", "theta"), (PlanarActuator("lower", (L, 0.0), (0.0, 0.0)),
                                             PlanarActuator("upper", (L, H), (0.0, H))))
    mirrored = make_setup({"kind": "two_actuators", "length_mm": L, "spacing_mm": H, "mirror": True}, 2)
    f = np.array([30.0, -10.0])
    _same(mirrored, explicit, d, f)
    # small motions in closed form: the right-hand actuators shorten as the top moves right,
    # and the upper one lengthens as it turns counter-clockwise: s = (-u, -u + H theta)
    small = np.array([0.01, 1e-6])
    np.testing.assert_allclose(mirrored.strokes(small), [-0.01, -0.01 + H * 1e-6], rtol=1e-6)
    # a push of the lower actuator (extension, f > 0) moves the top left: a negative shear
    assert mirrored.basic_forces(np.array([1.0, 0.0]), np.zeros(2))[0] == pytest.approx(-1.0)


def test_a_negative_displacement_factor_turns_the_rig_half_a_turn():
    # the drawn rig turned by pi in the plane: actuators to the right, the upper one H below
    explicit = PlanarSetup(("ux", "theta"), (PlanarActuator("lower", (L, 0.0), (0.0, 0.0)),
                                             PlanarActuator("upper", (L, -H), (0.0, -H))))
    turned = two_actuators(L, H, Factors(displacement=-1.0, force=-1.0))
    _same(turned, explicit, np.array([35.0, -0.2]), np.array([12.0, 7.0]))
    # and it is not the mirrored rig: the rotation's share of the upper stroke has the other sign
    mirrored = two_actuators(L, H, mirror=True)
    small = np.array([0.0, 1e-6])
    assert turned.strokes(small)[1] == pytest.approx(-mirrored.strokes(small)[1], rel=1e-6)


def test_three_actuators_mirrored_and_scaled():
    a = 400.0
    # horizontal actuator from the right; the vertical ones swap sides (the drawn left one at +a)
    explicit = PlanarSetup(("ux", "uy", "theta"), (
        PlanarActuator("horizontal", (L, 0.0), (0.0, 0.0)),
        PlanarActuator("left", (a, -L), (a, 0.0)),
        PlanarActuator("right", (-a, -L), (-a, 0.0)),
    ), Factors(displacement=2.0, force=3.0))
    mirrored = three_actuators(L, a, Factors(displacement=2.0, force=3.0), mirror=True)
    _same(mirrored, explicit, np.array([40.0, -12.0, 0.3]), np.array([5.0, -2.0, 9.0]))


def test_mirror_is_a_boolean_of_the_planar_kinds_only():
    with pytest.raises(ConfigError, match=r"^s\.mirror: must be true or false"):
        make_setup({"kind": "two_actuators", "length_mm": L, "spacing_mm": H, "mirror": 1}, 2, "s")
    with pytest.raises(ConfigError, match=r"^s\.mirror: unknown key of setup 'parallel'"):
        make_setup({"kind": "parallel", "ratios": [1.0, 1.0], "mirror": True}, 1, "s")
    with pytest.raises(ConfigError, match=r"^s\.mirror: unknown key of setup 'none'"):
        make_setup({"kind": "none", "mirror": True}, 1, "s")
    one = make_setup({"kind": "one_actuator", "length_mm": 1000.0, "angle_deg": 30.0, "mirror": True}, 1)
    assert one.strokes(np.array([1e-6]))[0] == pytest.approx(-1e-6 * math.cos(math.radians(30.0)), rel=1e-5)
