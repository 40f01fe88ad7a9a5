"""A late displacement channel or a delay in the loop: told apart by the force.

From the command and the measured displacement alone the two are the same model. The loop
(lag, dead band, flow limit, servo mode, backlash) is time-invariant and starts at rest, so
delaying its input delays its output: Loop[c(. - tau)](t) = Loop[c](t - tau). A transport
delay tau inside the loop and a displacement channel recorded tau late therefore give the same
measured displacement, sample for sample (tests/test_diagnose_timing.py checks it on the
emulator).

They differ in when the specimen moves. With a delay in the loop the rod, the specimen and the
load cell move with the measured displacement. With a late channel the specimen moves tau
before its displacement is recorded, so the force turns tau before the recorded displacement
turns. A specimen whose force follows the direction of its motion (elastic or hysteretic, rate
independent: the force grows while it is pushed and falls once it turns back) has
dF du >= 0 everywhere; read against a displacement shifted by s it shows sign violations near
each reversal unless s is its true lead. The share of violations,

    V(s) = sum max(0, -dF(t) du(t + s)) / sum |dF(t) du(t + s)|

(increments over about 2 ms, summed near the reversals of the displacement), is smallest at
s = 0 for a delay in the loop and at s = tau for a late channel. The verdict compares V(0)
with V(tau), tau being the fitted skew; where both are nearly 0 (a coarse load cell whose steps
never go against the motion) there is nothing to compare and the question stays open. A damper or another rate-dependent specimen, whose
force leads its displacement by itself, violates at both and leaves the question open; so do
records without force or with too few reversals. The channel that settles it then is the
displacement the controller closes its loop on (its feedback), recorded beside the measured
one: with a late channel the feedback leads the record by tau, with a delay it does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from hsio.diagnose.record import ActuatorRecord

SKEW = "channel_skew"
DELAY = "transport_delay"
OPEN = "undecided"
LATE_RATIO = 1.2  # V(0) / V(tau) at least this: the force leads, the channel is late
IN_TIME_RATIO = 1.0 / 1.1  # at most this: the force moves with the displacement, the delay is in the loop
FOLLOWS = 0.15  # the force follows the motion when the better of V(0), V(tau) is below this share
MIN_SHARE = 0.002  # the worse of V(0), V(tau) below this share: too few violations either way to tell
MIN_REVERSALS = 6
INCREMENT_S = 0.002
WINDOW_S = 0.025  # samples this close to a reversal count
SMOOTH_HZ = 20.0  # reversals are found on the displacement low-passed (zero phase) at this frequency
EXTRA_CHANNEL = ("the displacement the controller closes its loop on (its feedback), recorded beside the "
                 "measured one: it leads a late channel by the skew and moves with the measurement under a delay")


@dataclass(frozen=True)
class Timing:
    verdict: str  # channel_skew, transport_delay or undecided
    tau_s: float  # the fitted skew (or delay) tested
    violations_at_zero: float  # V(0)
    violations_at_tau: float  # V(tau)
    reversals: int
    reason: str

    @property
    def ratio(self) -> float:
        """V(0) / V(tau): inf when only V(tau) is 0, nan when both are (nothing to compare)."""
        v0, vt = self.violations_at_zero, self.violations_at_tau
        if vt > 0:
            return v0 / vt
        return float("inf") if v0 > 0 else float("nan")

    def to_json(self) -> dict:
        """The verdict with its evidence; a count or ratio that does not exist (no force, nothing
        to compare) is null, so that the output is strict JSON."""
        def number(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {"verdict": self.verdict, "tau_s": number(self.tau_s), "violations_at_zero": number(self.violations_at_zero),
                "violations_at_tau": number(self.violations_at_tau), "ratio": number(self.ratio),
                "reversals": self.reversals, "reason": self.reason, "extra_channel": EXTRA_CHANNEL}


def reversal_mask(u: np.ndarray, dt: float, min_excursion_mm: float) -> tuple[np.ndarray, int]:
    """Samples within WINDOW_S of a reversal of the displacement that travelled at least
    ``min_excursion_mm`` since the previous one, and how many such reversals."""
    wn = min(0.9, 2.0 * SMOOTH_HZ * dt)
    b, a = signal.butter(2, wn)
    us = signal.filtfilt(b, a, u) if u.size > 15 else u
    v = np.diff(us)
    turns = np.flatnonzero(np.sign(v[1:]) * np.sign(v[:-1]) < 0) + 1
    mask = np.zeros(u.size, bool)
    w = max(1, int(round(WINDOW_S / dt)))
    last, count = us[0], 0
    for i in turns.tolist():
        if abs(us[i] - last) >= min_excursion_mm:
            mask[max(0, i - w): i + w] = True
            last = us[i]
            count += 1
    return mask, count


def violations(force: np.ndarray, u: np.ndarray, mask: np.ndarray, lead_s: float, dt: float) -> float:
    """V(lead): the share of force increments against the direction of the displacement
    increments ``lead_s`` later (linear interpolation between whole samples); nan where the
    force does not change near the reversals."""
    h = max(1, int(round(INCREMENT_S / dt)))
    df, du, near = force[h:] - force[:-h], u[h:] - u[:-h], mask[h:]

    def at(s: int) -> float:
        n = du.size - abs(s)
        a, b, m = (df[:n], du[s:], near[s:]) if s >= 0 else (df[-s:], du[:n], near[:n])
        ab = (a * b)[m]
        total = float(np.abs(ab).sum())
        return float(np.maximum(0.0, -ab).sum()) / total if total > 0 else float("nan")

    x = lead_s / dt
    s = int(np.floor(x))
    f = x - s
    return (1.0 - f) * at(s) + f * at(s + 1) if f > 0 else at(s)


def tell(record: ActuatorRecord, tau_s: float, floor_mm: float) -> Timing:
    """Is the measured displacement ``tau_s`` late (channel_skew) or in time with the force
    (transport_delay)? ``floor_mm`` (the sensor floor) sets the smallest reversal counted."""
    if record.force_kN is None or np.ptp(record.force_kN) == 0.0:
        return Timing(OPEN, tau_s, float("nan"), float("nan"), 0, "the record has no force")
    if tau_s < 1.5 * record.dt:
        return Timing(OPEN, tau_s, float("nan"), float("nan"), 0, "the fitted skew is shorter than the sampling")
    u = record.measured_mm
    mask, count = reversal_mask(u, record.dt, max(20.0 * floor_mm, 0.02 * float(np.ptp(u))))
    if count < MIN_REVERSALS:
        return Timing(OPEN, tau_s, float("nan"), float("nan"), count, f"only {count} reversals of the displacement")
    v0 = violations(record.force_kN, u, mask, 0.0, record.dt)
    vt = violations(record.force_kN, u, mask, tau_s, record.dt)
    t = Timing(OPEN, tau_s, v0, vt, count, "")
    lead = f"{1e3 * tau_s:.2f} ms"
    if not (np.isfinite(v0) and np.isfinite(vt)):
        return Timing(OPEN, tau_s, v0, vt, count, "the force does not change near the reversals of the displacement "
                      "(a load cell coarser than the force's swing there), so its timing cannot tell")
    if min(v0, vt) > FOLLOWS:
        reason = (f"the force does not follow the direction of the motion ({100 * min(v0, vt):.0f} % of its changes "
                  "go against it: a damper or a rate-dependent specimen), so its timing cannot tell")
        return Timing(OPEN, tau_s, v0, vt, count, reason)
    if max(v0, vt) < MIN_SHARE:  # e.g. a coarse load cell whose steps never go against the motion
        return Timing(OPEN, tau_s, v0, vt, count,
                      f"the force's timing is too close to tell: almost none of its changes go against the motion "
                      f"({100 * v0:.2f} % against the measured motion, {100 * vt:.2f} % against it read {lead} "
                      f"earlier; at least {100 * MIN_SHARE:.1f} % are needed on one side)")
    if t.ratio >= LATE_RATIO:
        return Timing(SKEW, tau_s, v0, vt, count,
                      f"the force turns {lead} before the measured displacement does ({100 * v0:.2f} % of the force changes "
                      f"go against the measured motion, {100 * vt:.2f} % against it read {lead} earlier): "
                      "the specimen moves before its displacement is recorded")
    if t.ratio <= IN_TIME_RATIO:
        return Timing(DELAY, tau_s, v0, vt, count,
                      f"the force turns with the measured displacement ({100 * v0:.2f} % of the force changes go against "
                      f"the measured motion, {100 * vt:.2f} % against it read {lead} earlier): the delay is in the loop")
    return Timing(OPEN, tau_s, v0, vt, count,
                  f"the force's timing is too close to tell ({100 * v0:.2f} % against the measured motion, "
                  f"{100 * vt:.2f} % against it read {lead} earlier)")
