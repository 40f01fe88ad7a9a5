"""Actuator limits: a command beyond the stroke, the force capacity or the velocity limit, or not a
finite number, is refused before it is sent (the actuator keeps its last command); a command at
the limit is sent. The stroke is centred on zero (E&M 2007, eq. (2): d_max = 254 mm)."""

import math

import pytest

from hsio.errors import LimitError
from hsio.interfaces import Actuator, ActuatorChannels, ControlMode, Feedback, Limits


def test_default_limits():
    limits = Limits()
    assert limits.stroke_mm == 254.0 and limits.half_stroke_mm == 127.0
    assert limits.force_kN == 250.0 and limits.velocity_mm_s == 500.0


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_displacement_at_the_half_stroke_is_sent_and_beyond_it_refused(sign):
    limits = Limits(stroke_mm=100.0)
    limits.check_displacement(sign * 50.0, "here")
    limits.check(ControlMode.DISPLACEMENT, sign * 50.0, "here")
    with pytest.raises(LimitError, match=r"here: displacement command .*50\.001 mm is beyond the stroke \(\+/-50\.0 mm\)"):
        limits.check_displacement(sign * 50.001, "here")
    with pytest.raises(LimitError, match="^here: displacement command"):
        limits.check(ControlMode.DISPLACEMENT, sign * 50.001, "here")
    limits.check(ControlMode.FORCE, sign * 50.001, "here")  # a force command is checked against the force


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_force_at_the_capacity_is_sent_and_beyond_it_refused(sign):
    limits = Limits(force_kN=30.0)
    limits.check_force(sign * 30.0, "there")
    limits.check(ControlMode.FORCE, sign * 30.0, "there")
    with pytest.raises(LimitError, match=r"there: force command .*30\.010 kN is beyond the capacity \(\+/-30\.0 kN\)"):
        limits.check_force(sign * 30.01, "there")
    with pytest.raises(LimitError, match="^there: force command"):
        limits.check(ControlMode.FORCE, sign * 30.01, "there")
    limits.check(ControlMode.DISPLACEMENT, sign * 30.01, "there")  # within the default stroke


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_commands_that_are_not_finite_are_refused(value):
    limits = Limits()
    with pytest.raises(LimitError, match="not a finite number"):
        limits.check_displacement(value, "x")
    with pytest.raises(LimitError, match="not a finite number"):
        limits.check_force(value, "x")


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_velocity_at_the_limit_is_sent_and_beyond_it_refused(sign):
    limits = Limits(velocity_mm_s=10.0)
    limits.check_velocity(sign * 10.0, "v")
    with pytest.raises(LimitError, match=r"v: command velocity .*10\.1 mm/s is beyond the limit \(10\.0 mm/s\)"):
        limits.check_velocity(sign * 10.1, "v")


class Probe(Actuator, ActuatorChannels):
    def __init__(self, mode=ControlMode.DISPLACEMENT):
        self.name = "probe"
        self.limits = Limits(stroke_mm=20.0, force_kN=5.0)
        self._mode = mode
        self.sent = []

    @property
    def mode(self):
        return self._mode

    def set_mode(self, mode):
        self._mode = mode

    def _send(self, value):
        self.sent.append(value)

    def feedback(self):
        return Feedback(1.5, -0.5, 0.0)

    def hold(self):
        pass


def test_an_actuator_sends_only_commands_within_its_limits_for_its_mode():
    a = Probe()
    a.command(10.0)
    with pytest.raises(LimitError, match="actuator 'probe'"):
        a.command(10.5)
    assert a.sent == [10.0]
    a.set_mode(ControlMode.FORCE)
    a.command(5.0)
    with pytest.raises(LimitError, match="capacity"):
        a.command(6.0)
    assert a.sent == [10.0, 5.0]


def test_actuator_channels_name_their_units():
    a = Probe()
    assert [(c.name, c.unit) for c in a.channels] == [("probe.displacement", "mm"), ("probe.force", "kN")]
    assert a.read() == {"probe.displacement": 1.5, "probe.force": -0.5}
