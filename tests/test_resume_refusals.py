"""`hsio resume` refuses what it cannot carry on as the run began (docs/safety.md section 8): a
run that compensated its actuators (the compensation's state is not in the record) and a
structure that holds static preloads (a resume would ramp them in again). Exit 2, the record
unchanged, nothing opened."""

from __future__ import annotations

import sqlite3

import pytest
from click.testing import CliRunner

from hsio import config as config_mod
from hsio import runner
from hsio.cli import main
from hsio.experiment import ExperimentStopped
from hsio.safety.control import RunControl

from wire import write_config


def _stopped(tmp_path, extra: str, at_step: int = 5):
    control, steps = RunControl(), []

    def stop_at(n):
        steps.append(n)
        if len(steps) == at_step:
            control.request_stop("stopped by the test")

    out = tmp_path / "run"
    with pytest.raises(ExperimentStopped):
        runner.run(config_mod.load(write_config(tmp_path, duration=0.5, rate=5.0, extra=extra)), out, stop_at,
                   control=control)
    return out


def _rows(out):
    with sqlite3.connect(out / "run.sqlite") as db:
        return db.execute("SELECT COUNT(*) FROM steps").fetchone()[0]


@pytest.mark.parametrize("extra, says", [
    ('[compensation]\nmode = "online"\n', "the run compensated its actuators ([compensation] mode = 'online')"),
])
def test_a_run_resume_cannot_continue_as_it_began_is_refused(tmp_path, extra, says):
    out = _stopped(tmp_path, extra)
    before = _rows(out)
    result = CliRunner().invoke(main, ["resume", str(out)])
    assert result.exit_code == 2, result.output
    assert says in result.output and "Nothing was opened or moved" in result.output
    assert _rows(out) == before


def test_a_structure_with_static_preloads_is_not_resumed(tmp_path):
    cfg = write_config(tmp_path, duration=0.5, rate=5.0, extra='[structure]\nname = "preloaded_column"\n',
                       name="pre.toml")
    control, steps = RunControl(), []

    def stop_at(n):
        steps.append(n)
        if len(steps) == 5:
            control.request_stop("stopped by the test")

    out = tmp_path / "pre"
    with pytest.raises(ExperimentStopped):
        runner.run(config_mod.load(cfg), out, stop_at, control=control)
    result = CliRunner().invoke(main, ["resume", str(out)])
    assert result.exit_code == 2, result.output
    assert "holds static preloads" in result.output and "nothing was opened or moved" in result.output
