"""Recording: every step written durably to an SQLite file as it happens.

One file per run (``run.sqlite``), readable by any SQLite tool, pandas or MATLAB:

* ``meta``: key/value (JSON) - configuration, structure, DOF and actuator names, units, versions.
* ``steps``: one row per integration step - time, and per DOF ``u_``, ``v_``, ``a_``,
  ``u_pred_`` (mm, mm/s, mm/s^2), ``r_`` (restoring force, kN), ``mode_`` (displacement or force);
  per actuator ``target_``, ``command_``, ``disp_`` (mm or kN by mode), ``force_`` (kN); then
  ``late_steps`` (late steps of the command generator so far) and ``flags`` (the kinds of the
  events of the step, e.g. ``warning``, comma-separated; empty when none).
* ``samples``: one row per controller period - step, sample index, per actuator ``cmd_``,
  ``disp_``, ``force_``; then ``lab_time_s`` (the controller clock) and per actuator ``phase_``,
  the command generator's phase as a code (meta ``phase_codes``: 0 interpolate, 1 dwell,
  2 extrapolate, 3 slow, 4 hold; a channel on a setup: the most urgent of its element's actuators').
* ``ns``: the purely numerical simulation, per step ``u_`` per DOF.
* ``summary``: key/value (JSON), written at the end.
* ``events``: what the safety layer saw (docs/safety.md) - time (s of lab time), step, kind
  (``warning``, ``trip``, ``hold``, ``pause``, ``resume``, ``stop``, ``dry_run``, ...), actuator
  (or empty), message.
* ``uncommitted_steps`` and ``uncommitted_samples`` (after a stop in the middle of a step, never
  steps): the step the run was making, its trial, the stop's cause and lab time, and its
  controller-rate samples up to the stop (:meth:`Recorder.write_uncommitted`, docs/safety.md
  section 1).
* ``compensation`` (when the run has a compensation stage): one row per step - per actuator
  ``dc_``, ``da_`` (command and adjusted command, mm), ``v_`` (mm/s), ``er_cc_`` or ``er_ca_`` and
  ``er_aa_`` (execution errors / d_max), ``a_``, ``b_`` (parameters used), see hsio.compensation.
* ``actuators`` (elements loaded through setups, whose channels are their basic DOFs): one row per
  step - per actuator ``target_``, ``command_``, ``disp_``, ``force_`` (stroke sent, command,
  measured stroke and force; docs/setups.md).

Each step is committed durably (WAL journal, ``synchronous=FULL``) before the next begins: a run
that stops for any reason, a killed process or a power loss included, keeps every step it made.
A committed step lives in the journal ``run.sqlite-wal`` until a checkpoint copies it into
``run.sqlite``: the Recorder checkpoints when the record is created (its tables and meta), every
:attr:`Recorder.CHECKPOINT_S` of wall time after a step, and when it closes, so ``run.sqlite``
alone holds what was committed up to the last checkpoint; the record is the folder, both files.
A record is never overwritten: the Recorder refuses a file that exists, and
:func:`new_run_folder` creates a fresh numbered folder per run (docs/safety.md section 1). A
record has one writer at a time: the Recorder holds an exclusive lock (``flock``) on its file
while it writes, so a resume of a record that a run (or another resume) is still writing is
refused (:class:`RecordInUseError`) before anything is written or opened.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import sqlite3
import time
from collections import Counter
from pathlib import Path

import numpy as np

from hsio.errors import HsioError, RecordError

RUN_FILE = "run.sqlite"
MAX_RUN_NUMBER = 9999


class RecordExistsError(HsioError):
    """A run would overwrite an earlier record; nothing was written."""


class RecordInUseError(RecordError):
    """Another process (a run, a resume) is writing the record; nothing was written."""


def _lock(path: Path, fd: int) -> int:
    """Take the writer's lock on the record ``path`` through ``fd`` (kept open while it writes);
    :class:`RecordInUseError` if another process holds it."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise RecordInUseError(f"{path} is being written by another process (a run or a resume still going): "
                               f"one writer at a time; stop that one first (its control socket, or Ctrl-C), "
                               f"the record is unchanged and nothing moved") from None
    return fd


def being_written(path: str | Path) -> bool | None:
    """Whether a process holds the writer's lock of the record ``path`` (:func:`_lock`: a run or a
    resume writing it), read from the kernel's table of file locks without taking the lock (which
    would refuse that writer its own); None where it cannot be told: no /proc/locks (not Linux), or
    one that does not list a lock this process takes (a sandboxed or emulated kernel)."""
    try:
        st = os.stat(path)
        if _flock_on(st.st_ino, _locks_table()):
            return True
    except OSError:
        return None
    return False if _flocks_listed() else None


def _locks_table() -> str:
    with open("/proc/locks", encoding="ascii", errors="replace") as f:
        return f.read()


