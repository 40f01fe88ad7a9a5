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
    ("UPDATE steps SET time_s = 'abc' WHERE step = 3", "could not convert string to float: 'abc'"),
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
