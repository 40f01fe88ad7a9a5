"""The switching rule of mixed control (E&M 2007, mixed variables): two
thresholds per element with hysteresis, on the secant stiffness or on |R|."""

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.integrators import ImplicitMethod, SwitchingRule
from hsio.interfaces import ControlMode

DC = ControlMode.DISPLACEMENT
FC = ControlMode.FORCE


def test_stiffness_rule_switches_with_hysteresis():
    rule = SwitchingRule([3.0, 30.0], [2.0, 20.0])
    R = np.zeros(2)
    # DC goes to FC only above the upper threshold
    assert rule.next_modes([DC, DC], np.array([3.0, 30.0]), R) == [DC, DC]
    assert rule.next_modes([DC, DC], np.array([3.0001, 29.0]), R) == [FC, DC]
    # FC stays in FC between the thresholds and goes back to DC only below the lower one
    assert rule.next_modes([FC, FC], np.array([2.0, 25.0]), R) == [FC, FC]
    assert rule.next_modes([FC, FC], np.array([1.9999, 20.0]), R) == [DC, FC]
    # between the thresholds each element keeps its mode
    assert rule.next_modes([DC, FC], np.array([2.5, 25.0]), R) == [DC, FC]
    # no estimate (nan): no switch
    assert rule.next_modes([DC, FC], np.array([np.nan, np.nan]), R) == [DC, FC]


def test_force_rule_uses_the_magnitude_of_the_restoring_force():
    rule = SwitchingRule([10.0], [4.0], on="force")
    k = np.array([100.0])  # ignored
    assert rule.next_modes([DC], k, np.array([-10.5])) == [FC]
    assert rule.next_modes([DC], k, np.array([9.5])) == [DC]
    assert rule.next_modes([FC], k, np.array([-3.5])) == [DC]
    assert rule.next_modes([FC], k, np.array([5.0])) == [FC]


def test_thresholds_from_the_initial_stiffness():
    rule = SwitchingRule.from_initial_stiffness([2.0, 5.0])
    assert np.allclose(rule.upper, [2.4, 6.0]) and np.allclose(rule.lower, [1.6, 4.0]) and rule.on == "stiffness"
    rule = SwitchingRule.from_initial_stiffness([2.0, 5.0], ratio_f=2.0, ratio_d=0.5)
    assert np.allclose(rule.upper, [4.0, 10.0]) and np.allclose(rule.lower, [1.0, 2.5])
    rule = SwitchingRule.from_initial_stiffness([2.0, 5.0], K_f=7.0, K_d=3.0)
    assert np.allclose(rule.upper, [7.0, 7.0]) and np.allclose(rule.lower, [3.0, 3.0])


def test_bad_thresholds_are_refused():
    with pytest.raises(ConfigError, match="must be below"):
        SwitchingRule([2.0], [2.0])
    with pytest.raises(ConfigError, match="not negative"):
        SwitchingRule([2.0], [-0.1])
    with pytest.raises(ConfigError, match="thresholds must be finite"):
        SwitchingRule([np.nan], [1.0])
    assert SwitchingRule([np.inf], [1.0]).upper.tolist() == [np.inf]  # never FC
    with pytest.raises(ConfigError, match="'stiffness' or 'force'"):
        SwitchingRule([2.0], [1.0], on="displacement")
    SwitchingRule([2.0], [0.0])  # a zero lower threshold is allowed


def test_methods_start_in_their_modes():
    M, C, K_EI = np.diag([1.0, 1.0]), np.zeros((2, 2)), [2.0, 3.0]
    assert ImplicitMethod(M, C, None, [0, 1], K_EI, 0.01, method="implicit_dc").modes == [DC, DC]
    fc = ImplicitMethod(M, C, None, [0, 1], K_EI, 0.01, method="force_control")
    assert fc.modes == [FC, FC] and fc.rule is None and fc.fallback is None and fc.thresholds is None
    mixed = ImplicitMethod(M, C, None, [0, 1], K_EI, 0.01, method="mixed")
    assert mixed.modes == [DC, DC]
    assert np.allclose(mixed.fallback, [1.6, 2.4])  # falls back below the lower threshold
    assert mixed.thresholds["on"] == "stiffness"
    assert mixed.thresholds["upper"] == pytest.approx([2.4, 3.6]) and mixed.thresholds["lower"] == pytest.approx([1.6, 2.4])
    by_force = ImplicitMethod(M, C, None, [0, 1], K_EI, 0.01, method="mixed", rule=SwitchingRule([5.0, 5.0], [1.0, 1.0], "force"))
    assert by_force.fallback is None
    with pytest.raises(ConfigError, match="method must be one of"):
        ImplicitMethod(M, C, None, [0, 1], K_EI, 0.01, method="explicit")
