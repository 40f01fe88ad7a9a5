"""The experiment loop: one integration step at a time, for every method, hybrid (HS) or numerical (NS).

Each step the method (:mod:`hsio.integrators`) imposes trials on the experimental site
(:mod:`hsio.sites`: actuators, or the specimen models for NS), reads the measurements, solves and
commits; the loop records the step and reports progress (E&M 2007 Figures 9 and 11;
docs/method.md sections 2, 3 and 5). Between two steps it obeys the operator (pause, resume,
stop: :class:`hsio.safety.control.RunControl`) and records what the interlocks saw. Any error,
interlock, stop or interrupt stops the run in a safe state: the actuators hold (read back, and
said only when confirmed), every step already made stays in the record, and
:class:`ExperimentStopped` carries the partial :class:`~hsio.result.Result` and the cause
(docs/safety.md).

A run starts at rest (``start="rest"``) or from where the specimen stands
(``start="present"``, docs/safety.md section 6): the integrator starts from the measured
displacement and restoring force, the numerical DOFs in static equilibrium.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from hsio.errors import ConfigError, HsioError
from hsio.ground_motion import GroundMotion
from hsio.integrators.base import Integrator, StepOutcome
from hsio.interfaces import ControlMode
from hsio.recording import Recorder, column
from hsio.result import Result, Switch, max_error_pct
from hsio.structures import Structure, dof_units

__all__ = ["ExperimentStopped", "excitation", "run_steps", "max_error_pct", "stop_reason"]


class ExperimentStopped(HsioError):
    """The run stopped before the end; ``result`` holds every step made, ``cause`` is the error
    (or interrupt) that stopped it and ``hold`` the read-back of the actuators' hold (or None)."""

    def __init__(self, message: str, result: Result, cause: BaseException | None = None, hold=None):
        super().__init__(message)
        self.result = result
        self.cause = cause
        self.hold = hold


def excitation(structure: Structure, ground: GroundMotion) -> tuple[np.ndarray, np.ndarray]:
    """Time and the effective force P = -M iota a_g at the structure's time step (kN; E&M 2007
    section 2)."""
    g = ground.resampled(structure.dt)
    ag = g.acceleration_mm_s2()
    P = -np.outer(ag, structure.M @ structure.iota)
    return np.arange(len(ag)) * structure.dt, P


def stop_reason(exc: BaseException, last: int, dt: float) -> str:
    """Why a run stopped after step ``last``: an HsioError says it plainly; anything else is named."""
    if isinstance(exc, KeyboardInterrupt):
        return f"step {last + 1} (t = {(last + 1) * dt:.3f} s): interrupted (Ctrl-C)"
    from hsio.safety.status import OperatorStop

    if isinstance(exc, OperatorStop):
        return f"step {last + 1} (t = {(last + 1) * dt:.3f} s): {exc}"
    what = str(exc) if isinstance(exc, HsioError) else f"unexpected {exc!r}"
    return f"step {last + 1} (t = {(last + 1) * dt:.3f} s): {what}"


class _Histories:
    """Preallocated per-step arrays that the loop fills in, then cut to the steps made."""

    def __init__(self, n_steps: int, n_dof: int, n_e: int):
        dof = lambda: np.zeros((n_steps, n_dof))  # noqa: E731
        el = lambda: np.zeros((n_steps, n_e))  # noqa: E731
        self.u, self.v, self.a, self.u_pred, self.R = dof(), dof(), dof(), dof(), dof()
        self.modes = np.full((n_steps, n_dof), ControlMode.DISPLACEMENT.value, dtype=object)
        self.targets, self.commands, self.measured_displacement, self.measured_force = el(), el(), el(), el()
        self.iterations = np.zeros((n_steps, n_e), dtype=int)
        self.converged = np.ones(n_steps, dtype=bool)
        self.secant, self.u_solution, self.R_solution = el(), el(), el()
        self.step_wall_time_s = np.zeros(n_steps)

    def put(self, k: int, out: StepOutcome, dofs) -> None:
        self.u[k], self.v[k], self.a[k], self.u_pred[k], self.R[k] = out.u, out.v, out.a, out.u_pred, out.R
        for j, d in enumerate(dofs):
            self.modes[k, d] = out.modes[j].value
        self.targets[k], self.commands[k] = out.targets, out.commands
        self.measured_displacement[k], self.measured_force[k] = out.measured_u, out.measured_R
        self.iterations[k], self.converged[k] = out.iterations, out.converged
        self.secant[k], self.u_solution[k], self.R_solution[k] = out.secant, out.u_solution, out.R_solution

    def cut(self, last: int) -> dict:
        keep = slice(0, last + 1)
        return {name: values[keep] for name, values in vars(self).items()}


