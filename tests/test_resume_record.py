"""`hsio resume` and the record it continues (docs/safety.md sections 1 and 8): one writer at a
time (a record that a run or another resume is still writing is refused before anything opens);
a record whose meta or last step is damaged is refused by name (exit 2, no traceback, the record
unchanged); a resume that cannot open the hardware says so in the record; the summary and the
specimen ledger describe the whole record after a resume, not the session before it.

The interruption is an operator stop of a short run on the in-process emulator (tests/wire.py
stopped_run), which leaves a record that `hsio resume` continues."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest
from click.testing import CliRunner

from hsio import config as config_mod
from hsio import ledger, runner
from hsio.cli import main
from hsio.errors import RecordError
from hsio.recording import Recorder, Run

from wire import QUIET_SENSORS, refused_port, stopped_run, write_config


def _resume(out):
    result = CliRunner().invoke(main, ["resume", str(out)])
    assert not (result.exception and not isinstance(result.exception, SystemExit)), result.exception
    return result


def _fingerprint(out):
    with sqlite3.connect(out / "run.sqlite") as db:
        return [db.execute(f"SELECT * FROM {t} ORDER BY rowid").fetchall() for t in ("steps", "events", "summary")]


def test_a_record_another_process_writes_is_not_resumed(tmp_path):
    """A resume started while the run (or another resume) still writes the record would command
    the same actuators as a second host and write the same steps again."""
    out = stopped_run(tmp_path, 5)
    before = _fingerprint(out)
    writer = Recorder.append(out / "run.sqlite")  # the live writer: a run or resume still going
    try:
        result = _resume(out)
        assert result.exit_code == 2, result.output
        assert "is being written by another process" in result.output and "nothing moved" in result.output
        assert _fingerprint(out) == before
    finally:
        writer.close()
    assert _resume(out).exit_code == 0  # once the writer let go


def _meta(key, value):
    def damage(db):
        db.execute("UPDATE meta SET value = ? WHERE key = ?", (json.dumps(value), key))
    return damage


def _last_step(column, value):
    def damage(db):
        db.execute(f"UPDATE steps SET {column} = ? WHERE step = (SELECT MAX(step) FROM steps)", (value,))
    return damage


@pytest.mark.parametrize("damage, says", [
    (_meta("config", [1, 2]), "meta config is [1, 2], not a table"),
    (lambda db: db.execute("DELETE FROM meta WHERE key = 'config'"), "its meta holds no configuration table"),
    (_meta("inputs", "x"), "meta inputs is not a list of fingerprints"),
    (_meta("inputs", [{"what": 1}]), "meta inputs is not a list of fingerprints"),
    (_meta("dof_names", 7), "meta dof_names is 7, not a list of names"),
    (_last_step("r_C1", None), "the state of its last committed step 5 is not finite (r_C1)"),
    (_last_step("a_C2", float("inf")), "not finite (a_C2)"),
    (_last_step("step", 10 ** 9), "its last committed step is 1000000000, not one of the record's steps"),
    (lambda db: db.execute("UPDATE steps SET u_C1 = NULL WHERE step = 2"), "its step 2 holds u_C1 = nan"),
    (lambda db: db.execute("DELETE FROM steps WHERE step = 3"), "its steps are not 1..5 one after the other "
                                                                  "(step 3 is missing): the record is damaged"),
    (lambda db: db.execute("DROP TABLE events"), "(no events table)"),
    (lambda db: db.execute("UPDATE summary SET value = ? WHERE key = 'exit_status'", (json.dumps("0"),)),
     'its summary\'s exit_status is "0", not a whole number'),
], ids=["config", "no-config", "inputs-text", "inputs-entry", "dof-names", "nan-force", "inf-acceleration", "step", "hole", "missing-step",
                                  "events", "exit-status-text"])
def test_a_damaged_record_is_refused_by_name(tmp_path, damage, says):
    out = stopped_run(tmp_path, 5)
    with sqlite3.connect(out / "run.sqlite") as db:
        damage(db)
    with sqlite3.connect(out / "run.sqlite") as db:
        before = db.execute("SELECT COUNT(*) FROM steps").fetchone()[0]
    result = _resume(out)
    assert result.exit_code == 2, result.output
    assert says in result.output
    with sqlite3.connect(out / "run.sqlite") as db:
        assert db.execute("SELECT COUNT(*) FROM steps").fetchone()[0] == before


def test_a_record_on_a_full_disk_is_not_resumed(tmp_path, monkeypatch):
    """The disk is full when the resume would mark its session in the record: refused by name
    (exit 2, no traceback) before the hardware opens, the record as it was, the session's ledger
    row closed as refused; once there is room again the same record resumes."""
    out = stopped_run(tmp_path, 5, extra=f'[specimen]\nfolder = "{tmp_path / "spec"}"\n')
    with sqlite3.connect(out / "run.sqlite") as db:
        before = _fingerprint(out) + [db.execute("SELECT * FROM meta ORDER BY key").fetchall()]
    real = Recorder.write_meta

    def full(self, entries):
        self.db.executemany("INSERT OR REPLACE INTO meta VALUES (?, ?)", [(k, json.dumps(v)) for k, v in entries.items()])
        self.db.rollback()  # the commit finds no room
        raise RecordError(f"{self.path}: the meta could not be written (database or disk is full)")

    monkeypatch.setattr(Recorder, "write_meta", full)
    result = _resume(out)
    assert result.exit_code == 2, result.output
    assert "run.sqlite: cannot write to the record (database or disk is full); the record is unchanged and " \
           "nothing moved" in result.output
    assert "the actuators stand at" not in result.output  # the hardware was not opened
    with sqlite3.connect(out / "run.sqlite") as db:
        assert _fingerprint(out) + [db.execute("SELECT * FROM meta ORDER BY key").fetchall()] == before
    rows = ledger.read(tmp_path / "spec")
    assert [r["outcome"] for r in rows] == ["stopped by the operator", "refused"]
    monkeypatch.setattr(Recorder, "write_meta", real)
    assert _resume(out).exit_code == 0


def _resume_with_no_hardware(out):
    """``hsio resume`` of the record in ``out`` with its hardware URL pointing at a port that
    refuses connections."""
    with refused_port() as port, sqlite3.connect(out / "run.sqlite") as db:
        meta = json.loads(db.execute("SELECT value FROM meta WHERE key = 'config'").fetchone()[0])
        meta["hardware"]["url"] = f"modbus+tcp://127.0.0.1:{port}/1"
        db.execute("UPDATE meta SET value = ? WHERE key = 'config'", (json.dumps(meta),))
        db.commit()
        return _resume(out)


def test_a_resume_that_cannot_open_the_hardware_records_why(tmp_path):
    out = stopped_run(tmp_path, 5)
    result = _resume_with_no_hardware(out)
    assert result.exit_code == 3, result.output
    run = Run(out / "run.sqlite")
    kinds = [e["kind"] for e in run.events()]
    assert kinds[-2:] == ["resume", "stop"] and "cannot connect" in run.events()[-1]["message"]
    assert run.summary["exit_status"] == 3 and run.summary["resumed_from"] == 5
    assert json.loads((out / "summary.json").read_text())["exit_status"] == 3


def test_a_resume_that_cannot_open_the_hardware_on_a_full_disk_says_why(tmp_path, monkeypatch):
    """The hardware cannot be opened and the disk has no room left for the stop event: the
    operator still hears why (exit status 3, the link named), not that an event was lost."""
    out = stopped_run(tmp_path, 5)
    real = Recorder.write_event

    def full(self, time_s, step, kind, *args, **kwargs):
        if kind == "stop":
            raise RecordError(f"{self.path}: the stop event could not be written (database or disk is full)")
        return real(self, time_s, step, kind, *args, **kwargs)

    monkeypatch.setattr(Recorder, "write_event", full)
    result = _resume_with_no_hardware(out)
    assert result.exit_code == 3, result.output
    assert "cannot connect" in result.output and "event could not be written" not in result.output


def test_the_summary_and_the_ledger_describe_the_whole_resumed_record(tmp_path):
    spec = f'[specimen]\nid = "wall-r"\nfolder = "{tmp_path / "wall-r"}"\n'
    cfg = write_config(tmp_path, duration=0.5, rate=5.0, extra=QUIET_SENSORS + spec)
    whole = runner.run(config_mod.load(cfg), tmp_path / "whole")  # the same run, never stopped
    out = stopped_run(tmp_path, 20, config_path=cfg, out=tmp_path / "stopped")
    stopped = Run(out / "run.sqlite").summary
    why = Run(out / "run.sqlite").stop_reason()
    assert why and "stopped by" in why
    result = _resume(out)
    assert result.exit_code == 0
    assert f"resuming {out / 'run.sqlite'} after step 20 (the run recorded its stop: {why})" in result.output
    assert Run(out / "run.sqlite").stop_reason() is None  # finished in the resumed session
    last = Run(out / "run.sqlite").steps
    assert (f"the record's last step measured C1 {last['disp_C1'][19]:+.3f} mm; C2 {last['disp_C2'][19]:+.3f} mm"
            in result.output) and "the actuators stand at: C1 " in result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary == Run(out / "run.sqlite").summary
    for name in ("C1", "C2"):  # where the specimen stands at the end, not where the stop left it
        for key in ("displacement_mm", "force_kN"):
            assert summary["end_state"][name][key] == pytest.approx(whole["end_state"][name][key], abs=1e-9)
            assert abs(summary["end_state"][name][key] - stopped["end_state"][name][key]) > 1e-3
    assert summary["max_error_pct"] == pytest.approx(whole["max_error_pct"], abs=1e-9)
    assert np.allclose(summary["peak_displacement_mm"], whole["peak_displacement_mm"], atol=1e-9)
    assert "wall_time_s" not in summary and "rms_tracking_error_mm" not in summary  # the first session's alone
    first, this, again = ledger.read(tmp_path / "wall-r")[-3:]  # the whole run, the stopped one, its resume
    assert this["outcome"] == "stopped by the operator" and this["exit_status"] == 5  # left as it was
    assert this["end_state"] == stopped["end_state"]
    assert again["run_dir"] == this["run_dir"] and "(resumed after step 20)" in again["record"]
    assert again["outcome"] == "finished" and again["exit_status"] == 0
    assert again["end_state"] == summary["end_state"] and set(again["start_state"]) == {"C1", "C2"}
    assert summary["earlier_sessions"] == [stopped]  # the stopped session's summary, as it was


def test_a_resume_names_its_own_control_socket(tmp_path, monkeypatch):
    """A run folder whose path is too long for a UNIX socket gets its socket in a new temporary
    folder each session: the meta that the monitor and other tools read names the resume's."""
    from hsio.safety import resume as resume_mod

    out = stopped_run(tmp_path, 5, out=tmp_path / ("r" * 120))
    first = Run(out / "run.sqlite").meta["control_socket"]
    opened = []
    real = resume_mod.ControlServer

    def server(run_dir, control):
        opened.append(real(run_dir, control))
        return opened[0]

    monkeypatch.setattr(resume_mod, "ControlServer", server)
    assert _resume(out).exit_code == 0
    assert str(opened[0].path) != first
    assert Run(out / "run.sqlite").meta["control_socket"] == str(opened[0].path)


