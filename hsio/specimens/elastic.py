"""Path-independent (elastic) specimen models: linear, bilinear with a gap, Menegotto-Pinto.

Their force depends on the deformation only, so a trial needs no state and commit does nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hsio.errors import ConfigError
from hsio.specimens.base import Specimen


@dataclass
class Linear(Specimen):
    """R = k u."""

    k: float
    kind = "linear"

    @property
    def initial_stiffness(self) -> float:
        return self.k

    def trial(self, u: float, dt: float = 0.0) -> float:
        return self.k * u


@dataclass
class BilinearGap(Specimen):
    """Bilinear elastic stiffening: k1 until a gap closes at |u| = gap, then k2 (push and pull).

    Column C2 of the validation structure (E&M 2007, Table I): k1 = 0.536, k2 = 2.011 kN/mm.
    R = k1 u + (k2 - k1) sign(u) max(|u| - gap, 0).
    """

    k1: float
    k2: float
    gap: float
    kind = "bilinear_gap"

    def __post_init__(self):
        if not self.gap >= 0:
            raise ConfigError(f"bilinear_gap: gap must be zero or positive (mm), got {self.gap!r}")

    @property
    def initial_stiffness(self) -> float:
        return self.k1

    def trial(self, u: float, dt: float = 0.0) -> float:
        closing = max(abs(u) - self.gap, 0.0)
        return self.k1 * u + (self.k2 - self.k1) * math.copysign(closing, u)


@dataclass
class MenegottoPinto(Specimen):
    """Nonlinear elastic Menegotto-Pinto spring, E&M 2007 eq. (13).

    R = k0 u_y [theta x + (1 - theta) x / (1 + |x|^n)^(1/n)],  x = u / u_y.
    theta < 1 softens, theta > 1 hardens.
    """

    k0: float
    u_y: float
    theta: float
    n: float = 1.0
    kind = "menegotto_pinto"

    def __post_init__(self):
        for name in ("u_y", "n"):  # x = u / u_y and the exponent 1 / n
            if not getattr(self, name) > 0:
                raise ConfigError(f"menegotto_pinto: {name} must be positive, got {getattr(self, name)!r}")

    @property
    def initial_stiffness(self) -> float:
        return self.k0

    def trial(self, u: float, dt: float = 0.0) -> float:
        x = u / self.u_y
        ax = abs(x)
        # x / (1 + |x|^n)^(1/n), written so that no power overflows for a large n (a near-bilinear
        # spring): beyond |x| = 1, sign(x) / (1 + |x|^-n)^(1/n)
        if ax <= 1.0:
            transition = x / (1.0 + ax ** self.n) ** (1.0 / self.n)
        else:
            transition = math.copysign(1.0, x) / (1.0 + ax ** -self.n) ** (1.0 / self.n)
        shape = self.theta * x + (1.0 - self.theta) * transition
        return self.k0 * self.u_y * shape