def _implicit_row(names, out: StepOutcome) -> dict:
    """Per step and element: iterations, secant stiffness, displacement and force solutions."""
    row = {"converged": float(out.converged)}
    for j, name in enumerate(names):
        row.update({column("iterations", name): int(out.iterations[j]), column("secant", name): float(out.secant[j]),
                    column("u_solution", name): float(out.u_solution[j]),
                    column("r_solution", name): float(out.R_solution[j])})
    return row


def start_present(integrator, structure: Structure, P0: np.ndarray, site, numerical) -> StepOutcome:
    """Step 0 from where the specimen stands: each element at its measured displacement and
    force, E u_0 = u_e (E the elements' incidence, :attr:`hsio.structures.Structure.incidence`),
    the numerical DOFs in static equilibrium of the linear numerical part and the elements'
    forces on them, K_N u_0 + E^T R_e = 0 there, v_0 = 0 (docs/safety.md section 6)."""
    if getattr(integrator, "method", "") != "alpha_os" or not hasattr(integrator, "core"):
        raise ConfigError(f"start = 'present' is available for the alpha_os method, not {integrator.method!r}")
    dofs = list(structure.experimental_dofs)
    E = structure.incidence
    u_e, R_e = (np.asarray(x, dtype=float) for x in site.committed())
    n = structure.n_dof
    R_E = E.T @ R_e
    free = [d for d in range(n) if d not in dofs]
    if free and not numerical.is_linear:
        raise ConfigError(f"structure {structure.name!r}: start = 'present' needs a linear numerical part to put "
                          f"the numerical DOFs in static equilibrium")
    K = np.asarray(numerical.K_linear, dtype=float)
    A = np.vstack([E, K[free]])  # a row per element (its displacement), one per numerical DOF (its equilibrium)
    if np.linalg.matrix_rank(A) < n:
        raise ConfigError(f"structure {structure.name!r}: start = 'present': the elements' displacements and the "
                          f"numerical stiffness of the DOFs {', '.join(structure.dof_names[d] for d in free) or '(none)'} "
                          "do not fix the structure's displacement; no static equilibrium")
    u0 = np.linalg.solve(A, np.concatenate([u_e, -R_E[free]]))
    R0 = R_E + numerical.trial(u0)
    numerical.commit()
    state = integrator.core.start(P0, u0, np.zeros(n), R0)
    out = integrator._outcome(state, None, 0)
    out.measured_u, out.measured_R = u_e.copy(), R_e.copy()
    return out


def write_events(recorder, site, step: int) -> list[dict]:
    """The safety layer's events since the last call (``site.take_events``), written with ``step``
    into ``recorder`` (committed with the step's row); returned."""
    take = getattr(site, "take_events", None)
    events = take() if take is not None else []
    if recorder is not None:
        for e in events:
            recorder.write_event(e["time_s"], step, e["kind"], e["actuator"], e["message"], commit=False)
    return events


def write_unfinished(recorder, site, step: int, t: np.ndarray, stop_lab_time_s: float, stopped: str) -> str:
    """After a stop in the middle of step ``step``: its samples so far (``site.take_unfinished``)
    into the record's uncommitted tables (:meth:`hsio.recording.Recorder.write_uncommitted`),
    never into its steps. Returns "" when written or when there was nothing to write, else a
    clause saying they could not be (a full disk): never raised, the stop is what counts."""
    take = getattr(site, "take_unfinished", None)
    try:
        unfinished = take() if take is not None else None
        if unfinished is None or not len(unfinished["samples"]) or step >= len(t):
            return ""
        recorder.write_uncommitted(step, float(t[step]), stop_lab_time_s, stopped, unfinished["targets"],
                                   unfinished["samples"], unfinished["times"], unfinished["phases"])
        return ""
    except Exception as exc:  # the trip, the hold and the steps before are recorded already
        return f"the samples of the unfinished step {step} could not be recorded ({exc})"


INTERLOCK_TABLE = "interlocks"


def _interlock_row(site, recorder, step: int, last: dict | None) -> dict | None:
    """The interlock monitor's running state (:meth:`hsio.safety.interlocks.InterlockMonitor.state`),
    written into the record's ``interlocks`` table (``peak_force_kN_<actuator>``) with step
    ``step`` when it changed since ``last`` (committed with the step's row); returns the state now."""
    monitor = getattr(getattr(site, "loop", None), "monitor", None)
    if monitor is None:
        return last
    state = monitor.state()
    if state != last:
        recorder.write_row(INTERLOCK_TABLE, step, {f"peak_force_kN_{name}": peak for name, peak in state.items()})
    return state


