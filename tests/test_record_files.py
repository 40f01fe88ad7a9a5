"""Ground-motion files as labs have them: PEER .AT2 in other units and header orders, and plain
column files (time and acceleration, or accelerations at a given step), read into g."""

from __future__ import annotations

import numpy as np
import pytest

from hsio import runner
from hsio.config import load as load_config
from hsio.errors import ConfigError
from hsio.errors import RecordError
from hsio.ground_motion import G_MM_S2, read_at2, read_columns, read_record, unit_in_g
from hsio.structures import get_structure

G_CM_S2 = G_MM_S2 / 10.0  # 980.665


def at2(path, line3, line4="NPTS= 3, DT= 0.0100 SEC", values="0.5 -1.0 0.25"):
    path.write_text(f"PEER NGA STRONG MOTION DATABASE RECORD\nrecord\n{line3}\n{line4}\n{values}\n")
    return path


@pytest.mark.parametrize("unit, in_g", [
    ("G", 1.0), ("g", 1.0), ("CM/S/S", 1 / G_CM_S2), ("cm/s^2", 1 / G_CM_S2), ("CM/SEC/SEC", 1 / G_CM_S2),
    ("cm/s**2", 1 / G_CM_S2), ("gal", 1 / G_CM_S2), ("M/S2", 1 / 9.80665), ("m / s / s", 1 / 9.80665),
    ("mm/s^2", 1 / G_MM_S2), ("in/s^2", 25.4 / G_MM_S2),
])
def test_acceleration_units_are_their_size_in_g(unit, in_g):
    assert unit_in_g(unit) == pytest.approx(in_g, rel=1e-12)


@pytest.mark.parametrize("unit", ["ft/s^2", "kN", "cm/s", "m", "", "g/s"])
def test_other_units_are_unknown(unit):
    assert unit_in_g(unit) is None


def test_an_at2_file_in_cm_s2_is_converted_to_g(tmp_path):
    """980.665 cm/s^2 is 1 g: the record runs as strong as it was measured, not 980 times stronger."""
    g = read_at2(at2(tmp_path / "r.AT2", "ACCELERATION TIME SERIES IN UNITS OF CM/S/S", values=f"{G_CM_S2} -490.3325 0"))
    np.testing.assert_allclose(g.accel_g, [1.0, -0.5, 0.0], atol=1e-12)


@pytest.mark.parametrize("line4", ["NPTS= 3, DT= 0.0100 SEC", "DT= 0.0100 SEC, NPTS= 3", "NPTS=3 DT=.01 SEC",
                                   "3  0.0100  NPTS, DT", "DT=0.01, NPTS=3, UNITS=G"])
def test_at2_header_forms_give_npts_and_dt(tmp_path, line4):
    g = read_at2(at2(tmp_path / "r.AT2", "IN UNITS OF G", line4))
    assert (g.accel_g.size, g.dt) == (3, 0.01)


def test_a_two_column_csv_with_a_header_reads_its_step_from_the_times(tmp_path):
    t = 1.5 + 0.02 * np.arange(50)  # times need not start at zero
    a = np.sin(t)
    path = tmp_path / "lab.csv"
    path.write_text("# station X, component 90\ntime_s,accel_m_s2\n" + "".join(f"{x:.4f},{y:.6f}\n" for x, y in zip(t, a)))
    g = read_columns(path, units="m/s^2")
    assert g.dt == pytest.approx(0.02, rel=1e-9)
    np.testing.assert_allclose(g.accel_g * 9.80665, np.round(a, 6), atol=1e-12)


def test_a_column_file_needs_its_units(tmp_path):
    path = tmp_path / "acc.txt"
    path.write_text("0 0.1\n0.01 0.2\n")
    for units in (None, ""):
        with pytest.raises(RecordError, match="acc.txt: a column record file does not say its units"):
            read_columns(path, units=units)
    with pytest.raises(RecordError, match="does not say its units"):
        read_record(path)


def test_one_column_needs_its_step(tmp_path):
    path = tmp_path / "acc.txt"
    path.write_text("0.1\n-0.2\n\n0.05\n")
    with pytest.raises(RecordError, match="acc.txt: one column of accelerations and no time step: give dt_s"):
        read_columns(path, units="g")
    g = read_columns(path, dt_s=0.005, units="g")
    assert (g.dt, list(g.accel_g)) == (0.005, [0.1, -0.2, 0.05])


