"""`hsio monitor` given a damaged record, or one of another kind: a finished record that cannot be
read whole is refused before the page is served (exit 2, naming the file and what is wrong),
never served as a page that answers 500 with a traceback (docs/monitor.md, docs/faults.md)."""

from __future__ import annotations

import json
import sqlite3

import pytest

from hsio.monitor.feed import RecordFeed

from test_hostile_input import assert_clear_error, hsio
from test_monitor import write_record


def finished_record(folder, sql: str):
    rec = write_record(folder, 20)
    rec.write_summary({"steps": 20})
    rec.close()
    db = sqlite3.connect(folder / "run.sqlite")
    db.execute(sql)
    db.commit()
    db.close()


@pytest.mark.parametrize("sql, words", [
    ("DELETE FROM meta WHERE key = 'actuator_names'", "no 'actuator_names' in its meta table"),
    ("UPDATE meta SET value = '5' WHERE key = 'dof_names'", "meta dof_names is 5, not a list of names"),
    ("UPDATE meta SET value = '{oops' WHERE key = 'structure'", "not an hsio run record (Expecting"),
    ("UPDATE steps SET time_s = 'abc' WHERE step = 3", "row 3 of its steps table holds 'abc' in time_s, not a number"),
])
def test_a_damaged_finished_record_is_refused_before_the_page_is_served(tmp_path, sql, words):
    finished_record(tmp_path, sql)
    proc = hsio("monitor", tmp_path, "--port", "0", timeout=60)
    assert_clear_error(proc, "hsio monitor: error:", "run.sqlite: not an hsio run record", words)
    assert "serving" not in proc.stdout


def test_units_that_are_not_a_list_of_names_read_as_mm(tmp_path):
    finished_record(tmp_path, "INSERT OR REPLACE INTO meta VALUES ('dof_units', '3')")
    feed = RecordFeed(tmp_path)
    assert feed.poll(force=True) == 20
    assert feed.dof_unit == {"C1": "mm", "C2": "mm"}
    assert json.loads(sqlite3.connect(tmp_path / "run.sqlite").execute(
        "SELECT value FROM meta WHERE key = 'dof_units'").fetchone()[0]) == 3


KILLED_AT_CREATION = """
import os, sqlite3, sys
db = sqlite3.connect(sys.argv[1], isolation_level=None)
db.execute("BEGIN")
db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)")
db.executemany("INSERT INTO meta VALUES (?, ?)", [(str(i), "x" * 4000) for i in range(200)])  # pages on disk
os._exit(0)  # killed before the commit: the tables only in its -journal
"""


@pytest.mark.parametrize("how", ["empty file", "journal beside it"])
def test_a_record_whose_run_was_killed_as_it_created_it_is_named_not_waited_for(tmp_path, how):
    """A run.sqlite with no tables that no run writes (its run killed as it made it) will never hold
    a run: `hsio monitor` says so and why (exit 2) rather than wait for ever, and a page already
    following the folder says the same."""
    import subprocess
    import sys

    from bokeh.document import Document

    from hsio.monitor.operator import Operator
    from hsio.monitor.page import MonitorPage

    path = tmp_path / "run.sqlite"
    if how == "empty file":
        path.touch()
    else:
        subprocess.run([sys.executable, "-c", KILLED_AT_CREATION, str(path)], check=True, timeout=30)
        assert (tmp_path / "run.sqlite-journal").exists()
    proc = hsio("monitor", tmp_path, "--port", "0", timeout=60)
    assert_clear_error(proc, "hsio monitor: error:", "run.sqlite: not an hsio run record",
                       "the run was interrupted while it created its record")
    assert "serving" not in proc.stdout
    page = MonitorPage(Document(), RecordFeed(tmp_path), Operator(tmp_path))
    assert "holds no run and no run is writing it" in page.status.text
    assert "interrupted while it created its record" in page.status.text


def test_a_record_a_run_is_creating_is_waited_for(tmp_path):
    """The same empty file held by its writer (a run creating its record) is a record to come: the
    page waits for it, and the writer's lock is read without being taken (the writer keeps it)."""
    import fcntl
    import os

    from bokeh.document import Document

    from hsio.monitor.operator import Operator
    from hsio.monitor.page import MonitorPage
    from hsio.recording import Recorder, being_written

    path = tmp_path / "run.sqlite"
    fd = os.open(path, os.O_CREAT | os.O_WRONLY)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    try:
        assert being_written(path) is True
        page = MonitorPage(Document(), RecordFeed(tmp_path), Operator(tmp_path))
        assert "waiting for" in page.status.text and "no run is writing it" not in page.status.text
    finally:
        os.close(fd)
    assert being_written(path) is False
    rec = Recorder(tmp_path / "other" / "run.sqlite", ["C1"], ["C1"], {})
    assert being_written(rec.path) is True  # a run writing its record
    rec.close()
    assert being_written(rec.path) is False


def test_a_run_that_does_not_answer_is_told_apart_by_the_lock_on_its_record(tmp_path):
    """No summary and no answer on the socket: a run still writing its record (its lock held) is
    not called killed; with no writer left, the page says the run ended without its summary."""
    import fcntl
    import html
    import os
    import re

    from bokeh.document import Document

    from hsio.monitor.page import MonitorPage

    class Silent:
        answers, log = False, []

        def status(self):
            return ""

    write_record(tmp_path, 20).close()

    def state():
        page = MonitorPage(Document(), RecordFeed(tmp_path), Silent())
        return html.unescape(re.search(r"hsio-state'>([^<]*)<", page.status.text).group(1))

    assert "no run writes the record: the run ended without its summary" in state()
    fd = os.open(tmp_path / "run.sqlite", os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert "though a run still writes the record" in state()
    finally:
        os.close(fd)


def test_a_kernel_whose_lock_table_lists_no_flock_tells_nothing_of_the_writer(tmp_path, monkeypatch):
    """Where /proc/locks is there but lists no flock (a sandboxed kernel, an emulation layer), a
    record missing from it is not taken as one no run writes: that is not known (None), the run is
    not called ended, and a record being created is not refused."""
    import builtins
    import html
    import re

    from bokeh.document import Document

    from hsio import recording
    from hsio.monitor.page import MonitorPage

    empty = tmp_path / "locks"
    empty.write_text("")
    real_open = builtins.open
    monkeypatch.setattr(builtins, "open", lambda f, *a, **k: real_open(empty if f == "/proc/locks" else f, *a, **k))
    monkeypatch.setattr(recording, "_flock_listed", False, raising=False)

    class Silent:
        answers, log = False, []

        def status(self):
            return ""

    write_record(tmp_path, 20).close()
    assert recording.being_written(tmp_path / "run.sqlite") is None
    page = MonitorPage(Document(), RecordFeed(tmp_path), Silent())
    state = html.unescape(re.search(r"hsio-state'>([^<]*)<", page.status.text).group(1))
    assert "no run writes the record" not in state and "no answer from the run's control socket" in state
    (tmp_path / "new").mkdir()
    (tmp_path / "new" / "run.sqlite").touch()  # a run creating its record, its lock unseen
    page = MonitorPage(Document(), RecordFeed(tmp_path / "new"), Silent())
    assert "waiting for" in page.status.text and "no run is writing it" not in page.status.text
