"""The specimen ledger (docs/safety.md section 1): every run on a specimen, in order."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

import hsio
from hsio import config, ledger, runner
from hsio.errors import ConfigError
from hsio.safety.status import BAD_INPUT, DryRunRefused, exit_status


def test_the_ledger_lists_every_run_with_its_state_and_outcome(tmp_path):
    spec = {"id": "wall-07", "folder": str(tmp_path / "wall-07")}
    base = {"record": {"duration_s": 0.3}, "output": {"plots": False}, "specimen": spec}
    runner.run(config.from_dict(base), tmp_path / "a")
    runner.run(config.from_dict({**base, "record": {"duration_s": 0.3, "scale": 2.0}}), tmp_path / "b")
    with pytest.raises(DryRunRefused):  # far too large: refused before anything moves
        runner.run(config.from_dict({**base, "record": {"duration_s": 3.0, "scale": 20.0}}), tmp_path / "c")
    runs = ledger.read(tmp_path / "wall-07")
    assert [r["outcome"] for r in runs] == ["finished", "finished", "refused"]
    assert [r["exit_status"] for r in runs] == [0, 0, 2]
    assert all(r["specimen"] == "wall-07" and r["version"] == hsio.__version__ for r in runs)
    assert runs[1]["config"]["record"]["scale"] == 2.0 and runs[1]["run_dir"].endswith("b")
    first = runs[0]
    assert set(first["start_state"]) == {"C1", "C2"} and "displacement_mm" in first["end_state"]["C1"]
    assert runs[2]["start_state"] is None and runs[2]["dry_run"]["refused"]
    assert all(r["started"] and r["ended"] for r in runs)


def test_an_overridden_dry_run_is_in_the_ledger(tmp_path):
    spec = {"id": "wall-08", "folder": str(tmp_path / "wall-08")}
    cfg = config.from_dict({"record": {"duration_s": 1.0}, "output": {"plots": False}, "specimen": spec,
                            "emulator": {"stroke_mm": 1.0}, "safety": {"override": True}})
    try:
        runner.run(cfg, tmp_path / "a")
    except Exception:
        pass  # the stroke stops the run; what matters here is the ledger
    (entry,) = ledger.read(tmp_path / "wall-08")
    assert entry["override"] == 1 and entry["dry_run"]["exceeded"]


def test_a_ledger_belongs_to_one_specimen(tmp_path):
    ledger.Ledger(tmp_path / "s", "wall-01").close()
    with pytest.raises(ConfigError, match="keeps the ledger of specimen 'wall-01', not 'wall-02'"):
        ledger.Ledger(tmp_path / "s", "wall-02")


@pytest.mark.parametrize("spoil, says", [
    (lambda path: path.write_text("not a database\n"), "file is not a database"),
    (lambda path: sqlite3.connect(path).executescript("CREATE TABLE runs (x INTEGER);"),
     "its runs table has no column id"),
    (lambda path: path.mkdir(), "unable to open database file"),
], ids=["garbage", "other-schema", "folder"])
def test_a_ledger_hsio_cannot_keep_is_refused_before_the_run_folder(tmp_path, spoil, says):
    (tmp_path / "s").mkdir()
    spoil(tmp_path / "s" / ledger.LEDGER_FILE)
    cfg = config.from_dict({"record": {"duration_s": 0.1}, "output": {"plots": False},
                            "specimen": {"folder": str(tmp_path / "s")}})
    with pytest.raises(ConfigError, match=f"specimen ledger .*ledger.sqlite: not a ledger hsio can keep \\({says}"):
        runner.run(cfg, tmp_path / "out")
    assert not (tmp_path / "out").exists()  # no run folder, no record begun


def test_a_specimen_folder_that_is_a_file_is_named_so_before_the_run_folder(tmp_path):
    (tmp_path / "s").write_text("notes\n")
    cfg = config.from_dict({"record": {"duration_s": 0.1}, "output": {"plots": False},
                            "specimen": {"folder": str(tmp_path / "s")}})
    with pytest.raises(ConfigError, match="specimen folder .*s: this is a file, not a folder"):
        runner.run(cfg, tmp_path / "out")
    assert not (tmp_path / "out").exists() and (tmp_path / "s").read_text() == "notes\n"


def test_a_ledger_held_by_another_program_is_told_not_raised_once_the_run_began(tmp_path, monkeypatch):
    """Another program holding the ledger open for writing (a database browser): a run cannot
    begin unlisted (a clear error naming the ledger, no folder left holding only the record's
    meta), and one under way is not ended by it: the row that could not be completed is a
    warning, and the run keeps its outcome and its record."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(ledger.Ledger, "WAIT_S", 0.05)
    spec = {"id": "wall-09", "folder": str(tmp_path / "wall-09")}
    base = {"record": {"duration_s": 0.2}, "output": {"plots": False}, "specimen": spec}
    runner.run(config.from_dict(base), tmp_path / "a")
    other = sqlite3.connect(tmp_path / "wall-09" / ledger.LEDGER_FILE, isolation_level=None)
    real_finish, heard = ledger.Ledger.finish, []

    def held_meanwhile(self, *args, **kwargs):  # the other program takes the ledger as the run ends
        other.execute("BEGIN EXCLUSIVE")
        return real_finish(self, *args, **kwargs)

    monkeypatch.setattr(ledger.Ledger, "finish", held_meanwhile)
    summary = runner.run(config.from_dict(base), tmp_path / "b", notify=heard.append)
    assert summary["exit_status"] == 0
    assert any("could not be updated (database is locked)" in line and "lacks ended, outcome" in line
               for line in heard)
    with pytest.raises(ConfigError, match="cannot list the run in it .database is locked.") as info:
        runner.run(config.from_dict(base), tmp_path / "c")
    assert str(tmp_path / "wall-09" / ledger.LEDGER_FILE) in str(info.value)  # names the ledger
    assert exit_status(info.value) == BAD_INPUT
    assert not (tmp_path / "c").exists()  # not begun: no folder holding only the record's meta
    (tmp_path / "d").mkdir()  # a folder the operator made is kept, empty
    with pytest.raises(ConfigError, match=r"database is locked.*no record was left in it"):
        runner.run(config.from_dict(base), tmp_path / "d")
    assert list((tmp_path / "d").iterdir()) == []
    with pytest.raises(ConfigError, match="no run folder was left"):  # a new numbered folder likewise
        runner.run(config.from_dict(base))
    assert not list(Path("runs").glob("*/run-*"))
    other.execute("COMMIT")
    other.close()
    assert [r["outcome"] for r in ledger.read(tmp_path / "wall-09")] == ["finished", "running"]