def test_a_resume_through_setups_names_the_actuators_where_they_stand(tmp_path):
    """Through setups the record's channels are the element's basic DOFs (a rotation among them),
    not the actuators: the resume says where the actuators stand, and compares nothing in mm."""
    cfg = write_config(tmp_path, duration=0.1, rate=5.0, extra='[structure]\nname = "column_two_actuators"\n')
    out = stopped_run(tmp_path, 3, config_path=cfg)
    result = _resume(out)
    assert result.exit_code == 0, result.output
    assert "the actuators stand at: lower " in result.output and "; upper " in result.output
    assert "top_rot" not in result.output
    # each actuator's own table goes on after the stop, one row a step
    run = Run(out / "run.sqlite")
    steps = run.table("actuators")["step"]
    np.testing.assert_array_equal(steps, np.arange(1, len(run.steps["step"]) + 1))


def test_actuators_far_from_where_the_record_stops_are_not_resumed(tmp_path):
    """A new in-process emulator stands at rest, 1.05 mm from where the run stopped (step 120 of
    the validation structure): the first step would take the actuators back within one step to a
    specimen without the run's history, so the resume is refused (exit 2) and nothing moves;
    --max-gap, given by the operator, lets it go on."""
    cfg = write_config(tmp_path, duration=2.0, rate=5.0, extra=QUIET_SENSORS)
    out = stopped_run(tmp_path, 120, config_path=cfg)
    steps = len(Run(out / "run.sqlite").steps["step"])
    result = _resume(out)
    assert result.exit_code == 2, result.output
    assert "C1 stands -1.046 mm from the record's last step" in result.stderr
    assert "more than 1 mm: not resumed, nothing moved" in result.stderr and "in-process emulator" in result.stderr
    assert "the actuators hold (confirmed by read-back)" in result.stderr  # opened, held, told
    run = Run(out / "run.sqlite")
    assert len(run.steps["step"]) == steps and [e["kind"] for e in run.events()][-3:] == ["resume", "hold", "stop"]
    assert run.summary["exit_status"] == 2
    result = CliRunner().invoke(main, ["resume", str(out), "--max-gap", "2"])
    assert result.exit_code == 0, result.output


