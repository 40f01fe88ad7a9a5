"""The experimental elements for the implicit FC / mixed integrator (METHOD.md sections 3 and 5).

Both classes implement :class:`hsio.integrators.force_control.Elements`: impose a displacement (DC)
or a force (FC) on each element, return the measured displacement, force and the secant stiffness
of eq. (11) from the state at the end of the previous step (the base).

* :class:`ExperimentalElements`: actuators through the controller-rate loop. Each iteration is one
  :meth:`ControlLoop.execute` (t_d = TR dt of lab time); the secant comes from the controller-rate
  samples by :class:`hsio.secant.SecantEstimator` (raw, averaged or least squares). Mode switches
  go through :meth:`ControlLoop.set_mode` (bumpless).
* :class:`NumericalElements`: the specimen models, evaluated exactly. An iteration is a *trial*
  from the state committed at the end of the previous step (the model is copied), so iterating
  does not leave a trace in a path-dependent model; in FC the displacement that gives the
  commanded force is found by bracketing and Brent's method.
"""

from __future__ import annotations

import copy

import numpy as np
import scipy.optimize

from hsio.control_loop import ControlLoop, StepFeedback
from hsio.errors import ConfigError, HsioError
from hsio.interfaces import ControlMode
from hsio.secant import SecantEstimator, secant_stiffness
from hsio.specimens import Specimen
from hsio.structures import Structure


class ExperimentalElements:
    """One actuator per experimental element (identity setup), driven iteration by iteration."""

    def __init__(self, structure: Structure, loop: ControlLoop, estimator: SecantEstimator | None = None):
        if len(loop.actuators) != len(structure.experimental):
            raise ConfigError(f"{len(loop.actuators)} actuators for {len(structure.experimental)} experimental elements")
        if not loop.keep_samples:
            raise ConfigError("force control needs the controller-rate samples: set [output] samples = true")
        self.structure = structure
        self.loop = loop
        self.estimator = estimator or SecantEstimator("average", n_avg=max(loop.n_avg, 1))
        feedback = loop.feedback()
        self._base = (np.array([f.displacement_mm for f in feedback]), np.array([f.force_kN for f in feedback]))
        self._last = self._base
        self.estimator.begin_step(*self._base)
        self.step_samples: list[np.ndarray] = []  # every iteration's samples of the present step
        self.last: StepFeedback | None = None

    @property
    def modes(self) -> list[ControlMode]:
        return [a.mode for a in self.loop.actuators]

    def set_modes(self, modes: list[ControlMode]) -> list[int]:
        """Switch the actuators whose mode differs (bumplessly); return the indices switched."""
        switched = []
        for index, (actuator, mode) in enumerate(zip(self.loop.actuators, modes)):
            if actuator.mode is not mode:
                self.loop.set_mode(index, mode)
                switched.append(index)
        return switched

    def base(self):
        return self._base

    def impose(self, commands, modes):
        self.set_modes(modes)  # a fall-back from FC to DC within a step (bumpless)
        fb = self.loop.execute(np.asarray(commands, dtype=float))
        samples = fb.samples  # n x n_act x 3: command, displacement, force
        self.step_samples.append(samples)
        u, R, k = self.estimator.update(samples[:, :, 1], samples[:, :, 2])
        self._last = (u, R)
        self.last = fb
        return u, R, k

    def commit(self):
        self._base = self._last
        self.estimator.begin_step(*self._base)

    def take_step_samples(self) -> np.ndarray | None:
        """The samples of every iteration of the step just made, in order; cleared."""
        if not self.step_samples:
            return None
        out = np.concatenate(self.step_samples, axis=0)
        self.step_samples = []
        return out

    def close(self) -> None:
        self.loop.close()


def displacement_for_force(committed: Specimen, target: float, u_start: float, F_start: float, k_guess: float,
                           xtol: float = 1e-13) -> tuple[float, Specimen]:
    """The displacement at which a copy of ``committed``, moved from its state, carries ``target``.

    The specimens' force grows with displacement along any path from a committed state, so the
    root is bracketed by stepping out from ``u_start`` and found by Brent's method. Returns the
    displacement and the specimen copy moved there.
    """
    if target == F_start:
        return u_start, copy.deepcopy(committed)

    def residual(u: float) -> float:
        return copy.deepcopy(committed).force(u) - target

    direction = 1.0 if target > F_start else -1.0
    step = max(abs(target - F_start) / max(k_guess, 1e-12), 1e-9)
    lo, f_lo = u_start, F_start - target
    hi = u_start + direction * step
    f_hi = residual(hi)
    for _ in range(200):
        if f_lo * f_hi <= 0:
            break
        lo, f_lo = hi, f_hi
        step *= 2.0
        hi = u_start + direction * step
        f_hi = residual(hi)
    else:
        raise HsioError(f"force control: no displacement carries {target:.6g} kN from the state at "
                        f"{u_start:.6g} mm (the element cannot resist that force)")
    root = scipy.optimize.brentq(residual, min(lo, hi), max(lo, hi), xtol=xtol, rtol=4 * np.finfo(float).eps)
    moved = copy.deepcopy(committed)
    moved.force(root)
    return root, moved


class NumericalElements:
    """The experimental elements replaced by their specimen models (NS for the implicit methods)."""

    def __init__(self, structure: Structure):
        self.structure = structure
        self._committed = [e.model() for e in structure.experimental]
        self._trial = list(self._committed)
        self._base = (np.zeros(len(self._committed)), np.zeros(len(self._committed)))
        self._last = self._base
        self.last: StepFeedback | None = None

    def set_modes(self, modes):
        return []

    def base(self):
        return self._base

    def impose(self, commands, modes):
        u_b, R_b = self._base
        u = np.empty(len(self._committed))
        R = np.empty(len(self._committed))
        trial = []
        for index, (specimen, value, mode) in enumerate(zip(self._committed, commands, modes)):
            if mode is ControlMode.FORCE:
                x, moved = displacement_for_force(specimen, float(value), float(u_b[index]), float(R_b[index]),
                                                  specimen.initial_stiffness)
                u[index], R[index] = x, float(value)
            else:
                moved = copy.deepcopy(specimen)
                u[index], R[index] = float(value), moved.force(float(value))
            trial.append(moved)
        self._trial = trial
        self._last = (u, R)
        self.last = StepFeedback(targets=np.asarray(commands, dtype=float).copy(), commands=np.asarray(commands, dtype=float).copy(),
                                 displacement=u, force=R, samples=None)
        return u, R, secant_stiffness(u, R, u_b, R_b)

    def commit(self):
        self._committed = self._trial
        self._base = self._last

    def take_step_samples(self):
        return None

    def close(self) -> None:
        pass
