"""`hsio run`'s summary of a mixed run: per-actuator figures named by their actuator, and the
steps the guards ran in DC counted beside the other counts (docs/force_control.md)."""

from hsio import config, runner
from hsio.cli import _print_summary


def test_a_mixed_run_names_each_actuator_and_counts_its_guarded_steps(tmp_path, capsys):
    # structure_II_infill: two actuators (BF, IF). K_f below both K^EI: both start in FC; with
    # explored_fraction neither has carried any force yet, so the first step runs in DC (guarded)
    cfg = config.from_dict({"structure": {"name": "structure_II_infill"},
                            "record": {"synthetic_duration_s": 0.1, "pga_g": 0.05},
                            "integrator": {"method": "mixed", "K_f": 5.0, "K_d": 2.5, "explored_fraction": 0.9},
                            "output": {"plots": False, "ns": False}})
    summary = runner.run(cfg, tmp_path / "run")
    assert summary["channels"] == ["BF", "IF"]
    assert summary["guarded_steps"] >= 1
    _print_summary(summary)
    lines = {line[:15].strip(): line[15:] for line in capsys.readouterr().out.splitlines()}
    rms, fc = summary["rms_tracking_error_mm"], summary["fc_step_fraction"]
    assert lines["tracking RMS"] == f"BF {rms[0]:.4f} mm, IF {rms[1]:.4f} mm"
    assert f"FC in {fc[0] * 100:.0f} % (BF), {fc[1] * 100:.0f} % (IF) of steps" in lines["method"]
    assert lines["method"].endswith(f", {summary['guarded_steps']} guarded steps")


def test_a_run_without_guards_reports_none_guarded(tmp_path):
    cfg = config.from_dict({"structure": {"name": "structure_I"}, "record": {"synthetic_duration_s": 0.1},
                            "integrator": {"method": "mixed", "K_f": 3.12, "K_d": 2.08},
                            "output": {"plots": False, "ns": False}})
    summary = runner.run(cfg, tmp_path / "run")
    assert summary["guarded_steps"] == 0 and summary["channels"] == ["wall"]


def test_the_fc_secant_line_names_each_actuator(tmp_path, capsys):
    # force control on the emulator: the instruments are known, FC's secant rule is on (eq. 11a)
    cfg = config.from_dict({"structure": {"name": "structure_II"}, "record": {"synthetic_duration_s": 0.1, "pga_g": 0.05},
                            "integrator": {"method": "force_control"}, "output": {"plots": False, "ns": False}})
    summary = runner.run(cfg, tmp_path / "run")
    _print_summary(summary)
    lines = {line[:15].strip(): line[15:] for line in capsys.readouterr().out.splitlines()}
    refused = summary["secant_refused"]
    assert lines["FC secant"].endswith(f": {refused[0]} (BF), {refused[1]} (IF)")


def test_a_mode_an_actuator_never_ran_has_no_tracking_error(tmp_path, capsys):
    """Force control only: no displacement was tracked, so the DC tracking error is none, not a
    perfect 0 mm; the FC one is measured (and the other way round for implicit DC)."""
    for method in ("force_control", "implicit_dc"):
        cfg = config.from_dict({"structure": {"name": "structure_II"},
                                "record": {"synthetic_duration_s": 0.05, "pga_g": 0.05},
                                "integrator": {"method": method}, "output": {"plots": False, "ns": False}})
        summary = runner.run(cfg, tmp_path / method)
        dc, fc = summary["rms_tracking_error_mm"], summary["rms_force_tracking_error_kN"]
        if method == "force_control":
            assert dc == [None, None] and all(x > 0 for x in fc)
            _print_summary(summary)
            lines = {line[:15].strip(): line[15:] for line in capsys.readouterr().out.splitlines()}
            assert lines["tracking RMS"] == ("BF none (no step in displacement control), "
                                             "IF none (no step in displacement control)")
        else:
            assert fc == [None, None] and all(x > 0 for x in dc)
