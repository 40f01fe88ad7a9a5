"""`hsio resume` and the run's input files (docs/safety.md section 8): a structure, record or
driver file that differs from the one the run began with is refused by name, exit 2, before
anything opens; unchanged files resume; a record without fingerprints resumes with a warning.

The interruption is an operator stop at step 10 of a short run on the in-process emulator (as
tests/wire.py stopped_run), which leaves a record that `hsio resume` continues."""

from __future__ import annotations

import os
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from hsio import config as config_mod
from hsio.cli import main
from hsio.errors import ConfigError
from hsio.ground_motion import GroundMotion
from hsio.recording import Run
from hsio.safety.resume import resume

from wire import stopped_run

# An SDOF of f = sqrt(k / m) / 2 pi = 3.0 Hz; the edit below makes both ten times larger (the same
# frequency, a specimen ten times stiffer: the recorded force would jump tenfold at the resumed step).
STRUCTURE = """[structure]
name = "resme"
dt = 0.01
[[dof]]
name = "a"
mass = 0.0017
[[experimental]]
name = "a"
dof = "a"
model = { kind = "linear", k = 0.613 }
"""
CONFIG = """[structure]
file = "s.toml"
[record]
file = "quake.at2"
[test]
rate = 5.0
[output]
plots = false
samples = false
"""
STEPS = 60


def write_at2(path: Path, accel_g) -> Path:
    lines = ["PEER NGA STRONG MOTION DATABASE RECORD", "written by the test", "ACCELERATION TIME SERIES IN UNITS OF G",
             f"NPTS= {len(accel_g)}, DT= 0.0100 SEC"]
    lines += ["".join(f"{v:16.7E}" for v in accel_g[k:k + 5]) for k in range(0, len(accel_g), 5)]
    path.write_text("\n".join(lines) + "\n")
    return path


def quake(scale: float = 1.0) -> np.ndarray:
    t = 0.01 * np.arange(STEPS)
    return scale * 0.2 * np.sin(2 * np.pi * 2.0 * t)


def stopped(tmp_path: Path, ground: GroundMotion | None = None, at_step: int = 10) -> Path:
    """The run of CONFIG stopped by the operator at step ``at_step``; returns its folder."""
    (tmp_path / "s.toml").write_text(STRUCTURE)
    write_at2(tmp_path / "quake.at2", quake())
    (tmp_path / "run.toml").write_text(CONFIG)
    return stopped_run(tmp_path, at_step, config_path=tmp_path / "run.toml", ground=ground)


def untouched(out: Path) -> tuple[int, list[str]]:
    run = Run(out / "run.sqlite")
    return len(run.steps["step"]), [e["kind"] for e in run.events()]


def test_a_structure_file_edited_after_the_interruption_is_refused_by_name(tmp_path):
    out = stopped(tmp_path)
    before = untouched(out)
    structure = tmp_path / "s.toml"
    structure.write_text(STRUCTURE.replace("0.0017", "0.017").replace("0.613", "6.13"))
    result = CliRunner().invoke(main, ["resume", str(out)])
    assert result.exit_code == 2, result.output
    assert "would not continue the same test" in result.stderr
    assert f"{structure.resolve()} ([structure] file): changed" in result.stderr
    assert "quake.at2" not in result.stderr  # the unchanged record file is not named
    assert untouched(out) == before  # no step, no resume event: the record as it was


def test_each_changed_or_missing_file_is_named(tmp_path):
    out = stopped(tmp_path)
    before = untouched(out)
    write_at2(tmp_path / "quake.at2", quake(scale=3.0))
    (tmp_path / "s.toml").unlink()
    with pytest.raises(ConfigError) as info:
        resume(out)
    message = str(info.value)
    assert f"{(tmp_path / 'quake.at2').resolve()} ([record] file): changed" in message
    assert f"{(tmp_path / 's.toml').resolve()} ([structure] file): missing" in message
    assert untouched(out) == before


def test_a_fifo_in_place_of_a_file_is_refused_without_being_read(tmp_path):
    out = stopped(tmp_path)
    (tmp_path / "s.toml").unlink()
    os.mkfifo(tmp_path / "s.toml")  # opening it for reading would wait for a writer for ever
    with pytest.raises(ConfigError, match=r"s\.toml \(\[structure\] file\): cannot be read \(not a regular file\)"):
        resume(out)


