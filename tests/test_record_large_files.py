"""Large record files are parsed at once (numpy) when every row is plain numbers, and line by line
otherwise: both give the same samples, and every refusal names the same line, however deep in the
file it is."""

import codecs
from unittest import mock

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hsio import ground_motion
from hsio.errors import RecordError
from hsio.ground_motion import (_decimals, _first_column_places, _numbers_at_once, _rows_at_once, _rows_by_line,
                                read_at2, read_columns)

SETTINGS = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def by_line():
    """Every column file read by the line-by-line parser alone."""
    return mock.patch.object(ground_motion, "_rows_at_once", lambda path, data: None)


def word_by_word():
    """Every AT2 file's values read word by word."""
    return mock.patch.object(ground_motion, "_values_at_once", lambda data, pos, npts: None)


def outcome(read):
    try:
        g = read()
    except RecordError as exc:
        return "refused", str(exc)
    return g.dt, g.accel_g.tobytes()


# Numbers as files write them: integers, points at either end, exponents, signs, leading zeros.
mantissas = st.one_of(
    st.integers(-10**6, 10**6).map(str),
    st.floats(-1e4, 1e4, allow_nan=False).map(repr),
    st.tuples(st.sampled_from(["", "+", "-"]), st.text("0123456789", max_size=6), st.just("."),
              st.text("0123456789", max_size=6)).map("".join).filter(lambda w: any(c.isdigit() for c in w)),
)
numbers = st.one_of(
    mantissas,
    st.tuples(mantissas.filter(lambda m: "e" not in m), st.sampled_from(["e", "E"]), st.sampled_from(["", "+", "-"]),
              st.integers(0, 330).map(str)).map("".join),
)
gaps = st.sampled_from([" ", "  ", "\t", ",", ", ", ";", " ; ", ",\t"])
endings = st.sampled_from(["\n", "\r\n", "\r"])


@st.composite
def column_files(draw):
    columns = draw(st.sampled_from([1, 2]))
    n = draw(st.integers(1, 40))
    ending, gap = draw(endings), draw(gaps)
    rows = []
    for i in range(n):
        words = [draw(numbers) for _ in range(columns)]
        if columns == 2 and draw(st.booleans()):
            words[0] = f"{i * 0.0039:.{draw(st.integers(0, 6))}f}"  # times, rounded or not
        rows.append(draw(st.sampled_from(["", " ", ","])) + gap.join(words) + draw(st.sampled_from(["", " ", ";"])))
    head = draw(st.lists(st.sampled_from(["# a comment", "% units g", "", "   ", "time,acc", "t ; a"]), max_size=3))
    oddity = draw(st.sampled_from(["", "", "", "# late", "", "nan", "1_0", "1e999", "abc", "1 2 3", "0x10", "\xa0"]))
    if oddity:
        rows.insert(draw(st.integers(0, len(rows))), oddity)
    text = ending.join(head + rows) + draw(st.sampled_from(["", ending, ending * 3, " \n\t"]))
    return draw(st.sampled_from([b"", codecs.BOM_UTF8])) + text.encode("latin-1")


@SETTINGS
@given(data=column_files())
def test_parsed_at_once_or_line_by_line_the_rows_are_the_same(tmp_path, data):
    path = tmp_path / "acc.csv"
    path.write_bytes(data)
    data = data.removeprefix(codecs.BOM_UTF8)
    try:
        slow = _rows_by_line(path, data)
    except RecordError:
        slow = None
    fast = _rows_at_once(path, data)
    if fast is not None:
        assert slow is not None
        assert fast.values.shape == slow.values.shape
        assert fast.values.tobytes() == slow.values.tobytes()  # the same doubles, bit for bit
        assert list(fast.line_of) == list(slow.line_of)
        assert fast.first_words == slow.first_words
        if fast.values.shape[1] == 2:
            np.testing.assert_array_equal(np.asarray(fast.places(), dtype=float), np.array(slow.places(), dtype=float))
    for dt_s in (None, 0.01):
        with by_line():
            expected = outcome(lambda: read_columns(path, dt_s=dt_s, units="g"))
        assert outcome(lambda: read_columns(path, dt_s=dt_s, units="g")) == expected


