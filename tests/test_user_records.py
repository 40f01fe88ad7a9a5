"""Ground-motion files written by other programs than the ones hsio ships with."""

from __future__ import annotations

import numpy as np
import pytest

from hsio.ground_motion import read_columns


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
