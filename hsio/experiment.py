"""The experiment loop: one integration step at a time, hybrid (HS) or purely numerical (NS).

Each step (METHOD.md section 2, the paper's Figure 9): predict u~_{i+1}, impose it on the
experimental substructure and measure R~^E, add the numerical restoring force R~^N, solve and
correct, record. Any error stops the run in a safe state: the actuators hold, every step already
made stays in the record, and :class:`ExperimentStopped` carries the partial result.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from hsio.errors import HsioError
from hsio.ground_motion import GroundMotion
from hsio.integrators import AlphaOS
from hsio.recording import Recorder
from hsio.specimens import make_specimen
from hsio.structures import Structure
from hsio.substructure import numerical_restoring_force


@dataclass
class Result:
    """Histories of a run, one row per step (step 0 is the initial state)."""

    structure: str
    dt: float
    t: np.ndarray
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    u_pred: np.ndarray
    R: np.ndarray
    targets: np.ndarray  # per actuator
    commands: np.ndarray
    measured_displacement: np.ndarray
    measured_force: np.ndarray
    modes: np.ndarray  # per DOF, "displacement" or "force"
    wall_time_s: float = 0.0
    late_steps: int = 0
    stopped: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def steps(self) -> int:
        return len(self.t) - 1

    def tracking_error(self) -> np.ndarray:
        """Target minus measured displacement at the end of each step, per actuator (mm)."""
        return self.targets - self.measured_displacement


class ExperimentStopped(HsioError):
    """The run stopped before the end; ``result`` holds every step made."""

    def __init__(self, message: str, result: Result):
        super().__init__(message)
        self.result = result


def excitation(structure: Structure, ground: GroundMotion) -> tuple[np.ndarray, np.ndarray]:
    """Time and P = -M iota a_g at the structure's time step (kN)."""
    g = ground.resampled(structure.dt)
    ag = g.acceleration_mm_s2()
    P = -np.outer(ag, structure.M @ structure.iota)
    return np.arange(len(ag)) * structure.dt, P


def simulate(structure: Structure, ground: GroundMotion, substructure, alpha: float = -0.05,
             recorder: Recorder | None = None, progress: Callable[[int], None] | None = None) -> Result:
    """Run alpha-OS over the whole record against ``substructure`` (experimental or numerical)."""
    t, P = excitation(structure, ground)
    n_steps, n = len(t), structure.n_dof
    n_act = len(structure.experimental)
    integrator = AlphaOS(structure.M, structure.C, structure.K_init, structure.dt, alpha)
    integrator.start(P[0])
    numerical = [make_specimen(e.specimen) for e in structure.numerical]
    u, v, a, u_pred, R = (np.zeros((n_steps, n)) for _ in range(5))
    a[0] = integrator.state.a
    targets, commands, disp, force = (np.zeros((n_steps, n_act)) for _ in range(4))
    modes = np.full((n_steps, n), "displacement", dtype=object)
    started = time.perf_counter()
    last = 0
    stopped = ""
    try:
        for i in range(n_steps - 1):
            predicted, _ = integrator.predict()
            R_tilde = substructure.restoring_force(predicted) + numerical_restoring_force(structure, numerical, predicted)
            state = integrator.correct(R_tilde, P[i + 1])
            fb = substructure.last
            k = i + 1
            u[k], v[k], a[k], u_pred[k], R[k] = state.u, state.v, state.a, state.u_pred, state.R_pred
            targets[k], commands[k], disp[k], force[k] = fb.targets, fb.commands, fb.displacement, fb.force
            if recorder is not None:
                recorder.write_step(k, float(t[k]), u[k], v[k], a[k], u_pred[k], R[k], modes[k],
                                    targets[k], commands[k], disp[k], force[k], fb.samples)
            last = k
            if progress is not None:
                progress(1)
    except (Exception, KeyboardInterrupt) as exc:
        stopped = stop_reason(exc, last, structure.dt)
    histories = dict(t=t, u=u, v=v, a=a, u_pred=u_pred, R=R, targets=targets, commands=commands,
                     measured_displacement=disp, measured_force=force, modes=modes)
    return finish(structure, substructure, histories, last, started, stopped)


def stop_reason(exc: BaseException, last: int, dt: float) -> str:
    """Why a run stopped after step ``last``: an HsioError says it plainly; anything else is named."""
    if isinstance(exc, KeyboardInterrupt):
        return f"interrupted at step {last + 1}"
    what = str(exc) if isinstance(exc, HsioError) else f"unexpected {exc!r}"
    return f"step {last + 1} (t = {(last + 1) * dt:.3f} s): {what}"


def hold_all(owner) -> None:
    """Every actuator behind ``owner`` (a substructure with a control loop) holds."""
    hold = getattr(getattr(owner, "loop", None), "hold_all", None)
    if hold is not None:
        hold()


def finish(structure: Structure, owner, histories: dict, last: int, started: float, stopped: str,
           extra: dict | None = None) -> Result:
    """The Result of steps 0..last. If the run ``stopped``, the actuators behind ``owner`` hold
    and ExperimentStopped is raised carrying the Result."""
    if stopped:
        hold_all(owner)
    keep = slice(0, last + 1)
    result = Result(
        structure=structure.name, dt=structure.dt, **{name: h[keep] for name, h in histories.items()},
        wall_time_s=time.perf_counter() - started,
        late_steps=getattr(getattr(owner, "loop", None), "late_steps", 0),
        stopped=stopped, extra=extra or {},
    )
    if stopped:
        raise ExperimentStopped(f"run stopped at {stopped}; the actuators hold; {last} steps recorded", result)
    return result


def max_error_pct(u_hs: np.ndarray, u_ns: np.ndarray) -> tuple[float, list[float]]:
    """Max over time and DOF of |u_HS - u_NS| / peak |u_NS| of that DOF, in percent; and per DOF."""
    n = min(len(u_hs), len(u_ns))
    peak = np.max(np.abs(u_ns[:n]), axis=0)
    peak = np.where(peak > 0, peak, 1.0)
    per_dof = np.max(np.abs(u_hs[:n] - u_ns[:n]), axis=0) / peak * 100.0
    return float(np.max(per_dof)), [float(x) for x in per_dof]
