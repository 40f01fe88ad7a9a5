"""`hsio run` with [integrator] method = "implicit_dc", "force_control" or "mixed".

The pieces the runner needs for the implicit methods (METHOD.md sections 3 and 5): the switching
rule and secant estimator from the configuration, the numerical reference (the same iterated
alpha method on the specimen models, converged to 1e-10), the hybrid run, its summary and the
mode-history plot.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hsio.control_loop import ControlLoop
from hsio.experiment import Result
from hsio.fc_substructure import ExperimentalElements, NumericalElements
from hsio.ground_motion import GroundMotion
from hsio.mixed import SwitchingRule, simulate_implicit
from hsio.secant import SecantEstimator
from hsio.structures import Structure

IMPLICIT_METHODS = ("implicit_dc", "force_control", "mixed")


def is_implicit(config) -> bool:
    return config["integrator"].get("method", "alpha_os") in IMPLICIT_METHODS


def rule_from_config(structure: Structure, integ: dict) -> SwitchingRule:
    """K_f / K_d in kN/mm (0: 1.2 and 0.8 times each element's K^EI), or R_f / R_d in kN."""
    if integ["switch_on"] == "force":
        lower = integ["R_d"] if integ["R_d"] > 0 else 0.5 * integ["R_f"]
        return SwitchingRule(np.full(len(structure.experimental), integ["R_f"]),
                             np.full(len(structure.experimental), lower), "force")
    return SwitchingRule.from_initial_stiffness([e.K_EI for e in structure.experimental], integ["K_f"], integ["K_d"])


def numerical_reference(structure: Structure, ground: GroundMotion, alpha: float) -> Result:
    """NS for the implicit methods: iterated alpha method on the specimen models, DC, to 1e-10."""
    return simulate_implicit(structure, ground, NumericalElements(structure), alpha, "implicit_dc", j_max=20,
                             tol_displacement=1e-10, tol_force=1e-10)


def experimental_elements(structure: Structure, loop: ControlLoop, integ: dict) -> ExperimentalElements:
    estimator = SecantEstimator(integ["secant"], integ["secant_n_avg"], integ["secant_min_increment_mm"])
    return ExperimentalElements(structure, loop, estimator)


def run_hybrid(structure: Structure, ground: GroundMotion, elements, config, recorder=None, progress=None) -> Result:
    integ = config["integrator"]
    return simulate_implicit(structure, ground, elements, integ["alpha"], integ["method"],
                             rule_from_config(structure, integ) if integ["method"] == "mixed" else None,
                             j_max=integ["j_max"], tol_displacement=integ["tol_displacement_mm"],
                             tol_force=integ["tol_force_kN"], recorder=recorder, progress=progress)


def _fc_steps(hs: Result) -> np.ndarray:
    """Steps x actuators: true where the actuator ended the step in force control."""
    dofs = list(hs.extra.get("element_dofs", range(hs.targets.shape[1])))
    return hs.modes[:, dofs] == "force"


def tracking_view(hs: Result) -> Result:
    """A copy whose targets are displacements in every step: in FC steps, the displacement solution
    computed in parallel (what DC would have commanded), so that tracking plots stay in mm."""
    from dataclasses import replace

    fc = _fc_steps(hs)
    return replace(hs, targets=np.where(fc, hs.extra["u_solution"], hs.targets))


def summary(hs: Result) -> dict:
    """Method, switches, share of steps in FC, iterations and wall time per step; tracking errors
    of DC steps (mm) and of FC steps (kN) separately."""
    its = hs.extra["iterations"][1:]
    wall = hs.extra["step_wall_time_s"][1:]
    fc_act = _fc_steps(hs)[1:]
    d_err = np.where(~fc_act, hs.targets[1:] - hs.measured_displacement[1:], np.nan)
    f_err = np.where(fc_act, hs.targets[1:] - hs.measured_force[1:], np.nan)
    fc = hs.modes[1:] == "force"
    return {
        "rms_tracking_error_mm": [float(np.sqrt(np.nanmean(c ** 2))) if np.isfinite(c).any() else 0.0 for c in d_err.T],
        "rms_force_tracking_error_kN": [float(np.sqrt(np.nanmean(c ** 2))) if np.isfinite(c).any() else 0.0 for c in f_err.T],
        "method": hs.extra["method"],
        "switches": len(hs.extra["switches"]),
        "switch_log": hs.extra["switches"],
        "fc_step_fraction": [float(x) for x in fc.mean(axis=0)] if len(fc) else [],
        **({"test_time_s": round(hs.extra["lab_time_s"], 3)} if hs.extra.get("lab_time_s") is not None else {}),
        "iterations_per_step_mean": float(its.mean()) if its.size else 0.0,
        "iterations_per_step_max": int(its.max()) if its.size else 0,
        # Steps accepted after j_max commands without reaching the tolerance.
        "nonconverged_steps": int(np.count_nonzero(~hs.extra["converged"][1:])),
        "wall_time_per_step_ms": float(wall.mean() * 1e3) if wall.size else 0.0,
        "thresholds": hs.extra["thresholds"],
    }


def plot_modes(path: Path, hs: Result, dof_names, element_dofs) -> Path:
    """Per element: displacement with FC steps shaded, and the secant stiffness against the thresholds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(element_dofs)
    fig, axes = plt.subplots(2 * n, 1, figsize=(10, 4.4 * n + 0.8), sharex=True, squeeze=False)
    th = hs.extra["thresholds"]
    for j, d in enumerate(element_dofs):
        ax, ax_k = axes[2 * j, 0], axes[2 * j + 1, 0]
        fc = hs.modes[:, d] == "force"
        ax.plot(hs.t, hs.u[:, d], color="C0", lw=0.9, label="displacement")
        ymin, ymax = ax.get_ylim()
        ax.fill_between(hs.t, ymin, ymax, where=fc, color="C3", alpha=0.15, step="mid", label="force control")
        ax.set_ylim(ymin, ymax)
        ax.set_ylabel(f"{dof_names[d]} (mm)")
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
        switches = [s for s in hs.extra["switches"] if s["dof"] == dof_names[d]]
        ax.set_title(f"{dof_names[d]}: {len(switches)} switches, {fc[1:].mean() * 100:.0f} % of steps in FC", fontsize=9, loc="left")
        ax_k.plot(hs.t, hs.extra["secant"][:, j], color="C2", lw=0.8, label="secant stiffness")
        if th is not None and th["on"] == "stiffness":
            ax_k.axhline(th["upper"][j], color="C3", ls="--", lw=0.8, label="K_f (to FC)")
            ax_k.axhline(th["lower"][j], color="C0", ls="--", lw=0.8, label="K_d (to DC)")
        ax_k.set_ylabel("k (kN/mm)")
        ax_k.legend(loc="upper right", fontsize=8)
        ax_k.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(f"Control mode per step ({hs.extra['method']})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
