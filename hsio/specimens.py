"""Specimen models: the restoring force of a physical element as a function of its deformation.

The same models serve the emulated controller (the "physical" specimen behind an emulated
actuator) and the purely numerical simulation (NS), so that HS and NS see the same element.

A specimen cannot be reverted: :meth:`Specimen.force` *moves* it to ``u`` and returns the
restoring force there, updating any history. Units: mm and kN.
"""

from __future__ import annotations

import copy
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

from hsio.errors import ConfigError


class Specimen(ABC):
    """A one-dimensional restoring-force element."""

    kind: str = ""

    @property
    @abstractmethod
    def initial_stiffness(self) -> float:
        """K^EI, kN/mm: the stiffness at zero deformation from the virgin state."""

    @abstractmethod
    def force(self, u: float) -> float:
        """Move the specimen to deformation ``u`` (mm); return its restoring force (kN)."""

    def reset(self) -> None:
        """Return to the virgin state (path-independent models have none)."""

    def clone(self) -> "Specimen":
        """An independent copy in the virgin state."""
        twin = copy.deepcopy(self)
        twin.reset()
        return twin


@dataclass
class Linear(Specimen):
    """R = k u."""

    k: float
    kind = "linear"

    @property
    def initial_stiffness(self) -> float:
        return self.k

    def force(self, u: float) -> float:
        return self.k * u


@dataclass
class BilinearGap(Specimen):
    """Bilinear elastic stiffening: k1 until a gap closes at |u| = gap, then k2 (push and pull).

    Column C2 of the validation structure (METHOD.md section 6): k1 = 0.536, k2 = 2.011 kN/mm.
    R = k1 u + (k2 - k1) sign(u) max(|u| - gap, 0).
    """

    k1: float
    k2: float
    gap: float
    kind = "bilinear_gap"

    @property
    def initial_stiffness(self) -> float:
        return self.k1

    def force(self, u: float) -> float:
        closing = max(abs(u) - self.gap, 0.0)
        return self.k1 * u + (self.k2 - self.k1) * math.copysign(closing, u)


@dataclass
class MenegottoPinto(Specimen):
    """Nonlinear elastic Menegotto-Pinto spring, METHOD.md eq. (13).

    R = k0 u_y [theta x + (1 - theta) x / (1 + |x|^n)^(1/n)],  x = u / u_y.
    theta < 1 softens, theta > 1 hardens.
    """

    k0: float
    u_y: float
    theta: float
    n: float = 1.0
    kind = "menegotto_pinto"

    @property
    def initial_stiffness(self) -> float:
        return self.k0

    def force(self, u: float) -> float:
        x = u / self.u_y
        shape = self.theta * x + (1.0 - self.theta) * x / (1.0 + abs(x) ** self.n) ** (1.0 / self.n)
        return self.k0 * self.u_y * shape


@dataclass
class PinchedWood(Specimen):
    """Pinched hysteresis of a wood shear wall: flexible loading, stiff unloading, pinching.

    A simplified form of the CUREE/SAWS wall model (Folz and Filiatrault 2001), without strength
    degradation. Backbone: F_env(u) = sign(u) (F0 + r1 k0 |u|) (1 - exp(-k0 |u| / F0)).

    A move from the present force F follows the stiff unloading line F + r3 k0 du, bounded by the
    path of the direction of motion. Going positive, the bound is the pinching line
    F_I+ + r4 k0 u while u < 0, then the line from (0, F_I+) to the positive extreme point
    (u_max+, F_env(u_max+)), then the backbone; F_I+ = r_pinch F_env(u_max+). Going negative,
    the mirror image. Extremes grow on the backbone.
    """

    k0: float
    F0: float
    r1: float = 0.05
    r3: float = 1.5
    r4: float = 0.02
    r_pinch: float = 0.15
    kind = "pinched_wood"
    _u: float = field(default=0.0, init=False, repr=False)
    _F: float = field(default=0.0, init=False, repr=False)
    _u_max_pos: float = field(default=0.0, init=False, repr=False)
    _u_max_neg: float = field(default=0.0, init=False, repr=False)

    def __post_init__(self):
        self.reset()

    def reset(self) -> None:
        self._u = 0.0
        self._F = 0.0
        # A tiny virgin excursion keeps the reloading lines defined before any yielding.
        self._u_max_pos = 1e-6 * self.F0 / self.k0
        self._u_max_neg = -self._u_max_pos

    @property
    def initial_stiffness(self) -> float:
        return self.k0

    def backbone(self, u: float) -> float:
        a = abs(u)
        return math.copysign((self.F0 + self.r1 * self.k0 * a) * (1.0 - math.exp(-self.k0 * a / self.F0)), u)

    def _reloading_path(self, u: float, u_ext: float) -> float:
        """The path towards the extreme ``u_ext`` (positive or negative side), at ``u``."""
        direction = math.copysign(1.0, u_ext)
        f_ext = self.backbone(u_ext)
        f_pinch = self.r_pinch * f_ext
        if u * direction >= abs(u_ext):
            return self.backbone(u)
        if u * direction >= 0.0:
            return f_pinch + (f_ext - f_pinch) * u / u_ext
        pinching = f_pinch + self.r4 * self.k0 * u
        return max(pinching, self.backbone(u)) if direction > 0 else min(pinching, self.backbone(u))

    def force(self, u: float) -> float:
        du = u - self._u
        if du == 0.0:
            return self._F
        trial = self._F + self.r3 * self.k0 * du
        if du > 0:
            F = min(trial, self._reloading_path(u, self._u_max_pos))
            if u > self._u_max_pos and F >= self.backbone(u) - 1e-12:
                self._u_max_pos = u
        else:
            F = max(trial, self._reloading_path(u, self._u_max_neg))
            if u < self._u_max_neg and F <= self.backbone(u) + 1e-12:
                self._u_max_neg = u
        self._u, self._F = u, F
        return F


SPECIMEN_KINDS: dict[str, type[Specimen]] = {
    cls.kind: cls for cls in (Linear, BilinearGap, MenegottoPinto, PinchedWood)
}


def make_specimen(spec: dict) -> Specimen:
    """Build a specimen from a table such as ``{"kind": "linear", "k": 0.613}``."""
    if not isinstance(spec, dict) or "kind" not in spec:
        raise ConfigError(f"specimen must be a table with a 'kind' key, got {spec!r}")
    kind = spec["kind"]
    cls = SPECIMEN_KINDS.get(kind)
    if cls is None:
        raise ConfigError(f"unknown specimen kind {kind!r}; known: {', '.join(sorted(SPECIMEN_KINDS))}")
    params = {k: v for k, v in spec.items() if k != "kind"}
    try:
        return cls(**params)
    except TypeError as exc:
        raise ConfigError(f"specimen {kind!r}: {exc}") from None


def specimen_spec(specimen: Specimen) -> dict:
    """The table that :func:`make_specimen` turns back into ``specimen``."""
    params = {k: v for k, v in vars(specimen).items() if not k.startswith("_")}
    return {"kind": specimen.kind, **params}
