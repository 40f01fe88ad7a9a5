"""The emulated servo controller: lag, limits, interlocks, sensors, force loop."""

import math

import numpy as np
import pytest

from hsio.command import PredictorCorrector
from hsio.emulators.local import EmulatedActuator, open_url
from hsio.emulators.servo import ServoConfig, ServoController
from hsio.clock import LockstepClock
from hsio.errors import ConfigError, InterlockError, LimitError
from hsio.interfaces import ControlMode
from hsio.specimens import CrackingInfill, Linear
from hsio.structures import validation

QUIET = dict(noise_mm=0.0, resolution_mm=0.0, force_noise_kN=0.0, force_resolution_kN=0.0)


@pytest.mark.parametrize("lag", [0.01, 0.02, 0.05])
def test_step_response_time_constant_is_the_configured_lag(lag):
    c = ServoController(Linear(1.0), ServoConfig(lag_s=lag, **QUIET))
    c.set_command(1.0)
    x = []
    for _ in range(int(5 * lag * 1024)):
        c.step()
        x.append(c.measured_displacement)
    t = np.arange(1, len(x) + 1) / 1024
    t63 = np.interp(1 - math.exp(-1), x, t)
    assert t63 == pytest.approx(lag, rel=0.05)
    assert x[-1] == pytest.approx(1 - math.exp(-5), abs=0.01)


def test_ramp_lags_by_the_configured_lag():
    lag, v = 0.02, 10.0  # mm/s
    c = ServoController(Linear(1.0), ServoConfig(lag_s=lag, **QUIET))
    for k in range(1, 1025):
        c.set_command(v * k / 1024)
        c.step()
    assert c.command - c.measured_displacement == pytest.approx(v * lag, rel=0.01)


def test_flow_limit_saturates_velocity():
    c = ServoController(Linear(1.0), ServoConfig(velocity_limit_mm_s=50.0, **QUIET))
    c.set_command(100.0)
    c.advance(512)  # 0.5 s
    assert c.measured_displacement == pytest.approx(25.0, rel=0.01)


def test_sensors_quantise_to_resolution_and_add_noise():
    c = ServoController(Linear(1.0), ServoConfig(resolution_mm=0.025, noise_mm=0.01, seed=3))
    c.set_command(1.0)
    readings = []
    c.advance(1024)
    for _ in range(2000):
        c.step()
        readings.append(c.measured_displacement)
    readings = np.array(readings)
    assert np.allclose(np.round(readings / 0.025) * 0.025, readings)
    assert 0.005 < readings.std() < 0.03
    assert readings.mean() == pytest.approx(1.0, abs=0.01)


def test_interlock_trips_beyond_stroke_and_holds():
    c = ServoController(Linear(1.0), ServoConfig(stroke_mm=20.0, **QUIET))
    c.set_command(15.0)  # the emulator itself does not refuse: the host must
    c.advance(2048)
    assert c.tripped and "stroke" in c.tripped
    held = c.d_rod
    c.set_command(0.0)
    c.advance(100)
    assert c.d_rod == pytest.approx(held, abs=1e-9)


def test_force_control_follows_force_command_with_its_lag():
    c = ServoController(Linear(2.0), ServoConfig(force_lag_s=0.02, **QUIET))
    c.set_mode(ControlMode.FORCE)
    c.set_command(10.0)
    c.advance(int(0.02 * 1024))
    assert c.measured_force == pytest.approx(10.0 * (1 - math.exp(-1)), rel=0.05)
    c.advance(1024)
    assert c.measured_force == pytest.approx(10.0, rel=1e-3)
    assert c.measured_displacement == pytest.approx(5.0, rel=1e-3)


