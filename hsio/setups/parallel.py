"""Several actuators driving one basic DOF in parallel (docs/setups.md).

Two actuators side by side pushing a wall's top, or a beam loaded at two points tied to one
DOF: actuator i moves by its ratio a_i times the basic displacement d (in the lab's units),

    s_i = a_i d / lambda_d,

so the Jacobian is the column a / lambda_d and virtual work gives the basic force as the
ratio-weighted sum of the actuator forces, q = lambda_F lambda_d J^T f = lambda_F sum_i a_i f_i.
The actuators' measured strokes give d by least squares, d = lambda_d (a . s) / (a . a): the
same d from every actuator when they agree; when they do not, the mean of each actuator's
lambda_d s_i / a_i weighted by a_i^2 (an actuator that moves more for the DOF tells it better).
"""

from __future__ import annotations

import math

import numpy as np

from hsio.errors import ConfigError
from hsio.setups.base import MIN_FACTOR, Factors, Setup, check_strokes

MAX_ACTUATORS = 16  # actuators on one DOF: a rig, not an array


class ParallelSetup(Setup):
    """One basic DOF, ``len(ratios)`` actuators: s_i = ratios[i] d / lambda_d."""

    basic: tuple[str, ...] = ()
    n_basic = 1

    def __init__(self, ratios, factors: Factors | None = None):
        ratios = list(ratios)
        if not 2 <= len(ratios) <= MAX_ACTUATORS:
            raise ConfigError(f"ratios: must give 2 to {MAX_ACTUATORS} actuators (one ratio each), "
                              f"got {len(ratios)}")
        for j, r in enumerate(ratios):
            if (isinstance(r, bool) or not isinstance(r, (int, float)) or not math.isfinite(r)
                    or not MIN_FACTOR <= abs(r) <= 1.0 / MIN_FACTOR):
                raise ConfigError(f"ratios[{j}]: must be a number of magnitude {MIN_FACTOR:g} to "
                                  f"{1.0 / MIN_FACTOR:g} (the actuator's stroke per unit of the DOF; negative: "
                                  f"it moves the other way), got {r!r}")
        self.ratios = np.array(ratios, dtype=float)
        self.n_actuators = len(ratios)
        self.factors = factors or Factors()
        self._J = (self.ratios / self.factors.displacement)[:, None]

    def strokes(self, d) -> np.ndarray:
        d = np.asarray(d, dtype=float)
        if d.shape != (1,):
            raise ConfigError(f"parallel setup: {d.size} basic displacements for 1 basic DOF")
        return self._J[:, 0] * d[0]

    def jacobian(self, d) -> np.ndarray:
        return self._J.copy()

    def basic_displacements(self, strokes, tol: float = 1e-12, max_iter: int = 50, guess=None) -> np.ndarray:
        """Least squares over the actuators: d = lambda_d (a . s) / (a . a)."""
        s = np.asarray(strokes, dtype=float)
        check_strokes(s, self.n_actuators)
        a = self.ratios
        return np.array([self.factors.displacement * float(a @ s) / float(a @ a)])
