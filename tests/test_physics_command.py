"""The predictor-corrector (docs/method.md section 1) on targets that lie on a quadratic in time:
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
