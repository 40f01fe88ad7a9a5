"""The contract between the experiment loop and an integration method.

Every method (alpha-OS; implicit DC, FC and mixed) advances the structure one step at a time
against an experimental site (:class:`hsio.sites.ExperimentalSite`) and the structure's
numerical part (:class:`hsio.structures.NumericalAssembly`), and reports what it did in a
:class:`StepOutcome`. The loop (:mod:`hsio.experiment`) knows nothing else of the method.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from hsio.interfaces import ControlMode
from hsio.result import Switch


@dataclass
class StepOutcome:
    """One step, per DOF (``u`` ... ``R``) and per experimental element (the rest)."""

    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    u_pred: np.ndarray
    R: np.ndarray  # the restoring force the integrator used (kN)
    modes: list[ControlMode]  # per element, at the end of the step
    targets: np.ndarray  # the last commands of the integrator (mm in DC, kN in FC)
    commands: np.ndarray  # the last command the actuators were sent
    measured_u: np.ndarray
    measured_R: np.ndarray
    iterations: np.ndarray
    converged: bool
    secant: np.ndarray
    u_solution: np.ndarray
    R_solution: np.ndarray
    switches: list[Switch] = field(default_factory=list)


class Integrator(Protocol):
    """An integration method as the experiment loop drives it."""

    method: str
    thresholds: dict | None

    def start(self, P0: np.ndarray, site, numerical) -> StepOutcome:
        """The initial state (step 0) from P_0 and the site's committed state."""

    def step(self, P_next: np.ndarray, site, numerical, step: int, time_s: float) -> StepOutcome:
        """Advance one step to P_{i+1}; the site and the numerical part are committed."""
