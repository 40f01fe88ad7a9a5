"""The predictor-corrector (E&M 2007, Figure 2; docs/method.md) on targets that lie on a quadratic in time:
the Hermite segments and the extrapolation both reproduce the quadratic exactly, and a late
integrator makes the command slow down exponentially, then hold."""

import math

import numpy as np
import pytest

from hsio.command import Phase, PredictorCorrector

PERIOD = 1 / 1024
T_D = 0.0625  # 64 controller periods per step
N = 64


def q(s):
    """A quadratic path in step units s = t / t_d (mm)."""
    return 2.0 + 3.0 * s - 0.7 * s * s


def dq(s):
    """Its velocity in mm/s."""
    return (3.0 - 1.4 * s) / T_D


def feed(gen, steps):
    """Targets q(1) ... q(steps), one step each; every command with its time in step units."""
    s, c, v = [], [], []
    for i in range(1, steps + 1):
        gen.new_target(q(i))
        for k in range(1, N + 1):
            c.append(gen.next_sample())
            v.append(gen.velocity)
            s.append(i - 1 + k / N)
            if k < N:
                assert not gen.reached
        assert gen.reached and gen.phase is Phase.EXTRAPOLATE
    return np.array(s), np.array(c), np.array(v)


def test_interpolation_follows_a_quadratic_once_three_targets_are_known():
    gen = PredictorCorrector(T_D, PERIOD, initial=q(0))
    s, c, v = feed(gen, 6)
    assert c[N - 1] == q(1) and c[-1] == q(6)
    later = s > 2.0  # from the third step on: the start and end velocities are the quadratic's
    assert np.max(np.abs(c[later] - q(s[later]))) < 1e-12
    assert np.max(np.abs(v[later] - dq(s[later]))) < 1e-9
    # at the end of each interpolation the velocity is the slope of the quadratic through the last three targets
    for i in range(2, 7):
        assert v[i * N - 1] == pytest.approx(dq(i), rel=1e-12)


