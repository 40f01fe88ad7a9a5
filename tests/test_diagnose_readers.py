"""Readers of measured actuator records: CSV, the DAQ text export, hsio's own recordings; bad
input refused with the file and line."""

import math

import numpy as np
import pytest

from hsio.diagnose.readers import DaqChannels, read_csv, read_daq, read_record, read_run, write_csv
from hsio.diagnose.record import ActuatorRecord
from hsio.errors import RecordError

HEADER = "time_s,command_mm,measured_mm"


def _csv(tmp_path, rows, header=HEADER, name="r.csv"):
    path = tmp_path / name
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


def _rows(n=200, dt=0.001, force=False):
    out = []
    for k in range(n):
        c = math.sin(0.05 * k)
        out.append(f"{k * dt:.6f},{c:.6f},{0.9 * c:.6f}" + (f",{2 * c:.4f}" if force else ""))
    return out


def test_csv_round_trip_with_and_without_force(tmp_path):
    rec = read_csv(_csv(tmp_path, _rows(force=True), HEADER + ",force_kN"))
    assert rec.n == 200 and rec.dt == pytest.approx(0.001)
    assert rec.force_kN is not None and rec.force_kN[10] == pytest.approx(2 * math.sin(0.5), abs=1e-4)
    again = read_csv(write_csv(rec, tmp_path / "again.csv"))
    np.testing.assert_allclose(again.measured_mm, rec.measured_mm)
    assert read_csv(_csv(tmp_path, _rows(), name="nf.csv")).force_kN is None
    # Columns may come in any order.
    swapped = ["{1},{0},{2}".format(*r.split(",")) for r in _rows()]
    rec = read_csv(_csv(tmp_path, swapped, "command_mm,time_s,measured_mm", name="sw.csv"))
    assert rec.dt == pytest.approx(0.001)


@pytest.mark.parametrize("bad, line, words", [
    (lambda rows: rows[:50] + ["0.05,1.0"] + rows[51:], 52, "expected 3 fields"),
    (lambda rows: rows[:70] + ["0.07,nan,0.1"] + rows[71:], 72, "not finite"),
    (lambda rows: rows[:80] + ["0.08,abc,0.1"] + rows[81:], 82, "not a number"),
    (lambda rows: rows[:90] + rows[95:], 92, "gap"),
    (lambda rows: rows + ["end of test"], 202, "expected 3 fields"),
    (lambda rows: rows[:30] + [rows[29]] + rows[30:], 32, "repeated"),
    # a step of 0.0009 s in a 1 ms record: short, not repeated or backward
    (lambda rows: rows[:40] + ["0.0399,0.1,0.1"] + rows[41:], 42, r"a short step \(jitter"),
])
def test_csv_refuses_bad_rows_with_the_line(tmp_path, bad, line, words):
    path = _csv(tmp_path, bad(_rows()))
    with pytest.raises(RecordError, match=f"r.csv:{line}: .*{words}"):
        read_csv(path)


def test_csv_refuses_a_wrong_header(tmp_path):
    with pytest.raises(RecordError, match="r.csv:1: header must be"):
        read_csv(_csv(tmp_path, _rows(), "t,cmd,meas"))


DAQ_HEAD = ["Header Size:  7", "Version:  2", "Sampling Interval:  0.001", "Sampling Rate:  1000",
            "Sample Count:  {n}", "Device Serial Number:  0", "Sample Number, Date/Time, CHANNEL0, CHANNEL1, CHANNEL2, Events"]


def _daq(tmp_path, n=300, edit=None):
    rows = []
    for k in range(n):
        cmd = 0.2 * math.sin(0.03 * k)
        rows.append(f"{k + 1:>10},   06/29/2022 04:05:36.674 PM, {0.95 * cmd:.4f}, {0.01 * cmd:.4f}, {cmd:.4f}")
    rows[0] += ", DAQ Start"
    rows[-1] += ", DAQ Pause, DAQ Stop"
    if edit:
        rows = edit(rows)
    path = tmp_path / "rec.txt"
    path.write_bytes(("\r\n".join([h.format(n=len(rows)) for h in DAQ_HEAD] + rows) + "\r\n").encode())
    return path


