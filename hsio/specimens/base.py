"""The specimen interface: a one-dimensional restoring-force element with trial and commit.

A specimen model stands for a physical element: the emulated controller loads it at every
controller period, and the purely numerical simulation (NS) uses it in place of the actuators.
As OpenSees' uniaxial materials do, a model separates trying from accepting:

* :meth:`Specimen.trial` gives the force at a deformation reached from the committed state,
  without moving that state (an integrator may try several deformations in one step);
* :meth:`Specimen.commit` accepts the last trial as the new committed state;
* :meth:`Specimen.force` does both: the physical specimen, which cannot be reverted.

Units: mm and kN (docs/method.md section 1).
"""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod


class Specimen(ABC):
    """A one-dimensional restoring-force element."""

    kind: str = ""

    @property
    @abstractmethod
    def initial_stiffness(self) -> float:
        """K^EI, kN/mm: the stiffness at zero deformation from the virgin state."""

    @abstractmethod
    def trial(self, u: float, dt: float = 0.0) -> float:
        """The restoring force (kN) at deformation ``u`` (mm) reached from the committed state.

        ``dt`` is the time the move takes (s); 0 when unknown, and rate-dependent models then
        give their quasi-static force. The committed state does not change.
        """

    def commit(self) -> None:
        """Accept the last trial as the committed state (path-independent models have none)."""

    def revert_to_start(self) -> None:
        """Return to the virgin state."""

    def force(self, u: float, dt: float = 0.0) -> float:
        """Move the specimen to ``u`` and keep it there: trial, then commit."""
        F = self.trial(u, dt)
        self.commit()
        return F

    def clone(self) -> "Specimen":
        """An independent copy in the virgin state."""
        twin = copy.deepcopy(self)
        twin.revert_to_start()
        return twin
