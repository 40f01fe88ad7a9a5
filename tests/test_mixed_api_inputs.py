"""Options of the implicit methods from Python: a value that is not what the option takes is
refused with a ConfigError naming it, never read as something else (docs/api.md, docs/force_control.md)."""

import pytest

from hsio.api import make_integrator
from hsio.errors import ConfigError
from hsio.integrators import SwitchingRule
from hsio.structures import get_structure


@pytest.mark.parametrize("option, value", [
    ("fc_blend", "0.5"), ("blend_dc", "no"), ("blend_dc", 1), ("no_fc_at_reversal", "no"),
    ("no_fc_at_reversal", 0), ("fc_force_limit", -5.0), ("fc_force_limit", float("nan")),
    ("fc_force_limit", 0.0), ("fc_force_limit", "x"), ("fc_force_limit", [1.0, 2.0, 3.0]), ("fc_force_limit", True),
])
def test_a_wrong_kind_of_value_is_refused_naming_the_option(option, value):
    structure = get_structure("structure_II")  # two experimental elements
    extra = {"fc_blend": 0.5} if option == "blend_dc" else {}
    with pytest.raises(ConfigError, match=option):
        make_integrator(structure, "mixed", **{option: value}, **extra)


def test_none_leaves_an_option_at_its_default_and_a_limit_may_be_given_per_element():
    structure = get_structure("structure_II")
    for option in ("fc_blend", "blend_dc", "no_fc_at_reversal", "fc_force_limit", "refractory_steps"):
        make_integrator(structure, "mixed", **{option: None})
    assert make_integrator(structure, "mixed", fc_force_limit=[5.0, 6.0]).fc_force_limit.tolist() == [5.0, 6.0]
    assert make_integrator(structure, "mixed", no_fc_at_reversal=True).no_fc_at_reversal


@pytest.mark.parametrize("option, value", [("j_max", 7), ("tol_displacement", 0.5), ("tol_force", 1.0)])
def test_an_iteration_setting_given_to_alpha_os_is_refused(option, value):
    structure = get_structure("structure_I")
    with pytest.raises(ConfigError, match=f"{option}: not an option of method = 'alpha_os'"):
        make_integrator(structure, "alpha_os", **{option: value})
    make_integrator(structure, "implicit_dc", **{option: value})


@pytest.mark.parametrize("method", ["alpha_os", "implicit_dc", "force_control"])
def test_a_switching_rule_given_to_a_method_that_does_not_switch_is_refused(method):
    from hsio.integrators import SwitchingRule

    structure = get_structure("structure_I")
    with pytest.raises(ConfigError, match=f"a switching rule applies to method = 'mixed', not to '{method}'"):
        make_integrator(structure, method, rule=SwitchingRule.from_initial_stiffness([2.6]))


@pytest.mark.parametrize("min_increment", ["x", True, None])
def test_a_secant_estimator_with_a_min_increment_that_is_not_a_number_is_refused(min_increment):
    from hsio.secant import SecantEstimator

    with pytest.raises(ConfigError, match="min_increment must be zero or positive"):
        SecantEstimator("raw", 16, min_increment)


@pytest.mark.parametrize("make", [
    lambda S: S("x", [1.0]), lambda S: S([3.0, 4.0], [1.0, 2.0, 0.5]),
    lambda S: S.from_initial_stiffness([2.6], -1.0), lambda S: S.from_initial_stiffness([2.6], "3"),
    lambda S: S.from_initial_stiffness([2.6], 0.0, -2.0), lambda S: S.from_instruments([2.6], "0.025", 0.01),
    lambda S: S.from_instruments([2.6], None, 0.01),
])
def test_a_switching_rule_of_values_that_are_not_thresholds_is_refused(make):
    from hsio.integrators import SwitchingRule

    with pytest.raises(ConfigError, match="switching rule"):
        make(SwitchingRule)
    assert SwitchingRule([3.0, 4.0], [1.0]).lower.tolist() == [1.0]  # one lower threshold for all elements


def _implicit_method_args(**changed):
    import numpy as np

    args = dict(M=np.eye(2) * 0.01, C=np.zeros((2, 2)), K_N=None, element_dofs=[0, 1], K_EI=[1.5, 40.0], dt=0.01)
    args.update(changed)
    return args


@pytest.mark.parametrize("changed, says", [
    ({"dt": "0.01"}, "dt must be positive"),
    ({"element_dofs": [0.5, 1]}, "element_dofs must be whole DOF numbers"),
    ({"M": [[float("nan"), 0.0], [0.0, 0.01]]}, "M must be finite"),
    ({"M": [[0.01, 0.0], [0.0, 0.0]]}, "M must be positive definite"),
    ({"C": "abc"}, "C must be a matrix of numbers"),
    ({"K_N": [[float("inf"), 0.0], [0.0, 0.0]]}, "K_N must be finite"),
    ({"dof_names": ["a"]}, "dof_names: 1 names for 2 DOFs"),
    ({"rule": 5}, "rule must be a SwitchingRule"),
    ({"rule": "stiffness"}, "rule must be a SwitchingRule"),
    ({"rule": SwitchingRule([5.0, 6.0, 7.0], [1.0, 2.0, 3.0])}, "3 threshold"),
])
def test_implicit_method_refuses_what_it_cannot_integrate_naming_it(changed, says):
    """ImplicitMethod from Python: a value it would misread (a float DOF truncated to an index, a
    massless DOF, a NaN matrix, a rule that is not one) is a ConfigError naming it, never a
    TypeError, an AttributeError at the first step, or a run of NaN."""
    from hsio.integrators import ImplicitMethod

    with pytest.raises(ConfigError, match=says):
        ImplicitMethod(**_implicit_method_args(**changed))


def test_a_rule_from_instruments_with_stiffnesses_that_are_not_numbers_is_refused():
    from hsio.integrators import SwitchingRule

    with pytest.raises(ConfigError, match="K_EI must be numbers"):
        SwitchingRule.from_instruments("abc", 0.025, 0.01)


@pytest.mark.parametrize("j_max", ["3", None, 2.5])
def test_a_j_max_that_is_not_a_whole_number_is_named_beside_a_fallback(j_max):
    """fallback_after is compared with j_max: a j_max that is not a whole number is refused by its
    own name, not met by the comparison."""
    with pytest.raises(ConfigError, match="j_max"):
        make_integrator(get_structure("structure_I"), "mixed", j_max=j_max, fallback_after=2)
