"""Run configuration: a TOML file, checked key by key, with safe defaults.

Every table and key is optional; an unknown table or key, a wrong type or a value out of range
raises :class:`~hsio.errors.ConfigError` naming the file, the table and the key. See
docs/config.md for the whole list.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from hsio.errors import ConfigError
from hsio.files import read_bounded
from hsio.safety.settings import DEFAULTS as SAFETY_DEFAULTS
from hsio.safety.settings import check_table as check_safety_table

DEFAULTS: dict[str, dict] = {
    "structure": {"name": "validation", "file": ""},
    "record": {"file": "", "scale": 1.0, "duration_s": 0.0, "pga_g": 0.6, "seed": 1994, "synthetic_duration_s": 20.0,
               "dt_s": 0.0, "units": ""},
    "integrator": {"alpha": -0.05, "method": "alpha_os", "j_max": 3, "tol_displacement_mm": 0.02, "tol_force_kN": 0.05,
                   "secant": "average", "secant_n_avg": 16, "secant_min_increment_mm": 0.1,
                   "switch_on": "stiffness", "K_f": 0.0, "K_d": 0.0, "R_f": 0.0, "R_d": 0.0,
                   # mixed control (docs/force_control.md, "Running it"): where K_f / K_d come from,
                   # and the guards of ImplicitMethod; the defaults are the behaviour without them
                   "switch_rule": "initial_stiffness", "switch_margin": 0.03, "switch_hysteresis": 2.0,
                   "switch_resolution_mm": 0.0, "switch_force_resolution_kN": 0.0, "switch_noise_mm": 0.0,
                   "switch_force_noise_kN": 0.0, "switch_max_hysteretic_ratio": 0.1,
                   "fc_blend": 1.0, "fc_fallback_after": 0, "refractory_steps": 0, "no_fc_at_reversal": False,
                   "explored_fraction": 0.0, "fc_force_limit_kN": 0.0, "anchor_dc": True, "blend_dc": False},
    "test": {"rate": 20.0, "hold_fraction": 0.5, "n_avg": 4, "measured_displacement_correction": True},
    "hardware": {"url": "emulator://", "clock": "lockstep", "actuator_model": ""},
    "output": {"samples": True, "plots": True, "ns": True},
    # Feed-forward error compensation (docs/compensation.md); estimator keys as in
    # hsio.compensation.online.EstimatorSettings.
    "compensation": {"mode": "off", "a_mm_s": 0.0, "b_s_mm": 0.0, "by_actuator": {}, "actuators": [], "form": "lead",
                     "d_max_mm": 254.0,
                     "window": 400, "update_every": 10, "min_samples": 40, "min_beyond": 20, "max_rel_std": 0.25,
                     "lag_max_s": 0.1, "a_max_mm_s": 50.0, "lag_step_s": 0.005, "a_step_mm_s": 2.0},
    # Safe lab sessions (docs/safety.md): the dry run, the interlocks, operator control; the
    # specimen ledger; [test] start (below) picks a start at rest or from where the specimen stands.
    "safety": dict(SAFETY_DEFAULTS),
    "specimen": {"id": "", "folder": ""},
}
DEFAULTS["test"]["start"] = "rest"
# The [emulator] table is passed to the emulated controller (hsio.emulators.servo.ServoConfig), which
# checks its own keys; [drivers] likewise goes to the driver named by hardware.url.
FREE_TABLES = ("emulator", "driver")


@dataclass
class RunConfig:
    """A checked configuration: ``tables[table][key]``, defaults filled in; ``given``: the keys
    the configuration wrote, per table (a default can then adapt where a key was left out)."""

    tables: dict = field(default_factory=dict)
    source: str = "<defaults>"
    given: dict = field(default_factory=dict)

    def __getitem__(self, table: str) -> dict:
        return self.tables[table]


def _check_type(where: str, key: str, value, default):
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: {key} must be true or false, got {value!r}")
        return value
    if isinstance(default, int) and not isinstance(value, bool) and isinstance(value, float):
        raise ConfigError(f"{where}: {key} must be a whole number, got {value!r}")
    if isinstance(default, (int, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: {key} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: {key} must be finite, got {value!r}")
        return type(default)(value) if isinstance(default, float) else value
    if isinstance(default, str) and not isinstance(value, str):
        raise ConfigError(f"{where}: {key} must be a string, got {value!r}")
    return value


def from_dict(data: dict, source: str = "<dict>", replay: bool = False) -> RunConfig:
    """Check ``data`` (tables of keys) and fill in the defaults. ``replay``: the configuration a run
    recorded (every key, as it ran), read back by resume and the error budget: keys that nothing
    reads are not refused there (a run recorded them, and the command line may have set some,
    e.g. --override-dry-run)."""
    tables = {name: dict(values) for name, values in DEFAULTS.items()}
    for free in FREE_TABLES:
        tables[free] = {}
    for name, values in data.items():
        if name not in tables:
            raise ConfigError(f"{source}: unknown table [{name}]; known: {', '.join(sorted(tables))}")
        if not isinstance(values, dict):
            raise ConfigError(f"{source}: [{name}] must be a table, got {values!r}")
        if name in FREE_TABLES:
            tables[name].update(values)
            continue
        for key, value in values.items():
            if key not in DEFAULTS[name]:
                raise ConfigError(f"{source}: unknown key {key!r} in [{name}]; known: {', '.join(DEFAULTS[name])}")
            tables[name][key] = _check_type(f"{source}: [{name}]", key, value, DEFAULTS[name][key])
    given = {name: set(values) for name, values in data.items() if isinstance(values, dict)}
    _mixed_defaults(tables["integrator"], given.get("integrator", set()))
    _check_ranges(tables, source)
    check_bounds(tables, source)
    if not replay:
        _check_unread(tables, source)
    return RunConfig(tables, source, given)


# Keys that only some settings read: given (away from their defaults) where nothing reads them,
# they are refused rather than silently ignored (docs/config.md).
SYNTHETIC_ONLY = ("pga_g", "seed", "synthetic_duration_s")
COLUMN_FILE_ONLY = ("dt_s", "units")  # a column file's; a PEER .AT2 header gives both
INTERLOCK_KEYS = ("following_error_mm", "following_error_kN", "following_time_s", "jump_mm", "jump_kN",
                  "warning_fraction", "force_drop_fraction", "force_drop_min_kN", "force_drop_window_s")
DRY_RUN_KEYS = ("override", "stroke_margin", "force_margin", "velocity_margin")


def _check_unread(t: dict, source: str) -> None:
    def changed(table: str, keys) -> list[str]:
        defaults = SAFETY_DEFAULTS if table == "safety" else DEFAULTS[table]
        return [k for k in keys if t[table][k] != defaults[k]]

    if t["record"]["file"]:
        unread = changed("record", SYNTHETIC_ONLY)
        if unread:
            raise ConfigError(f"{source}: [record] {', '.join(unread)}: not read with a record file "
                              f"({t['record']['file']}), only for the synthetic record; scale the file with "
                              f"[record] scale (a factor) and cut it with duration_s")
        if t["record"]["file"].lower().endswith(".at2"):
            unread = changed("record", COLUMN_FILE_ONLY)
            if unread:
                raise ConfigError(f"{source}: [record] {', '.join(unread)}: not read with a PEER .AT2 file "
                                  f"({t['record']['file']}): its header gives the time step and the units")
        elif not t["record"]["units"]:
            raise ConfigError(f"{source}: [record] units: a column record file ({t['record']['file']}) does not say "
                              f"its units; give them (g, m/s^2, cm/s^2, mm/s^2 or in/s^2): a file in cm/s^2 read "
                              f"as g would run 980 times too strong")
    else:
        unread = changed("record", COLUMN_FILE_ONLY)
        if unread:
            raise ConfigError(f"{source}: [record] {', '.join(unread)}: only read with a column record file "
                              f"([record] file); the synthetic record is in g at the structure's time step")
    if t["compensation"]["mode"] == "off":
        unread = changed("compensation", [k for k in DEFAULTS["compensation"] if k != "mode"])
        if unread:
            raise ConfigError(f"{source}: [compensation] {', '.join(unread)}: not read with mode = 'off' (no "
                              f"compensation); set mode = 'offline' or 'online', or remove them")
    if not t["safety"]["interlocks"]:
        unread = changed("safety", INTERLOCK_KEYS)
        if unread:
            raise ConfigError(f"{source}: [safety] {', '.join(unread)}: not read with interlocks = false (the "
                              f"interlocks off); remove them or turn the interlocks on")
    if not t["safety"]["dry_run"]:
        unread = changed("safety", DRY_RUN_KEYS)
        if unread:
            raise ConfigError(f"{source}: [safety] {', '.join(unread)}: not read with dry_run = false (no dry "
                              f"run); remove them or turn the dry run on")
    integ, off = t["integrator"], DEFAULTS["integrator"]
    for key, why in UNREAD_BY.get(integ["method"], {}).items():
        if integ[key] != off[key]:
            raise ConfigError(f"{source}: [integrator] {key} = {integ[key]!r} is not read by method = "
                              f"{integ['method']!r} ({why}); remove it, or choose a method that reads it")
    if integ["secant"] != "average" and integ["secant_n_avg"] != off["secant_n_avg"]:
        raise ConfigError(f"{source}: [integrator] secant_n_avg is read by secant = 'average' only, not by "
                          f"secant = {integ['secant']!r}; remove it, or set secant = 'average'")
    if integ["method"] == "implicit_dc" and integ["fc_blend"] != off["fc_blend"] and not integ["blend_dc"]:
        raise ConfigError(f"{source}: [integrator] fc_blend is not read by method = 'implicit_dc' (it sets the base of "
                          f"elements in FC, and there are none) unless blend_dc = true; remove it, or set blend_dc")
    method = t["integrator"]["method"]
    if method != "alpha_os" and not t["output"]["samples"]:
        raise ConfigError(f"{source}: [integrator] method = {method!r} estimates the secant stiffness (eq. 11) from "
                          f"the controller-rate samples, which [output] samples = false leaves out: set samples = "
                          f"true, or method = 'alpha_os'")


# Mixed control without thresholds of its own runs the recipe of `hsio study mixed`: K_f, K_d from
# the instruments, FC only while NS predicts every element elastic, the complementary estimate in
# FC, a non-converging FC step finished in DC and that element in DC for good, no switch to FC at
# a reversal (docs/force_control.md, "Running it"). Any of these keys given is kept as given;
# thresholds of its own (or switch_rule = "initial_stiffness") give the paper's rule, no guards.
MIXED_RECIPE = {"switch_rule": "instruments", "fc_blend": 0.01, "fc_fallback_after": 2, "refractory_steps": 10**9,
                "no_fc_at_reversal": True}
THRESHOLD_KEYS = ("switch_on", "K_f", "K_d", "R_f", "R_d")


def _mixed_defaults(integrator: dict, given: set) -> None:
    """``method = "mixed"`` with none of K_f, K_d, R_f, R_d, switch_on given and no switch_rule
    other than "instruments": the keys of MIXED_RECIPE that were not given take the recipe's
    values (the fallback below j_max commands, off with j_max = 1: it needs a command left for DC)."""
    own_rule = "switch_rule" in given and integrator["switch_rule"] != "instruments"
    if integrator["method"] != "mixed" or own_rule or given & set(THRESHOLD_KEYS):
        return
    for key, value in MIXED_RECIPE.items():
        if key not in given:
            integrator[key] = min(value, integrator["j_max"] - 1) if key == "fc_fallback_after" else value


# -- Sanity bounds (docs/faults.md) --------------------------------------------------------------
# Upper (and lower) bounds of the run's own quantities: beyond them a run would hang, exhaust
# memory or mean a typing error. (table, key) -> (low, high, unit). Checked after the types.
BOUNDS: dict[tuple[str, str], tuple[float, float, str]] = {
    ("test", "rate"): (1e-3, 1000.0, ""),
    ("test", "n_avg"): (1, 1024, "samples"),
    ("record", "synthetic_duration_s"): (0.0, 3600.0, "s"),
    ("record", "duration_s"): (0.0, 3600.0, "s"),
    ("record", "scale"): (-100.0, 100.0, ""),
    ("record", "pga_g"): (0.0, 10.0, "g"),
    ("record", "seed"): (0, 2**32 - 1, ""),
    ("record", "dt_s"): (0.0, 1.0, "s"),
    ("integrator", "j_max"): (1, 100, "iterations"),
    ("integrator", "secant_n_avg"): (1, 10000, "samples"),
    ("integrator", "tol_displacement_mm"): (0.0, 1000.0, "mm"),
    ("integrator", "tol_force_kN"): (0.0, 1e5, "kN"),
    ("integrator", "secant_min_increment_mm"): (0.0, 1000.0, "mm"),
    ("integrator", "switch_margin"): (0.01, 1000.0, ""),
    ("integrator", "switch_hysteresis"): (1.0001, 100.0, ""),
    ("integrator", "switch_resolution_mm"): (0.0, 10.0, "mm"),
    ("integrator", "switch_force_resolution_kN"): (0.0, 100.0, "kN"),
    ("integrator", "switch_noise_mm"): (0.0, 10.0, "mm"),
    ("integrator", "switch_force_noise_kN"): (0.0, 100.0, "kN"),
    ("integrator", "switch_max_hysteretic_ratio"): (0.0, 100.0, ""),
    ("integrator", "fc_blend"): (0.0001, 1.0, ""),
    ("integrator", "fc_fallback_after"): (0, 100, "commands"),
    ("integrator", "refractory_steps"): (0, 10**9, "steps"),
    ("integrator", "explored_fraction"): (0.0, 1.0, ""),
    ("integrator", "fc_force_limit_kN"): (0.0, 1e5, "kN"),
}


def check_bounds(tables: dict, source: str) -> None:
    """Every bounded key within its bounds; the error names the file, the table, the key and the bound."""
    for (table, key), (low, high, unit) in BOUNDS.items():
        value = tables[table][key]
        if not low <= value <= high:
            raise ConfigError(f"{source}: [{table}] {key} = {value!r} is out of bounds: it must be within "
                              f"{low:g}..{high:g}{' ' + unit if unit else ''}")


def _resolve_beside(config: "RunConfig", path: Path) -> None:
    """File names inside the configuration ([driver] map, eds, instrument_map) are relative to the
    configuration file."""
    for key in ("map", "eds", "instrument_map"):
        value = config["driver"].get(key)
        if isinstance(value, str) and value and not Path(value).is_absolute():
            config["driver"][key] = str((path.parent / value).resolve())


def _check_ranges(t: dict, source: str) -> None:
    alpha = t["integrator"]["alpha"]
    if not -1.0 / 3.0 - 1e-12 <= alpha <= 0.0:
        raise ConfigError(f"{source}: [integrator] alpha must be in [-1/3, 0], got {alpha}")
    _check_implicit(t["integrator"], source, t["hardware"]["url"])
    if not t["test"]["rate"] > 0:
        raise ConfigError(f"{source}: [test] rate (TR) must be positive, got {t['test']['rate']}")
    if not 0.0 <= t["test"]["hold_fraction"] < 1.0:
        raise ConfigError(f"{source}: [test] hold_fraction must be in [0, 1), got {t['test']['hold_fraction']}")
    if not t["test"]["n_avg"] >= 1:
        raise ConfigError(f"{source}: [test] n_avg must be at least 1, got {t['test']['n_avg']}")
    if t["hardware"]["clock"] not in ("lockstep", "realtime"):
        raise ConfigError(f"{source}: [hardware] clock must be 'lockstep' or 'realtime', got {t['hardware']['clock']!r}")
    record = t["record"]
    if record["scale"] == 0:
        raise ConfigError(f"{source}: [record] scale = 0 would run the record as zeros: nothing would load the "
                          f"structure; give a factor (negative reverses the direction)")
    if record["duration_s"] < 0:
        raise ConfigError(f"{source}: [record] duration_s must not be negative")
    for key in ("synthetic_duration_s", "pga_g"):
        if not record[key] > 0:
            raise ConfigError(f"{source}: [record] {key} must be positive, got {record[key]}")
    if record["seed"] < 0:
        raise ConfigError(f"{source}: [record] seed must not be negative, got {record['seed']}")
    if record["units"]:
        from hsio.ground_motion import UNITS_IN_G, unit_in_g

        if unit_in_g(record["units"]) is None:
            raise ConfigError(f"{source}: [record] units = {record['units']!r} is not an acceleration unit hsio "
                              f"knows: one of {', '.join(UNITS_IN_G)} (m/s^2, CM/S/S and the like are read too)")
    from hsio.hardware import check_options, check_url  # each backend checks its own table

    try:
        check_url(t["hardware"]["url"])
    except ConfigError as exc:
        raise ConfigError(f"{source}: [hardware] url {str(exc).removeprefix('hardware URL ')}") from None
    if t["hardware"]["url"].startswith("emulator"):
        try:
            check_options(t["hardware"]["url"], t["emulator"])
        except ConfigError as exc:
            raise ConfigError(f"{source}: [emulator] {str(exc).removeprefix('emulator: ')}") from None
    from hsio.compensation.stage import CompensationSettings

    CompensationSettings.from_table(t["compensation"], f"{source}: [compensation]")
    check_safety_table(t["safety"], f"{source}: [safety]")
    if t["test"]["start"] not in ("rest", "present"):
        raise ConfigError(f"{source}: [test] start must be 'rest' or 'present', got {t['test']['start']!r}")
    if t["compensation"]["mode"] == "offline" and t["test"]["hold_fraction"] > 0:
        raise ConfigError(f"{source}: [compensation] mode = 'offline' compensates continuous motion (a and b are "
                          f"calibrated on continuous ramps): set [test] hold_fraction = 0, or use mode = 'online'")


# Options of the implicit methods (hsio.integrators.ImplicitMethod) and the guards of mixed control
# (docs/force_control.md, "Running it"): a method that does not read one accepts it only at its
# default in DEFAULTS["integrator"], which leaves it off; a switched-on option is refused, never dropped.
IMPLICIT_OPTIONS = ("fc_blend", "anchor_dc", "blend_dc")
MIXED_GUARDS = ("fc_fallback_after", "refractory_steps", "no_fc_at_reversal", "explored_fraction", "fc_force_limit_kN")
KEYWORDS = {"fc_fallback_after": "fallback_after", "fc_force_limit_kN": "fc_force_limit"}  # of make_integrator, where they differ


# Keys of the implicit iteration that a method does not read: refused away from their defaults.
_ITERATION = "alpha-OS makes one trial per step: no iteration, no secant stiffness"
UNREAD_BY = {
    "alpha_os": {key: _ITERATION for key in ("j_max", "tol_displacement_mm", "tol_force_kN", "secant", "secant_n_avg",
                                             "secant_min_increment_mm")},
    # both tolerances may be given to any implicit method (one table compared across methods): an
    # element's iteration reads the one of its mode
    "force_control": {"anchor_dc": "no element runs in DC", "blend_dc": "no element runs in DC"},
}


def _check_implicit(i: dict, source: str, url: str = "emulator://") -> None:
    """[integrator] keys of the implicit FC / mixed methods (docs/force_control.md)."""
    methods = ("alpha_os", "implicit_dc", "force_control", "mixed")
    if i["method"] not in methods:
        raise ConfigError(f"{source}: [integrator] method must be one of {', '.join(methods)}, got {i['method']!r}")
    if not i["j_max"] >= 1:
        raise ConfigError(f"{source}: [integrator] j_max must be at least 1, got {i['j_max']}")
    for key in ("tol_displacement_mm", "tol_force_kN", "secant_min_increment_mm", "K_f", "K_d", "R_f", "R_d"):
        if i[key] < 0:
            raise ConfigError(f"{source}: [integrator] {key} must not be negative, got {i[key]}")
    if i["secant"] not in ("raw", "average", "least_squares"):
        raise ConfigError(f"{source}: [integrator] secant must be 'raw', 'average' or 'least_squares', got {i['secant']!r}")
    if not i["secant_n_avg"] >= 1:
        raise ConfigError(f"{source}: [integrator] secant_n_avg must be at least 1, got {i['secant_n_avg']}")
    if i["switch_on"] not in ("stiffness", "force"):
        raise ConfigError(f"{source}: [integrator] switch_on must be 'stiffness' or 'force', got {i['switch_on']!r}")
    upper, lower = ("K_f", "K_d") if i["switch_on"] == "stiffness" else ("R_f", "R_d")
    if i["method"] == "mixed" and i["switch_on"] == "force" and not i[upper] > 0 and i["switch_rule"] != "instruments":
        raise ConfigError(f"{source}: [integrator] switch_on = 'force' needs R_f > 0 (kN)")
    if i[upper] > 0 and i[lower] > 0 and not i[lower] < i[upper]:
        raise ConfigError(f"{source}: [integrator] {lower} ({i[lower]}) must be below {upper} ({i[upper]})")
    if i["switch_rule"] not in ("initial_stiffness", "instruments"):
        raise ConfigError(f"{source}: [integrator] switch_rule must be 'initial_stiffness' or 'instruments', "
                          f"got {i['switch_rule']!r}")
    _check_switching(i, source)
    known = (i["switch_resolution_mm"] > 0 or i["switch_noise_mm"] > 0,
             i["switch_force_resolution_kN"] > 0 or i["switch_force_noise_kN"] > 0)
    if i["switch_rule"] == "instruments" and not all(known) and not url.startswith("emulator"):
        missing = [what for what, ok in zip(("the transducer's switch_resolution_mm or switch_noise_mm",
                                             "the load cell's switch_force_resolution_kN or switch_force_noise_kN"),
                                            known) if not ok]
        raise ConfigError(f"{source}: [integrator] switch_rule = 'instruments' (the rule of method = 'mixed' "
                          f"without thresholds of its own) on real hardware needs {' and '.join(missing)} (give "
                          f"the resolution, and the noise where there is any; or give K_f and K_d)")
    off = DEFAULTS["integrator"]  # each option's default is its "off" value (anchor_dc, on, is not checked below)
    for key in MIXED_GUARDS:
        if i["method"] != "mixed" and i[key] != off[key]:
            raise ConfigError(f"{source}: [integrator] {key} applies to method = 'mixed', not to {i['method']!r}")
    for key in IMPLICIT_OPTIONS:
        if i["method"] == "alpha_os" and key != "anchor_dc" and i[key] != off[key]:  # alpha-OS anchors nothing
            raise ConfigError(f"{source}: [integrator] {key} applies to the implicit methods, not to 'alpha_os'")
    if i["blend_dc"] and not i["fc_blend"] < 1:
        raise ConfigError(f"{source}: [integrator] blend_dc needs fc_blend below 1 (the estimate it uses)")
    if i["fc_fallback_after"] >= i["j_max"] and i["fc_fallback_after"] > 0:
        raise ConfigError(f"{source}: [integrator] fc_fallback_after ({i['fc_fallback_after']}) must be below "
                          f"j_max ({i['j_max']}): after that many FC commands the step's remaining commands go in "
                          f"DC, and at j_max none is left; 0: off")


# The keys of the switching rule of mixed control (docs/force_control.md, "Running it"), by the
# rule that reads them; each is refused where no rule reads it rather than silently ignored.
BY_STIFFNESS = ("K_f", "K_d")
BY_FORCE = ("R_f", "R_d")
BY_INSTRUMENTS = ("switch_margin", "switch_hysteresis", "switch_resolution_mm", "switch_force_resolution_kN",
                  "switch_noise_mm", "switch_force_noise_kN", "switch_max_hysteretic_ratio")


def _check_switching(i: dict, source: str) -> None:
    """The switching keys apply to ``method = "mixed"`` only, and each to the rule that reads it:
    K_f / K_d to ``switch_on = "stiffness"``, R_f / R_d to ``switch_on = "force"`` (both with
    ``switch_rule = "initial_stiffness"``), the margin, hysteresis, resolutions, noises and the
    hysteretic ratio to ``switch_rule = "instruments"``, which sets the thresholds on the stiffness
    itself."""
    off = DEFAULTS["integrator"]
    given = [k for k in ("switch_on", "switch_rule") + BY_STIFFNESS + BY_FORCE + BY_INSTRUMENTS if i[k] != off[k]]
    if i["method"] != "mixed":
        if given:
            raise ConfigError(f"{source}: [integrator] {given[0]} applies to method = 'mixed', not to "
                              f"{i['method']!r}: the other methods do not switch")
        return
    if i["switch_rule"] == "instruments":
        if i["switch_on"] != "stiffness":
            raise ConfigError(f"{source}: [integrator] switch_rule = 'instruments' switches on the stiffness: "
                              f"leave switch_on = 'stiffness'")
        for key in BY_STIFFNESS + BY_FORCE:
            if i[key] != off[key]:
                raise ConfigError(f"{source}: [integrator] {key} is not read with switch_rule = 'instruments', which "
                                  f"sets K_f and K_d from the instruments: leave K_f, K_d, R_f, R_d at 0")
        return
    for key in BY_INSTRUMENTS:
        if i[key] != off[key]:
            raise ConfigError(f"{source}: [integrator] {key} applies to switch_rule = 'instruments', not to "
                              f"{i['switch_rule']!r}")
    unread, reads = (BY_FORCE, "force") if i["switch_on"] == "stiffness" else (BY_STIFFNESS, "stiffness")
    for key in unread:
        if i[key] != off[key]:
            raise ConfigError(f"{source}: [integrator] {key} applies to switch_on = {reads!r}, not to "
                              f"{i['switch_on']!r}")


MAX_TOML_BYTES = 4_000_000


def read_toml(path: str | Path, what: str) -> dict:
    """A TOML file as a dict; an unreadable or malformed file, one that is not a regular file (a
    device such as /dev/zero would be read for ever) or one beyond ``MAX_TOML_BYTES`` is a
    ConfigError naming it."""
    path = Path(path)
    try:
        data = read_bounded(path, MAX_TOML_BYTES, lambda reason: ConfigError(f"{path}: cannot read {what}: {reason}"))
        return tomllib.loads(data.decode("utf-8-sig"))  # a byte-order mark (Windows editors) is dropped
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read {what}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: malformed TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: cannot read {what}: not UTF-8 text (byte {exc.start})") from None


def load(path: str | Path | None) -> RunConfig:
    """Read and check a TOML configuration; ``None`` gives the defaults."""
    if path is None:
        return from_dict({})
    path = Path(path)
    data = read_toml(path, "configuration")
    config = from_dict(data, str(path))
    resolve_paths(config, path)
    return config


def resolve_paths(config: "RunConfig", path: Path) -> None:
    """Every file or folder named in the configuration ([record] file, [structure] file,
    [hardware] actuator_model, [driver] map and eds, [specimen] folder) that is relative is taken
    relative to the configuration file ``path``."""
    for table, key in (("record", "file"), ("structure", "file"), ("hardware", "actuator_model"),
                       ("specimen", "folder")):
        value = config[table][key]
        if value and not Path(value).is_absolute():
            config[table][key] = str((path.parent / value).resolve())
    _resolve_beside(config, path)

