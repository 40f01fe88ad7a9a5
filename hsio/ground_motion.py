"""Ground-motion records: readers for PEER .AT2 files and for plain column files (time and
acceleration, or acceleration at a given time step), and a synthetic default record.

Accelerations are kept in g (a file in m/s^2, cm/s^2 (gal), mm/s^2 or in/s^2 is converted on
reading, by standard gravity 9.80665 m/s^2); :meth:`GroundMotion.acceleration_mm_s2` converts to mm/s^2 for the
equations of motion (kN, mm, s), and :meth:`GroundMotion.resampled` interpolates to the
integration time step.
"""

from __future__ import annotations

import codecs
import math
import numbers
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple, Sequence

import numpy as np

from hsio.errors import RecordError
from hsio.files import read_bounded

G_MM_S2 = 9806.65  # standard gravity in mm/s^2
# Sanity bounds (docs/faults.md): a record's time step, its length, and the steps of a run.
DT_MIN_S, DT_MAX_S = 1e-5, 1.0
MAX_SAMPLES = 2_000_000
MAX_STEPS = 1_000_000
MAX_FILE_BYTES = 200_000_000
SYNTHETIC_MIN_SAMPLES = 10


def _real(what: str, name: str, value) -> float:
    """``value`` as a finite real number, or :class:`RecordError` naming ``what``, ``name`` and it."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise RecordError(f"{what}: {name} must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class GroundMotion:
    """A uniformly sampled ground acceleration history, in g."""

    name: str
    dt: float
    accel_g: np.ndarray

    def __post_init__(self):
        dt_ok = (not isinstance(self.dt, (bool, np.bool_)) and isinstance(self.dt, numbers.Real)
                 and math.isfinite(self.dt) and self.dt > 0)
        if not dt_ok:
            raise RecordError(f"{self.name}: time step must be positive, got {self.dt!r}")
        try:
            if np.iscomplexobj(self.accel_g):
                raise RecordError(f"{self.name}: the accelerations must be real numbers (in g), got complex values")
            accel = np.asarray(self.accel_g, dtype=float)
        except (TypeError, ValueError):
            raise RecordError(f"{self.name}: the accelerations must be numbers (in g), got "
                              f"{type(self.accel_g).__name__}") from None
        if accel.ndim != 1:
            raise RecordError(f"{self.name}: the accelerations must be one history (a 1-D array), got shape "
                              f"{accel.shape}")
        bad = np.flatnonzero(~np.isfinite(accel))
        if bad.size:
            raise RecordError(f"{self.name}: sample {bad[0]} (t = {bad[0] * self.dt:.3f} s) is {float(accel[bad[0]])}, "
                              "not a finite number")
        if accel.size < 2:
            raise RecordError(f"{self.name}: needs at least 2 samples, has {accel.size}")
        object.__setattr__(self, "accel_g", accel)

    @property
    def duration_s(self) -> float:
        return (self.accel_g.size - 1) * self.dt

    @property
    def pga_g(self) -> float:
        return float(np.max(np.abs(self.accel_g)))

    def scaled(self, factor: float) -> "GroundMotion":
        if isinstance(factor, bool) or not isinstance(factor, (int, float, np.floating, np.integer)) \
                or not math.isfinite(factor):
            raise RecordError(f"{self.name}: scale factor {factor!r} is not a finite number")
        accel = self._times(float(factor), f"when scaled by the factor {float(factor):g}")
        return GroundMotion(f"{self.name} x {factor:g}", self.dt, accel)

    def truncated(self, duration_s: float) -> "GroundMotion":
        """The first ``duration_s`` of the record; shorter than one of its time steps, or longer than
        the record, is refused (a cut, never a silent clamp)."""
        duration_s = _real(self.name, "cut duration_s", duration_s)
        if not duration_s >= self.dt * (1 - 1e-9):
            raise RecordError(f"{self.name}: a cut to {duration_s:g} s is shorter than one time step of the record "
                              f"({self.dt:g} s)")
        if duration_s > self.duration_s + 0.5 * self.dt:
            raise RecordError(f"{self.name}: a cut to {duration_s:g} s is longer than the record "
                              f"({self.duration_s:g} s)")
        n = int(min(round(duration_s / self.dt), MAX_SAMPLES)) + 1
        return GroundMotion(self.name, self.dt, self.accel_g[: max(n, 2)])

    def resampled(self, dt: float) -> "GroundMotion":
        """Linear interpolation to time step ``dt`` over the same duration (at most
        :data:`MAX_STEPS` steps: a longer run is refused, naming the record and the bound)."""
        dt = _real(self.name, "time step dt", dt)
        if not dt > 0:
            raise RecordError(f"{self.name}: time step must be positive, got {dt!r}")
        steps = self.duration_s / dt
        if steps > MAX_STEPS:
            raise RecordError(f"{self.name}: {self.duration_s:g} s at the structure's time step {dt:g} s is "
                              f"{steps:.0f} steps, more than the bound of {MAX_STEPS} steps per run; shorten it "
                              "([record] duration_s) or check the record's DT")
        if math.isclose(dt, self.dt, rel_tol=1e-12):
            return self
        if self.duration_s < dt * (1 - 1e-9):
            raise RecordError(f"{self.name}: the record lasts {self.duration_s:g} s ({self.accel_g.size} samples at "
                              f"{self.dt:g} s), shorter than one time step {dt:g} s of the structure: nothing to run")
        n = int(math.floor(self.duration_s / dt + 1e-9)) + 1
        t_new = np.arange(n) * dt
        t_old = np.arange(self.accel_g.size) * self.dt
        return GroundMotion(self.name, dt, np.interp(t_new, t_old, self.accel_g))

    def acceleration_mm_s2(self) -> np.ndarray:
        """The accelerations in mm/s^2; a sample whose value there is beyond the floating-point range
        is refused, naming it (a finite value in g is not always finite in mm/s^2)."""
        return self._times(G_MM_S2, f"in mm/s^2 (x {G_MM_S2:g})")

    def _times(self, factor: float, what: str) -> np.ndarray:
        """The accelerations times ``factor``; a sample the product takes beyond the floating-point
        range is refused, naming it and ``what`` the product is."""
        with np.errstate(over="ignore"):
            accel = self.accel_g * factor
        over = np.flatnonzero(~np.isfinite(accel))
        if over.size:
            i = over[0]
            if not np.isfinite(self.accel_g[i]):  # accel_g changed in place after the record was made
                raise RecordError(f"{self.name}: sample {i} (t = {i * self.dt:.3f} s) is {float(self.accel_g[i])}, "
                                  "not a finite number")
            raise RecordError(f"{self.name}: sample {i} (t = {i * self.dt:.3f} s) = {float(self.accel_g[i]):g} g "
                              f"is {float(accel[i])} {what}: beyond the largest floating-point number "
                              f"({np.finfo(float).max:.4g})")
        return accel


# Line 3 of an AT2 file says what the values are, e.g. "ACCELERATION TIME SERIES IN UNITS OF G".
_UNITS = re.compile(r"UNITS\s+OF\s+(\S+(?:\s*/\s*\S+)*)", re.IGNORECASE)
_NOT_ACCELERATION = re.compile(r"\b(VELOCITY|DISPLACEMENT)\b", re.IGNORECASE)
_NPTS = re.compile(r"\bNPTS\s*[=:]\s*(\d+(?:\.\d*)?(?:[Ee][+-]?\d+)?)", re.IGNORECASE)
_DT = re.compile(r"\bDT\s*[=:]\s*([0-9.Ee+-]+)", re.IGNORECASE)
_WORD = re.compile(rb"\S+")
_LINE = re.compile(rb"([^\r\n]*)(?:\r\n|\r|\n|$)")  # one line, any line ending (LF, CRLF, CR)
_NPTS_DT_PLAIN = re.compile(r"^\s*(\d+(?:\.\d*)?(?:[Ee][+-]?\d+)?)\s+([0-9.Ee+-]+)\s+NPTS\s*,\s*DT", re.IGNORECASE)

# Acceleration units a record may be in, and their size in g. A unit is written as the file or the
# configuration spells it; case, spaces, "sec" for "s" and "s/s", "s2", "s^2", "s**2" all mean the same.
UNITS_IN_G = {"g": 1.0, "m/s2": 1000.0 / G_MM_S2, "cm/s2": 10.0 / G_MM_S2, "gal": 10.0 / G_MM_S2,
              "mm/s2": 1.0 / G_MM_S2, "in/s2": 25.4 / G_MM_S2}


def unit_in_g(unit: str) -> float | None:
    """The size in g of the acceleration unit ``unit`` ("g", "m/s^2", "CM/S/S", "gal", ...), or None
    for a unit hsio does not know (:data:`UNITS_IN_G`)."""
    u = re.sub(r"\s+", "", str(unit)).lower().strip(".,;()[]")
    u = u.replace("sec", "s").replace("**", "^")
    u = re.sub(r"/s/s$|/s\^2$|/s2$|/s\*s$", "/s2", u)
    u = {"m/s2": "m/s2", "cm/s2": "cm/s2", "mm/s2": "mm/s2", "in/s2": "in/s2", "gals": "gal"}.get(u, u)
    return UNITS_IN_G.get(u)


def _known_units() -> str:
    return "g, m/s^2, cm/s^2 (gal), mm/s^2, in/s^2"


def read_at2(path: str | Path) -> GroundMotion:
    """Read a PEER .AT2 file (NGA-West2 and older PEER headers), accelerations in g.

    Header: 4 lines; the 3rd names the units ("... IN UNITS OF G"; cm/s^2 and the other units of
    :data:`UNITS_IN_G` are converted to g), the 4th gives NPTS and DT as ``NPTS= 2000, DT= .0200 SEC``
    (in either order, commas optional) or as ``4000  0.0100  NPTS, DT``. Then the values, several
    to a line. A broken header, a value that is not a number, a NaN, or a count that differs from
    NPTS raises :class:`RecordError` naming the file and line.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise RecordError(f"read_at2: path must be a file path, got {path!r}")
    path = Path(path)
    try:
        data = read_bounded(path, MAX_FILE_BYTES, lambda reason: RecordError(
            f"{path}: {reason} (a ground-motion file is a PEER .AT2 text file of at most {MAX_FILE_BYTES} bytes)"))
    except OSError as exc:
        raise RecordError(f"{path}: cannot read ground-motion file: {exc.strerror}") from None
    # The header line by line; the values word by word over the rest of the bytes, so that neither a
    # long line nor millions of blank lines are ever split into a list in memory.
    lines, pos = [], 0
    while len(lines) < 4 and pos < len(data):
        line = _LINE.match(data, pos)
        lines.append(line.group(1).decode("latin-1"))
        pos = line.end()
    if len(lines) < 4:
        raise RecordError(f"{path}: too short for an AT2 file ({len(lines)} lines; the header alone has 4)")
    factor = _check_units(path, lines[2])
    named_npts, named_dt = _NPTS.search(lines[3]), _DT.search(lines[3])
    plain = _NPTS_DT_PLAIN.search(lines[3])
    if named_npts and named_dt:
        npts_text, dt_text = named_npts.group(1), named_dt.group(1)
    elif plain:
        npts_text, dt_text = plain.group(1), plain.group(2)
    else:
        raise RecordError(
            f"{path}:4: header line must give NPTS and DT ('NPTS= 2000, DT= .0200 SEC' or "
            f"'4000 0.0100 NPTS, DT'), got {lines[3].strip()!r}"
        )
    if not npts_text.isdigit():  # '2000.0' is 2000; '2000.5' or '2e3' is a header typed wrong
        if not re.fullmatch(r"\d+\.0*", npts_text):
            raise RecordError(f"{path}:4: NPTS = {npts_text} is not a whole number of samples")
        npts_text = npts_text.split(".")[0]
    digits = npts_text.lstrip("0") or "0"
    npts = int(digits) if len(digits) <= 18 else MAX_SAMPLES + 1  # past 18 digits it is out of bounds
    try:
        dt = float(dt_text)
    except ValueError:
        raise RecordError(f"{path}:4: DT {dt_text!r} is not a number") from None
    if not (dt > 0 and math.isfinite(dt)):
        raise RecordError(f"{path}:4: DT must be positive, got {dt!r}")
    if not DT_MIN_S <= dt <= DT_MAX_S:
        raise RecordError(f"{path}:4: DT = {dt:g} s is out of bounds: a record's time step must be within "
                          f"{DT_MIN_S:g}..{DT_MAX_S:g} s")
    if not 2 <= npts <= MAX_SAMPLES:
        shown = npts if len(digits) <= 18 else f"{digits[:6]}... ({len(digits)} digits)"
        raise RecordError(f"{path}:4: NPTS = {shown} is out of bounds: within 2..{MAX_SAMPLES}")
    if _WORD.search(data, pos) is None:
        raise RecordError(f"{path}: no values after the 4-line header (NPTS = {npts})")
    at_once = _values_at_once(data, pos, npts)
    if at_once is not None:
        return GroundMotion(name=path.name, dt=dt, accel_g=at_once * factor)
    values: list[float] = []
    for found in _WORD.finditer(data, pos):
        word = found.group().decode("latin-1")
        try:
            if "_" in word:  # float() reads '1_0' as 10: a typing error here, never a value
                raise ValueError(word)
            value = float(word)
        except ValueError:
            raise RecordError(f"{path}:{_line_number(data, found.start())}: {word!r} is not a number") from None
        if not math.isfinite(value):
            raise RecordError(f"{path}:{_line_number(data, found.start())}: value {word!r} is not finite")
        if len(values) == npts:  # refused at once, before the rest of a long file is read
            raise RecordError(f"{path}:{_line_number(data, found.start())}: header says NPTS = {npts}, file holds "
                              "more values")
        values.append(value)
    if len(values) != npts:
        raise RecordError(f"{path}: header says NPTS = {npts}, file holds {len(values)} values")
    return GroundMotion(name=path.name, dt=dt, accel_g=np.array(values) * factor)


