"""`hsio run`: a configuration in, the library calls of :mod:`hsio.api` (NS, open the site, HS),
the record, summary and plots out."""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path

import numpy as np

from hsio import api, plots
from hsio.compensation.stage import CompensationSettings, CompensationStage
from hsio.config import RunConfig
from hsio.diagnose.modelfile import merged_emulator_table
from hsio.errors import ConfigError
from hsio.experiment import ExperimentStopped
from hsio.ground_motion import GroundMotion, read_at2, synthetic_record
from hsio.integrators import IMPLICIT_METHODS, SwitchingRule
from hsio.recording import Recorder
from hsio.result import Result, max_error_pct
from hsio.secant import SecantEstimator
from hsio.structures import Structure, get_structure, load_structure


def build_record(config: RunConfig, structure: Structure) -> GroundMotion:
    rec = config["record"]
    if rec["file"]:
        ground = read_at2(rec["file"])
    else:
        ground = synthetic_record(duration_s=rec["synthetic_duration_s"], dt=structure.dt, pga_g=rec["pga_g"], seed=rec["seed"])
    if rec["scale"] != 1.0:
        ground = ground.scaled(rec["scale"])
    if rec["duration_s"] > 0:
        ground = ground.truncated(rec["duration_s"])
    return ground


def load_run_structure(config: RunConfig) -> Structure:
    """The structure a run configuration names: ``[structure] file`` (a structure file,
    docs/structures.md) or else ``name`` (a shipped structure)."""
    table = config["structure"]
    return load_structure(table["file"]) if table["file"] else get_structure(table["name"])


def switching_rule(structure: Structure, integ: dict) -> SwitchingRule:
    """K_f / K_d in kN/mm (0: 1.2 and 0.8 times each element's K^EI), or R_f / R_d in kN."""
    n = len(structure.experimental)
    if integ["switch_on"] == "force":
        lower = integ["R_d"] if integ["R_d"] > 0 else 0.5 * integ["R_f"]
        return SwitchingRule(np.full(n, integ["R_f"]), np.full(n, lower), "force")
    return SwitchingRule.from_initial_stiffness([e.K_EI for e in structure.experimental], integ["K_f"], integ["K_d"])


def integrator_options(config: RunConfig, structure: Structure) -> dict:
    """The [integrator] and [test] keys as options of :func:`hsio.api.make_integrator`."""
    integ = config["integrator"]
    if integ["method"] == "alpha_os":
        return {"correct_measured_displacement": config["test"]["measured_displacement_correction"]}
    return {"rule": switching_rule(structure, integ) if integ["method"] == "mixed" else None,
            "j_max": integ["j_max"], "tol_displacement": integ["tol_displacement_mm"], "tol_force": integ["tol_force_kN"]}


