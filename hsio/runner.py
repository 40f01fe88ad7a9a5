"""`hsio run`: build the structure, record and hardware from a configuration, run HS and NS,
record, summarise and plot."""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path

import numpy as np

from hsio import implicit_run, plots
from hsio.clock import LockstepClock, RealTimeClock
from hsio.compensation.stage import CompensationSettings, CompensationStage
from hsio.config import RunConfig
from hsio.control_loop import ControlLoop
from hsio.diagnose.modelfile import merged_emulator_table
from hsio.errors import ConfigError
from hsio.experiment import ExperimentStopped, Result, max_error_pct, simulate
from hsio.ground_motion import GroundMotion, read_at2, synthetic_record
from hsio.hardware import open_hardware
from hsio.recording import Recorder
from hsio.structures import Structure, get_structure
from hsio.substructure import Correction, ExperimentalSubstructure, NumericalSubstructure


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


def run_numerical(structure: Structure, ground: GroundMotion, alpha: float) -> Result:
    """NS: the same integrator with the specimen models in place of the actuators."""
    return simulate(structure, ground, NumericalSubstructure(structure), alpha)


def run(config: RunConfig, out_dir: str | Path, progress=None, ground: GroundMotion | None = None) -> dict:
    """Run a hybrid simulation as configured; write run.sqlite, plots and summary.json in out_dir.

    ``ground`` replaces the configured [record] (a record built in code, e.g. a harmonic test).

    Returns the summary. Raises ExperimentStopped (after writing what was recorded) if the run
    stopped early.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    structure = get_structure(config["structure"]["name"])
    ground = ground if ground is not None else build_record(config, structure)
    alpha = config["integrator"]["alpha"]
    test = config["test"]
    hardware = config["hardware"]

    implicit = implicit_run.is_implicit(config)
    ns = None
    if config["output"]["ns"]:
        ns = implicit_run.numerical_reference(structure, ground, alpha) if implicit else run_numerical(structure, ground, alpha)
    compensation = CompensationStage([e.name for e in structure.experimental], test["rate"] * structure.dt,
                                     CompensationSettings.from_table(config["compensation"]))
    if implicit and compensation.settings.mode != "off":
        raise ConfigError(f"{config.source}: [compensation] applies to the alpha_os method, not to {config['integrator']['method']!r}")
    clock = LockstepClock() if hardware["clock"] == "lockstep" else RealTimeClock()
    # An actuator model from `hsio diagnose` goes under the run's own [emulator] table.
    emulator = merged_emulator_table(hardware["actuator_model"], config["emulator"])
    meta = {
        "config": config.tables, "config_source": config.source, "structure": structure.name,
        "record": ground.name, "dt": structure.dt, "test_rate": test["rate"], "emulator_settings": emulator,
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    with contextlib.ExitStack() as cleanup:
        # Whatever fails from here on, what was opened is closed (the actuators left holding).
        actuators = open_hardware(hardware["url"], structure.experimental, clock,
                                  emulator if hardware["url"].startswith("emulator") else config["driver"])
        try:
            loop = ControlLoop(actuators, clock, structure.dt, test["rate"], n_avg=test["n_avg"],
                               keep_samples=config["output"]["samples"], hold_fraction=test["hold_fraction"])
        except BaseException:
            _close_all(actuators)
            raise
        cleanup.callback(loop.close)  # from here on the loop owns the actuators
        if implicit:
            substructure = implicit_run.experimental_elements(structure, loop, config["integrator"])
        else:
            substructure = ExperimentalSubstructure(structure, loop, Correction(test["measured_displacement_correction"]), compensation)
        recorder = Recorder(out / "run.sqlite", structure.dof_names, [a.name for a in actuators], meta)
        cleanup.callback(recorder.close)
        compensation.sink = recorder.write_compensation
        if ns is not None:
            recorder.write_ns(ns.t, ns.u)
        stopped = None
        try:
            if implicit:
                hs = implicit_run.run_hybrid(structure, ground, substructure, config, recorder, progress)
            else:
                hs = simulate(structure, ground, substructure, alpha, recorder, progress)
        except ExperimentStopped as exc:
            hs, stopped = exc.result, exc
        loop.close()
        summary = summarise(structure, config, ground, hs, ns, out)
        summary["clock_overruns"] = getattr(clock, "overruns", 0)
        summary["compensation"] = compensation.summary()
        if implicit:
            summary.update(implicit_run.summary(hs))
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
        recorder.write_summary(summary)
        if config["output"]["plots"] and hs.steps > 0:
            summary["plots"] = make_plots(out, structure, implicit_run.tracking_view(hs) if implicit else hs, ns, config)
            if implicit:
                summary["plots"].append(str(implicit_run.plot_modes(out / "modes.png", hs, structure.dof_names, structure.experimental_dofs)))
            (out / "summary.json").write_text(json.dumps(summary, indent=2))
            recorder.write_summary(summary)
    if stopped is not None:
        raise stopped
    return summary


def _close_all(actuators) -> None:
    """Hold and release every actuator; each is tried whatever the others do."""
    for actuator in actuators:
        try:
            actuator.close()
        except Exception:
            pass


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


def make_plots(out: Path, structure: Structure, hs: Result, ns: Result | None, config: RunConfig) -> list[str]:
    actuators = [e.name for e in structure.experimental]
    title = f"{structure.name}: HS vs NS, TR = {config['test']['rate']:g}"
    if ns is not None:
        worst, _ = max_error_pct(hs.u, ns.u)
        title += f", max error {worst:.2f} % of peak"
    paths = [
        plots.displacement_histories(out / "displacement.png", hs.t, hs.u, ns.t if ns is not None else None,
                                     ns.u if ns is not None else None, structure.dof_names, title),
        plots.hysteresis_loops(out / "hysteresis.png", hs.measured_displacement, hs.measured_force, actuators,
                               ns.measured_displacement if ns is not None else None, ns.measured_force if ns is not None else None),
        plots.tracking_error(out / "tracking.png", hs.t, hs.targets, hs.measured_displacement, actuators,
                             config["emulator"].get("resolution_mm", 0.025)),
    ]
    return [str(p) for p in paths]
