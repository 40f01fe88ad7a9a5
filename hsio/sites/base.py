"""The contract between an integrator and the experimental elements of a structure.

Modelled on the control contract of hybrid-simulation middleware: the integrator imposes a
*trial* (:meth:`ExperimentalSite.set_trial`), reads what was measured
(:meth:`ExperimentalSite.get_daq`) and, once the step is accepted, commits it
(:meth:`ExperimentalSite.commit`). A step may hold several trials (the iterations of the implicit
methods, docs/method.md sections 3 and 5); a trial is never rolled back, only followed by
another trial or by the commit.

Everything is per experimental element, in the structure's element order: displacements in mm,
forces in kN, each element in displacement (DC) or force (FC) control.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hsio.interfaces import ControlMode


@dataclass
class Daq:
    """What one trial measured, per element.

    ``u`` and ``R`` are the measured displacement and force, ``k`` the secant stiffness of
    E&M 2007 eq. (11) from the committed state (nan where no estimate is possible), ``targets``
    what the integrator asked, ``commands`` the last command the actuators were sent (with
    feed-forward compensation, the adjusted one), ``samples`` the controller-rate samples of
    the trial (n x elements x 3: command, displacement, force) when kept.
    """

    u: np.ndarray
    R: np.ndarray
    k: np.ndarray
    targets: np.ndarray
    commands: np.ndarray
    samples: np.ndarray | None = None


class ExperimentalSite(Protocol):
    """The experimental elements as an integrator sees them."""

    n_elements: int
    late_steps: int  # steps whose target came after the command generator had slowed down
    lab_time_s: float | None  # controller time spent so far; None for a numerical site

    def committed(self) -> tuple[np.ndarray, np.ndarray]:
        """The measured (u, R) per element at the end of the last committed step."""

    def set_trial(self, commands: np.ndarray, modes: list[ControlMode]) -> None:
        """Impose displacements (DC) or forces (FC) per element; returns when they are reached."""

    def get_daq(self) -> Daq:
        """What the last trial measured."""

    def commit(self) -> None:
        """The step is accepted: the last trial becomes the committed state."""

    def set_modes(self, modes: list[ControlMode]) -> list[int]:
        """Switch elements' control modes between trials, bumplessly; the indices switched."""

    def take_samples(self) -> np.ndarray | None:
        """The controller-rate samples of every trial since the last call, in order."""

    def hold(self) -> None:
        """Every actuator holds where it stands (called when a run stops early)."""

    def close(self) -> None:
        """Leave every actuator holding and release it."""
