"""A run's record read as it grows: the monitor's only source of data (docs/monitor.md section 2).

The run writes ``run.sqlite`` (:mod:`hsio.recording`), committing each step before the next; the
feed opens it read-only and, at each :meth:`RecordFeed.poll`, reads only what was committed since
the last poll (steps, events) and, when asked, the last controller samples. It never writes and
never holds a transaction open between polls; the run never waits for it: SQLite's WAL journal
lets a reader work beside the writer. The same code replays a finished record and follows a run in progress.
The run's summary is read again only when the record can have changed since the last read: when
SQLite's ``data_version`` of the feed's connection moved (another connection committed). The file's
own size and mtime cannot tell: in WAL mode a commit goes to ``run.sqlite-wal``.

Derived per channel as the steps arrive: the tracking error and the tracking indicator
(:mod:`hsio.monitor.indicators`).
"""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path

import numpy as np

from hsio.monitor.indicators import tracking_indicator
from hsio.recording import RUN_FILE, column, connect_read_only

SAMPLES_WINDOW = 4096  # controller samples read for the spectrum (4 s at 1024 Hz)
META_EVERY_S = 2.0
RESUMED = "resumed after step"  # the event `hsio resume` writes as it reopens a record (not a pause's resume)


class _Columns:
    """Growing float columns (capacity doubles: appending n rows costs O(n))."""

    def __init__(self, names):
        self.names = list(names)
        self.n = 0
        self._data = np.full((len(self.names), 1024), np.nan)

    def append(self, block: np.ndarray) -> None:
        m = block.shape[1]
        if self.n + m > self._data.shape[1]:
            grown = np.full((len(self.names), max(2 * self._data.shape[1], self.n + m)), np.nan)
            grown[:, : self.n] = self._data[:, : self.n]
            self._data = grown
        self._data[:, self.n: self.n + m] = block
        self.n += m

    def __getitem__(self, name: str) -> np.ndarray:
        return self._data[self.names.index(name), : self.n]


