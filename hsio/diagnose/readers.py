"""Readers for measured actuator records.

* CSV: a header row ``time_s,command_mm,measured_mm`` and optionally ``force_kN`` (any order),
  one row per sample, uniform time step.
* DAQ text export (as an MTS rig's data acquisition writes it): ``Header Size: n`` header lines, the
  last one the column names ``Sample Number, Date/Time, CHANNEL0, ...``, then rows of sample number,
  date/time, channel values in volts and an optional trailing event text. Channels are mapped
  and scaled to mm and kN by :class:`DaqChannels`.
* hsio's own recordings (``run.sqlite``): the controller-period samples of one actuator.

Bad input is refused with :class:`~hsio.errors.RecordError` naming the file and line: rows with
the wrong number of fields, text where a number belongs, NaN or infinite values, time steps that
are not uniform (gaps, repeats) and missing channels.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hsio.diagnose.record import ActuatorRecord
from hsio.errors import RecordError
from hsio.files import read_bounded

CSV_REQUIRED = ("time_s", "command_mm", "measured_mm")
CSV_OPTIONAL = ("force_kN",)
FORMATS = ("csv", "daq", "run")
STEP_TOLERANCE = 0.05  # a time step may differ from the median by this fraction (rounding)
MAX_COLUMNS = 64  # a record's header names a few columns; a line of more is not one
MAX_FILE_BYTES = 100_000_000  # about 1.5 to 3 million samples: an hour at 1 kHz, within a few GB of memory


def _number(text: str, path, lineno: int, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise RecordError(f"{path}:{lineno}: {what} {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise RecordError(f"{path}:{lineno}: {what} is {text.strip()!r} (not finite)")
    return value


def uniform_step(time_s: np.ndarray, lines: list[int], path) -> float:
    """The sampling interval of a time column; refuses gaps, repeats and jitter with line numbers."""
    if time_s.size < 2:
        raise RecordError(f"{path}: needs at least 2 samples, has {time_s.size}")
    steps = np.diff(time_s)
    dt = float(np.median(steps))
    if not dt > 0:
        raise RecordError(f"{path}: time does not increase (median step {dt!r})")
    bad = np.flatnonzero(np.abs(steps - dt) > STEP_TOLERANCE * dt)
    if bad.size:
        i = int(bad[0])
        if steps[i] > dt:
            kind = "a gap"
        elif steps[i] <= 0:
            kind = "a repeated or backward time"
        else:
            kind = "a short step (jitter, or times printed with too few decimals)"
        raise RecordError(f"{path}:{lines[i + 1]}: {kind}: time steps from {time_s[i]:.6g} to {time_s[i + 1]:.6g} s "
                          f"(the record's step is {dt:.6g} s, each step within {100 * STEP_TOLERANCE:g} % of it)")
    return (float(time_s[-1]) - float(time_s[0])) / (time_s.size - 1)


def read_bytes(path: str | Path) -> bytes:
    """The bytes of a record file, at most MAX_FILE_BYTES of them; a RecordError naming the file
    when it cannot be read, is not a regular file or is larger."""
    path = Path(path)
    try:
        return read_bounded(path, MAX_FILE_BYTES, lambda reason: RecordError(
            f"{path}: {reason} (a record file holds at most {MAX_FILE_BYTES} bytes: cut a longer record "
            "into parts)"))
    except OSError as exc:
        raise RecordError(f"{path}: cannot read: {exc.strerror}") from None


def read_text(path: str | Path) -> tuple[Path, str]:
    """The text of a record file (UTF-8, a byte-order mark allowed); a RecordError naming the
    file when it cannot be read, is larger than MAX_FILE_BYTES or is not UTF-8."""
    path = Path(path)
    raw = read_bytes(path)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise RecordError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    return path, text


def read_csv_table(path: str | Path, header_error) -> tuple[Path, dict[str, np.ndarray], float]:
    """The columns of a CSV record with a header row (blank and ``#`` lines skipped) and its
    uniform time step. ``header_error(fields)`` says what is wrong with a header (None: fine)."""
    path, text = read_text(path)
    header = None
    rows: list[list[float]] = []
    lines: list[int] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        count = stripped.count(",") + 1  # counted before the split: a line of millions of commas stays bytes
        if header is not None and count != len(header):
            raise RecordError(f"{path}:{lineno}: expected {len(header)} fields ({','.join(header)}), got {count}")
        if header is None and count > MAX_COLUMNS:
            raise RecordError(f"{path}:{lineno}: header must be {header_error([])}, got a line of {count} fields")
        fields = [f.strip() for f in stripped.split(",")]
        if header is None:
            wrong = header_error(fields)
            if wrong:
                raise RecordError(f"{path}:{lineno}: header must be {wrong}, got {stripped!r}")
            header = fields
            continue
        rows.append([_number(f, path, lineno, name) for f, name in zip(fields, header)])
        lines.append(lineno)
    if header is None:
        raise RecordError(f"{path}: empty file (no header row {header_error([])})")
    data = np.array(rows, dtype=float).reshape(-1, len(header))
    col = {name: data[:, i] for i, name in enumerate(header)}
    return path, col, uniform_step(col["time_s"], lines, path)


def _actuator_header_error(fields: list[str]) -> str | None:
    missing = [c for c in CSV_REQUIRED if c not in fields]
    unknown = [c for c in fields if c not in CSV_REQUIRED + CSV_OPTIONAL]
    if missing or unknown or len(set(fields)) != len(fields):
        return f"{','.join(CSV_REQUIRED)}[,force_kN]"
    return None


def read_csv(path: str | Path) -> ActuatorRecord:
    """A CSV record with the header ``time_s,command_mm,measured_mm[,force_kN]``."""
    path, col, dt = read_csv_table(path, _actuator_header_error)
    return ActuatorRecord(str(path), dt, col["command_mm"], col["measured_mm"], col.get("force_kN"))


def write_csv(record: ActuatorRecord, path: str | Path) -> Path:
    """Write a record in the CSV format :func:`read_csv` reads."""
    path = Path(path)
    columns = [record.time_s, record.command_mm, record.measured_mm]
    header = "time_s,command_mm,measured_mm"
    if record.force_kN is not None:
        columns.append(record.force_kN)
        header += ",force_kN"
    np.savetxt(path, np.column_stack(columns), delimiter=",", header=header, comments="", fmt="%.9g")
    return path


@dataclass(frozen=True)
class DaqChannels:
    """Which DAQ channel is which, and its scale (mm per V, kN per V).

    The defaults are those of the MTS test rig whose exports docs/diagnose.md reads: CHANNEL0
    measured (10 mm/V), CHANNEL2 command (10 mm/V), CHANNEL1 load cell (1 V = 1 tf = 9.80665 kN;
    the data's own description leaves that scale uncertain by a factor of 10). ``force=""``
    ignores the force channel.
    """

    command: str = "CHANNEL2"
    measured: str = "CHANNEL0"
    force: str = "CHANNEL1"
    command_scale: float = 10.0
    measured_scale: float = 10.0
    force_scale: float = 9.80665


def daq_header_size(lines: list[str], path) -> int:
    """The n of a DAQ export's first line ``Header Size: n``: the lines of its header, the row of
    column names the last."""
    if not lines or not lines[0].lower().startswith("header size"):
        raise RecordError(f"{path}:1: not a DAQ export (expected 'Header Size: n', got {lines[0][:40] if lines else ''!r})")
    _, colon, text = lines[0].partition(":")
    if not colon:
        raise RecordError(f"{path}:1: expected 'Header Size: n', got {lines[0][:40]!r} (no colon)")
    size = _number(text, path, 1, "Header Size")
    if size != int(size) or size < 2:
        raise RecordError(f"{path}:1: Header Size must be a whole number of lines, at least 2 (the header and the "
                          f"column names), got {text.strip()!r}")
    return int(size)


def read_daq(path: str | Path, channels: DaqChannels | None = None) -> ActuatorRecord:
    """A DAQ text export (the module docstring's format): header, column names, sample rows with
    event text."""
    path = Path(path)
    ch = channels or DaqChannels()
    text = read_bytes(path).decode("latin-1")
    all_lines = text.splitlines()
    header_size = daq_header_size(all_lines, path)
    info = {}
    # The header lines include the row of column names (the last one).
    for lineno in range(2, header_size):
        if lineno > len(all_lines):
            raise RecordError(f"{path}:{lineno}: file ends inside the header")
        key, _, value = all_lines[lineno - 1].partition(":")
        info[key.strip().lower()] = (value.strip(), lineno)
    if "sampling interval" not in info:
        raise RecordError(f"{path}: header has no 'Sampling Interval'")
    value, lineno = info["sampling interval"]
    dt = _number(value, path, lineno, "Sampling Interval")
    if not dt > 0:
        raise RecordError(f"{path}:{lineno}: Sampling Interval must be positive, got {value!r}")
    names_line = header_size
    if names_line > len(all_lines):
        raise RecordError(f"{path}:{names_line}: missing the row of column names")
    names = [n.strip() for n in all_lines[names_line - 1].split(",")]
    if len(names) < 3 or names[0].lower() != "sample number":
        raise RecordError(f"{path}:{names_line}: expected 'Sample Number, Date/Time, CHANNEL...', got {all_lines[names_line - 1][:60]!r}")
    channel_names = [n for n in names[2:] if n.lower() != "events"]
    wanted = {"command": ch.command, "measured": ch.measured}
    if ch.force:
        wanted["force"] = ch.force
    for role, name in wanted.items():
        if name not in channel_names:
            raise RecordError(f"{path}:{names_line}: no channel {name!r} for the {role}; channels: {', '.join(channel_names)}")
    n_ch = len(channel_names)
    values: list[list[float]] = []
    numbers: list[float] = []
    lines: list[int] = []
    for lineno in range(names_line + 1, len(all_lines) + 1):
        line = all_lines[lineno - 1].strip()
        if not line:
            continue
        fields = [f.strip() for f in line.split(",", 2 + n_ch)]  # the event text after the channels stays one field
        if len(fields) < 2 + n_ch:
            raise RecordError(f"{path}:{lineno}: expected {2 + n_ch} fields (sample, date/time, {n_ch} channels), got {len(fields)}")
        numbers.append(_number(fields[0], path, lineno, "sample number"))
        values.append([_number(f, path, lineno, channel_names[i]) for i, f in enumerate(fields[2:2 + n_ch])])
        # Anything after the channels is event text (DAQ Start, DAQ Pause, ...): not data.
        lines.append(lineno)
    if not values:
        raise RecordError(f"{path}: no data rows")
    data = np.array(values)
    number = np.array(numbers)
    jumps = np.flatnonzero(np.diff(number) != 1)
    if jumps.size:
        i = int(jumps[0])
        raise RecordError(f"{path}:{lines[i + 1]}: sample number jumps from {number[i]:g} to {number[i + 1]:g} (a gap in the record)")
    if "sample count" in info:
        value, lineno = info["sample count"]
        count = _number(value, path, lineno, "Sample Count")
        if count != len(values):
            raise RecordError(f"{path}:{lineno}: header says Sample Count {count:g}, file holds {len(values)} rows")
    col = {name: data[:, i] for i, name in enumerate(channel_names)}
    force = col[ch.force] * ch.force_scale if ch.force else None
    return ActuatorRecord(str(path), dt, col[ch.command] * ch.command_scale, col[ch.measured] * ch.measured_scale, force)


def read_run(path: str | Path, actuator: str | None = None) -> ActuatorRecord:
    """The controller-period samples of one actuator of an hsio recording (``run.sqlite``)."""
    from hsio.clock import CONTROLLER_RATE_HZ
    from hsio.recording import Run, column

    path = Path(path)
    try:
        run = Run(path)
    except FileNotFoundError as exc:
        raise RecordError(str(exc)) from None
    except Exception as exc:  # sqlite3.DatabaseError and friends: not an hsio run file
        raise RecordError(f"{path}: not an hsio recording: {exc}") from None
    config = run.meta.get("config", {})
    hardware = config.get("hardware") if isinstance(config.get("hardware"), dict) else {}
    if hardware.get("clock") == "realtime":
        raise RecordError(f"{path}: a real-time run keeps the samples of each step only, with gaps between "
                          "steps; diagnose needs a lockstep run or a continuous record")
    names = run.actuator_names
    if not names:
        raise RecordError(f"{path}: the recording names no actuator")
    name = actuator or names[0]
    if name not in names:
        raise RecordError(f"{path}: no actuator {name!r}; actuators: {', '.join(names)}")
    for key, modes in run.steps.items():
        if key.startswith("mode_") and np.any(modes == "force"):
            raise RecordError(f"{path}: steps in force control ({key}); diagnose needs displacement control throughout")
    samples = run.samples()
    if not samples or samples[column("cmd", name)].size == 0:
        raise RecordError(f"{path}: no controller samples recorded (run with [output] samples = true)")
    settings = run.meta.get("emulator_settings") or config.get("emulator") or {}
    rate = settings.get("rate_hz", CONTROLLER_RATE_HZ) if isinstance(settings, dict) else None
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (math.isfinite(rate) and rate > 0):
        raise RecordError(f"{path}: its meta gives no usable controller rate (emulator_settings "
                          f"{json.dumps(settings, default=str)[:60]})")
    lab = samples.get("lab_time_s")
    if lab is not None and lab.size > 1:
        jumps = np.flatnonzero(np.abs(np.diff(lab) - 1.0 / rate) > STEP_TOLERANCE / rate)
        if jumps.size:
            i = int(jumps[0])
            step = float(samples["step"][i + 1])
            resumed = [e["step"] for e in run.events() if e["kind"] == "resume" and e["step"] is not None
                       and e["step"] + 1 == step]
            if resumed:  # the actuators stood still between the two sessions, for a time not recorded
                raise RecordError(f"{path}: the run was resumed after step {resumed[0]}: the controller samples of "
                                  f"{name} start again at lab time {lab[i + 1]:.6g} s after {lab[i]:.6g} s, the two "
                                  "sessions separate records with the actuators standing between them; diagnose "
                                  "needs every period of a continuous record")
            raise RecordError(f"{path}: the controller samples of {name} jump in lab time from {lab[i]:.6g} to "
                              f"{lab[i + 1]:.6g} s at step {samples['step'][i + 1]:g} ({jumps.size} such gaps): "
                              "periods the loop ran were not recorded (an outer loop's corrections); "
                              "diagnose needs every period of a continuous record")
    # The run records every controller period: its rate is the loop's.
    return ActuatorRecord(f"{path}#{name}", 1.0 / rate, samples[column("cmd", name)], samples[column("disp", name)],
                          samples[column("force", name)], controller_dt=1.0 / rate)


def detect_format(path: str | Path) -> str:
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return "csv"
    if suffix in (".sqlite", ".db"):
        return "run"
    try:
        with path.open("rb") as fh:
            head = fh.read(64)
    except OSError as exc:
        raise RecordError(f"{path}: cannot read: {exc.strerror}") from None
    if head.startswith(b"SQLite format 3"):
        return "run"
    if head.lower().startswith(b"header size"):
        return "daq"
    return "csv"


def read_record(path: str | Path, fmt: str | None = None, channels: DaqChannels | None = None,
                actuator: str | None = None) -> ActuatorRecord:
    """Read a record in ``fmt`` (csv, daq or run; None: from the name and first bytes)."""
    fmt = fmt or detect_format(path)
    if actuator is not None and fmt != "run":
        raise RecordError(f"{path}: --actuator chooses an actuator of an hsio recording (run.sqlite); "
                          f"this is a {fmt} record of one actuator")
    if fmt == "csv":
        return read_csv(path)
    if fmt == "daq":
        ch = channels or DaqChannels()
        if ch.command == ch.measured:
            raise RecordError(f"{path}: the command and the measured displacement are both channel {ch.command!r}: "
                              "give each its own (--command-channel, --measured-channel)")
        return read_daq(path, ch)
    if fmt == "run":
        return read_run(path, actuator)
    raise RecordError(f"{path}: unknown format {fmt!r}; known: {', '.join(FORMATS)}")
