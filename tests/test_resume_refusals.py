"""`hsio resume` refuses what it cannot carry on as the run began (docs/safety.md section 8): a
run that compensated its actuators (the compensation's state is not in the record) and a
structure that holds static preloads (a resume would ramp them in again). Exit 2, the record
unchanged, nothing opened."""

from __future__ import annotations

import sqlite3

import pytest
from click.testing import CliRunner

from hsio.cli import main

from wire import stopped_run


def _rows(out):
    with sqlite3.connect(out / "run.sqlite") as db:
        return db.execute("SELECT COUNT(*) FROM steps").fetchone()[0]


@pytest.mark.parametrize("extra, says", [
    ('[compensation]\nmode = "online"\n', "the run compensated its actuators ([compensation] mode = 'online')"),
    ('[structure]\nname = "preloaded_column"\n', "the structure holds static preloads"),
])
def test_a_run_resume_cannot_continue_as_it_began_is_refused(tmp_path, extra, says):
    out = stopped_run(tmp_path, 5, extra=extra)
    before = _rows(out)
    result = CliRunner().invoke(main, ["resume", str(out)])
    assert result.exit_code == 2, result.output
    assert says in result.output and "the record is unchanged and nothing moved" in result.output
    assert _rows(out) == before