def read_record(path: str | Path, dt_s: float | None = None, units: str | None = None) -> GroundMotion:
    """Read a ground-motion file: a PEER .AT2 file (:func:`read_at2`; its header gives the time step
    and the units, so neither ``dt_s`` nor ``units`` is taken) when the name ends in .AT2, else a
    column file (:func:`read_columns`)."""
    if not isinstance(path, (str, os.PathLike)):
        raise RecordError(f"read_record: path must be a file path, got {path!r}")
    if Path(path).suffix.lower() == ".at2":
        given = [name for name, value in (("dt_s", dt_s), ("units", units)) if value not in (None, "", 0, 0.0)]
        if given:
            raise RecordError(f"{path}: {', '.join(given)} not read for a PEER .AT2 file: its header gives the time "
                              "step and the units")
        return read_at2(path)
    return read_columns(path, dt_s=dt_s, units=units)


_SEPARATOR = re.compile(r"[\s,;]+")
_COMMENT = ("#", "%", "//", "!")


def read_columns(path: str | Path, dt_s: float | None = None, units: str | None = None) -> GroundMotion:
    """Read a plain text record: one acceleration per line at the time step ``dt_s``, or two
    columns, time (s) and acceleration, whose times must be evenly spaced (the step is read from
    them; a ``dt_s`` given as well must agree). Columns are separated by spaces, tabs, commas or
    semicolons; lines starting with #, %, // or ! are comments, and a first line of words (a CSV
    header such as ``time,acc``) is skipped. A one-column file whose first value is a whole number
    written without a point equal to the count of the values below it (a count header, "4000" then
    4000 accelerations) is refused, naming it: read as an acceleration it would be a pulse of
    4000 g at t = 0. ``units``: the accelerations' unit (:data:`UNITS_IN_G`),
    converted to g: required (a file in cm/s^2 read as g would run 980 times too strong). Every
    refusal names the file and the line."""
    if not isinstance(path, (str, os.PathLike)):
        raise RecordError(f"read_columns: path must be a file path, got {path!r}")
    path = Path(path)
    if units is None or units == "":
        raise RecordError(f"{path}: a column record file does not say its units: give them (units = \"g\", "
                          f"\"m/s^2\", ...; [record] units in a run configuration; known: {_known_units()})")
    factor = unit_in_g(units) if isinstance(units, str) else None
    if factor is None:
        raise RecordError(f"{path}: units {units!r} is not an acceleration unit hsio knows ({_known_units()})")
    if dt_s is not None and dt_s != 0:
        dt_s = _real(str(path), "dt_s", dt_s)
        if not DT_MIN_S <= dt_s <= DT_MAX_S:
            raise RecordError(f"{path}: dt_s = {dt_s:g} s is out of bounds: a record's time step must be within "
                              f"{DT_MIN_S:g}..{DT_MAX_S:g} s")
    else:
        dt_s = None
    try:
        data = read_bounded(path, MAX_FILE_BYTES, lambda reason: RecordError(
            f"{path}: {reason} (a ground-motion file is a text file of at most {MAX_FILE_BYTES} bytes)"))
    except OSError as exc:
        raise RecordError(f"{path}: cannot read ground-motion file: {exc.strerror}") from None
    data = data.removeprefix(codecs.BOM_UTF8)  # the mark some editors and spreadsheets write first
    rows = _rows_at_once(path, data)
    if rows is None:  # a file numpy cannot read at once: line by line, naming the line of what is refused
        rows = _rows_by_line(path, data)
    values, line_of, first_words = rows.values, rows.line_of, rows.first_words
    if len(values) < 2:
        raise RecordError(f"{path}: {len(values)} samples; a record needs at least 2")
    if values.shape[1] == 1:
        if re.fullmatch(r"\+?\d+", first_words[0]) and int(first_words[0]) == len(values) - 1:
            raise RecordError(f"{path}:{line_of[0]}: {first_words[0]!r} is the count of the {len(values) - 1} values "
                              f"below it, not an acceleration ({values[0][0]:g} {units}): remove that line or make "
                              f"it a comment ('# {first_words[0]}')")
        if dt_s is None:
            raise RecordError(f"{path}: one column of accelerations and no time step: give dt_s ([record] dt_s in a "
                              "run configuration), or a first column of times")
        return GroundMotion(name=path.name, dt=dt_s, accel_g=values[:, 0] * factor)
    t, accel = values[:, 0], values[:, 1]
    steps = np.diff(t)
    if not np.all(steps > 0):
        i = int(np.flatnonzero(steps <= 0)[0])
        raise RecordError(f"{path}:{line_of[i + 1]}: the times of the first column do not increase "
                          f"({t[i]:g} s, then {t[i + 1]:g} s)")
    step = float(np.median(steps))
    dt = float(t[-1] - t[0]) / (len(t) - 1)
    uneven = np.flatnonzero(np.abs(steps - step) > 1e-3 * step)
    if uneven.size:
        # Times printed to fewer decimals than the step has (1/256 s as 0.0039, 0.0078, 0.0117, ...;
        # 0.0025 s as 0.002, 0.005, 0.007, ...; to six significant digits, 0.00390625 then 11.9961)
        # are each off the even grid by up to half their own last place: taken where that is at most
        # a quarter of a step (a missing sample, a step twice as long, is still refused) and every
        # time lies on one even grid within it.
        # A time with fewer places than both its neighbours lost trailing zeros (%g writes 1/256 s x
        # 256 as "1"): it is as exact as the coarser of them.
        written = np.array(rows.places(), dtype=float)
        padded = np.concatenate(([np.inf], written, [np.inf]))
        written = np.maximum(written, np.minimum(padded[:-2], padded[2:]))
        printed = 0.5 * 10.0 ** -np.minimum(written, 300.0)
        if printed.max() <= 0.25 * dt:
            # and the difference of two times carries their floating-point rounding, which grows with t
            rounding = 4 * np.finfo(float).eps * np.abs(t[1:])
            tolerance = np.maximum(1e-3 * step, (printed[:-1] + printed[1:]) * (1 + 1e-9) + rounding)
            uneven = np.flatnonzero(np.abs(steps - step) > tolerance)
            if not uneven.size:
                index = np.arange(len(t))
                dt, t0 = (float(v) for v in np.polyfit(index, t, 1))
                off = np.flatnonzero(np.abs(t - (t0 + index * dt)) > np.maximum(1e-3 * dt, 1.5 * printed))
                if off.size:
                    j = int(off[0])
                    raise RecordError(f"{path}:{line_of[j]}: the times are not evenly spaced: {t[j]:g} s is "
                                      f"{t[j] - (t0 + j * dt):+.3g} s off the even steps of {dt:g} s, more than the "
                                      f"rounding of a time written to {int(written[j])} decimals; resample it")
    if uneven.size:
        i = int(uneven[0])
        raise RecordError(f"{path}:{line_of[i + 1]}: the times are not evenly spaced: {t[i]:g} to {t[i + 1]:g} s is a "
                          f"step of {steps[i]:g} s where the record's step is {step:g} s; resample it")
    if not DT_MIN_S <= dt <= DT_MAX_S:
        raise RecordError(f"{path}: time step {dt:g} s is out of bounds: within {DT_MIN_S:g}..{DT_MAX_S:g} s")
    if dt_s is not None and not math.isclose(dt_s, dt, rel_tol=1e-3):
        raise RecordError(f"{path}: dt_s = {dt_s:g} s but the times of the first column are {dt:g} s apart")
    return GroundMotion(name=path.name, dt=dt, accel_g=accel * factor)


