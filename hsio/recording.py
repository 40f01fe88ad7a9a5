"""Recording: every step written durably to an SQLite file as it happens.

One file per run (``run.sqlite``), readable by any SQLite tool, pandas or MATLAB:

* ``meta``: key/value (JSON) - configuration, structure, DOF and actuator names, units, versions.
* ``steps``: one row per integration step - time, and per DOF ``u_``, ``v_``, ``a_``,
  ``u_pred_`` (mm, mm/s, mm/s^2), ``r_`` (restoring force, kN), ``mode_`` (displacement or force);
  per actuator ``target_``, ``command_``, ``disp_`` (mm or kN by mode), ``force_`` (kN).
* ``samples``: one row per controller period - step, sample index, per actuator ``cmd_``,
  ``disp_``, ``force_``.
* ``ns``: the purely numerical simulation, per step ``u_`` per DOF.
* ``summary``: key/value (JSON), written at the end.
* ``compensation`` (when the run has a compensation stage): one row per step - per actuator
  ``dc_``, ``da_`` (command and adjusted command, mm), ``v_`` (mm/s), ``er_cc_`` or ``er_ca_`` and
  ``er_aa_`` (execution errors / d_max), ``a_``, ``b_`` (parameters used), see hsio.compensation.

Each step is committed (WAL journal): a run that stops for any reason keeps every step it made.
"""

from __future__ import annotations

import json
import re
import sqlite3
from pathlib import Path

import numpy as np

_NAME = re.compile(r"[^0-9A-Za-z_]")


def column(prefix: str, name: str) -> str:
    return f"{prefix}_{_NAME.sub('_', name)}"


class Recorder:
    """Writes a run, step by step, to ``path`` (an SQLite database)."""

    def __init__(self, path: str | Path, dof_names, actuator_names, meta: dict | None = None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists():
            self.path.unlink()
        self.dof_names = list(dof_names)
        self.actuator_names = list(actuator_names)
        self.db = sqlite3.connect(self.path)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=NORMAL")
        dof_cols = [column(p, d) for d in self.dof_names for p in ("u", "v", "a", "u_pred", "r")]
        mode_cols = [column("mode", d) for d in self.dof_names]
        act_cols = [column(p, a) for a in self.actuator_names for p in ("target", "command", "disp", "force")]
        self._step_cols = ["step", "time_s", *dof_cols, *mode_cols, *act_cols]
        self._sample_cols = ["step", "k", *[column(p, a) for a in self.actuator_names for p in ("cmd", "disp", "force")]]
        self._ns_cols = ["step", "time_s", *[column("u", d) for d in self.dof_names]]
        self.db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)")
        self.db.execute("CREATE TABLE summary (key TEXT PRIMARY KEY, value TEXT)")
        self.db.execute(
            "CREATE TABLE steps (step INTEGER PRIMARY KEY, time_s REAL, "
            + ", ".join(f"{c} {'TEXT' if c.startswith('mode_') else 'REAL'}" for c in self._step_cols[2:]) + ")"
        )
        self.db.execute("CREATE TABLE samples (step INTEGER, k INTEGER, " + ", ".join(f"{c} REAL" for c in self._sample_cols[2:]) + ")")
        self.db.execute("CREATE TABLE ns (step INTEGER PRIMARY KEY, time_s REAL, " + ", ".join(f"{c} REAL" for c in self._ns_cols[2:]) + ")")
        meta = dict(meta or {})
        meta.update(dof_names=self.dof_names, actuator_names=self.actuator_names,
                    units={"displacement": "mm", "force": "kN", "time": "s", "mass": "kN s^2/mm"})
        self.db.executemany("INSERT INTO meta VALUES (?, ?)", [(k, json.dumps(v)) for k, v in meta.items()])
        self.db.commit()
        self._insert_step = f"INSERT INTO steps VALUES ({', '.join('?' * len(self._step_cols))})"
        self._insert_sample = f"INSERT INTO samples VALUES ({', '.join('?' * len(self._sample_cols))})"
        self._insert_ns = f"INSERT INTO ns VALUES ({', '.join('?' * len(self._ns_cols))})"
        self.steps_written = 0
        self._extra_tables: dict[str, list[str]] = {}

    def write_step(self, step: int, time_s: float, u, v, a, u_pred, r, modes, targets, commands, disp, force, samples=None) -> None:
        """One integration step; ``samples`` is n x n_actuators x 3 (command, disp, force)."""
        row = [step, time_s]
        for k in range(len(self.dof_names)):
            row += [float(u[k]), float(v[k]), float(a[k]), float(u_pred[k]), float(r[k])]
        row += [str(m) for m in modes]
        for j in range(len(self.actuator_names)):
            row += [float(targets[j]), float(commands[j]), float(disp[j]), float(force[j])]
        self.db.execute(self._insert_step, row)
        if samples is not None and len(samples):
            flat = np.asarray(samples, dtype=float).reshape(len(samples), -1)
            self.db.executemany(self._insert_sample, [(step, k, *map(float, r_)) for k, r_ in enumerate(flat)])
        self.db.commit()
        self.steps_written += 1

    def write_row(self, table: str, step: int, row: dict) -> None:
        """One step of an extra table (``compensation``, ``implicit``), created on first use with
        the row's keys as REAL columns; committed with the step's row by :meth:`write_step`."""
        if table not in self._extra_tables:
            names = [_NAME.sub("_", k) for k in row]
            self._extra_tables[table] = names
            self.db.execute(f"CREATE TABLE {table} (step INTEGER PRIMARY KEY, " + ", ".join(f"{c} REAL" for c in names) + ")")
        n = len(self._extra_tables[table])
        self.db.execute(f"INSERT INTO {table} VALUES ({', '.join('?' * (n + 1))})",
                        [step, *(None if x is None else float(x) for x in row.values())])

    def write_compensation(self, step: int, row: dict) -> None:
        """One step of the compensation stage (Er^cc, or Er^ca and Er^aa, per actuator)."""
        self.write_row("compensation", step, row)

    def write_ns(self, t: np.ndarray, u: np.ndarray) -> None:
        self.db.executemany(self._insert_ns, [(i, float(t[i]), *map(float, u[i])) for i in range(len(t))])
        self.db.commit()

    def write_summary(self, summary: dict) -> None:
        self.db.executemany("INSERT OR REPLACE INTO summary VALUES (?, ?)", [(k, json.dumps(v)) for k, v in summary.items()])
        self.db.commit()

    def close(self) -> None:
        if self.db is not None:
            self.db.commit()
            self.db.close()
            self.db = None