def test_daq_export_maps_and_scales_channels(tmp_path):
    rec = read_record(_daq(tmp_path))  # the format is recognised from the header
    assert rec.n == 300 and rec.dt == pytest.approx(0.001)
    k = 100
    assert rec.command_mm[k] == pytest.approx(10 * round(0.2 * math.sin(0.03 * k), 4))
    assert rec.measured_mm[k] == pytest.approx(10 * round(0.19 * math.sin(0.03 * k), 4))
    assert rec.force_kN[k] == pytest.approx(9.80665 * round(0.002 * math.sin(0.03 * k), 4))
    other = read_daq(_daq(tmp_path), DaqChannels(command="CHANNEL0", measured="CHANNEL2", force="",
                                                 command_scale=1.0, measured_scale=2.0))
    assert other.force_kN is None
    assert other.command_mm[k] == pytest.approx(round(0.19 * math.sin(0.03 * k), 4))
    assert other.measured_mm[k] == pytest.approx(2 * round(0.2 * math.sin(0.03 * k), 4))


@pytest.mark.parametrize("edit, channels, words", [
    (lambda r: r[:120] + r[121:], None, r"rec.txt:128: sample number jumps from 120 to 122"),
    (lambda r: r[:40] + ["        41,   06/29/2022 04:05:36.674 PM, NaN, 0.0, 0.1"] + r[41:], None, r"rec.txt:48: CHANNEL0 is 'NaN'"),
    (lambda r: r[:60] + ["        61,   06/29/2022, 0.1"] + r[61:], None, r"rec.txt:68: expected 5 fields"),
    (None, DaqChannels(force="CHANNEL7"), r"rec.txt:7: no channel 'CHANNEL7' for the force"),
])
def test_daq_export_refuses_bad_input(tmp_path, edit, channels, words):
    with pytest.raises(RecordError, match=words):
        read_daq(_daq(tmp_path, edit=edit), channels)


@pytest.mark.parametrize("size", ["-3", "7.5", "1"])
def test_daq_header_size_must_be_a_whole_number_of_lines(tmp_path, size):
    path = _daq(tmp_path)
    path.write_bytes(path.read_bytes().replace(b"Header Size:  7", f"Header Size:  {size}".encode(), 1))
    with pytest.raises(RecordError, match=f"rec.txt:1: Header Size must be a whole number of lines, at least 2 .* got '{size}'"):
        read_daq(path)


def test_an_actuator_is_chosen_only_in_a_run_recording(tmp_path):
    """--actuator names one actuator of a run.sqlite; given with a CSV or DAQ record (one
    actuator, one specimen) it is refused rather than ignored."""
    from hsio.diagnose.specimen_record import read_specimen

    with pytest.raises(RecordError, match="--actuator chooses an actuator of an hsio recording .* a daq record"):
        read_record(_daq(tmp_path), actuator="C2")
    with pytest.raises(RecordError, match="--actuator chooses an actuator of an hsio recording .* a daq record"):
        read_specimen(_daq(tmp_path), actuator="C2")


def test_daq_sample_count_must_match(tmp_path):
    path = _daq(tmp_path)
    path.write_bytes(path.read_bytes().replace(b"Sample Count:  300", b"Sample Count:  301"))
    with pytest.raises(RecordError, match="rec.txt:5: header says Sample Count 301"):
        read_daq(path)


def test_record_refuses_non_finite_and_short_arrays():
    with pytest.raises(RecordError, match="measured_mm sample 3"):
        ActuatorRecord("x", 0.001, np.zeros(200), np.r_[np.zeros(3), np.nan, np.zeros(196)])
    with pytest.raises(RecordError, match="at least 100"):
        ActuatorRecord("x", 0.001, np.zeros(10), np.zeros(10))


def test_real_daq_file(shared_data):
    rec = read_daq(shared_data / "actuator" / "0A.txt")
    assert rec.n == 61500 and rec.dt == pytest.approx(0.001)
    assert 2.0 < np.max(np.abs(rec.command_mm)) < 2.5  # about +/-0.23 V x 10 mm/V
    assert rec.force_kN is not None


def test_daq_header_size_without_a_colon_is_named(tmp_path):
    path = _daq(tmp_path)
    path.write_bytes(path.read_bytes().replace(b"Header Size:  7", b"Header Size  7", 1))
    with pytest.raises(RecordError, match=r"rec.txt:1: expected 'Header Size: n', got 'Header Size  7' \(no colon\)"):
        read_daq(path)