class _Rows(NamedTuple):
    """The rows of a column file: ``values`` (one row per sample, one or two columns), the file's
    line of each row (``line_of``, for the messages), the words of the first row, and ``places()``:
    the decimal places each time of the first column is written to (two columns only)."""

    values: np.ndarray
    line_of: Sequence[int]
    first_words: list[str]
    places: Callable[[], Sequence[float]]


def _rows_by_line(path: Path, data: bytes) -> _Rows:
    """The rows of a column file read line by line: every refusal names the line."""
    rows: list[tuple[float, ...]] = []
    line_of: list[int] = []  # the file's line of each row, for the messages
    columns = 0
    places = []  # the decimal places each time of the first column is written to
    pos, number, seen_data = 0, 0, False
    first_words: list[str] = []
    while pos < len(data):
        match = _LINE.match(data, pos)
        pos, number = match.end(), number + 1
        if match.end() == match.start():
            break
        text = match.group(1).decode("latin-1").strip()
        if not text or text.startswith(_COMMENT):
            continue
        words = [w for w in _SEPARATOR.split(text) if w]
        if not words:
            continue
        try:
            if any("_" in w for w in words):  # float() reads '1_0' as 10: a typing error here, never a value
                raise ValueError
            row = tuple(float(w) for w in words)
        except ValueError:
            if not seen_data and not any(_is_number(w) for w in words):
                seen_data = True  # a header of column names, once, before the first value
                continue
            raise RecordError(f"{path}:{number}: {text[:60]!r} is not a row of numbers") from None
        seen_data = True
        if not all(math.isfinite(v) for v in row):
            raise RecordError(f"{path}:{number}: {text[:60]!r} holds a value that is not finite")
        if columns == 0:
            columns = len(row)
            if columns > 2:
                raise RecordError(f"{path}:{number}: {columns} columns; a record file has one (acceleration) or two "
                                  "(time, acceleration)")
        elif len(row) != columns:
            raise RecordError(f"{path}:{number}: {len(row)} columns where the lines above have {columns}")
        if len(rows) == MAX_SAMPLES:
            raise RecordError(f"{path}:{number}: more than {MAX_SAMPLES} samples")
        if not rows:
            first_words = words
        rows.append(row)
        line_of.append(number)
        if columns == 2:
            places.append(_decimals(words[0]))
    values = np.array(rows, dtype=float).reshape(len(rows), max(columns, 1))
    return _Rows(values, line_of, first_words, lambda: places)


