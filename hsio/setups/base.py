"""The setup contract, and per-signal factors (sign, units, similitude scale).

A setup of ``n_basic`` basic DOFs and ``n_actuators`` actuators gives

* :meth:`Setup.strokes`: the actuator strokes (mm, from their length at rest) that put the
  element at basic displacements ``d`` (mm, rad), exactly;
* :meth:`Setup.basic_displacements`: the inverse, from measured strokes;
* :meth:`Setup.basic_forces`: the element's basic forces (kN, kN mm) from the actuator forces
  at the deformed geometry, by virtual work: q = J(d)^T f with J = d(strokes)/d(d) (times the
  factors below);
* :meth:`Setup.jacobian` and the linearised form, strokes = J(0) d.

:class:`Factors` scales each signal between the model and the lab: a displacement of the model
is ``displacement`` times the lab's, a force ``force`` times (a negative factor flips a sign);
rotations are the same in both, so a moment scales with ``force`` x ``displacement``. With the
Jacobian taken against the model's displacements, virtual work gives every basic force at once:
q = force x displacement x J^T f.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from hsio.errors import ConfigError


MIN_FACTOR = 1e-6  # a factor's magnitude is within [MIN_FACTOR, 1 / MIN_FACTOR]: scales and units, not overflow


@dataclass(frozen=True)
class Factors:
    """Model quantity = factor x lab quantity, per signal (similitude scale, units, sign)."""

    displacement: float = 1.0
    force: float = 1.0

    def __post_init__(self):
        for name in ("displacement", "force"):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
                    or not MIN_FACTOR <= abs(value) <= 1.0 / MIN_FACTOR):
                raise ConfigError(f"setup factors: {name} must be a number of magnitude {MIN_FACTOR:g} to "
                                  f"{1.0 / MIN_FACTOR:g} (negative flips the sign), got {value!r}")


def check_strokes(s: np.ndarray, n_actuators: int) -> None:
    """Refuse (ConfigError) strokes that are not one finite number per actuator: no pose gives them."""
    if s.shape != (n_actuators,):
        raise ConfigError(f"setup: {s.size} strokes for {n_actuators} actuators")
    if not np.all(np.isfinite(s)):
        raise ConfigError("setup: a stroke is not a finite number")


class Setup(ABC):
    """Basic DOFs of one experimental element <-> its actuators."""

    n_basic: int
    n_actuators: int
    factors: Factors = Factors()

    @abstractmethod
    def strokes(self, d: np.ndarray) -> np.ndarray:
        """Actuator strokes (lab mm) that put the element at basic displacements ``d`` (model)."""

    @abstractmethod
    def jacobian(self, d: np.ndarray) -> np.ndarray:
        """d(strokes)/d(d) at ``d``: n_actuators x n_basic."""

    def basic_displacements(self, strokes: np.ndarray, tol: float = 1e-12, max_iter: int = 50,
                            guess=None) -> np.ndarray:
        """The basic displacements at which the actuators have ``strokes``: Newton's method on
        the exact geometry from ``guess`` (the pose commanded: far from rest the same strokes
        may have another pose nearer rest), else, or where it does not close from there on a
        pose the actuators can drive to (:meth:`pose_problem`), from the linearised guess."""
        s = np.asarray(strokes, dtype=float)
        check_strokes(s, self.n_actuators)
        if guess is not None:
            start = np.asarray(guess, dtype=float)
            if start.shape == (self.n_basic,) and np.all(np.isfinite(start)):
                try:
                    d = self._newton(s, start.copy(), tol, max_iter)
                except ConfigError:
                    d = None
                if d is not None and not self.pose_problem(d):  # a pose the actuators can drive to
                    return d
        J0 = self.jacobian(np.zeros(self.n_basic))
        return self._newton(s, np.linalg.lstsq(J0, s, rcond=None)[0], tol, max_iter)

    def _newton(self, s: np.ndarray, d: np.ndarray, tol: float, max_iter: int) -> np.ndarray:
        for _ in range(max_iter):
            residual = self.strokes(d) - s
            step = np.linalg.lstsq(self.jacobian(d), residual, rcond=None)[0]
            d = d - step
            if np.max(np.abs(step)) <= tol * max(1.0, float(np.max(np.abs(d)))):
                return d
        raise ConfigError(f"setup: no basic displacement gives the strokes {s.tolist()} (the geometry "
                          f"does not close within {max_iter} iterations)")

    def pose_problem(self, d) -> str:
        """Why the actuators cannot drive the element to basic displacements ``d`` (empty: they can)."""
        return ""

    def basic_forces(self, forces: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Basic forces (model units) from the actuator forces (lab kN) at basic displacements ``d``."""
        f = np.asarray(forces, dtype=float)
        return self.factors.force * self.factors.displacement * (self.jacobian(d).T @ f)

    def linearised_strokes(self, d: np.ndarray) -> np.ndarray:
        """The small-displacement form: J(0) d."""
        return self.jacobian(np.zeros(self.n_basic)) @ np.asarray(d, dtype=float)
