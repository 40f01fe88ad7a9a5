"""The controller-rate loop's measurement of a step (docs/method.md section 5): the mean of
exactly the last n_avg controller periods, over an actuator whose samples differ period by
period; the commands land on the targets, and limits are checked before anything moves."""

import numpy as np
import pytest

from hsio.clock import LockstepClock
from hsio.control_loop import ControlLoop
from hsio.errors import LimitError
from hsio.interfaces import Actuator, ControlMode, Feedback, Limits
from hsio.sites import ActuatorSite


class LaggingSpring(Actuator):
    """A displacement-controlled actuator on a linear spring k whose position follows the command
    with a first-order lag (a fraction ``gain`` of the error per period). Logs every feedback."""

    def __init__(self, name="a", k=2.0, gain=0.2, offset=0.0, limits=Limits()):
        self.name, self.k, self.gain, self.limits = name, k, gain, limits
        self.position = offset
        self.target = offset
        self.log: list[tuple[float, float]] = []
        self.sent: list[float] = []
        self.holding = False
        self._mode = ControlMode.DISPLACEMENT
        self.ticks = 0

    @property
    def mode(self):
        return self._mode

    def set_mode(self, mode):
        self._mode = mode

    def _send(self, value):
        self.sent.append(value)
        self.target = value

    def advance(self, ticks):
        for _ in range(ticks):
            self.position += self.gain * (self.target - self.position)
            self.ticks += 1

    def feedback(self):
        fb = Feedback(self.position, self.k * self.position, self.ticks / 1024)
        self.log.append((fb.displacement_mm, fb.force_kN))
        return fb

    def hold(self):
        self.holding = True


def loop_over(actuators, n_avg, test_rate=6.25, dt=0.01):
    clock = LockstepClock()
    for a in actuators:
        clock.attach(a)
    return ControlLoop(actuators, clock, dt, test_rate, n_avg=n_avg, keep_samples=True)


@pytest.mark.parametrize("n_avg", [1, 5, 20])
def test_step_measurement_is_the_mean_of_exactly_the_last_n_avg_periods(n_avg):
    actuators = [LaggingSpring("a", k=2.0), LaggingSpring("b", k=5.0, gain=0.1)]
    loop = loop_over(actuators, n_avg)
    for targets in ([3.0, -1.0], [4.5, -2.0], [4.0, 0.5]):
        before = [len(a.log) for a in actuators]
        fb = loop.execute(np.array(targets))
        for j, a in enumerate(actuators):
            step_log = np.array(a.log[before[j]:])
            assert len(step_log) == 64  # t_d = 6.25 x 0.01 s at 1024 Hz
            tail = step_log[-n_avg:]
            assert fb.displacement[j] == pytest.approx(tail[:, 0].mean(), rel=1e-14)
            assert fb.force[j] == pytest.approx(tail[:, 1].mean(), rel=1e-14)
            if n_avg > 1:  # the samples differ: one more or one fewer would give another mean
                assert fb.displacement[j] != pytest.approx(step_log[-n_avg - 1:, 0].mean(), rel=1e-9)
                assert fb.displacement[j] != pytest.approx(step_log[-n_avg + 1:, 0].mean(), rel=1e-9)
            assert a.sent[-1] == targets[j]  # the last command is the target
            assert np.allclose(fb.samples[:, j, 1], step_log[:, 0], rtol=0, atol=0)
        assert np.array_equal(fb.targets, targets)


def test_site_reports_the_averaged_measurement_and_its_secant():
    actuator = LaggingSpring("a", k=2.0, gain=0.05)
    site = ActuatorSite(loop_over([actuator], n_avg=8))
    site.set_trial(np.array([2.0]), [ControlMode.DISPLACEMENT])
    daq = site.get_daq()
    tail = np.array(actuator.log[-8:])
    assert daq.u[0] == pytest.approx(tail[:, 0].mean(), rel=1e-14)
    assert daq.R[0] == pytest.approx(tail[:, 1].mean(), rel=1e-14)
    assert daq.u[0] < 2.0  # lagging: the average is behind the target
    assert daq.k[0] == pytest.approx(2.0, rel=1e-12)  # a linear spring from rest
    site.commit()
    assert np.allclose(site.committed()[0], daq.u)


def test_a_target_beyond_the_stroke_is_refused_before_any_command_is_sent():
    actuator = LaggingSpring("a", limits=Limits(stroke_mm=20.0))
    loop = loop_over([actuator], n_avg=1)
    with pytest.raises(LimitError, match="stroke"):
        loop.execute(np.array([10.5]))
    assert actuator.sent == []
    loop.execute(np.array([10.0]))  # at the edge of the stroke: accepted
    assert actuator.sent[-1] == 10.0
