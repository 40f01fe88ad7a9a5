"""A preloaded run's log of its static actuators (docs/setups.md) is in the record as the run
goes, committed with each step: a run killed with SIGKILL keeps it up to its last committed step
(nothing recorded is lost), as a run that ends keeps the whole of it."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from hsio.recording import Run
from test_resume import kill_at
from wire import QUIET_SENSORS, write_config

LIBRARY = Path(__file__).resolve().parents[1] / "hsio" / "library"


def test_a_killed_preloaded_run_keeps_its_preload_log_up_to_its_last_step(tmp_path):
    cfg = write_config(tmp_path, duration=8.0, rate=5.0, extra=QUIET_SENSORS + f'[structure]\nfile = "{LIBRARY / "preloaded_column.toml"}"\n')
    cfg.write_text(cfg.read_text().replace("[record]\n", "[record]\npga_g = 0.1\n"))
    out = tmp_path / "run"
    kill_at([sys.executable, "-m", "hsio.cli", "run", str(cfg), "--out", str(out)], out, 30, tmp_path)
    run = Run(out / "run.sqlite")
    steps = run.steps["step"]
    assert len(steps) >= 30 and "stopped" not in run.summary  # killed in the record, no finally ran
    static = run.table("static")
    phase = static["phase"]
    assert set(phase.astype(int)) == {0, 1}  # the ramp in, then the test; no ramp off
    held = static["force_axial"][phase == 1]
    assert len(held) >= len(steps)  # every committed step's commands
    assert np.allclose(held, 125.0, atol=1.0) and np.all(static["target_axial"][phase == 1] == 125.0)