def test_a_channel_that_records_an_instruments_reading_is_not_compared_with_its_rod(tmp_path):
    """An element with displacement_from records its LVDT's reading, which a compliant load train
    keeps c F short of the rod the actuator reports: comparing the two would refuse a resume where
    nothing moved, so that channel is left out of the gaps."""
    from hsio.safety.resume import gaps

    out = stopped_run(tmp_path, 5)
    run = Run(out / "run.sqlite")
    last = {name: float(run.steps[f"disp_{name}"][-1]) for name in ("C1", "C2")}
    standing = {"C1": {"displacement_mm": last["C1"] + 2.0, "force_kN": 0.0},
                "C2": {"displacement_mm": last["C2"] + 0.1, "force_kN": 0.0}}
    assert gaps(standing, run) == pytest.approx({"C1": 2.0, "C2": 0.1})
    assert gaps(standing, run, external=["C1"]) == pytest.approx({"C2": 0.1})


def test_a_run_with_an_external_instrument_resumes_and_its_instruments_log_goes_on(tmp_path):
    """The record's instruments table (one row per trial) is continued by the resumed session: its
    trials are numbered after the record's last one, and none of the earlier rows is lost."""
    from importlib import resources

    wall = (resources.files("hsio") / "library" / "structure_I.toml").read_text()
    text = wall.replace('[[experimental]]\nname = "wall"', '[[experimental]]\nname = "wall"\n'
                        'displacement_from = "wall_lvdt"\nouter_loop = { tolerance_mm = 0.05, max_iterations = 4 }')
    text += '\n[[instrument]]\nname = "wall_lvdt"\nkind = "lvdt"\nelement = "wall"\nresolution = 0.005\n'
    (tmp_path / "wall.toml").write_text(text)
    cfg = write_config(tmp_path, duration=0.5, rate=5.0, extra=f'[structure]\nfile = "{tmp_path / "wall.toml"}"\n')
    out = stopped_run(tmp_path, 5, config_path=cfg)
    before = Run(out / "run.sqlite").table("instruments")
    result = _resume(out)
    assert result.exit_code == 0, result.output
    run = Run(out / "run.sqlite")
    trials = run.table("instruments")["step"]
    assert trials.size == len(run.steps["step"]) > before["step"].size
    assert np.array_equal(trials, np.arange(1, trials.size + 1))
    assert np.array_equal(run.table("instruments")["iterations"][: before["step"].size], before["iterations"])



