"""`hsio run` of a structure whose element is loaded through a two-actuator setup: the dry run
checks actuator strokes and forces (not rotations and moments), the record has a column per
channel, and HS matches NS."""

from pathlib import Path

from hsio import config, runner
from hsio.recording import Run

LIBRARY = Path(__file__).resolve().parents[1] / "hsio" / "library"


def test_hsio_run_of_a_column_on_two_actuators(tmp_path):
    cfg = config.from_dict({"structure": {"file": str(LIBRARY / "column_two_actuators.toml")},
                            "record": {"synthetic_duration_s": 1.5, "pga_g": 0.3}, "test": {"rate": 10.0},
                            "output": {"plots": False}})
    summary = runner.run(cfg, tmp_path / "run")
    assert summary["steps"] == 150 and summary["max_error_pct"] < 2.0
    run = Run(tmp_path / "run" / "run.sqlite")
    assert len(run.actuator_names) == 2 and all("." in n for n in run.actuator_names)
    ns_structure = runner.load_run_structure(cfg)
    ns, report = runner.predict(cfg, ns_structure, runner.build_record(cfg, ns_structure))
    assert not report.refused
    assert set(report.prediction.actuators) == {"lower", "upper"}
    assert max(report.prediction.force) < 250.0  # actuator forces, not the moment about the column top
