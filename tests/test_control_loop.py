"""The controller-rate loop in real time: steps land together after a mode switch, a hold holds,
and an unexpected fault stops the loop holding."""

import time

import numpy as np
import pytest

from hsio.emulators.local import open_url
from hsio.clock import LockstepClock, RealTimeClock
from hsio.control_loop import ControlLoop
from hsio.errors import HsioError, InterlockError
from hsio.interfaces import ControlMode
from hsio.structures import validation


def loop_on_emulators(clock, test_rate=5.0):
    s = validation()
    actuators = open_url("emulator://", s.experimental, clock)
    return ControlLoop(actuators, clock, s.dt, test_rate, n_avg=1), actuators


def test_real_time_step_after_a_mode_switch_lands():
    loop, actuators = loop_on_emulators(RealTimeClock())
    try:
        loop.execute(np.array([0.5, 0.5]))
        time.sleep(0.03)  # the integrator computes: the other generator extrapolates meanwhile
        loop.set_mode(0, ControlMode.FORCE)
        started = time.perf_counter()
        fb = loop.execute(np.array([actuators[0].feedback().force_kN + 0.2, 0.6]))
        assert time.perf_counter() - started < 1.0
        assert fb.targets[1] == 0.6
    finally:
        loop.close()


def test_hold_all_holds_while_the_real_time_loop_runs():
    loop, actuators = loop_on_emulators(RealTimeClock())
    try:
        loop.execute(np.array([2.0, 2.0]))  # moving, then extrapolating beyond 2 mm
        loop.hold_all()
        held = [a.controller.command for a in actuators]
        time.sleep(0.05)
        assert all(a.controller.holding for a in actuators)
        assert [a.controller.command for a in actuators] == held
        with pytest.raises(HsioError, match="holds"):
            loop.execute(np.array([2.1, 2.1]))
    finally:
        loop.close()


def test_unexpected_fault_in_lockstep_is_an_hsio_error_and_holds():
    clock = LockstepClock()
    loop, actuators = loop_on_emulators(clock)

    def broken():
        raise ValueError("a register that cannot be encoded")

    actuators[1].feedback = broken
    with pytest.raises(HsioError, match="control loop stopped: ValueError"):
        loop.execute(np.array([0.5, 0.5]))
    assert all(a.controller.holding for a in actuators)


def test_ctrl_c_inside_the_loop_stays_a_keyboard_interrupt_and_holds():
    """A Ctrl-C that lands while the loop reads the controllers is not turned into a fault (a
    study would take it for one failed run and go on; a run would report exit 3, not 5)."""
    clock = LockstepClock()
    loop, actuators = loop_on_emulators(clock)

    def interrupted():
        raise KeyboardInterrupt

    actuators[0].feedback = interrupted
    with pytest.raises(KeyboardInterrupt):
        loop.execute(np.array([0.5, 0.5]))
    assert all(a.controller.holding for a in actuators)


def test_real_time_clock_does_not_burst_after_a_stall():
    clock = RealTimeClock()
    clock.tick()
    time.sleep(0.2)  # a pause of about 200 periods
    clock.tick()
    assert clock.overruns == 1
    started = time.perf_counter()
    for _ in range(20):
        clock.tick()
    assert time.perf_counter() - started > 15 * clock.period_s  # paced, not made up at once


def test_a_refused_target_asks_the_controller_for_its_trip_between_two_periods():
    """A target the limits refuse while the real-time loop runs: the controller is asked whether it
    tripped (the cause to report) with the loop's lock held, so the question never crosses the
    loop's own exchange on the same link; the trip is what the step reports."""
    loop, actuators = loop_on_emulators(RealTimeClock())
    asked = []

    def tripped():
        asked.append(loop._lock._is_owned())
        return "interlock tripped: force 251 kN beyond the capacity"

    actuators[0].tripped = tripped
    try:
        with pytest.raises(InterlockError, match="actuator .*: interlock tripped: force 251 kN"):
            loop.execute(np.array([10 * actuators[0].limits.stroke_mm, 0.0]))
        assert asked == [True]
    finally:
        loop.close()
