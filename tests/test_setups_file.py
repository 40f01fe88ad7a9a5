"""Elements loaded through setups in structure files: parsing, K^EI matrices, errors by key."""

import numpy as np
import pytest

import hsio
from hsio.errors import ConfigError
from hsio.specimens.matrix import LinearMatrix, cantilever_top_stiffness
from hsio.structure_file import parse_structure

BASE = """
[structure]
dt = 0.01
[[dof]]
name = "x"
mass = 0.01
[[dof]]
name = "r"
mass = 900.0
"""

ELEMENT = """
[[experimental]]
name = "col"
dofs = ["x", "r"]
actuators = ["a", "b"]
setup = { kind = "two_actuators", length_mm = 1500.0, spacing_mm = 500.0 }
model = { kind = "cantilever", EI = 2.0e9, L = 2000.0 }
"""


def test_cantilever_top_stiffness_in_closed_form():
    EI, L, EA = 2.0e9, 2000.0, 4.0e5
    K = cantilever_top_stiffness(EI, L, EA, ("ux", "uy", "theta"))
    np.testing.assert_allclose(K, [[12 * EI / L**3, 0, 6 * EI / L**2], [0, EA / L, 0], [6 * EI / L**2, 0, 4 * EI / L]])
    # the condensed lateral stiffness of a cantilever with a free top: 3 EI / L^3
    K2 = cantilever_top_stiffness(EI, L)
    assert K2[0, 0] - K2[0, 1] ** 2 / K2[1, 1] == pytest.approx(3 * EI / L**3, rel=1e-12)
    with pytest.raises(ConfigError, match="EA"):
        cantilever_top_stiffness(EI, L, 0.0, ("ux", "uy"))
    with pytest.raises(ConfigError, match="positive definite"):
        LinearMatrix([[1.0, 2.0], [2.0, 1.0]])


def test_shipped_column_and_joint():
    column = hsio.load_structure("column_two_actuators")
    (e,) = column.experimental
    assert e.basic_dofs == (0, 1) and e.actuator_names == ("lower", "upper")
    assert column.experimental_dofs == [0, 1]
    assert column.experimental_names == ["column.top_x", "column.top_rot"]
    np.testing.assert_allclose(column.K_EI, cantilever_top_stiffness(2.0e9, 2000.0))
    np.testing.assert_allclose(column.K_EI_basic, column.K_EI)
    joint = hsio.load_structure("joint_three_actuators")
    assert joint.experimental[0].make_setup().n_actuators == 3
    assert joint.K_EI[0, 2] == 3000.0 and joint.iota.tolist() == [1.0, 0.5, 0.0]


def test_declared_K_EI_matrix_and_identity_setup_with_factors():
    text = BASE + """
[[experimental]]
name = "col"
dofs = ["x", "r"]
setup = { kind = "none", factors = { displacement = 2.0, force = 0.5 } }
model = { kind = "matrix", K = [[3.0, 3000.0], [3000.0, 4.0e6]] }
K_EI = [[2.5, 3000.0], [3000.0, 4.0e6]]
"""
    s = parse_structure(text, "f.toml")
    (e,) = s.experimental
    np.testing.assert_allclose(s.K_EI, [[2.5, 3000.0], [3000.0, 4.0e6]])
    assert e.actuator_names == ("col.0", "col.1")
    setup = e.make_setup()
    np.testing.assert_allclose(setup.strokes([4.0, 0.01]), [2.0, 0.005])
    np.testing.assert_allclose(setup.basic_forces([10.0, 1.0], [0.0, 0.0]), [5.0, 0.5])


@pytest.mark.parametrize("element, where", [
    (ELEMENT.replace('kind = "two_actuators"', 'kind = "four_actuators"'), "experimental[0].setup.kind"),
    (ELEMENT.replace('actuators = ["a", "b"]', 'actuators = ["a"]'), "experimental[0].actuators"),
    (ELEMENT.replace('actuators = ["a", "b"]', 'actuators = ["a", "a"]'), "experimental[0].actuators"),
    (ELEMENT.replace('dofs = ["x", "r"]', 'dofs = ["x", "z"]'), "experimental[0].dofs[1]"),
    (ELEMENT.replace(', spacing_mm = 500.0', ''), "experimental[0].setup.spacing_mm"),
    (ELEMENT.replace('spacing_mm = 500.0', 'spacing_mm = 500.0, height = 1'), "experimental[0].setup.height"),
    (ELEMENT.replace('kind = "two_actuators"', 'kind = "three_actuators"'), "experimental[0].setup.kind"),
    (ELEMENT.replace('{ kind = "cantilever", EI = 2.0e9, L = 2000.0 }', '{ kind = "linear", k = 1.0 }'),
     "experimental[0].model.kind"),
    (ELEMENT.replace('{ kind = "cantilever", EI = 2.0e9, L = 2000.0 }', '{ kind = "matrix", K = [[1.0]] }'),
     "experimental[0].model.K"),
    (ELEMENT + 'K_EI = [[1.0, 0.0], [1.0, 1.0]]\n', "experimental[0].K_EI"),
    (ELEMENT + ELEMENT.replace('"col"', '"col2"').replace('["a", "b"]', '["c", "d"]'), "experimental[1].dofs"),
    (ELEMENT.replace('setup = { kind = "two_actuators", length_mm = 1500.0, spacing_mm = 500.0 }',
                     'setup = { kind = "two_actuators", length_mm = 1500.0, spacing_mm = 500.0, factors = { force = 0 } }'),
     "experimental[0].setup.factors"),
])
def test_errors_name_the_file_table_and_key(element, where):
    with pytest.raises(ConfigError) as info:
        parse_structure(BASE + element, "rig.toml")
    assert str(info.value).startswith(f"rig.toml: {where}"), str(info.value)


def test_implicit_methods_refuse_coupled_elements():
    column = hsio.load_structure("column_two_actuators")
    with pytest.raises(ConfigError, match="alpha_os"):
        hsio.api.make_integrator(column, "implicit_dc")
