"""The [integrator] keys of mixed control and the [emulator] instrument keys in `hsio run` configs
(docs/force_control.md, "Running it")."""

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from hsio.api import make_integrator
from hsio.cli import main
from hsio.config import DEFAULTS, IMPLICIT_OPTIONS, MIXED_GUARDS, from_dict, load
from hsio.errors import ConfigError
from hsio.integrators import SwitchingRule
from hsio.structures import get_structure

MIXED = {"method": "mixed", "switch_rule": "instruments", "switch_margin": 3.0, "switch_hysteresis": 2.0,
         "fc_blend": 0.01, "fc_fallback_after": 2, "refractory_steps": 1000, "no_fc_at_reversal": True,
         "explored_fraction": 0.9, "fc_force_limit_kN": 30.0, "anchor_dc": True, "blend_dc": True}
INSTRUMENTS = {"resolution_mm": 0.025, "noise_mm": 0.01, "force_resolution_kN": 0.01, "force_noise_kN": 0.01,
               "force_bandwidth_hz": 200.0, "displacement_bandwidth_hz": 200.0}


def _toml(tables: dict) -> str:
    lines = []
    for name, values in tables.items():
        lines.append(f"[{name}]")
        for key, value in values.items():
            text = json.dumps(value) if not isinstance(value, bool) else str(value).lower()
            lines.append(f"{key} = {text}")
    return "\n".join(lines) + "\n"


def _run(tmp_path, integrator: dict, emulator: dict | None = None, name: str = "c.toml"):
    tables = {"structure": {"name": "structure_II_infill"},
              "record": {"synthetic_duration_s": 0.25, "pga_g": 0.15},
              "test": {"rate": 10.0}, "integrator": integrator, "output": {"plots": False}}
    if emulator:
        tables["emulator"] = emulator
    cfg = tmp_path / name
    cfg.write_text(_toml(tables))
    return CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / (name + ".out"))])


def test_every_key_runs_and_reaches_the_integrator(tmp_path):
    out = _run(tmp_path, MIXED, INSTRUMENTS)
    assert out.exit_code == 0, out.output
    summary = json.loads((tmp_path / "c.toml.out" / "summary.json").read_text())
    # K_f = c s_F / s_u, s = sqrt(noise^2 + resolution^2 / 12): 3 x 0.010408 / 0.012333, K_d = K_f / 2,
    # per element (BF, IF); this 0.25 s record cracks the infill in NS (0.61 mm against 0.49 mm),
    # so no element goes to FC (upper thresholds None)
    s_F, s_u = (0.01**2 + 0.01**2 / 12) ** 0.5, (0.01**2 + 0.025**2 / 12) ** 0.5
    assert summary["thresholds"]["upper"] == [None, None]
    assert summary["thresholds"]["lower"] == pytest.approx([1.5 * s_F / s_u] * 2)
    assert summary["method"] == "mixed"


def test_a_wall_that_ns_finds_hysteretic_never_goes_to_fc(tmp_path):
    """Structure I's pinched wood wall with a 0.001 kN load cell: the instruments alone would put
    it in FC (K_f = 0.03 x 0.00104 / 0.0123 = 0.0025 kN/mm, below its 2.6), but NS finds it dissipating
    energy, so its K_f is infinite (null) and no step runs in FC, with [output] ns and the dry run
    both off (the rule computes NS itself)."""
    tables = {"structure": {"name": "structure_I"}, "record": {"synthetic_duration_s": 0.5},
              "test": {"rate": 10.0}, "output": {"plots": True, "ns": False}, "safety": {"dry_run": False},
              "integrator": {"method": "mixed", "switch_rule": "instruments"},
              "emulator": {"force_resolution_kN": 0.001, "force_noise_kN": 0.001}}
    cfg = tmp_path / "wall.toml"
    cfg.write_text(_toml(tables))
    out = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "wall")])
    assert out.exit_code == 0, out.output
    summary = json.loads((tmp_path / "wall" / "summary.json").read_text())
    assert summary["thresholds"]["upper"] == [None]
    assert summary["fc_step_fraction"] == [0.0] and summary["switches"] == 0
    assert (tmp_path / "wall" / "modes.png").stat().st_size > 0  # drawn without a K_f line
    tables["integrator"]["switch_max_hysteretic_ratio"] = 0.0  # the gate off: the instruments put it in FC
    cfg.write_text(_toml(tables))
    out = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "ungated")])
    summary = json.loads((tmp_path / "ungated" / "summary.json").read_text())
    assert summary["thresholds"]["upper"][0] == pytest.approx(0.03 * (0.001**2 * 13 / 12) ** 0.5 / (0.01**2 + 0.025**2 / 12) ** 0.5)
    assert summary["fc_step_fraction"][0] > 0