def test_unchanged_files_resume_to_the_end(tmp_path):
    out = stopped(tmp_path)
    (tmp_path / "s.toml").touch()  # a new modification time, the same bytes
    told = []
    summary = resume(out, notify=told.append, max_gap_mm=100.0)  # the in-process emulator starts again at rest
    assert summary["exit_status"] == 0
    np.testing.assert_array_equal(Run(out / "run.sqlite").steps["step"], np.arange(1, STEPS))  # each step once
    assert not [line for line in told if line.startswith("WARNING")]


def test_a_record_without_fingerprints_resumes_with_a_warning(tmp_path):
    """A record written by an hsio that took no fingerprints: resumed, with a warning that the
    files cannot be checked."""
    out = stopped(tmp_path)
    with sqlite3.connect(out / "run.sqlite") as db:
        db.execute("DELETE FROM meta WHERE key IN ('inputs', 'ground_motion_sha256')")
    told = []
    summary = resume(out, notify=told.append, max_gap_mm=100.0)  # the in-process emulator starts again at rest
    assert summary["exit_status"] == 0
    warnings = [line for line in told if line.startswith("WARNING")]
    assert len(warnings) == 1 and "no fingerprints" in warnings[0] and "cannot check" in warnings[0]


def test_a_ground_motion_given_in_code_is_not_continued_with_the_configured_record(tmp_path):
    """runner.run(..., ground=...) runs a record built in code; the resume, which builds the
    configured record, would continue another test."""
    harmonic = GroundMotion("harmonic", 0.01, quake(scale=2.0))
    out = stopped(tmp_path, ground=harmonic)
    before = untouched(out)
    with pytest.raises(ConfigError, match=r"would not continue the same test: the ground motion built from the "
                                          r"configuration \(quake.at2\) differs from the one the run began with "
                                          r"\(harmonic"):
        resume(out)
    assert untouched(out) == before


def test_the_files_of_the_hardware_backends_are_inputs(tmp_path):
    """A Modbus register map (hsio's default where none is named), a CANopen EDS, the DAQ
    module's map: each is fingerprinted, and a changed one is named."""
    from hsio.drivers.modbus_map import DEFAULT_MAP
    from hsio.safety.inputs import compare_inputs, fingerprints, input_files

    modbus = config_mod.from_dict({"hardware": {"url": "modbus+tcp://127.0.0.1:1502"}})
    assert ("[driver] map", DEFAULT_MAP) in input_files(modbus)
    regmap = shutil.copy(DEFAULT_MAP, tmp_path / "map.toml")
    daq = tmp_path / "daq.toml"
    daq.write_text("# the DAQ map\n")
    modbus["driver"].update(map=str(regmap), instrument_map=str(daq))
    assert "[driver] instrument_map" not in {w for w, _ in input_files(modbus)}  # no DAQ named: not read
    modbus["driver"]["instruments"] = "modbus+tcp://127.0.0.1:1503"
    recorded = fingerprints(modbus)
    assert {e["what"] for e in recorded} == {"[structure] name (shipped)", "[driver] map", "[driver] instrument_map"}
    assert compare_inputs(recorded, modbus) == ([], [])
    daq.write_text("# another DAQ map\n")
    changed, _ = compare_inputs(recorded, modbus)
    assert len(changed) == 1 and changed[0].startswith(f"{daq} ([driver] instrument_map): changed")
    older = [e for e in recorded if e["what"] != "[driver] map"]  # a file the recording hsio did not fingerprint
    assert compare_inputs(older, modbus)[1] == [f"{regmap} ([driver] map)"]

    eds = tmp_path / "drive.eds"
    eds.write_text("[FileInfo]\n")
    canopen = config_mod.from_dict({"hardware": {"url": "canopen+virtual://hsio/1"}, "driver": {"eds": str(eds)}})
    assert ("[driver] eds", eds) in input_files(canopen)
    assert not [w for w, _ in input_files(config_mod.from_dict({"hardware": {"url": "canopen+virtual://hsio/1"}}))
                if w == "[driver] eds"]  # hsio's own object dictionary: no file


def test_a_shipped_structure_is_an_input_too():
    """The shipped structure's file in hsio/library/ (another hsio may ship it changed)."""
    from hsio.safety.inputs import input_files

    files = dict(input_files(config_mod.from_dict({"structure": {"name": "validation"}})))
    path = files["[structure] name (shipped)"]
    assert path.name == "validation.toml" and path.is_file()
