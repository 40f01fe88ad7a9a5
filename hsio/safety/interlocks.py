"""Interlocks of the control loop: the error detectors of a lab controller, checked every
controller period (docs/safety.md section 3).

Per actuator, on each period's command and measurement:

* following error: |command - measured| (mm in displacement control, kN in force control) above
  ``following_error_mm`` / ``following_error_kN`` for longer than ``following_time_s``: the
  actuator stopped following (a stuck valve, a dead transducer, another client commanding);
* implausible measurement: a displacement or force that is not a finite number, or that jumps by
  more than ``jump_mm`` / ``jump_kN`` between two periods;
* warning bands: |displacement| beyond ``warning_fraction`` of the half stroke, |force| beyond
  that fraction of the capacity: recorded as a warning, once per entry into the band, no trip;
* specimen failure (optional, ``force_drop_fraction`` > 0): once |force| has peaked above
  ``force_drop_min_kN``, the envelope (the largest |force| over the last
  ``force_drop_window_s`` of lab time) falls below ``force_drop_fraction`` of the peak.

The lab time of a pause does not count (:meth:`InterlockMonitor.skip`): a window or a timer that
spanned it would judge the run by what it did before the pause alone.

What a resumed run must not forget goes into the record with each step (:meth:`InterlockMonitor.state`,
table ``interlocks``) and is restored by ``hsio resume`` (:meth:`InterlockMonitor.restore`): the
peak force per actuator, so a specimen that lost strength before the interruption is judged
against the peak it reached, not against a peak that starts again from zero. The windows and
timers (the force envelope, the following-error time) start again with the resumed session: a
drop is judged once a whole window of resumed samples lies below the fraction of that peak.

A trip raises :class:`~hsio.safety.status.InterlockTrip`; the loop then holds every actuator.
"""

from __future__ import annotations

import collections
import math

from hsio.interfaces import ControlMode
from hsio.safety.settings import SafetySettings
from hsio.safety.status import InterlockTrip


class _Channel:
    """The running state of one actuator's detectors."""

    def __init__(self, name: str, limits):
        self.name = name
        self.limits = limits
        self.previous: tuple[float, float] | None = None
        self.following_since: float | None = None
        self.in_band = {"displacement": False, "force": False}
        self.peak_force = 0.0
        self.window: collections.deque = collections.deque()  # (t, |F|), decreasing |F| (sliding maximum)
        self.window_start: float | None = None
        self.restored = False  # a peak taken over from the run being resumed: its window starts at the next sample