@pytest.mark.parametrize("text, words", [
    ("0 0.1\n0.01 0.2\n0.02 0.1\n0.04 0\n", "acc.txt:4: the times are not evenly spaced: 0.02 to 0.04 s"),
    ("0 0.1\n0.01 0.2 0.3\n", "acc.txt:2: 3 columns where the lines above have 2"),
    ("0 0.1 1\n0.01 0.2 2\n", "acc.txt:1: 3 columns; a record file has one"),
    ("0.1\nabc\n", "acc.txt:2: 'abc' is not a row of numbers"),
    ("0 0.1\n0.01 nan\n", "acc.txt:2: '0.01 nan' holds a value that is not finite"),
    ("0.1\n", "1 samples; a record needs at least 2"),
    ("0.01 0.1\n0 0.2\n", "acc.txt:2: the times of the first column do not increase"),
    ("0 0.1\n1_0 0.2\n", "acc.txt:2: "),
])
def test_a_broken_column_file_is_refused_naming_the_line(tmp_path, text, words):
    path = tmp_path / "acc.txt"
    path.write_text(text)
    with pytest.raises(RecordError) as info:
        read_columns(path, dt_s=0.01, units="g")
    assert words in str(info.value)


def test_a_step_given_for_two_columns_must_agree_with_the_times(tmp_path):
    path = tmp_path / "acc.txt"
    path.write_text("0 0.1\n0.01 0.2\n0.02 0.1\n")
    assert read_columns(path, dt_s=0.01, units="g").dt == pytest.approx(0.01)
    with pytest.raises(RecordError, match="dt_s = 0.02 s but the times of the first column are 0.01 s apart"):
        read_columns(path, dt_s=0.02, units="g")


def test_read_record_takes_no_step_or_unit_for_an_at2_file(tmp_path):
    path = at2(tmp_path / "r.AT2", "IN UNITS OF G")
    assert read_record(path).accel_g.size == 3
    with pytest.raises(RecordError, match="dt_s not read for a PEER .AT2 file"):
        read_record(path, dt_s=0.01)


def test_a_run_configuration_reads_a_column_record_in_its_units(tmp_path):
    """[record] file, dt_s and units: the run's record is the file's accelerations in g, scaled."""
    (tmp_path / "acc.txt").write_text("".join(f"{v}\n" for v in (0.0, 98.0665, -196.133, 0.0)))
    (tmp_path / "run.toml").write_text('[record]\nfile = "acc.txt"\ndt_s = 0.01\nunits = "cm/s^2"\nscale = 2.0\n')
    ground = runner.build_record(load_config(tmp_path / "run.toml"), get_structure("validation"))
    np.testing.assert_allclose(ground.accel_g, [0.0, 0.2, -0.4, 0.0], atol=1e-12)
    assert ground.dt == 0.01


@pytest.mark.parametrize("toml, words", [
    ('[record]\ndt_s = 0.01\n', "[record] dt_s: only read with a column record file"),
    ('[record]\nfile = "r.AT2"\nunits = "g"\n', "[record] units: not read with a PEER .AT2 file"),
    ('[record]\nfile = "acc.txt"\nunits = "furlongs"\n', "[record] units = 'furlongs' is not an acceleration unit"),
    ('[record]\nfile = "acc.txt"\ndt_s = 0.01\n', "[record] units: a column record file (acc.txt) does not say its units"),
    ('[record]\nfile = "acc.txt"\ndt_s = -1.0\n', "dt_s"),
])
def test_record_keys_where_nothing_reads_them_or_out_of_range_are_refused(tmp_path, toml, words):
    (tmp_path / "acc.txt").write_text("0\n0.1\n")
    at2(tmp_path / "r.AT2", "IN UNITS OF G")
    (tmp_path / "run.toml").write_text(toml)
    with pytest.raises(ConfigError) as info:
        load_config(tmp_path / "run.toml")
    assert words in str(info.value)


def test_a_count_on_the_first_line_of_one_column_is_refused_naming_it(tmp_path):
    """'4000' then 4000 accelerations: read as a value, the count is a 4000 g pulse at t = 0. The
    reader refuses it by name, so the API (run_numerical) and `hsio run` both stop there."""
    path = tmp_path / "count.txt"
    path.write_text("4000\n" + "\n".join(f"{0.1 * np.sin(0.05 * i):.6f}" for i in range(4000)) + "\n")
    with pytest.raises(RecordError, match=r"count\.txt:1: '4000' is the count of the 4000 values below it, not an "
                                          r"acceleration \(4000 g\)"):
        read_record(path, dt_s=0.01, units="g")
    path.write_text("# 4000\n" + path.read_text().partition("\n")[2])  # the advice: a comment
    assert len(read_record(path, dt_s=0.01, units="g").accel_g) == 4000


@pytest.mark.parametrize("first", ["4001", "3999", "4000.0", "-4000", "4e3"])
def test_a_first_value_that_is_not_the_count_is_an_acceleration(tmp_path, first):
    """Only a whole number written without a point equal to the count below is taken for a count."""
    path = tmp_path / "r.txt"
    path.write_text(first + "\n" + "0.01\n" * 4000)
    g = read_record(path, dt_s=0.01, units="g")
    assert len(g.accel_g) == 4001 and g.accel_g[0] == float(first)
