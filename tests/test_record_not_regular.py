"""A run folder whose run.sqlite is not a regular file: a FIFO (SQLite would wait on it for
ever) or a folder. `hsio resume`, `hsio diagnose --run`, `hsio calibrate` and `hsio monitor`
refuse it at once, naming it (exit 2), as docs/faults.md says of every file hsio reads."""

from __future__ import annotations

import os

import pytest

from hsio.errors import RecordError
from hsio.recording import Run

from test_hostile_input import assert_clear_error, hsio

COMMANDS = [["resume"], ["diagnose", "--run"], ["calibrate"], ["monitor", "--port", "0", "{dir}"]]


def fifo_run(tmp_path):
    os.mkfifo(tmp_path / "run.sqlite")
    return tmp_path


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c[:2]))
def test_a_fifo_in_place_of_the_record_is_refused_not_waited_on(tmp_path, command):
    folder = fifo_run(tmp_path)
    args = [a.format(dir=folder) for a in command] if "{dir}" in command else [*command, folder]
    proc = hsio(*args, timeout=30)
    assert_clear_error(proc, "run.sqlite", "not a regular file")


def test_a_folder_in_place_of_the_record_is_named_by_calibrate(tmp_path):
    (tmp_path / "run.sqlite").mkdir()
    proc = hsio("calibrate", tmp_path, timeout=30)
    assert_clear_error(proc, "run.sqlite: not a regular file")


def test_run_refuses_a_fifo(tmp_path):
    with pytest.raises(RecordError, match="run.sqlite: not a regular file"):
        Run(fifo_run(tmp_path) / "run.sqlite")
