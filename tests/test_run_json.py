"""`hsio run --json` prints the summary the run wrote, whatever the outcome: finished, refused by
the dry run (exit 2), stopped by a limit (exit 3); where no summary was written (bad input before
the run folder), a JSON object naming the error. The exit status is kept."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

# A record scaled far beyond the stroke: the dry run refuses it; overridden, the run stops at the
# first target beyond +/-127 mm.
BIG = ("[record]\nscale = 12.0\nsynthetic_duration_s = {duration}\n[test]\nrate = 6.25\n"
       "[emulator]\nvelocity_limit_mm_s = 5000.0\n[output]\nplots = false\nsamples = false\n[safety]\nkeys = false\n")


def run_json(tmp_path, *args, duration=3.0, text=None):
    cfg = tmp_path / "run.toml"
    cfg.write_text(text if text is not None else BIG.format(duration=duration))
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "run", str(cfg), "--out", str(tmp_path / "o"), "--json",
                           *args], capture_output=True, text=True, timeout=120)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc, json.loads(proc.stdout)


@pytest.mark.parametrize("args, status, outcome", [((), 2, "refused"),
                                                   (("--override-dry-run",), 3, "stopped by a limit or fault")])
def test_a_run_that_did_not_finish_prints_the_summary_it_wrote(tmp_path, args, status, outcome):
    proc, printed = run_json(tmp_path, *args)
    assert proc.returncode == status, proc.stderr
    assert printed == json.loads((tmp_path / "o" / "summary.json").read_text())
    assert printed["exit_status"] == status and printed["outcome"] == outcome and printed["stopped"]


def test_bad_input_before_the_run_folder_prints_the_error(tmp_path):
    proc, printed = run_json(tmp_path, text="[test]\nrate = -1.0\n")
    assert proc.returncode == 2, proc.stderr
    assert set(printed) == {"error", "exit_status", "outcome"}
    assert "rate" in printed["error"] and printed["error"] in proc.stderr
    assert printed["exit_status"] == 2 and printed["outcome"] == "refused"
    assert not (tmp_path / "o").exists()
