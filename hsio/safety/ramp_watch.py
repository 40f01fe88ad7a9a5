"""The watch over a ramp of the static preloads: the measured rod, every controller period
(docs/setups.md, docs/safety.md section 3).

Before a ramp moves anything its rod velocity is predicted, the force rate over the declared
K^EI of what each preload loads (:mod:`hsio.safety.preload_ramp`), and its stroke by the dry
run, F / K^EI. What the rod really does depends on the real stiffness: a specimen softer than
declared (cracked, a wrong K^EI, a load train more compliant than thought) turns the same force
rate into a faster rod and the same force into a longer stroke. While a ramp runs, every period,
each static actuator's measured displacement d is therefore held against its stroke, and its
measured velocity against its velocity limit, each less the run's margin (the dry run's,
docs/safety.md section 2):

    |d| <= (1 - stroke_margin) stroke / 2,      |v| <= (1 - velocity_margin) v_max,

v = (d(t) - d(t - W)) / W over the last W = :data:`VELOCITY_WINDOW_S` of lab time, judged once a
whole window is measured (the transducer's noise over one period alone would read as speed).
Beyond either the ramp is stopped
(:class:`hsio.safety.status.InterlockTrip`, kind ``preload_ramp``): the loop holds every actuator,
and the message names the actuator, the measured value, the allowed one, and the secant the rod
measured over the ramp so far, k = (F - F_0) / (d - d_0), beside the declared K^EI.
"""

from __future__ import annotations

import collections
import math

from hsio.safety.status import InterlockTrip

VELOCITY_WINDOW_S = 0.01  # lab time over which the rod's velocity is measured (its change over the window)