def test_a_rod_read_by_an_lvdt_is_compared_by_its_own_transducer(tmp_path):
    """An element with displacement_from records its LVDT's reading, but the record's samples
    hold the rod's own transducer: the rod is compared with its last sample of the last committed
    step, so a rod that moved while the run stood still is refused, its stroke named."""
    from importlib import resources

    from hsio.safety.resume import gaps

    wall = (resources.files("hsio") / "library" / "structure_I.toml").read_text()
    text = wall.replace('[[experimental]]\nname = "wall"', '[[experimental]]\nname = "wall"\n'
                        'displacement_from = "wall_lvdt"\nouter_loop = { tolerance_mm = 0.05, max_iterations = 4 }')
    text += '\n[[instrument]]\nname = "wall_lvdt"\nkind = "lvdt"\nelement = "wall"\nresolution = 0.005\n'
    (tmp_path / "wall.toml").write_text(text)
    cfg = write_config(tmp_path, duration=0.5, rate=5.0, extra=f'[structure]\nfile = "{tmp_path / "wall.toml"}"\n')
    cfg.write_text(cfg.read_text().replace("samples = false", "samples = true"))
    out = stopped_run(tmp_path, 20, config_path=cfg)
    run = Run(out / "run.sqlite")
    samples = run.samples(first_step=20)
    rod = samples["disp_wall"][-1]
    assert samples["step"][-1] == 20 and rod != run.steps["disp_wall"][-1]  # the rod, not the LVDT
    assert gaps({"wall": {"displacement_mm": rod + 2.5, "force_kN": 0.0}}, run, ["wall"]) == pytest.approx({"wall": 2.5})
    # a new in-process emulator stands at rest, |rod| from where the record stops
    result = CliRunner().invoke(main, ["resume", str(out), "--max-gap", f"{abs(rod) / 2:.6f}"])
    assert result.exit_code == 2, result.output
    assert f"the record's last step measured wall {rod:+.3f} mm" in result.output
    assert f"wall stands {-rod:+.3f} mm from the record's last step" in result.stderr
    assert len(Run(out / "run.sqlite").steps["step"]) == 20