def test_the_integrator_gets_the_guards():
    from hsio.api import run_numerical
    from hsio.ground_motion import synthetic_record
    from hsio.runner import integrator_options
    from hsio.structures import get_structure

    structure = get_structure("structure_II_infill")
    elastic = run_numerical(structure, synthetic_record(duration_s=2.0, dt=structure.dt, pga_g=0.05, seed=1994))
    cfg = from_dict({"structure": {"name": "structure_II_infill"}, "integrator": MIXED,
                     "emulator": {"resolution_mm": 0.0025, "force_resolution_kN": 0.02}})
    options = integrator_options(cfg, structure, elastic)
    assert options["fallback_after"] == 2 and options["refractory_steps"] == 1000 and options["no_fc_at_reversal"]
    assert options["fc_blend"] == 0.01 and options["explored_fraction"] == 0.9 and options["fc_force_limit"] == 30.0
    assert options["anchor_dc"] and options["blend_dc"]
    # from the [emulator] instruments: resolutions as given, the noises the emulator's defaults
    # (0.01 mm, 0.002 kN); c = 3 from MIXED
    s_u, s_F = (0.01**2 + 0.0025**2 / 12) ** 0.5, (0.002**2 + 0.02**2 / 12) ** 0.5
    assert options["rule"].upper.tolist() == pytest.approx([3 * s_F / s_u] * 2)
    explicit = from_dict({"integrator": {**MIXED, "switch_resolution_mm": 0.01, "switch_force_resolution_kN": 0.1,
                                         "switch_noise_mm": 0.02, "switch_force_noise_kN": 0.05},
                          "structure": {"name": "structure_II_infill"}})
    rule = integrator_options(explicit, structure, elastic)["rule"]
    K_f = 3 * (0.05**2 + 0.1**2 / 12) ** 0.5 / (0.02**2 + 0.01**2 / 12) ** 0.5
    assert rule.upper.tolist() == pytest.approx([K_f] * 2) and rule.lower.tolist() == pytest.approx([K_f / 2] * 2)
    with pytest.raises(ConfigError, match="needs the NS prediction"):
        integrator_options(cfg, structure)


@pytest.mark.parametrize("key, value, says", [
    ("switch_rule", "magic", "switch_rule must be"),
    ("switch_margin", 0.0, "switch_margin = 0.0 is out of bounds"),
    ("switch_hysteresis", 1.0, "switch_hysteresis = 1.0 is out of bounds"),
    ("switch_resolution_mm", -0.1, "switch_resolution_mm = -0.1 is out of bounds"),
    ("switch_force_resolution_kN", 1000.0, "switch_force_resolution_kN = 1000.0 is out of bounds"),
    ("fc_blend", 0.0, "fc_blend = 0.0 is out of bounds"),
    ("fc_blend", 1.5, "fc_blend = 1.5 is out of bounds"),
    ("fc_fallback_after", 4, "fc_fallback_after (4) must be below j_max (3)"),
    ("fc_fallback_after", 3, "fc_fallback_after (3) must be below j_max (3)"),  # no command left for DC
    ("fc_fallback_after", 1.5, "fc_fallback_after must be a whole number"),
    ("refractory_steps", -1, "refractory_steps = -1 is out of bounds"),
    ("no_fc_at_reversal", 1, "no_fc_at_reversal must be true or false"),
    ("explored_fraction", 1.5, "explored_fraction = 1.5 is out of bounds"),
    ("fc_force_limit_kN", -5.0, "fc_force_limit_kN = -5.0 is out of bounds"),
    ("anchor_dc", "yes", "anchor_dc must be true or false"),
    ("blend_dc", 0, "blend_dc must be true or false"),
    ("switch_noise_mm", -0.01, "switch_noise_mm = -0.01 is out of bounds"),
    ("switch_force_noise_kN", 1e3, "switch_force_noise_kN = 1000.0 is out of bounds"),
    ("switch_max_hysteretic_ratio", -0.1, "switch_max_hysteretic_ratio = -0.1 is out of bounds"),
])
def test_bad_integrator_values_exit_2_naming_the_key(tmp_path, key, value, says):
    out = _run(tmp_path, {**MIXED, "blend_dc": False, key: value})
    assert out.exit_code == 2, out.output
    assert "[integrator]" in out.output and says in out.output


