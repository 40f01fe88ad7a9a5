"""The predictor-corrector command generator: continuity, targets reached, slow and hold."""

import numpy as np
import pytest

from hsio.command import Phase, PredictorCorrector

PERIOD = 1 / 1024


def run_steps(gen, targets):
    """Feed one target per step; return commands and the indices where each step ended."""
    commands, ends = [], []
    for d in targets:
        gen.new_target(d)
        while True:
            commands.append(gen.next_sample())
            if gen.reached:
                ends.append(len(commands) - 1)
                assert commands[-1] == pytest.approx(d)
                break
    return np.array(commands), ends


def test_commands_and_velocity_are_continuous_across_step_boundaries():
    t_d = 0.1
    steps = np.arange(60) * 0.01
    targets = 20 * np.sin(2 * np.pi * 1.3 * steps) + 5 * np.sin(2 * np.pi * 3.1 * steps)
    gen = PredictorCorrector(t_d, PERIOD)
    c, ends = run_steps(gen, targets)
    v = np.diff(c) / PERIOD
    dv = np.abs(np.diff(v))
    at_boundaries = dv[np.array(ends[2:-1]) - 1]
    typical = np.median(dv)
    # No jump at boundaries: velocity changes there are like those inside a step.
    assert at_boundaries.max() < 5 * np.percentile(dv, 99)
    assert at_boundaries.max() < 50 * typical + 1e-9
    # Each step lasts t_d in lockstep.
    assert np.all(np.diff(ends) == round(t_d / PERIOD))


def test_ramp_hold_ends_at_rest_and_dwells():
    gen = PredictorCorrector(0.1, PERIOD, hold_fraction=0.5)
    c, ends = run_steps(gen, [1.0, 3.0, 2.0])
    c = np.concatenate([[0.0], c])
    v = np.diff(c) / PERIOD
    n = round(0.1 / PERIOD)
    dwell = n // 2
    start = 0
    for e in ends:
        e += 1
        assert np.all(c[e - dwell: e + 1] == c[e])  # dwelling on the target
        moving = v[start: e - dwell]
        peak = np.max(np.abs(moving))
        assert abs(moving[0]) < 0.15 * peak and abs(moving[-1]) < 0.15 * peak  # starts and stops at rest
        start = e


def test_late_target_extrapolates_then_slows_then_holds():
    t_d = 0.1
    gen = PredictorCorrector(t_d, PERIOD)
    run_steps(gen, [0.0, 1.0, 2.0, 3.0])
    seen = []
    c = []
    for _ in range(round(3 * t_d / PERIOD)):
        c.append(gen.next_sample())
        seen.append(gen.phase)
    assert seen[0] is Phase.EXTRAPOLATE
    assert Phase.SLOW in seen
    assert seen[-1] is Phase.HOLD
    c = np.array(c)
    v = np.diff(c) / PERIOD
    assert abs(v[0]) > 5.0  # still moving at about 10 mm/s when the integrator is late
    assert np.all(np.diff(c) >= -1e-12)  # keeps going the same way, no reversal
    assert abs(v[-1]) < 1e-6 and np.ptp(c[-50:]) == 0.0  # holding still
    assert np.max(np.abs(np.diff(v))) < 0.05 * abs(v[0])  # slowing down without a jolt
    # The late target is approached smoothly over a whole step, and counted.
    gen.new_target(c[-1] + 0.5)
    nxt = [gen.next_sample() for _ in range(round(t_d / PERIOD))]
    assert gen.reached and nxt[-1] == pytest.approx(c[-1] + 0.5)
    assert abs(nxt[0] - c[-1]) < 0.01
    assert gen.late_steps == 1


def test_arguments_are_checked():
    with pytest.raises(ValueError):
        PredictorCorrector(0.0, PERIOD)
    with pytest.raises(ValueError):
        PredictorCorrector(0.1, PERIOD, hold_fraction=1.0)


def test_late_target_is_counted_with_ramp_hold_too():
    gen = PredictorCorrector(0.1, PERIOD, hold_fraction=0.5)
    run_steps(gen, [0.0, 1.0])
    for _ in range(round(3 * 0.1 / PERIOD)):  # the integrator is three steps late
        gen.next_sample()
    assert gen.phase is Phase.HOLD
    gen.new_target(2.0)
    assert gen.late_steps == 1
    on_time = PredictorCorrector(0.1, PERIOD, hold_fraction=0.5)
    run_steps(on_time, [0.0, 1.0, 2.0, 3.0])
    assert on_time.late_steps == 0


def test_a_common_segment_length_keeps_generators_in_step():
    """Two generators, one fresh and one that extrapolated for a while: told the same length,
    they land on their targets on the same period."""
    a = PredictorCorrector(0.1, PERIOD)
    b = PredictorCorrector(0.1, PERIOD)
    run_steps(a, [1.0, 2.0])
    for _ in range(20):
        a.next_sample()
    assert a.planned_samples() != b.planned_samples()
    n = max(a.planned_samples(), b.planned_samples())
    a.new_target(3.0, samples=n)
    b.new_target(3.0, samples=n)
    for _ in range(n):
        a.next_sample()
        b.next_sample()
    assert a.reached and b.reached
