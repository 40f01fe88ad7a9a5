"""`hsio diagnose` on a CSV record from the emulator, and its refusal of bad input."""

import dataclasses
import json
import re
import subprocess
import sys

import pytest
from click.testing import CliRunner

from hsio.commands.diagnose import diagnose
from hsio.emulators.servo import ServoConfig
from hsio.diagnose.readers import write_csv
from hsio.diagnose.synth import chirp_command, emulate


def _diagnose(*args):
    return subprocess.run([sys.executable, "-m", "hsio.cli", "diagnose", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


def test_csv_without_force(tmp_path):
    record = emulate(chirp_command(8.0, 500.0, amplitude_mm=4.0, f1_hz=5.0),
                     ServoConfig(rate_hz=500.0, lag_s=0.03, backlash_mm=0.15))
    path = write_csv(dataclasses.replace(record, force_kN=None), tmp_path / "bench test.csv")
    proc = _diagnose(path, "--json", "--model", tmp_path / "m.toml")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert result["rate_hz"] == pytest.approx(500.0)
    assert result["cause"] == "backlash"
    assert "force_coupling" not in {c["cause"] for c in result["candidates"]}  # no force channel
    assert result["extended"]["params"]["backlash_mm"] == pytest.approx(0.15, rel=0.2)
    assert "backlash_mm = " in (tmp_path / "m.toml").read_text()
    summary = CliRunner().invoke(diagnose, [str(path)])  # the human-readable summary, in this process
    assert summary.exit_code == 0 and "cause       backlash" in summary.stdout


def test_bad_record_exits_with_the_line(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("time_s,command_mm,measured_mm\n0,0,0\n0.001,0.1\n")
    proc = _diagnose(path)
    assert proc.returncode == 2
    assert "bad.csv:3: expected 3 fields" in proc.stderr


def _strict(text):
    def refuse(constant):
        raise ValueError(f"{constant} is not JSON")
    return json.loads(text, parse_constant=refuse)


def test_json_of_a_delay_without_force_is_strict_json(tmp_path):
    """A delay names the timing block; with no force to time it, its counts and ratio are null,
    never NaN (which strict JSON readers refuse)."""
    record = emulate(chirp_command(8.0, 500.0, amplitude_mm=4.0, f1_hz=3.0),
                     ServoConfig(rate_hz=500.0, lag_s=0.02, transport_delay_s=0.006, noise_mm=0.01, resolution_mm=0.025))
    path = write_csv(dataclasses.replace(record, force_kN=None), tmp_path / "delay.csv")
    result = CliRunner().invoke(diagnose, [str(path), "--json", "--report", str(tmp_path / "r")])
    assert result.exit_code == 0, result.stderr
    out = _strict(result.stdout)
    assert out["cause"] == "transport_delay"
    assert out["timing"]["verdict"] == "undecided" and out["timing"]["reason"] == "the record has no force"
    assert out["timing"]["ratio"] is None and out["timing"]["violations_at_zero"] is None
    assert _strict((tmp_path / "r" / "diagnosis.json").read_text())["timing"]["ratio"] is None


@pytest.mark.parametrize("option, value", [("--train-fraction", "0.99"), ("--choose-fraction", "0.5")])
def test_a_fraction_out_of_bounds_names_its_option(tmp_path, option, value):
    record = emulate(chirp_command(2.0, 500.0, amplitude_mm=4.0, f1_hz=3.0), ServoConfig(rate_hz=500.0, lag_s=0.02))
    path = write_csv(record, tmp_path / "r.csv")
    result = CliRunner().invoke(diagnose, [str(path), option, value])
    assert result.exit_code == 2 and f"({option}) must be in" in result.output, result.output


@pytest.mark.parametrize("mistake, message", [
    ("swapped", "the measured displacement leads the command by 2"),  # by the lag's 24 ms of phase on this chirp
    ("reversed", "the measured displacement moves against the command (correlation -0.99"),
])
def test_a_measurement_that_cannot_follow_its_command_is_refused(tmp_path, mistake, message):
    """The two channels swapped (the measurement a lag ahead of its command) or one of them of the
    wrong sign: no effect of the library applies, and a fit would name one with an unphysical
    value (a compliance of -4 mm/kN, a lag at its 2 s bound); refused, naming the mistake."""
    record = emulate(chirp_command(6.0, 500.0, amplitude_mm=4.0, f1_hz=3.0), ServoConfig(rate_hz=500.0, lag_s=0.03))
    if mistake == "swapped":
        record = dataclasses.replace(record, command_mm=record.measured_mm, measured_mm=record.command_mm)
    else:
        record = dataclasses.replace(record, measured_mm=-record.measured_mm)
    path = write_csv(record, tmp_path / f"{mistake}.csv")
    result = CliRunner().invoke(diagnose, [str(path), "--json"])
    assert result.exit_code == 2 and message in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("args, message", [
    (["--measured-scale", "5"], "--measured-scale: not read for an actuator record in csv format"),
    (["--force-channel", "none"], "--force-channel: not read for an actuator record in csv format"),
    (["--displacement-scale", "3"], "--displacement-scale: not read for an actuator record in csv format"),
])
def test_an_option_the_record_does_not_read_is_refused_not_ignored(tmp_path, args, message):
    """A DAQ export's channel and scale options mean nothing to a CSV file: a scale typed for it
    would otherwise be ignored unseen, and the diagnosis reported as if it had been applied."""
    record = emulate(chirp_command(6.0, 500.0, amplitude_mm=4.0, f1_hz=3.0), ServoConfig(rate_hz=500.0, lag_s=0.03))
    path = write_csv(record, tmp_path / "r.csv")
    result = CliRunner().invoke(diagnose, [str(path), *args])
    assert result.exit_code == 2 and message in result.stderr, result.stderr
    result = CliRunner().invoke(diagnose, ["--run", str(tmp_path), "--margin", "1.2"])
    assert result.exit_code == 2 and "--margin: not read for --run" in result.stderr, result.stderr


def test_channels_swapped_on_a_slow_motion_are_refused(tmp_path):
    """On a slow chirp (0.2 to 1 Hz) the cross-correlation's peak is too flat to show the 20 ms
    lead of swapped channels; the lag fitted both ways round shows it: the command, read as the
    measurement, trails by the lag, and the measurement cannot lead its command."""
    record = emulate(chirp_command(8.0, 1000.0, amplitude_mm=2.0, f0_hz=0.2, f1_hz=1.0, rest_s=2.0),
                     ServoConfig(rate_hz=1000.0, seed=3))
    swapped = dataclasses.replace(record, command_mm=record.measured_mm, measured_mm=record.command_mm)
    result = CliRunner().invoke(diagnose, [str(write_csv(swapped, tmp_path / "swapped.csv")), "--json"])
    assert result.exit_code == 2 and "the command follows the measured displacement" in result.stderr, result.stderr
    assert "channels are swapped" in result.stderr and "Traceback" not in result.stderr
    result = CliRunner().invoke(diagnose, [str(write_csv(record, tmp_path / "right.csv")), "--json"])
    assert result.exit_code == 0, result.output  # the right way round is read


def test_one_daq_channel_for_command_and_measurement_is_refused(tmp_path):
    """A command channel given as the measurement too would be diagnosed as an actuator that
    follows perfectly (a velocity threshold with a gain of hundreds): refused, naming both roles."""
    path = tmp_path / "daq.txt"
    rows = [f"{k + 1}, 06/29/2022 04:05:36.674 PM, {0.1 * (k % 50) / 50:.4f}, 0.0, {0.1 * (k % 50) / 50:.4f}"
            for k in range(200)]
    path.write_text("Header Size:  7\nVersion:  2\nSampling Interval:  0.001\nSampling Rate:  1000\n"
                    "Sample Count:  200\nDevice Serial Number:  0\nSample Number, Date/Time, CHANNEL0, CHANNEL1, "
                    "CHANNEL2, Events\n" + "\n".join(rows) + "\n")
    result = CliRunner().invoke(diagnose, [str(path), "--measured-channel", "CHANNEL2"])
    assert result.exit_code == 2, result.output
    assert "daq.txt: the command and the measured displacement are both channel 'CHANNEL2'" in result.stderr


@pytest.mark.parametrize("factor", [0.1, 25.4])
def test_a_command_in_other_units_is_refused(tmp_path, factor):
    """A command column in V (at 10 mm/V) or in inches beside a measurement in mm: a scale_error
    would be named with its gain pinned at the bound of its range; refused, naming the units."""
    record = emulate(chirp_command(6.0, 500.0, amplitude_mm=4.0, f1_hz=3.0), ServoConfig(rate_hz=500.0, lag_s=0.03))
    record = dataclasses.replace(record, command_mm=record.command_mm * factor)
    result = CliRunner().invoke(diagnose, [str(write_csv(record, tmp_path / "units.csv")), "--json"])
    assert result.exit_code == 2, result.output
    moves = float(re.search(r"the measured displacement moves (\S+) times its command", result.stderr).group(1))
    assert moves == pytest.approx(1.0 / factor, rel=0.05) and "different units" in result.stderr


@pytest.mark.parametrize("factor", [1.0, 0.1])
def test_a_fast_record_behind_a_large_lag_is_not_taken_for_other_units(factor):
    """A sweep from 4 to 12 Hz through a first-order lag of 120 ms: the actuator moves 0.18 times
    as far as its command, 0.19 by least squares at the best shift, with no unit mistaken. Its
    gain is that of the command through the lag that follows it best, 1; the same record with
    the command in V at 10 mm/V is refused, 10 times."""
    import numpy as np

    from hsio.diagnose.selection import check_following
    from hsio.errors import RecordError

    record = emulate(chirp_command(8.0, 1000.0, amplitude_mm=3.0, f0_hz=4.0, f1_hz=12.0),
                     ServoConfig(rate_hz=1000.0, lag_s=0.12))
    assert np.std(record.measured_mm) < 0.2 * np.std(record.command_mm)
    record = dataclasses.replace(record, command_mm=record.command_mm * factor)
    n_train = record.command_mm.size * 6 // 10
    if factor == 1.0:
        check_following(record, n_train)
    else:
        with pytest.raises(RecordError, match="different units") as info:
            check_following(record, n_train)
        moves = float(re.search(r"moves (\S+) times its command", str(info.value)).group(1))
        assert moves == pytest.approx(10.0, rel=0.05)
