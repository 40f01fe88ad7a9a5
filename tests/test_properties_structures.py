"""Property-based tests (hypothesis) of structure files: every shipped structure, and one with an
instrument and an outer loop, with one to three of its values replaced or removed. Each either
loads or is refused with a ConfigError naming the file; nothing else escapes (docs/structures.md,
docs/setups.md). Bounded: a few seconds. Values at the edges are plain tests below."""

from __future__ import annotations

import copy
import re
import tomllib
from importlib import resources

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hsio.errors import ConfigError
from hsio.structure_file import parse_structure, structure_from_tables


def _documents() -> dict[str, dict]:
    library = resources.files("hsio") / "library"
    docs = {p.name: tomllib.loads(p.read_text()) for p in library.iterdir() if p.name.endswith(".toml")}
    wall = copy.deepcopy(docs["structure_I.toml"])
    wall["instrument"] = [{"name": "lv", "kind": "lvdt", "element": wall["experimental"][0].get("name", "wall")}]
    wall["experimental"][0]["displacement_from"] = "lv"
    wall["experimental"][0]["outer_loop"] = {"tolerance_mm": 0.05, "max_iterations": 4}
    docs["instrumented.toml"] = wall
    return docs


DOCUMENTS = _documents()
DELETE = object()
values = st.one_of(
    st.sampled_from([DELETE, 0, -1, 0.0, 1e308, -1e308, 5e-324, 1e-200, 2**63, True, "", "ground", "x", [], [[0.0]],
                     {}, {"kind": "linear"}, {"kind": "matrix", "K": [[1.0]]}]),
    st.floats(allow_nan=True), st.integers(-10**20, 10**20), st.text(max_size=8),
    st.lists(st.floats(-1e6, 1e6), max_size=3), st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
)


def _paths(node, prefix=()):
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        yield prefix + (key,)
        yield from _paths(value, prefix + (key,))


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(sorted(DOCUMENTS)), st.lists(st.tuples(st.integers(0, 10**6), values), min_size=1, max_size=3))
def test_a_structure_file_with_values_changed_loads_or_is_refused(name, changes):
    doc = copy.deepcopy(DOCUMENTS[name])
    for pick, value in changes:
        paths = list(_paths(doc))
        if not paths:
            break
        path = paths[pick % len(paths)]
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        if value is DELETE:
            del parent[path[-1]]
        else:
            parent[path[-1]] = copy.deepcopy(value)
    try:
        structure_from_tables(doc, name)
    except ConfigError as exc:
        assert name in str(exc)


def _with(base: str, extra: str, old: str = "", new: str = "") -> bytes:
    text = (resources.files("hsio") / "library" / base).read_text()
    assert old in text
    return (text.replace(old, new) + extra).encode()


@pytest.mark.parametrize("data, where", [
    (_with("structure_I.toml", '\n[[instrument]]\nname = "lv"\nkind = { a = 1 }\n'), "instrument[0].kind"),
    (_with("structure_I.toml", '\n[[instrument]]\nname = "lv"\nkind = ["lvdt"]\n'), "instrument[0].kind"),
    (_with("joint_three_actuators.toml", "", 'kind = "three_actuators"', 'kind = ["three_actuators"]'),
     "experimental[0].setup.kind"),
    (_with("column_two_actuators.toml", "", 'kind = "two_actuators"', 'kind = { two = 2 }'),
     "experimental[0].setup.kind"),
])
def test_a_kind_that_is_not_a_string_is_named(data, where):
    with pytest.raises(ConfigError, match=re.escape(f"rig.toml: {where}: unknown")):
        parse_structure(data, "rig.toml")


def test_a_cantilever_whose_stiffness_leaves_the_floating_point_range_is_named():
    text = (resources.files("hsio") / "library" / "column_two_actuators.toml").read_text()
    start = text.index("model = {")
    end = text.index("\n", start)
    data = text[:start] + 'model = { kind = "cantilever", EI = 1.0e9, L = 1e-200, EA = 1.0 }' + text[end:]
    with pytest.raises(ConfigError, match=r"rig\.toml: experimental\[0\]\.model: cantilever: .*floating-point range"):
        parse_structure(data, "rig.toml")


def test_a_list_of_one_damping_ratio_is_that_ratio_on_every_anchor_mode():
    """zeta = [z] (a list of one) means z, for Rayleigh damping's two modes as for modal damping's
    every mode: it loads, never an error without the file's name."""
    for damping in ({"kind": "rayleigh", "zeta": [0.05], "modes": [1, 3]}, {"kind": "modal", "zeta": [0.05]}):
        doc = copy.deepcopy(DOCUMENTS["three_storey.toml"])
        doc["damping"] = damping
        structure = structure_from_tables(doc, "three_storey.toml")
        assert structure.damping.zeta == 0.05
