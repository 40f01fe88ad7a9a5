"""`hsio run`: a configuration in, the library calls of :mod:`hsio.api` (NS, open the site, HS),
the record, summary and plots out.

Around them, the safe lab session of docs/safety.md: a new run folder that never replaces a
record, the specimen ledger, the dry run before any hardware opens, the interlocks, the control
socket and signals (pause, resume, stop), and an exit status per cause.
"""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
import time
from pathlib import Path

import numpy as np

import hsio
from hsio import api, plots
from hsio.clock import OVERRUN_WARNING
from hsio.compensation.stage import CompensationSettings, CompensationStage
from hsio.config import BOUNDS, RunConfig
from hsio.diagnose.modelfile import merged_emulator_table
from hsio.emulators.servo import ServoConfig
from hsio.errors import ConfigError, HsioError, RecordError
from hsio.experiment import ExperimentStopped, excitation, write_events
from hsio.hardware import check_options
from hsio.ground_motion import GroundMotion, read_record, synthetic_record
from hsio.integrators import IMPLICIT_METHODS, SwitchingRule
from hsio.integrators.mixed import RATIO_D, RATIO_F, initial_stiffness_thresholds, predicted_elastic
from hsio.ledger import Ledger
from hsio.recording import (RUN_FILE, NotARunError, Recorder, Run, discard_new_record, new_run_folder,
                            refuse_recorded_folder)
from hsio.safety.control import RunControl, stop_on_signals
from hsio.safety.dry_run import actuator_lag, actuator_limits, check, dry_run, enforce, from_present, with_static
from hsio.safety.dry_run import predict as predict_peaks
from hsio.safety.inputs import fingerprints, ground_fingerprint
from hsio.sites.numerical import StandingSite
from hsio.sites.setup_map import SetupMap
from hsio.safety.settings import SafetySettings
from hsio.safety.socket import ControlServer
from hsio.safety.status import DryRunRefused, OperatorStop, exit_status, outcome_name
from hsio.result import Result, max_error_pct
from hsio.secant import SecantEstimator
from hsio.structures import (Structure, channel_names, channel_units, dof_units, get_structure,  # channel_names: re-exported
                             load_structure)
from hsio.structure_file import is_plain_name


def build_record(config: RunConfig, structure: Structure, replay: bool = False) -> GroundMotion:
    """The ground motion a configuration names, scaled and cut. ``replay``: the configuration of
    a record read back (resume, budget): a ``duration_s`` longer than the record, refused for a
    new run, runs the whole record, as runs recorded before that refusal did."""
    rec = config["record"]
    if rec["file"]:
        ground = read_record(rec["file"], dt_s=rec["dt_s"] or None, units=rec["units"] or None)
    else:
        try:
            ground = synthetic_record(duration_s=rec["synthetic_duration_s"], dt=structure.dt, pga_g=rec["pga_g"],
                                      seed=rec["seed"])
        except RecordError as exc:
            raise ConfigError(f"{config.source}: [record] synthetic_duration_s = {rec['synthetic_duration_s']!r}, the "
                              f"synthetic record at the structure's dt of {structure.dt:g} s: {exc}; give a [record] "
                              f"file, or another synthetic_duration_s or dt") from None
    if rec["scale"] != 1.0:
        ground = ground.scaled(rec["scale"])
    if rec["duration_s"] > 0:
        longer = rec["duration_s"] > ground.duration_s + 0.5 * ground.dt
        if longer and not replay:  # a cut, never a silent clamp
            more = "" if rec["file"] else "; or lengthen the synthetic record ([record] synthetic_duration_s)"
            raise ConfigError(f"{config.source}: [record] duration_s = {rec['duration_s']!r} s is longer than the "
                              f"record {ground.name!r} ({ground.duration_s:g} s); 0 runs the whole record{more}")
        try:
            ground = ground if longer else ground.truncated(rec["duration_s"])
        except RecordError as exc:
            raise ConfigError(f"{config.source}: [record] duration_s = {rec['duration_s']!r}: {exc}") from None
    longest = BOUNDS[("record", "duration_s")][1]
    if ground.duration_s > longest + 0.5 * ground.dt:  # the bound of duration_s holds for a record file too
        raise ConfigError(f"{rec['file'] or config.source}: the record lasts {ground.duration_s:g} s, beyond the "
                          f"bound of {longest:g} s for one run; cut it with [record] duration_s")
    return ground


def load_run_structure(config: RunConfig) -> Structure:
    """The structure a run configuration names: ``[structure] file`` (a structure file,
    docs/structures.md) or else ``name`` (a shipped structure)."""
    table = config["structure"]
    if table["file"]:
        structure = load_structure(table["file"])
    else:
        try:
            structure = get_structure(table["name"])
        except ConfigError as exc:
            raise ConfigError(f"{config.source}: [structure] name: {exc}") from None
    if not structure.experimental:
        raise ConfigError(f"{table['file'] or structure.name}: the structure has no [[experimental]] element: a "
                          f"hybrid run needs at least one (a purely numerical model runs with hsio.run_numerical)")
    return structure


def check_run_method(config: RunConfig, structure: Structure) -> None:
    """The implicit methods iterate on the secant stiffness of elements driven by one actuator
    each: a structure with setups or multi-DOF elements runs with alpha_os (static preloads are held
    on their own actuators while the others iterate); mixed control on the instruments rule needs
    their resolution or noise; a present start (``[test] start = "present"``) is for alpha_os.
    Checked before anything is created or opened."""
    method = config["integrator"]["method"]
    if method not in IMPLICIT_METHODS:
        return
    if config["test"]["start"] == "present":
        raise ConfigError(f"{config.source}: [test] start = 'present' is available for the alpha_os method, not "
                          f"[integrator] method = {method!r} (docs/safety.md section 6)")
    coupled = [e.name for e in structure.experimental if e.has_setup]
    if coupled:
        raise ConfigError(f"{config['structure']['file'] or structure.name}: [integrator] method = {method!r} "
                          f"iterates on the secant stiffness of elements driven by one actuator each "
                          f"(elements with setups or several basic DOFs: {', '.join(coupled)}): "
                          f"use method = 'alpha_os'")
    numerical = structure.numerical_assembly()
    if not numerical.is_linear:
        nonlinear = [e.name for e, m in zip(structure.numerical, numerical.models) if m.kind != "linear"]
        raise ConfigError(f"{config.source}: [integrator] method = {method!r} takes linear numerical elements only "
                          f"(the secant model of eq. 9 covers the experimental elements), and structure "
                          f"{structure.name!r} has nonlinear ones ({', '.join(nonlinear)}): use method = 'alpha_os'")
    if method == "mixed":  # the rule's inputs (the NS gate aside): a crossed K_f / K_d is refused here
        try:
            if config["integrator"]["switch_rule"] == "instruments":
                switch_instruments(config["integrator"], emulated_instruments(config))
            else:
                switching_rule(structure, config["integrator"])
        except ConfigError as exc:
            raise ConfigError(f"{config.source}: {exc}") from None