def _flock_on(inode: int, table: str) -> bool:
    """Whether ``table`` (/proc/locks) lists a granted flock on ``inode``."""
    # "1: FLOCK  ADVISORY  WRITE 16881 fe:00:2155528 0 EOF" ("->": a waiter). Matched on the inode
    # number alone: the device can read differently there than in stat (overlay file systems), and a
    # lock on a namesake inode of another device only makes a finished record look written (followed).
    for line in table.splitlines():
        fields = line.split()
        if "->" not in fields and len(fields) >= 6 and fields[1] == "FLOCK" \
                and fields[5].rpartition(":")[2] == str(inode):
            return True
    return False


_flock_listed: bool | None = None  # whether this kernel's /proc/locks lists a flock of this process


def _flocks_listed() -> bool:
    """Whether /proc/locks lists flocks at all: one taken on a temporary file must show there
    (checked once per process; a check that could not be made is made again next time)."""
    global _flock_listed
    if _flock_listed is None:
        import tempfile

        try:
            with tempfile.TemporaryFile() as f:
                fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                _flock_listed = _flock_on(os.fstat(f.fileno()).st_ino, _locks_table())
        except OSError:
            return False
    return _flock_listed


class RunFileMissingError(RecordError, FileNotFoundError):
    """:class:`Run` was given a path where no file is."""


class NotARunError(RecordError, sqlite3.DatabaseError):
    """:class:`Run` was given a directory, a file that is no SQLite database, or a database that
    is no hsio run record."""


# What a run leaves in its folder beside run.sqlite: SQLite's journals (a journal left without its
# database would be replayed into a new one) and the summary. Any of them marks a used folder.
RECORD_TRACES = (RUN_FILE, RUN_FILE + "-wal", RUN_FILE + "-journal", "summary.json")


def holds_record(folder: str | Path) -> bool:
    """True if ``folder`` holds a run record."""
    return (Path(folder) / RUN_FILE).exists()


def refuse_recorded_folder(folder: str | Path) -> Path:
    """``folder`` for a new run, or :class:`RecordExistsError` if it already holds a record (or
    what is left of one: its journal or its summary)."""
    folder = Path(folder)
    if holds_record(folder):
        raise RecordExistsError(f"{folder / RUN_FILE} already holds the record of an earlier run; records are "
                                f"never overwritten: choose another --out folder (or omit --out for a "
                                f"new numbered folder)")
    left = [name for name in RECORD_TRACES if os.path.lexists(folder / name)]
    if left:
        raise RecordExistsError(f"{folder} holds {', '.join(left)} of an earlier run; records are never "
                                f"overwritten: choose another --out folder (or omit --out for a new numbered folder)")
    return folder