@pytest.mark.parametrize("key", ["resolution_mm", "noise_mm", "force_resolution_kN", "force_noise_kN",
                                 "force_bandwidth_hz", "displacement_bandwidth_hz"])
@pytest.mark.parametrize("value", [-1.0, 1e4])
def test_bad_instrument_values_exit_2_naming_the_key(tmp_path, key, value):
    out = _run(tmp_path, {"method": "implicit_dc"}, {key: value})
    assert out.exit_code == 2, out.output
    assert "[emulator]" in out.output and key in out.output


def test_guards_of_mixed_are_refused_with_other_methods():
    with pytest.raises(ConfigError, match=r"\[integrator\] no_fc_at_reversal applies to method = 'mixed'"):
        from_dict({"integrator": {"method": "implicit_dc", "no_fc_at_reversal": True}})
    with pytest.raises(ConfigError, match=r"fc_blend applies to the implicit methods"):
        from_dict({"integrator": {"fc_blend": 0.5}})
    with pytest.raises(ConfigError, match=r"blend_dc needs fc_blend below 1"):
        from_dict({"integrator": {"method": "mixed", "blend_dc": True, "fc_blend": 1.0}})
    for anchor in (True, False):  # alpha-OS has no secant line to anchor: either value is accepted
        assert from_dict({"integrator": {"anchor_dc": anchor}})["integrator"]["anchor_dc"] is anchor
    with pytest.raises(ConfigError, match=r"K_f is not read with switch_rule = 'instruments'"):
        from_dict({"integrator": {"method": "mixed", "switch_rule": "instruments", "K_f": 5.0}})
    with pytest.raises(ConfigError, match=r"on real hardware needs the transducer's switch_resolution_mm or "
                                          r"switch_noise_mm and the load cell's"):
        from_dict({"integrator": {"method": "mixed", "switch_rule": "instruments"},
                   "hardware": {"url": "modbus+tcp://127.0.0.1:1502"}})
    with pytest.raises(ConfigError, match=r"on real hardware needs the load cell's switch_force_resolution_kN "
                                          r"or switch_force_noise_kN \("):  # no load cell
        from_dict({"integrator": {"method": "mixed", "switch_rule": "instruments", "switch_resolution_mm": 0.025},
                   "hardware": {"url": "modbus+tcp://127.0.0.1:1502"}})
    noise_only = from_dict({"integrator": {"method": "mixed", "switch_rule": "instruments", "switch_noise_mm": 0.01,
                                           "switch_force_noise_kN": 0.01},
                            "hardware": {"url": "modbus+tcp://127.0.0.1:1502"}})  # a noise alone prices it
    assert noise_only["integrator"]["switch_noise_mm"] == 0.01


# The keys that only mixed control reads (its guards and switching rule); each left at its default is off.
MIXED_ONLY = MIXED_GUARDS + ("switch_on", "switch_rule", "switch_margin", "switch_hysteresis", "switch_resolution_mm",
                             "switch_force_resolution_kN", "switch_noise_mm", "switch_force_noise_kN",
                             "switch_max_hysteretic_ratio", "K_f", "K_d", "R_f", "R_d")


@pytest.mark.parametrize("method", ["alpha_os", "implicit_dc", "force_control"])
def test_every_mixed_key_written_at_its_default_loads_with_another_method(tmp_path, method):
    """A configuration that spells out every key of mixed control and of the implicit methods at
    its default (as TOML types it) loads with any method."""
    path = tmp_path / "c.toml"
    path.write_text(_toml({"integrator": {"method": method,
                                          **{k: DEFAULTS["integrator"][k] for k in MIXED_ONLY + IMPLICIT_OPTIONS}}}))
    cfg = load(path)
    assert cfg["integrator"] == {**DEFAULTS["integrator"], "method": method}


