"""Bad input gets a clear error that names it; out-of-range targets never reach an actuator."""

import json
import sqlite3
import subprocess
import sys

import numpy as np
import pytest

from hsio.emulators.servo import ServoController
from hsio import config, runner
from hsio.experiment import ExperimentStopped
from hsio.errors import ConfigError, RecordError
from hsio.ground_motion import GroundMotion, read_at2
from hsio.structures import get_structure


def hsio(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "hsio.cli", *args], capture_output=True, text=True, timeout=300, cwd=cwd)


def test_unknown_structure_is_named(tmp_path):
    with pytest.raises(ConfigError, match="'tower'.*known: validation"):
        get_structure("tower")
    cfg = tmp_path / "c.toml"
    cfg.write_text('[structure]\nname = "tower"\n')
    proc = hsio("run", str(cfg), "--out", str(tmp_path / "o"))
    assert proc.returncode == 2
    assert f"{cfg}: [structure] name: unknown structure 'tower'" in proc.stderr


def test_malformed_toml_names_the_file_and_line(tmp_path):
    cfg = tmp_path / "broken.toml"
    cfg.write_text("[test]\nrate = = 3\n")
    with pytest.raises(ConfigError, match=r"broken.toml: malformed TOML.*line 2"):
        config.load(cfg)


@pytest.mark.parametrize("text, match", [
    ("[tset]\nrate = 3\n", r"unknown table \[tset\]"),
    ("[test]\nrat = 3\n", r"unknown key 'rat' in \[test\]"),
    ("[test]\nrate = 'fast'\n", r"\[test\]: rate must be a number"),
    ("[test]\nrate = -1\n", r"rate \(TR\) must be positive"),
    ("[integrator]\nalpha = 0.2\n", r"alpha must be in \[-1/3, 0\]"),
    ("[hardware]\nclock = 'sometimes'\n", r"clock must be 'lockstep' or 'realtime'"),
    ("[test]\nn_avg = 2.5\n", r"n_avg must be a whole number"),
    ("[record]\nsynthetic_duration_s = -1\n", r"synthetic_duration_s must be positive"),
    ("[record]\nseed = -3\n", r"seed must not be negative"),
    ("[emulator]\nlag_s = 'fast'\n", r"\[emulator\] lag_s must be a finite number"),
])
def test_config_errors_name_table_and_key(tmp_path, text, match):
    cfg = tmp_path / "c.toml"
    cfg.write_text(text)
    with pytest.raises(ConfigError, match=match):
        config.load(cfg)


def write_at2(path, header4, values):
    lines = ["PEER NGA STRONG MOTION DATABASE RECORD", "test record", "ACCELERATION TIME SERIES IN UNITS OF G", header4]
    lines += ["  ".join(values[i:i + 5]) for i in range(0, len(values), 5)]
    path.write_text("\n".join(lines) + "\n")


def test_at2_broken_header_is_named(tmp_path):
    f = tmp_path / "bad.AT2"
    write_at2(f, "NPTS is missing here", ["0.1"] * 10)
    with pytest.raises(RecordError, match=r"bad.AT2:4: header line must give NPTS and DT"):
        read_at2(f)


@pytest.mark.parametrize("tail", ["", "\n\n   \n"])
def test_at2_with_a_header_and_no_values_says_so(tmp_path, tail):
    f = tmp_path / "empty.AT2"
    write_at2(f, "NPTS=   12, DT=   .0200 SEC", [])
    f.write_text(f.read_text() + tail)
    with pytest.raises(RecordError, match=r"empty.AT2: no values after the 4-line header \(NPTS = 12\)"):
        read_at2(f)
    write_at2(f, "NPTS is missing here", [])  # a broken header is named first
    with pytest.raises(RecordError, match=r"empty.AT2:4: header line must give NPTS and DT"):
        read_at2(f)


@pytest.mark.parametrize("dt, accel, says", [
    (0.01, "abc", "must be numbers"), (0.01, [[0.0, 1.0], [2.0, 3.0]], "one history"),
    ("0.01", [0.0, 1.0], "time step must be positive"), (0.01, [0.0, None, 1.0], "sample 1"),
])
def test_a_ground_motion_built_in_code_is_checked(dt, accel, says):
    with pytest.raises(RecordError, match=says):
        GroundMotion("x", dt, accel)
    with pytest.raises(RecordError, match="not a finite number"):
        GroundMotion("x", 0.01, [0.0, 1.0]).scaled("2")


def test_at2_nan_is_named_with_its_line(tmp_path):
    f = tmp_path / "nan.AT2"
    values = ["0.01"] * 12
    values[7] = "NaN"
    write_at2(f, "NPTS=   12, DT=   .0200 SEC", values)
    with pytest.raises(RecordError, match=r"nan.AT2:6: value 'NaN' is not finite"):
        read_at2(f)


