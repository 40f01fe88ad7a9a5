"""Records sampled slower than the servo loop runs (a DAQ at 200, 100 or 50 Hz beside a 1000 Hz
controller): with --controller-rate the model steps at the loop's rate and is compared at the
record's samples (hsio/diagnose/loop_rate.py); without it, such a record names no cause."""

import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner

from hsio.commands.diagnose import diagnose as diagnose_command
from hsio.diagnose.loop_rate import SLOW, predict
from hsio.diagnose.model import simulate
from hsio.diagnose.readers import write_csv
from hsio.diagnose.record import ActuatorRecord
from hsio.diagnose.selection import NONE, diagnose
from hsio.diagnose.synth import chirp_command, emulate, seismic_command
from hsio.emulators.servo import ServoConfig
from hsio.errors import RecordError

LOOP_HZ = 1000.0
DURATION_S = 12.0
LAG_S = 0.020
COMMANDS = {
    "seismic": lambda: seismic_command(DURATION_S, LOOP_HZ, peak_mm=20.0),
    "chirp": lambda: chirp_command(DURATION_S, LOOP_HZ, amplitude_mm=5.0, f0_hz=0.2, f1_hz=4.0),
}
# A delay of 8 ms, a 3 % transducer gain and 0.2 mm of slop, hidden in the emulator.
HIDDEN = {"transport_delay": ("transport_delay_s", 0.008), "scale_error": ("displacement_gain", 1.03),
          "backlash": ("backlash_mm", 0.2)}
SLOW_SEEDS = (5, 9)


@pytest.fixture(scope="module")
def commands():
    return {name: make() for name, make in COMMANDS.items()}


def _loop_record(command, seed=3, **settings) -> ActuatorRecord:
    """The emulator's 1000 Hz loop, with sensor noise and 0.025 mm quantisation."""
    return emulate(command, ServoConfig(rate_hz=LOOP_HZ, lag_s=LAG_S, noise_mm=0.01, resolution_mm=0.025, seed=seed,
                                        **settings))


def _daq(record: ActuatorRecord, rate_hz: float) -> ActuatorRecord:
    """Every (1000 / rate_hz)-th sample of the loop's record: a DAQ at ``rate_hz`` beside it."""
    every = int(round(LOOP_HZ / rate_hz))
    s = slice(0, None, every)
    return ActuatorRecord(f"daq {rate_hz:g} Hz", record.dt * every, record.command_mm[s], record.measured_mm[s],
                          record.force_kN[s])


def test_the_loop_rate_model_read_at_the_samples_is_the_full_rate_model():
    """A cubic command is what its samples' spline gives back exactly, so the model stepped at
    1000 Hz from 50 Hz samples must equal the model run on the 1000 Hz command, read every 20th
    period; with a hidden delay, mode, backlash and compliance."""
    t = np.arange(2001) / LOOP_HZ
    command = 3.0 * t - 4.0 * t**2 + 1.2 * t**3
    force = 2.0 * command
    params = {"lag_s": 0.02, "transport_delay_s": 0.006, "servo_frequency_hz": 12.0, "servo_damping": 0.3,
              "backlash_mm": 0.05, "compliance_mm_per_kN": 0.01}
    full = simulate(command, 1.0 / LOOP_HZ, params, force)
    daq = ActuatorRecord("cubic", 20 / LOOP_HZ, command[::20], command[::20], force[::20], controller_dt=1.0 / LOOP_HZ)
    assert np.max(np.abs(predict(daq, params) - full[::20])) < 1e-9
    assert np.max(np.abs(predict(daq, params, 40) - full[:800:20])) < 1e-9
    # Stepped at the record's rate instead (a 20 ms loop period), the model is another one.
    assert np.max(np.abs(predict(dataclasses.replace(daq, controller_dt=None), params) - full[::20])) > 1e-3


@pytest.mark.parametrize("seed", [3] + [pytest.param(s, marks=pytest.mark.slow) for s in SLOW_SEEDS])
@pytest.mark.parametrize("rate_hz", [200.0, 100.0, 50.0])
@pytest.mark.parametrize("kind", sorted(COMMANDS))
def test_nothing_hidden_answers_none_at_the_loop_rate(commands, kind, rate_hz, seed):
    d = diagnose(_daq(_loop_record(commands[kind], seed), rate_hz), controller_rate_hz=LOOP_HZ)
    assert d.cause == NONE, [(c.cause, round(c.choose_gain, 3)) for c in d.candidates]
    assert d.baseline.params["lag_s"] == pytest.approx(LAG_S, rel=0.02)
    assert d.to_json()["controller_rate_hz"] == LOOP_HZ


def _effect_cases():
    for rate in (200.0, 100.0, 50.0):
        for kind in sorted(COMMANDS):
            for effect in sorted(HIDDEN):
                marks = () if rate == 100.0 or (rate == 50.0 and kind == "chirp") else (pytest.mark.slow,)
                yield pytest.param(kind, rate, effect, marks=marks)