def run_steps(structure: Structure, ground: GroundMotion, integrator: Integrator, site,
              recorder: Recorder | None = None, progress: Callable[[int], None] | None = None,
              control=None, start: str = "rest", resume_state=None) -> Result:
    """Run ``integrator`` over the whole record against ``site`` (actuators or specimen models).

    ``control`` (a :class:`hsio.safety.control.RunControl`) is obeyed between steps; ``start`` is
    ``"rest"`` or ``"present"``; ``resume_state`` (an alpha-OS state read back from a record,
    docs/safety.md section 8) continues a run after its last committed step, the rows before it
    left empty. Returns the :class:`Result`; raises :class:`ExperimentStopped`
    carrying the steps made if the run stops early (the actuators behind ``site`` hold first).
    """
    if start not in ("rest", "present"):
        raise ConfigError(f"start must be 'rest' or 'present', got {start!r}")
    t, P = excitation(structure, ground)
    n_steps = len(t)
    dofs = structure.experimental_dofs
    names = structure.experimental_names
    numerical = structure.numerical_assembly()
    h = _Histories(n_steps, structure.n_dof, len(dofs))
    switches: list[Switch] = []
    started = time.perf_counter()
    last = 0
    stopped = ""
    cause: BaseException | None = None
    hold_report = None
    interlock_row = None
    unfinished_note = ""

    def log(kind: str, message: str) -> None:
        if recorder is not None:
            recorder.write_event(site.lab_time_s, last, kind, "", message)

    first = 0 if resume_state is None else int(resume_state.i)
    last = first
    try:
        if resume_state is not None:
            integrator.core.state = resume_state
            numerical.trial(resume_state.u)
            numerical.commit()
            h.put(first, integrator._outcome(resume_state, None, 0), dofs)
        elif start == "present":
            h.put(0, start_present(integrator, structure, P[0], site, numerical), dofs)
        else:
            h.put(0, integrator.start(P[0], site, numerical), dofs)
        if hasattr(site, "opened_for"):
            site.moved = True  # from the first command on, the actuators may stand away from rest
        if control is not None:  # a pause or stop asked before the first step: before it, not after
            control.checkpoint(site, first, log)
        for i in range(first, n_steps - 1):
            k = i + 1
            t0 = time.perf_counter()
            out = integrator.step(P[k], site, numerical, k, float(t[k]))
            h.step_wall_time_s[k] = time.perf_counter() - t0
            h.put(k, out, dofs)
            switches += out.switches
            samples = site.take_samples()
            if recorder is not None:
                if integrator.method != "alpha_os":
                    recorder.write_row("implicit", k, _implicit_row(names, out))
                meta = site.take_sample_meta() if hasattr(site, "take_sample_meta") else None
                events = write_events(recorder, site, k)
                if hasattr(site, "record_tables"):  # preload and instrument logs, committed with the step
                    recorder.write_tables(site.record_tables())
                interlock_row = _interlock_row(site, recorder, k, interlock_row)
                recorder.write_step(k, float(t[k]), h.u[k], h.v[k], h.a[k], h.u_pred[k], h.R[k], h.modes[k],
                                    h.targets[k], h.commands[k], h.measured_displacement[k], h.measured_force[k],
                                    samples, sample_meta=meta, late_steps=site.late_steps,
                                    flags=sorted({e["kind"] for e in events}))
            last = k
            if progress is not None:
                progress(1)
            if control is not None:
                if k < n_steps - 1:
                    control.checkpoint(site, k, log)
                else:  # the last step: no step left to pause or stop before; the run finishes and holds
                    control.step = k
    except (Exception, KeyboardInterrupt) as exc:
        stopped = stop_reason(exc, last, structure.dt)
        cause = exc
        stop_lab_time_s = site.lab_time_s
        hold = getattr(site, "hold", None)
        if hold is not None:
            hold_report = hold()
        if recorder is not None:
            try:
                write_events(recorder, site, last + 1)
                if hold_report is not None:
                    recorder.write_event(site.lab_time_s, last + 1, "hold", "", hold_report.message, commit=False)
                recorder.write_event(site.lab_time_s, last + 1, "stop", "", stopped)
            except Exception:
                pass  # the record keeps what it has; the stop is reported below
            # after the trip, the hold and the stop are committed: a failure here loses none of them
            unfinished_note = write_unfinished(recorder, site, last + 1, t, stop_lab_time_s, stopped)
    result = Result(
        structure=structure.name, method=integrator.method, dt=structure.dt,
        dof_names=tuple(structure.dof_names), element_names=tuple(names), element_dofs=tuple(dofs),
        t=t[: last + 1], **h.cut(last), switches=switches, thresholds=integrator.thresholds,
        secant_refused=getattr(integrator, "secant_refused", None),
        guarded_steps=int(getattr(integrator, "guarded_steps", 0)),
        wall_time_s=time.perf_counter() - started, lab_time_s=site.lab_time_s, late_steps=site.late_steps,
        stopped=stopped, dof_units=tuple(dof_units(structure)),
    )
    if stopped:
        held = hold_report.message if hold_report is not None else "no actuators to hold"
        note = f"; {unfinished_note}" if unfinished_note else ""
        raise ExperimentStopped(f"run stopped at {stopped}; {held}; {last} steps recorded{note}", result, cause,
                                hold_report)
    return result
