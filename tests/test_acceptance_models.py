"""The model-facing features on data, seeds and setups of their own: records with a known truth
(other rates, lags, seeds and magnitudes than the feature tests), odd records refused with exit 2
and a message (never a traceback), the hockey-stick fit when only the fastest steps pass the
threshold, and the calibration's refusals and warnings."""

import numpy as np
import pytest
from click.testing import CliRunner

from hsio.commands.calibrate import calibrate
from hsio.commands.diagnose import diagnose
from hsio.compensation import hockey_stick
from hsio.diagnose import readers
from hsio.diagnose.selection import diagnose as run_diagnosis
from hsio.diagnose.specimen_fit import NONE, diagnose_specimen
from hsio.diagnose.specimen_record import SpecimenRecord
from hsio.diagnose.synth import chirp_command, emulate, emulate_specimen
from hsio.emulators.servo import ServoConfig
from hsio.specimens import Diagnosed


def _csv(path, header, rows):
    path.write_text(header + "\n" + "".join(",".join(repr(float(x)) for x in row) + "\n" for row in rows))
    return path


def _sine(n=2000, rate=500.0):
    t = np.arange(n) / rate
    return t, 5.0 * np.sin(2 * np.pi * t)


def _refused(command, args, *words):
    result = CliRunner().invoke(command, [str(a) for a in args])
    assert result.exit_code == 2, (result.output, result.exception)
    for word in words:
        assert word in result.output, result.output
    return result.output


# -- known truth at another rate, lag, seed and magnitude ---------------------------------------------

@pytest.mark.parametrize("setting, value", [("backlash_mm", 0.35), ("lag_retract_s", 0.018),
                                            ("dead_band_mm", 0.08), ("transport_delay_s", 0.012)])
def test_effect_hidden_at_500_hz_with_a_30_ms_lag_is_named_and_measured(setting, value):
    command = chirp_command(15.0, 500.0, amplitude_mm=3.0, f0_hz=0.1, f1_hz=6.0)
    record = emulate(command, ServoConfig(rate_hz=500.0, lag_s=0.03, noise_mm=0.01, resolution_mm=0.02, seed=11,
                                          **{setting: value}))
    d = run_diagnosis(record)
    cause = {"backlash_mm": "backlash", "lag_retract_s": "asymmetric_lag", "dead_band_mm": "dead_band",
             "transport_delay_s": "transport_delay"}[setting]
    assert d.cause == cause
    assert d.single.fit.params[setting] == pytest.approx(value, rel=0.05)
    assert d.single.fit.params["lag_s"] == pytest.approx(0.03, rel=0.05)
    assert d.gain > 2.0  # on the scoring block


# -- odd actuator records: exit 2 and a message --------------------------------------------------------

def test_measured_channel_that_never_moves_is_refused(tmp_path):
    t, c = _sine()
    path = _csv(tmp_path / "dead.csv", "time_s,command_mm,measured_mm", zip(t, c, 0 * c))
    _refused(diagnose, [path], "dead.csv", "measured displacement does not move")


def test_values_no_transducer_reads_are_refused(tmp_path):
    t, c = _sine()
    path = _csv(tmp_path / "huge.csv", "time_s,command_mm,measured_mm", zip(t, 1e300 * c, 1e300 * c))
    _refused(diagnose, [path], "huge.csv", "command_mm sample 1", "beyond")


def test_a_time_column_not_in_seconds_is_refused(tmp_path):
    t, c = _sine()
    path = _csv(tmp_path / "ns.csv", "time_s,command_mm,measured_mm", zip(t * 1e-300, c, c))
    _refused(diagnose, [path], "ns.csv", "Hz", "seconds")


def test_a_step_command_is_diagnosed_without_a_traceback(tmp_path):
    t, _ = _sine()
    step = (t >= 0.2).astype(float)
    path = _csv(tmp_path / "step.csv", "time_s,command_mm,measured_mm", zip(t, step, np.r_[0.0, step[:-1]]))
    result = CliRunner().invoke(diagnose, [str(path)])
    assert result.exit_code == 0, result.exception
    assert "cause" in result.output