def check_hardware(config: RunConfig) -> None:
    """The hardware URL and its options table ([emulator] or [driver]) checked before anything is
    created or opened: a typing error there leaves no record behind."""
    url = config["hardware"]["url"]
    emulator = merged_emulator_table(config["hardware"]["actuator_model"], config["emulator"])
    if url.startswith("emulator") and config["driver"]:  # a [driver] limit the run would ignore
        raise ConfigError(f"{config.source}: [driver] {', '.join(config['driver'])} is not read with {url!r}: the "
                          f"emulated controller takes [emulator] (stroke_mm, force_limit_kN, ...); to rehearse a "
                          f"rig's configuration on the emulator, comment its [driver] table out")
    check_options(url, emulator if url.startswith("emulator") else config["driver"])


def switch_instruments(integrator: dict, emulator: dict | None) -> tuple[float, float, float, float]:
    """delta_u (mm), delta_F (kN), sigma_u (mm) and sigma_F (kN) of ``switch_rule = "instruments"``:
    the [integrator] keys, or (where 0, with the emulated controller) its transducer's and load
    cell's resolution and noise ([emulator] resolution_mm, force_resolution_kN, noise_mm,
    force_noise_kN, or their defaults)."""
    du, dF, su, sF = _instrument_values(integrator, emulator)
    if not (du > 0 or su > 0) or not (dF > 0 or sF > 0):
        raise ConfigError("[integrator] switch_rule = 'instruments' needs the transducer's and the load cell's "
                          "resolution or noise above 0: set switch_resolution_mm, switch_force_resolution_kN "
                          "(or switch_noise_mm, switch_force_noise_kN)")
    return du, dF, su, sF


def _instrument_values(integrator: dict, emulator: dict | None) -> tuple[float, float, float, float]:
    """delta_u, delta_F, sigma_u, sigma_F: the [integrator] switch_* keys, or (where 0, with the
    emulated controller) its transducer's and load cell's (0 where neither is known)."""
    servo = ServoConfig()
    keys = (("switch_resolution_mm", "resolution_mm"), ("switch_force_resolution_kN", "force_resolution_kN"),
            ("switch_noise_mm", "noise_mm"), ("switch_force_noise_kN", "force_noise_kN"))
    return tuple(float(integrator[key]) if integrator[key] > 0 or emulator is None
                 else float(emulator.get(own, getattr(servo, own))) for key, own in keys)


def secant_instruments(integrator: dict, emulator: dict | None):
    """The instruments' ((sigma_u, delta_u), (sigma_F, delta_F)) for the FC secant rule of method
    ``force_control`` (eq. 11a): the switch_* keys, else the emulated controller's; None where
    neither is known (every estimate taken)."""
    du, dF, su, sF = _instrument_values(integrator, emulator)
    return ((su, du), (sF, dF)) if du + dF + su + sF > 0 else None


def switching_rule(structure: Structure, integ: dict, emulator: dict | None = None, ns=None) -> SwitchingRule:
    """K_f / K_d in kN/mm (0: 1.2 and 0.8 times each element's K^EI), or R_f / R_d in kN; with
    ``switch_rule = "instruments"`` from the transducer's and the load cell's resolution and noise,
    and FC only while the NS prediction ``ns`` finds every element elastic (hysteretic ratios below
    ``switch_max_hysteretic_ratio``; docs/force_control.md)."""
    n = len(structure.experimental)
    K_EI = [e.K_EI for e in structure.experimental]
    if integ["switch_rule"] == "instruments":
        du, dF, su, sF = switch_instruments(integ, emulator)
        rule = SwitchingRule.from_instruments(K_EI, du, dF, integ["switch_margin"], integ["switch_hysteresis"], su, sF)
        if needs_prediction(integ):
            if ns is None:
                raise ConfigError("[integrator] switch_max_hysteretic_ratio needs the NS prediction of the run")
            rule = rule.elastic_only(ns, structure, integ["switch_max_hysteretic_ratio"])
        return rule
    if integ["switch_on"] == "force":
        lower = integ["R_d"] if integ["R_d"] > 0 else 0.5 * integ["R_f"]
        return SwitchingRule(np.full(n, integ["R_f"]), np.full(n, lower), "force")
    upper, lower = initial_stiffness_thresholds(K_EI, integ["K_f"], integ["K_d"])
    crossed = [(e.name, up, lo) for e, up, lo in zip(structure.experimental, upper, lower) if not lo < up]
    if crossed:
        name, up, lo = crossed[0]
        given = {key: integ[key] for key in ("K_f", "K_d") if integ[key] > 0}
        defaults = " and ".join(f"{key} = {share:g} K^EI" for key, share in (("K_f", RATIO_F), ("K_d", RATIO_D))
                                if key not in given)
        raise ConfigError(f"[integrator] element {name}: K_d = {lo:.4g} kN/mm must be below K_f = {up:.4g} kN/mm "
                          f"(to FC above K_f, back to DC below K_d; {defaults or 'both given'} where not given); "
                          f"give K_d below K_f, or K_f above K_d")
    return SwitchingRule.from_initial_stiffness(K_EI, integ["K_f"], integ["K_d"])


def emulated_instruments(config: RunConfig) -> dict | None:
    """The emulated controller's table (with an actuator model's settings), where the instruments
    rule reads the transducer and the load cell; None on real hardware (the [integrator] keys)."""
    if not config["hardware"]["url"].startswith("emulator"):
        return None
    return merged_emulator_table(config["hardware"]["actuator_model"], config["emulator"])


