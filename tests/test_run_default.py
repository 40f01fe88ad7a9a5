"""The default run end to end: `hsio run --json` on emulated actuators matches NS."""

import json
import subprocess
import sys


def test_default_run_matches_numerical_simulation(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "run", "--out", str(out), "--json"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    for key in ("structure", "steps", "dt", "test_rate", "peak_displacement_mm", "ns_peak_displacement_mm",
                "max_error_pct", "wall_time_s"):
        assert key in summary
    assert summary["structure"] == "validation"
    assert 6.25 <= summary["test_rate"] <= 50
    assert summary["max_error_pct"] < 0.25  # README: 0.12 %
    assert len(summary["peak_displacement_mm"]) == 2
    assert min(summary["ns_peak_displacement_mm"]) > 5.0  # the default record really shakes it
    for name in ("run.sqlite", "summary.json", "displacement.png", "hysteresis.png", "tracking.png"):
        assert (out / name).stat().st_size > 0