def test_a_record_file_larger_than_the_bound_is_refused(tmp_path, monkeypatch):
    t, c = _sine()
    path = _csv(tmp_path / "long.csv", "time_s,command_mm,measured_mm", zip(t, c, c))
    monkeypatch.setattr(readers, "MAX_FILE_BYTES", 1000)
    _refused(diagnose, [path], "long.csv", "more than 1000 bytes")
    daq = tmp_path / "long.txt"
    daq.write_text("Header Size: 3\nSampling Interval: 0.001\nSample Number, Date/Time, CHANNEL0, CHANNEL1, CHANNEL2\n"
                   + "".join(f"{i},x,{v},{v},{v}\n" for i, v in enumerate(c)))
    _refused(diagnose, [daq], "long.txt", "more than 1000 bytes")


# -- specimens -----------------------------------------------------------------------------------------

def test_a_load_cell_that_reads_nothing_is_refused(tmp_path):
    t, u = _sine(rate=250.0)
    path = _csv(tmp_path / "s.csv", "time_s,displacement_mm,force_kN", zip(t, u, 0 * u))
    _refused(diagnose, ["--specimen", path], "s.csv", "force does not change")
    path = _csv(tmp_path / "ns.csv", "time_s,displacement_mm,force_kN", zip(t * 1e-300, u, 2 * u))
    _refused(diagnose, ["--specimen", path], "ns.csv", "Hz")


def test_a_linear_spring_is_predicted_to_the_last_sample():
    # The record ends while moving at full speed: the low-pass's start-up transient must not
    # fall on its last samples (the scoring block), nor count as displacement noise.
    t, u = _sine(rate=250.0)
    d = diagnose_specimen(SpecimenRecord("spring", 1 / 250.0, u, 2.0 * u))
    assert d.baseline.params["k"] == pytest.approx(2.0, rel=1e-3)
    assert d.baseline.rms_test_kN < 0.005  # 10 kN peak; 0.09 kN with the transient
    assert d.sig.u_noise < 0.005


@pytest.mark.parametrize("seed", [13, 21])
def test_a_noisy_linear_spring_at_500_hz_answers_none(seed):
    sweep = chirp_command(12.0, 500.0, amplitude_mm=6.0, f0_hz=0.2, f1_hz=4.0)
    d = diagnose_specimen(emulate_specimen(Diagnosed(k=2.5, c=0.02), sweep, 500.0, seed=seed))
    assert d.cause == NONE, [(c.cause, round(c.choose_gain, 3)) for c in d.candidates]
    assert d.baseline.params["k"] == pytest.approx(2.5, rel=0.01)


def test_friction_hidden_at_500_hz_is_named_and_measured():
    sweep = chirp_command(12.0, 500.0, amplitude_mm=6.0, f0_hz=0.2, f1_hz=4.0)
    d = diagnose_specimen(emulate_specimen(Diagnosed(k=2.5, c=0.02, friction_kN=0.6, friction_v0_mm_s=4.0), sweep,
                                           500.0, seed=13))
    assert d.cause == "friction"
    assert d.single.fit.params["friction_kN"] == pytest.approx(0.6, rel=0.05)


# -- the hockey stick -------------------------------------------------------------------------------------

@pytest.mark.parametrize("seed", [1, 2, 17])
def test_a_threshold_only_the_fastest_steps_pass_is_found(seed):
    # a = 40 mm/s lies beyond the 95th percentile of |v| (24 mm/s for seed 1): a slow test.
    rng = np.random.default_rng(seed)
    d = np.convolve(np.cumsum(rng.normal(0.0, 1.0, 600)), np.ones(5) / 5, "same") * 1.5
    v = hockey_stick.step_velocity(d, 0.05)
    er = hockey_stick.error(v, 40.0, 4e-5) + rng.normal(0.0, 0.01 / 254, v.size)
    fit = hockey_stick.fit(v[2:], er[2:])
    assert fit.a_mm_s == pytest.approx(40.0, rel=0.05)
    assert fit.b_s_mm == pytest.approx(4e-5, rel=0.05)


def _steps(tmp_path, name, n, a=3.0, lag=0.03, t_d=0.05, seed=5):
    rng = np.random.default_rng(seed)
    c = np.cumsum(rng.normal(0.0, 1.0, n))
    v = hockey_stick.step_velocity(c, t_d)
    m = c - 254.0 * hockey_stick.error(v, a, lag / 254.0)
    return _csv(tmp_path / name, "time_s,command_mm,measured_mm", zip(np.arange(n) * t_d, c, m))