def describe_switching(config: RunConfig, structure: Structure, ns) -> dict | None:
    """What mixed control will do, for `hsio check`: the rule, each element's thresholds (upper
    None: the element stays in DC) and, with the instruments rule, the NS prediction it read."""
    integ = config["integrator"]
    if integ["method"] != "mixed":
        return None
    thresholds = switching_rule(structure, integ, emulated_instruments(config), ns).as_dict()
    unit = "kN/mm" if thresholds["on"] == "stiffness" else "kN"
    out = {"rule": integ["switch_rule"], "on": thresholds["on"], "unit": unit, "elements": {
        e.name: {"upper": up, "lower": lo}
        for e, up, lo in zip(structure.experimental, thresholds["upper"], thresholds["lower"])}}
    if needs_prediction(integ):
        out["ns_elastic"] = {e.name: bool(ok) for e, ok in zip(
            structure.experimental, predicted_elastic(ns, structure, integ["switch_max_hysteretic_ratio"]))}
    return out


def switching_text(switching: dict) -> str:
    """:func:`describe_switching` as lines of text."""
    lines = [f"switching      mixed, rule {switching['rule']!r} on the {switching['on']}"]
    elastic = switching.get("ns_elastic")
    if elastic is not None:
        dissipating = [name for name, ok in elastic.items() if not ok]
        lines.append("  NS predicts every element elastic: FC allowed where the thresholds say" if not dissipating
                     else f"  NS predicts {', '.join(dissipating)} dissipating energy or off the K^EI line: every "
                          "element stays in DC")
    for name, t in switching["elements"].items():
        if t["upper"] is None:
            lines.append(f"  {name:<12} DC throughout")
        else:
            lines.append(f"  {name:<12} to FC above {t['upper']:.4g} {switching['unit']}, "
                         f"back to DC below {t['lower']:.4g} {switching['unit']}")
    return "\n".join(lines)


def needs_prediction(integ: dict) -> bool:
    """Whether the switching rule reads the NS prediction (mixed, instruments rule, a hysteretic gate)."""
    return (integ["method"] == "mixed" and integ["switch_rule"] == "instruments"
            and integ["switch_max_hysteretic_ratio"] > 0)


def integrator_options(config: RunConfig, structure: Structure, ns=None) -> dict:
    """The [integrator] and [test] keys as options of :func:`hsio.api.make_integrator` (``ns``: the
    NS prediction, read by the instruments rule of mixed control)."""
    integ = config["integrator"]
    if integ["method"] == "alpha_os":
        return {"correct_measured_displacement": config["test"]["measured_displacement_correction"]}
    options = {"rule": (switching_rule(structure, integ, emulated_instruments(config), ns)
                        if integ["method"] == "mixed" else None),
               "j_max": integ["j_max"], "tol_displacement": integ["tol_displacement_mm"],
               "tol_force": integ["tol_force_kN"], "fc_blend": integ["fc_blend"], "anchor_dc": integ["anchor_dc"],
               "blend_dc": integ["blend_dc"]}
    if integ["method"] == "force_control":  # FC's secant beyond the instruments' noise where they are known
        options["secant_uncertainty"] = secant_instruments(integ, emulated_instruments(config))
    if integ["method"] == "mixed":
        options.update(fallback_after=integ["fc_fallback_after"] or None, refractory_steps=integ["refractory_steps"],
                       no_fc_at_reversal=integ["no_fc_at_reversal"],
                       explored_fraction=integ["explored_fraction"] or None,
                       fc_force_limit=integ["fc_force_limit_kN"] or None)
    return options


def _state(site) -> dict | None:
    """Measured displacement and force per actuator, where the specimen stands now."""
    if site is None:
        return None
    try:
        feedback = site.loop.feedback()
    except Exception as exc:  # a lost link: say so rather than guess
        return {"error": str(exc)}
    return {a.name: {"displacement_mm": f.displacement_mm, "force_kN": f.force_kN}
            for a, f in zip(site.loop.actuators, feedback)}


def format_state(head: str, state: dict | None) -> str:
    """One line per actuator of a start or end state, as the operator reads it."""
    if not state:
        return f"{head}: no actuators"
    if "error" in state:
        return f"{head}: could not be read ({state['error']})"
    return head + ": " + "; ".join(f"{name} {v['displacement_mm']:+.3f} mm {v['force_kN']:+.3f} kN"
                                   for name, v in state.items())


def run_folder(config: RunConfig, structure: Structure, out_dir: str | Path | None) -> Path:
    """The folder of a new run: ``out_dir`` if it holds no record (else RecordExistsError), or a
    new numbered folder runs/<structure>/run-NNNN (docs/safety.md section 1). A folder that cannot
    be created is a ConfigError naming it and why."""
    if out_dir is not None and not str(out_dir).strip():
        raise ConfigError("--out: the run folder is an empty path; name a folder (or omit --out for a new "
                          "numbered folder)")
    if out_dir is None and not is_plain_name(structure.name):
        raise ConfigError(f"structure {structure.name!r}: its name would make the run folder runs/{structure.name}/, "
                          f"outside runs/ or nested; give the structure a plain name (without '/', '\\', a "
                          f"leading '.' or control characters), or name the run folder with --out")
    target = Path("runs") / structure.name if out_dir is None else Path(out_dir)
    try:
        if out_dir is None:
            return new_run_folder(target)
        out = refuse_recorded_folder(target)
        if out.exists() and not out.is_dir():
            raise ConfigError(f"--out {out}: this is a file (or a device), not a folder; name a folder for the run")
        out.mkdir(parents=True, exist_ok=True)
        return out
    except OSError as exc:
        raise ConfigError(f"{target}: cannot create the run folder: {exc.strerror or exc}") from None


def open_ledger(config: RunConfig, specimen_dir: str | Path | None = None) -> Ledger | None:
    """The specimen ledger of ``--specimen DIR`` or [specimen] folder / id (None: no ledger)."""
    spec = config["specimen"]
    if spec["id"] and (spec["id"] in (".", "..") or any(c in spec["id"] for c in "/\\") or not spec["id"].strip()
                       or not spec["id"].isprintable()):
        raise ConfigError(f"{config.source}: [specimen] id = {spec['id']!r}: a specimen id is a plain name (it names "
                          f"the folder specimens/<id>), without '/', '\\', '..', control characters or only spaces")
    folder = specimen_dir or spec["folder"] or (str(Path("specimens") / spec["id"]) if spec["id"] else "")
    return Ledger(folder, spec["id"]) if folder else None


