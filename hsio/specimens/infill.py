"""A masonry-infilled RC frame as one storey spring: stiff until the infill cracks, then softening
and losing strength, with cyclic deterioration.

The envelope is the trilinear strut-type envelope used for infilled frames (after the infill
models of Mehrabi and Shing and of Stavridis and Shing): an uncracked branch of high stiffness
k0 up to the cracking force F_cr, a cracked branch up to the peak strength F_max at u_max, a
falling branch (the diagonal strut crushes, the sliding cracks open) down to a residual strength
F_res, then flat. The hysteresis is peak-oriented with energy-based deterioration of strength and
unloading stiffness (:class:`hsio.specimens.degrading.PeakOriented`, which this model
parameterises):

    PeakOriented(k0, Fy = F_cr, alpha_s = (F_max - F_cr) / (u_max - u_cr) / k0, u_c = u_max,
                 alpha_c = (F_max - F_res) / (u_res - u_max) / k0, residual = F_res / F_cr,
                 gamma, c)

with u_cr = F_cr / k0 and u_res where the falling branch reaches F_res.

Default numbers (stated here as this model's own choice, not measurements): k0 = 122.6 kN/mm,
the infilled frame of test structure II (E&M 2007, Table III; docs/method.md section 6);
F_cr = 60 kN (u_cr = 0.49 mm), F_max = 85 kN at u_max = 2.5 mm (cracked stiffness 12.4 kN/mm,
about k0 / 10, the order the infill models above give after the first diagonal crack),
F_res = 40 kN at u_res = 10 mm (falling branch -6 kN/mm), energy capacity gamma = 40 F_cr u_cr.
"""

from __future__ import annotations

from hsio.errors import ConfigError
from hsio.specimens.base import Specimen
from hsio.specimens.degrading import PeakOriented


class CrackingInfill(Specimen):
    """Infilled-frame storey spring: trilinear strut-type envelope, peak-oriented cyclic deterioration."""

    kind = "cracking_infill"

    def __init__(self, k0: float = 122.6, F_cr: float = 60.0, F_max: float = 85.0, u_max: float = 2.5,
                 F_res: float = 40.0, u_res: float = 10.0, gamma: float = 40.0, c: float = 1.0):
        self.k0, self.F_cr, self.F_max, self.u_max = float(k0), float(F_cr), float(F_max), float(u_max)
        self.F_res, self.u_res, self.gamma, self.c = float(F_res), float(u_res), float(gamma), float(c)
        checks = [(self.k0 > 0, "k0 must be positive"),
                  (0 < self.F_cr < self.F_max, "need 0 < F_cr < F_max"),
                  (self.u_max > self.F_cr / self.k0 if self.k0 > 0 else False, "u_max must exceed F_cr / k0"),
                  (0 < self.F_res < self.F_cr, "need 0 < F_res < F_cr"),
                  (self.u_res > self.u_max, "u_res must exceed u_max")]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f"cracking_infill: {message}")
        u_cr = self.F_cr / self.k0
        alpha_s = (self.F_max - self.F_cr) / (self.u_max - u_cr) / self.k0
        if not alpha_s < 1:
            raise ConfigError("cracking_infill: the cracked branch must be softer than k0")
        alpha_c = (self.F_max - self.F_res) / (self.u_res - self.u_max) / self.k0
        self._core = PeakOriented(self.k0, self.F_cr, self.u_max, alpha_s, alpha_c, self.F_res / self.F_cr,
                                  self.gamma, self.c)

    @property
    def initial_stiffness(self) -> float:
        return self.k0

    @property
    def strength_factor(self) -> float:
        return self._core.strength_factor

    def backbone(self, u: float) -> float:
        """The virgin envelope at ``u`` (kN)."""
        return self._core.backbone(u)

    def trial(self, u: float, dt: float = 0.0) -> float:
        return self._core.trial(u, dt)

    def commit(self) -> None:
        self._core.commit()

    def revert_to_start(self) -> None:
        self._core.revert_to_start()
