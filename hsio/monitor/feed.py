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
(:mod:`hsio.monitor.indicators`), and over the whole run the peaks the page's status and margins
show (peak |u| per DOF; peak |d|, |f| and |error| in each control mode per channel) and the
switches of control mode per DOF. The step columns themselves are kept bounded
(:class:`hsio.monitor.history.History`: the recent steps whole, the older ones thinned), as is
the NS prediction (every stride-th point, its peaks from the record), so a long run costs the
page server no more memory than a short one.
"""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path

import numpy as np

from hsio.monitor.history import CAP, WINDOW, History
from hsio.monitor.indicators import tracking_indicator
from hsio.recording import RUN_FILE, column, connect_read_only

SAMPLES_WINDOW = 4096  # controller samples read for the spectrum (4 s at 1024 Hz)
META_EVERY_S = 2.0
EVENTS_KEPT = 64  # the newest events kept (the page lists the last 8)
MARKS = ("pause", "resume", "acknowledge", "controller_trip")  # the events the run's state is told from
MARKS_KEPT = 16
RESUMED = "resumed after step"  # the event `hsio resume` writes as it reopens a record (not a pause's resume)


class RecordFeed:
    """Reads the record of the run in ``run_dir`` incrementally."""

    MIN_POLL_S = 0.1  # polls closer together than this return at once
    READ_BATCH = 1000  # steps read from the record at a time

    def __init__(self, run_dir: str | Path, window: int = WINDOW, cap: int = CAP):
        self.run_dir = Path(run_dir)
        self.window, self.cap = window, cap  # of the kept history (hsio.monitor.history)
        self.path = self.run_dir / RUN_FILE
        self.db: sqlite3.Connection | None = None
        self.meta: dict = {}
        self.summary: dict = {}
        self.dofs: list[str] = []
        self.channels: list[str] = []
        self.channel_dof: dict[str, str | None] = {}
        self.dof_unit: dict[str, str] = {}
        self.channel_unit: dict[str, str] = {}
        self.columns: History | None = None
        self.ns: dict[str, np.ndarray] = {}  # time_s and u_ per DOF, every ns_stride-th point
        self.ns_stride = 1
        self.ns_steps = 0  # steps of the NS prediction (its points less the initial one)
        self.ns_peak: dict[str, float] = {}  # peak |u| per DOF of the whole prediction
        self.peak: dict[str, float] = {}  # over every step read: |u_| per DOF, |disp_|, |force_| per channel
        self.peak_error: dict[str, tuple[float, float]] = {}  # per channel |error| (in DC steps, in FC steps)
        self.switches: dict[str, int] = {}  # control-mode switches per DOF
        self.events: list[dict] = []  # the newest EVENTS_KEPT
        self.marks: list[dict] = []  # the newest MARKS_KEPT of the kinds MARKS, however many events came since
        self._reopened_after: int | None = None  # the step after which `hsio resume` last reopened the record
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
        return self._reopened_after is None or self.summary.get("resumed_from") == self._reopened_after

    @property
    def total_steps(self) -> int | None:
        """Steps the whole test will take (from the NS prediction, else from the run's ``steps_total``;
        None if neither was recorded)."""
        if self.ns:
            return self.ns_steps
        total = self.meta.get("steps_total")
        return int(total) if isinstance(total, int) and total > 0 else None

    def __getitem__(self, name: str) -> np.ndarray:
        """Column ``name`` over the recent steps (the last ``window``, all while there are fewer)."""
        return self.columns.recent(name)

    def last(self, name: str) -> float:
        """Column ``name`` at the newest step read."""
        return self.columns.last(name)

    def rows(self, rows: np.ndarray, names=None) -> dict[str, np.ndarray]:
        """Columns ``names`` (default: all) at row numbers ``rows``: recent ones, or on the stride of a
        page whose cap is at most ``self.cap`` (:class:`hsio.monitor.history.History`)."""
        return self.columns.take(rows, names)

    def ns_points(self, stride: int) -> dict[str, np.ndarray]:
        """The NS prediction at every ``stride``-th point (a multiple of ``ns_stride``)."""
        if stride % self.ns_stride:
            raise ValueError(f"the NS prediction is kept every {self.ns_stride}th point, not every {stride}th")
        return {k: v[:: stride // self.ns_stride] for k, v in self.ns.items()}

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
        # the columns the page shows (the record's others are not kept)
        names = ["step", "time_s", "late_steps"]
        names += [column(p, d) for d in self.dofs for p in ("u", "fc")]
        names += [column(p, c) for c in self.channels for p in ("target", "disp", "force", "error", "ti", "tif")]
        self.columns = History(names, self.window, self.cap)
        self.peak = {**{column("u", d): float("nan") for d in self.dofs},
                     **{column(p, c): float("nan") for c in self.channels for p in ("disp", "force")}}
        self.peak_error = {c: (float("nan"), float("nan")) for c in self.channels}
        self.switches = {d: 0 for d in self.dofs}
        self._ti_state = {c: (0.0, None) for c in self.channels}
        self._tif_state = {c: (0.0, None) for c in self.channels}
        return True

    def _read(self) -> int:
        db = self.db
        if time.monotonic() - self._meta_at > META_EVERY_S:  # the run adds keys (the dry run, the socket)
            self._meta_at = time.monotonic()
            self.meta.update({k: json.loads(v) for k, v in db.execute("SELECT key, value FROM meta")})
        if not self.ns:
            self._read_ns(db)
        steps = self._read_steps(db)
        self._read_events(db)
        self._read_summary(db)
        if steps:
            self.seen_at.append((time.monotonic(), self.n))
            del self.seen_at[:-64]
        return steps

    def _read_events(self, db) -> None:
        """The events committed since the last read, READ_BATCH at a time (a run that wrote many
        warnings is never held whole as rows); the newest EVENTS_KEPT and MARKS_KEPT are kept."""
        while True:
            rows = db.execute("SELECT rowid, time_s, step, kind, actuator, message FROM events WHERE rowid > ? "
                              "ORDER BY rowid LIMIT ?", (self._last_event, self.READ_BATCH)).fetchall()
            for r in rows:
                event = dict(zip(("time_s", "step", "kind", "actuator", "message"), r[1:]))
                self.events.append(event)
                if event["kind"] in MARKS:
                    self.marks.append(event)
                if event["kind"] == "resume" and str(event["message"]).startswith(RESUMED):
                    self._reopened_after = event["step"]
                self._last_event = r[0]
            del self.events[:-EVENTS_KEPT]
            del self.marks[:-MARKS_KEPT]
            if len(rows) < self.READ_BATCH:
                return

    def _read_ns(self, db) -> None:
        """The NS prediction (written whole by the dry run before the first step): every
        ns_stride-th point, the stride that of a history of ``cap`` points, and its peaks."""
        try:
            points = db.execute("SELECT COUNT(*) FROM ns").fetchone()[0]
        except sqlite3.OperationalError:  # no ns table
            return
        if points < 1:
            return
        stride = 1
        while -(-points // stride) > self.cap:
            stride *= 2
        us = [column("u", d) for d in self.dofs]
        table = _table(db, f"SELECT time_s, {', '.join(us)} FROM ns WHERE step % ? = 0 ORDER BY step", (stride,))
        if not table:  # no such columns: a prediction the page cannot show (the steps are read all the same)
            return
        peaks = db.execute(f"SELECT {', '.join(f'MAX(ABS({u}))' for u in us)} FROM ns").fetchone()
        self.ns, self.ns_stride, self.ns_steps = table, stride, points - 1
        self.ns_peak = {d: float("nan") if p is None else float(p) for d, p in zip(self.dofs, peaks)}

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
                before = self.columns.last(column("fc", d))
                modes = fc[d] if np.isnan(before) else np.concatenate([[before], fc[d]])
                self.switches[d] += int(np.count_nonzero(np.diff(modes)))
                block[self.columns.names.index(column("fc", d))] = fc[d]
        for c in self.channels:
            target = block[self.columns.names.index(column("target", c))]
            disp = block[self.columns.names.index(column("disp", c))]
            force = block[self.columns.names.index(column("force", c))]
            dof = self.channel_dof.get(c)
            in_fc = fc[dof] > 0 if dof in fc and len(fc[dof]) else np.zeros(len(rows), bool)
            error = target - np.where(in_fc, force, disp)
            block[self.columns.names.index(column("error", c))] = error
            dc_peak, fc_peak = self.peak_error[c]
            self.peak_error[c] = (_peak(dc_peak, error[~in_fc]), _peak(fc_peak, error[in_fc]))
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
        for name in self.peak:
            self.peak[name] = _peak(self.peak[name], block[self.columns.names.index(name)])
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


def _peak(peak: float, values: np.ndarray) -> float:
    """The larger of ``peak`` and max |values|, NaN ignored (NaN while there is no number)."""
    finite = np.abs(values[np.isfinite(values)])
    return float(np.fmax(peak, finite.max())) if finite.size else peak


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
