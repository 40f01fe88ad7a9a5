"""The channel <-> actuator map of a structure's setups (hsio.sites.setup_map) in closed form:
which actuator is a channel's own, the actuator forces that carry given basic forces, and the
recorder's per-channel samples by the linearised geometry."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.setups import Factors, one_actuator, two_actuators
from hsio.setups.factory import IdentitySetup
from hsio.sites.setup_map import SetupMap

ANGLE = math.radians(30.0)


def _element(name, setup, actuators):
    return SimpleNamespace(name=name, actuator_names=tuple(actuators), make_setup=lambda: setup)


def _map(scaled=Factors(displacement=0.5, force=2.0)):
    """A column on two actuators (channels 0, 1), an inclined actuator with factors (channel 2) and
    two plain actuators (channels 3, 4; actuators 3, 4), in that order."""
    return SetupMap([_element("column", two_actuators(1000.0, 400.0), ("lower", "upper")),
                     _element("brace", one_actuator(1500.0, 30.0, scaled), ("brace",)),
                     _element("walls", IdentitySetup(2), ("w1", "w2"))])


def test_a_channel_without_a_setup_has_its_own_actuator():
    m = _map()
    assert (m.n_channels, m.n_actuators) == (5, 5)
    assert m.actuator_names == ["lower", "upper", "brace", "w1", "w2"]
    assert [m.external_strokes(c).tolist() for c in (3, 4)] == [[0, 0, 0, 1, 0], [0, 0, 0, 0, 1]]
    for c in (0, 1, 2):
        with pytest.raises(ConfigError, match="loaded through a setup"):
            m.external_strokes(c)
    with pytest.raises(ConfigError, match="no channel 5"):
        m.external_strokes(5)
    scaled = SetupMap([_element("w", IdentitySetup(1, Factors(displacement=2.0)), ("w",))])
    with pytest.raises(ConfigError, match="loaded through a setup"):  # stroke = displacement / 2: not its own
        scaled.external_strokes(0)
    # several actuators on one DOF: each moves by its ratio
    from hsio.setups import ParallelSetup

    pair = SetupMap([_element("w", IdentitySetup(1), ("w",)), _element("p", ParallelSetup([1.0, -0.5]), ("e", "f"))])
    assert pair.external_strokes(1).tolist() == [0.0, 1.0, -0.5]


def test_forces_for_carries_the_basic_forces_at_the_pose():
    m = _map()
    d = np.array([12.0, 0.02, 8.0, 1.0, -2.0])
    q = np.array([40.0, 3000.0, -25.0, 5.0, 6.0])
    f = m.forces_for(q, d)
    # back through q = J(d)^T f at the measured pose: the basic forces asked for
    u, q_back = m.basic(m.strokes(d), f)
    np.testing.assert_allclose(u, d, atol=1e-9)
    np.testing.assert_allclose(q_back, q, rtol=1e-9)
    # the inclined actuator in closed form: model force = force factor x f cos(phi), phi at the pose
    lab_u = d[2] / 0.5
    cos_phi = (1500.0 * math.cos(ANGLE) + lab_u) / math.hypot(1500.0 * math.cos(ANGLE) + lab_u, 1500.0 * math.sin(ANGLE))
    assert f[2] == pytest.approx(q[2] / (2.0 * cos_phi), rel=1e-9)
    np.testing.assert_allclose(f[3:], q[3:], rtol=1e-12)


def test_linearised_samples_map_each_column_by_J0():
    m = _map()
    n = 3
    samples = np.arange(n * 5 * 3, dtype=float).reshape(n, 5, 3) + 1.0  # command, stroke, force
    out = m.linearised_samples(samples)
    # the inclined actuator: channel displacement = factor x stroke / cos(a); force = factor f cos(a)
    for col in (0, 1):
        np.testing.assert_allclose(out[:, 2, col], 0.5 * samples[:, 2, col] / math.cos(ANGLE), rtol=1e-12)
    np.testing.assert_allclose(out[:, 2, 2], 2.0 * samples[:, 2, 2] * math.cos(ANGLE), rtol=1e-12)
    np.testing.assert_allclose(out[:, 3:, :], samples[:, 3:, :], rtol=1e-12)
    # the column: x from the lower actuator, the rotation from the difference over the spacing
    np.testing.assert_allclose(out[:, 0, 1], samples[:, 0, 1], rtol=1e-12)
    np.testing.assert_allclose(out[:, 1, 1], (samples[:, 0, 1] - samples[:, 1, 1]) / 400.0, rtol=1e-12)
    # forces: the shear is their sum, the moment the upper one's times the spacing (sign of J0)
    np.testing.assert_allclose(out[:, 0, 2], samples[:, 0, 2] + samples[:, 1, 2], rtol=1e-12)
    np.testing.assert_allclose(out[:, 1, 2], -400.0 * samples[:, 1, 2], rtol=1e-12)