class InterlockMonitor:
    """Checks every controller period of a :class:`hsio.control_loop.ControlLoop`."""

    MAX_EVENTS = 10_000  # warnings kept before the oldest are dropped (a run keeps going)

    def __init__(self, actuators, settings: SafetySettings | None = None):
        self.settings = settings or SafetySettings()
        self.channels = [_Channel(a.name, a.limits) for a in actuators]
        self.events: collections.deque = collections.deque(maxlen=self.MAX_EVENTS)
        self.warnings = 0

    def take_events(self) -> list[dict]:
        out = []
        while self.events:
            out.append(self.events.popleft())
        return out

    def skip(self, seconds: float) -> None:
        """Lab time that passed while the run was paused (the actuators holding, nothing checked)
        does not count: the following-error timer and the force-drop window go on from where they
        stood when the pause began, as if the pause had not been."""
        if not seconds > 0:
            return
        for ch in self.channels:
            if ch.following_since is not None:
                ch.following_since += seconds
            if ch.window_start is not None:
                ch.window_start += seconds
            ch.window = collections.deque((t + seconds, f) for t, f in ch.window)

    def state(self) -> dict[str, float]:
        """The running state a resumed run takes over: ``peak_force_kN`` per actuator, keyed by
        actuator name (docs/safety.md section 8)."""
        return {ch.name: ch.peak_force for ch in self.channels}

    def restore(self, peaks: dict[str, float]) -> None:
        """Take over the peak force per actuator (:meth:`state`) of the run being resumed; the
        force-drop window starts with the first resumed sample."""
        for ch in self.channels:
            peak = peaks.get(ch.name)
            if peak is not None and math.isfinite(peak) and peak > ch.peak_force:
                ch.peak_force = float(peak)
                ch.window_start = None  # set by the first resumed sample
                ch.restored = True

    def _event(self, t: float, kind: str, name: str, message: str) -> None:
        self.events.append({"time_s": t, "kind": kind, "actuator": name, "message": message})

    def _trip(self, t: float, kind: str, ch: _Channel, message: str):
        text = f"interlock ({kind}) on actuator {ch.name!r} at t = {t:.4f} s of lab time: {message}"
        self._event(t, "trip", ch.name, text)
        raise InterlockTrip(text, kind, ch.name)

    def check(self, t: float, commands, feedback, modes) -> None:
        """One period: ``commands`` sent, ``feedback`` measured, ``modes`` per actuator."""
        s = self.settings
        for ch, c, fb, mode in zip(self.channels, commands, feedback, modes):
            d, f = fb.displacement_mm, fb.force_kN
            if not (math.isfinite(d) and math.isfinite(f)):
                self._trip(t, "not_finite", ch, f"measured displacement {d!r} mm, force {f!r} kN: not a finite number")
            if ch.previous is not None:
                dd, df = abs(d - ch.previous[0]), abs(f - ch.previous[1])
                if dd > s.jump_mm:
                    self._trip(t, "jump", ch, f"measured displacement jumped by {dd:.3f} mm in one controller period "
                                              f"(limit {s.jump_mm:g} mm): the transducer is not plausible")
                if df > s.jump_kN:
                    self._trip(t, "jump", ch, f"measured force jumped by {df:.3f} kN in one controller period "
                                              f"(limit {s.jump_kN:g} kN): the load cell is not plausible")
            ch.previous = (d, f)
            force_mode = mode is ControlMode.FORCE
            error = c - (f if force_mode else d)
            threshold = s.following_error_kN if force_mode else s.following_error_mm
            if abs(error) > threshold:
                if ch.following_since is None:
                    ch.following_since = t
                elif t - ch.following_since > s.following_time_s:
                    unit = "kN" if force_mode else "mm"
                    self._trip(t, "following", ch,
                               f"command - measured = {error:.3f} {unit} beyond {threshold:g} {unit} for "
                               f"{t - ch.following_since:.3f} s (limit {s.following_time_s:g} s): the actuator "
                               f"does not follow its command")
            else:
                ch.following_since = None
            self._bands(t, ch, d, f)
            if s.force_drop_fraction > 0:
                self._force_drop(t, ch, abs(f))

    def _bands(self, t: float, ch: _Channel, d: float, f: float) -> None:
        wf = self.settings.warning_fraction
        for what, value, limit, unit in (("displacement", d, ch.limits.half_stroke_mm, "mm"),
                                         ("force", f, ch.limits.force_kN, "kN")):
            inside = abs(value) > wf * limit
            if inside and not ch.in_band[what]:
                self.warnings += 1
                self._event(t, "warning", ch.name, f"{what} {value:.3f} {unit} beyond {wf:.0%} of the limit "
                                                   f"(+/-{limit:g} {unit})")
            ch.in_band[what] = inside

    def _force_drop(self, t: float, ch: _Channel, f: float) -> None:
        s = self.settings
        w = ch.window
        while w and w[-1][1] <= f:
            w.pop()
        w.append((t, f))
        while w and w[0][0] < t - s.force_drop_window_s:
            w.popleft()
        if f > ch.peak_force:
            ch.peak_force = f
            ch.window_start = t
            ch.restored = False
        elif ch.restored:
            ch.window_start, ch.restored = t, False
        if ch.peak_force < s.force_drop_min_kN or ch.window_start is None:
            return
        if t - ch.window_start >= s.force_drop_window_s and w[0][1] < s.force_drop_fraction * ch.peak_force:
            self._trip(t, "force_drop", ch,
                       f"force envelope {w[0][1]:.3f} kN over the last {s.force_drop_window_s:g} s is below "
                       f"{s.force_drop_fraction:.0%} of the peak {ch.peak_force:.3f} kN: the specimen failed")
