"""Records are never lost (docs/safety.md section 1): a new numbered folder per run, a folder
holding a record refused, the Recorder refusing an existing file, each step durable."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from hsio import config, runner
from hsio.recording import Recorder, RecordExistsError, Run, new_run_folder

ROOT = Path(__file__).resolve().parents[1]
SHORT = {"record": {"duration_s": 0.3}, "output": {"plots": False}}


def hsio(*args, cwd):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "hsio.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=300, env=env, cwd=cwd)


def test_runs_without_out_get_new_numbered_folders(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    first = runner.run(config.from_dict(SHORT))
    second = runner.run(config.from_dict(SHORT))
    assert first["run_dir"] == str(Path("runs/validation/run-0001"))
    assert second["run_dir"] == str(Path("runs/validation/run-0002"))
    for folder in ("run-0001", "run-0002"):
        assert len(Run(tmp_path / "runs/validation" / folder / "run.sqlite").steps["step"]) == 30


def test_out_holding_a_record_is_refused_and_the_record_kept(tmp_path):
    cfg = tmp_path / "short.toml"
    cfg.write_text("[record]\nduration_s = 0.3\n[output]\nplots = false\n")
    out = tmp_path / "o"
    assert hsio("run", cfg, "--out", out, cwd=tmp_path).returncode == 0
    before = (out / "run.sqlite").read_bytes()
    proc = hsio("run", cfg, "--out", out, cwd=tmp_path)
    assert proc.returncode == 2
    assert f"{out / 'run.sqlite'} already holds the record of an earlier run" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert (out / "run.sqlite").read_bytes() == before


def test_the_recorder_refuses_an_existing_file(tmp_path):
    path = tmp_path / "run.sqlite"
    path.write_bytes(b"an earlier record")
    with pytest.raises(RecordExistsError, match="already holds a record"):
        Recorder(path, ["x"], ["A"])
    assert path.read_bytes() == b"an earlier record"


def test_numbered_folders_are_created_atomically(tmp_path):
    made: list[Path] = []
    lock = threading.Lock()

    def take():
        folder = new_run_folder(tmp_path / "runs")
        with lock:
            made.append(folder)

    threads = [threading.Thread(target=take) for _ in range(12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=10)
    assert len(made) == 12 and len(set(made)) == 12


def test_each_step_is_committed_durably(tmp_path):
    rec = Recorder(tmp_path / "run.sqlite", ["x"], ["A"])
    try:
        assert rec.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert rec.db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
    finally:
        rec.close()


def test_records_carry_version_specimen_and_sample_phases(tmp_path):
    import hsio

    summary = runner.run(config.from_dict({**SHORT, "specimen": {"id": "W1", "folder": str(tmp_path / "W1")}}),
                         tmp_path / "o")
    run = Run(tmp_path / "o" / "run.sqlite")
    assert run.meta["version"] == hsio.__version__ and run.meta["specimen_id"] == "W1"
    assert summary["exit_status"] == 0
    samples = run.samples()
    assert set(samples["phase_C1"]) <= set(run.meta["phase_codes"].values())
    assert {0, 1} <= set(samples["phase_C1"].astype(int))  # interpolate and dwell (ramp-hold)
    assert (samples["lab_time_s"][1:] > samples["lab_time_s"][:-1]).all()  # lab time stamps, increasing
    assert "late_steps" in run.steps and "flags" in run.steps


def test_a_record_in_a_folder_named_with_uri_characters_is_read_and_resumed(tmp_path):
    """SQLite opens records through a URI: a '#', '?' or '%' in a folder's name must not cut the
    path short (which opened another file, read-write, and created it)."""
    from click.testing import CliRunner

    from hsio.cli import main
    from wire import stopped_run

    out = tmp_path / "wall #3?a%20b"
    stopped_run(tmp_path, 5, out=out)
    run = Run(out / "run.sqlite")
    assert len(run.steps["step"]) == 5 and run.summary["exit_status"] == 5 and run.events()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["run.toml", out.name])  # nothing else created
    result = CliRunner().invoke(main, ["resume", str(out)])
    assert result.exit_code == 0, result.output
    assert Run(out / "run.sqlite").summary["exit_status"] == 0


READ_BACK = "import sys; from hsio.recording import Run; r = Run(sys.argv[1]); print(len(r.steps['step']), len(r.events()))"


def test_a_write_protected_record_is_read_and_not_resumed(tmp_path):
    """An archived record, its folder and files write-protected, read by a user who cannot write
    there (as root: the user nobody, through setpriv): read back whole; `hsio resume` refused by
    name, exit 2."""
    import shutil
    import stat

    from other_user import as_other_user, folder_for
    from wire import stopped_run

    as_user = as_other_user("read")
    folder = folder_for(as_user, tmp_path)
    try:
        out = stopped_run(tmp_path, 5)
        archived = folder / "archived"
        shutil.copytree(out, archived)
        for p in archived.iterdir():
            p.chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
        for d in (archived, folder):
            d.chmod(0o555)
        env = {**os.environ, "PYTHONPATH": str(ROOT), "HOME": str(folder)}
        read = subprocess.run([*as_user, sys.executable, "-c", READ_BACK, str(archived / "run.sqlite")],
                              capture_output=True, text=True, timeout=120, env=env)
        if as_user and ("Permission denied" in read.stderr and "hsio" not in read.stderr or read.returncode in (126, 127)):
            pytest.skip(f"the user nobody cannot start this Python: {read.stderr.strip()[-200:]}")
        assert read.returncode == 0, read.stderr
        assert read.stdout.split() == ["5", str(len(Run(out / "run.sqlite").events()))]
        resumed = subprocess.run([*as_user, sys.executable, "-m", "hsio.cli", "resume", str(archived)],
                                 capture_output=True, text=True, timeout=120, env=env)
        assert resumed.returncode == 2, resumed.stderr
        assert "cannot write to" in resumed.stderr and "Traceback" not in resumed.stderr
        assert sorted(p.name for p in archived.iterdir()) == ["run.sqlite", "summary.json"]
    finally:
        for d in (folder, *folder.rglob("*")):
            if d.is_dir():
                d.chmod(0o755)
        shutil.rmtree(folder, ignore_errors=True)


def test_a_full_disk_stops_the_run_holding_and_keeps_the_steps_before(tmp_path, monkeypatch):
    """The disk fills at step 5: that step is not kept in part (its row without its samples), the
    run stops like any fault (actuators held, exit status 3), and a summary that cannot be written
    is a warning, not a traceback."""
    import errno
    import sqlite3

    from hsio.experiment import ExperimentStopped
    from hsio.safety.status import exit_status

    real_step = Recorder._write_step

    def filling(self, step, row, samples, sample_meta):
        if step < 5:
            return real_step(self, step, row, samples, sample_meta)
        self.db.execute(self._insert_step, row)  # the step's row goes in, its samples do not
        raise sqlite3.OperationalError("database or disk is full")

    real_write_text = Path.write_text

    def full_disk(self, *args, **kwargs):
        if self.name.startswith("summary.json"):
            self.write_bytes(b"")  # a full disk takes the file, not its text
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write_text(self, *args, **kwargs)

    monkeypatch.setattr(Recorder, "_write_step", filling)
    monkeypatch.setattr(Path, "write_text", full_disk)
    heard = []
    with pytest.raises(ExperimentStopped) as stopped:
        runner.run(config.from_dict(SHORT), tmp_path / "o", notify=heard.append)
    assert exit_status(stopped.value) == 3
    assert "step 5 could not be written (database or disk is full)" in str(stopped.value)
    assert "the actuators hold (confirmed by read-back)" in str(stopped.value)
    assert any("WARNING: the summary could not be written" in line and "No space left" in line for line in heard)
    run = Run(tmp_path / "o" / "run.sqlite")
    assert list(run.steps["step"]) == [1, 2, 3, 4] and set(run.samples()["step"]) == {1, 2, 3, 4}
    assert run.events()[-1]["kind"] == "stop"
    assert run.summary["exit_status"] == 3  # the record's summary, though summary.json could not be written
    assert sorted(p.name for p in (tmp_path / "o").iterdir() if p.name.startswith("summary")) == []  # none cut short


def test_a_summary_that_cannot_be_written_leaves_the_earlier_one_whole(tmp_path, monkeypatch):
    """A resumed session on a full disk: summary.json keeps the earlier session's summary whole
    (not a file cut short); the record's summary table, which a resume reads, is still written."""
    import errno
    import json

    from click.testing import CliRunner

    from hsio.cli import main
    from wire import stopped_run

    out = stopped_run(tmp_path, 5)
    before = (out / "summary.json").read_text()
    assert json.loads(before)["exit_status"] == 5
    real_write_text = Path.write_text

    def full_disk(self, *args, **kwargs):
        if self.name.startswith("summary.json"):
            real_write_text(self, "{")  # the disk fills after the first byte
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write_text(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full_disk)
    result = CliRunner().invoke(main, ["resume", str(out)])
    assert result.exit_code == 0, result.output
    assert "WARNING: the summary could not be written" in result.output
    assert (out / "summary.json").read_text() == before
    assert not (out / "summary.json.partial").exists()
    assert Run(out / "run.sqlite").summary["exit_status"] == 0


