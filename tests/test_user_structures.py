"""Structure files and load_structure as a lab uses them: its own files, names and arguments."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import hsio

LIBRARY = Path(hsio.__file__).parent / "library"


def test_a_structure_file_with_an_upper_case_suffix_is_read_as_a_file(tmp_path, monkeypatch):
    shutil.copy(LIBRARY / "structure_I.toml", tmp_path / "WALL.TOML")
    monkeypatch.chdir(tmp_path)
    assert hsio.load_structure("WALL.TOML").name == "structure_I"


@pytest.mark.parametrize("argument", [b"validation", None, 3, ["validation"]])
def test_load_structure_refuses_what_is_neither_a_name_nor_a_path(argument):
    with pytest.raises(hsio.ConfigError, match="load_structure: a shipped structure's name or a structure file's path"):
        hsio.load_structure(argument)


WALL = """
[structure]
dt = 0.01
[[dof]]
name = "top"
mass = 0.01
[[experimental]]
name = "wall"
dof = "top"
model = {{ kind = "pinched_wood", k0 = 2.0, F0 = 10.0, {extra} }}
"""


@pytest.mark.parametrize("extra, words", [
    ("r3 = 0.5", "r3 must be at least 1"),        # an unloading line softer than the backbone
    ("r3 = -1.5", "r3 must be at least 1"),       # a sign typed wrong: the wall would give energy out
    ("r1 = -0.1", "r1 must be zero or positive"),
    ("r4 = -0.02", "r4 must be zero or positive"),
    ("r_pinch = 1.5", "r_pinch must be within 0..1"),
])
def test_a_pinched_wall_with_parameters_outside_its_model_is_refused(tmp_path, extra, words):
    path = tmp_path / "wall.toml"
    path.write_text(WALL.format(extra=extra))
    with pytest.raises(hsio.ConfigError, match=rf"wall.toml: experimental\[0\].model: pinched_wood: {words}"):
        hsio.load_structure(path)


@pytest.mark.parametrize("params", [{"r3": 1.0, "r_pinch": 1.0, "r1": 0.0, "r4": 0.0}, {}])
def test_a_pinched_wall_at_the_edges_of_its_parameters_dissipates_energy_over_a_cycle(params):
    from hsio.specimens import make_specimen

    wall = make_specimen({"kind": "pinched_wood", "k0": 2.0, "F0": 10.0, **params})
    u = np.r_[np.linspace(0, 20, 2001), np.linspace(20, -20, 4001)[1:], np.linspace(-20, 20, 4001)[1:]]
    force = []
    for x in u:
        force.append(wall.trial(x))
        wall.commit()
    cycle = slice(2000, None)
    assert np.trapezoid(force[cycle], u[cycle]) > 0.0


def test_a_structure_built_with_a_mass_matrix_reports_its_diagonal_as_the_masses():
    from hsio.structures import Damping, ExperimentalElement, Structure

    wall = ExperimentalElement("e", 0, {"kind": "linear", "k": 2.0})
    s = Structure("s", ("x",), (0.01,), (wall,), damping=Damping(kind="mass"), mass_matrix=((0.05,),))
    assert s.masses == (0.05,) and np.array_equal(s.M, [[0.05]])
    assert s.natural_frequencies_hz()[0] == pytest.approx(np.sqrt(2.0 / 0.05) / (2 * np.pi), rel=1e-12)


@pytest.mark.parametrize("name", [None, "", "  ", 5, "a\nb"])
def test_a_structure_built_in_code_needs_a_name_as_a_file_does(name):
    from hsio.structures import Damping, ExperimentalElement, Structure

    wall = ExperimentalElement("e", 0, {"kind": "linear", "k": 2.0})
    with pytest.raises(hsio.ConfigError, match=r": name: "):
        Structure(name, ("x",), (0.01,), (wall,), damping=Damping(kind="mass"))