class Run:
    """A recorded run, read back as arrays (for plots, calibration and diagnostics)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such run file")
        db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True)
        try:
            self.meta = {k: json.loads(v) for k, v in db.execute("SELECT key, value FROM meta")}
            self.summary = {k: json.loads(v) for k, v in db.execute("SELECT key, value FROM summary")}
            self.steps = self._table(db, "steps")
            self.ns = self._table(db, "ns")
            self._db_path = self.path
        finally:
            db.close()
        self.dof_names = self.meta["dof_names"]
        self.actuator_names = self.meta["actuator_names"]

    @staticmethod
    def _table(db, name: str) -> dict[str, np.ndarray]:
        cur = db.execute(f"SELECT * FROM {name} ORDER BY step")
        cols = [c[0] for c in cur.description]
        rows = cur.fetchall()
        out = {}
        for i, c in enumerate(cols):
            values = [r[i] for r in rows]
            out[c] = np.array(values, dtype=object if c.startswith("mode_") else float)
        return out

    def samples(self) -> dict[str, np.ndarray]:
        """Every controller-period sample (may be large)."""
        db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True)
        try:
            return self._table_samples(db)
        finally:
            db.close()

    @staticmethod
    def _table_samples(db) -> dict[str, np.ndarray]:
        cur = db.execute("SELECT * FROM samples ORDER BY step, k")
        cols = [c[0] for c in cur.description]
        data = np.array(cur.fetchall(), dtype=float).reshape(-1, len(cols))
        return {c: data[:, i] for i, c in enumerate(cols)}

    def table(self, name: str) -> dict[str, np.ndarray]:
        """An extra per-step table (``compensation``, ``implicit``); empty if the run has none.
        Missing values are NaN."""
        db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True)
        try:
            if not db.execute("SELECT name FROM sqlite_master WHERE type='table' AND name=?", (name,)).fetchone():
                return {}
            cur = db.execute(f"SELECT * FROM {name} ORDER BY step")
            cols = [c[0] for c in cur.description]
            data = np.array(cur.fetchall(), dtype=float).reshape(-1, len(cols))
            return {c: data[:, i] for i, c in enumerate(cols)}
        finally:
            db.close()

    def compensation(self) -> dict[str, np.ndarray]:
        """The compensation table (empty if the run had none)."""
        return self.table("compensation")

    def dof(self, prefix: str, name: str) -> np.ndarray:
        return self.steps[column(prefix, name)]

    def actuator(self, prefix: str, name: str) -> np.ndarray:
        return self.steps[column(prefix, name)]
