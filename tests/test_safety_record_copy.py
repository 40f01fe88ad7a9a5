"""A record is its folder (docs/safety.md section 1): what a run commits goes first to the journal
``run.sqlite-wal``; the Recorder copies it into ``run.sqlite`` at its checkpoints, so that file
alone holds the record up to the last one, and a reader given the file without its journal and
without tables says which file is missing."""

from __future__ import annotations

import shutil
import sqlite3

import pytest

from hsio.recording import NotARunError, Recorder, Run


def _step(rec: Recorder, k: int) -> None:
    rec.write_step(k, 0.01 * k, [0.1 * k], [0.0], [0.0], [0.0], [2.0 * k], ["displacement"], [0.1 * k], [0.1 * k],
                   [0.1 * k], [2.0 * k])


def test_run_sqlite_copied_alone_from_a_run_being_written_holds_its_checkpointed_steps(tmp_path, monkeypatch):
    """The writer still open (a run killed now would leave this): run.sqlite copied without its
    -wal holds the meta from the start, and every step committed before the last checkpoint."""
    rec = Recorder(tmp_path / "live" / "run.sqlite", ["x"], ["C1"], {"structure": "s"})
    try:
        shutil.copytree(tmp_path / "live", tmp_path / "early", ignore=shutil.ignore_patterns("*-wal", "*-shm"))
        assert Run(tmp_path / "early" / "run.sqlite").meta["structure"] == "s"  # tables and meta: at creation
        monkeypatch.setattr(Recorder, "CHECKPOINT_S", 0.0)  # a checkpoint after every step
        for k in range(1, 6):
            _step(rec, k)
        assert (tmp_path / "live" / "run.sqlite-wal").exists()  # the writer is still open
        shutil.copytree(tmp_path / "live", tmp_path / "copy", ignore=shutil.ignore_patterns("*-wal", "*-shm"))
    finally:
        rec.close()
    run = Run(tmp_path / "copy" / "run.sqlite")
    assert list(run.steps["step"]) == [1, 2, 3, 4, 5]
    assert list(run.actuator("force", "C1")) == [2.0, 4.0, 6.0, 8.0, 10.0]


def test_a_closed_record_is_whole_in_run_sqlite_though_a_reader_kept_it_open(tmp_path):
    """A reader open when the run ends (the monitor) keeps SQLite's own checkpoint at close from
    running: the Recorder's own checkpoint at close still puts every step into run.sqlite."""
    path = tmp_path / "r" / "run.sqlite"
    rec = Recorder(path, ["x"], ["C1"], {})
    reader = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        reader.execute("SELECT COUNT(*) FROM steps").fetchall()
        for k in range(1, 4):
            _step(rec, k)
        rec.close()
        shutil.copy(path, tmp_path / "run.sqlite")
    finally:
        reader.close()
    assert list(Run(tmp_path / "run.sqlite").steps["step"]) == [1, 2, 3]


def test_run_sqlite_without_its_journal_and_tables_is_named_so(tmp_path):
    """A run.sqlite whose tables were all still in its -wal, copied alone: the error says to copy
    the folder's two files together, not only "no such table"."""
    db = sqlite3.connect(tmp_path / "w.sqlite")
    db.execute("PRAGMA journal_mode=WAL")
    db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)")
    db.commit()
    (tmp_path / "copy").mkdir()
    shutil.copy(tmp_path / "w.sqlite", tmp_path / "copy" / "run.sqlite")  # the journal left behind
    db.close()
    with pytest.raises(NotARunError) as info:
        Run(tmp_path / "copy" / "run.sqlite")
    assert "no such table: meta" in str(info.value)
    assert "no run.sqlite-wal with steps is beside it" in str(info.value)
    assert "copy both files together" in str(info.value)