def test_a_stop_recorded_only_as_an_event_is_told_at_the_resume(tmp_path):
    """A record whose summary lost its ``stopped`` (a process killed while writing it) still tells
    why it stopped, from its stop event."""
    out = stopped_run(tmp_path, 5)
    with sqlite3.connect(out / "run.sqlite") as db:
        db.execute("DELETE FROM summary WHERE key = 'stopped'")
    why = Run(out / "run.sqlite").stop_reason()
    assert why and "stopped by the test" in why
    result = _resume(out)
    assert result.exit_code == 0, result.output
    assert f"(the run recorded its stop: {why})" in result.output


@pytest.mark.parametrize("keys", [True, False])
def test_a_resumed_session_takes_the_terminals_keys_as_the_run_says(tmp_path, keys):
    """The operator's keys (p, r, s) work in a resumed session as in the run ([safety] keys): here
    the operator presses s as the session begins, and it stops before its first step, holding."""
    from hsio.experiment import ExperimentStopped
    from hsio.safety.resume import resume
    from hsio.safety.status import OperatorStop, exit_status

    out = stopped_run(tmp_path, 5, extra="" if keys else "[safety]\nkeys = false\n")
    started = []

    class PressS:
        def __init__(self, control):
            started.append(control)
            control.request_stop("stopped by the operator (key s)")

        def close(self):
            started.append("closed")

    try:
        summary = resume(out, keys=PressS)
    except (ExperimentStopped, OperatorStop) as exc:
        summary = None
        assert exit_status(exc) == 5 and "key s" in str(exc)
    assert (summary is None) == keys and (started[-1] == "closed" if keys else not started)
    assert Run(out / "run.sqlite").summary["exit_status"] == (5 if keys else 0)


@pytest.mark.parametrize("when", ["tables", "meta"])
def test_a_recorder_killed_in_its_creation_leaves_a_record_that_says_so(tmp_path, when):
    """The Recorder itself killed while it creates its tables or writes its meta (the process ends
    at once, as under SIGKILL): the file holds no tables, and reading or resuming it says the run
    was interrupted while it created its record, not that a journal of steps was left behind."""
    import subprocess
    import sys

    from hsio.recording import NotARunError

    out = tmp_path / "killed"
    code = ("import os, sys, sqlite3\n"
            "import hsio.recording as r\n"
            "made = []\n"
            "class Db(sqlite3.Connection):\n"
            "    def execute(self, sql, *a):\n"
            "        if sql.startswith('CREATE TABLE'):\n"
            "            made.append(sql)\n"
            "            if sys.argv[2] == 'tables' and len(made) == 3: os._exit(0)\n"
            "        return super().execute(sql, *a)\n"
            "    def executemany(self, sql, *a):\n"
            "        super().executemany(sql, *a)\n"
            "        if sql.startswith('INSERT INTO meta'): os._exit(0)\n"
            "connect = sqlite3.connect\n"
            "r.sqlite3.connect = lambda *a, **k: connect(*a, factory=Db, **k)\n"
            "r.Recorder(sys.argv[1], ['x'], ['C1'], {})\n")
    subprocess.run([sys.executable, "-c", code, str(out / "run.sqlite"), when], check=True, timeout=60)
    with pytest.raises(NotARunError) as info:
        Run(out / "run.sqlite")
    assert "interrupted while it created its record, before its first step" in str(info.value)
    assert "copy both files together" not in str(info.value)
    result = _resume(out)
    assert result.exit_code == 2
    assert "interrupted while it created its record" in result.output