ON = {"fc_fallback_after": 1, "refractory_steps": 1, "no_fc_at_reversal": True, "explored_fraction": 0.5,
      "fc_force_limit_kN": 1e-3, "fc_blend": 0.5, "anchor_dc": True, "blend_dc": True}


@pytest.mark.parametrize("key", MIXED_GUARDS)
def test_each_guard_switched_on_with_implicit_dc_exits_2_naming_it(tmp_path, key):
    says = f"[integrator] {key} applies to method = 'mixed', not to 'implicit_dc'"
    with pytest.raises(ConfigError, match=re.escape(says)):
        from_dict({"integrator": {"method": "implicit_dc", key: ON[key]}})
    out = _run(tmp_path, {"method": "implicit_dc", key: ON[key]})
    assert out.exit_code == 2 and says in out.output and "Traceback" not in out.output, out.output
    from_dict({"integrator": {"method": "mixed", key: ON[key]}})  # where it is read, it is taken


@pytest.mark.parametrize("key", [k for k in IMPLICIT_OPTIONS if k != "anchor_dc"])  # alpha-OS anchors nothing
def test_each_implicit_option_switched_on_with_alpha_os_exits_2_naming_it(tmp_path, key):
    says = f"[integrator] {key} applies to the implicit methods, not to 'alpha_os'"
    out = _run(tmp_path, {"method": "alpha_os", key: ON[key]})
    assert out.exit_code == 2 and says in out.output, out.output


def test_a_guard_is_off_at_its_default_in_DEFAULTS(monkeypatch):
    """The off value of a guard is its entry in DEFAULTS, the one source of the defaults: moved
    there, the check follows it."""
    monkeypatch.setitem(DEFAULTS["integrator"], "refractory_steps", 5)
    monkeypatch.setitem(DEFAULTS["integrator"], "fc_blend", 0.5)
    assert from_dict({"integrator": {"method": "implicit_dc"}})["integrator"]["refractory_steps"] == 5
    from_dict({"integrator": {"method": "implicit_dc", "refractory_steps": 5}})
    with pytest.raises(ConfigError, match=r"refractory_steps applies to method = 'mixed'"):
        from_dict({"integrator": {"method": "implicit_dc", "refractory_steps": 0}})
    from_dict({"integrator": {"method": "alpha_os", "fc_blend": 0.5}})
    with pytest.raises(ConfigError, match=r"fc_blend applies to the implicit methods"):
        from_dict({"integrator": {"method": "alpha_os", "fc_blend": 1.0}})


def test_an_off_value_of_another_type_is_typed_by_the_default(tmp_path):
    """A whole number where the default is a real number is that number (0 for 0.0: off); a real
    number for a count, or a number for a switch, is refused by its type, not compared as equal
    (0.0 == 0 == False in Python)."""
    cfg = from_dict({"integrator": {"method": "implicit_dc", "explored_fraction": 0, "fc_force_limit_kN": 0}})
    assert type(cfg["integrator"]["explored_fraction"]) is float and type(cfg["integrator"]["fc_force_limit_kN"]) is float
    assert type(from_dict({"integrator": {"fc_blend": 1}})["integrator"]["fc_blend"]) is float
    for key, value, says in [("refractory_steps", 0.0, "refractory_steps must be a whole number"),
                             ("fc_fallback_after", 0.0, "fc_fallback_after must be a whole number"),
                             ("refractory_steps", False, "refractory_steps must be a number"),
                             ("no_fc_at_reversal", 0, "no_fc_at_reversal must be true or false"),
                             ("anchor_dc", 0, "anchor_dc must be true or false")]:
        with pytest.raises(ConfigError, match=re.escape(f"[integrator]: {key}")) as info:
            from_dict({"integrator": {"method": "implicit_dc", key: value}})
        assert says in str(info.value)
        out = _run(tmp_path, {"method": "implicit_dc", key: value}, name=f"{key}-{value}.toml")
        assert out.exit_code == 2 and says in out.output, out.output


