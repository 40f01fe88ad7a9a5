"""A peak-oriented hysteresis with strength and stiffness degradation and a softening branch.

After the model of Ibarra, Medina and Krawinkler (2005), simplified: a tri-linear backbone with
a post-capping (negative stiffness) branch, peak-oriented reloading, and cyclic deterioration
driven by the hysteretic energy (Rahnama and Krawinkler 1993). It lets a structure have a
member that loses strength: force control on a softening branch (docs/force_control.md) can be
exercised on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hsio.errors import ConfigError
from hsio.specimens.base import Specimen


@dataclass
class PeakOriented(Specimen):
    """Peak-oriented hysteresis with energy-based cyclic deterioration.

    Virgin backbone, for a = |u| (mm), F in kN, u_y = F_y / k0:

    * elastic k0 a up to the yield point (u_y, F_y);
    * hardening H(a) = F_y + alpha_s k0 (a - u_y) up to the capping point u_c;
    * post-capping P(a) = F_c - alpha_c k0 (a - u_c), F_c = H(u_c), down to the residual
      strength residual F_y, then flat.

    Each excursion (a half-cycle between zero crossings of the force) that dissipates E_i
    deteriorates the strength and the unloading stiffness by the factor (1 - beta_i), with
    beta_i = (E_i / (E_t - sum E_j))^c and E_t = gamma F_y u_y the energy capacity. With strength
    factor s the envelope is min(k0 a, s max(min(H, P), residual F_y)): the elastic stiffness
    stays, the yield point moves down the elastic line. Unloading is linear with the
    (deteriorated) unloading stiffness k_u; reloading from the zero crossing aims at the largest
    earlier excursion in that direction on the deteriorated envelope (peak-oriented), or at the
    deteriorated yield point if the model has not yielded that way.
    """

    k0: float
    Fy: float
    u_c: float
    alpha_s: float = 0.03
    alpha_c: float = 0.10
    residual: float = 0.2
    gamma: float = 50.0
    c: float = 1.0
    kind = "peak_oriented"
    _state: tuple = field(default=(), init=False, repr=False)
    _trial_state: tuple | None = field(default=None, init=False, repr=False)

    BETA_MAX = 0.999
    # The unloading stiffness never falls below this fraction of k0: once the energy capacity is
    # spent every zero crossing takes BETA_MAX off it, and a specimen jittering about its
    # zero-force point (the transducer's noise) would underflow it to 0 within a few hundred
    # crossings, leaving the zero-force point u_c - F_c / k_u undefined.
    K_U_MIN = 1e-9

    def __post_init__(self):
        checks = [(self.k0 > 0, "k0 must be positive"), (self.Fy > 0, "Fy must be positive"),
                  (self.u_c > self.Fy / self.k0 if self.k0 > 0 else False, "u_c must exceed the yield displacement Fy/k0"),
                  (0 <= self.alpha_s < 1, "alpha_s must be in [0, 1)"), (self.alpha_c >= 0, "alpha_c must not be negative"),
                  (0 <= self.residual < 1, "residual must be in [0, 1)"), (self.gamma > 0, "gamma must be positive"),
                  (self.c > 0, "c must be positive")]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f"peak_oriented: {message}")
        self.revert_to_start()

    # state: u, F, u0 (start of the excursion), excursion sign, work in it, sum E_j, s, k_u,
    # largest positive and negative excursions
    def revert_to_start(self) -> None:
        self._state = (0.0, 0.0, 0.0, 0, 0.0, 0.0, 1.0, self.k0, 0.0, 0.0)
        self._trial_state = None

    @property
    def initial_stiffness(self) -> float:
        return self.k0

    @property
    def u_y(self) -> float:
        return self.Fy / self.k0

    @property
    def energy_capacity(self) -> float:
        """E_t = gamma F_y u_y, kN mm."""
        return self.gamma * self.Fy * self.u_y

    @property
    def strength_factor(self) -> float:
        """s: the committed strength deterioration (1 in the virgin state)."""
        return self._state[6]

    @property
    def unloading_stiffness(self) -> float:
        """k_u: the committed unloading stiffness (k0 in the virgin state)."""
        return self._state[7]

    def strength(self, a: float, s: float = 1.0) -> float:
        """s max(min(H(a), P(a)), residual F_y): the bound of the force at |u| = a beyond yield."""
        hardening = self.Fy + self.alpha_s * self.k0 * (a - self.u_y)
        F_cap = self.Fy + self.alpha_s * self.k0 * (self.u_c - self.u_y)
        capping = F_cap - self.alpha_c * self.k0 * (a - self.u_c)
        return s * max(min(hardening, capping), self.residual * self.Fy)

    def backbone(self, u: float, s: float = 1.0) -> float:
        """The envelope at ``u`` with strength factor ``s`` (1: the virgin backbone)."""
        a = abs(u)
        return math.copysign(min(self.k0 * a, self.strength(a, s)), u)

    def _yield_point(self, s: float) -> float:
        """Where the elastic line meets the deteriorated hardening line s H(a)."""
        return s * self.Fy * (1 - self.alpha_s) / (self.k0 * (1 - s * self.alpha_s))

    def _path(self, u: float, d: int, u0: float, s: float, u_max: float) -> float:
        """The reloading path in direction ``d`` from the zero crossing ``u0``, at ``u``."""
        a_y = self._yield_point(s)
        if abs(u_max) > a_y:
            u_t, F_t = u_max, self.backbone(u_max, s)
        else:
            u_t, F_t = d * a_y, d * self.k0 * a_y
        if (u - u_t) * d >= 0:
            return self.backbone(u, s)
        span = u_t - u0
        if span * d <= 1e-12 * self.u_y:
            return self.backbone(u, s) if u * d > 0 else 0.0
        line = F_t * (u - u0) / span
        if u * d > 0:  # bounded by the post-yield branches, not by the elastic one
            return d * min(d * line, self.strength(abs(u), s))
        return line

    def trial(self, u: float, dt: float = 0.0) -> float:
        u_c, F_c, u0, exc, W, E_sum, s, k_u, u_pos, u_neg = self._state
        du = u - u_c
        if du == 0.0:
            self._trial_state = self._state
            return F_c
        d = 1 if du > 0 else -1
        if F_c * d < 0 or (F_c == 0.0 and exc != d):
            u_zero = u_c - F_c / k_u
            if (u - u_zero) * d < 0:  # still unloading
                F = F_c + k_u * du
                W += 0.5 * (F_c + F) * du
            else:  # the excursion ends at u_zero; a new one starts there
                E_i = max(W - F_c**2 / (2 * k_u), 0.0)
                if exc != 0:
                    remaining = self.energy_capacity - E_sum
                    beta = 1.0 if remaining <= E_i else (E_i / remaining) ** self.c
                    beta = min(beta, self.BETA_MAX)
                    s *= 1 - beta
                    k_u = max(k_u * (1 - beta), self.K_U_MIN * self.k0)
                    E_sum += E_i
                exc, u0 = d, u_zero
                path = self._path(u, d, u0, s, u_pos if d > 0 else u_neg)
                F = d * min(d * k_u * (u - u_zero), d * path)
                W = 0.5 * F * (u - u_zero)
        else:
            path = self._path(u, d, u0, s, u_pos if d > 0 else u_neg)
            F = d * min(d * (F_c + k_u * du), d * path)
            W += 0.5 * (F_c + F) * du
        on_envelope = abs(F - self.backbone(u, s)) <= 1e-9 * max(1.0, abs(F))
        if on_envelope and u > u_pos:
            u_pos = u
        if on_envelope and u < u_neg:
            u_neg = u
        self._trial_state = (u, F, u0, exc, W, E_sum, s, k_u, u_pos, u_neg)
        return F

    def commit(self) -> None:
        if self._trial_state is not None:
            self._state = self._trial_state
            self._trial_state = None