def test_force_loop_under_ramp_hold_commands_never_passes_its_targets():
    """The force loop (first order on k0) driven by the ramp-hold force profile of the command
    generator: in every controller period the specimen's force stays within the targets, so force
    commands below the cracking force leave a brittle specimen uncracked (docs/force_control.md,
    "hsio study mixed"). Steps of nearly 2 F_cr, each target held for a few steps so that the
    force settles on it."""
    infill = CrackingInfill()  # k0 = 122.6 kN/mm, F_cr = 60 kN
    c = ServoController(infill, ServoConfig(**QUIET))
    c.set_mode(ControlMode.FORCE)
    generator = PredictorCorrector(t_d=0.05, period=1 / 1024, hold_fraction=0.5)  # TR 10, dt 0.005 s
    top = 0.999 * infill.F_cr
    peak, off_line = 0.0, 0.0
    for target in [top] * 4 + [-top] * 4 + [0.5 * top, top, top, top, 0.0, -top, -top, -top]:
        generator.new_target(target)
        for _ in range(generator.samples_per_step):
            c.set_command(generator.next_sample())
            c.step()
            peak = max(peak, abs(c.force))
            off_line = max(off_line, abs(c.force - infill.k0 * c.d_spec))
    assert peak > 0.99 * top  # the force reached the targets
    assert peak <= top * (1 + 1e-12)
    assert off_line < 1e-9  # never cracked: the force stayed on the k0 line


def test_mode_switch_is_bumpless():
    c = ServoController(Linear(2.0), ServoConfig(**QUIET))
    c.set_command(3.0)
    c.advance(1024)
    before = c.d_rod
    c.set_mode(ControlMode.FORCE)
    assert c.command == pytest.approx(c.measured_force)
    c.advance(10)
    assert c.d_rod == pytest.approx(before, abs=1e-6)


def test_actuator_refuses_commands_beyond_limits_without_sending():
    clock = LockstepClock()
    act = open_url("emulator://?noise_mm=0", validation().experimental[:1], clock)[0]
    act.command(5.0)
    clock.tick()
    with pytest.raises(LimitError, match="beyond the stroke"):
        act.command(200.0)
    assert act.controller.command == 5.0
    with pytest.raises(LimitError, match="not a finite"):
        act.command(float("nan"))
    act.set_mode(ControlMode.FORCE)
    with pytest.raises(LimitError, match="capacity"):
        act.command(1000.0)


def test_tripped_actuator_raises_interlock_error():
    clock = LockstepClock()
    ctrl = ServoController(Linear(1.0), ServoConfig(force_limit_kN=5.0, **QUIET))
    act = EmulatedActuator("a", ctrl, clock)
    act.command(10.0)  # 10 kN on a 1 kN/mm specimen: beyond the capacity
    for _ in range(2048):
        clock.tick()
    with pytest.raises(InterlockError, match="capacity"):
        act.command(0.0)


def test_trip_message_shows_the_measurement_beyond_the_limit():
    """A reading just past the capacity is shown with the digits that put it beyond it."""
    ctrl = ServoController(Linear(1.0), ServoConfig(force_limit_kN=5.0, **QUIET))
    ctrl.measured_force = 5.00004
    ctrl._check_interlocks()
    assert ctrl.tripped == "force 5.00004 kN beyond the capacity (+/-5.000 kN)"


def test_unknown_emulator_setting_is_named():
    with pytest.raises(ConfigError, match="lagg"):
        ServoConfig.from_dict({"lagg": 0.02})
    with pytest.raises(ConfigError, match="lag_s"):
        ServoConfig(lag_s=-1.0)


def test_actuator_reads_as_a_daq_with_named_channels_and_units():
    clock = LockstepClock()
    act = open_url("emulator://?noise_mm=0&resolution_mm=0", validation().experimental[:1], clock)[0]
    assert [(c.name, c.unit) for c in act.channels] == [("C1.displacement", "mm"), ("C1.force", "kN")]
    act.command(2.0)
    for _ in range(1024):
        clock.tick()
    reading = act.read()
    assert reading["C1.displacement"] == pytest.approx(2.0, abs=1e-3)
    assert reading["C1.force"] == pytest.approx(2.0 * 0.613, abs=0.01)