class RampWatch:
    """Watches the static actuators ``actuators[first:]`` through one ramp (``phase``:
    "ramp_in" or "ramp_off") of the preloads ``static`` (:class:`hsio.structures.StaticLoad`),
    from ``start`` (their measured (displacement mm, force kN) at lab time ``t_start``, when the
    ramp began); ``margins``: (stroke_margin, velocity_margin). Call it with each period's lab
    time and feedback of every actuator; it raises :class:`InterlockTrip` beyond a limit and
    keeps the peaks."""

    KIND = "preload_ramp"  # the InterlockTrip's kind

    def __init__(self, static, actuators, first: int, start, t_start: float, phase: str,
                 margins: tuple[float, float], period_s: float):
        self.static = list(static)
        self.first = first
        self.phase = phase
        self.names = [a.name for a in actuators[first:]]
        stroke_margin, velocity_margin = margins
        self.allowed_stroke = [(1.0 - stroke_margin) * a.limits.half_stroke_mm for a in actuators[first:]]
        self.allowed_velocity = [(1.0 - velocity_margin) * a.limits.velocity_mm_s for a in actuators[first:]]
        self.half_stroke = [a.limits.half_stroke_mm for a in actuators[first:]]
        self.velocity_limit = [a.limits.velocity_mm_s for a in actuators[first:]]
        self.margins = margins
        self.start = [(float(d), float(f)) for d, f in start]
        self.window = max(int(round(VELOCITY_WINDOW_S / period_s)), 1)
        self.history = [collections.deque([(float(t_start), d)], maxlen=self.window + 1) for d, _ in self.start]
        self.peak_speed = [0.0] * len(self.static)  # mm/s, measured
        self.peak_stroke = [abs(d) for d, _ in self.start]  # mm, |measured displacement|
        self.last = list(self.start)  # (displacement, force) of the last period
        self.last_time: float | None = None

    def __call__(self, t: float, feedback) -> None:
        self.last_time = t
        for j, fb in enumerate(feedback[self.first:]):
            d, f = fb.displacement_mm, fb.force_kN
            self.last[j] = (d, f)
            if not (math.isfinite(d) and math.isfinite(f)):
                continue  # the implausible-measurement interlock's to judge
            history = self.history[j]
            history.append((t, d))
            t0, d0 = history[0]
            span = t - t0
            # judged once a whole window is measured: over fewer periods the noise reads as speed
            speed = abs(d - d0) / span if len(history) > self.window and span > 0 else 0.0
            self.peak_speed[j] = max(self.peak_speed[j], speed)
            self.peak_stroke[j] = max(self.peak_stroke[j], abs(d))
            if abs(d) > self.allowed_stroke[j]:
                self._trip(t, j, f"measured rod displacement {d:.3f} mm is beyond the stroke less the margin "
                                 f"({self.allowed_stroke[j]:.3f} mm = {1 - self.margins[0]:.0%} of "
                                 f"+/-{self.half_stroke[j]:g} mm)", stroke=True)
            if speed > self.allowed_velocity[j]:
                self._trip(t, j, f"measured rod speed {speed:.1f} mm/s (over the last {span * 1e3:.1f} ms) is beyond "
                                 f"the velocity limit less the margin ({self.allowed_velocity[j]:.1f} mm/s = "
                                 f"{1 - self.margins[1]:.0%} of {self.velocity_limit[j]:g} mm/s)")

    def secant(self, j: int) -> float | None:
        """(F - F_0) / (d - d_0) of static actuator ``j`` over the ramp so far (None: the rod has not moved)."""
        (d0, f0), (d, f) = self.start[j], self.last[j]
        return (f - f0) / (d - d0) if abs(d - d0) > 1e-9 else None

    def cause(self, j: int, stroke: bool = False) -> str:
        """What most likely moved the rod beyond what the check before the ramp predicted
        (``stroke``: the stroke tripped, else the speed)."""
        declared = self.static[j].K_EI
        k = self.secant(j)
        if k is None:
            return f"the rod stood there when the ramp began (declared K^EI = {declared:g} kN/mm)"
        if k <= 0:
            return (f"likely cause: the rod moved {self.last[j][0] - self.start[j][0]:+.3f} mm while the measured force "
                    f"did not follow it as a spring's would (secant {k:.4g} kN/mm over the ramp so far, declared K^EI = {declared:g} "
                    f"kN/mm): nothing holds the rod (a failed specimen, a slipped load train) or the load cell does "
                    f"not read")
        if k < declared:
            return (f"likely cause: what it loads is softer than its declared K^EI = {declared:g} kN/mm: measured "
                    f"secant {k:.4g} kN/mm over the ramp so far (a cracked specimen, a wrong K^EI, a load train more "
                    f"compliant than thought)")
        if stroke:  # the rod is no farther than the force asks of K^EI: the preload asks more stroke than allowed
            load = self.static[j]
            return (f"measured secant {k:.4g} kN/mm over the ramp so far, not below the declared K^EI = {declared:g} "
                    f"kN/mm: the rod is where the force puts it; the preload of {load.force_kN:g} kN over K^EI asks "
                    f"{abs(load.force_kN) / declared:.3f} mm, more than the stroke less the margin allows (the dry "
                    f"run refuses such a preload)")
        return (f"measured secant {k:.4g} kN/mm over the ramp so far, not below the declared K^EI = {declared:g} kN/mm: "
                f"the rod moves faster than the force rate asks of that stiffness (check the force loop and the load "
                f"cell)")

    def _trip(self, t: float, j: int, what: str, stroke: bool = False) -> None:
        load = self.static[j]
        d, f = self.last[j]
        text = (f"interlock ({self.KIND}) on actuator {self.names[j]!r} at t = {t:.4f} s of lab time: the "
                f"{self.phase.replace('_', ' ')} of static preload {load.name!r} was stopped at {f:.4g} kN "
                f"measured: {what}; {self.cause(j, stroke)}")
        raise InterlockTrip(text, self.KIND, self.names[j])

    def peaks(self) -> dict[str, dict[str, float]]:
        """Per preload: the peak measured rod speed (mm/s) and |displacement| (mm) of the ramp."""
        return {load.name: {"peak_speed_mm_s": float(v), "peak_stroke_mm": float(s)}
                for load, v, s in zip(self.static, self.peak_speed, self.peak_stroke)}
