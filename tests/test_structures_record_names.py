"""Names the record writes as columns: every DOF, recorded channel, element, actuator
and instrument has a column of its own, or the structure is refused when it is loaded (before a run
opens anything), naming the file and the key."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest

import hsio
from hsio.errors import ConfigError
from hsio.interfaces import ControlMode
from hsio.recording import Recorder, Run
from hsio.structure_file import parse_structure

WALL = (resources.files("hsio") / "library" / "structure_I.toml").read_text()
COLUMN = (resources.files("hsio") / "library" / "column_two_actuators.toml").read_text()


def instruments(*names: str) -> str:
    return "".join(f'\n[[instrument]]\nname = "{n}"\nkind = "lvdt"\nelement = "wall"\n' for n in names)


@pytest.mark.parametrize("names, message", [
    (("LVDT", "lvdt"), "instrument[1].name: instrument 'lvdt' and 'LVDT' of instrument[0].name would be one column"),
    (("lvdt-1", "lvdt_1"), "instrument[1].name: instrument 'lvdt_1' and 'lvdt-1' of instrument[0].name"),
    (("\u00e9", "\u00fc"), "instrument[1].name: instrument '\u00fc' and '\u00e9'"),
    (("iterations",), "instrument[0].name: instrument name 'iterations' is a column the record's instruments table"),
    (("Step",), "instrument[0].name: instrument name 'Step' is a column"),
])
def test_instruments_that_would_share_a_column_of_the_record_are_refused(names, message):
    with pytest.raises(ConfigError, match="^wall.toml: ") as info:
        parse_structure(WALL + instruments(*names), "wall.toml")
    assert message in str(info.value)


def test_dofs_that_differ_only_in_case_are_refused():
    text = COLUMN.replace('name = "top_rot"', 'name = "TOP_X"').replace('"top_rot"]', '"TOP_X"]')
    with pytest.raises(ConfigError, match=r"^col.toml: dof\[1\].name: DOF 'TOP_X' and 'top_x' of dof\[0\].name "
                                          "would be one column of the record"):
        parse_structure(text, "col.toml")


def test_an_element_named_as_another_elements_channel_is_refused():
    """Element `column` on DOFs top_x and top_rot records channels `column.top_x` and
    `column.top_rot`; a one-DOF element named `column.top_x` would record a second channel of that
    name (a DataFrame or a record would keep only one of the two)."""
    text = COLUMN.replace('[[dof]]\nname = "top_x"', '[[dof]]\nname = "side"\nmass = 0.01\n\n[[dof]]\nname = "top_x"', 1)
    text += '\n[[experimental]]\nname = "column.top_x"\ndof = "side"\nmodel = { kind = "linear", k = 1.0 }\n'
    with pytest.raises(ConfigError, match=r"^col.toml: experimental\[1\].name: recorded channel 'column.top_x' is "
                                          r"also the recorded channel of experimental\[0\].name"):
        parse_structure(text, "col.toml")


def test_preload_actuators_that_would_share_a_column_are_refused():
    text = (resources.files("hsio") / "library" / "preloaded_column.toml").read_text()
    text += '\n[[static]]\nname = "Axial"\nforce_kN = 10.0\nmodel = { kind = "linear", k = 5.0 }\n'
    with pytest.raises(ConfigError, match=r"static\[1\].name: actuator 'Axial' and 'axial'"):
        parse_structure(text, "pre.toml")  # the key the file gives: the actuator is named after the preload
    text = text.replace('name = "Axial"\n', 'name = "second"\nactuator = "Axial"\n')
    with pytest.raises(ConfigError, match=r"static\[1\].actuator: actuator 'Axial' and 'axial'"):
        parse_structure(text, "pre.toml")


def test_a_structure_built_in_code_gets_the_same_check():
    from dataclasses import replace

    with pytest.raises(ConfigError, match="structure 'sdof2': dof\\[1\\].name: DOF 'X' and 'x'"):
        replace(hsio.structures.sdof(m=0.01, k=1.0), name="sdof2", dof_names=("x", "X"), masses=(0.01, 0.01))


def test_an_instrument_named_as_an_sql_keyword_or_from_a_digit_is_recorded(tmp_path):
    """The record quotes the instruments' columns: `select` and `1lvdt` are names like any other."""
    structure = parse_structure(WALL + instruments("select", "1lvdt"), "wall.toml")
    path = tmp_path / "run.sqlite"
    recorder = Recorder(path, structure.dof_names, structure.experimental_names)
    with hsio.open_site(structure, "emulator://", test_rate=2) as site:
        site.set_trial(np.array([0.5]), [ControlMode.DISPLACEMENT])
        recorder.write_tables(site.record_tables())
    recorder.close()
    table = Run(path).table("instruments")
    assert set(table) == {"step", "iterations", "select", "1lvdt"}
    assert table["select"][0] == pytest.approx(table["1lvdt"][0]) and abs(table["select"][0]) > 0.1