def new_run_folder(root: str | Path) -> Path:
    """A new, empty folder ``root/run-NNNN`` (the next free number), created atomically: two
    runs started together never share a folder."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    taken = [int(p.name[4:]) for p in root.glob("run-[0-9][0-9][0-9][0-9]") if p.name[4:].isdigit()]
    n = max(taken, default=0) + 1
    for _ in range(MAX_RUN_NUMBER):
        if n > MAX_RUN_NUMBER:
            break
        folder = root / f"run-{n:04d}"
        try:
            folder.mkdir()  # atomic: fails if another run took the number first
            return folder
        except FileExistsError:
            n += 1
    raise RecordExistsError(f"{root}: no free run number up to run-{MAX_RUN_NUMBER:04d}; use --out")

def discard_new_record(folder: str | Path, remove_folder: bool) -> None:
    """Remove the record a run created in ``folder`` before anything was recorded in it (its
    metadata only: the run could not begin), and the folder when ``remove_folder`` and it is then
    empty. Used before the first command, never on a record that holds a step."""
    folder = Path(folder)
    for suffix in ("", "-wal", "-shm", "-journal"):
        Path(f"{folder / RUN_FILE}{suffix}").unlink(missing_ok=True)
    if remove_folder:
        try:
            folder.rmdir()
        except OSError:
            pass  # not empty (or gone): left as it is

_NAME = re.compile(r"[^0-9A-Za-z_]")
PHASE_CODES = {"interpolate": 0, "dwell": 1, "extrapolate": 2, "slow": 3, "hold": 4}


def column(prefix: str, name: str) -> str:
    return f"{prefix}_{_NAME.sub('_', name)}"


def _names(path: Path, what: str, names) -> list[str]:
    """DOF or actuator names: strings whose columns (:func:`column`) are distinct."""
    if isinstance(names, (str, bytes)) or not hasattr(names, "__iter__"):
        raise RecordError(f"{path}: {what} must be a list of names, got {names!r}")
    names = list(names)
    seen: dict[str, str] = {}
    for name in names:
        if not isinstance(name, str) or not name:
            raise RecordError(f"{path}: {what}: a name must be a non-empty string, got {name!r}")
        key = column("", name).casefold()  # SQLite's column names ignore case
        if key in seen:
            same = "twice" if seen[key] == name else (f"and {seen[key]!r} (both recorded as column suffix "
                                                      f"{column('', name)[1:]!r}, column names ignoring case)")
            raise RecordError(f"{path}: {what}: {name!r} {same}; give names that differ in letters, digits or _")
        seen[key] = name
    return names


CORE_TABLES = ("meta", "summary", "steps", "samples", "events", "ns")  # every record has these; the others are extra
# what a stop in the middle of a step leaves (:meth:`Recorder.write_uncommitted`): never a step,
# never continued by a resume; made on the first such stop
UNCOMMITTED_TABLES = ("uncommitted_steps", "uncommitted_samples")


class Recorder:
    """Writes a run, step by step, to ``path`` (an SQLite database): a new file, never one that
    exists (:class:`RecordExistsError`)."""

    CHECKPOINT_S = 1.0  # a committed step reaches run.sqlite itself within this much wall time

    def __init__(self, path: str | Path, dof_names, actuator_names, meta: dict | None = None):
        self.path = Path(path)
        self.dof_names = _names(self.path, "dof_names", dof_names)
        self.actuator_names = _names(self.path, "actuator_names", actuator_names)
        dof_cols = [column(p, d) for d in self.dof_names for p in ("u", "v", "a", "u_pred", "r")]
        mode_cols = [column("mode", d) for d in self.dof_names]
        act_cols = [column(p, a) for a in self.actuator_names for p in ("target", "command", "disp", "force")]
        self._step_cols = ["step", "time_s", *dof_cols, *mode_cols, *act_cols, "late_steps", "flags"]
        self._sample_cols = ["step", "k", *[column(p, a) for a in self.actuator_names for p in ("cmd", "disp", "force")],
                             "lab_time_s", *[column("phase", a) for a in self.actuator_names]]
        self._ns_cols = ["step", "time_s", *[column("u", d) for d in self.dof_names]]
        for table, cols in (("steps", self._step_cols), ("samples", self._sample_cols), ("ns", self._ns_cols)):
            twice = sorted(c for c, count in Counter(c.casefold() for c in cols).items() if count > 1)
            if twice:
                raise RecordError(f"{self.path}: the DOF names {self.dof_names} and actuator names "
                                  f"{self.actuator_names} give the {table} table column {twice[0]!r} twice; "
                                  "rename one")
        meta = dict(meta or {})
        for key, value in meta.items():
            try:
                json.dumps(value)
            except (TypeError, ValueError) as exc:
                raise RecordError(f"{self.path}: meta[{key!r}] cannot be recorded as JSON ({exc}); give lists, "
                                  "numbers, strings and dicts (e.g. array.tolist())") from None
        if self.path.is_dir():
            raise RecordError(f"{self.path} is a directory; a record is a file (e.g. {self.path / RUN_FILE})")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:  # created exclusively: an earlier record is never replaced
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            raise RecordExistsError(f"{self.path} already holds a record; records are never overwritten") from None
        except OSError as exc:  # a read-only or full file system, a folder without write permission
            raise RecordError(f"{self.path}: cannot create the record: {exc.strerror or exc}") from None
        self.db = None
        self._lock_fd = _lock(self.path, fd)
        try:
            self._create(meta)
        except BaseException as exc:  # no half-made record is left behind: the same call can be made again
            self._abandon()
            for suffix in ("", "-wal", "-shm", "-journal"):
                Path(f"{self.path}{suffix}").unlink(missing_ok=True)
            if isinstance(exc, (sqlite3.Error, OSError)):  # e.g. the disk full before the first page
                raise RecordError(f"{self.path}: cannot create the record: {exc}") from None
            raise

    def _create(self, meta: dict) -> None:
        self.db = sqlite3.connect(self.path, check_same_thread=False)
        self.db.execute("PRAGMA synchronous=FULL")  # each commit on disk before the next step
        # The tables and the meta in one transaction of the rollback journal, then WAL: a run killed
        # while it creates its record leaves no tables and a -journal beside them (without_journal),
        # never a record with some of its tables.
        self.db.execute("BEGIN")
        self.db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)")
        self.db.execute("CREATE TABLE summary (key TEXT PRIMARY KEY, value TEXT)")
        self.db.execute(
            "CREATE TABLE steps (step INTEGER PRIMARY KEY, time_s REAL, "
            + ", ".join(f"{c} {'TEXT' if c.startswith('mode_') or c == 'flags' else 'REAL'}" for c in self._step_cols[2:])
            + ")"
        )
        self.db.execute("CREATE TABLE samples (step INTEGER, k INTEGER, " + ", ".join(f"{c} REAL" for c in self._sample_cols[2:]) + ")")
        self.db.execute("CREATE TABLE events (time_s REAL, step INTEGER, kind TEXT, actuator TEXT, message TEXT)")
        self.db.execute("CREATE TABLE ns (step INTEGER PRIMARY KEY, time_s REAL, " + ", ".join(f"{c} REAL" for c in self._ns_cols[2:]) + ")")
        meta.update(dof_names=self.dof_names, actuator_names=self.actuator_names,
                    units={"displacement": "mm", "force": "kN", "time": "s", "mass": "kN s^2/mm"},
                    phase_codes=PHASE_CODES)
        self.db.executemany("INSERT INTO meta VALUES (?, ?)", [(k, json.dumps(v)) for k, v in meta.items()])
        self.db.commit()
        self.db.execute("PRAGMA journal_mode=WAL")
        self._checkpoint()  # run.sqlite alone holds the tables and the meta
        self._insert_step = f"INSERT INTO steps VALUES ({', '.join('?' * len(self._step_cols))})"
        self._insert_sample = f"INSERT INTO samples VALUES ({', '.join('?' * len(self._sample_cols))})"
        self._insert_ns = f"INSERT INTO ns VALUES ({', '.join('?' * len(self._ns_cols))})"
        self.steps_written = 0
        self._extra_tables: dict[str, list[str]] = {}

    @classmethod
    def append(cls, path: str | Path) -> "Recorder":
        """Reopen the record at ``path`` to continue it after its last committed step (a resumed
        run, docs/safety.md section 8)."""
        self = cls.__new__(cls)
        self.path = Path(path)
        self.db = None
        try:
            if not os.access(self.path.parent, os.W_OK | os.X_OK):  # SQLite writes its journal beside the record
                raise PermissionError(13, "its folder cannot be written to")
            fd = os.open(self.path, os.O_RDWR)
        except OSError as exc:
            raise RecordError(f"{self.path}: cannot write to the record ({exc.strerror or exc}); the record is "
                              f"unchanged") from None
        self._lock_fd = _lock(self.path, fd)
        try:
            self._reopen()
        except BaseException:
            self._abandon()
            raise
        return self

    def _reopen(self) -> None:
        self.db = sqlite3.connect(self.path, check_same_thread=False)
        tables = {name for (name,) in self.db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        missing = sorted(set(CORE_TABLES) - tables)
        if missing:
            raise NotARunError(f"{self.path}: not an hsio run record that can be continued (no {', '.join(missing)} "
                               f"table){without_journal(self.path)}; the record is unchanged")
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=FULL")
        meta = {k: json.loads(v) for k, v in self.db.execute("SELECT key, value FROM meta")}
        self.dof_names, self.actuator_names = list(meta["dof_names"]), list(meta["actuator_names"])
        cols = lambda table: [r[1] for r in self.db.execute(f"PRAGMA table_info({table})")]  # noqa: E731
        self._step_cols, self._sample_cols, self._ns_cols = cols("steps"), cols("samples"), cols("ns")
        self._insert_step = f"INSERT INTO steps VALUES ({', '.join('?' * len(self._step_cols))})"
        self._insert_sample = f"INSERT INTO samples VALUES ({', '.join('?' * len(self._sample_cols))})"
        self._insert_ns = f"INSERT INTO ns VALUES ({', '.join('?' * len(self._ns_cols))})"
        self.steps_written = self.db.execute("SELECT COUNT(*) FROM steps").fetchone()[0]
        self._checkpointed = time.monotonic()
        # every extra table the record holds (compensation, implicit, static, instruments, actuators) is continued
        self._extra_tables = {name: cols(name)[1:] for name in sorted(tables - set(CORE_TABLES) - set(UNCOMMITTED_TABLES))
                             if not name.startswith("sqlite_")}

    def write_step(self, step: int, time_s: float, u, v, a, u_pred, r, modes, targets, commands, disp, force, samples=None,
                   sample_meta=None, late_steps: int = 0, flags=()) -> None:
        """One integration step; ``samples`` is n x n_actuators x 3 (command, disp, force),
        ``sample_meta`` (lab times, per-sample phases) beside them when known."""
        row = [step, time_s]
        for k in range(len(self.dof_names)):
            row += [float(u[k]), float(v[k]), float(a[k]), float(u_pred[k]), float(r[k])]
        row += [str(m) for m in modes]
        for j in range(len(self.actuator_names)):
            row += [float(targets[j]), float(commands[j]), float(disp[j]), float(force[j])]
        row += [int(late_steps), ",".join(flags)]
        try:
            self._write_step(step, row, samples, sample_meta)
        except sqlite3.Error as exc:  # a full or vanished disk: the run stops, the steps before are kept
            try:
                self.db.rollback()  # a step is written whole or not at all (a later commit must not keep half)
            except sqlite3.Error:
                pass
            raise RecordError(f"{self.path}: step {step} could not be written ({exc})") from None
        self.steps_written += 1
        if time.monotonic() - self._checkpointed >= self.CHECKPOINT_S:
            self._checkpoint()

    def _checkpoint(self) -> None:
        """Copy what the journal (``-wal``) holds into the record's file (a passive checkpoint:
        it waits for no reader, such as the monitor; what a reader still needs stays for the next
        one). The steps are durable in the journal already: a checkpoint that fails loses nothing."""
        self._checkpointed = time.monotonic()
        with contextlib.suppress(sqlite3.Error):
            self.db.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchall()

    def _write_step(self, step: int, row: list, samples, sample_meta) -> None:
        self.db.execute(self._insert_step, row)
        if samples is not None and len(samples):
            flat = np.asarray(samples, dtype=float).reshape(len(samples), -1)
            n_act = len(self.actuator_names)
            if sample_meta is not None and len(sample_meta[0]) == len(flat):
                times, phases = sample_meta
                extra = [(float(t), *(PHASE_CODES.get(p, -1) for p in ph)) for t, ph in zip(times, phases)]
            else:
                extra = [(None, *([None] * n_act))] * len(flat)
            self.db.executemany(self._insert_sample,
                                [(step, k, *map(float, r_), *e) for k, (r_, e) in enumerate(zip(flat, extra))])
        self.db.commit()

    def write_tables(self, tables: dict[str, list[tuple[int, dict]]]) -> None:
        """Whole extra tables at once, ``{table: [(step, row), ...]}`` (a site's ``record_tables``)."""
        for table, rows in tables.items():
            for step, row in rows:
                self.write_row(table, step, row)

    def write_row(self, table: str, step: int, row: dict) -> None:
        """One step of an extra table (``compensation``, ``implicit``), created on first use with
        the row's keys as REAL columns; committed with the step's row by :meth:`write_step`."""
        if table not in self._extra_tables:
            names = [_NAME.sub("_", k) for k in row]
            self._extra_tables[table] = names
            # quoted: a name may be an SQL keyword or begin with a digit (an instrument "1lvdt", "select")
            self.db.execute(f"CREATE TABLE {table} (step INTEGER PRIMARY KEY, " + ", ".join(f'"{c}" REAL' for c in names) + ")")
        n = len(self._extra_tables[table])
        self.db.execute(f"INSERT INTO {table} VALUES ({', '.join('?' * (n + 1))})",
                        [step, *(None if x is None else float(x) for x in row.values())])

    def write_compensation(self, step: int, row: dict) -> None:
        """One step of the compensation stage (Er^cc, or Er^ca and Er^aa, per actuator)."""
        self.write_row("compensation", step, row)

    def write_uncommitted(self, step: int, time_s: float, stop_lab_time_s: float | None, cause: str, targets,
                          samples, times=None, phases=None) -> int:
        """What a run that stopped in the middle of step ``step`` had of it (docs/safety.md
        section 1): a row of ``uncommitted_steps`` (the step's time ``time_s``, the lab time of
        the stop, its cause, the step's trial ``target_`` per actuator, ``committed`` = 0) and the
        step's controller-rate samples so far in ``uncommitted_samples`` (the columns of
        ``samples``, after a ``stop`` number), in a transaction of their own. The ``steps`` and
        ``samples`` tables are untouched: a resume, the summaries, diagnose and the monitor see
        whole steps only. Returns the stop's number (1 for a record's first such stop); a full
        or vanished disk is a :class:`RecordError`, everything recorded before kept."""
        n_act = len(self.actuator_names)
        flat = np.asarray(samples, dtype=float).reshape(len(samples), -1)
        times = [None] * len(flat) if times is None or len(times) != len(flat) else [float(t) for t in times]
        if phases is None or len(phases) != len(flat):
            phases = [[None] * n_act] * len(flat)
        targets = [np.nan] * n_act if targets is None else [float(x) for x in targets]
        try:  # a savepoint of its own: a failure undoes these rows only, never an event not yet committed
            self.db.execute("SAVEPOINT uncommitted")
            self.db.execute("CREATE TABLE IF NOT EXISTS uncommitted_steps (stop INTEGER PRIMARY KEY, step INTEGER, "
                            "time_s REAL, stop_lab_time_s REAL, n_samples INTEGER, committed INTEGER, cause TEXT, "
                            + ", ".join(f"{column('target', a)} REAL" for a in self.actuator_names) + ")")
            self.db.execute("CREATE TABLE IF NOT EXISTS uncommitted_samples (stop INTEGER, "
                            + ", ".join(f"{c} {'INTEGER' if c in ('step', 'k') else 'REAL'}" for c in self._sample_cols)
                            + ")")
            stop = self.db.execute("SELECT COALESCE(MAX(stop), 0) + 1 FROM uncommitted_steps").fetchone()[0]
            self.db.execute(f"INSERT INTO uncommitted_steps VALUES ({', '.join('?' * (7 + n_act))})",
                            [stop, int(step), float(time_s), None if stop_lab_time_s is None else float(stop_lab_time_s),
                             len(flat), 0, cause, *targets])
            code = lambda p: PHASE_CODES.get(p) if p in PHASE_CODES else None  # noqa: E731  (None: none went out)
            self.db.executemany(f"INSERT INTO uncommitted_samples VALUES ({', '.join('?' * (len(self._sample_cols) + 1))})",
                                [(stop, int(step), k, *map(float, r_), t, *(code(p) for p in ph))
                                 for k, (r_, t, ph) in enumerate(zip(flat, times, phases))])
            self.db.execute("RELEASE uncommitted")
            self.db.commit()
        except sqlite3.Error as exc:
            try:
                self.db.execute("ROLLBACK TO uncommitted")
                self.db.execute("RELEASE uncommitted")
            except sqlite3.Error:
                with contextlib.suppress(sqlite3.Error):
                    self.db.rollback()
            raise RecordError(f"{self.path}: the samples of the unfinished step {step} could not be written "
                              f"({exc})") from None
        return stop

    def write_event(self, time_s: float | None, step: int | None, kind: str, actuator: str, message: str,
                    commit: bool = True) -> None:
        """One event (docs/safety.md): committed at once unless ``commit`` is false (then with the step)."""
        try:
            self.db.execute("INSERT INTO events VALUES (?, ?, ?, ?, ?)",
                            (None if time_s is None else float(time_s), step, kind, actuator or "", message))
            if commit:
                self.db.commit()
        except sqlite3.Error as exc:  # a full or vanished disk
            raise RecordError(f"{self.path}: the {kind} event could not be written ({exc})") from None

    def write_meta(self, items: dict) -> None:
        """Add or replace metadata (e.g. an override of the dry run, the control socket)."""
        self._commit("meta", "INSERT OR REPLACE INTO meta VALUES (?, ?)", [(k, json.dumps(v)) for k, v in items.items()])

    def write_ns(self, t: np.ndarray, u: np.ndarray) -> None:
        self._commit("NS", self._insert_ns, [(i, float(t[i]), *map(float, u[i])) for i in range(len(t))])

    def _commit(self, what: str, sql: str, rows: list) -> None:
        """``rows`` into the record whole or not at all; a full or vanished disk is a RecordError."""
        try:
            self.db.executemany(sql, rows)
            self.db.commit()
        except sqlite3.Error as exc:
            with contextlib.suppress(sqlite3.Error):
                self.db.rollback()
            raise RecordError(f"{self.path}: the {what} could not be written ({exc})") from None

    def write_summary(self, summary: dict, replace: bool = False) -> None:
        """Add or replace summary entries; ``replace``: the summary becomes ``summary`` alone."""
        try:
            if replace:
                self.db.execute("DELETE FROM summary")
            self.db.executemany("INSERT OR REPLACE INTO summary VALUES (?, ?)",
                                [(k, json.dumps(v)) for k, v in summary.items()])
            self.db.commit()
        except BaseException:  # all or nothing: a later commit must not keep the deletion alone
            self.db.rollback()
            raise

    def _abandon(self) -> None:
        """Close without committing what a failed creation or reopening began, and let go of the lock."""
        if self.db is not None:
            self.db.close()
            self.db = None
        self.close()

    def close(self) -> None:
        """Commit and close; then let go of the writer's lock (after SQLite's own file is closed:
        closing a descriptor of the file drops the process's locks on it)."""
        try:
            if self.db is not None:
                self.db.commit()
                self._checkpoint()  # a reader still open (the monitor) keeps SQLite's own from running at close
                self.db.close()
        finally:
            self.db = None
            fd, self._lock_fd = getattr(self, "_lock_fd", None), None
            if fd is not None:
                os.close(fd)


def connect_read_only(path: str | Path, check_same_thread: bool = True) -> sqlite3.Connection:
    """A read-only SQLite connection to the record at ``path``, whatever its folder is called (the
    path is percent-encoded into SQLite's URI: a ``#``, ``?`` or ``%`` in a name would otherwise
    cut it short and open another file, read-write).

    A record in a folder this process cannot write to (a write-protected archive) is read as
    immutable: SQLite cannot create the WAL index beside it, and a closed record has no journal
    left to merge. A journal (``-wal``) that still holds steps is named instead of being skipped."""
    path = Path(path).absolute()
    db = sqlite3.connect(path.as_uri() + "?mode=ro", uri=True, check_same_thread=check_same_thread)
    try:
        db.execute("SELECT name FROM sqlite_master LIMIT 1").fetchall()
        return db
    except sqlite3.OperationalError:
        db.close()
        if os.access(path.parent, os.W_OK) or not os.access(path, os.R_OK):
            raise
    wal = Path(f"{path}-wal")
    if wal.exists() and wal.stat().st_size > 0:
        raise sqlite3.OperationalError(f"its folder is write-protected and its journal {wal.name} holds steps not "
                                       f"yet merged into it: let the folder be written to, or copy it, to read it")
    return sqlite3.connect(path.as_uri() + "?mode=ro&immutable=1", uri=True, check_same_thread=check_same_thread)


def without_journal(path: str | Path) -> str:
    """A clause for the error about a record file that holds no tables: a run interrupted while it
    created its record (the file still in the rollback format, or its ``-journal`` beside it), or a
    ``run.sqlite`` copied alone, whose committed steps were still in its ``-wal`` ("" otherwise)."""
    path = Path(path)
    wal = Path(f"{path}-wal")
    if wal.exists() and wal.stat().st_size > 0:  # an empty one: made by SQLite as the file was read
        return ""
    journal = Path(f"{path}-journal")
    hot = journal.exists() and journal.stat().st_size > 0
    try:
        db = connect_read_only(path)
        try:
            tables = db.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()[0]
        finally:
            db.close()
    except sqlite3.Error:  # a reader cannot roll back the journal of a creation killed as it was written
        if not hot:
            return ""
        tables = 0
    if tables:
        return ""
    try:
        with open(path, "rb") as f:
            header = f.read(20)
    except OSError:
        header = b""
    # The tables are made in one transaction of the rollback journal before the record turns to WAL
    # (Recorder): no tables in a file still in the rollback format (bytes 18-19 of the header are 1;
    # 2 in WAL), or in an empty one, is that transaction never committed.
    creating = len(header) < 20 or header[18] == 1
    if creating or hot:
        beside = f" and its {journal.name} is beside it" if journal.exists() else ""
        return (f"; it holds no tables{beside}: the run was interrupted while it created its record, before "
                f"its first step; there is nothing to read or resume: start the run again")
    return (f"; it holds no tables and no {path.name}-wal with steps is beside it: a record is its folder, and what a run "
            f"commits stays in {path.name}-wal until copied into {path.name}: copy both files together")


def _numbers_only(db, table: str, columns: dict) -> None:
    """ValueError naming the first row and column of ``table`` whose value is not a number (nor
    NULL) where the record keeps numbers (as :meth:`Run._table` would fail to read it)."""
    numeric = [c for c, v in columns.items() if v.dtype != object]
    if not numeric:
        return
    names = ", ".join('"' + c + '"' for c in numeric)
    test = " OR ".join("typeof(\"" + c + "\") NOT IN ('integer', 'real', 'null')" for c in numeric)
    row = db.execute(f"SELECT rowid, {names} FROM {table} WHERE {test} LIMIT 1").fetchone()
    if row is None:
        return
    c, value = next((c, v) for c, v in zip(numeric, row[1:]) if isinstance(v, (str, bytes)))
    raise ValueError(f"row {row[0]} of its {table} table holds {value[:40]!r} in {c}, not a number")


class Run:
    """A recorded run, read back as arrays (for plots, calibration and diagnostics)."""

    def __init__(self, path: str | Path, read: bool = True):
        """``read`` False: the record is checked as when it is read, without reading its steps and
        NS into memory (``steps`` and ``ns`` hold their columns, empty); a value that is no number
        in them is found by SQLite and named."""
        self.path = Path(path)
        if not self.path.exists():
            raise RunFileMissingError(f"{self.path}: no such run file")
        if self.path.is_dir():
            raise NotARunError(f"{self.path} is a directory, not a run file (a run's folder holds {RUN_FILE})")
        if not self.path.is_file():  # a FIFO or a device: SQLite would wait on it for ever
            raise NotARunError(f"{self.path}: not a regular file, so not a run file")
        try:
            db = connect_read_only(self.path)
            try:
                self.meta = {k: json.loads(v) for k, v in db.execute("SELECT key, value FROM meta")}
                self.summary = {k: json.loads(v) for k, v in db.execute("SELECT key, value FROM summary")}
                self.steps = self._table(db, "steps", limit=None if read else 0)
                self.ns = self._table(db, "ns", limit=None if read else 0)
                if not read:
                    _numbers_only(db, "steps", self.steps)
                    _numbers_only(db, "ns", self.ns)
                self._db_path = self.path
            finally:
                db.close()
            self.dof_names = self.meta["dof_names"]
            self.actuator_names = self.meta["actuator_names"]
            for key, prefixes in (("dof_names", ("u", "r")), ("actuator_names", ("target", "disp", "force"))):
                names = self.meta[key]
                if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
                    raise ValueError(f"meta {key} is {json.dumps(names)[:60]}, not a list of names")
                missing = [column(p, n) for n in names for p in prefixes if column(p, n) not in self.steps]
                if missing:
                    raise ValueError(f"meta {key} names {', '.join(names)}, but the steps table has no "
                                     f"{', '.join(missing[:4])}")
            if not self.dof_names:
                raise ValueError("meta dof_names is empty")
            if not isinstance(self.meta.get("config", {}), dict):
                raise ValueError(f"meta config is {json.dumps(self.meta['config'])[:60]}, not a table")
        except (sqlite3.Error, KeyError, ValueError) as exc:
            detail = f"no {exc} in its meta table" if isinstance(exc, KeyError) else str(exc)
            raise NotARunError(f"{self.path}: not an hsio run record ({detail}){without_journal(self.path)}") from None

    @staticmethod
    def _table(db, name: str, order: str = "step", text_columns=(), limit: int | None = None) -> dict[str, np.ndarray]:
        """A table as arrays by column (text columns as objects, the others float, NULL as NaN);
        its first ``limit`` rows only, if given."""
        cur = db.execute(f"SELECT * FROM {name} ORDER BY {order}" + ("" if limit is None else f" LIMIT {int(limit)}"))
        cols = [c[0] for c in cur.description]
        rows = cur.fetchall()
        out = {}
        for i, c in enumerate(cols):
            values = [r[i] for r in rows]
            text = c.startswith("mode_") or c == "flags" or c in text_columns
            out[c] = np.array([v if v is not None else np.nan for v in values] if not text else values,
                              dtype=object if text else float)
        return out

    def samples(self, first_step: int | None = None) -> dict[str, np.ndarray]:
        """Every controller-period sample (may be large), or those of the steps from
        ``first_step`` on."""
        try:
            db = connect_read_only(self.path)
            try:
                return self._table_samples(db, first_step)
            finally:
                db.close()
        except (sqlite3.Error, ValueError, TypeError) as exc:
            raise NotARunError(f"{self.path}: its samples cannot be read ({exc})") from None

    @staticmethod
    def _table_samples(db, first_step: int | None = None) -> dict[str, np.ndarray]:
        cur = (db.execute("SELECT * FROM samples ORDER BY step, k") if first_step is None else
               db.execute("SELECT * FROM samples WHERE step >= ? ORDER BY step, k", (int(first_step),)))
        cols = [c[0] for c in cur.description]
        data = np.array([[np.nan if x is None else x for x in row] for row in cur.fetchall()],
                        dtype=float).reshape(-1, len(cols))
        return {c: data[:, i] for i, c in enumerate(cols)}

    def table(self, name: str) -> dict[str, np.ndarray]:
        """An extra per-step table (``compensation``, ``implicit``); empty if the run has none.
        Missing values are NaN."""
        try:
            db = connect_read_only(self.path)
            try:
                if not db.execute("SELECT name FROM sqlite_master WHERE type='table' AND name=?", (name,)).fetchone():
                    return {}
                cur = db.execute(f"SELECT * FROM {name} ORDER BY step")
                cols = [c[0] for c in cur.description]
                data = np.array(cur.fetchall(), dtype=float).reshape(-1, len(cols))
                return {c: data[:, i] for i, c in enumerate(cols)}
            finally:
                db.close()
        except (sqlite3.Error, ValueError, TypeError) as exc:
            raise NotARunError(f"{self.path}: its {name} table cannot be read ({exc})") from None

    def uncommitted(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """What the run had of the steps it stopped in the middle of (docs/safety.md section 1):
        ``uncommitted_steps`` (a row per such stop: ``stop``, ``step``, ``time_s``,
        ``stop_lab_time_s``, ``n_samples``, ``committed`` = 0, ``cause``, ``target_`` per
        actuator) and ``uncommitted_samples`` (the ``samples`` columns after ``stop``), ordered by
        stop and sample; both empty for a run that never stopped mid-step. Never steps: the
        ``steps`` and ``samples`` tables do not hold them. Missing values are NaN."""
        try:
            db = connect_read_only(self.path)
            try:
                if not db.execute("SELECT name FROM sqlite_master WHERE type='table' AND name='uncommitted_steps'").fetchone():
                    return {}, {}
                return (self._table(db, "uncommitted_steps", "stop", ("cause",)),
                        self._table(db, "uncommitted_samples", "stop, k"))
            finally:
                db.close()
        except (sqlite3.Error, ValueError, TypeError) as exc:
            raise NotARunError(f"{self.path}: its uncommitted steps cannot be read ({exc})") from None

    def events(self) -> list[dict]:
        """The events table as a list of dicts (time_s, step, kind, actuator, message)."""
        db = connect_read_only(self.path)
        try:
            if not db.execute("SELECT name FROM sqlite_master WHERE type='table' AND name='events'").fetchone():
                return []
            cur = db.execute("SELECT time_s, step, kind, actuator, message FROM events ORDER BY rowid")
            return [dict(zip(("time_s", "step", "kind", "actuator", "message"), row)) for row in cur.fetchall()]
        finally:
            db.close()

    def stop_reason(self) -> str | None:
        """Why the run stopped, as it recorded it: its summary's ``stopped``, else the last ``stop``
        event since its last resumption; None for a run that recorded no stop (it finished, or its
        process died)."""
        stopped = self.summary.get("stopped")
        if stopped:
            return str(stopped)
        why = None
        for event in self.events():
            if event["kind"] == "resume":
                why = None
            elif event["kind"] == "stop" and event["message"]:
                why = event["message"]
        return why

    def compensation(self) -> dict[str, np.ndarray]:
        """The compensation table (empty if the run had none)."""
        return self.table("compensation")

    def dof(self, prefix: str, name: str) -> np.ndarray:
        return self.steps[column(prefix, name)]

    def actuator(self, prefix: str, name: str) -> np.ndarray:
        return self.steps[column(prefix, name)]
