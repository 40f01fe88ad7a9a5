"""The specimen model that `hsio diagnose --specimen` writes: a linear spring and dashpot with the
effects the diagnosis found (docs/diagnose.md, "Specimen diagnosis").

    F = D(s) [k u + k_3 u^3 + k_gap sign(u) max(|u| - gap, 0) + f_y (z / u_y) P(u)]   spring, gap, hysteresis
        + c v_ref sign(v) |v / v_ref|^alpha                                     dashpot (alpha = 1: viscous)
        + F_c tanh(v / v_0)                                                     friction (Coulomb; with c: Bingham)
        + m a                                                                   a moving mass

* k_3 u^3 makes the spring nonlinear but elastic (hardening with k_3 > 0, softening with
  k_3 < 0): the force is a function of the displacement alone and its loops enclose no area.
* z is the Bouc-Wen hysteretic displacement, dz = du [1 - |z/u_y|^2 (beta sign(du z) + gamma)]
  with beta = gamma = 1/2 (Wen 1976, with n = 2), integrated exactly over each move: it follows
  u elastically after a reversal and saturates at +-u_y, so the hysteretic force is bounded by
  the strength f_y.
* P(u) = 1 - pinch exp(-(u / pinch_width_mm)^2) pinches the loop near zero deformation (slack
  connectors, closing cracks): the hysteretic force is reduced where the loop crosses u = 0.
* D(s) = 1 / (1 + degradation_per_mm s) degrades stiffness and strength with the travel
  s = sum |du| accumulated since the virgin state (a damage index).
* v and a are backward differences over the move (dt): v = (u - u_c) / dt, a = (v - v_c) / dt.
  With dt = 0 (quasi-static) the rate terms vanish.

Units: mm, kN, s; mass in kg (m a in kN = mass_kg 1e-6 a in mm/s^2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hsio.specimens.base import Specimen

BETA = GAMMA = 0.5
_EDGE = 1.0 - 1e-12


def bouc_wen_step(z: float, du: float, u_y: float) -> float:
    """The hysteretic displacement after a move du, integrated exactly: unloading (du z < 0) has
    dz/du = 1 - (beta - gamma) |z/u_y|^2 = 1 until z crosses zero; loading has
    dz/du = 1 - (z/u_y)^2, so z/u_y = tanh(atanh(z0/u_y) + du/u_y)."""
    if du == 0.0 or u_y <= 0.0:
        return z
    if du * z < 0.0:
        if abs(du) <= abs(z):
            return z + du
        du += z  # the part of the move beyond z = 0 loads from zero
        z = 0.0
    x = max(min(z / u_y, _EDGE), -_EDGE)
    return u_y * math.tanh(math.atanh(x) + du / u_y)


def pinching(u: float, pinch: float, width: float) -> float:
    return 1.0 - pinch * math.exp(-((u / width) ** 2)) if pinch > 0.0 and width > 0.0 else 1.0


def damper(v: float, c: float, alpha: float, v_ref: float) -> float:
    if alpha == 1.0 or v == 0.0:
        return c * v
    return c * v_ref * math.copysign(abs(v / v_ref) ** alpha, v)


@dataclass
class Diagnosed(Specimen):
    """A linear viscoelastic specimen extended by the diagnosed effects (all neutral by default)."""

    k: float
    c: float = 0.0
    k3: float = 0.0  # kN/mm^3
    alpha: float = 1.0
    v_ref_mm_s: float = 1.0
    friction_kN: float = 0.0
    friction_v0_mm_s: float = 1.0
    mass_kg: float = 0.0
    gap_mm: float = 0.0
    k_gap: float = 0.0
    fy_kN: float = 0.0
    uy_mm: float = 1.0
    pinch: float = 0.0
    pinch_width_mm: float = 1.0
    degradation_per_mm: float = 0.0
    _state: tuple = field(default=(0.0, 0.0, 0.0, 0.0), repr=False)  # committed u, v, z, s
    _trial: tuple = field(default=(0.0, 0.0, 0.0, 0.0), repr=False)
    kind = "diagnosed"

    def __post_init__(self):
        from hsio.errors import ConfigError

        for name in ("k", "k3", "c", "alpha", "v_ref_mm_s", "friction_kN", "friction_v0_mm_s", "mass_kg", "gap_mm", "k_gap",
                     "fy_kN", "uy_mm", "pinch", "pinch_width_mm", "degradation_per_mm"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"specimen 'diagnosed': {name} must be a finite number, got {value!r}")
            if name not in ("k", "k3") and value < 0:
                raise ConfigError(f"specimen 'diagnosed': {name} must be zero or positive, got {value!r}")
        for name in ("alpha", "v_ref_mm_s", "friction_v0_mm_s", "uy_mm", "pinch_width_mm"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"specimen 'diagnosed': {name} must be positive, got {getattr(self, name)!r}")
        if self.pinch >= 1.0:
            raise ConfigError(f"specimen 'diagnosed': pinch must be below 1, got {self.pinch!r}")

    @property
    def initial_stiffness(self) -> float:
        hysteretic = self.fy_kN / self.uy_mm * pinching(0.0, self.pinch, self.pinch_width_mm)
        return self.k + hysteretic + (self.k_gap if self.gap_mm == 0.0 else 0.0)

    def trial(self, u: float, dt: float = 0.0) -> float:
        u_c, v_c, z, s = self._state
        du = u - u_c
        z = bouc_wen_step(z, du, self.uy_mm) if self.fy_kN > 0.0 else 0.0
        s += abs(du)
        v = du / dt if dt > 0.0 else 0.0
        a = (v - v_c) / dt if dt > 0.0 else 0.0
        self._trial = (u, v, z, s)
        d = 1.0 / (1.0 + self.degradation_per_mm * s)
        spring = self.k * u + self.k3 * u**3 + self.k_gap * math.copysign(max(abs(u) - self.gap_mm, 0.0), u)
        if self.fy_kN > 0.0:
            spring += self.fy_kN * (z / self.uy_mm) * pinching(u, self.pinch, self.pinch_width_mm)
        rate = damper(v, self.c, self.alpha, self.v_ref_mm_s) + self.friction_kN * math.tanh(v / self.friction_v0_mm_s)
        return d * spring + rate + 1e-6 * self.mass_kg * a

    def commit(self) -> None:
        self._state = self._trial

    def revert_to_start(self) -> None:
        self._state = self._trial = (0.0, 0.0, 0.0, 0.0)