def secant_n_avg(config: RunConfig, structure: Structure) -> int:
    """[integrator] secant_n_avg; left out, its default (16) but no more than a step's dwell (a fast
    test at a small dt has fewer periods than that to average: TR 5 at dt 0.005 s, 13). A value
    written is checked against the dwell (:func:`check_dwell`), never cut."""
    test, n = config["test"], config["integrator"]["secant_n_avg"]
    if "secant_n_avg" in config.given.get("integrator", ()):
        return n
    return min(n, api.dwell_periods(structure.dt, test["rate"], test["hold_fraction"]))


def check_instruments(config: RunConfig, structure: Structure) -> None:
    """The structure's instruments readable on the configured hardware (:func:`hsio.api.check_instruments`),
    checked before anything is created or opened; named with the configuration."""
    url = config["hardware"]["url"]
    try:
        api.check_instruments(structure, url, None if url.startswith("emulator") else config["driver"])
    except ConfigError as exc:
        raise ConfigError(f"{config.source}: {exc}") from None


def check_dwell(config: RunConfig, structure: Structure) -> None:
    """[test] n_avg within a step's dwell (:func:`hsio.api.check_dwell`), named with the configuration."""
    test, integ = config["test"], config["integrator"]
    try:
        api.check_step_periods(structure.dt, test["rate"], key="[test] rate")
    except ConfigError as exc:
        raise ConfigError(f"{config.source}: {exc}") from None
    averaged = [("[test] ", test["n_avg"])]
    if integ["method"] in IMPLICIT_METHODS and integ["secant"] == "average":
        averaged.append(("[integrator] secant_", secant_n_avg(config, structure)))
    for key, count in averaged:
        try:
            api.check_dwell(structure.dt, test["rate"], test["hold_fraction"], count)
        except ConfigError as exc:
            raise ConfigError(f"{config.source}: {key}{exc}") from None


def check_site(config: RunConfig, structure: Structure) -> None:
    """The hardware, the dwell and the instruments (:func:`check_hardware`, :func:`check_dwell`,
    :func:`check_instruments`): once per run, before anything is created or opened."""
    check_hardware(config)
    check_dwell(config, structure)
    check_instruments(config, structure)


def predict(config: RunConfig, structure: Structure, ground: GroundMotion, control: RunControl | None = None):
    """NS and the dry run of the configured test (docs/safety.md section 2): (NS result, report).
    The site is checked first (:func:`check_site`), as a run checks it."""
    check_site(config, structure)
    return _predict(config, structure, ground, control)


def _predict(config: RunConfig, structure: Structure, ground: GroundMotion, control: RunControl | None = None):
    """:func:`predict` of a site checked already."""
    integ, test, hardware = config["integrator"], config["test"], config["hardware"]
    try:
        ns = api.run_numerical(structure, ground, integ["method"], integ["alpha"],  # a pause: before the first step
                               control=_StopOnly(control) if control is not None else None)
    except ExperimentStopped as exc:  # the models cannot be evaluated along the record: bad input, not a fault
        if isinstance(exc.cause, (OperatorStop, KeyboardInterrupt)):
            raise exc.cause from None  # the run's stop, not a step of this prediction: nothing was recorded
        if exc.cause is None:
            raise
        raise _prediction_failed(config, structure, exc, "the prediction (NS: the structure with its specimen models "
                                 "in place of the actuators)", "Nothing was sent to the actuators; check the models' "
                                 f"parameters ({config['structure']['file'] or config['structure']['name']})") from None
    emulator = merged_emulator_table(hardware["actuator_model"], config["emulator"])
    setups = SetupMap.of(structure) if structure.has_setups else None
    stage = compensation_stage(config, structure)  # whose lead adds to the commands sent
    lag = actuator_lag(hardware["url"], emulator, stage.settings, stage.names, ns.steps)
    report = dry_run(ns, test["rate"] * structure.dt, test["hold_fraction"], hardware["url"], emulator,
                     config["driver"], SafetySettings.from_table(config["safety"]), setups, structure.static, lag)
    return ns, report


class _StopOnly:
    """A run's control as its predictions (NS, and NS from the present state) see it: a stop (key,
    socket, signal) ends that NS at once; a pause waits for the first step of the test, where it
    holds the actuators and is recorded ("paused after step 0")."""

    def __init__(self, control: RunControl):
        self.control = control

    def checkpoint(self, site, step: int, log=None) -> None:
        self.control.check_stop()


def ns_from_present(config: RunConfig, structure: Structure, ground: GroundMotion, start_state: dict | None,
                    control: RunControl | None = None):
    """NS of a run that starts where the specimen stands (``[test] start = "present"``): each
    specimen model about the measured displacement and force of its actuator, the numerical DOFs
    in static equilibrium, v = 0. None through setups or where the present state could not be
    read (the prediction from rest is all there is then). A stop asked of ``control`` meanwhile is
    raised (OperatorStop) at the next step of that NS."""
    if structure.has_setups or not start_state or "error" in start_state:
        return None
    standing = list(start_state.values())[:len(structure.experimental)]  # element actuators first, in order
    u0 = [v["displacement_mm"] for v in standing]
    R0 = [v["force_kN"] for v in standing]
    site = StandingSite([e.model() for e in structure.experimental], u0, R0)
    try:
        return api.simulate(structure, ground, site, "alpha_os", config["integrator"]["alpha"], start="present",
                            control=_StopOnly(control) if control is not None else None)
    except ExperimentStopped as exc:
        if isinstance(exc.cause, (OperatorStop, KeyboardInterrupt)):
            raise exc.cause from None  # the run's stop, not a step of this prediction
        if exc.cause is None:
            raise
        raise _prediction_failed(config, structure, exc, "the prediction from the present state (NS: the specimen "
                                 "models about where the actuators stand)", "No command was sent to the actuators; "
                                 "check the models' parameters") from None


def _prediction_failed(config: RunConfig, structure: Structure, exc: ExperimentStopped, which: str,
                       advice: str) -> ConfigError:
    """A prediction whose models could not be evaluated along the record (``exc``): bad input,
    named with the step it could not pass and why."""
    steps = len(exc.result.t) if exc.result is not None else 0
    cause = exc.cause
    what = str(cause) if isinstance(cause, HsioError) else f"{type(cause).__name__}: {cause}"
    return ConfigError(f"{config.source}: {which} could not go past step {steps} (t = {steps * structure.dt:.3f} s): "
                       f"{what}. {advice} and the record's scale")