# A row of the fast path: numbers written in ASCII (sign, digits, point, exponent; never '_', inf or
# nan) separated by spaces, tabs, commas or semicolons, one line each, no line in between.
_NUMBER = rb"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_GAP = b" \t,;"
_ROW = {n: rb"[ \t,;]*" + rb"[ \t,;]+".join([_NUMBER] * n) for n in (1, 2)}
_ROWS = {n: re.compile(rb"(?:" + row + rb"[ \t,;]*(?:\r\n|\r|\n))*+" + row) for n, row in _ROW.items()}
_FIRST_ROW = {n: re.compile(row + rb"[ \t,;]*") for n, row in _ROW.items()}
_TO_SPACE = bytes.maketrans(b",;", b"  ")
_SEPARATOR_BYTE = re.compile(rb"[ \t\r\n,;]")
_IN_A_NUMBER = np.zeros(256, dtype=bool)
_IN_A_NUMBER[list(b"0123456789+-.eE")] = True


def _rows_at_once(path: Path, data: bytes) -> _Rows | None:
    """The rows of a column file parsed at once (numpy), when every line from the first row to the
    last is a row of one or two plain numbers, with no comment or blank line among them; else None,
    and :func:`_rows_by_line` reads the file (and names the line of what it refuses). The lines
    before the first row (comments, blank lines, a header of column names) are read as
    :func:`_rows_by_line` reads them."""
    pos, number, header = 0, 0, False
    while True:
        if pos >= len(data):
            return None
        match = _LINE.match(data, pos)
        number += 1
        text = match.group(1).decode("latin-1").strip()
        words = [w for w in _SEPARATOR.split(text) if w] if text and not text.startswith(_COMMENT) else []
        if words:
            if len(words) <= 2 and _FIRST_ROW[len(words)].fullmatch(match.group(1)):
                break
            if header or any(_is_number(w) for w in words):
                return None
            header = True  # a header of column names, once, before the first value
        pos = match.end()
    columns, start, first_line = len(words), match.start(), number
    end = _end_of_values(data, start, _GAP + b"\r\n")
    if not _ROWS[columns].fullmatch(data, start, end):
        return None
    n = data.count(b"\n", start, end) + data.count(b"\r", start, end) - data.count(b"\r\n", start, end) + 1
    values = _numbers_at_once(data, start, end, min(n, MAX_SAMPLES + 1) * columns, more=n > MAX_SAMPLES + 1)
    if values is None:
        return None
    if n > MAX_SAMPLES:
        raise RecordError(f"{path}:{first_line + MAX_SAMPLES}: more than {MAX_SAMPLES} samples")
    return _Rows(values.reshape(n, columns), range(first_line, first_line + n), words,
                 lambda: _first_column_places(data, start, end, columns))


