"""The ramps of the static preloads and what they move (docs/setups.md, docs/safety.md section 2).

A static actuator ramps its preload in force control, one loop step t_d at a time: over the
longest ``ramp_s`` of the preloads, ``steps = max(ceil(ramp_s / t_d), 1)`` targets
F_k = F_0 + (F - F_0) k / steps, then F held. The command generator (docs/method.md section 1)
runs between them as between any targets, so the force rate the actuator is sent is that of the
predictor-corrector over those targets. What the actuator loads answers with its stiffness: the
rod moves at that force rate over the stiffness K^EI of what it loads (the declared ``K_EI``,
else the specimen model's initial stiffness), and a force rate beyond K^EI times the velocity
limit asks the servo-valve for more flow than it has (the actuator would then lag its force
command, or an actuator without a flow limit move at a speed nobody checked). Both the dry run
and the ramp itself check it, before anything moves; while the ramp runs, the measured rod is
watched (:mod:`hsio.safety.ramp_watch`), for what loads it may be softer than declared.
"""

from __future__ import annotations

import math

import numpy as np

from hsio.errors import LimitError
from hsio.structures import MAX_RAMP_S

SETTLE_TARGETS = 3  # targets held after the ramp's end in the prediction (its last segment eases onto them)


def ramp_steps(ramp_s: float, t_d: float) -> int:
    """Loop steps of a ramp of ``ramp_s`` seconds of lab time, one target per t_d (at least one)."""
    return max(int(math.ceil(ramp_s / t_d)), 1)


def ramp_targets(start: np.ndarray, end: np.ndarray, steps: int) -> np.ndarray:
    """The per-step force targets of a ramp (steps x preloads): start + (end - start) k / steps for
    k = 1..steps, the last exactly ``end``."""
    start, end = np.atleast_1d(np.asarray(start, dtype=float)), np.atleast_1d(np.asarray(end, dtype=float))
    k = np.arange(1, steps + 1)[:, None] / steps
    out = start + (end - start) * k
    out[-1] = end
    return out


def ramp_velocity(start, end, stiffness, ramp_s: float, t_d: float, period: float,
                  hold_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """Per preload, the peak |force rate| (kN/s) the command generator sends over the ramp from
    ``start`` to ``end`` (kN) and the rod velocity it asks, that rate over ``stiffness`` (kN/mm):
    (peak force rate, peak velocity mm/s)."""
    from hsio.safety.dry_run import peak_command_velocity

    start, end = np.atleast_1d(np.asarray(start, dtype=float)), np.atleast_1d(np.asarray(end, dtype=float))
    targets = ramp_targets(start, end, ramp_steps(ramp_s, t_d))
    targets = np.vstack([targets, np.repeat(targets[-1:], SETTLE_TARGETS, axis=0)])
    rate = np.array([peak_command_velocity(targets[:, j], t_d, period, hold_fraction, float(start[j]))
                     for j in range(len(start))])
    return rate, rate / np.abs(np.asarray(stiffness, dtype=float))


def check_ramp(static, start, end, velocity_limits, t_d: float, period: float, hold_fraction: float,
               phase: str, share: str = "") -> None:
    """Refuse (LimitError, before anything moves) a ramp of the ``static`` preloads
    (:class:`hsio.structures.StaticLoad`) from ``start`` to ``end`` whose rod velocity, the force
    rate over the K^EI of what each loads, exceeds its actuator's velocity limit (``velocity_limits``, mm/s),
    naming the preload, the velocity, the limit and the ``ramp_s`` that would keep within it.
    ``share``: what the limits are of the actuators' own (e.g. "95 % of the actuator's", the run's
    velocity margin taken off), for the message."""
    ramp_s = max(load.ramp_s for load in static)
    stiffness = [load.K_EI for load in static]
    rate, velocity = ramp_velocity(start, end, stiffness, ramp_s, t_d, period, hold_fraction)
    for j, (load, k, r, v, limit) in enumerate(zip(static, stiffness, rate, velocity, velocity_limits)):
        if limit is not None and v > limit:
            within = within_limit(start[j], end[j], k, limit, ramp_s, t_d, period, hold_fraction)
            raise LimitError(f"static preload {load.name!r} on actuator {load.actuator!r}: the {phase} over "
                             f"{ramp_s:g} s moves the rod at {v:.1f} mm/s ({r:.1f} kN/s over {k:g} kN/mm), "
                             f"beyond the velocity limit ({limit:g} mm/s{', ' + share + ' limit' if share else ''}); "
                             f"not sent ({within})")


def within_limit(start: float, end: float, stiffness: float, limit: float, ramp_s: float, t_d: float,
                 period: float, hold_fraction: float) -> str:
    """The shortest ``ramp_s`` (a whole number of loop steps) whose ramp keeps the rod within
    ``limit``, as advice; the rod velocity falls as 1/steps, so the search from the proportional
    guess is short."""
    steps = ramp_steps(ramp_s, t_d)
    _, (v,) = ramp_velocity([start], [end], [stiffness], ramp_s, t_d, period, hold_fraction)
    n = max(int(math.ceil(steps * v / limit)), steps + 1)
    for _ in range(8):
        if n * t_d > MAX_RAMP_S:
            break
        _, (v,) = ramp_velocity([start], [end], [stiffness], n * t_d, t_d, period, hold_fraction)
        if v <= limit:
            return f"a ramp_s of {n * t_d:.10g} s keeps within it"  # as many digits as it has: not rounded down
        n += max(n // 8, 1)
    return f"no ramp_s up to {MAX_RAMP_S:g} s keeps within it at t_d = {t_d:g} s"