def test_a_plain_file_is_parsed_at_once(tmp_path):
    """The property above is not vacuous: plain files take the fast path."""
    path = tmp_path / "acc.csv"
    path.write_text("time,acc\n" + "".join(f"{i * 0.005:.3f},{np.sin(i):.6e}\n" for i in range(1000)))
    rows = _rows_at_once(path, path.read_bytes())
    assert rows is not None and rows.values.shape == (1000, 2) and rows.line_of[0] == 2


@settings(max_examples=200, deadline=None)
@given(words=st.lists(numbers, min_size=1, max_size=30), gap=gaps, ending=endings)
def test_the_decimal_places_of_the_times_are_read_as_python_reads_them(words, gap, ending):
    data = b"head\n" + ending.join(f"{w}{gap}1.5" for w in words).encode()
    assert list(_first_column_places(data, 5, len(data), 2)) == [float(_decimals(w)) for w in words]


def test_numbers_read_a_chunk_at_a_time_are_all_read():
    values = np.random.default_rng(3).standard_normal(5000)
    data = b"\n".join(f"{float(v)!r}, {-float(v)!r}".encode() for v in values)
    for chunk in (1, 7, 64, 1 << 22):
        read = _numbers_at_once(data, 0, len(data), 10000, chunk=chunk)
        np.testing.assert_array_equal(read.reshape(-1, 2), np.column_stack([values, -values]))
    assert _numbers_at_once(data, 0, len(data), 9999, chunk=64) is None  # one more than asked for
    assert _numbers_at_once(data, 0, len(data), 10001, chunk=64) is None  # one fewer
    np.testing.assert_array_equal(_numbers_at_once(data, 0, len(data), 9999, more=True, chunk=64), read[:9999])


N = 120_000  # rows: past numpy's chunk of 4 MB in two columns


