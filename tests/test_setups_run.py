"""`hsio run` of a structure whose element is loaded through a two-actuator setup: the dry run
checks actuator strokes and forces (not rotations and moments), the record has a column per
channel, and HS matches NS."""

from pathlib import Path

import numpy as np

from hsio import config, runner
from hsio.recording import Run, column

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
    # The command generator's phase per channel and the lab time are recorded with setups too
    # (a channel takes its element's actuators' phase): the monitor shows them.
    samples = run.samples()
    for name in run.actuator_names:
        codes = samples[column("phase", name)]
        assert np.isfinite(codes).all() and set(codes.astype(int)) <= set(run.meta["phase_codes"].values())
    assert (np.diff(samples["lab_time_s"]) > 0).all()


def test_a_channel_on_a_setup_takes_the_most_urgent_phase_of_its_elements_actuators():
    from hsio.sites.setup_map import SetupMap
    from hsio.structure_file import load_structure

    setups = SetupMap.of(load_structure(LIBRARY / "column_two_actuators.toml"))
    assert setups.channel_phases(["dwell", "dwell"]) == ["dwell", "dwell"]
    assert setups.channel_phases(["interpolate", "slow"]) == ["slow", "slow"]
    assert setups.channel_phases(["hold", "extrapolate"]) == ["hold", "hold"]
