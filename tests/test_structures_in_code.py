"""Structures built in code get the checks of a structure file: a declared K^EI matrix has one row
per basic DOF of its element, is symmetric and positive definite; on a one-DOF element a 1 x 1
matrix is that number."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

import hsio
from hsio.errors import ConfigError
from hsio.structures import Damping, ExperimentalElement, Structure


def one_dof(K_EI) -> Structure:
    element = ExperimentalElement("e", 0, {"kind": "linear", "k": 30.0}, K_EI_declared=K_EI)
    return Structure(name="c", dof_names=("a",), masses=(0.01,), experimental=(element,), damping=Damping(0.05, "mass"))


@pytest.mark.parametrize("K_EI", [((40.0,),), np.array([[40.0]]), [[40]]])
def test_a_one_by_one_matrix_on_a_one_dof_element_is_its_number(K_EI):
    structure = one_dof(K_EI)
    assert structure.experimental[0].K_EI == 40.0
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, seed=1)
    assert np.array_equal(hsio.run_numerical(structure, ground).u, hsio.run_numerical(one_dof(40.0), ground).u)


@pytest.mark.parametrize("K_EI, message", [
    (((40.0, 0.0), (0.0, 40.0)), "must be a 1 x 1 matrix (a row per basic DOF), got 2 x 2"),
    (((-40.0,),), "must be positive definite"),
])
def test_a_declared_matrix_that_does_not_fit_a_one_dof_element_is_refused(K_EI, message):
    with pytest.raises(ConfigError, match=rf"^experimental element 'e': K_EI_declared {re.escape(message)}"):
        one_dof(K_EI)


@pytest.mark.parametrize("K_EI, message", [
    (np.eye(3) * 5.0, "must be a 2 x 2 matrix (a row per basic DOF), got 3 x 3"),
    (((5.0, 1.0), (0.0, 5.0)), "must be symmetric"),
    (((1.0, 2.0), (2.0, 1.0)), "must be positive definite"),
])
def test_a_declared_matrix_of_an_element_on_several_dofs_is_checked(K_EI, message):
    column = hsio.load_structure("column_two_actuators").experimental[0]
    with pytest.raises(ConfigError, match=rf"^experimental element '{column.name}': K_EI_declared {re.escape(message)}"):
        dataclasses.replace(column, K_EI_declared=K_EI)


def test_damping_ratios_and_modes_given_as_numpy_arrays_are_those_numbers():
    from hsio.structures import Spring

    def two_dof(damping: Damping) -> Structure:
        return Structure(name="c", dof_names=("a", "b"), masses=(0.01, 0.01), springs=(Spring(1, 0, 5.0),),
                         experimental=(ExperimentalElement("e", 0, {"kind": "linear", "k": 10.0}),), damping=damping)

    from_arrays = two_dof(Damping(np.array([0.02, 0.05]), "rayleigh", np.array([2, 1])))
    from_tuples = two_dof(Damping((0.02, 0.05), "rayleigh", (2, 1)))
    assert np.allclose(from_arrays.damping_ratios(), [0.05, 0.02])
    assert from_arrays == from_tuples


def test_a_declared_matrix_given_as_a_numpy_array_is_those_numbers():
    """A K^EI matrix given as a numpy array is kept as the structure file keeps it, rows of
    numbers: two structures built alike from arrays are equal, as two from tuples are."""
    column = hsio.load_structure("column_two_actuators")

    def built():
        element = dataclasses.replace(column.experimental[0], K_EI_declared=np.array([[5.0, 1.0], [1.0, 5.0]]))
        return dataclasses.replace(column, experimental=(element,))

    assert built().experimental[0].K_EI_declared == ((5.0, 1.0), (1.0, 5.0))
    assert built() == built()