def test_calibrate_takes_a_short_csv_of_steps(tmp_path):
    result = CliRunner().invoke(calibrate, [str(_steps(tmp_path, "short.csv", 50)), "--json"])
    assert result.exit_code == 0, result.output
    assert '"lag_s": 0.03' in result.output


def test_calibrate_refuses_odd_sources(tmp_path):
    import sqlite3

    other = tmp_path / "other.sqlite"
    sqlite3.connect(other).execute("create table x (a)").connection.commit()
    _refused(calibrate, [other], "other.sqlite", "not an hsio recording")
    t, c = _sine()
    huge = _csv(tmp_path / "huge.csv", "time_s,command_mm,measured_mm", zip(t, 1e300 * c, c))
    _refused(calibrate, [huge], "huge.csv", "command_mm", "beyond")
    _refused(calibrate, [_steps(tmp_path, "s.csv", 50), "--t-d", "1e-9"], "t_d", "out of bounds")


def test_calibrate_warns_when_few_steps_pass_the_threshold(tmp_path):
    # Only the few fastest steps pass a = 25 mm/s: the slope is guessed, and said to be.
    rng = np.random.default_rng(3)
    t_d = 0.2
    c = np.cumsum(rng.normal(0.0, 1.5, 400))
    v = hockey_stick.step_velocity(c, t_d)
    m = c - 254.0 * hockey_stick.error(v, 25.0, 0.02 / 254.0) + rng.normal(0.0, 0.01, c.size)
    path = _csv(tmp_path / "slow.csv", "time_s,command_mm,measured_mm", zip(np.arange(c.size) * t_d, c, m))
    result = CliRunner().invoke(calibrate, [str(path)])
    assert result.exit_code == 0, result.output
    assert "poorly determined" in result.output
    fast = CliRunner().invoke(calibrate, [str(_steps(tmp_path, "fast.csv", 400))])
    assert fast.exit_code == 0 and "poorly determined" not in fast.output


# -- setups: another geometry against a hand computation, and refusals --------------------------------

def test_two_actuators_of_another_geometry_match_the_hand_computation():
    import math

    from hsio.setups.factory import make_setup

    L, h, ux, th = 1200.0, 350.0, 4.0, 0.003
    setup = make_setup({"kind": "two_actuators", "length_mm": L, "spacing_mm": h,
                        "factors": {"displacement": 2.0, "force": -4.0}}, 2)
    lower, upper = np.array([ux, 0.0]), np.array([ux - h * math.sin(th), h * math.cos(th)])  # pins at the pose
    strokes = [np.linalg.norm(lower - [-L, 0.0]) - L, np.linalg.norm(upper - [-L, h]) - L]
    d_model = np.array([2.0 * ux, th])  # the model's translation is twice the lab's; rotations are equal
    assert setup.strokes(d_model) == pytest.approx(strokes, abs=1e-9)
    assert setup.basic_displacements(np.array(strokes)) == pytest.approx(d_model, abs=1e-9)
    f = np.array([12.0, -5.0])
    e_l = (lower - [-L, 0.0]) / np.linalg.norm(lower - [-L, 0.0])
    e_u = (upper - [-L, h]) / np.linalg.norm(upper - [-L, h])
    fx = f[0] * e_l[0] + f[1] * e_u[0]
    arm = upper - lower
    moment = f[1] * float(arm[0] * e_u[1] - arm[1] * e_u[0])  # about the control point (2-D cross product)
    assert setup.basic_forces(f, d_model) == pytest.approx([-4.0 * fx, -4.0 * 2.0 * moment], rel=1e-9)


@pytest.mark.parametrize("table", [
    {"kind": "one_actuator", "length_mm": 800.0, "angle_deg": 90.0},
    {"kind": "one_actuator", "length_mm": 800.0, "angle_deg": 270.0},
    {"kind": "one_actuator", "length_mm": 800.0, "angle_deg": 89.9},
    {"kind": "inverted_v_brace", "leg_length_mm": 1000.0, "angle_deg": 1e-7},
])
def test_an_actuator_square_to_its_dof_is_refused(table):
    from hsio.errors import ConfigError
    from hsio.setups.factory import make_setup

    with pytest.raises(ConfigError, match="cannot move every basic DOF"):
        make_setup(table, 1 if table["kind"] == "one_actuator" else 2)
    assert make_setup({**table, "angle_deg": 60.0}, 1 if table["kind"] == "one_actuator" else 2)
