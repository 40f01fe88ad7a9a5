"""Mixed variables: DC and FC side by side, switched per DOF between steps (METHOD.md section 5).

Every iteration of :class:`hsio.integrators.ImplicitForceControl` computes both the displacement and
the force of each element from one solve of eq. (7) (DC and FC in parallel over the whole history);
the element's mode decides which is commanded. At the end of each step :class:`SwitchingRule`
decides, per DOF, the mode of the next step from the measured secant stiffness (or the restoring
force), with two thresholds for hysteresis:

* to FC when the quantity rises above the upper threshold (K_f: the DOF is stiff, its displacement
  increments are small against the sensor resolution - unloading branches of wood walls, infill);
* back to DC when it falls below the lower threshold (K_d: the DOF is flexible again).

A switch is bumpless: the actuator and its command generator restart from the present measurement
of the new quantity. :func:`simulate_implicit` runs a whole record in ``implicit_dc``,
``force_control`` or ``mixed`` and records the mode of each DOF per step, the switches, the
iterations and the secant stiffness.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from hsio.errors import ConfigError
from hsio.experiment import Result, excitation, finish, stop_reason
from hsio.ground_motion import GroundMotion
from hsio.integrators import ImplicitForceControl
from hsio.interfaces import ControlMode
from hsio.recording import Recorder, column
from hsio.structures import Structure

METHODS = ("implicit_dc", "force_control", "mixed")
DC = ControlMode.DISPLACEMENT
FC = ControlMode.FORCE


@dataclass(frozen=True)
class SwitchingRule:
    """Two thresholds per element on the secant stiffness (kN/mm) or on |R| (kN).

    ``on = "stiffness"``: to FC when k > upper (K_f), to DC when k < lower (K_d).
    ``on = "force"``: to FC when |R| > upper, to DC when |R| < lower (specimens that stiffen
    with load, e.g. a closing gap).
    """

    upper: np.ndarray
    lower: np.ndarray
    on: str = "stiffness"

    def __post_init__(self):
        if self.on not in ("stiffness", "force"):
            raise ConfigError(f"switching rule: 'on' must be 'stiffness' or 'force', got {self.on!r}")
        upper = np.atleast_1d(np.asarray(self.upper, dtype=float))
        lower = np.atleast_1d(np.asarray(self.lower, dtype=float))
        if np.any(~np.isfinite(upper)) or np.any(~np.isfinite(lower)) or np.any(lower < 0):
            raise ConfigError(f"switching rule: thresholds must be finite and not negative, got {upper}, {lower}")
        if np.any(lower >= upper):
            raise ConfigError(f"switching rule: the lower threshold (to DC, {lower.tolist()}) must be below "
                              f"the upper one (to FC, {upper.tolist()})")
        object.__setattr__(self, "upper", upper)
        object.__setattr__(self, "lower", lower)

    @classmethod
    def from_initial_stiffness(cls, K_EI, K_f: float = 0.0, K_d: float = 0.0, ratio_f: float = 1.2,
                               ratio_d: float = 0.8) -> "SwitchingRule":
        """K_f, K_d in kN/mm, or (when zero) ratio_f K^EI and ratio_d K^EI per element."""
        K_EI = np.asarray(K_EI, dtype=float)
        upper = np.full(K_EI.shape, K_f) if K_f > 0 else ratio_f * K_EI
        lower = np.full(K_EI.shape, K_d) if K_d > 0 else ratio_d * K_EI
        return cls(upper, lower, "stiffness")

    def next_modes(self, modes: list[ControlMode], k: np.ndarray, R: np.ndarray) -> list[ControlMode]:
        q = np.asarray(k, dtype=float) if self.on == "stiffness" else np.abs(np.asarray(R, dtype=float))
        upper = np.broadcast_to(self.upper, q.shape)
        lower = np.broadcast_to(self.lower, q.shape)
        out = []
        for m, value, up, lo in zip(modes, q, upper, lower):
            if m is DC and value > up:
                out.append(FC)
            elif m is FC and value < lo:
                out.append(DC)
            else:
                out.append(m)
        return out


def implicit_numerical_stiffness(structure: Structure) -> np.ndarray:
    """K_N plus the numerical *linear* elements; nonlinear numerical elements are refused."""
    K = structure.K_N.copy()
    for element in structure.numerical:
        if element.specimen.get("kind") != "linear":
            raise ConfigError(f"structure {structure.name!r}: numerical element {element.name!r} is "
                              f"{element.specimen.get('kind')!r}; the implicit FC/mixed integrator takes numerical "
                              f"linear springs and linear elements only - use alpha_os")
        K[element.dof, element.dof] += float(element.specimen["k"])
    return K


def simulate_implicit(structure: Structure, ground: GroundMotion, elements, alpha: float = -0.05,
                      method: str = "mixed", rule: SwitchingRule | None = None, j_max: int = 4,
                      tol_displacement: float = 1e-3, tol_force: float = 1e-3,
                      recorder: Recorder | None = None, progress: Callable[[int], None] | None = None) -> Result:
    """Run a record with implicit DC, FC or mixed control against ``elements``.

    ``elements`` is :class:`hsio.fc_substructure.ExperimentalElements` (HS) or
    :class:`~hsio.fc_substructure.NumericalElements` (NS). ``Result.extra`` holds per step the
    iterations, the secant stiffness, the displacement and force solutions (DC and FC in
    parallel), and the list of switches.
    """
    if method not in METHODS:
        raise ConfigError(f"integrator method must be one of {', '.join(METHODS)}, got {method!r}")
    if method == "mixed" and rule is None:
        rule = SwitchingRule.from_initial_stiffness([e.K_EI for e in structure.experimental])
    t, P = excitation(structure, ground)
    n_steps, n = len(t), structure.n_dof
    n_e = len(structure.experimental)
    dofs = [e.dof for e in structure.experimental]
    integ = ImplicitForceControl(structure.M, structure.C, implicit_numerical_stiffness(structure), dofs,
                                 [e.K_EI for e in structure.experimental], structure.dt, alpha, j_max=j_max,
                                 tol_displacement=tol_displacement, tol_force=tol_force)
    modes = [FC if method == "force_control" else DC] * n_e
    fallback = rule.lower if method == "mixed" and rule.on == "stiffness" else None
    started = time.perf_counter()
    last = 0
    stopped = ""
    u, v, a, u_pred, R = (np.zeros((n_steps, n)) for _ in range(5))
    targets, commands, disp, force = (np.zeros((n_steps, n_e)) for _ in range(4))
    iterations = np.zeros((n_steps, n_e), dtype=int)
    converged = np.ones(n_steps, dtype=bool)  # False: j_max reached before the tolerance
    secant = np.zeros((n_steps, n_e))
    u_sol, R_sol = np.zeros((n_steps, n_e)), np.zeros((n_steps, n_e))
    mode_hist = np.full((n_steps, n), DC.value, dtype=object)
    step_time = np.zeros(n_steps)
    switches: list[dict] = []
    try:
        elements.set_modes(modes)
        integ.start(P[0], elements)
        u_b, R_b = elements.base()
        secant[0] = integ.k
        disp[0], force[0] = u_b, R_b
        a[0] = integ.state.a
        for j, d in enumerate(dofs):
            mode_hist[0, d] = modes[j].value
        for i in range(n_steps - 1):
            k_ = i + 1
            t0 = time.perf_counter()
            state, report = integ.step(P[k_], elements, modes, fallback)
            step_time[k_] = time.perf_counter() - t0
            u[k_], v[k_], a[k_], u_pred[k_], R[k_] = state.u, state.v, state.a, state.u_pred, state.R
            for j in np.flatnonzero(report.fell_back):
                switches.append({"step": k_, "time_s": float(t[k_]), "dof": structure.dof_names[dofs[j]], "to": DC.value,
                                 "within_step": True, "secant_kN_mm": float(report.k[j]),
                                 "force_kN": float(report.measured_R[j])})
            modes = report.modes
            for j, d in enumerate(dofs):
                mode_hist[k_, d] = modes[j].value
            fb = elements.last
            targets[k_] = report.commands
            commands[k_] = fb.commands if fb is not None else report.commands
            disp[k_], force[k_] = report.measured_u, report.measured_R
            iterations[k_], secant[k_] = report.iterations, report.k
            converged[k_] = report.converged
            u_sol[k_], R_sol[k_] = report.u_solution, report.R_solution
            if recorder is not None:
                recorder.write_row("implicit", k_, _implicit_row(structure, iterations[k_], converged[k_], secant[k_],
                                                                 u_sol[k_], R_sol[k_]))
                recorder.write_step(k_, float(t[k_]), u[k_], v[k_], a[k_], u_pred[k_], R[k_], mode_hist[k_],
                                    targets[k_], commands[k_], disp[k_], force[k_], elements.take_step_samples())
            else:
                elements.take_step_samples()
            last = k_
            if method == "mixed" and k_ < n_steps - 1:
                new = rule.next_modes(modes, report.k, report.measured_R)
                changed = [j for j in range(n_e) if new[j] is not modes[j]]
                if changed:
                    elements.set_modes(new)
                    for j in changed:
                        switches.append({"step": k_, "time_s": float(t[k_]), "dof": structure.dof_names[dofs[j]],
                                         "to": new[j].value, "within_step": False, "secant_kN_mm": float(report.k[j]),
                                         "force_kN": float(report.measured_R[j])})
                    modes = new
            if progress is not None:
                progress(1)
    except (Exception, KeyboardInterrupt) as exc:
        stopped = stop_reason(exc, last, structure.dt)
    histories = dict(t=t, u=u, v=v, a=a, u_pred=u_pred, R=R, targets=targets, commands=commands,
                     measured_displacement=disp, measured_force=force, modes=mode_hist)
    keep = slice(0, last + 1)
    extra = {"method": method, "element_dofs": dofs, "iterations": iterations[keep], "converged": converged[keep], "secant": secant[keep],
             "u_solution": u_sol[keep], "R_solution": R_sol[keep], "switches": switches,
             "step_wall_time_s": step_time[keep],
             "lab_time_s": _lab_time(elements),
             "thresholds": None if rule is None else {"on": rule.on, "upper": rule.upper.tolist(), "lower": rule.lower.tolist()}}
    return finish(structure, elements, histories, last, started, stopped, extra)


def _implicit_row(structure: Structure, iterations, converged: bool, secant, u_sol, R_sol) -> dict:
    """Per step and element: iterations, secant stiffness, displacement and force solutions."""
    row = {"converged": float(converged)}
    for j, e in enumerate(structure.experimental):
        row.update({column("iterations", e.name): int(iterations[j]), column("secant", e.name): float(secant[j]),
                    column("u_solution", e.name): float(u_sol[j]), column("r_solution", e.name): float(R_sol[j])})
    return row


def _lab_time(elements) -> float | None:
    """Controller time spent (ticks x period) when the elements run on a controller-rate loop."""
    clock = getattr(getattr(elements, "loop", None), "clock", None)
    return None if clock is None else float(clock.now_s)


def mode_switches(modes: np.ndarray) -> int:
    """Number of mode changes over a mode history (steps x DOF)."""
    m = np.asarray(modes)
    return int(np.sum(m[1:] != m[:-1]))
