"""The --faults SPEC of `hsio emulate` (docs/faults.md): an empty SPEC or an empty item is refused,
naming --faults, and every refusal quotes the item as it was given."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

import hsio.commands.emulate as emulate_command
from hsio.cli import main
from hsio.emulators.faults import RECOVERABLE, parse
from hsio.errors import ConfigError


@pytest.mark.parametrize("spec, words", [
    ("", "--faults '': empty SPEC"),
    ("  ", "--faults '  ': empty SPEC"),
    (",,,", "--faults ',,,': item 1 is empty"),
    ("drop@10,", "--faults 'drop@10,': item 2 is empty"),
    ("drop@10,,spike@20", "--faults 'drop@10,,spike@20': item 2 is empty"),
    ("seed=7,every=0", "--faults 'every=0': 0 is not in 10.."),
    ("seed=7, every = 0", "--faults 'every = 0': 0 is not in 10.."),
    ("seed=x", "--faults 'seed=x': 'x' is not a whole number"),
    ("until=0", "--faults 'until=0': 0 is not in 1.."),
    ("seed=1,seed=2", "--faults 'seed=2': seed is given twice (also 'seed=1')"),
    ("kinds=drop+bogus", "--faults 'kinds=drop+bogus': unknown fault(s) 'bogus'"),
    ("kinds=drop++corrupt", "--faults 'kinds=drop++corrupt': an empty kind"),
    ("kinds=", "--faults 'kinds=': no kind given"),
    # a random schedule beyond the cap on faults is refused, not cut short at its 100,000th fault
    ("seed=1,every=10", "--faults: a fault every 10 ticks up to tick 10000000 is more than 100000 faults"),
    ("seed=1,every=100,until=20000000", "a larger every= or a smaller until="),
])
def test_a_bad_spec_is_refused_quoting_the_item_as_given(spec, words):
    with pytest.raises(ConfigError) as exc:
        parse(spec)
    assert words in str(exc.value)


def test_good_specs_still_parse():
    assert [(f.kind, f.tick, f.arg) for f in parse("drop@3000, spike@5000:40").faults] == [
        ("drop", 3000, 0.0), ("spike", 5000, 40.0)]
    schedule = parse("seed=7,every=2000,until=20000")
    assert schedule.faults and {f.kind for f in schedule.faults} <= set(RECOVERABLE)
    assert all(f.tick <= 20000 for f in schedule.faults)


@pytest.mark.parametrize("spec, words", [("", "empty SPEC"), (",,,", "item 1 is empty")])
def test_emulate_refuses_an_empty_spec_before_it_serves(monkeypatch, spec, words):
    monkeypatch.setattr(emulate_command, "bank_from_config", lambda *a, **k: pytest.fail("the emulator was built"))
    result = CliRunner().invoke(main, ["emulate", "modbus", "--port", "0", "--faults", spec])
    assert result.exit_code == 2, result.output
    assert f"--faults {spec!r}: {words}" in result.output
