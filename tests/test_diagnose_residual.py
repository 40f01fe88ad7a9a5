"""What the actuator model cannot explain: effects outside the library hidden in emulator records
(a mains hum on the transducer, a slow drift that is not a straight line, a lightly damped mode)
must come out as `unexplained` or as the new effect that fits, never as a wrong library cause,
with their signature; the four new effects hidden alone are named with their parameter."""

import dataclasses
import json

import numpy as np
import pytest

from hsio.emulators.servo import ServoConfig
from hsio.diagnose.selection import NONE, UNEXPLAINED, diagnose
from hsio.diagnose.synth import chirp_command, emulate, seismic_command

RATE_HZ = 500.0
DURATION_S = 10.0
LAG_S = 0.020


@pytest.fixture(scope="module")
def commands():
    return {"seismic": seismic_command(DURATION_S, RATE_HZ, peak_mm=20.0, seed=11),
            "chirp": chirp_command(DURATION_S, RATE_HZ, amplitude_mm=5.0, f0_hz=0.2, f1_hz=4.0)}


def _record(command, seed=5, **settings):
    config = ServoConfig(rate_hz=RATE_HZ, lag_s=LAG_S, noise_mm=0.01, resolution_mm=0.025, seed=seed, **settings)
    return emulate(command, config)


def test_hum_on_the_transducer_is_unexplained_with_its_line(commands):
    record = _record(commands["seismic"])
    t = record.time_s
    hummed = dataclasses.replace(record, measured_mm=record.measured_mm + 0.04 * np.sin(2 * np.pi * 50.0 * t + 0.4))
    d = diagnose(hummed)
    assert d.cause == UNEXPLAINED, [(c.cause, round(c.choose_gain, 3)) for c in d.candidates]
    residual = d.to_json()["residual"]
    assert residual["rms_test_mm"] > 1.5 * residual["sensor_floor_mm"]
    assert residual["lines_hz"] and residual["lines_hz"][0] == pytest.approx(50.0, rel=0.05)
    assert residual["lines"][0]["amplitude_mm"] == pytest.approx(0.04, rel=0.3)
    assert "50.0" in residual["remains"] or "49.9" in residual["remains"] or "50.1" in residual["remains"]


def test_a_faint_hum_still_shows_as_a_line(commands):
    """A 60 Hz hum of 0.02 mm barely lifts the RMS above the floor, yet its line stands out."""
    record = _record(commands["chirp"], seed=8)
    t = record.time_s
    d = diagnose(dataclasses.replace(record, measured_mm=record.measured_mm + 0.02 * np.sin(2 * np.pi * 60.0 * t)))
    assert d.cause == UNEXPLAINED
    assert d.to_json()["residual"]["lines_hz"][0] == pytest.approx(60.0, rel=0.05)


def test_nothing_hidden_reaches_the_floor(commands):
    d = diagnose(_record(commands["chirp"]))
    assert d.cause == NONE
    residual = json.loads(json.dumps(d.to_json()))["residual"]  # --json prints it
    assert residual["explained"] and residual["lines_hz"] == []
    # The floor is measured from the data: 0.01 mm noise with 0.025 mm steps is about 0.012 mm.
    assert 0.009 < residual["sensor_floor_mm"] < 0.02
    assert residual["quantisation_mm"] == pytest.approx(0.025, rel=0.01)


def test_a_bent_drift_is_the_drift_or_unexplained_never_another_cause(commands):
    record = _record(commands["chirp"])
    t = record.time_s
    bent = 0.15 * (t / t[-1]) ** 2  # a drift that accelerates (warming electronics)
    d = diagnose(dataclasses.replace(record, measured_mm=record.measured_mm + bent))
    assert d.cause in ("sensor_drift", UNEXPLAINED)
    if d.cause == "sensor_drift":
        assert d.single.fit.params["sensor_drift_mm_s"] > 0


def test_a_resonance_is_the_servo_mode_not_a_delay(commands):
    d = diagnose(_record(commands["chirp"], servo_frequency_hz=9.0, servo_damping=0.08))
    assert d.cause in ("servo_dynamics", UNEXPLAINED), [(c.cause, round(c.choose_gain, 3)) for c in d.candidates]
    assert d.cause == "servo_dynamics"
    assert d.single.fit.params["servo_frequency_hz"] == pytest.approx(9.0, rel=0.05)


NEW = {  # effect -> (command, emulator settings, parameter, value)
    "servo_dynamics": ("seismic", {"servo_frequency_hz": 12.0, "servo_damping": 0.15}, "servo_frequency_hz", 12.0),
    "sensor_drift": ("seismic", {"sensor_drift_mm_s": 0.008}, "sensor_drift_mm_s", 0.008),
    "dead_band": ("chirp", {"dead_band_mm": 0.08}, "dead_band_mm", 0.08),
}


@pytest.mark.parametrize("effect", sorted(NEW))
def test_new_effect_is_named_and_measured(commands, effect):
    kind, settings, key, value = NEW[effect]
    d = diagnose(_record(commands[kind], **settings))
    assert d.cause == effect, [(c.cause, round(c.choose_gain, 3)) for c in d.candidates]
    assert d.single.fit.params[key] == pytest.approx(value, rel=0.20)
    assert d.single.fit.params["lag_s"] == pytest.approx(LAG_S, rel=0.20)
    assert d.single.gain > 1.0
    if effect == "sensor_drift":  # the signature: the baseline's residual trends at the drift rate
        assert d.to_json()["residual"]["trend_mm_per_s"] == pytest.approx(value, rel=0.20)


@pytest.mark.parametrize("kind", ["seismic", "chirp"])
def test_a_noise_free_record_of_the_lag_answers_none_and_a_hidden_effect_is_still_named(commands, kind):
    """Without noise or quantisation the baseline replays the emulator to its fit's convergence (1e-9 mm): no
    candidate may be named on gains between rounding errors (a transport delay of 1e-17 s), and
    the floor is the arithmetic's, not zero (a floor of zero leaves every residual 'unexplained'). An effect
    hidden in the same noise-free record leaves a real error and is still named."""
    quiet = {"noise_mm": 0.0, "resolution_mm": 0.0}
    d = diagnose(emulate(commands[kind], ServoConfig(rate_hz=RATE_HZ, lag_s=LAG_S, **quiet)))
    assert d.cause == NONE, [(c.cause, c.choose_gain) for c in d.candidates if c.named]
    floor = d.to_json()["residual"]["sensor_floor_mm"]
    assert 0 < floor < 1e-6 and d.baseline.rms_test_mm < floor
    d = diagnose(emulate(commands[kind], ServoConfig(rate_hz=RATE_HZ, lag_s=LAG_S, backlash_mm=0.2, **quiet)))
    assert d.cause == "backlash" and d.single.fit.params["backlash_mm"] == pytest.approx(0.2, rel=0.01)