def _end_of_values(data: bytes, start: int, blank: bytes) -> int:
    """The offset just past the last byte of ``data[start:]`` that is not in ``blank``."""
    end = len(data)
    while end > start:
        chunk = data[max(start, end - 65536):end]
        kept = len(chunk.rstrip(blank))
        if kept:
            return end - len(chunk) + kept
        end -= len(chunk)
    return start


def _first_column_places(data: bytes, start: int, end: int, columns: int) -> np.ndarray:
    """The decimal places (:func:`_decimals`) of the first number of each row of ``data[start:end]``,
    whose rows each hold ``columns`` plain numbers (as :func:`_rows_at_once` checked)."""
    chars = np.frombuffer(data, dtype=np.uint8, count=end - start, offset=start)
    inside = _IN_A_NUMBER[chars]
    every_first = np.flatnonzero(inside[1:] & ~inside[:-1]) + 1  # where each number begins
    if inside[0]:
        every_first = np.r_[0, every_first]
    every_last = np.flatnonzero(inside[:-1] & ~inside[1:]) + 1  # and where it ends (one past)
    if inside[-1]:
        every_last = np.r_[every_last, chars.size]
    del inside
    firsts, lasts = every_first[::columns], every_last[::columns]
    dot, exp_at = np.full(firsts.size, -1), lasts.copy()
    for mark, where in ((b".", dot), (b"e", exp_at), (b"E", exp_at)):
        at = np.flatnonzero(chars == mark[0])
        owner = np.searchsorted(every_first, at, side="right") - 1  # the number each mark is in
        mine = owner % columns == 0
        where[owner[mine] // columns] = at[mine]
    places = np.where(dot >= 0, exp_at - dot - 1, 0).astype(float)
    has_exp = np.flatnonzero(exp_at < lasts)
    if has_exp.size:
        sign_at = exp_at[has_exp] + 1
        signed = np.isin(chars[sign_at], np.frombuffer(b"+-", dtype=np.uint8))
        negative = chars[sign_at] == ord("-")
        digits_from, digits_to = sign_at + signed, lasts[has_exp]
        width = digits_to - digits_from
        if width.max() > 15:  # an exponent past 15 digits: as Python reads it
            return np.array([_decimals(data[start + a:start + b].decode("ascii")) for a, b in zip(firsts, lasts)],
                            dtype=float)
        exponent = np.zeros(has_exp.size)
        for k in range(int(width.max())):
            here = k < width
            digit = chars[np.where(here, digits_from + k, 0)].astype(float) - ord("0")
            exponent = np.where(here, exponent * 10 + digit, exponent)
        places[has_exp] = np.maximum(0.0, places[has_exp] - np.where(negative, -exponent, exponent))
    return places


def _values_at_once(data: bytes, pos: int, npts: int) -> np.ndarray | None:
    """The ``npts`` values of an AT2 file after its header (from ``pos``) parsed at once (numpy),
    when they are all plain finite numbers separated by spaces, tabs and line ends and there are
    ``npts`` of them; else None, and :func:`read_at2` reads them word by word (naming the line of
    what it refuses)."""
    end = _end_of_values(data, pos, b" \t\r\n\f\v")
    if not _AT2_VALUES.fullmatch(data, pos, end):
        return None
    return _numbers_at_once(data, pos, end, npts)


def _numbers_at_once(data: bytes, start: int, end: int, count: int, more: bool = False,
                     chunk: int = 1 << 22) -> np.ndarray | None:
    """The ``count`` numbers of ``data[start:end]``, plain numbers (as checked by the caller) separated
    by spaces, tabs, commas, semicolons or line ends, parsed by numpy a chunk of bytes at a time (the
    memory it takes is the values' and one chunk's); None when there are not ``count`` of them, or
    one is not finite. ``more``: the bytes may hold more numbers, not read."""
    values = np.empty(count)
    filled, at = 0, start
    while at < end and filled < count + (not more):
        cut = _SEPARATOR_BYTE.search(data, min(at + chunk, end), end)
        cut = cut.start() if cut else end
        piece = data[at:cut].translate(_TO_SPACE)
        at = cut
        if piece.isspace():  # numpy reads a chunk of spaces alone as -1
            continue
        try:
            read = np.fromstring(piece, sep=" ")
        except ValueError:  # a word numpy does not read: the caller's check let through what it should not
            return None
        if filled + read.size > count and not more:
            return None
        read = read[:count - filled]
        values[filled:filled + read.size] = read
        filled += read.size
    if filled != count or not np.isfinite(values).all():
        return None
    return values


_AT2_VALUES = re.compile(rb"[ \t\r\n]*+(?:" + _NUMBER + rb"[ \t\r\n]++)*+" + _NUMBER)


def _decimals(word: str) -> int:
    """The decimal places a number is written to: 3 for '0.125' and '1.25e-1', 0 for '12'."""
    mantissa, _, exponent = word.lower().partition("e")
    places = len(mantissa.partition(".")[2])
    try:
        return max(0, places - int(exponent or 0))
    except ValueError:
        return places


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _line_number(data: bytes, offset: int) -> int:
    """The line (from 1) of the byte at ``offset``, as a text editor counts lines."""
    head = data[:offset]
    return head.count(b"\n") + head.count(b"\r") - head.count(b"\r\n") + 1


def _check_units(path: Path, line: str) -> float:
    """Line 3 names the quantity and its units: the size of that unit in g (1 when it names none).
    Velocities, displacements and units hsio does not know are refused rather than read, say,
    cm/s^2 as g."""
    other = _NOT_ACCELERATION.search(line)
    if other:
        raise RecordError(f"{path}:3: the record holds {other.group(1).lower()}, not acceleration "
                          f"({line.strip()!r}); hsio reads ground accelerations")
    units = _UNITS.search(line)
    if not units:
        return 1.0
    factor = unit_in_g(units.group(1))
    if factor is None:
        raise RecordError(f"{path}:3: the accelerations are in units of {units.group(1)!r}, which hsio does not "
                          f"know; it reads {_known_units()}")
    return factor


def synthetic_record(
    duration_s: float = 20.0,
    dt: float = 0.01,
    pga_g: float = 0.3,
    seed: int = 1994,
    f_g_hz: float = 2.5,
    zeta_g: float = 0.6,
) -> GroundMotion:
    """A reproducible synthetic earthquake: Kanai-Tajimi filtered white noise, enveloped.

    White noise passes through the Kanai-Tajimi ground filter (frequency f_g, damping zeta_g)
    and a Saragoni-Hart-like envelope (build-up, strong motion, decay); a 0.1 Hz high-pass
    removes drift; the result is scaled to ``pga_g``. Generated in code, so a default run needs
    no data file.
    """
    from scipy import signal

    what = "synthetic record"
    duration_s, dt = _real(what, "duration_s", duration_s), _real(what, "dt", dt)
    pga_g, f_g_hz, zeta_g = _real(what, "pga_g", pga_g), _real(what, "f_g_hz", f_g_hz), _real(what, "zeta_g", zeta_g)
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise RecordError(f"{what}: seed must be a whole number from 0, got {seed!r}")
    if not pga_g > 0:
        raise RecordError(f"{what}: pga_g must be positive, got {pga_g!r} (a negative record is scaled by a "
                          "negative factor: GroundMotion.scaled)")
    if not zeta_g > 0:
        raise RecordError(f"{what}: zeta_g must be positive (the ground filter's damping ratio), got {zeta_g!r}")
    for name, value in (("duration_s", duration_s), ("dt", dt)):
        if not value > 0:
            raise RecordError(f"{what}: {name} must be positive, got {value!r}")
    if not duration_s / dt <= MAX_STEPS:
        raise RecordError(f"synthetic record: {duration_s!r} s at {dt!r} s is beyond the bound of {MAX_STEPS} steps")
    if not DT_MIN_S <= dt <= DT_MAX_S:
        raise RecordError(f"synthetic record: time step {dt:g} s is out of bounds: within {DT_MIN_S:g}..{DT_MAX_S:g} s")
    if not 0 < f_g_hz < 0.5 / dt:
        raise RecordError(f"{what}: f_g_hz = {f_g_hz!r} Hz must be positive and below the Nyquist frequency "
                          f"1/(2 dt) = {0.5 / dt:g} Hz of the time step {dt:g} s")
    n = int(round(duration_s / dt)) + 1
    if n < SYNTHETIC_MIN_SAMPLES:  # the drift filter runs forwards and backwards over 9 samples
        raise RecordError(f"synthetic record: {duration_s:g} s at {dt:g} s is {n} samples; it needs at least "
                          f"{SYNTHETIC_MIN_SAMPLES} ({(SYNTHETIC_MIN_SAMPLES - 1) * dt:g} s)")
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal(n)
    w_g = 2 * math.pi * f_g_hz
    # Kanai-Tajimi: H(s) = (2 zeta w s + w^2) / (s^2 + 2 zeta w s + w^2), discretised (bilinear).
    b, a = signal.bilinear([2 * zeta_g * w_g, w_g**2], [1.0, 2 * zeta_g * w_g, w_g**2], fs=1.0 / dt)
    accel = signal.lfilter(b, a, noise)
    t = np.arange(n) * dt
    t_peak = 0.2 * duration_s
    envelope = (t / t_peak) ** 2 * np.exp(2.0 * (1.0 - t / t_peak))
    accel *= envelope
    sos = signal.butter(2, 0.1, btype="highpass", fs=1.0 / dt, output="sos")
    accel = signal.sosfiltfilt(sos, accel)
    accel *= pga_g / np.max(np.abs(accel))
    return GroundMotion(f"synthetic (Kanai-Tajimi, seed {seed})", dt, accel)