@pytest.mark.parametrize("integrator, says", [
    ({"method": "implicit_dc", "switch_margin": 10.0}, "switch_margin applies to method = 'mixed', not to 'implicit_dc'"),
    ({"method": "alpha_os", "switch_hysteresis": 5.0}, "switch_hysteresis applies to method = 'mixed', not to 'alpha_os'"),
    ({"method": "force_control", "switch_resolution_mm": 0.5}, "switch_resolution_mm applies to method = 'mixed'"),
    ({"method": "implicit_dc", "K_f": 3.0}, "K_f applies to method = 'mixed'"),
    ({"method": "implicit_dc", "switch_rule": "instruments"}, "switch_rule applies to method = 'mixed'"),
    ({"method": "mixed", "switch_rule": "initial_stiffness", "switch_margin": 10.0},
     "switch_margin applies to switch_rule = 'instruments', not to 'initial_stiffness'"),
    ({"method": "mixed", "K_f": 3.0, "switch_hysteresis": 5.0}, "switch_hysteresis applies to switch_rule = 'instruments'"),
    ({"method": "mixed", "switch_rule": "initial_stiffness", "switch_resolution_mm": 0.5,
      "switch_force_resolution_kN": 1.0}, "switch_resolution_mm applies to switch_rule = 'instruments'"),
    ({"method": "mixed", "R_f": 5.0, "switch_on": "force", "switch_force_resolution_kN": 1.0},
     "switch_force_resolution_kN applies to switch_rule"),
    ({"method": "mixed", "switch_rule": "instruments", "R_f": 5.0}, "R_f is not read with switch_rule = 'instruments'"),
    ({"method": "mixed", "switch_rule": "instruments", "R_d": 1.0}, "R_d is not read with switch_rule = 'instruments'"),
    ({"method": "mixed", "R_f": 5.0}, "R_f applies to switch_on = 'force', not to 'stiffness'"),
    ({"method": "mixed", "switch_on": "force", "R_f": 5.0, "K_f": 3.0}, "K_f applies to switch_on = 'stiffness'"),
    # the key to change, not R_f, which the instruments rule would refuse next
    ({"method": "mixed", "switch_rule": "instruments", "switch_on": "force"},
     "switch_rule = 'instruments' switches on the stiffness: leave switch_on = 'stiffness'"),
])
def test_switching_keys_no_rule_reads_exit_2_naming_the_key(tmp_path, integrator, says):
    """docs/force_control.md: the switching keys apply to mixed only, each to the rule that reads
    it; one given where nothing reads it is refused, not ignored."""
    with pytest.raises(ConfigError, match=re.escape(says)):
        from_dict({"integrator": integrator})
    out = _run(tmp_path, integrator)
    assert out.exit_code == 2, out.output
    assert "[integrator]" in out.output and says in out.output


def test_switching_keys_where_read_are_accepted():
    from_dict({"integrator": {"method": "mixed", "switch_on": "force", "R_f": 5.0, "R_d": 2.0}})
    from_dict({"integrator": {"method": "mixed", "K_f": 3.0, "K_d": 2.0}})
    from_dict({"integrator": {**MIXED, "switch_margin": 5.0, "switch_hysteresis": 3.0, "switch_resolution_mm": 0.01,
                              "switch_force_resolution_kN": 0.1}})


@pytest.mark.parametrize("method, option, value", [
    ("implicit_dc", "no_fc_at_reversal", True), ("implicit_dc", "fallback_after", 1),
    ("implicit_dc", "refractory_steps", 1), ("force_control", "refractory_steps", True),
    ("implicit_dc", "explored_fraction", 1.0), ("implicit_dc", "fc_force_limit", 1),
    ("alpha_os", "blend_dc", True),
    ("alpha_os", "fc_blend", 0.5), ("alpha_os", "fc_blend", True),
])
def test_make_integrator_refuses_an_option_the_method_does_not_take(method, option, value):
    """A switched-on option is refused by name, never dropped, even where it equals 1 (True == 1 == 1.0)."""
    with pytest.raises(ConfigError, match=rf"^{option}: not an option of method = '{method}'"):
        make_integrator(get_structure("structure_II_infill"), method, **{option: value})