def test_a_summary_that_fails_half_way_replaces_nothing(tmp_path):
    """Recorder.write_summary(replace=True) is all or nothing: a failure after the old entries were
    deleted does not leave the deletion for the next commit (the close) to keep."""
    recorder = Recorder(tmp_path / "run.sqlite", ["x"], ["A"])
    recorder.write_summary({"exit_status": 5, "steps": 7})
    with pytest.raises(TypeError):
        recorder.write_summary({"steps": object()}, replace=True)
    recorder.close()
    assert Run(tmp_path / "run.sqlite").summary == {"exit_status": 5, "steps": 7}


@pytest.mark.parametrize("fault", ["read-only", "full"])
def test_a_record_that_cannot_be_created_is_a_clear_refusal(tmp_path, monkeypatch, fault):
    """An --out folder on a read-only file system, or a disk already full when the record is
    created: exit status 2 naming the record and why, no traceback, nothing moved, no folder of
    this run left behind."""
    import errno
    import sqlite3

    from click.testing import CliRunner

    from hsio import recording
    from hsio.cli import main

    if fault == "read-only":
        def refuse(path, flags, mode=0o777):
            raise OSError(errno.EROFS, "Read-only file system", str(path))

        monkeypatch.setattr(recording.os, "open", refuse)
    else:
        def full(self, meta):
            self.db = sqlite3.connect(self.path)
            raise sqlite3.OperationalError("database or disk is full")

        monkeypatch.setattr(Recorder, "_create", full)
    cfg = tmp_path / "short.toml"
    cfg.write_text("[record]\nduration_s = 0.3\n[output]\nplots = false\n[safety]\nkeys = false\n")
    out = tmp_path / "o"
    result = CliRunner().invoke(main, ["run", str(cfg), "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    reason = "Read-only file system" if fault == "read-only" else "database or disk is full"
    assert f"{out / 'run.sqlite'}: cannot create the record: {reason}" in result.output
    assert not out.exists()


def test_a_disk_that_fills_before_the_first_step_is_a_clear_stop(tmp_path, monkeypatch):
    """The record is created, then the disk fills as the dry run's NS is written (SQLite's page
    limit: a real 'database or disk is full'): exit status 2 naming what could not be written, no
    traceback, before the hardware opens."""
    from click.testing import CliRunner

    from hsio.cli import main

    real_create = Recorder._create

    def tight(self, meta):
        real_create(self, meta)
        pages = self.db.execute("PRAGMA page_count").fetchone()[0]
        self.db.execute(f"PRAGMA max_page_count = {pages}")

    monkeypatch.setattr(Recorder, "_create", tight)
    cfg = tmp_path / "short.toml"
    cfg.write_text("[record]\nduration_s = 3.0\n[output]\nplots = false\n[safety]\nkeys = false\n")
    result = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert f"{tmp_path / 'o' / 'run.sqlite'}: the NS could not be written (database or disk is full)" in result.output
    assert "the actuators stand at" not in result.output


@pytest.mark.parametrize("thing", ["file", "folder"])
def test_a_file_in_the_control_sockets_way_is_kept_and_refused(tmp_path, thing):
    """A file or folder named control.sock in the --out folder is not a socket a killed run left:
    it is not removed, and the run is refused by name (exit 2, no traceback, no record left)."""
    from click.testing import CliRunner

    from hsio.cli import main

    out = tmp_path / "o"
    out.mkdir()
    if thing == "file":
        (out / "control.sock").write_text("notes")
    else:
        (out / "control.sock").mkdir()
    cfg = tmp_path / "short.toml"
    cfg.write_text("[record]\nduration_s = 0.3\n[output]\nplots = false\n[safety]\nkeys = false\n")
    result = CliRunner().invoke(main, ["run", str(cfg), "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert "a file that is not a control socket is in the way" in result.output
    assert sorted(p.name for p in out.iterdir()) == ["control.sock"]
    assert thing != "file" or (out / "control.sock").read_text() == "notes"


@pytest.mark.parametrize("option", [["--out"], ["--out", "--monitor", "--monitor-port", "0"], ["--specimen"]])
def test_a_folder_name_too_long_for_the_file_system_is_a_clear_refusal(tmp_path, monkeypatch, option):
    """A run folder or specimen folder whose name the file system cannot hold (over 255 bytes):
    exit 2 naming the folder and why, no traceback, nothing made."""
    from click.testing import CliRunner

    from hsio.cli import main

    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "short.toml"
    cfg.write_text("[record]\nduration_s = 0.3\n[output]\nplots = false\n")
    name = "x" * 300
    args = ["run", str(cfg), option[0], name, *option[1:]]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    assert "File name too long" in result.output and name in result.output
    assert not isinstance(result.exception, OSError)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["short.toml"]
