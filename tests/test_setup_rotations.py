"""A setup's rotation DOF (basic DOF theta, rad) in a structure file: a ground translation does
not turn it, and no spring joins it to a translation (docs/structures.md, docs/setups.md)."""

import pytest

from hsio.errors import ConfigError
from hsio.structure_file import parse_structure

COLUMN = """
[structure]
dt = 0.01
[[dof]]
name = "x"
mass = 0.02
[[dof]]
name = "r"
mass = 20000.0
IOTA
[damping]
kind = "rayleigh"
zeta = 0.03
[[experimental]]
name = "column"
dofs = ["x", "r"]
actuators = ["lo", "hi"]
setup = { kind = "two_actuators", length_mm = 900.0, spacing_mm = 300.0 }
model = { kind = "cantilever", EI = 1.5e9, L = 1800.0 }
"""


def test_a_rotation_left_at_the_default_iota_is_refused_naming_the_key():
    """iota defaults to 1: on a rotation, P = -M iota a_g would turn the platen by the ground's
    translation (0.3 g gave 38 rad and a 49 m sway). The file must say iota = 0 there."""
    with pytest.raises(ConfigError, match=r"^col\.toml: dof\[1\]\.iota: DOF 'r' is a rotation .* must be 0, got 1"):
        parse_structure(COLUMN.replace("IOTA", ""), "col.toml")
    with pytest.raises(ConfigError, match=r"dof\[1\]\.iota: .* got -0.5"):
        parse_structure(COLUMN.replace("IOTA", "iota = -0.5"), "col.toml")
    structure = parse_structure(COLUMN.replace("IOTA", "iota = 0.0"), "col.toml")
    assert structure.iota.tolist() == [1.0, 0.0]


@pytest.mark.parametrize("spring, ok", [('dof = "r"\nto = "x"', False), ('dof = "x"\nto = "r"', False),
                                        ('dof = "r"', True), ('dof = "x"', True)])
def test_a_spring_from_a_rotation_to_a_translation_is_refused(spring, ok):
    text = COLUMN.replace("IOTA", "iota = 0.0") + f"[[spring]]\n{spring}\nk = 1.0\n"
    if ok:
        parse_structure(text, "col.toml")
        return
    with pytest.raises(ConfigError, match=r"^col\.toml: spring\[0\]: joins DOF .* a rotation \(rad\) to a translation"):
        parse_structure(text, "col.toml")
