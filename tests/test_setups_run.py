"""`hsio run` of a structure whose element is loaded through a two-actuator setup: the dry run
checks actuator strokes and forces (not rotations and moments), the record has a column per
channel, and HS matches NS."""

from pathlib import Path

import numpy as np

from hsio import config, runner
from hsio.recording import Run, column

LIBRARY = Path(__file__).resolve().parents[1] / "hsio" / "library"


def test_hsio_run_of_a_column_on_two_actuators(tmp_path, capsys):
    cfg = config.from_dict({"structure": {"file": str(LIBRARY / "column_two_actuators.toml")},
                            "record": {"synthetic_duration_s": 1.5, "pga_g": 0.3}, "test": {"rate": 10.0},
                            "output": {"plots": False}})
    summary = runner.run(cfg, tmp_path / "run")
    assert summary["steps"] == 150 and summary["max_error_pct"] < 2.0
    # the rotation DOF in rad (its moment in kN mm), in the summary and as printed
    assert summary["dof_units"] == ["mm", "rad"] and summary["channel_units"] == ["mm", "rad"]
    from hsio.cli import _print_summary

    _print_summary(summary)
    printed = capsys.readouterr().out
    rotation = next(line for line in printed.splitlines() if line.startswith("peak top_rot"))
    assert rotation.count(" rad") == 2 and " mm" not in rotation, printed
    assert next(line for line in printed.splitlines() if line.startswith("tracking RMS")).endswith(" rad"), printed
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


def test_the_plots_label_a_rotation_in_rad_and_its_moment_in_kN_mm(tmp_path, monkeypatch):
    from hsio import plots
    from hsio.structure_file import load_structure
    from hsio.structures import channel_units, dof_units

    figures = []
    monkeypatch.setattr(plots.plt, "close", figures.append)
    structure = load_structure(LIBRARY / "column_two_actuators.toml")
    t, x = np.linspace(0.0, 1.0, 11), np.zeros((11, 2))
    plots.displacement_histories(tmp_path / "d.png", t, x, t, x, structure.dof_names, units=dof_units(structure))
    plots.hysteresis_loops(tmp_path / "h.png", x, x, ["column.top_x", "column.top_rot"], units=channel_units(structure))
    plots.tracking_error(tmp_path / "t.png", t, x, x, ["column.top_x", "column.top_rot"], 0.025,
                         units=[u for u, _ in channel_units(structure)])
    displacement, hysteresis, tracking = ([ax for ax in f.axes if ax.get_visible()] for f in figures)
    assert displacement[0].get_ylabel().endswith("(mm)") and displacement[2].get_ylabel().endswith("(rad)")
    assert (hysteresis[0].get_xlabel(), hysteresis[0].get_ylabel()) == ("displacement (mm)", "force (kN)")
    assert (hysteresis[1].get_xlabel(), hysteresis[1].get_ylabel()) == ("rotation (rad)", "moment (kN mm)")
    assert tracking[1].get_ylabel().endswith("(rad)") and tracking[1].get_title(loc="left").endswith(" rad")
    assert dof_units(load_structure(LIBRARY / "joint_three_actuators.toml")) == ["mm", "mm", "rad"]


def test_a_results_plot_labels_a_rotation_in_rad_and_its_moment_in_kN_mm():
    import hsio

    structure = hsio.load_structure(LIBRARY / "column_two_actuators.toml")
    ns = hsio.run_numerical(structure, hsio.synthetic_record(duration_s=0.2, dt=structure.dt, pga_g=0.1))
    assert ns.dof_units == ("mm", "rad")
    figure = ns.plot()
    left = [ax for ax in figure.axes[0::2] if ax.get_visible()]
    right = [ax for ax in figure.axes[1::2] if ax.get_visible()]
    assert left[0].get_ylabel().endswith("(mm)") and left[1].get_ylabel().endswith("(rad)")
    assert right[0].get_ylabel() == "force (kN)"
    assert right[1].get_xlabel().endswith("rotation (rad)") and right[1].get_ylabel() == "moment (kN mm)"