def run(config: RunConfig, out_dir: str | Path, progress=None, ground: GroundMotion | None = None) -> dict:
    """Run a hybrid simulation as configured; write run.sqlite, plots and summary.json in out_dir.

    ``ground`` replaces the configured [record] (a record built in code, e.g. a harmonic test).

    Returns the summary. Raises ExperimentStopped (after writing what was recorded) if the run
    stopped early.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    structure = load_run_structure(config)
    ground = ground if ground is not None else build_record(config, structure)
    integ = config["integrator"]
    method, alpha = integ["method"], integ["alpha"]
    implicit = method in IMPLICIT_METHODS
    test = config["test"]
    hardware = config["hardware"]

    ns = api.run_numerical(structure, ground, method, alpha) if config["output"]["ns"] else None
    compensation = CompensationStage([e.actuator for e in structure.experimental], test["rate"] * structure.dt,
                                     CompensationSettings.from_table(config["compensation"]))
    if implicit and compensation.settings.mode != "off":
        raise ConfigError(f"{config.source}: [compensation] applies to the alpha_os method, not to {method!r}")
    # An actuator model from `hsio diagnose` goes under the run's own [emulator] table.
    emulator = merged_emulator_table(hardware["actuator_model"], config["emulator"])
    meta = {
        "config": config.tables, "config_source": config.source, "structure": structure.name,
        "record": ground.name, "dt": structure.dt, "test_rate": test["rate"], "emulator_settings": emulator,
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    estimator = (SecantEstimator(integ["secant"], integ["secant_n_avg"], integ["secant_min_increment_mm"])
                 if implicit else None)
    with contextlib.ExitStack() as cleanup:
        # Whatever fails from here on, what was opened is closed (the actuators left holding).
        site = api.open_site(structure, hardware["url"], clock=hardware["clock"], test_rate=test["rate"],
                             hold_fraction=test["hold_fraction"], n_avg=test["n_avg"],
                             keep_samples=config["output"]["samples"],
                             options=emulator if hardware["url"].startswith("emulator") else config["driver"],
                             estimator=estimator, compensation=None if implicit else compensation)
        cleanup.callback(site.close)
        recorder = Recorder(out / "run.sqlite", structure.dof_names, [e.actuator for e in structure.experimental], meta)
        cleanup.callback(recorder.close)
        compensation.sink = recorder.write_compensation
        if ns is not None:
            recorder.write_ns(ns.t, ns.u)
        stopped = None
        try:
            hs = api.simulate(structure, ground, site, method, alpha, recorder, progress,
                                **integrator_options(config, structure))
        except ExperimentStopped as exc:
            hs, stopped = exc.result, exc
        site.close()
        summary = summarise(structure, config, ground, hs, ns, out)
        summary["clock_overruns"] = getattr(site.loop.clock, "overruns", 0)
        summary["compensation"] = compensation.summary()
        if implicit:
            summary.update(implicit_summary(hs))
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
        recorder.write_summary(summary)
        if config["output"]["plots"] and hs.steps > 0:
            summary["plots"] = make_plots(out, structure, hs, ns, config)
            if implicit:
                summary["plots"].append(str(plots.control_modes(out / "modes.png", hs)))
            (out / "summary.json").write_text(json.dumps(summary, indent=2))
            recorder.write_summary(summary)
    if stopped is not None:
        raise stopped
    return summary


def summarise(structure: Structure, config: RunConfig, ground: GroundMotion, hs: Result, ns: Result | None, out: Path) -> dict:
    summary = {
        "structure": structure.name,
        "record": ground.name,
        "steps": hs.steps,
        "dt": structure.dt,
        "test_rate": config["test"]["rate"],
        "hardware": config["hardware"]["url"],
        "clock": config["hardware"]["clock"],
        "dof": list(structure.dof_names),
        "peak_displacement_mm": [float(x) for x in np.max(np.abs(hs.u), axis=0)],
        "rms_tracking_error_mm": [float(x) for x in np.sqrt(np.mean(hs.tracking_error()[1:] ** 2, axis=0))] if hs.steps else [],
        "late_steps": hs.late_steps,
        "wall_time_s": round(hs.wall_time_s, 3),
        "test_time_s": round(hs.steps * structure.dt * config["test"]["rate"], 3),
        "run_file": str(out / "run.sqlite"),
        "stopped": hs.stopped,
    }
    if ns is not None:
        summary["ns_peak_displacement_mm"] = [float(x) for x in np.max(np.abs(ns.u), axis=0)]
        worst, per_dof = max_error_pct(hs.u, ns.u)
        summary["max_error_pct"] = worst
        summary["max_error_pct_per_dof"] = per_dof
    return summary


def implicit_summary(hs: Result) -> dict:
    """Method, switches, share of steps in FC, iterations and wall time per step; tracking errors
    of DC steps (mm) and of FC steps (kN) separately."""
    its = hs.iterations[1:]
    wall = hs.step_wall_time_s[1:]
    fc_act = hs.force_control[1:]
    d_err = np.where(~fc_act, hs.targets[1:] - hs.measured_displacement[1:], np.nan)
    f_err = np.where(fc_act, hs.targets[1:] - hs.measured_force[1:], np.nan)
    fc = hs.modes[1:] == "force"

    def rms(columns):
        return [float(np.sqrt(np.nanmean(c ** 2))) if np.isfinite(c).any() else 0.0 for c in columns.T]

    return {
        "rms_tracking_error_mm": rms(d_err),
        "rms_force_tracking_error_kN": rms(f_err),
        "method": hs.method,
        "switches": len(hs.switches),
        "switch_log": [s.as_dict() for s in hs.switches],
        "fc_step_fraction": [float(x) for x in fc.mean(axis=0)] if len(fc) else [],
        **({"test_time_s": round(hs.lab_time_s, 3)} if hs.lab_time_s is not None else {}),
        "iterations_per_step_mean": float(its.mean()) if its.size else 0.0,
        "iterations_per_step_max": int(its.max()) if its.size else 0,
        # Steps accepted after j_max commands without reaching the tolerance.
        "nonconverged_steps": int(np.count_nonzero(~hs.converged[1:])),
        "wall_time_per_step_ms": float(wall.mean() * 1e3) if wall.size else 0.0,
        "thresholds": hs.thresholds,
    }


def make_plots(out: Path, structure: Structure, hs: Result, ns: Result | None, config: RunConfig) -> list[str]:
    actuators = [e.actuator for e in structure.experimental]
    title = f"{structure.name}: HS vs NS, TR = {config['test']['rate']:g}"
    if ns is not None:
        worst, _ = max_error_pct(hs.u, ns.u)
        title += f", max error {worst:.2f} % of peak"
    paths = [
        plots.displacement_histories(out / "displacement.png", hs.t, hs.u, ns.t if ns is not None else None,
                                     ns.u if ns is not None else None, structure.dof_names, title),
        plots.hysteresis_loops(out / "hysteresis.png", hs.measured_displacement, hs.measured_force, actuators,
                               ns.measured_displacement if ns is not None else None, ns.measured_force if ns is not None else None),
        plots.tracking_error(out / "tracking.png", hs.t, hs.measured_displacement + hs.tracking_error(),
                             hs.measured_displacement, actuators,
                             config["emulator"].get("resolution_mm", 0.025)),
    ]
    return [str(p) for p in paths]
