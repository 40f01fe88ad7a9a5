"""A site of independent bilinear elements with exact measurements, for the integrator tests
(tests/test_mut_mixed.py, tests/test_mut_implicit.py)."""

from __future__ import annotations

import numpy as np

from hsio.interfaces import ControlMode
from hsio.sites.base import Daq

FC = ControlMode.FORCE


class ExactSite:
    """Independent elements, exact measurements: element e is linear at k1[e] up to u_c[e], then
    k2[e]. The secant reported is the exact one from the committed state, or ``k_seen[e]`` when
    set (what a noisy estimator might read)."""

    def __init__(self, k1, u_c=None, k2=None):
        self.k1 = np.asarray(k1, dtype=float)
        n = self.k1.size
        self.u_c = np.full(n, np.inf) if u_c is None else np.asarray(u_c, dtype=float)
        self.k2 = self.k1.copy() if k2 is None else np.asarray(k2, dtype=float)
        self.k_seen = [None] * n
        self.base = self.last = (np.zeros(n), np.zeros(n))
        self.sent: list[tuple[np.ndarray, list]] = []
        self.mode_changes: list[list] = []

    def R(self, u):
        return self.k1 * np.minimum(u, self.u_c) + self.k2 * np.maximum(u - self.u_c, 0.0)

    def u_of(self, F):
        F_c = self.k1 * self.u_c
        return np.minimum(F, F_c) / self.k1 + np.maximum(F - F_c, 0.0) / self.k2

    def committed(self):
        return self.base

    def set_modes(self, modes):
        self.mode_changes.append(list(modes))
        return []

    def set_trial(self, commands, modes):
        commands = np.asarray(commands, dtype=float)
        self.sent.append((commands.copy(), list(modes)))
        fc = np.array([m is FC for m in modes])
        u = np.where(fc, self.u_of(commands), commands)
        R = self.R(u)
        du = u - self.base[0]
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.where(du != 0, (R - self.base[1]) / np.where(du != 0, du, 1.0), np.nan)
        k = np.array([k[e] if self.k_seen[e] is None else self.k_seen[e] for e in range(k.size)])
        self.last = (u, R)
        self._daq = Daq(u=u, R=R, k=k, targets=commands, commands=commands, samples=None)

    def get_daq(self):
        return self._daq

    def commit(self):
        self.base = self.last