def _dry_run_from_present(config: RunConfig, structure: Structure, ns_present, report, site,
                          start_state: dict | None, safety: SafetySettings, recorder, notify, ledger, run_id) -> None:
    """Check the test again from where the specimen stands, read when the hardware opened and
    before the first command (docs/safety.md section 2); refuse as the dry run does.

    Elements loaded by one actuator each: NS from the present state (each specimen model about
    the measured displacement and force, the numerical DOFs in static equilibrium, v = 0: the
    free vibration the offset starts is in the prediction). Through setups: the prediction from
    rest shifted by each actuator's present stroke and force. Each actuator is checked against its
    own limits: those [driver] gives, else the ones its controller reported when the hardware
    opened; the lag allowance is that of the dry run from rest."""
    if not start_state or "error" in start_state:
        raise DryRunRefused("dry run from the present state: the actuators' present state could not be read "
                            f"({(start_state or {}).get('error', 'no feedback')}); no command was sent")
    if structure.has_setups:  # setups and multi-DOF elements alike
        prediction = from_present(report.prediction, start_state)
        how = "NS from rest plus where each actuator stands"
    else:
        test = config["test"]
        rest = report.prediction
        lag = None if rest.lag is None else rest.lag.first(len(rest.actuators) - rest.static)
        t_d = test["rate"] * structure.dt
        prediction = with_static(predict_peaks(ns_present, t_d, test["hold_fraction"], lag=lag), structure.static,
                                 t_d, test["hold_fraction"])
        how = "NS from where the specimen stands"
    source = report.source
    unknown = [key for key, value in report.limits.items() if value is None]
    if unknown:  # not in [driver]: each controller has reported its own now that the hardware is open
        source += f"; {', '.join(unknown)} as the controller reports them, each actuator's own"
    present = check(prediction, report.limits, source, safety,
                    actuator_limits(prediction, report.limits, site.loop.actuators))
    text = f"from the present state ({how}):\n" + present.text()
    recorder.write_event(None, 0, "dry_run", "", text)
    recorder.write_meta({"dry_run_present": present.as_dict()})
    if ledger:
        ledger.update(run_id, dry_run={**report.as_dict(), "present": present.as_dict()},  # the check that decides
                      override=int(bool((report.exceeded or present.exceeded) and present.override)))
    if present.refused:
        raise DryRunRefused(text)
    notify(text)




# A rest start on an actuator standing farther than this from zero is refused (as a resume's gap, mm).
REST_GAP_MM = 1.0


def check_rest_start(structure: Structure, method: str, start_state: dict | None, t_d: float,
                     safety: SafetySettings, recorder, notify, overridden=lambda: None) -> None:
    """A test from rest (``[test] start = "rest"``) on actuators that stand away from zero (the
    residual displacement of an earlier record) would drive them back to zero within its first
    step t_d = TR dt: a motion the dry run, made from rest, does not predict. Beyond REST_GAP_MM it
    is refused as the dry run refuses (DryRunRefused: no command sent), unless overridden
    (``--override-dry-run``, recorded: ``overridden`` marks it in the ledger). Elements on one
    actuator each, in displacement control (through setups the strokes at rest are not known here;
    in force control the first command is a force)."""
    if not start_state or "error" in start_state or structure.has_setups or method == "force_control":
        return
    far = {name: start_state[name]["displacement_mm"] for name in channel_names(structure)
           if name in start_state and not abs(start_state[name]["displacement_mm"]) <= REST_GAP_MM}
    if not far:
        return
    where = "; ".join(f"{name} stands at {d:+.3f} mm" for name, d in far.items())
    fastest = max(abs(d) for d in far.values()) / t_d
    text = (f"dry run from the present state: the test starts from rest ([test] start = \"rest\") but {where}, more "
            f"than {REST_GAP_MM:g} mm from zero: its first step would drive the specimen back to zero within "
            f"{t_d:g} s (about {fastest:.0f} mm/s), a motion the dry run from rest does not predict; start from where "
            f"the specimen stands ([test] start = \"present\"), or bring the actuators back to zero first")
    recorder.write_event(None, 0, "dry_run", "", text)
    if safety.override:
        overridden()
        notify(f"WARNING: {text} (overridden)")
        return
    raise DryRunRefused(f"{text}; no command was sent")


def run(config: RunConfig, out_dir: str | Path | None = None, progress=None, ground: GroundMotion | None = None,
        control: RunControl | None = None, specimen_dir: str | Path | None = None, notify=None,
        checked: bool = False) -> dict:
    """Run a hybrid simulation as configured; write run.sqlite, plots and summary.json in a new
    run folder (``out_dir``, refused if it holds a record; None: runs/<structure>/run-NNNN).

    ``ground`` replaces the configured [record] (a record built in code, e.g. a harmonic test);
    ``control`` takes pause / resume / stop requests (a new one if None); SIGTERM and SIGINT stop
    the run; ``notify`` (a callable taking a line of text) hears the dry run, pauses and stops;
    ``checked``: the caller has checked this configuration's method and site (:func:`check_run_method`,
    :func:`check_site`).

    Returns the summary. Raises (after writing what was recorded, the actuators holding):
    ExperimentStopped if the run stopped early, DryRunRefused if the dry run refused the test,
    OperatorStop if a stop came before the steps began; each carries ``run_dir``.
    """
    control = control or RunControl()
    with stop_on_signals(control):
        control.check_stop()  # a stop asked before the run began (a Ctrl-C while hsio started): no folder
        return _run(config, out_dir, progress, ground, control, specimen_dir, notify or (lambda line: None), checked)


def compensation_stage(config: RunConfig, structure: Structure) -> CompensationStage:
    """The [compensation] stage of a run, checked against the structure's actuators and the step
    duration t_d = TR dt (docs/compensation.md): one channel per actuator (through setups, the
    setups' actuators, not the basic DOFs)."""
    actuator_names = SetupMap.of(structure).actuator_names if structure.has_setups else channel_names(structure)
    try:
        return CompensationStage(list(actuator_names), config["test"]["rate"] * structure.dt,
                                 CompensationSettings.from_table(config["compensation"]))
    except ConfigError as exc:
        raise ConfigError(f"{config.source}: {exc}") from None