def large(tmp_path, line, columns=2):
    """A column file of N rows, a header first, with ``line`` in place of row 100,000 (line 100,001)."""
    t = np.arange(N) * 0.005
    rows = [f"{a:.3f},{b:.6e}" if columns == 2 else f"{b:.6e}" for a, b in zip(t, np.sin(t))]
    if line is not None:
        rows[100_000 - 1] = line
    path = tmp_path / "big.csv"
    path.write_text("time,acc\n" + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("line, message", [
    ("500.000,abc", r"big\.csv:100001: '500.000,abc' is not a row of numbers"),
    ("500.000,1_0", r"big\.csv:100001: '500.000,1_0' is not a row of numbers"),
    ("500.000,nan", r"big\.csv:100001: '500.000,nan' holds a value that is not finite"),
    ("500.000,1e999", r"big\.csv:100001: '500.000,1e999' holds a value that is not finite"),
    ("500.000,1,2", r"big\.csv:100001: 3 columns where the lines above have 2"),
    ("0.25", r"big\.csv:100001: 1 columns where the lines above have 2"),
    ("499.985,0.1", r"big\.csv:100001: the times of the first column do not increase \(499\.99 s, then 499\.985 s\)"),
    ("499.995\xa0 0.1", r"big\.csv:100001: .* is not a row of numbers"),
])
def test_a_bad_line_deep_in_a_large_file_is_named(tmp_path, line, message):
    path = large(tmp_path, line)
    with pytest.raises(RecordError, match=message) as fast:
        read_columns(path, units="g")
    with by_line(), pytest.raises(RecordError) as slow:
        read_columns(path, units="g")
    assert str(fast.value) == str(slow.value)


def test_a_step_missing_deep_in_a_large_file_is_named(tmp_path):
    t = np.r_[np.arange(100_000), np.arange(100_001, N)] * 0.005
    path = tmp_path / "big.csv"
    path.write_text("time,acc\n" + "".join(f"{a:.3f},0.0\n" for a in t))
    with pytest.raises(RecordError, match=r"^.*big\.csv:100002: the times are not evenly spaced: 499\.995 to 500\.005"):
        read_columns(path, units="g")


@pytest.mark.parametrize("line", ["# a comment", "", "   ,  "])
def test_a_comment_or_blank_line_deep_in_a_large_file_keeps_the_lines_below_it(tmp_path, line):
    path = large(tmp_path, None)
    lines = path.read_text().split("\n")
    lines.insert(100_000, line)
    lines[110_001] = "550.000,0.1,9"  # refused: named by its line, counted past the one inserted
    path.write_text("\n".join(lines))
    with pytest.raises(RecordError, match=r"^.*big\.csv:110002: 3 columns where the lines above have 2$"):
        read_columns(path, units="g")


def test_a_large_file_read_at_once_equals_the_line_by_line_reading(tmp_path):
    path = large(tmp_path, None, columns=1)
    fast = read_columns(path, dt_s=0.005, units="cm/s^2")
    with by_line():
        slow = read_columns(path, dt_s=0.005, units="cm/s^2")
    assert fast.accel_g.tobytes() == slow.accel_g.tobytes() and fast.dt == slow.dt


def test_more_than_max_samples_is_named_at_its_line(tmp_path, monkeypatch):
    monkeypatch.setattr(ground_motion, "MAX_SAMPLES", 100_000)
    path = large(tmp_path, None)
    with pytest.raises(RecordError, match=r"^.*big\.csv:100002: more than 100000 samples$") as fast:
        read_columns(path, units="g")
    with by_line(), pytest.raises(RecordError) as slow:
        read_columns(path, units="g")
    assert str(fast.value) == str(slow.value)


def test_a_count_header_is_refused_as_line_by_line(tmp_path):
    path = tmp_path / "acc.txt"
    path.write_text("5\n0.1\n0.2\n0.3\n0.4\n0.5\n")
    with pytest.raises(RecordError, match=r"acc\.txt:1: '5' is the count of the 5 values below it") as fast:
        read_columns(path, dt_s=0.01, units="g")
    with by_line(), pytest.raises(RecordError) as slow:
        read_columns(path, dt_s=0.01, units="g")
    assert str(fast.value) == str(slow.value)


def at2(path, values_text, npts):
    path.write_text("PEER\nrecord\nACCELERATION TIME SERIES IN UNITS OF G\n"
                    f"NPTS= {npts}, DT= .0050 SEC\n" + values_text)
    return path


@SETTINGS
@given(words=st.lists(numbers, min_size=2, max_size=40), per_line=st.integers(1, 8), ending=endings,
       extra=st.integers(-1, 1), oddity=st.sampled_from(["", "", "nan", "1_0", "x", "1e999", "\f"]))
def test_an_at2_file_read_at_once_or_word_by_word_is_the_same(tmp_path, words, per_line, ending, extra, oddity):
    if oddity:
        words = words + [oddity]
    text = ending.join("  ".join(words[i:i + per_line]) for i in range(0, len(words), per_line)) + ending
    path = at2(tmp_path / "rec.AT2", text, len(words) + extra)
    with word_by_word():
        expected = outcome(lambda: read_at2(path))
    assert outcome(lambda: read_at2(path)) == expected


def test_a_bad_value_deep_in_a_large_at2_file_is_named(tmp_path):
    values = [f"{v:.7E}" for v in np.sin(np.arange(500_000) * 0.01)]
    values[400_002] = "1.0E+999"
    text = "\n".join("  ".join(values[i:i + 5]) for i in range(0, len(values), 5)) + "\n"
    path = at2(tmp_path / "rec.AT2", text, len(values))
    with pytest.raises(RecordError, match=r"^.*rec\.AT2:80005: value '1\.0E\+999' is not finite$"):
        read_at2(path)
    path = at2(tmp_path / "rec.AT2", text.replace("1.0E+999", "1.0E-001"), len(values))
    fast = read_at2(path)
    with word_by_word():
        assert read_at2(path).accel_g.tobytes() == fast.accel_g.tobytes()