@pytest.mark.parametrize("name, message", [
    ("x" * 101, r"dof\[0\]\.name: a name of 101 characters; at most 100"),
    ("a\\nb", r"dof\[0\]\.name: 'a\\nb' holds the control character '\\n'"),
    ("bell\\u0007", r"dof\[0\]\.name: 'bell\\x07' holds the control character"),
])
def test_names_too_long_or_with_control_characters_are_refused(name, message):
    text = WALL.replace('[[dof]]\nname = "wall"', f'[[dof]]\nname = "{name}"').replace('dof = "wall"', f'dof = "{name}"')
    with pytest.raises(ConfigError, match="^wall.toml: " + message):
        parse_structure(text, "wall.toml")


def test_names_of_unicode_letters_and_spaces_up_to_100_characters_load():
    name = "Wand Erdgeschoss \u00e4\u00f6\u00fc \u6f22" + "x" * 78
    assert len(name) == 100
    text = WALL.replace('[[dof]]\nname = "wall"', f'[[dof]]\nname = "{name}"').replace('dof = "wall"', f'dof = "{name}"')
    assert parse_structure(text, "wall.toml").dof_names == (name,)


def test_elements_that_differ_only_in_case_are_refused_though_their_actuators_differ():
    """Elements `C1` and `c1` on actuators `C1` and `A2`: their recorded channels differ, but the
    implicit methods' table has a column per element (iterations_C1, iterations_c1), one column
    to SQLite; refused when the structure is loaded, not at the first step of a run."""
    text = (resources.files("hsio") / "library" / "validation.toml").read_text()
    text = text.replace('[[experimental]]\nname = "C2"\ndof = "C2"', '[[experimental]]\nname = "c1"\ndof = "C2"\n'
                        'actuator = "A2"')
    with pytest.raises(ConfigError, match=r"^v.toml: experimental\[1\].name: element 'c1' and 'C1' of "
                                          r"experimental\[0\].name would be one column of the record"):
        parse_structure(text, "v.toml")


def test_actuators_of_a_setup_that_differ_only_in_case_are_refused():
    """A column on actuators `lower` and `Lower`: its channels are column.top_x and column.top_rot,
    but the record keeps a column per actuator (interlocks, compensation): one column to SQLite."""
    text = COLUMN.replace('actuators = ["lower", "upper"]', 'actuators = ["lower", "Lower"]')
    with pytest.raises(ConfigError, match=r"^col.toml: experimental\[0\].actuators\[1\]: actuator 'Lower' and "
                                          r"'lower' of experimental\[0\].actuators\[0\] would be one column"):
        parse_structure(text, "col.toml")


@pytest.mark.parametrize("second", ["pred_wall", "Pred-Wall"])
def test_a_dof_named_pred_and_another_dofs_name_is_refused(second):
    """DOF `pred_wall`'s displacement column u_pred_wall is DOF `wall`'s predicted displacement:
    the record and `Result.to_dataframe()` would keep one of the two."""
    text = WALL + (f'\n[[dof]]\nname = "{second}"\nmass = 0.01\n\n[[spring]]\ndof = "{second}"\nto = "wall"\n'
                   "k = 1.0\n")
    with pytest.raises(ConfigError) as info:
        parse_structure(text, "wall.toml")
    assert str(info.value).startswith(f"wall.toml: dof[1].name: DOF '{second}' would make the column "
                                      f"'u_{second.replace('-', '_')}' of the record, which is the predicted "
                                      "displacement (u_pred_) of DOF 'wall' of dof[0].name")


def test_every_dof_column_of_a_dataframe_is_its_own():
    text = WALL + '\n[[dof]]\nname = "pred"\nmass = 0.01\n\n[[spring]]\ndof = "pred"\nto = "wall"\nk = 1.0\n'
    structure = parse_structure(text, "wall.toml")
    result = hsio.run_numerical(structure, hsio.synthetic_record(duration_s=0.2, dt=structure.dt, seed=1))
    pytest.importorskip("pandas")
    frame = result.to_dataframe()
    assert len(frame.columns) == 1 + 6 * 2 + 6 * 1
    assert np.array_equal(frame["u_pred_wall"], result.u_pred[:, 0])
    assert np.array_equal(frame["u_pred"], result.u[:, 1])
