"""A user structure from TOML alone: the three-storey building whose first storey is an
experimental, degrading specimen, run on emulated actuators with every method."""

from pathlib import Path

import numpy as np
import pytest

from hsio import config, runner

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "three_storey.toml"


def run(tmp_path, method: str, rate: float = 20.0) -> dict:
    cfg = config.from_dict({
        "structure": {"file": str(EXAMPLE)},
        "record": {"pga_g": 0.4, "synthetic_duration_s": 5.0},
        "integrator": {"method": method},
        "test": {"rate": rate},
        "emulator": {"force_limit_kN": 1000.0},
        "output": {"plots": False},
    })
    return runner.run(cfg, tmp_path / method)


@pytest.mark.parametrize("method", ["alpha_os", "implicit_dc", "mixed"])
def test_three_storey_matches_ns_within_2_percent(tmp_path, method):
    summary = run(tmp_path, method)
    assert summary["structure"] == "three_storey" and summary["steps"] == 1000
    assert summary["dof"] == ["floor1", "floor2", "roof"]
    # the first storey yields: its force reaches the specimen's strength (Fy = 420 kN)
    assert max(summary["ns_peak_displacement_mm"]) > 20.0
    assert summary["max_error_pct"] < 2.0, summary["max_error_pct_per_dof"]


def test_three_storey_in_force_control_runs_to_the_end(tmp_path):
    """Force control alone completes; it is the wrong method on a softening storey (E&M 2007
    section 5), and its error shows it."""
    summary = run(tmp_path, "force_control")
    assert summary["steps"] == 1000 and summary["stopped"] == ""
    assert summary["fc_step_fraction"][0] == 1.0
    assert np.isfinite(summary["max_error_pct"])
