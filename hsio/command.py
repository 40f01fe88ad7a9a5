"""Command generation at the controller rate: the predictor-corrector of docs/method.md section 1.

Between two integration steps the actuator must keep moving smoothly. For each actuator, one
:class:`PredictorCorrector` turns the sequence of targets d_i (one per integration step, every
t_d = TR dt seconds) into one command per controller period:

* INTERPOLATE: when a new target arrives, a cubic Hermite segment runs from the present command
  and its velocity to the target, reaching it at the end of the step with the velocity of the
  quadratic through the last three targets. Command and velocity are continuous.
* EXTRAPOLATE: after the target is reached and while the integrator computes, the command
  follows that quadratic (polynomial extrapolation of the last targets).
* SLOW: if no target has come after ``slow_after`` t_d, the command velocity decays
  exponentially (time constant ``slow_tau`` t_d): the test runs slower than asked, smoothly.
* HOLD: once the velocity has died out (or ``hold_after`` t_d has passed) the command stays put.

A target that arrives while slow or holding is approached over a whole t_d.

Ramp-hold (``hold_fraction`` h > 0, one of the remedies of docs/method.md section 2): the Hermite
segment ends at rest after (1 - h) t_d, the command dwells on the target for h t_d so that the
actuator settles before the measurement, and then holds there until the next target.
"""

from __future__ import annotations

import enum
import math


class Phase(enum.Enum):
    INTERPOLATE = "interpolate"
    DWELL = "dwell"
    EXTRAPOLATE = "extrapolate"
    SLOW = "slow"
    HOLD = "hold"



def step_samples(t_d: float, period: float, hold_fraction: float = 0.0) -> tuple[int, int]:
    """Controller periods of one integration step (at least one) and of its dwell at the target."""
    per_step = max(int(round(t_d / period)), 1)
    return per_step, int(round(hold_fraction * per_step))


class PredictorCorrector:
    """Controller-rate command generator for one actuator.

    ``t_d`` is the duration of one integration step in the lab (TR dt), ``period`` the
    controller period. Call :meth:`new_target` once per integration step and :meth:`next_sample`
    once per period; :attr:`reached` turns true on the sample that lands on the target.
    """

    def __init__(self, t_d: float, period: float, initial: float = 0.0,
                 slow_after: float = 0.5, slow_tau: float = 0.25, hold_after: float = 2.0,
                 hold_fraction: float = 0.0):
        if not t_d > 0 or not period > 0:
            raise ValueError(f"t_d and period must be positive, got {t_d!r}, {period!r}")
        self.t_d = float(t_d)
        self.period = float(period)
        if not 0.0 <= hold_fraction < 1.0:
            raise ValueError(f"hold_fraction must be in [0, 1), got {hold_fraction!r}")
        self.samples_per_step, self.dwell_samples = step_samples(self.t_d, self.period, hold_fraction)
        self.slow_after = slow_after
        self.slow_decay = math.exp(-self.period / (slow_tau * self.t_d))
        self.hold_after = hold_after
        self.history = [float(initial)] * 3  # d_{i-2}, d_{i-1}, d_i
        self.command = float(initial)
        self.velocity = 0.0
        self.phase = Phase.HOLD
        self.reached = False
        self.late_steps = 0
        self._started = False
        self._k = 0  # samples since the present segment started
        self._waited = 0  # samples since the last target was reached (the integrator computing)
        self._n = 0  # length of the interpolation segment, in samples
        self._hermite: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    # -- the quadratic through the last three targets, in step units s = t / t_d -----------
    def _extrapolation(self, s: float) -> tuple[float, float]:
        d2, d1, d0 = self.history
        slope = 0.5 * (3.0 * d0 - 4.0 * d1 + d2)
        curve = 0.5 * (d0 - 2.0 * d1 + d2)
        return d0 + s * slope + s * s * curve, (slope + 2.0 * s * curve) / self.t_d

    def planned_samples(self) -> int:
        """How many periods a target arriving now would be interpolated over."""
        if self.dwell_samples:
            # Ramp-hold: the integrator computes while the actuator dwells; the ramp keeps its length.
            return max(self.samples_per_step - self.dwell_samples, 1)
        if self.phase in (Phase.SLOW, Phase.HOLD):
            return self.samples_per_step
        return max(self.samples_per_step - self._k, self.samples_per_step // 2, 1)

    def new_target(self, target: float, samples: int | None = None) -> None:
        """Start moving to ``target``: it is reached at the end of the step, after
        :meth:`planned_samples` periods, or ``samples`` when several generators keep step."""
        target = float(target)
        if self._started and self._waited > self.slow_after * self.samples_per_step:
            self.late_steps += 1
        n = max(int(samples if samples is not None else self.planned_samples()), 1)
        self.history = [self.history[1], self.history[2], target]
        _, v_end = self._extrapolation(0.0)
        if self.dwell_samples:
            v_end = 0.0
        self._hermite = (self.command, self.velocity, target, v_end)
        self._n = n
        self._k = 0
        self._waited = 0
        self.phase = Phase.INTERPOLATE
        self.reached = False
        self._started = True

    def next_sample(self) -> float:
        """Advance one controller period and return the command for it."""
        self._k += 1
        self.reached = False
        if self.phase in (Phase.EXTRAPOLATE, Phase.SLOW, Phase.HOLD):
            self._waited += 1
        if self.phase is Phase.INTERPOLATE:
            self.command, self.velocity = self._hermite_at(self._k)
            if self._k >= self._n:
                self.command = self.history[2]
                self._k = 0
                if self.dwell_samples:
                    self.velocity = 0.0
                    self.phase = Phase.DWELL
                else:
                    self.reached = True
                    self.phase = Phase.EXTRAPOLATE
        elif self.phase is Phase.DWELL:
            if self._k >= self.dwell_samples:
                self.reached = True
                self.phase = Phase.HOLD
        elif self.phase is Phase.EXTRAPOLATE:
            waited = self._k / self.samples_per_step
            if waited <= self.slow_after:
                self.command, self.velocity = self._extrapolation(waited)
            else:
                self.phase = Phase.SLOW
                self._slow()
        elif self.phase is Phase.SLOW:
            self._slow()
        return self.command

    def _slow(self) -> None:
        self.velocity *= self.slow_decay
        self.command += self.velocity * self.period
        waited = self._k / self.samples_per_step
        if abs(self.velocity) * self.t_d < 1e-9 or waited >= self.hold_after:
            self.velocity = 0.0
            self.phase = Phase.HOLD

    def _hermite_at(self, k: int) -> tuple[float, float]:
        """Cubic Hermite from (c0, v0) to (c1, v1) over n samples, at sample k."""
        c0, v0, c1, v1 = self._hermite
        T = self._n * self.period
        s = k / self._n
        s2, s3 = s * s, s * s * s
        # h00 c0 + h01 c1 with h00 = 1 - h01, written from c0: a segment between equal commands at
        # rest stays exactly on them (a preload held at its actuator's capacity is not 1 ulp beyond it)
        pos = c0 + (-2 * s3 + 3 * s2) * (c1 - c0) + (s3 - 2 * s2 + s) * T * v0 + (s3 - s2) * T * v1
        vel = ((6 * s2 - 6 * s) * c0 + (3 * s2 - 4 * s + 1) * T * v0 + (-6 * s2 + 6 * s) * c1 + (3 * s2 - 2 * s) * T * v1) / T
        return pos, vel
