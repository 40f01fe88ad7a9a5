"""The controller-rate loop's measurement of a step (E&M 2007: N_avg samples averaged): the mean of
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
            assert fb.commands[j] == targets[j]
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


def test_commands_start_from_the_actuators_present_position():
    actuator = LaggingSpring("a", offset=5.0, gain=1.0)
    loop = loop_over([actuator], n_avg=1)
    fb = loop.execute(np.array([5.5]))
    assert min(actuator.sent) >= 5.0 - 1e-12 and max(actuator.sent) <= 5.5 + 1e-12
    assert fb.displacement[0] == pytest.approx(5.5)


def test_ramp_hold_dwells_on_the_target_for_the_hold_fraction():
    actuator = LaggingSpring("a", gain=0.5)
    clock = LockstepClock()
    clock.attach(actuator)
    loop = ControlLoop([actuator], clock, 0.01, 6.25, n_avg=4, hold_fraction=0.5)
    loop.execute(np.array([1.0]))
    assert len(actuator.sent) == 64
    assert actuator.sent[-33:] == [1.0] * 33 and actuator.sent[-34] != 1.0
    assert actuator.position == pytest.approx(1.0, abs=1e-9)  # settled during the dwell


def test_displacement_commands_faster_than_the_actuator_are_refused_and_hold():
    actuator = LaggingSpring("a", limits=Limits(velocity_mm_s=10.0))
    loop = loop_over([actuator], n_avg=1)
    loop.execute(np.array([0.3]))  # about 5 mm/s
    with pytest.raises(LimitError, match="velocity"):
        loop.execute(np.array([2.0]))  # about 30 mm/s
    assert actuator.holding
    assert max(np.abs(np.diff([0.0] + actuator.sent))) * 1024 <= 10.0


def test_force_commands_are_not_checked_against_the_displacement_velocity():
    actuator = LaggingSpring("a", limits=Limits(velocity_mm_s=10.0))
    loop = loop_over([actuator], n_avg=1)
    loop.set_mode(0, ControlMode.FORCE)
    fb = loop.execute(np.array([20.0]))  # kN: a fast force ramp
    assert actuator.mode is ControlMode.FORCE and actuator.sent[-1] == 20.0
    assert fb.targets[0] == 20.0


def test_a_mode_switch_starts_the_new_command_at_the_present_measurement():
    actuator = LaggingSpring("a", k=4.0, gain=1.0)
    loop = loop_over([actuator], n_avg=1, )
    loop.execute(np.array([0.5]))
    loop.set_mode(0, ControlMode.FORCE)
    assert loop.generators[0].command == pytest.approx(2.0)  # 4 kN/mm x 0.5 mm
    assert loop.generators[0].period == pytest.approx(1 / 1024)
    loop.execute(np.array([2.4]))
    assert min(actuator.sent[-64:]) >= 2.0 - 1e-12
    loop.set_mode(0, ControlMode.FORCE)  # already in force control: nothing changes
    assert actuator.mode is ControlMode.FORCE
    loop.set_mode(0, ControlMode.DISPLACEMENT)  # back: from the present displacement
    assert loop.generators[0].command == pytest.approx(actuator.position) and actuator.k * actuator.position > 2 * actuator.position


def test_a_mode_switch_keeps_the_ramp_hold():
    actuator = LaggingSpring("a")
    clock = LockstepClock()
    clock.attach(actuator)
    loop = ControlLoop([actuator], clock, 0.01, 6.25, hold_fraction=0.5)
    loop.set_mode(0, ControlMode.FORCE)
    assert loop.generators[0].dwell_samples == 32


def test_loop_arguments():
    actuator = LaggingSpring("a")
    clock = LockstepClock()
    clock.attach(actuator)
    with pytest.raises(ValueError, match="test rate must be positive"):
        ControlLoop([actuator], clock, 0.01, 0.0)
    slow = ControlLoop([actuator], clock, 0.1, 0.625, n_avg=0, keep_samples=False)  # TR below 1 is allowed
    assert slow.t_d == pytest.approx(0.0625) and slow.n_avg == 1
    before = len(actuator.log)
    fb = slow.execute(np.array([0.2]))
    assert fb.samples is None
    assert fb.displacement[0] == actuator.log[-1][0] and len(actuator.log) - before == 64