class RecordFeed:
    """Reads the record of the run in ``run_dir`` incrementally."""

    MIN_POLL_S = 0.1  # polls closer together than this return at once
    READ_BATCH = 5000  # steps read from the record at a time

    def __init__(self, run_dir: str | Path):
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / RUN_FILE
        self.db: sqlite3.Connection | None = None
        self.meta: dict = {}
        self.summary: dict = {}
        self.dofs: list[str] = []
        self.channels: list[str] = []
        self.channel_dof: dict[str, str | None] = {}
        self.dof_unit: dict[str, str] = {}
        self.channel_unit: dict[str, str] = {}
        self.columns: _Columns | None = None
        self.modes: list[np.ndarray] = []  # per DOF, 1 in force control, 0 in displacement control
        self.ns: dict[str, np.ndarray] = {}
        self.events: list[dict] = []
        self.samples: dict[str, np.ndarray] = {}
        self.seen_at: list[tuple[float, int]] = []  # (monotonic time, steps) at each poll that found steps
        self._last_step = -1
        self._last_event = 0
        self._last_sample = 0
        self._last_poll = 0.0
        self._meta_at = 0.0
        self._summary_version: int | None = None  # data_version at the last read of the summary
        self._ti_state: dict[str, tuple[float, tuple[float, float] | None]] = {}

    # -- state -------------------------------------------------------------------------------
    @property
    def opened(self) -> bool:
        return self.columns is not None

    @property
    def n(self) -> int:
        return self.columns.n if self.columns is not None else 0

    @property
    def finished(self) -> bool:
        """The run wrote its summary and no `hsio resume` has reopened the record since.

        A resume leaves the summary of the run it continues in place until it writes its own (with
        ``resumed_from``, the step it continued after): the record is open again while the last
        resume event names a step that summary does not. (The page also treats a record whose
        control socket answers as a run in progress.)"""
        if not self.summary:
            return False
        resumed = [e for e in self.events if e["kind"] == "resume" and str(e["message"]).startswith(RESUMED)]
        return not resumed or self.summary.get("resumed_from") == resumed[-1]["step"]

    @property
    def total_steps(self) -> int | None:
        """Steps the whole test will take (from the NS prediction, else from the run's ``steps_total``;
        None if neither was recorded)."""
        if self.ns.get("time_s") is not None and len(self.ns["time_s"]):
            return len(self.ns["time_s"]) - 1
        total = self.meta.get("steps_total")
        return int(total) if isinstance(total, int) and total > 0 else None

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    # -- reading -----------------------------------------------------------------------------
    def poll(self, force: bool = False) -> int:
        """Read what was committed since the last poll; returns the number of new steps."""
        now = time.monotonic()
        if not force and now - self._last_poll < self.MIN_POLL_S:
            return 0
        self._last_poll = now
        if self.db is None and not self._open():
            return 0
        try:
            return self._read()
        except sqlite3.DatabaseError:  # a table not yet created or a file being replaced: next time
            return 0

    def _open(self) -> bool:
        if not self.path.is_file():  # not yet there; never anything but a file (a FIFO blocks its reader)
            return False
        try:
            db = connect_read_only(self.path, check_same_thread=False)
            meta = {k: json.loads(v) for k, v in db.execute("SELECT key, value FROM meta")}
        except sqlite3.DatabaseError:
            return False
        if "dof_names" not in meta:
            db.close()
            return False
        self.db, self.meta = db, meta
        self.dofs, self.channels = list(meta["dof_names"]), list(meta["actuator_names"])
        self.channel_dof = channel_dofs(meta, self.channels)
        # displacement units ("mm", or "rad" for a rotation; records without them: mm)
        self.dof_unit = dict(zip(self.dofs, _units(meta.get("dof_units"), self.dofs)))
        self.channel_unit = dict(zip(self.channels, _units(meta.get("channel_units"), self.channels)))
        names = ["step", "time_s", "late_steps"]
        names += [column(p, d) for d in self.dofs for p in ("u", "v", "a", "u_pred", "r")]
        names += [column(p, c) for c in self.channels
                  for p in ("target", "command", "disp", "force", "error", "ti", "tif")]
        names += [column("fc", d) for d in self.dofs]
        self.columns = _Columns(names)
        self._ti_state = {c: (0.0, None) for c in self.channels}
        self._tif_state = {c: (0.0, None) for c in self.channels}
        return True

    def _read(self) -> int:
        db = self.db
        if time.monotonic() - self._meta_at > META_EVERY_S:  # the run adds keys (the dry run, the socket)
            self._meta_at = time.monotonic()
            self.meta.update({k: json.loads(v) for k, v in db.execute("SELECT key, value FROM meta")})
        if not self.ns:
            self.ns = _table(db, "SELECT * FROM ns ORDER BY step")
        steps = self._read_steps(db)
        rows = db.execute("SELECT rowid, time_s, step, kind, actuator, message FROM events WHERE rowid > ? "
                          "ORDER BY rowid", (self._last_event,)).fetchall()
        for r in rows:
            self.events.append(dict(zip(("time_s", "step", "kind", "actuator", "message"), r[1:])))
            self._last_event = r[0]
        self._read_summary(db)
        if steps:
            self.seen_at.append((time.monotonic(), self.n))
            del self.seen_at[:-64]
        return steps

    def _read_summary(self, db) -> None:
        """The summary, read again only if another connection (the run, a resume) committed since
        the last read: ``PRAGMA data_version`` moves at each such commit, and only then."""
        version = db.execute("PRAGMA data_version").fetchone()[0]
        if version == self._summary_version:
            return
        self.summary = {k: json.loads(v) for k, v in db.execute("SELECT key, value FROM summary")}
        self._summary_version = version  # taken before the read: a commit in between is read next time

    def _read_steps(self, db) -> int:
        """The steps committed since the last read, taken READ_BATCH rows at a time: a long
        record read at once (a page opened late, a replay) would hold every row as Python
        objects, several times the memory its columns take."""
        read = 0
        while True:
            cur = db.execute("SELECT * FROM steps WHERE step > ? ORDER BY step LIMIT ?", (self._last_step, self.READ_BATCH))
            rows = cur.fetchall()
            if rows:
                self._append_steps([c[0] for c in cur.description], rows)
                read += len(rows)
            if len(rows) < self.READ_BATCH:
                return read

    def _append_steps(self, names: list[str], rows: list) -> None:
        raw = {name: [r[i] for r in rows] for i, name in enumerate(names)}
        block = np.full((len(self.columns.names), len(rows)), np.nan)
        for k, name in enumerate(self.columns.names):
            if name in raw and not name.startswith("mode_"):
                block[k] = np.array([np.nan if x is None else x for x in raw[name]], dtype=float)
        fc = {d: np.array([m == "force" for m in raw.get(column("mode", d), [])], dtype=float) for d in self.dofs}
        for d in self.dofs:
            if len(fc[d]):
                block[self.columns.names.index(column("fc", d))] = fc[d]
        for c in self.channels:
            target = block[self.columns.names.index(column("target", c))]
            disp = block[self.columns.names.index(column("disp", c))]
            force = block[self.columns.names.index(column("force", c))]
            dof = self.channel_dof.get(c)
            in_fc = fc[dof] > 0 if dof in fc and len(fc[dof]) else np.zeros(len(rows), bool)
            error = target - np.where(in_fc, force, disp)
            block[self.columns.names.index(column("error", c))] = error
            # Two tracking indicators, one per loop: of displacement control (mm^2) over the DC
            # steps and of force control (kN^2) over the FC steps; in the other mode's steps the
            # command is taken as the measurement, so they add nothing there.
            dc = np.where(in_fc, disp, target)
            start, previous = self._ti_state[c]
            ti = tracking_indicator(dc, disp, start, previous)
            block[self.columns.names.index(column("ti", c))] = ti
            self._ti_state[c] = (float(ti[-1]), (float(dc[-1]), float(disp[-1])))
            fc_command = np.where(in_fc, target, force)
            start, previous = self._tif_state[c]
            tif = tracking_indicator(fc_command, force, start, previous)
            block[self.columns.names.index(column("tif", c))] = tif
            self._tif_state[c] = (float(tif[-1]), (float(fc_command[-1]), float(force[-1])))
        self.columns.append(block)
        self._last_step = int(rows[-1][0])

    def read_samples(self) -> dict[str, np.ndarray]:
        """The last SAMPLES_WINDOW controller samples (read again only if new ones were recorded)."""
        if self.db is None:
            return {}
        try:
            row = self.db.execute("SELECT MAX(rowid) FROM samples").fetchone()
        except sqlite3.DatabaseError:
            return self.samples
        top = row[0] if row and row[0] is not None else 0
        if top != self._last_sample or not self.samples:
            self._last_sample = top
            self.samples = _table(self.db, "SELECT * FROM (SELECT * FROM samples WHERE rowid > ? ORDER BY rowid DESC) "
                                           "ORDER BY step, k", (top - SAMPLES_WINDOW,))
        return self.samples

    def phases(self) -> dict[str, float]:
        """The command generator's phase code per channel at the last recorded sample."""
        names = [column("phase", c) for c in self.channels]
        try:
            row = self.db.execute(f"SELECT {', '.join(names)} FROM samples ORDER BY rowid DESC LIMIT 1").fetchone()
        except (sqlite3.DatabaseError, AttributeError):
            return {}
        return {c: v for c, v in zip(self.channels, row or ()) if v is not None}

    # -- derived -----------------------------------------------------------------------------
    def steps_per_second(self, window_s: float = 5.0) -> float | None:
        """Steps committed per second of wall time over the last ``window_s`` until now (live
        runs only); None when no step came within it (a pause: no rate, no time to finish)."""
        now = time.monotonic()
        if len(self.seen_at) < 2 or self.seen_at[-1][0] < now - window_s:
            return None
        before = [p for p in self.seen_at if p[0] <= now - window_s]
        t0, n0 = before[-1] if before else self.seen_at[0]
        if now - t0 <= 0:
            return None
        return (self.seen_at[-1][1] - n0) / (now - t0)

    def close(self) -> None:
        if self.db is not None:
            self.db.close()
            self.db = None


