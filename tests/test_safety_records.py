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