def test_mixed_without_thresholds_of_its_own_runs_the_study_recipe():
    """method = "mixed" alone: K_f, K_d from the instruments with the NS gate and the guards of
    `hsio study mixed`; any key given is kept; thresholds given keep the K^EI rule, guards off."""
    from hsio.config import MIXED_RECIPE

    i = from_dict({"integrator": {"method": "mixed"}})["integrator"]
    assert {k: i[k] for k in MIXED_RECIPE} == MIXED_RECIPE and i["switch_rule"] == "instruments"
    assert i["switch_max_hysteretic_ratio"] == 0.1
    i = from_dict({"integrator": {"method": "mixed", "fc_blend": 0.2, "switch_margin": 3.0}})["integrator"]
    assert i["fc_blend"] == 0.2 and i["switch_margin"] == 3.0 and i["switch_rule"] == "instruments"
    for own in ({"K_f": 3.0}, {"switch_on": "force", "R_f": 5.0}, {"switch_rule": "initial_stiffness"}):
        i = from_dict({"integrator": {"method": "mixed", **own}})["integrator"]
        assert i["switch_rule"] == "initial_stiffness" and i["fc_blend"] == 1.0 and i["refractory_steps"] == 0
    i = from_dict({"integrator": {"method": "mixed", "switch_rule": "instruments", "j_max": 1}})["integrator"]
    assert i["no_fc_at_reversal"] is True and i["fc_fallback_after"] == 0  # below j_max: off with one command
    i = from_dict({"integrator": {"method": "mixed", "switch_rule": "instruments", "j_max": 2}})["integrator"]
    assert i["fc_fallback_after"] == 1
    assert from_dict({"integrator": {"method": "implicit_dc"}})["integrator"]["fc_blend"] == 1.0
    with pytest.raises(ConfigError, match=r"the rule of method = 'mixed' without thresholds of its own\) on real "
                                          r"hardware needs the transducer's"):
        from_dict({"integrator": {"method": "mixed"}, "hardware": {"url": "modbus+tcp://127.0.0.1:1502"}})


def test_anchor_dc_is_checked_on_by_default_and_may_be_given_per_element_in_mixed():
    structure = get_structure("structure_II_infill")
    for bad in (1, "yes", [True], ["no", "no"], [1, 0]):
        with pytest.raises(ConfigError, match="anchor_dc must be True or False"):
            make_integrator(structure, "implicit_dc", anchor_dc=bad)
    assert make_integrator(structure, "implicit_dc").core.anchor_dc.tolist() == [True, True]
    assert make_integrator(structure, "implicit_dc", anchor_dc=False).core.anchor_dc.tolist() == [False, False]
    assert make_integrator(structure, "implicit_dc", anchor_dc=[False, True]).core.anchor_dc.tolist() == [False, True]
    kept = SwitchingRule([3.0, np.inf], [1.5, 1.5])  # the infill kept in DC, the frame free to switch
    assert make_integrator(structure, "mixed", rule=kept).core.anchor_dc.tolist() == [True, True]
    assert make_integrator(structure, "mixed", rule=kept, anchor_dc=[True, False]).core.anchor_dc.tolist() == [True, False]


def test_make_integrator_accepts_an_option_left_off():
    structure = get_structure("structure_II_infill")
    make_integrator(structure, "alpha_os", fc_blend=1.0, anchor_dc=False, blend_dc=None, no_fc_at_reversal=False,
                    fallback_after=None, refractory_steps=0, explored_fraction=0.0, fc_force_limit=None)
    integrator = make_integrator(structure, "mixed", fallback_after=1, no_fc_at_reversal=True)
    assert integrator.fallback_after == 1 and integrator.no_fc_at_reversal is True


