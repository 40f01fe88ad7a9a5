"""Experimental and numerical substructures: what the integrator asks for R~ at u~.

:class:`ExperimentalSubstructure` drives actuators through the controller-rate loop
(:mod:`hsio.control_loop`) to the predicted displacements and returns the measured restoring
forces, corrected to the target with the measured displacement (METHOD.md section 2):

    R~^E = R_measured + K^EI (u~ - u_measured)

:class:`NumericalSubstructure` returns the specimen models' forces directly: the purely
numerical simulation (NS) of the same elements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hsio.control_loop import ControlLoop, StepFeedback
from hsio.structures import Structure


class NumericalSubstructure:
    """The experimental elements replaced by their specimen models (NS)."""

    def __init__(self, structure: Structure):
        self.structure = structure
        self.specimens = [e.model() for e in structure.experimental]
        self.last: StepFeedback | None = None

    def restoring_force(self, u_pred: np.ndarray) -> np.ndarray:
        R = np.zeros(self.structure.n_dof)
        d = np.array([u_pred[e.dof] for e in self.structure.experimental])
        F = np.array([s.force(x) for s, x in zip(self.specimens, d)])
        for e, f in zip(self.structure.experimental, F):
            R[e.dof] += f
        self.last = StepFeedback(targets=d, commands=d, displacement=d, force=F, samples=None)
        return R

    def close(self) -> None:
        pass


@dataclass
class Correction:
    """How the measured force is brought to the target displacement."""

    use_measured_displacement: bool = True


class ExperimentalSubstructure:
    """Actuators (one per experimental element, identity setup) driven step by step."""

    def __init__(self, structure: Structure, loop: ControlLoop, correction: Correction | None = None,
                 compensation=None):
        if len(loop.actuators) != len(structure.experimental):
            raise ValueError(f"{len(loop.actuators)} actuators for {len(structure.experimental)} experimental elements")
        self.structure = structure
        self.loop = loop
        self.correction = correction or Correction()
        self.K_EI = np.array([e.K_EI for e in structure.experimental])
        self.last: StepFeedback | None = None
        # Optional feed-forward stage d^c -> d^a (hsio.compensation.stage.CompensationStage).
        self.compensation = compensation

    def restoring_force(self, u_pred: np.ndarray) -> np.ndarray:
        d = np.array([u_pred[e.dof] for e in self.structure.experimental])
        if self.compensation is not None:
            d_a = self.compensation.adjust(d)
            fb = self.loop.execute(d_a)
            self.compensation.observe(d, d_a, fb.displacement)
            fb.targets = d.copy()  # the integrator's command; fb.commands holds the adjusted one
        else:
            fb = self.loop.execute(d)
        F = fb.force.copy()
        if self.correction.use_measured_displacement:
            F += self.K_EI * (d - fb.displacement)
        R = np.zeros(self.structure.n_dof)
        for e, f in zip(self.structure.experimental, F):
            R[e.dof] += f
        self.last = fb
        return R

    def close(self) -> None:
        self.loop.close()


def numerical_restoring_force(structure: Structure, numerical_specimens, u: np.ndarray) -> np.ndarray:
    """R~^N at u: the numerical linear springs plus the numerical nonlinear elements."""
    R = structure.K_N @ u
    for element, specimen in zip(structure.numerical, numerical_specimens):
        R[element.dof] += specimen.force(u[element.dof])
    return R