def test_a_record_killed_while_it_was_created_says_so(tmp_path):
    """A run killed while it created its record leaves run.sqlite without tables and the creation's
    rollback journal beside it: the refusal says that no step was committed (start the run again),
    not that a journal of steps was left behind when copying."""
    import subprocess
    import sys

    out = tmp_path / "killed"
    out.mkdir()
    code = ("import os, sqlite3, sys\n"
            "db = sqlite3.connect(sys.argv[1], isolation_level=None)\n"
            "db.execute('BEGIN'); db.execute('CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)')\n"
            "db.execute('PRAGMA cache_spill = 1'); db.execute('CREATE TABLE pad (x)')\n"
            "db.executemany('INSERT INTO pad VALUES (?)', [(b'x' * 4000,)] * 50)\n"
            "os._exit(0)\n")  # killed: the transaction that creates the tables is never committed
    subprocess.run([sys.executable, "-c", code, str(out / "run.sqlite")], check=True, timeout=30)
    assert (out / "run.sqlite-journal").stat().st_size > 0
    result = _resume(out)
    assert result.exit_code == 2
    assert "interrupted while it created its record, before its first step" in result.output
    assert "copy both files together" not in result.output


def test_a_record_killed_in_the_commit_of_its_creation_says_so_when_read(tmp_path):
    """Killed while the creation's transaction was being written (pages of it in run.sqlite, its
    rollback journal beside it, never deleted): reading the record (the monitor, plots, diagnose)
    cannot roll the journal back, and still says the run was interrupted while it created it."""
    import subprocess
    import sys

    from hsio.recording import NotARunError

    out = tmp_path / "killed"
    out.mkdir()
    code = ("import os, sqlite3, sys\n"
            "db = sqlite3.connect(sys.argv[1], isolation_level=None)\n"
            "db.execute('PRAGMA cache_size = 1'); db.execute('BEGIN')\n"
            "db.execute('CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)')\n"
            "db.execute('CREATE TABLE pad (x)')\n"
            "db.executemany('INSERT INTO pad VALUES (?)', [(b'x' * 4000,)] * 50)\n"
            "os._exit(0)\n")  # pages spilled into run.sqlite, the transaction never committed
    subprocess.run([sys.executable, "-c", code, str(out / "run.sqlite")], check=True, timeout=30)
    assert (out / "run.sqlite").stat().st_size > 0 and (out / "run.sqlite-journal").stat().st_size > 0
    with pytest.raises(NotARunError) as info:
        Run(out / "run.sqlite")
    assert "interrupted while it created its record, before its first step" in str(info.value)
    assert (out / "run.sqlite-journal").exists()  # a reader changes nothing


def test_actuators_through_a_setup_far_from_where_the_record_stops_are_not_resumed(tmp_path):
    """Through a parallel setup the record's channel is the element's basic DOF, but its
    ``actuators`` table holds each rod's stroke at every step: a new in-process emulator standing
    at rest, 1.13 mm from where the strokes stopped, is refused as for elements on one actuator
    each (exit 2, nothing moved), the strokes named; --max-gap lets it go on."""
    wall = tmp_path / "wall.toml"
    wall.write_text('[structure]\nname = "wall_par"\ndt = 0.01\n[[dof]]\nname = "top"\nmass = 0.02\n'
                    '[damping]\nkind = "mass"\nzeta = 0.02\n[[experimental]]\nname = "wall"\ndofs = ["top"]\n'
                    'actuators = ["east", "west"]\nsetup = { kind = "parallel", ratios = [1.0, 1.0] }\n'
                    'model = { kind = "linear", k = 4.0 }\n')
    cfg = write_config(tmp_path, duration=0.9, rate=5.0, extra=QUIET_SENSORS + f'[structure]\nfile = "{wall}"\n')
    out = stopped_run(tmp_path, 80, config_path=cfg)
    stroke = Run(out / "run.sqlite").table("actuators")["disp_east"][-1]
    assert stroke > 1.0
    result = _resume(out)
    assert result.exit_code == 2, result.output
    assert f"the record's last step measured east {stroke:+.3f} mm; west" in result.output
    assert f"east stands {-stroke:+.3f} mm from the record's last step" in result.stderr
    assert "more than 1 mm: not resumed, nothing moved" in result.stderr
    assert "the actuators hold (confirmed by read-back)" in result.stderr
    run = Run(out / "run.sqlite")
    assert len(run.steps["step"]) == 80 and [e["kind"] for e in run.events()][-3:] == ["resume", "hold", "stop"]
    result = CliRunner().invoke(main, ["resume", str(out), "--max-gap", "2"])
    assert result.exit_code == 0, result.output
    np.testing.assert_array_equal(Run(out / "run.sqlite").table("actuators")["step"], np.arange(1, 91))