def _run(config, out_dir, progress, ground, control, specimen_dir, notify, checked) -> dict:
    structure = load_run_structure(config)
    if not checked:  # before the folder: a typing error or an instrument that cannot be read leaves none
        check_run_method(config, structure)
        check_site(config, structure)
    ground = ground if ground is not None else build_record(config, structure)
    integ = config["integrator"]
    method, alpha = integ["method"], integ["alpha"]
    implicit = method in IMPLICIT_METHODS
    test = config["test"]
    hardware = config["hardware"]
    safety = SafetySettings.from_table(config["safety"])
    compensation = compensation_stage(config, structure)
    # An actuator model from `hsio diagnose` goes under the run's own [emulator] table.
    emulator = merged_emulator_table(hardware["actuator_model"], config["emulator"])
    inputs = fingerprints(config)  # before the folder: a file that cannot be read leaves none
    ledger = open_ledger(config, specimen_dir)  # before the folder: a ledger that cannot be kept leaves none
    if ledger:
        ledger.warn = notify
    existed = out_dir is not None and os.path.isdir(out_dir)  # False for a name too long: run_folder names it
    try:
        out = run_folder(config, structure, out_dir)
    except BaseException:
        if ledger:
            ledger.close()
        raise
    meta = {
        "config": config.tables, "config_source": config.source, "structure": structure.name,
        "record": ground.name, "dt": structure.dt, "test_rate": test["rate"], "emulator_settings": emulator,
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "version": hsio.__version__,
        "specimen_id": ledger.specimen_id if ledger else config["specimen"]["id"],
        "dry_run_override": safety.override, "start": test["start"],
        "dof_units": dof_units(structure), "channel_units": [u for u, _ in channel_units(structure)],
        "inputs": inputs, "ground_motion_sha256": ground_fingerprint(ground),
        "steps_total": len(excitation(structure, ground)[0]) - 1,  # the monitor's progress, with or without NS
    }
    site = None
    summary: dict = {}
    error: BaseException | None = None
    with contextlib.ExitStack() as cleanup:
        # Whatever fails from here on, what was opened is closed (the actuators left holding).
        try:
            server = ControlServer(out, control) if safety.control_socket else None
            if server is not None:
                cleanup.callback(server.close)
            recorder = Recorder(out / RUN_FILE, structure.dof_names, channel_names(structure), meta)
        except (RecordError, ConfigError) as exc:  # a full or read-only disk, a file in the socket's way:
            # nothing began, no folder of this run is left
            exc.not_begun = str(exc)  # a caller that wrote in the folder (the monitor's log) may clear it
            cleanup.close()
            if ledger:
                ledger.close()
            if not existed:
                with contextlib.suppress(OSError):  # the Recorder left no file: the folder is empty
                    out.rmdir()
            raise
        cleanup.callback(recorder.close)
        try:
            run_id = ledger.begin(out, config.tables, structure.name, ground.name, hsio.__version__) if ledger else None
        except ConfigError as exc:  # not listed, so not begun: no folder left holding only meta
            cleanup.close()  # the record and the control socket
            ledger.close()
            discard_new_record(out, remove_folder=not existed)
            left = "no run folder was left" if not out.exists() else "no record was left in it"
            refused = ConfigError(f"{exc} ({out}: {left})")
            refused.not_begun = str(exc)  # no run began: a caller that made the folder may remove it
            raise refused from None
        if ledger:
            cleanup.callback(ledger.close)
            recorder.write_meta({"ledger": str(ledger.folder.resolve())})  # where a resume lists itself
        if server is not None:
            recorder.write_meta({"control_socket": str(server.path)})
        try:
            control.check_stop()
            ns = report = predicted = None
            if config["output"]["ns"] or safety.dry_run or needs_prediction(integ):
                control.enter("NS")
                ns, report = _predict(config, structure, ground, control)
                predicted = ns
                if not safety.dry_run:
                    report = None
                else:
                    recorder.write_event(None, 0, "dry_run", "", report.text())
                    recorder.write_meta({"dry_run": report.as_dict()})
                    if ledger:
                        ledger.update(run_id, dry_run=report.as_dict(), override=int(bool(report.exceeded and report.override)))
                    enforce(report)  # a refusal is told once, by whoever catches it
                    notify(report.text())
                if not config["output"]["ns"]:
                    ns = None
            present = test["start"] == "present"
            if ns is not None and not present:  # a present start: NS from where the specimen stands, below
                recorder.write_ns(ns.t, ns.u)
            integrator = api.make_integrator(structure, method, alpha, **integrator_options(config, structure, predicted))
            control.enter("start-up")
            control.check_stop()
            estimator = (SecantEstimator(integ["secant"], secant_n_avg(config, structure), integ["secant_min_increment_mm"])
                         if implicit else None)
            if estimator is not None:
                recorder.write_meta({"secant_n_avg": estimator.n_avg})  # the samples averaged, as used
            site = api.open_site(structure, hardware["url"], clock=hardware["clock"], test_rate=test["rate"],
                                 hold_fraction=test["hold_fraction"], n_avg=test["n_avg"],
                                 keep_samples=config["output"]["samples"],
                                 options=emulator if hardware["url"].startswith("emulator") else config["driver"],
                                 estimator=estimator, compensation=compensation if not implicit or compensation.settings.mode != "off" else None,
                                 safety=safety)
            cleanup.callback(site.close)
            start_state = _state(site)
            recorder.write_meta({"start_state": start_state})
            if ledger:
                ledger.update(run_id, start_state=start_state)
            notify(format_state("the actuators stand at", start_state))
            if structure.instruments:  # every channel's reading, before the first command (docs/setups.md)
                notify("initial read-back:\n" + api.format_readback(site.readback,
                                                                      {i.name: i.unit for i in structure.instruments}))
            if not hardware["url"].startswith("emulator") and (config["emulator"] or hardware["actuator_model"]):
                notify(f"[emulator] and [hardware] actuator_model are not read by a run on {hardware['url']}: they "
                       f"set the emulated controller (`hsio emulate ... CONFIG`), not the real one")
            if not present and safety.dry_run:
                check_rest_start(structure, method, start_state, test["rate"] * structure.dt, safety, recorder, notify,
                                 lambda: ledger.update(run_id, override=1) if ledger else None)
            if present:  # what HS is compared with: NS from the same start, not from rest
                ns_present = ns_from_present(config, structure, ground, start_state, control) \
                    if ns is not None or report is not None else None
                if report is not None:
                    _dry_run_from_present(config, structure, ns_present, report, site, start_state, safety,
                                          recorder, notify, ledger, run_id)
                if ns is not None:
                    ns = ns_present if ns_present is not None else ns
                    recorder.write_ns(ns.t, ns.u)
            compensation.sink = recorder.write_compensation
            control.check_stop()
            control.enter("HS")
            try:
                hs = api.simulate(structure, ground, site, recorder=recorder, progress=progress, integrator=integrator,
                                  control=control, start=test["start"])
            except ExperimentStopped as exc:
                hs, error = exc.result, exc
            control.enter("closing")
            end_state = _state(site)
            site.close()
            summary = summarise(structure, config, ground, hs, ns, out)
            summary["clock_overruns"] = overruns = getattr(site.loop.clock, "overruns", 0)
            if hasattr(site.loop.clock, "lateness"):  # a real-time clock: how late its periods started
                summary["clock_lateness"] = site.loop.clock.lateness()
            periods = getattr(site.loop.clock, "ticks", 0)
            if periods and overruns > OVERRUN_WARNING * periods:
                paused = f" (not counting {control.paused_s:.3g} s of pause)" if control.paused_s else ""
                notify(f"WARNING: the host did not keep the controller's rate: {overruns} of {periods} periods started "
                       "more than one period late (a link slower than the period, or a loaded machine); the test took "
                       f"{max(0.0, summary['wall_time_s'] - control.paused_s):.6g} s{paused} for "
                       f"{summary['test_time_s']:g} s at its rate TR {test['rate']:g}")
            summary["compensation"] = compensation.summary()
            summary["start_state"], summary["end_state"] = start_state, end_state
            summary.update(site.report_final_hold(recorder, notify, len(hs.t) - 1))  # read back; warned if not
            if implicit:
                summary.update(implicit_summary(hs))
        except (Exception, KeyboardInterrupt) as exc:  # before or around the steps: hold, record, re-raise
            error = exc
            hold = site.hold() if site is not None else None
            reason = (str(exc) if isinstance(exc, HsioError) else "interrupted (Ctrl-C)"
                      if isinstance(exc, KeyboardInterrupt) else f"unexpected {exc!r}")
            for note in getattr(exc, "__notes__", ()):  # what else went wrong on the way (a record not written)
                reason += f"; {note}"
            if hold is not None:
                reason += f"; {hold.message}"
                if not isinstance(exc, ExperimentStopped):  # the operator hears the hold, as the record has it
                    exc.stop_message = reason
            try:
                if hold is not None:
                    write_events(recorder, site, 0)  # a trip before the steps (in the ramp in of static preloads)
                    recorder.write_event(site.lab_time_s, 0, "hold", "", hold.message, commit=False)
                recorder.write_event(None, 0, "stop", "", reason)
            except RecordError:  # a full disk took the record's last page: the message carries the stop
                pass
            summary = {"structure": structure.name, "record": ground.name, "steps": 0, "stopped": reason,
                       "run_file": str(out / RUN_FILE), "end_state": _state(site)}
            if site is not None and site.static and site.ramp_peaks:  # a ramp in stopped: how far its rods went
                summary["static_ramps"] = site.ramp_peaks
        status = exit_status(error)
        summary.update(exit_status=status, outcome=outcome_name(status), run_dir=str(out),
                       dry_run_override=safety.override, version=hsio.__version__)
        if error is not None and not summary.get("stopped"):
            summary["stopped"] = str(error)
        written = write_summary(out, recorder, summary, notify)
        if ledger:
            ledger.finish(run_id, summary["outcome"], status, summary.get("stopped", ""), summary.get("end_state"))
        if written and config["output"]["plots"] and summary.get("steps", 0) > 0 and not isinstance(error, KeyboardInterrupt):
            try:
                summary["plots"] = make_plots(out, structure, hs, ns, config)
                if implicit:
                    summary["plots"].append(str(plots.control_modes(out / "modes.png", hs, structure.incidence)))
                if error is not None:
                    summary["plots"] += stop_plot(out, structure, notify)
            except OSError as exc:
                notify(f"WARNING: the plots could not be written to {out} ({exc.strerror or exc})")
            except KeyboardInterrupt:  # the run is over, held and recorded: a second Ctrl-C ends the plots only
                summary.pop("plots", None)
                notify(f"WARNING: the plots were not written to {out} (interrupted by Ctrl-C); the run ended as "
                       f"recorded ({summary['outcome']})")
            write_summary(out, recorder, summary, notify)
    if error is not None:
        error.run_dir = out
        raise error
    return summary


