"""A two-column record whose times are written to fewer decimals than its step has (a DAQ at
256 Hz exporting 0.0039, 0.0078, ...; 400 Hz written to the millisecond) is evenly sampled: it is
read at its true step. A missing sample or a rate that changes is still refused."""

import math

import numpy as np
import pytest

from hsio.errors import RecordError
from hsio.ground_motion import read_columns


def write(path, dt, n, decimals, skip=(), header="time,acc\n", step_after=None):
    lines, t = [], 0.0
    for i in range(n):
        if i not in skip:
            lines.append(f"{t:.{decimals}f},{0.05 * math.sin(2 * math.pi * 2.0 * t):.6f}\n")
        t += step_after if step_after is not None and i >= n // 2 else dt
    path.write_text(header + "".join(lines))
    return path


@pytest.mark.parametrize("dt, decimals", [(1 / 256, 4), (0.0025, 3), (1 / 60, 3), (1 / 1024, 5), (0.02, 2)])
def test_times_rounded_in_print_give_the_true_step(tmp_path, dt, decimals):
    g = read_columns(write(tmp_path / "acc.csv", dt, 1024, decimals), units="g")
    assert g.dt == pytest.approx(dt, rel=1e-3)
    assert g.accel_g.size == 1024
    t = np.arange(1024) * dt
    np.testing.assert_allclose(g.accel_g, 0.05 * np.sin(2 * np.pi * 2.0 * t), atol=2e-3)


@pytest.mark.parametrize("decimals", [3, 6])
def test_a_missing_sample_is_still_refused_naming_its_line(tmp_path, decimals):
    path = write(tmp_path / "acc.csv", 0.0025, 400, decimals, skip={200})
    with pytest.raises(RecordError, match=r"acc\.csv:202: the times are not evenly spaced: 0\.49\d* to 0\.50\d* s"):
        read_columns(path, units="g")


def test_a_rate_that_changes_halfway_is_still_refused(tmp_path):
    """Steps of 2.5 then 2.6 ms written to the millisecond: each step is within the rounding,
    the times are not on one even grid."""
    path = write(tmp_path / "acc.csv", 0.0025, 800, 3, step_after=0.0026)
    with pytest.raises(RecordError, match=r"acc\.csv:\d+: the times are not evenly spaced: .* off the even steps"):
        read_columns(path, units="g")


def test_times_written_coarser_than_a_quarter_step_are_refused_as_before(tmp_path):
    """0.0025 s written to two decimals (0.00, 0.00, 0.01, ...) says nothing of the step."""
    path = write(tmp_path / "acc.csv", 0.004, 100, 2)
    with pytest.raises(RecordError, match="not evenly spaced|do not increase"):
        read_columns(path, units="g")


@pytest.mark.parametrize("dt", [1 / 256, 1 / 60, 0.0025])
def test_times_written_to_six_significant_digits_give_the_true_step(tmp_path, dt):
    """Times printed with %g (six significant digits: 0.00390625 at first, 11.9961 at 12 s) each
    carry their own rounding, finer at the start than at the end of the record."""
    n = int(round(12.0 / dt))
    t = np.arange(n) * dt
    path = tmp_path / "acc.csv"
    path.write_text("".join(f"{x:g},{0.05 * math.sin(2 * math.pi * 2.0 * x):.6f}\n" for x in t))
    g = read_columns(path, units="g")
    assert g.dt == pytest.approx(dt, rel=1e-6) and g.accel_g.size == n
    lines = path.read_text().splitlines()
    del lines[n // 2]  # a missing sample is still refused
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordError, match=rf"acc\.csv:{n // 2 + 1}: the times are not evenly spaced"):
        read_columns(path, units="g")


def test_a_long_record_with_rounded_times_is_read_past_1024_s(tmp_path):
    """256 Hz written to 4 decimals over 1100 s: beyond about 1024 s the difference of two times
    carries their floating-point rounding on top of the print's, and the record is read all the same."""
    n = 1100 * 256
    t = np.arange(n) / 256.0
    path = tmp_path / "long.csv"
    path.write_text("".join(f"{x:.4f},{0.05 * math.sin(x):.6f}\n" for x in t))
    g = read_columns(path, units="g")
    assert g.accel_g.size == n and g.dt == pytest.approx(1 / 256, rel=1e-9)
