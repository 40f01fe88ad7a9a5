"""Records cut from a longer test: an actuator record that starts in motion is replayed from a
lead-in (the model enters it already tracking), and a record whose blocks are too short to tell
names no cause."""

import numpy as np
import pytest

from hsio.diagnose.model import simulate
from hsio.diagnose.record import ActuatorRecord
from hsio.diagnose.selection import NONE, UNEXPLAINED, diagnose
from hsio.diagnose.synth import chirp_command, emulate, seismic_command
from hsio.emulators.servo import ServoConfig

RATE_HZ = 1024.0
LAG_S = 0.02


@pytest.fixture(scope="module")
def full():
    command = seismic_command(8.0, RATE_HZ, peak_mm=20.0, seed=4)
    return emulate(command, ServoConfig(rate_hz=RATE_HZ, lag_s=LAG_S, noise_mm=0.01, resolution_mm=0.025, seed=1))


def _cut(full, a, n):
    return ActuatorRecord("cut", full.dt, full.command_mm[a:a + n], full.measured_mm[a:a + n], full.force_kN[a:a + n])


def test_the_model_enters_a_ramp_already_tracking_it():
    """A first-order lag tracking c = v t lags by lag v: a record that starts on the ramp is
    predicted from its first sample, with no start-up transient."""
    dt, v = 1.0 / RATE_HZ, 100.0
    c = 5.0 + v * dt * np.arange(500)
    m = simulate(c, dt, {"lag_s": LAG_S})
    # The loop sees the previous period's position: the lag between a command and the
    # measurement that follows it is lag_s (docs/diagnose.md, "The model").
    assert np.max(np.abs(m - (c - v * LAG_S))) < 1e-3  # 2 mm (lag v) from rest


def test_a_lag_cut_from_the_middle_of_a_test_answers_none(full):
    d = diagnose(_cut(full, 2000, 4000))
    assert d.cause == NONE, [(c.cause, round(c.choose_gain, 3)) for c in d.candidates]
    assert d.baseline.params["lag_s"] == pytest.approx(LAG_S, rel=0.05)
    assert d.too_short is None


def test_blocks_too_short_to_tell_name_no_cause(full):
    """400 samples (0.4 s) from the middle of the test: 80 samples per block, 4 lags each; a
    block needs 10 lags (205 samples), so 1025 samples would do."""
    d = diagnose(_cut(full, 5000, 400))
    assert d.cause == "too_few_samples", [(c.cause, round(c.choose_gain, 3)) for c in d.candidates]
    assert not any(c.named for c in d.candidates) and d.extended is d.baseline
    assert "too short to tell" in d.to_json()["too_short"]
    assert "too few samples to judge (400 < 10" in d.to_json()["too_short"]


@pytest.mark.parametrize("n", [100, 150, 200])
def test_a_few_samples_on_a_linear_spring_are_too_few_to_judge(n, tmp_path):
    """100 to 200 samples of an actuator on a linear spring, cut at several places: neither none
    nor unexplained (their blocks are too short to judge the floor) but too_few_samples, said
    as such in --json and report.md."""
    from hsio.diagnose.report import evidence, text
    from hsio.specimens.elastic import Linear

    record = emulate(seismic_command(8.0, RATE_HZ, peak_mm=20.0, seed=4),
                     ServoConfig(rate_hz=RATE_HZ, lag_s=LAG_S, noise_mm=0.01, resolution_mm=0.025, seed=1), Linear(k=2.0))
    for a in range(1000, 8000, 1500):
        d = diagnose(_cut(record, a, n))
        assert d.cause == "too_few_samples", (a, d.cause)
        assert f"too few samples to judge ({n} < " in d.to_json()["too_short"]
    assert "Cause: too_few_samples" in text(d, evidence(d))


def test_a_long_rest_at_the_end_judges_nothing():
    """An 8 ms delay hidden in 10 s of motion followed by 15 s of rest: the choosing and scoring
    blocks hold no motion, so nothing can be judged there (judged on the rest, the answer would be
    none, as if the lag explained the record)."""
    rate = 500.0
    motion = seismic_command(10.0, rate, peak_mm=15.0, seed=4)
    command = np.r_[motion, np.full(int(15.0 * rate), motion[-1])]
    record = emulate(command, ServoConfig(rate_hz=rate, lag_s=LAG_S, noise_mm=0.01, resolution_mm=0.025, seed=1,
                                          transport_delay_s=0.008))
    d = diagnose(record)
    assert d.cause == "too_few_samples" and d.gain == 1.0
    assert "block (samples 7500 to 10000) holds no motion" in d.too_short
    assert "cut the rest off the record" in d.to_json()["too_short"]
    # The motion alone names the delay.
    moving = ActuatorRecord("moving", record.dt, record.command_mm[:5000], record.measured_mm[:5000], record.force_kN[:5000])
    assert diagnose(moving).cause == "transport_delay"


@pytest.mark.parametrize("seed", [1, 2])
def test_a_quiet_end_that_still_moves_judges_nothing(seed):
    """An 8 ms delay hidden in a 10 mm chirp that is followed by a slow 0.3 mm sway (an
    earthquake's free-vibration tail): the held-out blocks move, but too slowly to show the
    delay, so the baseline meets the floor there while it misses the fitting block by ten floors.
    The answer is too_few_samples, not none; with nothing hidden the same command answers none."""
    n = int(6.0 * RATE_HZ)
    strong = chirp_command(3.6, RATE_HZ, amplitude_mm=10.0, f0_hz=0.5, f1_hz=3.0, rest_s=0.2)
    sway = 0.3 * np.sin(2 * np.pi * 0.4 * np.arange(n - strong.size) / RATE_HZ)
    command = np.r_[strong, sway]
    delayed = diagnose(emulate(command, ServoConfig(rate_hz=RATE_HZ, lag_s=LAG_S, transport_delay_s=0.008, seed=seed)),
                       effects=("transport_delay",))
    assert delayed.baseline.rms_train_mm > 5 * delayed.floor.sensor_floor_mm
    assert delayed.cause == "too_few_samples"
    assert "misses the fitting block" in delayed.to_json()["too_short"]
    clean = diagnose(emulate(command, ServoConfig(rate_hz=RATE_HZ, lag_s=LAG_S, seed=seed)), effects=("transport_delay",))
    assert clean.cause == NONE and clean.too_short is None
