"""The specimen ledger: one SQLite file per specimen folder listing every run made on it
(docs/safety.md section 1).

A specimen is usually tested several times in a row (small, design-level, then large
earthquakes) and only once in its life: the ledger says what was done to it, in order. Each run
gets a row when it starts (outcome ``running``) and is completed when it ends: the run folder,
the configuration, the software version, the state of the specimen at the start and at the end
(measured displacement and force per actuator), whether the dry run was overridden, the outcome
and the exit status. A row left ``running`` belongs to a run that was killed or lost power.

Every write is committed durably (WAL, ``synchronous=FULL``).
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from pathlib import Path

from hsio.errors import ConfigError

LEDGER_FILE = "ledger.sqlite"

_COLUMNS = ("id", "specimen", "run_dir", "started", "ended", "version", "structure", "record", "config",
            "start_state", "end_state", "dry_run", "override", "outcome", "exit_status", "message")
_JSON = {"config", "start_state", "end_state", "dry_run"}


WRITABLE = ("let hsio write there (chmod u+w, or a disk mounted writable), or name another specimen folder "
            "(--specimen DIR, [specimen] folder)")


def unwritable(path: Path) -> str | None:
    """Why this process cannot write the ledger at ``path`` (a read-only file system, the file or
    its folder write-protected: SQLite writes its journal ``-wal`` and index ``-shm`` beside the
    file), or None when it can."""
    folder = path.parent
    try:
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            return f"{folder} is on a file system mounted read-only"
    except OSError:
        return None
    if path.exists() and not os.access(path, os.W_OK):
        return f"the file {path.name} is write-protected"
    if not os.access(folder, os.W_OK):
        return (f"its folder {folder} is write-protected: SQLite writes {path.name}-wal and {path.name}-shm "
                f"beside the file")
    return None


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


class Ledger:
    """The ledger of the specimen kept in ``folder`` (created if needed)."""

    WAIT_S = 10.0  # how long a write waits for another program that holds the ledger

    def __init__(self, folder: str | Path, specimen_id: str = "", warn=None):
        self.folder = Path(folder)
        self.warn = warn or (lambda line: None)  # hears a row that could not be updated
        try:
            if self.folder.exists() and not self.folder.is_dir():
                raise ConfigError(f"specimen folder {self.folder}: this is a file, not a folder; name a folder for the "
                                  f"specimen's ledger")
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"specimen folder {self.folder}: cannot create it: {exc.strerror}") from None
        self.path = self.folder / LEDGER_FILE
        self.db = None
        try:
            self._open(specimen_id)
        except sqlite3.Error as exc:
            self.close()
            reason = unwritable(self.path)
            if reason:
                raise ConfigError(f"specimen ledger {self.path}: cannot write to it ({reason}): {WRITABLE}") from None
            raise ConfigError(f"specimen ledger {self.path}: not a ledger hsio can keep ({exc}); move it aside or "
                              f"name another specimen folder") from None

    def _open(self, specimen_id: str) -> None:
        self.db = sqlite3.connect(self.path, timeout=self.WAIT_S)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=FULL")
        self.db.execute("CREATE TABLE IF NOT EXISTS specimen (key TEXT PRIMARY KEY, value TEXT)")
        self.db.execute("CREATE TABLE IF NOT EXISTS runs (id INTEGER PRIMARY KEY AUTOINCREMENT, specimen TEXT, "
                        "run_dir TEXT, started TEXT, ended TEXT, version TEXT, structure TEXT, record TEXT, "
                        "config TEXT, start_state TEXT, end_state TEXT, dry_run TEXT, override INTEGER, "
                        "outcome TEXT, exit_status INTEGER, message TEXT)")
        for table, wanted in (("specimen", ("key", "value")), ("runs", _COLUMNS)):
            have = {r[1] for r in self.db.execute(f"PRAGMA table_info({table})")}
            missing = [c for c in wanted if c not in have]
            if missing:
                raise sqlite3.DatabaseError(f"its {table} table has no column {', '.join(missing)}")
        row = self.db.execute("SELECT value FROM specimen WHERE key = 'id'").fetchone()
        wanted = specimen_id or self.folder.resolve().name
        if row is None:
            self.db.execute("INSERT INTO specimen VALUES ('id', ?)", (wanted,))
            self.db.execute("INSERT INTO specimen VALUES ('created', ?)", (_now(),))
            self.specimen_id = wanted
        else:
            self.specimen_id = row[0]
            if specimen_id and specimen_id != self.specimen_id:
                self.db.close()
                raise ConfigError(f"specimen folder {self.folder} keeps the ledger of specimen {self.specimen_id!r}, "
                                  f"not {specimen_id!r}: check [specimen] id and folder")
        self.db.commit()

    def begin(self, run_dir: str | Path, config: dict, structure: str, record: str, version: str) -> int:
        """A new row for a run that starts now; returns its id. A ledger that cannot take it (locked
        by another program beyond the wait, a full disk) is a ConfigError: the run does not start
        unlisted."""
        try:
            cur = self.db.execute(
                "INSERT INTO runs (specimen, run_dir, started, version, structure, record, config, override, "
                "outcome) VALUES (?, ?, ?, ?, ?, ?, ?, 0, 'running')",
                (self.specimen_id, str(Path(run_dir).resolve()), _now(), version, structure, record,
                 json.dumps(config, default=str)))
            self.db.commit()
        except sqlite3.Error as exc:
            self._rollback()
            reason = unwritable(self.path)
            if reason:
                detail = f"{reason}: {WRITABLE}"
            elif "locked" in str(exc) or "busy" in str(exc):
                detail = (f"database is locked: another program has held it open for writing for more than "
                          f"{self.WAIT_S:g} s, a database browser or another run listing itself; let it go and "
                          f"start the run again")
            else:
                detail = f"{exc}; check the disk and the ledger file"
            raise ConfigError(f"specimen ledger {self.path}: cannot list the run in it ({detail}); the run did not "
                              f"begin, nothing was sent to the actuators") from None
        return int(cur.lastrowid)

    def _rollback(self) -> None:
        try:
            self.db.rollback()
        except sqlite3.Error:
            pass

    def update(self, run_id: int, **values) -> None:
        """Set columns of a run's row (start_state, end_state, dry_run, override, ...). A ledger that
        cannot take it (locked by another program beyond the wait) is told to ``warn``, not raised."""
        bad = set(values) - set(_COLUMNS)
        if bad:
            raise ValueError(f"ledger: unknown columns {sorted(bad)}")
        cols = ", ".join(f"{k} = ?" for k in values)
        args = [json.dumps(v, default=str) if k in _JSON else v for k, v in values.items()]
        try:
            self.db.execute(f"UPDATE runs SET {cols} WHERE id = ?", (*args, run_id))
            self.db.commit()
        except sqlite3.Error as exc:  # the run goes on or ends as it would: its record has what is missed here
            self._rollback()
            self.warn(f"WARNING: the specimen ledger {self.path} could not be updated ({exc}): its row {run_id} "
                      f"lacks {', '.join(values)} of this run; the run's record (run.sqlite, summary.json) has them")

    def finish(self, run_id: int, outcome: str, exit_status: int, message: str = "", end_state=None) -> None:
        self.update(run_id, ended=_now(), outcome=outcome, exit_status=int(exit_status), message=message,
                    end_state=end_state)

    def runs(self) -> list[dict]:
        """Every run on the specimen, oldest first."""
        return _rows(self.db, self.path)

    def close(self) -> None:
        if self.db is not None:
            self.db.close()
            self.db = None


def read(folder: str | Path) -> list[dict]:
    """The runs listed in the ledger of ``folder``, read only: a write-protected ledger (an archived
    specimen) is read as it is."""
    from hsio.recording import connect_read_only

    path = Path(folder) / LEDGER_FILE
    if not path.exists():
        raise ConfigError(f"{folder}: no specimen ledger ({LEDGER_FILE})")
    try:
        db = connect_read_only(path)
    except sqlite3.Error as exc:
        raise ConfigError(f"specimen ledger {path}: cannot be read ({exc})") from None
    try:
        return _rows(db, path)
    except sqlite3.Error as exc:
        raise ConfigError(f"specimen ledger {path}: not a ledger hsio wrote ({exc})") from None
    finally:
        db.close()


def _rows(db: sqlite3.Connection, path: Path) -> list[dict]:
    """The rows of the ledger's ``runs`` table, oldest first, JSON columns decoded."""
    cur = db.execute(f"SELECT {', '.join(_COLUMNS)} FROM runs ORDER BY id")
    out = []
    for row in cur.fetchall():
        entry = dict(zip(_COLUMNS, row))
        for k in _JSON:
            if entry[k] is not None:
                try:
                    entry[k] = json.loads(entry[k])
                except (TypeError, ValueError) as exc:  # edited by another program
                    raise ConfigError(f"specimen ledger {path}: run {entry['id']}: its {k} is not the JSON "
                                      f"hsio writes ({str(entry[k])[:40]!r}: {exc}); another program changed "
                                      f"it: read that row with an SQLite tool") from None
        out.append(entry)
    return out
