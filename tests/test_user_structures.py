"""Structure files and load_structure as a lab uses them: its own files, names and arguments."""

from __future__ import annotations

import shutil
from pathlib import Path

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
