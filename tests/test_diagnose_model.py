"""The diagnose model replays the emulator sample by sample, and each emulator effect does what
its name says (hsio.emulators.servo.ServoController driven directly, noise off)."""

import math

import numpy as np
import pytest

from hsio.emulators.servo import ServoConfig, ServoController
from hsio.diagnose.model import simulate
from hsio.diagnose.synth import emulate, seismic_command
from hsio.specimens import Linear

RATE = 1024.0
QUIET = dict(rate_hz=RATE, noise_mm=0.0, resolution_mm=0.0, force_noise_kN=0.0, force_resolution_kN=0.0)


@pytest.mark.parametrize("settings", [
    {}, {"transport_delay_s": 8 / RATE}, {"velocity_threshold_mm_s": 5.0}, {"velocity_limit_mm_s": 80.0},
    {"backlash_mm": 0.2}, {"lag_retract_s": 0.03}, {"displacement_gain": 1.03}, {"compliance_mm_per_kN": 0.01},
    {"transport_delay_s": 4 / RATE, "lag_retract_s": 0.025, "backlash_mm": 0.1, "velocity_limit_mm_s": 120.0},
    {"dead_band_mm": 0.05}, {"servo_frequency_hz": 12.0, "servo_damping": 0.15}, {"sensor_drift_mm_s": 0.01},
    {"channel_skew_s": 4.3 / RATE}, {"channel_skew_s": 0.6 / RATE},
    {"dead_band_mm": 0.03, "servo_frequency_hz": 20.0, "servo_damping": 0.3, "channel_skew_s": 2 / RATE},
])
def test_model_replays_the_emulator(settings):
    command = seismic_command(6.0, RATE, peak_mm=15.0)
    record = emulate(command, ServoConfig(lag_s=0.02, **QUIET, **settings))
    predicted = simulate(record.command_mm, record.dt, {"lag_s": 0.02, **settings}, record.force_kN)
    assert np.max(np.abs(predicted - record.measured_mm)) < 1e-5


def _drive(config, command, specimen=None):
    c = ServoController(specimen or Linear(1.0), config)
    out = []
    for value in command:
        c.set_command(value)
        c.step()
        out.append((c.measured_displacement, c.d_rod, c.measured_force))
    return np.array(out)


def test_transport_delay_is_a_pure_delay():
    n_delay = 10
    step = np.r_[np.zeros(20), np.ones(200)]
    x = _drive(ServoConfig(lag_s=0.02, transport_delay_s=n_delay / RATE, **QUIET), step)[:, 0]
    first = int(np.flatnonzero(x > 0)[0])
    assert first == 20 + n_delay


def test_velocity_threshold_is_the_hockey_stick():
    lag, a = 0.02, 5.0
    for v in (3.0, 20.0, 60.0):
        ramp = v * np.arange(2048) / RATE
        x = _drive(ServoConfig(lag_s=lag, velocity_threshold_mm_s=a, **QUIET), ramp)[:, 0]
        error = ramp[-1] - x[-1]
        # E&M 2007, eq. (1) with b d_max = lag, between a command and the measurement after it.
        assert error == pytest.approx(lag * max(v - a, 0.0), abs=1e-6)


def test_velocity_saturation_caps_the_speed():
    x = _drive(ServoConfig(lag_s=0.02, velocity_limit_mm_s=50.0, **QUIET), np.full(1024, 20.0))[:, 0]
    speed = np.diff(x) * RATE
    assert speed.max() == pytest.approx(50.0, rel=1e-9)
    assert x[-1] == pytest.approx(20.0, abs=0.01)


def test_backlash_is_a_gap_taken_up_at_each_reversal():
    gap = 0.3
    up = 10.0 * np.arange(1024) / RATE
    path = np.r_[up, up[::-1]]
    out = _drive(ServoConfig(lag_s=0.02, backlash_mm=gap, **QUIET), path)
    measured, rod = out[:, 0], out[:, 1]
    assert rod[1000] - measured[1000] == pytest.approx(gap / 2, abs=1e-9)  # pushing: trailing by half the gap
    assert rod[-30] - measured[-30] == pytest.approx(-gap / 2, abs=1e-9)  # pulling: the other side
    reversal = int(np.argmax(measured))
    stall = np.ptp(measured[reversal: reversal + 20])
    assert stall < 1e-9 and np.ptp(rod[reversal: reversal + 20]) > 0.01  # the rod crosses the gap, the specimen waits


