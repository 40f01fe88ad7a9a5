"""Modal damping on a symmetric structure: modes at one frequency have no shapes of their own,
so the damping matrix must not depend on the order in which the file lists the DOFs
(docs/structures.md, [damping])."""

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.structure_file import parse_structure


def triangle(order, zeta):
    """Three equal masses, each on its own ground element, joined pairwise by equal springs:
    frequencies w0 and twice w0 (two modes)."""
    text = '[structure]\nname = "triangle"\ndt = 0.005\n'
    text += "".join(f'[[dof]]\nname = "{n}"\nmass = 0.01\n' for n in order)
    text += f'[damping]\nkind = "modal"\nzeta = {zeta}\n'
    text += "".join(f'[[experimental]]\nname = "{n}"\ndof = "{n}"\nmodel = {{ kind = "linear", k = 1.0 }}\n'
                    for n in order)
    text += "".join(f'[[spring]]\ndof = "{i}"\nto = "{j}"\nk = 1.0\n' for i, j in (("a", "b"), ("b", "c"), ("a", "c")))
    structure = parse_structure(text, "triangle.toml")
    index = [order.index(n) for n in "abc"]
    return structure, structure.C[np.ix_(index, index)]


def test_two_ratios_on_modes_of_one_frequency_are_refused_naming_the_key():
    with pytest.raises(ConfigError, match=r"^triangle\.toml: damping\.zeta: modal damping cannot give modes 2 and 3 "
                                          r"two ratios \(3 % and 6 %\): both are at 3\.1831 Hz"):
        triangle(("a", "b", "c"), "[0.02, 0.03, 0.06]")


@pytest.mark.parametrize("zeta", ["[0.02, 0.06, 0.06]", "0.05"])
def test_one_ratio_per_frequency_gives_one_damping_matrix_whatever_the_order_of_the_dofs(zeta):
    first, C = triangle(("a", "b", "c"), zeta)
    for order in (("b", "c", "a"), ("c", "a", "b"), ("b", "a", "c")):
        np.testing.assert_allclose(triangle(order, zeta)[1], C, rtol=1e-10, atol=1e-15)
    # and in closed form: the rigid mode (1 1 1)/sqrt(3m) at w0 = 10 rad/s takes zeta_1; the
    # other two at 2 w0 take zeta_2, C = sum_r 2 zeta_r w_r M phi_r phi_r^T M
    z1, z2 = (0.02, 0.06) if zeta.startswith("[") else (0.05, 0.05)
    m, w0 = 0.01, 10.0
    P1 = np.full((3, 3), 1.0 / 3.0)
    np.testing.assert_allclose(C, 2 * m * (z1 * w0 * P1 + z2 * 2 * w0 * (np.eye(3) - P1)), rtol=1e-10)
    np.testing.assert_allclose(first.damping_ratios(), [z1, z2, z2], rtol=1e-10)
