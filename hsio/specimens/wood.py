"""The pinched hysteresis of a wood shear wall (test structure I, docs/method.md section 6)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hsio.errors import ConfigError
from hsio.specimens.base import Specimen


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
    _trial_state: tuple | None = field(default=None, init=False, repr=False)

    def __post_init__(self):
        for name in ("k0", "F0"):  # the backbone divides by both
            if not getattr(self, name) > 0:
                raise ConfigError(f"pinched_wood: {name} must be positive, got {getattr(self, name)!r}")
        # The model's premises: a backbone that does not fall (r1), an unloading line at least as
        # stiff as the backbone's initial tangent k0 (r3; a softer one makes loading follow it and,
        # below about 0.3, makes a closed cycle give energy out), pinching lines that rise (r4)
        # and meet the axis between zero and the extreme's force (r_pinch).
        for name, ok, meaning in (("r1", self.r1 >= 0, "zero or positive"), ("r3", self.r3 >= 1, "at least 1"),
                                  ("r4", self.r4 >= 0, "zero or positive"),
                                  ("r_pinch", 0 <= self.r_pinch <= 1, "within 0..1")):
            if not ok:
                raise ConfigError(f"pinched_wood: {name} must be {meaning}, got {getattr(self, name)!r}")
        self.revert_to_start()

    def revert_to_start(self) -> None:
        self._u = 0.0
        self._F = 0.0
        # A tiny virgin excursion keeps the reloading lines defined before any yielding.
        self._u_max_pos = 1e-6 * self.F0 / self.k0
        self._u_max_neg = -self._u_max_pos
        self._trial_state = None

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

    def trial(self, u: float, dt: float = 0.0) -> float:
        """The force at ``u`` moved to from the committed state; the state is kept as the trial."""
        u_max_pos, u_max_neg = self._u_max_pos, self._u_max_neg
        du = u - self._u
        if du == 0.0:
            self._trial_state = (self._u, self._F, u_max_pos, u_max_neg)
            return self._F
        trial = self._F + self.r3 * self.k0 * du
        if du > 0:
            F = min(trial, self._reloading_path(u, u_max_pos))
            if u > u_max_pos and F >= self.backbone(u) - 1e-12:
                u_max_pos = u
        else:
            F = max(trial, self._reloading_path(u, u_max_neg))
            if u < u_max_neg and F <= self.backbone(u) + 1e-12:
                u_max_neg = u
        self._trial_state = (u, F, u_max_pos, u_max_neg)
        return F

    def commit(self) -> None:
        if self._trial_state is not None:
            self._u, self._F, self._u_max_pos, self._u_max_neg = self._trial_state
            self._trial_state = None