def _table(db, sql: str, args=()) -> dict[str, np.ndarray]:
    try:
        cur = db.execute(sql, args)
    except sqlite3.OperationalError:  # the table does not exist (yet)
        return {}
    names = [c[0] for c in cur.description]
    rows = cur.fetchall()
    if not rows:
        return {}
    data = np.array([[np.nan if x is None else x for x in r] for r in rows], dtype=float)
    return {name: data[:, i] for i, name in enumerate(names)}


def _units(units, names: list[str]) -> list[str]:
    """The unit of each of ``names`` from a record's meta: its list of unit names, or mm for a record
    without one (or with one that is not a list of as many names)."""
    if isinstance(units, list) and len(units) == len(names) and all(isinstance(u, str) for u in units):
        return units
    return ["mm"] * len(names)


def channel_dofs(meta: dict, channels: list[str]) -> dict[str, str | None]:
    """The structure DOF each recorded channel acts on (its control mode is that DOF's), from
    the structure the run's configuration names; None where it cannot be told."""
    out: dict[str, str | None] = {c: None for c in channels}
    dofs = list(meta.get("dof_names", []))
    for c in channels:  # ``element.dof`` channels name their DOF
        head, _, tail = c.rpartition(".")
        if head and tail in dofs:
            out[c] = tail
    if all(out.values()):
        return out
    try:
        from hsio.structures import get_structure, load_structure

        table = (meta.get("config") or {}).get("structure", {})
        structure = load_structure(table["file"]) if table.get("file") else get_structure(table.get("name") or meta["structure"])
        for e in structure.experimental:
            dof = structure.dof_names[e.basic_dofs[0]]
            if len(e.basic_dofs) == 1 and not e.has_setup and e.actuator in out and dof in dofs:
                out[e.actuator] = dof
    except Exception:  # a structure file moved since the run: modes stay unknown
        pass
    for c in channels:  # a record of served elements (hsio serve opensees) names its DOFs after its channels
        if out[c] is None and c in dofs:
            out[c] = c
    return out