def test_asymmetric_lag_retracts_slower():
    def time_constant(target, retract):
        x = _drive(ServoConfig(lag_s=0.02, lag_retract_s=retract, **QUIET), np.full(512, target))[:, 0]
        return (np.flatnonzero(np.abs(x) >= (1 - math.exp(-1)) * abs(target))[0] + 1) / RATE

    assert time_constant(1.0, 0.04) == pytest.approx(0.02, abs=2 / RATE)
    assert time_constant(-1.0, 0.04) == pytest.approx(0.04, abs=2 / RATE)


def test_force_coupling_and_scale_error_act_on_the_measurement():
    hold = np.full(2048, 10.0)
    out = _drive(ServoConfig(lag_s=0.02, compliance_mm_per_kN=0.05, **QUIET), hold, Linear(2.0))
    measured, rod, force = out[-1]
    assert measured == pytest.approx(rod - 0.05 * force, rel=1e-6)
    assert measured == pytest.approx(10.0 / (1 + 0.05 * 2.0), rel=1e-4)  # the spring pushes the load train back
    out = _drive(ServoConfig(lag_s=0.02, displacement_gain=1.03, **QUIET), hold)
    assert out[-1, 0] == pytest.approx(1.03 * out[-1, 1], rel=1e-9)


def test_a_linear_spring_behind_the_compliance_stands_at_x_over_1_plus_ck_every_period():
    """The load train shortens under the force it carries in the same period: behind a rod at x,
    a linear spring k stands at d = x / (1 + c k), while the rod moves as well as at rest (with
    the force of the period before it would be off by c k (F_k - F_{k-1}) while moving)."""
    c, k = 0.02, 2.5
    command = seismic_command(3.0, RATE, peak_mm=15.0)
    controller = ServoController(Linear(k), ServoConfig(lag_s=0.02, compliance_mm_per_kN=c, **QUIET))
    spec, rod = [], []
    for value in command:
        controller.set_command(value)
        controller.step()
        spec.append(controller.d_spec)
        rod.append(controller.d_rod)
    spec, rod = np.array(spec), np.array(rod)
    assert np.ptp(rod) > 10.0 and np.max(np.abs(np.diff(rod))) > 0.05  # it moved, and fast
    assert np.max(np.abs(spec - rod / (1.0 + c * k))) < 1e-12


def test_a_nonlinear_spring_behind_the_compliance_is_solved_every_period():
    """A stiffening spring (a gap that closes): d + c F(d) = x holds in every period, and the
    force read is the specimen's at d."""
    from hsio.specimens import BilinearGap

    c = 0.05
    specimen = BilinearGap(k1=0.5, k2=4.0, gap=2.0)
    controller = ServoController(specimen, ServoConfig(lag_s=0.02, compliance_mm_per_kN=c, **QUIET))
    worst = 0.0
    for value in seismic_command(3.0, RATE, peak_mm=15.0):
        controller.set_command(value)
        controller.step()
        d, F = controller.d_spec, controller.force
        worst = max(worst, abs(d + c * F - controller.d_rod))
        assert F == pytest.approx(specimen.trial(d), abs=1e-12)
    assert worst < 1e-9


@pytest.mark.parametrize("frequency_hz, damping, rate_hz", [
    (12.0, 0.15, 1024.0), (20.0, 0.3, 500.0), (3.0, 0.7, 200.0), (60.0, 0.05, 1000.0)])
def test_the_mode_filter_is_the_emulators(frequency_hz, damping, rate_hz):
    """diagnose's closed-form bilinear transform of the servo mode and the emulator's
    (scipy.signal.bilinear) give the same coefficients, and unit gain at rest."""
    from hsio.diagnose.model import mode_filter
    from hsio.emulators.servo import servo_mode_filter

    b, a = mode_filter(frequency_hz, damping, 1.0 / rate_hz)
    b_emulator, a_emulator = servo_mode_filter(frequency_hz, damping, rate_hz)
    np.testing.assert_allclose(b, b_emulator, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(a, a_emulator, rtol=1e-12, atol=1e-15)
    assert sum(b) / sum(a) == pytest.approx(1.0, rel=1e-12)
