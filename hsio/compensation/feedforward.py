"""The adjusted command of docs/method.md section 4, eq. 2, for one actuator.

With the hockey stick of eq. 1 (threshold a, lag L = b d_max) the actuator ends a step short of
its command by L (|v| - a) sign(v). Sending d^a instead of d^c makes it land on d^c:

* ``form = "eq2"``: the paper's eq. 2, where v in the model is the adjusted command's own
  step velocity (d^a_i - d^a_{i-1}) / t_d:

      d^a_i = [d^c_i - L (d^a_{i-1} / t_d + sign(v) a)] / (1 - L / t_d)        if |v| > a

  It feeds d^a_{i-1} back with gain -r / (1 - r), r = L / t_d: it is stable only for r < 1/2
  (L < t_d / 2), e.g. structure I at TR = 40 (r = 0.1) but not at TR = 6.25 (r = 0.64).
* ``form = "lead"`` (default): the same steady-ramp solution written without the recursion,

      d^a_i = d^c_i + L (|v_i| - a) sign(v_i)                                   if |v_i| > a

  with v_i the command's velocity at the end of step i (backward quadratic through the last
  three commands, as the command generator uses). For a constant-velocity ramp both forms give
  the same d^a; this one stays stable at any test rate and is second-order accurate in t_d when
  the velocity changes.
"""

from __future__ import annotations

import math

from hsio.compensation.hockey_stick import last_velocity

FORMS = ("lead", "eq2")


class FeedForward:
    """Turns the integrator's commands d^c into adjusted commands d^a, one step at a time."""

    def __init__(self, t_d: float, a_mm_s: float = 0.0, lag_s: float = 0.0, form: str = "lead"):
        if not t_d > 0:
            raise ValueError(f"t_d must be positive, got {t_d!r}")
        if form not in FORMS:
            raise ValueError(f"compensation form must be one of {', '.join(FORMS)}, got {form!r}")
        self.t_d = float(t_d)
        self.form = form
        self.a = 0.0
        self.lag = 0.0
        self.set_parameters(a_mm_s, lag_s)
        self._c: list[float] = []  # last commands d^c (up to three)
        self.last_adjusted: float | None = None  # d^a_{i-1}
        self.velocity = 0.0  # v_i used for the last adjustment

    def set_parameters(self, a_mm_s: float, lag_s: float) -> None:
        if not (math.isfinite(a_mm_s) and a_mm_s >= 0):
            raise ValueError(f"threshold a must be zero or positive, got {a_mm_s!r}")
        if not (math.isfinite(lag_s) and lag_s >= 0):
            raise ValueError(f"lag b d_max must be zero or positive, got {lag_s!r}")
        if self.form == "eq2" and lag_s >= 0.5 * self.t_d:
            raise ValueError(f"eq. 2 is unstable for b d_max = {lag_s:.4g} s >= t_d / 2 = {0.5 * self.t_d:.4g} s; "
                             "use form = 'lead'")
        self.a = float(a_mm_s)
        self.lag = float(lag_s)

    def restart(self) -> None:
        """Forget the command history (the actuator was not in displacement control)."""
        self._c = []
        self.last_adjusted = None
        self.velocity = 0.0

    def command_velocity(self, d_c: float) -> float:
        """The velocity of the command stream ending at d_c (without recording it)."""
        return last_velocity([*self._c[-2:], d_c], self.t_d, 1 if self.form == "eq2" else 2)

    def adjust(self, d_c: float) -> float:
        """d^a_i for the command d^c_i (eq. 2); advances the step."""
        d_c = float(d_c)
        v = self.command_velocity(d_c)
        self._c = [*self._c[-2:], d_c]
        self.velocity = v
        if abs(v) <= self.a or self.lag == 0.0:
            d_a = d_c
        elif self.form == "lead":
            d_a = d_c + self.lag * math.copysign(abs(v) - self.a, v)
        else:
            previous = self.last_adjusted if self.last_adjusted is not None else d_c
            r = self.lag / self.t_d
            d_a = (d_c - self.lag * (previous / self.t_d + math.copysign(self.a, v))) / (1.0 - r)
        self.last_adjusted = d_a
        return d_a
