"""Ground-motion files written by other programs than the ones hsio ships with."""

from __future__ import annotations

import numpy as np
import pytest

from hsio.errors import RecordError
from hsio.ground_motion import read_at2, read_columns


@pytest.mark.parametrize("text", [
    "0,0.1\r\n0.01,-0.2\r\n0.02,0.3\r\n",           # two columns, no header (a spreadsheet's "CSV UTF-8")
    "0.1\n-0.2\n0.3\n",                             # one column (Notepad's "UTF-8 with BOM")
])
def test_a_column_file_that_starts_with_a_byte_order_mark_is_read(tmp_path, text):
    path = tmp_path / "record.csv"
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    record = read_columns(path, dt_s=0.01, units="g")
    assert record.dt == pytest.approx(0.01)
    np.testing.assert_array_equal(record.accel_g, [0.1, -0.2, 0.3])


HEADER = "PEER NGA STRONG MOTION DATABASE RECORD\nstation\nACCELERATION TIME SERIES IN UNITS OF G\n"


@pytest.mark.parametrize("line4", ["NPTS= 3.7, DT= .0050 SEC", "NPTS= 2.5, DT= .0050 SEC", "3.5 0.0050 NPTS, DT",
                                   "NPTS= 3e0, DT= .0050 SEC"])
def test_an_at2_header_whose_npts_is_not_a_whole_number_is_refused(tmp_path, line4):
    """NPTS = 3.7 is a header typed wrong, not 3 samples."""
    path = tmp_path / "r.AT2"
    path.write_text(f"{HEADER}{line4}\n0.1 0.2 0.3\n")
    with pytest.raises(RecordError, match=r"r.AT2:4: NPTS = \S+ is not a whole number of samples"):
        read_at2(path)


@pytest.mark.parametrize("line4", ["NPTS= 3.0, DT= .0050 SEC", "NPTS=3., DT=.005", "3 .005 NPTS, DT"])
def test_an_at2_header_with_npts_written_as_a_decimal_whole_number_is_read(tmp_path, line4):
    path = tmp_path / "r.AT2"
    path.write_text(f"{HEADER}{line4}\n0.1 0.2 0.3\n")
    record = read_at2(path)
    assert record.dt == pytest.approx(0.005) and record.accel_g.size == 3
