"""A tracking controller as a discrete stage of the RTHS loop.

A stage is a step function ``u = step(p, s, k, x_t, v_t, a_t, x_m)`` called once per sample:
``p`` holds its fixed parameters, ``s`` its state (updated in place), ``x_t, v_t, a_t`` are the
desired displacement, velocity and acceleration from the numerical substructure and ``x_m`` the
measured displacement; ``u`` is the command to the plant. Step functions use scalar arithmetic
only, so that numba can compile them and plain Python runs them unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass
class Stage:
    name: str
    step: Callable  # a hsio.rths.jit.jit function
    p: np.ndarray
    s0: np.ndarray

    def fresh_state(self) -> np.ndarray:
        return self.s0.copy()