@pytest.mark.parametrize("name", ["column_two_actuators"])
def test_an_implicit_method_on_setups_is_refused_before_the_run_folder(tmp_path, name):
    """The implicit methods iterate on one actuator's secant per element: a structure with setups
    is refused naming the method, before anything is created or opened (a static preload is not:
    tests/test_preload.py)."""
    cfg = tmp_path / "c.toml"
    cfg.write_text(_toml({"structure": {"name": name}, "integrator": {"method": "mixed"},
                          "output": {"plots": False}}))
    out = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "o")])
    assert out.exit_code == 2, out.output
    assert "method = 'mixed'" in out.output and "alpha_os" in out.output
    assert not (tmp_path / "o").exists()
    out = CliRunner().invoke(main, ["run", str(cfg), "--monitor", "--monitor-port", "0", "--out", str(tmp_path / "m")])
    assert out.exit_code == 2 and not (tmp_path / "m").exists()  # no page, no folder
    checked = CliRunner().invoke(main, ["check", str(cfg)])
    assert checked.exit_code == 2 and "alpha_os" in checked.output


@pytest.mark.parametrize("method", ["implicit_dc", "force_control", "mixed"])
def test_an_implicit_method_on_nonlinear_numerical_elements_is_refused_before_the_run_folder(tmp_path, method):
    """The secant model of eq. (9) covers the experimental elements only: a structure with a
    nonlinear numerical element is refused naming the configuration, the method and the element,
    before the dry run and before anything is created; `hsio check` says the same."""
    (tmp_path / "s.toml").write_text(
        '[structure]\nname = "nl"\ndt = 0.01\n[[dof]]\nname = "a"\nmass = 0.01\n[[dof]]\nname = "b"\n'
        'mass = 0.01\n[[numerical]]\nname = "brace"\ndof = "a"\nto = "b"\n'
        'model = { kind = "peak_oriented", k0 = 5.0, Fy = 20.0, u_c = 10.0 }\n'
        '[[experimental]]\ndof = "a"\nmodel = { kind = "linear", k = 3.0 }\n'
        '[[experimental]]\ndof = "b"\nmodel = { kind = "linear", k = 3.0 }\n')
    cfg = tmp_path / "c.toml"
    cfg.write_text(_toml({"structure": {"file": "s.toml"}, "record": {"synthetic_duration_s": 0.2},
                          "integrator": {"method": method}, "output": {"plots": False}}))
    out = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "o")])
    assert out.exit_code == 2, out.output
    says = f"{cfg}: [integrator] method = {method!r} takes linear numerical elements only"
    assert says in out.output and "(brace)" in out.output and "dry run" not in out.output
    assert not (tmp_path / "o").exists()
    checked = CliRunner().invoke(main, ["check", str(cfg)])
    assert checked.exit_code == 2 and says in checked.output


def test_mixed_on_instruments_without_resolution_or_noise_is_refused_before_the_run_folder(tmp_path):
    """The instruments rule cannot set K_f from a transducer and a load cell that read exactly:
    refused naming the keys, before the dry run and before anything is created."""
    cfg = tmp_path / "c.toml"
    cfg.write_text(_toml({"structure": {"name": "structure_II"}, "record": {"synthetic_duration_s": 0.2},
                          "integrator": {"method": "mixed"},
                          "emulator": {"resolution_mm": 0.0, "noise_mm": 0.0, "force_resolution_kN": 0.0,
                                       "force_noise_kN": 0.0},
                          "output": {"plots": False}}))
    out = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "o")])
    assert out.exit_code == 2, out.output
    assert "switch_resolution_mm" in out.output and "dry run" not in out.output
    assert not (tmp_path / "o").exists()


def test_a_server_that_never_integrates_is_not_refused_for_the_method():
    """hsio serve opensees reads the structure of a configuration whose [integrator] it ignores."""
    from hsio.config import from_dict
    from hsio.runner import load_run_structure

    cfg = from_dict({"structure": {"name": "column_two_actuators"}, "integrator": {"method": "mixed"}})
    assert load_run_structure(cfg).name == "column_two_actuators"