def test_an_actuator_of_its_own_beside_a_setup_is_checked_too(tmp_path):
    """A structure with an element on one actuator (C1) beside one through a parallel setup: each
    actuator is compared with what the record measured of it, C1 from its channel, east and west
    from the actuators table."""
    from hsio.safety.resume import gaps

    wall = tmp_path / "mix.toml"
    wall.write_text('[structure]\nname = "mix"\ndt = 0.01\n[[dof]]\nname = "top"\nmass = 0.02\n[[dof]]\n'
                    'name = "mid"\nmass = 0.02\n[damping]\nkind = "mass"\nzeta = 0.02\n[[experimental]]\n'
                    'name = "wall"\ndofs = ["top"]\nactuators = ["east", "west"]\n'
                    'setup = { kind = "parallel", ratios = [1.0, 1.0] }\nmodel = { kind = "linear", k = 4.0 }\n'
                    '[[experimental]]\nname = "C1"\ndof = "mid"\nmodel = { kind = "linear", k = 3.0 }\n')
    cfg = write_config(tmp_path, duration=0.2, rate=5.0, extra=QUIET_SENSORS + f'[structure]\nfile = "{wall}"\n')
    run = Run(stopped_run(tmp_path, 15, config_path=cfg) / "run.sqlite")
    table = run.table("actuators")
    standing = {name: {"displacement_mm": 0.5, "force_kN": 0.0} for name in ("east", "west", "C1")}
    assert gaps(standing, run) == pytest.approx({"east": 0.5 - table["disp_east"][-1],
                                                 "west": 0.5 - table["disp_west"][-1],
                                                 "C1": 0.5 - run.steps["disp_C1"][-1]})
    assert table["step"][-1] == run.steps["step"][-1] == 15


def test_a_run_killed_before_its_summary_is_described_whole_after_the_resume(tmp_path):
    """SIGKILL leaves no summary: the resume writes the run's description again from the record
    (what ran, on what, in which units, where it started), as an uninterrupted run has it."""
    cfg = write_config(tmp_path, duration=0.3, rate=5.0, extra=QUIET_SENSORS)
    whole = runner.run(config_mod.load(cfg), tmp_path / "whole")
    out = stopped_run(tmp_path, 1, config_path=cfg)  # the in-process emulator stands at rest again
    with sqlite3.connect(out / "run.sqlite") as db:
        db.execute("DELETE FROM summary")  # as a kill leaves it
    (out / "summary.json").unlink()
    result = _resume(out)
    assert result.exit_code == 0, result.output
    summary = Run(out / "run.sqlite").summary
    assert json.loads((out / "summary.json").read_text()) == summary
    for key in ("structure", "record", "dt", "test_rate", "hardware", "clock", "dof", "dof_units", "channel_units",
                "channels", "start_state", "dry_run_override", "version", "ns_peak_displacement_mm"):
        assert summary[key] == whole[key], key
    assert summary["run_file"] == str(out / "run.sqlite") and summary["steps"] == whole["steps"]


def test_a_stop_as_the_resume_opens_says_in_the_summary_and_ledger_how_the_hold_went(tmp_path):
    """A stop that comes once the hardware opened, before the first resumed step: the record has
    the hold and the stop, and the summary and the ledger row say how the hold went, as the
    message does."""
    from hsio.safety.control import RunControl
    from hsio.safety.resume import resume
    from hsio.safety.status import OperatorStop

    specimen = tmp_path / "specimen"
    cfg = write_config(tmp_path, duration=0.3, rate=5.0, extra=f'[specimen]\nfolder = "{specimen}"\nid = "w1"\n')
    out = stopped_run(tmp_path, 1, config_path=cfg)
    control = RunControl()

    def notify(line):
        if line.startswith("the actuators stand at"):
            control.request_stop("stopped by the test as the hardware opened")

    with pytest.raises(OperatorStop) as info:
        resume(out, control=control, notify=notify)
    assert "the actuators hold (confirmed by read-back)" in info.value.stop_message
    run = Run(out / "run.sqlite")
    assert [(e["kind"], e["message"]) for e in run.events()][-2:] == [
        ("hold", "the actuators hold (confirmed by read-back)"), ("stop", info.value.stop_message)]
    assert run.summary["stopped"] == info.value.stop_message and run.summary["exit_status"] == 5
    assert ledger.read(specimen)[-1]["message"] == info.value.stop_message