def test_a_specimen_daq_export_with_header_size_written_as_7_0_is_read(tmp_path):
    """'7.0' is a whole number of lines for the reader; the specimen's segments count the same lines."""
    from hsio.diagnose.specimen_record import read_specimen

    path = _daq(tmp_path, n=400)
    path.write_bytes(path.read_bytes().replace(b"Header Size:  7", b"Header Size:  7.0", 1))
    (record,) = read_specimen(path, "daq")
    assert record.displacement_mm.size == 400


@pytest.mark.parametrize("text, words", [
    ("," * 2_000_000 + "\n", r"r.csv:1: header must be time_s,command_mm,measured_mm\[,force_kN\], got a line of 2000001 fields"),
    ("time_s,command_mm,measured_mm\n" + "1," * 2_000_000 + "\n", r"r.csv:2: expected 3 fields \(time_s,command_mm,measured_mm\), got 2000001"),
])
def test_a_line_of_millions_of_fields_is_counted_before_it_is_split(tmp_path, text, words):
    """A line is refused on its count of commas: a 100 MB line of commas split into fields would
    take some 2 GB."""
    path = tmp_path / "r.csv"
    path.write_text(text)
    with pytest.raises(RecordError, match=words):
        read_csv(path)


def test_an_event_text_of_millions_of_commas_is_not_split(tmp_path):
    """The text after a row's channels is its event (DAQ Start, ...), kept whole: a row whose event
    holds two million commas reads in memory of the order of the file, not a list of its fields."""
    import tracemalloc

    path = _daq(tmp_path, edit=lambda r: r[:5] + [r[5] + ", " + "," * 2_000_000] + r[6:])
    tracemalloc.start()
    try:
        rec = read_daq(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert rec.n == 300
    assert peak < 8 * path.stat().st_size, peak


STRUCTURE_WITH_LVDT = """
[structure]
name = "lvdt"
dt = 0.01
[[dof]]
name = "top"
mass = 0.02
[[experimental]]
name = "wall"
dof = "top"
displacement_from = "wall_lvdt"
outer_loop = { tolerance_mm = 0.05, max_iterations = 4 }
model = { kind = "linear", k = 4.0 }
[[instrument]]
name = "wall_lvdt"
kind = "lvdt"
element = "wall"
"""


def test_a_run_whose_outer_loop_corrected_has_gaps_and_is_refused(tmp_path):
    """An element driven by an external LVDT's outer loop: the periods of its corrections run in
    lab time but are not recorded as controller samples, so the samples are not one continuous
    record (read as one, the fit pins the lag at its least value and a transducer gain at 0.5)."""
    from hsio import config, runner

    (tmp_path / "lvdt.toml").write_text(STRUCTURE_WITH_LVDT)
    runner.run(config.from_dict({"structure": {"file": str(tmp_path / "lvdt.toml")}, "record": {"duration_s": 0.3},
                                 "output": {"plots": False}, "emulator": {"compliance_mm_per_kN": 0.2}}), tmp_path / "run")
    with pytest.raises(RecordError, match=r"run.sqlite: the controller samples of wall jump in lab time from .* "
                                          r"periods the loop ran were not recorded \(an outer loop's corrections\)"):
        read_run(tmp_path / "run" / "run.sqlite")


def test_a_resumed_run_is_refused_naming_the_resume(tmp_path):
    """A resumed run's samples start again where the new session's controller starts (a new
    in-process emulator at lab time 0): two records with the actuators standing between them,
    refused as such, not as an outer loop's corrections."""
    from click.testing import CliRunner
    from wire import stopped_run, write_config

    from hsio.cli import main

    cfg = write_config(tmp_path, duration=0.6, rate=5.0)
    cfg.write_text(cfg.read_text().replace("samples = false", "samples = true"))
    out = stopped_run(tmp_path, 20, config_path=cfg)
    read_run(out / "run.sqlite")  # one session: one continuous record
    assert CliRunner().invoke(main, ["resume", str(out)]).exit_code == 0
    with pytest.raises(RecordError, match=r"run.sqlite: the run was resumed after step 20: the controller samples of "
                                          r"C1 start again at lab time .* separate records.*diagnose needs") as info:
        read_run(out / "run.sqlite")
    assert "outer loop" not in str(info.value)