@pytest.mark.parametrize("kind, rate_hz, effect", list(_effect_cases()))
def test_a_hidden_effect_is_named_and_measured_at_the_loop_rate(commands, kind, rate_hz, effect):
    setting, value = HIDDEN[effect]
    d = diagnose(_daq(_loop_record(commands[kind], **{setting: value}), rate_hz), controller_rate_hz=LOOP_HZ)
    assert d.cause == effect, [(c.cause, round(c.choose_gain, 3)) for c in d.candidates]
    assert d.single.fit.params[setting] == pytest.approx(value, rel=0.10)
    assert d.single.fit.params["lag_s"] == pytest.approx(LAG_S, rel=0.05)


def test_a_slow_record_without_the_loop_rate_names_no_cause(commands):
    """A 100 Hz DAQ beside the loop, an 8 ms delay hidden: taken as the loop's rate the record is
    misread, so diagnose says why it names nothing; given the record's own rate as the loop's,
    it judges the record at that rate."""
    record = _daq(_loop_record(commands["chirp"], transport_delay_s=0.008), 100.0)
    d = diagnose(record)
    assert d.cause == SLOW and not any(c.named for c in d.candidates) and d.extended is d.baseline
    assert "--controller-rate" in d.to_json()["slow_record"] and "100 Hz" in d.slow_record
    assert diagnose(record, controller_rate_hz=100.0).cause not in (SLOW, NONE)


def test_a_record_at_the_loop_rate_reads_the_same_with_or_without_it(commands):
    record = _loop_record(commands["chirp"][:4000], transport_delay_s=0.008)
    a, b = diagnose(record), diagnose(record, controller_rate_hz=LOOP_HZ)
    assert a.cause == b.cause == "transport_delay"
    assert a.extended.params == b.extended.params
    assert np.array_equal(a.extended.prediction, b.extended.prediction)


def test_a_run_record_keeps_its_own_controller_rate(commands):
    record = dataclasses.replace(_loop_record(commands["chirp"][:3000]), controller_dt=1.0 / LOOP_HZ)
    with pytest.raises(RecordError, match="holds every period of its controller at 1000 Hz"):
        diagnose(record, controller_rate_hz=2000.0)


@pytest.fixture(scope="module")
def daq_csv(tmp_path_factory, commands):
    record = _daq(_loop_record(commands["chirp"]), 100.0)
    return write_csv(record, tmp_path_factory.mktemp("daq") / "daq 100 Hz.csv")


@pytest.mark.parametrize("value, message", [
    ("0", "must be a positive number of hertz"),
    ("-1000", "must be a positive number of hertz"),
    ("nan", "must be a positive number of hertz"),
    ("inf", "must be a positive number of hertz"),
    ("50", "--controller-rate 50 Hz is below the record's rate (100 Hz"),
    ("1e9", "controller periods, more than the"),
])
def test_a_bad_controller_rate_exits_2_with_a_message(daq_csv, value, message):
    result = CliRunner().invoke(diagnose_command, [str(daq_csv), "--controller-rate", value])
    assert result.exit_code == 2, result.output
    assert message in result.stderr and "Traceback" not in result.output


def test_the_command_reads_the_controller_rate(daq_csv):
    result = CliRunner().invoke(diagnose_command, [str(daq_csv), "--controller-rate", "1000", "--json"])
    assert result.exit_code == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["cause"] == NONE and out["controller_rate_hz"] == 1000.0 and out["rate_hz"] == pytest.approx(100.0)
    summary = CliRunner().invoke(diagnose_command, [str(daq_csv)])
    assert summary.exit_code == 0 and "cause       slow_record (the record is sampled at 100 Hz" in summary.stdout
    specimen = CliRunner().invoke(diagnose_command, ["--specimen", str(daq_csv), "--controller-rate", "1000"])
    assert specimen.exit_code == 2 and "--controller-rate: not read for --specimen" in specimen.stderr


@pytest.mark.parametrize("rate_hz, hidden", [(300.0, {}), (128.0, {"transport_delay_s": 0.008})])
def test_a_daq_off_the_loops_periods_is_read_between_them(commands, rate_hz, hidden):
    """A DAQ whose samples fall between the loop's periods (300 or 128 Hz beside 1000 Hz, its
    channels read between periods by linear interpolation): the prediction is read there too."""
    loop = _loop_record(commands["seismic"], **hidden)
    k, periods = np.arange(0.0, loop.n - 1, LOOP_HZ / rate_hz), np.arange(loop.n)
    record = ActuatorRecord("daq", 1.0 / rate_hz, *(np.interp(k, periods, x) for x in
                                                    (loop.command_mm, loop.measured_mm, loop.force_kN)))
    d = diagnose(record, controller_rate_hz=LOOP_HZ)
    if not hidden:
        assert d.cause == NONE, [(c.cause, round(c.choose_gain, 3)) for c in d.candidates]
    else:
        assert d.cause == "transport_delay" and d.single.fit.params["transport_delay_s"] == pytest.approx(0.008, rel=0.1)
