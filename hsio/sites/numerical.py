"""The experimental elements replaced by their specimen models: the purely numerical simulation.

A trial evaluates each model from its committed state without moving it
(:meth:`hsio.specimens.Specimen.trial`), so an implicit step may try as often as it needs; the
commit moves the models. In force control the displacement that carries the commanded force is
found by bracketing from the committed state and Brent's method (scipy.optimize.brentq).
"""

from __future__ import annotations

import numpy as np
import scipy.optimize

from hsio.errors import HsioError
from hsio.interfaces import ControlMode
from hsio.secant import secant_stiffness
from hsio.sites.base import Daq
from hsio.specimens import Specimen


def displacement_for_force(model: Specimen, target: float, u_start: float, F_start: float, k_guess: float,
                           xtol: float = 1e-13) -> float:
    """The displacement at which ``model``, moved from its committed state, carries ``target``.

    The models' force grows with displacement along any path from a committed state, so the root
    is bracketed by stepping out from ``u_start`` and found by Brent's method. The model's trial
    is left at the root.
    """
    if target == F_start:
        model.trial(u_start)
        return u_start

    def residual(u: float) -> float:
        return model.trial(u) - target

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
    model.trial(root)
    return root


class NumericalSite:
    """Specimen models in place of actuators (one per experimental element)."""

    late_steps = 0
    lab_time_s = None

    def __init__(self, models: list[Specimen]):
        self.models = list(models)
        # a multi-DOF model (hsio.specimens.matrix) takes as many channels as it has basic DOFs
        self._sizes = [getattr(m, "n", 1) if not isinstance(m, Specimen) else 1 for m in self.models]
        self._slices = []
        start = 0
        for size in self._sizes:
            self._slices.append(slice(start, start + size))
            start += size
        self.n_elements = start
        self.modes = [ControlMode.DISPLACEMENT] * self.n_elements
        self._committed = (np.zeros(self.n_elements), np.zeros(self.n_elements))
        self._daq: Daq | None = None

    @classmethod
    def of(cls, structure) -> "NumericalSite":
        """The specimen models of ``structure``'s experimental elements, in the virgin state
        (``built_for`` names the structure, which hsio.simulate checks)."""
        site = cls([e.model() for e in structure.experimental])
        site.built_for = structure
        return site

    def committed(self):
        return self._committed

    def set_modes(self, modes) -> list[int]:
        switched = [j for j, (old, new) in enumerate(zip(self.modes, modes)) if old is not new]
        self.modes = list(modes)
        return switched

    def set_trial(self, commands, modes) -> None:
        self.set_modes(modes)
        commands = np.asarray(commands, dtype=float)
        u_b, R_b = self._committed
        u = np.empty(self.n_elements)
        R = np.empty(self.n_elements)
        for model, block in zip(self.models, self._slices):
            if not isinstance(model, Specimen):  # multi-DOF: q = K d, or d for q in force control
                force = [m is ControlMode.FORCE for m in self.modes[block]]
                if all(force):
                    u[block] = model.displacement_for_force(commands[block])
                    R[block] = model.trial(u[block])
                elif not any(force):
                    u[block] = commands[block]
                    R[block] = model.trial(commands[block])
                else:
                    raise HsioError("numerical site: a multi-DOF element runs all its basic DOFs in one mode")
                continue
            j = block.start
            value, mode = commands[j], self.modes[j]
            if mode is ControlMode.FORCE:
                u[j] = displacement_for_force(model, float(value), float(u_b[j]), float(R_b[j]), model.initial_stiffness)
                R[j] = float(value)
            else:
                u[j], R[j] = float(value), model.trial(float(value))
        self._daq = Daq(u=u, R=R, k=secant_stiffness(u, R, u_b, R_b), targets=commands.copy(), commands=commands.copy())

    def get_daq(self) -> Daq:
        if self._daq is None:
            raise HsioError("numerical site: get_daq before any trial")
        return self._daq

    def commit(self) -> None:
        for model in self.models:
            model.commit()
        if self._daq is not None:
            self._committed = (self._daq.u, self._daq.R)

    def take_samples(self):
        return None

    def hold(self) -> None:
        pass

    def close(self) -> None:
        pass


class StandingSite(NumericalSite):
    """The specimen models standing where a measured specimen stands: element j answers
    R0_j + model_j(u - u0_j), its virgin model about the measured displacement u0_j and force
    R0_j (the prediction of a run that starts from the present state, docs/safety.md section 2:
    a damaged specimen taken as its initial model about where it stands). Displacement control
    only, as the present start is (alpha-OS), and one-DOF elements only: a structure with setups
    or multi-DOF elements is predicted from rest plus where each actuator stands instead."""

    def __init__(self, models: list[Specimen], u0, R0):
        if not all(isinstance(m, Specimen) for m in models):
            raise HsioError("standing site: one-DOF specimen models only (not a multi-DOF element)")
        super().__init__(models)
        self.u0, self.R0 = (np.asarray(x, dtype=float).copy() for x in (u0, R0))
        if self.u0.shape != (self.n_elements,) or self.R0.shape != (self.n_elements,):
            raise HsioError(f"standing site: {self.n_elements} elements, got {self.u0.size} displacements and "
                            f"{self.R0.size} forces")
        self._committed = (self.u0.copy(), self.R0.copy())

    def set_trial(self, commands, modes) -> None:
        if any(m is ControlMode.FORCE for m in modes):
            raise HsioError("standing site: displacement control only")
        self.set_modes(modes)
        u = np.asarray(commands, dtype=float).copy()
        R = self.R0 + np.array([model.trial(float(d)) for model, d in zip(self.models, u - self.u0)], dtype=float)
        u_b, R_b = self._committed
        self._daq = Daq(u=u, R=R, k=secant_stiffness(u, R, u_b, R_b), targets=u.copy(), commands=u.copy())