def test_extrapolation_continues_the_quadratic_through_the_last_three_targets():
    gen = PredictorCorrector(T_D, PERIOD, initial=q(0))
    feed(gen, 3)
    extrapolated = []
    for k in range(1, N // 2 + 1):  # up to slow_after = 0.5 t_d
        extrapolated.append((gen.next_sample(), gen.velocity, gen.phase))
        assert extrapolated[-1][2] is Phase.EXTRAPOLATE
    c = np.array([e[0] for e in extrapolated])
    v = np.array([e[1] for e in extrapolated])
    s = 3 + np.arange(1, N // 2 + 1) / N
    assert np.max(np.abs(c - q(s))) < 1e-12
    assert np.max(np.abs(v - dq(s))) < 1e-9
    # a target arriving now is approached from the extrapolated command, without a jump
    gen.new_target(q(4))
    first = gen.next_sample()
    assert abs(first - c[-1]) < 1.5 * abs(dq(3.5)) * PERIOD


def test_a_straight_line_is_followed_exactly_from_the_second_step():
    gen = PredictorCorrector(T_D, PERIOD, initial=0.0)
    commands = []
    for i in range(1, 5):
        gen.new_target(1.5 * i)
        for _ in range(N):
            commands.append(gen.next_sample())
    s = np.arange(1, 4 * N + 1) / N
    assert np.max(np.abs(np.array(commands)[s > 2.0] - 1.5 * s[s > 2.0])) < 1e-12


def test_a_late_integrator_slows_the_command_exponentially_then_holds():
    tau = 0.25
    gen = PredictorCorrector(T_D, PERIOD, initial=q(0), slow_tau=tau)
    feed(gen, 3)
    phases, c, v = [], [], []
    for _ in range(3 * N):
        c.append(gen.next_sample())
        v.append(gen.velocity)
        phases.append(gen.phase)
    phases = np.array([p.value for p in phases])
    c, v = np.array(c), np.array(v)
    slow = np.flatnonzero(phases == Phase.SLOW.value)
    assert slow[0] == N // 2  # just after slow_after = 0.5 t_d of extrapolation
    # the velocity decays with time constant tau t_d, and the command integrates it
    ratios = v[slow[1:]] / v[slow[:-1]]
    assert np.allclose(ratios, math.exp(-PERIOD / (tau * T_D)), rtol=1e-12)
    assert np.allclose(np.diff(c[slow[0] - 1: slow[-1] + 1]), v[slow[0]: slow[-1] + 1] * PERIOD, rtol=0, atol=1e-13)
    assert v[slow[0]] == pytest.approx(v[slow[0] - 1] * math.exp(-PERIOD / (tau * T_D)), rel=1e-12)
    # hold after hold_after = 2 t_d of waiting: velocity zero, command fixed
    hold = np.flatnonzero(phases == Phase.HOLD.value)
    assert hold[0] == 2 * N - 1 and np.all(np.diff(hold) == 1)
    assert np.all(v[hold] == 0.0) and np.ptp(c[hold]) == 0.0
    assert gen.late_steps == 0
    gen.new_target(q(4))
    assert gen.late_steps == 1


def test_first_segment_starts_from_rest_on_the_initial_command():
    """A fresh generator holds its initial command at rest; the first segment is the cubic Hermite
    from (initial, 0) to (target, slope of the quadratic through initial, initial, target)."""
    gen = PredictorCorrector(T_D, PERIOD, initial=1.0)
    assert gen.command == 1.0 and gen.velocity == 0.0 and gen.phase is Phase.HOLD and not gen.reached
    gen.new_target(3.0)
    assert not gen.reached and gen.phase is Phase.INTERPOLATE
    c = [gen.next_sample() for _ in range(N)]
    v_end = 0.5 * (3 * 3.0 - 4 * 1.0 + 1.0) / T_D
    T = N * PERIOD
    # Hermite at mid-segment: (c0 + c1) / 2 + T (v0 - v1) / 8
    assert c[N // 2 - 1] == pytest.approx(2.0 + T * (0.0 - v_end) / 8, rel=1e-13)
    assert gen.velocity == pytest.approx(v_end, rel=1e-13)


def test_ramp_hold_segment_ends_at_rest_then_dwells_for_the_hold_fraction():
    gen = PredictorCorrector(T_D, PERIOD, initial=0.0, hold_fraction=0.25)
    assert gen.planned_samples() == N - N // 4
    gen.new_target(2.0)
    c, phases = [], []
    while not gen.reached:
        c.append(gen.next_sample())
        phases.append(gen.phase)
    assert len(c) == N  # 48 samples moving, 16 dwelling
    assert c[(N - N // 4) // 2 - 1] == pytest.approx(1.0, rel=1e-13)  # symmetric: from rest to rest
    assert all(p is Phase.INTERPOLATE for p in phases[: N - N // 4 - 1])
    assert all(p is Phase.DWELL for p in phases[N - N // 4 - 1: -1]) and phases[-1] is Phase.HOLD
    assert c[N - N // 4 - 1:] == [2.0] * (N // 4 + 1)
    assert gen.velocity == 0.0


def test_a_target_arriving_during_extrapolation_lands_at_the_end_of_the_step():
    """Segment length: the rest of the step, at least half a step; a full step after slowing."""
    gen = PredictorCorrector(T_D, PERIOD, initial=q(0), slow_after=0.9)
    feed(gen, 3)
    for _ in range(10):
        gen.next_sample()
    assert gen.planned_samples() == N - 10
    for _ in range(40):
        gen.next_sample()
    assert gen.phase is Phase.EXTRAPOLATE and gen.planned_samples() == N // 2
    gen.new_target(q(4))
    n = 0
    while not gen.reached:
        gen.next_sample()
        n += 1
    assert n == N // 2 and gen.command == q(4)
    for _ in range(int(0.9 * N) + 1):
        gen.next_sample()
    assert gen.phase is Phase.SLOW and gen.planned_samples() == N


def test_a_target_is_late_only_after_slow_after_steps_of_waiting():
    gen = PredictorCorrector(T_D, PERIOD, initial=0.0)
    feed(gen, 2)
    for _ in range(N // 2):  # exactly slow_after = 0.5 t_d
        gen.next_sample()
    gen.new_target(q(3))
    assert gen.late_steps == 0
    for _ in range(N):
        gen.next_sample()
    for _ in range(N // 2 + 1):
        gen.next_sample()
    gen.new_target(q(4))
    assert gen.late_steps == 1
    for _ in range(N + N // 2 + 1):
        gen.next_sample()
    gen.new_target(q(5))
    assert gen.late_steps == 2


def test_the_command_holds_once_its_velocity_has_died_out():
    """With a long hold_after the slow phase ends when |v| t_d falls below 1e-9 mm."""
    tau = 0.02
    gen = PredictorCorrector(T_D, PERIOD, initial=q(0), slow_tau=tau, hold_after=50.0)
    feed(gen, 3)
    for _ in range(N // 2):
        gen.next_sample()
    v = gen.velocity
    decay = math.exp(-PERIOD / (tau * T_D))
    expected = 0
    while abs(v) * T_D >= 1e-9:
        v *= decay
        expected += 1
    k = 0
    while gen.phase is not Phase.HOLD:
        gen.next_sample()
        k += 1
    assert k == expected and gen.velocity == 0.0


def test_one_sample_per_step_when_the_step_is_shorter_than_a_period():
    gen = PredictorCorrector(0.0005, PERIOD, initial=0.0)
    assert gen.samples_per_step == 1 and gen.planned_samples() == 1
    gen.new_target(0.01)
    assert gen.next_sample() == 0.01 and gen.reached


def test_arguments_are_refused_with_their_names():
    with pytest.raises(ValueError, match="t_d and period must be positive"):
        PredictorCorrector(0.1, 0.0)
    with pytest.raises(ValueError, match="hold_fraction"):
        PredictorCorrector(0.1, PERIOD, hold_fraction=1.0)