def write_summary(out: Path, recorder, summary: dict, notify, replace: bool = False) -> bool:
    """The record's ``summary`` table, then ``summary.json`` beside it, replaced whole (written to a
    temporary file, then renamed over it): a disk that refuses either (full, gone) is reported, not
    raised, and leaves what was there before (the steps committed, an earlier session's summary),
    never a file cut short; the run ends with the status it had. False when not written."""
    failed = []
    try:
        recorder.write_summary(summary, replace=replace)
    except sqlite3.Error as exc:
        failed.append(str(exc))
    path, partial = out / "summary.json", out / "summary.json.partial"
    try:
        partial.write_text(json.dumps(summary, indent=2, default=str))
        partial.replace(path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            partial.unlink(missing_ok=True)
        failed.append(exc.strerror or str(exc))
    if failed:
        notify(f"WARNING: the summary could not be written in {out} ({'; '.join(dict.fromkeys(failed))}); "
               f"the steps committed before are in {out / RUN_FILE}")
    return not failed


def describe(structure: Structure, config: RunConfig, ground: GroundMotion, out: Path) -> dict:
    """The summary's description of the run: what ran, on what, in which units (a resume after a
    kill, which left no summary, writes it again from the record's configuration)."""
    return {
        "structure": structure.name,
        "record": ground.name,
        "dt": structure.dt,
        "test_rate": config["test"]["rate"],
        "hardware": config["hardware"]["url"],
        "clock": config["hardware"]["clock"],
        "dof": list(structure.dof_names),
        # a rotation's displacements are in rad (the keys say mm): the unit of each DOF and channel
        "dof_units": dof_units(structure),
        "channel_units": [u for u, _ in channel_units(structure)],
        "channels": channel_names(structure),  # the actuators, in the order of the per-channel lists
        "run_file": str(out / "run.sqlite"),
    }


def summarise(structure: Structure, config: RunConfig, ground: GroundMotion, hs: Result, ns: Result | None, out: Path) -> dict:
    summary = {
        **describe(structure, config, ground, out),
        "steps": hs.steps,
        "peak_displacement_mm": [float(x) for x in np.max(np.abs(hs.u), axis=0)],
        "rms_tracking_error_mm": [float(x) for x in np.sqrt(np.mean(hs.tracking_error()[1:] ** 2, axis=0))] if hs.steps else [],
        "late_steps": hs.late_steps,
        "wall_time_s": round(hs.wall_time_s, 3),
        "test_time_s": round(hs.steps * structure.dt * config["test"]["rate"], 3),
        "stopped": hs.stopped,
    }
    if structure.static and hs.static_hold_error is not None:  # the largest |measured - preload| / preload
        summary["static_hold_error_pct"] = {load.name: float(100.0 * e)
                                            for load, e in zip(structure.static, hs.static_hold_error)}
    if structure.static and hs.static_ramps:  # per ramp, per preload: the measured peak rod speed and stroke
        summary["static_ramps"] = hs.static_ramps
    if hs.instrument_log:
        iterations = np.array([n for _, n, _ in hs.instrument_log], dtype=float)
        summary["outer_loop_iterations"] = {"mean": float(iterations.mean()), "max": int(iterations.max())}
    if ns is not None:
        summary["ns_peak_displacement_mm"] = [float(x) for x in np.max(np.abs(ns.u), axis=0)]
        worst, per_dof = max_error_pct(hs.u, ns.u)
        summary["max_error_pct"] = worst
        summary["max_error_pct_per_dof"] = per_dof
    return summary


def implicit_summary(hs: Result) -> dict:
    """Method, switches, share of steps in FC, iterations and wall time per step; tracking errors
    of DC steps (mm) and of FC steps (kN) separately."""
    its = hs.iterations[1:]
    wall = hs.step_wall_time_s[1:]
    fc_act = hs.force_control[1:]
    d_err = np.where(~fc_act, hs.targets[1:] - hs.measured_displacement[1:], np.nan)
    f_err = np.where(fc_act, hs.targets[1:] - hs.measured_force[1:], np.nan)

    def rms(columns):  # None for an actuator that made no step in that mode: nothing was tracked
        return [float(np.sqrt(np.nanmean(c ** 2))) if np.isfinite(c).any() else None for c in columns.T]

    return {
        "rms_tracking_error_mm": rms(d_err),
        "rms_force_tracking_error_kN": rms(f_err),
        "method": hs.method,
        "switches": len(hs.switches),
        "switch_log": [s.as_dict() for s in hs.switches],
        "fc_step_fraction": [float(x) for x in fc_act.mean(axis=0)] if len(fc_act) else [],  # per channel
        **({"test_time_s": round(hs.lab_time_s, 3)} if hs.lab_time_s is not None else {}),
        "iterations_per_step_mean": float(its.mean()) if its.size else 0.0,
        "iterations_per_step_max": int(its.max()) if its.size else 0,
        # Steps accepted after j_max commands without reaching the tolerance.
        "nonconverged_steps": int(np.count_nonzero(~hs.converged[1:])),
        # Steps an FC element ran in DC as its force left the FC range (fc_force_limit_kN, explored_fraction).
        "guarded_steps": hs.guarded_steps,
        "wall_time_per_step_ms": float(wall.mean() * 1e3) if wall.size else 0.0,
        "thresholds": hs.thresholds,
        # FC estimates of eq. (11) within SECANT_Z sigma_k of the secant in use, turned away, per element (eq. 11a)
        **({"secant_refused": hs.secant_refused} if hs.secant_refused is not None else {}),
    }


STOP_PLOT_STEPS = 5  # committed steps shown before the unfinished one


def stop_plot(out: Path, structure: Structure, notify) -> list[str]:
    """``stop.png``: the samples before a stop in the middle of a step, from the record's
    uncommitted tables (docs/safety.md section 1); none when the run stopped between steps. A
    record that cannot be read for it is a warning: the run ends as recorded."""
    try:
        run = Run(out / RUN_FILE)
        steps, uncommitted = run.uncommitted()
        if not steps:
            return []
        last = len(steps["stop"]) - 1
        stop = {key: values[last] for key, values in steps.items()}
        mine = {key: values[uncommitted["stop"] == stop["stop"]] for key, values in uncommitted.items()}
        committed = run.samples(first_step=int(stop["step"]) - STOP_PLOT_STEPS)
        path = plots.last_samples(out / "stop.png", committed, mine, stop, channel_names(structure),
                                  units=[u for u, _ in channel_units(structure)])
        return [str(path)]
    except NotARunError as exc:
        notify(f"WARNING: the samples before the stop could not be plotted ({exc})")
        return []


def make_plots(out: Path, structure: Structure, hs: Result, ns: Result | None, config: RunConfig) -> list[str]:
    actuators = channel_names(structure)
    title = f"{structure.name}: HS vs NS, TR = {config['test']['rate']:g}"
    if ns is not None:
        worst, _ = max_error_pct(hs.u, ns.u)
        title += f", max error {worst:.2f} % of peak"
    units = channel_units(structure)
    paths = [
        plots.displacement_histories(out / "displacement.png", hs.t, hs.u, ns.t if ns is not None else None,
                                     ns.u if ns is not None else None, structure.dof_names, title,
                                     units=dof_units(structure)),
        plots.hysteresis_loops(out / "hysteresis.png", hs.measured_displacement, hs.measured_force, actuators,
                               ns.measured_displacement if ns is not None else None, ns.measured_force if ns is not None else None,
                               units=units),
        plots.tracking_error(out / "tracking.png", hs.t, hs.measured_displacement + hs.tracking_error(),
                             hs.measured_displacement, actuators,
                             config["emulator"].get("resolution_mm", 0.025), units=[u for u, _ in units]),
    ]
    return [str(p) for p in paths]