def test_at2_count_mismatch_and_garbage(tmp_path):
    f = tmp_path / "short.AT2"
    write_at2(f, "NPTS=   12, DT=   .0200 SEC", ["0.01"] * 10)
    with pytest.raises(RecordError, match="NPTS = 12, file holds 10"):
        read_at2(f)
    g = tmp_path / "garbage.AT2"
    write_at2(g, "4 0.01 NPTS, DT", ["0.01", "0.02", "x1", "0.0"])
    with pytest.raises(RecordError, match=r"garbage.AT2:5: 'x1' is not a number"):
        read_at2(g)


def test_nan_in_a_record_array_is_refused():
    with pytest.raises(RecordError, match="sample 3"):
        GroundMotion("r", 0.01, np.array([0.0, 0.1, 0.2, np.nan, 0.0]))


def test_target_beyond_stroke_stops_the_run_holding_and_keeps_the_record(tmp_path):
    """A record scaled far too large: the first target beyond +/-127 mm is refused unsent (the dry
    run, which would refuse the test before anything moves, overridden)."""
    cfg = tmp_path / "big.toml"
    cfg.write_text("[record]\nscale = 12.0\nsynthetic_duration_s = 8.0\n[test]\nrate = 6.25\n"
                   "[emulator]\nvelocity_limit_mm_s = 5000.0\n[safety]\noverride = true\n")
    out = tmp_path / "o"
    proc = hsio("run", str(cfg), "--out", str(out), "--json")
    assert proc.returncode == 3, proc.stderr
    assert "beyond the stroke" in proc.stderr and "; not sent; the actuators hold (confirmed by read-back)" in proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped"]
    db = sqlite3.connect(out / "run.sqlite")
    n_steps = db.execute("SELECT COUNT(*) FROM steps").fetchone()[0]
    assert n_steps == summary["steps"] > 0
    max_target = db.execute("SELECT MAX(ABS(target_C1)) FROM steps").fetchone()[0]
    assert max_target <= 127.0


def commands_reaching_the_emulator(monkeypatch) -> list[float]:
    """Every command that reaches an emulated controller, as the controller sees it."""
    seen = []
    original = ServoController.set_command

    def spy(self, value):
        seen.append((id(self), float(value)))
        original(self, value)

    monkeypatch.setattr(ServoController, "set_command", spy)
    return seen


def test_no_command_beyond_the_stroke_reaches_the_actuator(tmp_path, monkeypatch):
    seen = commands_reaching_the_emulator(monkeypatch)
    cfg = config.from_dict({"record": {"scale": 12.0, "synthetic_duration_s": 8.0}, "test": {"rate": 6.25},
                            "emulator": {"velocity_limit_mm_s": 5000.0}, "output": {"plots": False},
                            "safety": {"override": True}})
    with pytest.raises(ExperimentStopped, match="beyond the stroke"):
        runner.run(cfg, tmp_path / "o")
    assert len(seen) > 1000
    assert max(abs(v) for _, v in seen) <= 127.0


def test_no_command_faster_than_the_actuator_reaches_it(tmp_path, monkeypatch):
    seen = commands_reaching_the_emulator(monkeypatch)
    cfg = config.from_dict({"record": {"synthetic_duration_s": 4.0}, "test": {"rate": 1.0},
                            "emulator": {"velocity_limit_mm_s": 100.0}, "output": {"plots": False},
                            "safety": {"override": True}})
    with pytest.raises(ExperimentStopped, match="command velocity"):
        runner.run(cfg, tmp_path / "o")
    for controller in {c for c, _ in seen}:
        values = np.array([v for c, v in seen if c == controller])
        assert values.size > 100
        assert np.max(np.abs(np.diff(values))) * 1024 <= 100.0 + 1e-9


def test_command_faster_than_the_actuator_is_refused(tmp_path):
    """A test rate too fast for the servo-valve: refused before the command is sent, not clamped."""
    cfg = tmp_path / "fast.toml"
    cfg.write_text("[record]\nsynthetic_duration_s = 4.0\n[test]\nrate = 1.0\n[emulator]\nvelocity_limit_mm_s = 100.0\n"
                   "[output]\nplots = false\n[safety]\noverride = true\n")
    out = tmp_path / "o"
    proc = hsio("run", str(cfg), "--out", str(out))
    assert proc.returncode == 3, proc.stderr
    assert "command velocity" in proc.stderr and "beyond the limit (100.0 mm/s)" in proc.stderr
    db = sqlite3.connect(out / "run.sqlite")
    assert db.execute("SELECT COUNT(*) FROM steps").fetchone()[0] > 0  # the steps made are kept