def test_a_resume_that_cannot_list_itself_leaves_the_record_as_it_was(tmp_path, monkeypatch):
    from hsio.experiment import ExperimentStopped
    from hsio.recording import Run
    from hsio.safety import resume
    from hsio.safety.control import RunControl

    monkeypatch.setattr(ledger.Ledger, "WAIT_S", 0.05)
    spec = {"id": "wall-10", "folder": str(tmp_path / "wall-10")}
    cfg = config.from_dict({"record": {"duration_s": 0.5}, "output": {"plots": False}, "specimen": spec})
    control = RunControl()
    real_checkpoint = control.checkpoint

    def stop_at_10(site, step, log=None):
        if control.phase == "HS" and step >= 10:
            control.request_stop("stopped by the test")
        return real_checkpoint(site, step, log)

    control.checkpoint = stop_at_10
    with pytest.raises(ExperimentStopped):
        runner.run(cfg, tmp_path / "o", control=control)
    before = Run(tmp_path / "o" / "run.sqlite").events()
    meta_before = Run(tmp_path / "o" / "run.sqlite").meta
    other = sqlite3.connect(tmp_path / "wall-10" / ledger.LEDGER_FILE, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")
    try:
        with pytest.raises(ConfigError, match="cannot list the run in it .database is locked"):
            resume.resume(tmp_path / "o", max_gap_mm=1000.0)
    finally:
        other.execute("COMMIT")
        other.close()
    assert Run(tmp_path / "o" / "run.sqlite").events() == before  # no resume event for a session that never began
    assert Run(tmp_path / "o" / "run.sqlite").meta == meta_before  # nor this session's control socket


def test_a_locked_ledger_under_the_monitor_leaves_no_folder(tmp_path, monkeypatch):
    """`hsio run --monitor` makes the run folder for its page before the run lists itself: a
    ledger held by another program still leaves no folder (numbered or named by --out) holding the
    page's log only."""
    from click.testing import CliRunner

    from hsio.cli import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(ledger.Ledger, "WAIT_S", 0.05)
    spec = {"id": "wall-11", "folder": str(tmp_path / "wall-11")}
    runner.run(config.from_dict({"record": {"duration_s": 0.1}, "output": {"plots": False}, "specimen": spec}),
               tmp_path / "first")
    (tmp_path / "run.toml").write_text('[record]\nduration_s = 0.1\n[output]\nplots = false\n'
                                       f'[specimen]\nid = "wall-11"\nfolder = "{tmp_path / "wall-11"}"\n'
                                       '[safety]\nkeys = false\n')
    other = sqlite3.connect(tmp_path / "wall-11" / ledger.LEDGER_FILE, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")
    try:
        for out in (["--out", str(tmp_path / "named")], []):
            got = CliRunner().invoke(main, ["run", "run.toml", "--monitor", "--monitor-port", "0", *out])
            assert got.exit_code == 2, got.output
            assert "cannot list the run in it" in got.output and "no run folder was left" in got.output, got.output
    finally:
        other.execute("COMMIT")
        other.close()
    assert not (tmp_path / "named").exists() and not list(Path("runs").glob("*/run-*"))


@pytest.mark.parametrize("cell", ["{not json", "", b"\xff\xfe"])
def test_a_ledger_cell_changed_by_another_program_is_named_when_read(tmp_path, cell):
    """A database browser can write anything into a cell: reading the ledger names the run and the
    column instead of ending in a JSON traceback."""
    book = ledger.Ledger(tmp_path / "spec", "s1")
    run_id = book.begin(tmp_path / "r", {"a": 1}, "validation", "synthetic", "0")
    book.db.execute("UPDATE runs SET config = ? WHERE id = ?", (cell, run_id))
    book.db.commit()
    book.close()
    with pytest.raises(ConfigError, match=rf"ledger.*run {run_id}: its config is not the JSON"):
        ledger.read(tmp_path / "spec")


@pytest.mark.parametrize("protect", ["file", "folder"])
def test_a_write_protected_ledger_is_named_as_such_and_read_as_it_is(tmp_path, protect):
    """A specimen's ledger that this user cannot write (the file, or its folder where SQLite writes
    the -wal and -shm beside it): the refusal says so and what to do, not "move it aside" as for a
    damaged file; `hsio.ledger.read` reads it as it is. As root, run as the user nobody
    (setpriv), for whom the permissions hold."""
    import shutil
    import subprocess
    import sys

    from other_user import as_other_user, folder_for

    as_user = as_other_user("write")
    top = folder_for(as_user, tmp_path)
    try:
        spec = top / "wall-ro"
        book = ledger.Ledger(spec, "s1")
        book.finish(book.begin(top / "r", {"a": 1}, "validation", "synthetic", "0"), "finished", 0)
        book.close()
        top.chmod(0o755)
        spec.chmod(0o555 if protect == "folder" else 0o777)
        (spec / "ledger.sqlite").chmod(0o444 if protect == "file" else 0o666)
        script = ("import sys\nfrom hsio import ledger\nfrom hsio.errors import ConfigError\n"
                  "print([r['outcome'] for r in ledger.read(sys.argv[1])])\n"
                  "try:\n    book = ledger.Ledger(sys.argv[1], 's1')\n"
                  "    book.begin('/tmp/x', {}, 'validation', 'synthetic', '0')\n"
                  "except ConfigError as exc:\n    print(exc)\n")
        got = subprocess.run([*as_user, sys.executable, "-c", script, str(spec)], capture_output=True, text=True,
                             timeout=60, cwd="/")
        assert got.returncode == 0, got.stderr
        read, refusal = got.stdout.splitlines()
        assert read == "['finished']"
        assert "move it aside" not in refusal
        what = "the file ledger.sqlite is write-protected" if protect == "file" else f"its folder {spec} is write-protected"
        assert f"specimen ledger {spec / 'ledger.sqlite'}: cannot" in refusal and what in refusal, refusal
        assert "chmod u+w" in refusal and "name another specimen folder" in refusal
    finally:
        for p in (top, *top.rglob("*")):
            p.chmod(0o777) if p.is_dir() else p.chmod(0o666)
        shutil.rmtree(top)