@pytest.mark.parametrize("pga, says", [
    (0.05, ["NS predicts every element elastic", "BF           to FC above 0.02532 kN/mm, back to DC below 0.01266 kN/mm"]),
    (0.2, ["NS predicts IF dissipating energy or off the K^EI line: every element stays in DC", "IF           DC throughout"]),
])
def test_check_says_what_mixed_control_will_do(tmp_path, pga, says):
    """`hsio check` shows the switching rule of a mixed run: the thresholds (here from the
    emulator's instruments: 0.03 x 0.0104 / 0.0123 kN/mm) and what the NS gate read."""
    cfg = tmp_path / "c.toml"
    cfg.write_text(_toml({"structure": {"name": "structure_II_infill"},
                          "record": {"synthetic_duration_s": 2.0, "pga_g": pga},
                          "integrator": {"method": "mixed"}, "emulator": INSTRUMENTS}))
    out = CliRunner().invoke(main, ["check", str(cfg)])
    assert out.exit_code == 0, out.output
    assert "switching      mixed, rule 'instruments' on the stiffness" in out.output
    for line in says:
        assert line in out.output, out.output
    data = json.loads(CliRunner().invoke(main, ["check", "--json", str(cfg)]).output)
    assert data["switching"]["ns_elastic"]["IF"] is (pga == 0.05)
    assert (data["switching"]["elements"]["IF"]["upper"] is None) is (pga == 0.2)


@pytest.mark.parametrize("integrator, says", [
    ({"method": "mixed", "K_f": 5.0}, "element BF: K_d = 5.76 kN/mm must be below K_f = 5 kN/mm"),
    ({"method": "mixed", "K_d": 200.0}, "element BF: K_d = 200 kN/mm must be below K_f = 8.64 kN/mm"),
    ({"method": "mixed", "K_f": 3.0, "K_d": 4.0}, "K_d (4.0) must be below K_f (3.0)"),
])
def test_crossed_stiffness_thresholds_exit_2_before_the_actuators_open(tmp_path, integrator, says):
    """K_f given alone below 0.8 K^EI (the default K_d), or K_d alone above 1.2 K^EI: refused with
    the element and both values, and what the missing one defaults to, naming the file, before
    the dry run and before the run folder is created (no "actuators stand at"); `hsio check`
    says the same."""
    out = _run(tmp_path, integrator)
    assert out.exit_code == 2, out.output
    assert says in out.output and f"{tmp_path / 'c.toml'}: [integrator]" in out.output
    assert "stand at" not in out.output and "dry run" not in out.output
    assert not list(tmp_path.glob("*.out"))
    if len(integrator) == 2:
        missing = "K_d = 0.8 K^EI" if "K_f" in integrator else "K_f = 1.2 K^EI"
        assert missing in out.output
    cfg = tmp_path / "c.toml"
    checked = CliRunner().invoke(main, ["check", str(cfg)])
    assert checked.exit_code == 2 and says in checked.output


def test_fc_share_is_given_per_actuator_channel_not_per_dof():
    """structure_II_infill has three DOFs (BF, IF, the numerical BF_mirror) and two actuators:
    the share of steps in FC is one number per actuator, beside the per-channel tracking RMS."""
    from hsio.api import run_numerical
    from hsio.ground_motion import synthetic_record
    from hsio.runner import implicit_summary
    from hsio.structures import get_structure

    structure = get_structure("structure_II_infill")
    ns = run_numerical(structure, synthetic_record(duration_s=0.05, dt=structure.dt, seed=1), "mixed")
    summary = implicit_summary(ns)
    assert len(summary["fc_step_fraction"]) == len(summary["rms_tracking_error_mm"]) == 2


def test_force_control_gets_the_instruments_of_its_secant_rule():
    from hsio.runner import integrator_options
    from hsio.structures import get_structure

    structure = get_structure("structure_II_infill")
    emulated = from_dict({"structure": {"name": "structure_II_infill"}, "integrator": {"method": "force_control"},
                          "emulator": {"resolution_mm": 0.0025, "force_resolution_kN": 0.02}})
    # (noise, resolution) of the transducer and of the load cell: the emulator's noises 0.01 mm, 0.002 kN
    assert integrator_options(emulated, structure)["secant_uncertainty"] == ((0.01, 0.0025), (0.002, 0.02))
    # on hardware the instruments are not known to force control: every estimate is taken
    hardware = from_dict({"structure": {"name": "structure_II_infill"}, "integrator": {"method": "force_control"},
                          "hardware": {"url": "modbus+tcp://127.0.0.1:1502"}})
    assert integrator_options(hardware, structure)["secant_uncertainty"] is None
