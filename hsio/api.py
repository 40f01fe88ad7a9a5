"""hsio as a library: what a notebook or a script needs, in a few calls.

    import hsio

    structure = hsio.load_structure("validation")            # a shipped name or a TOML file
    ground = hsio.synthetic_record(duration_s=10.0, dt=structure.dt)
    ns = hsio.run_numerical(structure, ground)               # NS: specimen models, no hardware
    with hsio.open_site(structure, "emulator://", test_rate=20) as site:
        hs = hsio.simulate(structure, ground, site)          # HS: the same loop on actuators
    hs.to_dataframe()                                        # pandas (optional extra)
    hs.plot("hs.png", reference=ns)

Several records on one specimen: keep the site open and start each record from where the
specimen stands (docs/safety.md section 6):

    with hsio.open_site(structure, "emulator://") as site:
        first = hsio.simulate(structure, small, site)
        second = hsio.simulate(structure, large, site, start="present")

``hsio run`` is a thin shell over these functions (:mod:`hsio.runner`).
"""

from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass

import numpy as np

from hsio.clock import CONTROLLER_RATE_HZ, LockstepClock, RealTimeClock
from hsio.command import step_samples
from hsio.config import BOUNDS as config_bounds
from hsio.config import DEFAULTS as config_defaults
from hsio.config import IMPLICIT_OPTIONS as config_implicit_options
from hsio.config import KEYWORDS as config_keywords
from hsio.config import MIXED_GUARDS as config_guards
from hsio.control_loop import ControlLoop
from hsio.errors import ConfigError
from hsio.experiment import ExperimentStopped, excitation, run_steps, write_events
from hsio.ground_motion import GroundMotion
from hsio.hardware import open_hardware
from hsio.interfaces import ActuatorSpec
from hsio.integrators import IMPLICIT_METHODS, METHODS, ImplicitMethod, OperatorSplitting, SwitchingRule
from hsio.recording import Recorder
from hsio.result import Result
from hsio.safety.interlocks import InterlockMonitor
from hsio.safety.settings import SafetySettings
from hsio.safety.status import OperatorStop
from hsio.secant import SecantEstimator
from hsio.sites import ActuatorSite, NumericalSite
from hsio.sites.actuators import RampStopped
from hsio.sites.setup_map import SetupMap
from hsio.structures import Structure, channel_names

__all__ = ["make_integrator", "run_numerical", "open_site", "simulate", "format_readback"]


# The options of ImplicitMethod and the value that leaves each off. A method that does not take an
# option accepts it only at that value (None: not given): a switched-on option is refused, never
# dropped. The comparison minds the type, as True == 1 == 1.0 in Python.
# The options and their off values are those of [integrator] in a run configuration
# (hsio.config.IMPLICIT_OPTIONS, MIXED_GUARDS, DEFAULTS), under the keywords of ImplicitMethod.
ALPHA = config_defaults["integrator"]["alpha"]  # the default of the alpha method (-0.05)
_OFF = config_defaults["integrator"]  # anchor_dc, on by default, is the exception: is_off reads only False as off
IMPLICIT_OPTIONS = {k: _OFF[k] for k in config_implicit_options}
GUARDS = {config_keywords.get(k, k): _OFF[k] for k in config_guards}
OPTIONS_OFF = {**IMPLICIT_OPTIONS, **GUARDS}


def is_off(key: str, value) -> bool:
    """Whether ``value`` leaves option ``key`` off: None, or its off value of the same kind (a
    switch is off only at ``False``, a number only at its off number, never at a bool)."""
    off = OPTIONS_OFF[key]
    if value is None:
        return True
    if isinstance(off, bool):
        return isinstance(value, (bool, np.bool_)) and not value
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)) and value == off


def make_integrator(structure: Structure, method: str = "alpha_os", alpha: float = ALPHA, *,
                    correct_measured_displacement: bool = True, rule: SwitchingRule | None = None,
                    j_max: int = 3, tol_displacement: float = 0.02, tol_force: float = 0.05, **implicit):
    """The integration method ``method`` for ``structure`` (docs/method.md sections 2, 3 and 5).

    ``alpha_os``: operator splitting, one trial per step. ``implicit_dc``, ``force_control``,
    ``mixed``: the implicit alpha method by secant iteration (at most ``j_max`` commands per
    step, tolerances in mm and kN); ``rule`` gives the switching thresholds of ``mixed``
    (default 1.2 and 0.8 times each element's K^EI). Further keywords go to
    :class:`hsio.integrators.ImplicitMethod` (``fc_blend``, ``anchor_dc``, ``blend_dc``; for ``mixed`` the guards
    ``fallback_after``, ``refractory_steps``, ``no_fc_at_reversal``, ``explored_fraction``,
    ``fc_force_limit``; docs/force_control.md; for ``force_control`` and ``mixed``
    ``secant_uncertainty``, the instruments of FC's secant rule, eq. 11a).
    """
    _check_structure("make_integrator", structure)
    if not isinstance(method, str) or method not in METHODS:
        raise ConfigError(f"integrator method must be one of {', '.join(METHODS)}, got {method!r}")
    if not _is_number(alpha):
        raise ConfigError(f"alpha must be a number in [-1/3, 0], got {alpha!r}")
    dofs = structure.experimental_dofs
    if rule is not None and not isinstance(rule, SwitchingRule):
        raise ConfigError(f"rule must be a hsio.integrators.SwitchingRule (e.g. SwitchingRule.from_initial_stiffness"
                          f"(K_EI, K_f, K_d)), got {rule!r}")
    if rule is not None and np.size(rule.upper) != len(structure.experimental):
        raise ConfigError(f"switching rule: {np.size(rule.upper)} threshold(s) for the {len(structure.experimental)} "
                          f"experimental element(s) of structure {structure.name!r}; give one per element")
    if structure.has_setups:
        if method != "alpha_os":
            coupled = [e.name for e in structure.experimental if e.has_setup or e.is_multi_dof]
            raise ConfigError(f"structure {structure.name!r}: elements loaded through setups ({', '.join(coupled)}) "
                              f"run with method = 'alpha_os'; {method!r} iterates per actuator (docs/setups.md)")
        K_EI = structure.K_EI_basic
    else:
        K_EI = [e.K_EI for e in structure.experimental]
    if method != "mixed" and rule is not None:
        raise ConfigError(f"a switching rule applies to method = 'mixed', not to {method!r} (the other methods do "
                          f"not switch)")
    iteration = {"j_max": (j_max, _OFF["j_max"]), "tol_displacement": (tol_displacement, _OFF["tol_displacement_mm"]),
                 "tol_force": (tol_force, _OFF["tol_force_kN"])}
    if method == "alpha_os":
        given = [k for k, (value, default) in iteration.items() if value is not None and value != default]
        if given:
            raise ConfigError(f"{', '.join(given)}: not an option of method = 'alpha_os' (one trial per step, no "
                              f"iteration); they apply to the implicit methods")
    if method != "alpha_os" and not correct_measured_displacement:
        raise ConfigError(f"correct_measured_displacement applies to alpha_os; {method!r} iterates to the target")
    secant_uncertainty = implicit.pop("secant_uncertainty", None)  # FC's secant rule (eq. 11a)
    if secant_uncertainty is not None and method not in ("force_control", "mixed"):
        raise ConfigError(f"secant_uncertainty: not an option of method = {method!r} (it applies to the elements in "
                          f"force control, methods 'force_control' and 'mixed')")
    unknown = sorted(set(implicit) - set(OPTIONS_OFF))
    if unknown:
        raise ConfigError(f"make_integrator: unknown option(s) {', '.join(unknown)}")
    anchor = implicit.get("anchor_dc")
    one_per_element = (isinstance(anchor, (list, tuple, np.ndarray)) and np.ndim(anchor) == 1
                       and len(anchor) == len(structure.experimental)
                       and all(isinstance(a, (bool, np.bool_)) for a in anchor))
    if anchor is not None and not isinstance(anchor, (bool, np.bool_)) and not one_per_element:
        raise ConfigError(f"anchor_dc must be True or False, or one of them per experimental element "
                          f"({len(structure.experimental)}), got {anchor!r}")
    if method == "alpha_os":  # no secant line to anchor: alpha-OS takes the measured force as it is
        implicit.pop("anchor_dc", None)
    allowed = (set(IMPLICIT_OPTIONS) if method != "alpha_os" else set()) | (set(GUARDS) if method == "mixed" else set())
    misplaced = sorted(k for k, v in implicit.items() if k not in allowed and not is_off(k, v))
    if misplaced:
        takes = "the implicit methods" if misplaced[0] in IMPLICIT_OPTIONS else "method = 'mixed'"
        raise ConfigError(f"{', '.join(misplaced)}: not an option of method = {method!r} "
                          f"({misplaced[0]} applies to {takes})")
    implicit = {k: v for k, v in implicit.items() if k in allowed and v is not None}  # None: off, the default
    if secant_uncertainty is not None:
        implicit["secant_uncertainty"] = secant_uncertainty
    if method == "alpha_os":
        return _built_for(structure, OperatorSplitting(structure.M, structure.C, structure.K_init, structure.dt, alpha,
                                                       dofs, K_EI, correct_measured_displacement,
                                                       structure.experimental_refs))
    numerical = structure.numerical_assembly()
    if not numerical.is_linear:
        raise ConfigError(f"structure {structure.name!r}: the implicit methods ({', '.join(IMPLICIT_METHODS)}) take "
                          f"linear numerical elements only (the secant model of eq. 9 covers the experimental "
                          f"elements); use method = 'alpha_os'")
    return _built_for(structure, ImplicitMethod(structure.M, structure.C, numerical.K_linear, dofs, K_EI, structure.dt,
                                                alpha, method, rule, structure.dof_names, j_max=j_max,
                                                tol_displacement=tol_displacement, tol_force=tol_force,
                                                element_refs=structure.experimental_refs, **implicit))


def _same_structure(a: Structure, b: Structure) -> bool:
    """Whether ``a`` and ``b`` are one structure: the same object, or equal field by field."""
    try:
        return a is b or bool(a == b)
    except (ValueError, TypeError):  # a field that compares element-wise (an array)
        return False


def _built_for(structure: Structure, thing):
    """``thing`` (an integrator, a numerical site) marked with the structure it was built for, which
    :func:`simulate` compares with the structure it runs."""
    thing.built_for = structure
    return thing


def run_numerical(structure: Structure, ground: GroundMotion, method: str = "alpha_os", alpha: float = ALPHA,
                  control=None, **options) -> Result:
    """NS: the run with the specimen models in place of the actuators.

    For the implicit methods the reference is implicit DC iterated to 1e-10 (at most 20
    iterations): the converged solution that any of them approaches.
    """
    _check_structure("run_numerical", structure)
    if not isinstance(method, str):
        raise ConfigError(f"run_numerical: method must be one of {', '.join(METHODS)}, got {method!r}")
    if method in IMPLICIT_METHODS:
        if options:
            raise ConfigError(f"run_numerical: the reference of the implicit methods is implicit DC converged "
                              f"to 1e-10; it takes no options (got {', '.join(sorted(options))})")
        integrator = make_integrator(structure, "implicit_dc", alpha, j_max=20, tol_displacement=1e-10,
                                     tol_force=1e-10)
    else:
        integrator = make_integrator(structure, method, alpha, **options)
    return simulate(structure, ground, NumericalSite.of(structure), integrator=integrator, control=control)


def open_site(structure: Structure, hardware: str = "emulator://", *, clock: str = "lockstep",
              test_rate: float = 20.0, hold_fraction: float = 0.5, n_avg: int = 4, keep_samples: bool = True,
              options: dict | None = None, estimator: SecantEstimator | None = None,
              compensation=None, relative: bool = False, safety: SafetySettings | None = None) -> ActuatorSite:
    """Open the actuators of ``structure``'s experimental elements at ``hardware`` (a URL:
    ``emulator://``, ``modbus+tcp://HOST:PORT``, ...) behind the controller-rate loop.

    ``options`` is the [emulator] table for ``emulator://`` and the [driver] table otherwise.
    ``relative``: every displacement command and measurement is taken from the actuators'
    positions when the site opens (docs/setups.md); ``site.readback`` holds the reading of every
    channel taken then, before the first command (:func:`format_readback` shows it).
    Use it as a context manager (or call ``close()``): the actuators are left holding.
    ``safety`` sets the interlocks checked every controller period (docs/safety.md section 3;
    default: the documented defaults, on).
    """
    _check_site_arguments(structure, hardware, options, estimator, compensation, safety)
    safety = safety or SafetySettings()
    check_test_settings(test_rate, hold_fraction, n_avg)
    averaged = [("", n_avg)]
    if estimator is not None and estimator.method == "average":  # it averages the last n_avg samples too
        averaged.append(("the secant estimator's ", estimator.n_avg))
    for whose, count in averaged:
        try:
            check_dwell(structure.dt, test_rate, hold_fraction, count)
        except ConfigError as exc:
            raise ConfigError(f"open_site: {whose}{exc}") from None
    t_d = test_rate * structure.dt
    if compensation is not None and not math.isclose(getattr(compensation, "t_d", t_d), t_d, rel_tol=1e-9):
        raise ConfigError(f"open_site: the compensation stage was built for t_d = {compensation.t_d:g} s, and a step "
                          f"here lasts test_rate x dt = {test_rate:g} x {structure.dt:g} s = {t_d:g} s; build it with "
                          f"CompensationStage(names, {t_d:g}, ...)")
    if not structure.experimental:
        raise ConfigError(f"structure {structure.name!r} has no experimental elements: there is nothing for the "
                          f"actuators to load; run it with hsio.run_numerical")
    if clock not in ("lockstep", "realtime"):
        raise ConfigError(f"clock must be 'lockstep' or 'realtime', got {clock!r}")
    check_instruments(structure, hardware, options)  # before any axis is enabled
    ticker = LockstepClock() if clock == "lockstep" else RealTimeClock()
    elements = list(structure.experimental) + list(structure.static)  # static preloads after the channels
    actuators = open_hardware(hardware, elements, ticker, options or {})
    try:
        monitor = InterlockMonitor(actuators, safety) if safety.interlocks else None
        loop = ControlLoop(actuators, ticker, structure.dt, test_rate, n_avg=n_avg, keep_samples=keep_samples,
                           hold_fraction=hold_fraction, monitor=monitor)
    except BaseException:
        for actuator in actuators:
            try:
                actuator.close()
            except Exception:
                pass
        raise
    try:
        setups = SetupMap.of(structure) if structure.has_setups else None
        instruments = external = None
        if structure.instruments:
            instruments = open_instruments(hardware, structure, elements, actuators, options or {})
            # per channel (an element with a setup has one per basic DOF and takes no instrument)
            external = [(e.displacement_from, e.outer_loop) if e.displacement_from else None
                        for e in structure.experimental for _ in e.basic_dofs]
        site = ActuatorSite(loop, estimator, compensation, setups, structure.static, instruments, external, relative,
                            safety)
        if external is not None:
            by_name = {i.name: i for i in structure.instruments}
            site.displacement_instruments = [None if src is None else (float(by_name[src[0]].noise),
                                                                      float(by_name[src[0]].resolution))
                                             for src in external]
        site.opened_for = OpenedFor(structure.name, tuple(channel_names(structure)), float(structure.dt))
        return site
    except BaseException:
        loop.close()
        raise


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def check_test_settings(test_rate, hold_fraction, n_avg) -> None:
    """The test settings of :func:`open_site`, refused outside the bounds of a run's [test] table
    (docs/config.md), before any actuator is opened."""
    low, high, _ = config_bounds[("test", "rate")]
    if not (_is_number(test_rate) and low <= test_rate <= high):
        raise ConfigError(f"open_site: test_rate must be a number in [{low:g}, {high:g}], got {test_rate!r}")
    if not (_is_number(hold_fraction) and 0.0 <= hold_fraction < 1.0):
        raise ConfigError(f"open_site: hold_fraction must be a number in [0, 1), got {hold_fraction!r}")
    low, high, _ = config_bounds[("test", "n_avg")]
    if not (isinstance(n_avg, numbers.Integral) and not isinstance(n_avg, (bool, np.bool_)) and low <= n_avg <= high):
        raise ConfigError(f"open_site: n_avg must be a whole number of controller periods in [{low}, {high}], "
                          f"got {n_avg!r}")


def dwell_periods(dt: float, test_rate: float, hold_fraction: float, rate_hz: float = CONTROLLER_RATE_HZ) -> int:
    """The controller periods a step's measurement can average: those of its dwell (hold_fraction
    > 0), or of the whole step (continuous ramps, or a dwell that rounds to nothing), counted as
    the command generator counts them (:func:`hsio.command.step_samples`)."""
    periods, dwell = step_samples(test_rate * dt, 1.0 / rate_hz, hold_fraction)
    return dwell if dwell >= 1 else periods


def _report_preloads_short(site, recorder) -> None:
    """A preload the ramp-in left beyond PRELOAD_REACHED of its target after holding as long again
    as the ramp (a soft load train, a slow force loop): the record starts under it, and a warning
    (printed, and an event of the record) says by how much."""
    for name, short in site.preloads_short():
        message = f"{short}; the record starts under it (lengthen ramp_s, or check the load train)"
        warnings.warn(message, stacklevel=3)
        if recorder is not None:
            recorder.write_event(site.lab_time_s, 0, "warning", name, message)


def _ramp_pause(control, site, recorder, ramp: str, step: int):
    """An operator's pause between two steps of a ramp of the static preloads: the run holds
    there as between two steps of the record (``control.checkpoint``), its pause and resume
    recorded as events at ``step`` (the last step of the record done); None without a control."""
    if control is None:
        return None

    def log(kind: str, message: str) -> None:
        if recorder is not None:
            recorder.write_event(site.lab_time_s, step, kind, "", f"{message} (in the {ramp} of the static preloads)")

    return lambda: control.checkpoint(site, step, log)


def check_instruments(structure: Structure, hardware: str, options: dict | None = None) -> None:
    """The structure's instruments can be read on ``hardware``: on the emulator each names an
    element without a setup (what it reads); elsewhere the driver option ``instruments`` gives
    the DAQ module. Checked before anything opens (``hsio check`` and ``hsio run`` before the
    run folder too)."""
    emulated = hardware.startswith("emulator://")
    rigged = {e.name for e in structure.experimental if (e.has_setup or e.is_multi_dof) and not e.is_parallel}
    for inst in structure.instruments:
        if emulated and not inst.element:
            raise ConfigError(f"instrument {inst.name!r} names no element: the emulator has nothing for it to read "
                              f"(give its element)")
        if emulated and inst.element in rigged:
            raise ConfigError(f"instrument {inst.name!r} reads element {inst.element!r}, which is loaded through a "
                              f"setup: the emulator emulates instruments on elements without setups or with a "
                              f"'parallel' one only")
    if structure.instruments and not emulated and not (options or {}).get("instruments"):
        raise ConfigError(f"structure {structure.name!r} names instruments; give the DAQ module's URL as the "
                          f"driver option 'instruments' (modbus+tcp://HOST:PORT)")


STEP_ROUNDING = 0.05  # a step's whole controller periods may differ this much from TR x dt, no more


def check_step_periods(dt: float, test_rate: float, key: str = "test_rate", rate_hz: float = CONTROLLER_RATE_HZ) -> None:
    """A step lasts whole controller periods: a TR x dt that they miss by more than
    :data:`STEP_ROUNDING` (a step shorter than one period, say) would run the test at another
    test rate than the one asked, and is refused, naming ``key``."""
    periods, _ = step_samples(test_rate * dt, 1.0 / rate_hz)
    t_d, lasts = test_rate * dt, periods / rate_hz
    if abs(lasts - t_d) > STEP_ROUNDING * t_d:
        raise ConfigError(f"{key} = {test_rate:g}: a step lasts TR x dt = {test_rate:g} x {dt:g} s = {t_d:.3g} s, and the "
                          f"controller moves in whole periods of 1/{rate_hz:g} s: {periods} period(s), {lasts:.3g} s, "
                          f"would run the test at TR {lasts / dt:.3g}, not {test_rate:g}. Give a test rate whose step "
                          f"is within {STEP_ROUNDING:.0%} of whole periods (any TR from {10 / (rate_hz * dt):.3g} is)")


def check_dwell(dt: float, test_rate: float, hold_fraction: float, n_avg: int,
                rate_hz: float = CONTROLLER_RATE_HZ) -> None:
    """The measurement of a step averages its last ``n_avg`` controller periods: they must lie in
    the step's dwell (:func:`dwell_periods`), never reach back into the ramp or the step before;
    and the step itself is whole controller periods (:func:`check_step_periods`)."""
    check_step_periods(dt, test_rate, rate_hz=rate_hz)
    periods, dwell = step_samples(test_rate * dt, 1.0 / rate_hz, hold_fraction)
    limit = dwell if dwell >= 1 else periods  # dwell_periods
    if n_avg > limit:
        what = (f"the dwell of a step: {dwell} periods (TR {test_rate:g} x dt {dt:g} s x {rate_hz:g} Hz x "
                f"hold_fraction {hold_fraction:g})" if dwell >= 1 else
                f"a step: {periods} periods (TR {test_rate:g} x dt {dt:g} s x {rate_hz:g} Hz)")
        raise ConfigError(f"n_avg = {n_avg} controller periods is more than {what}; the average would take in the "
                          f"motion before it. Give n_avg at most {limit}, or a slower test rate")


def _check_structure(where: str, structure) -> None:
    if not isinstance(structure, Structure):
        hint = f" (hsio.load_structure({structure!r}))" if isinstance(structure, str) else ""
        raise ConfigError(f"{where}: structure must be a hsio.Structure{hint}, got {type(structure).__name__}")


def _check_site_arguments(structure, hardware, options, estimator, compensation, safety) -> None:
    """The types of :func:`open_site`'s arguments, named, before anything opens."""
    from hsio.compensation.stage import CompensationStage

    _check_structure("open_site", structure)
    expected = [("hardware", hardware, str, "a URL string such as 'emulator://'"),
                ("options", options, (dict, type(None)), "a dict (the [emulator] or [driver] table) or None"),
                ("estimator", estimator, (SecantEstimator, type(None)), "a hsio.secant.SecantEstimator or None"),
                ("compensation", compensation, (CompensationStage, type(None)),
                 "a hsio.compensation.stage.CompensationStage or None"),
                ("safety", safety, (SafetySettings, type(None)), "a hsio.safety.settings.SafetySettings or None")]
    for name, value, kind, what in expected:
        if not isinstance(value, kind):
            raise ConfigError(f"open_site: {name} must be {what}, got {value!r}")


@dataclass(frozen=True)
class OpenedFor:
    """What an actuator site was opened for: the structure's name, its channels and time step."""

    name: str
    channels: tuple
    dt: float


def check_run_inputs(structure: Structure, ground, site, start: str = "rest") -> None:
    """What :func:`simulate` is given, checked before the first step: a ground motion of one
    component, a site that is still open, was opened for this structure (its channels and time
    step) and, once it has run, is started from where the specimen stands (``start="present"``)."""
    if not isinstance(structure, Structure):
        raise ConfigError(f"simulate: structure must be a hsio.Structure, got {type(structure).__name__}")
    if not isinstance(ground, GroundMotion):
        raise ConfigError(f"simulate: ground must be a hsio.GroundMotion (hsio.read_at2, hsio.synthetic_record or "
                          f"hsio.GroundMotion(name, dt, accel_g)), got {type(ground).__name__}")
    if np.ndim(ground.accel_g) != 1:
        raise ConfigError(f"ground motion {ground.name!r}: accel_g must be one component (a 1-D array), got shape "
                          f"{np.shape(ground.accel_g)}")
    if start not in ("rest", "present"):
        raise ConfigError(f"simulate: start must be 'rest' or 'present', got {start!r}")
    if not hasattr(site, "set_trial"):
        raise ConfigError(f"simulate: site must be a site from hsio.open_site (or a NumericalSite), got {site!r}")
    if isinstance(site, NumericalSite):
        built = getattr(site, "built_for", None)
        channels = tuple(channel_names(structure))
        if (built is not None and not _same_structure(built, structure)) or site.n_elements != len(channels):
            whose = f"structure {built.name!r}" if built is not None else f"{site.n_elements} channel(s)"
            raise ConfigError(f"simulate: the NumericalSite holds the specimen models of {whose}, not of "
                              f"{structure.name!r} (channels {', '.join(channels)}); build it with "
                              f"NumericalSite.of(structure)")
    if isinstance(site, ActuatorSite):
        if getattr(site, "final_hold", None) is not None:
            raise ConfigError("simulate: the site is closed (its actuators were released); open a new one with "
                              "hsio.open_site")
        if not structure.experimental:
            raise ConfigError(f"structure {structure.name!r} has no experimental elements: a hybrid run needs at "
                              f"least one; run it with hsio.run_numerical")
        opened = getattr(site, "opened_for", None)
        if opened is not None:
            channels = tuple(channel_names(structure))
            if channels != opened.channels or not math.isclose(structure.dt, opened.dt, rel_tol=1e-12):
                raise ConfigError(f"simulate: the site was opened for structure {opened.name!r} (actuators "
                                  f"{', '.join(opened.channels)}, dt {opened.dt:g} s), not for {structure.name!r} "
                                  f"(actuators {', '.join(channels)}, dt {structure.dt:g} s); nothing moved. Open a "
                                  f"site for this structure")
        if getattr(site, "moved", False) and start == "rest":
            raise ConfigError("simulate: this site has run a record already, and its actuators stand where that run "
                              "left them, not at rest: start=\"present\" goes on from there (docs/safety.md section "
                              "6), or open a new site to start a test from rest; nothing moved")
        if start == "rest" and not getattr(site, "moved", False) and hasattr(site, "check_instruments_at_rest"):
            site.check_instruments_at_rest()


def format_readback(readback: dict[str, float], units: dict[str, str] | None = None) -> str:
    """The initial reading of every channel as a table, one channel a line, to be checked before
    the test starts (docs/setups.md)."""
    units = units or {}
    width = max((len(k) for k in readback), default=7)
    lines = [f"{'channel':<{width}}  {'value':>12}  unit"]
    for name, value in readback.items():
        unit = units.get(name) or ("mm" if name.endswith(".displacement") else "kN" if name.endswith(".force") else "")
        lines.append(f"{name:<{width}}  {value:>12.4f}  {unit}")
    return "\n".join(lines)


def open_instruments(hardware: str, structure: Structure, elements, actuators, options: dict):
    """The DAQ of ``structure``'s external instruments: emulated beside ``emulator://`` actuators,
    else the Modbus DAQ module named by ``options['instruments']`` (docs/setups.md)."""
    if hardware.startswith("emulator://"):
        from hsio.emulators.local import open_instruments as emulated

        return emulated(structure.instruments, elements, actuators)
    url = options.get("instruments")
    if not url:
        raise ConfigError(f"structure {structure.name!r} names instruments; give the DAQ module's URL as the "
                          f"driver option 'instruments' (modbus+tcp://HOST:PORT)")
    from hsio.drivers.modbus_daq import open_daq

    return open_daq(url, structure.instruments, options.get("instrument_map"))


def simulate(structure: Structure, ground: GroundMotion, site, method: str = "alpha_os", alpha: float = ALPHA,
             recorder: Recorder | None = None, progress=None, integrator=None, control=None, start: str = "rest",
             resume_state=None, **options) -> Result:
    """``method`` over the whole record against ``site``: HS on actuators (from :func:`open_site`),
    NS on a :class:`~hsio.sites.NumericalSite`.

    ``start="present"`` starts from where the specimen stands (the site's committed state, e.g.
    after an earlier record on the same open site); ``control`` (a
    :class:`hsio.safety.control.RunControl`) pauses, resumes or stops the run between steps.

    ``options`` go to :func:`make_integrator` (or pass a ready ``integrator``). Raises :class:`hsio.experiment.ExperimentStopped`
    (carrying the steps made, the actuators holding) if the run stops early.
    """
    check_run_inputs(structure, ground, site, start)
    if integrator is not None and not hasattr(integrator, "step"):
        raise ConfigError(f"simulate: integrator must be an integrator from make_integrator, got {integrator!r} (to "
                          f"choose a method by name, pass method=...)")
    built = getattr(integrator, "built_for", None)
    if built is not None and not _same_structure(built, structure):
        raise ConfigError(f"simulate: the integrator was made for structure {built.name!r}, not for "
                          f"{structure.name!r}; make it with make_integrator(structure, ...)")
    if progress is not None and not callable(progress):
        raise ConfigError(f"simulate: progress must be a callable (called with 1 after each step, such as a tqdm "
                          f"bar's update) or None, got {progress!r}")
    if recorder is not None and not hasattr(recorder, "write_step"):
        raise ConfigError(f"simulate: recorder must be a hsio.recording.Recorder or None, got {recorder!r}")
    if integrator is None:
        integrator = make_integrator(structure, method, alpha, **options)
    else:
        ignored = sorted(options) + (["method"] if method != "alpha_os" and method != getattr(integrator, "method", method)
                                     else []) + (["alpha"] if alpha != ALPHA else [])
        if ignored:
            raise ConfigError(f"simulate: {', '.join(ignored)} given beside a ready integrator, which they would not "
                              f"change; build the integrator with them (make_integrator), or leave them out")
    if start == "present" and (getattr(integrator, "method", "") != "alpha_os" or not hasattr(integrator, "core")):
        raise ConfigError(f"simulate: start = 'present' is available for the alpha_os method, not "
                          f"{getattr(integrator, 'method', integrator)!r} (docs/safety.md section 6); nothing moved")
    if (getattr(integrator, "method", "") in ("force_control", "mixed") and isinstance(site, ActuatorSite)
            and site.estimator is None):
        warnings.warn(f"{integrator.method}: the site has no secant estimator, so eq. (11) is taken on each "
                      f"step's averaged measurement, whose noise near the peaks misleads force control (a linear "
                      f"SDOF: 10 to 14 % off NS, against 1.5 to 1.9 % with open_site(..., estimator="
                      f"SecantEstimator('average', 16, 0.1)); docs/api.md)", stacklevel=2)
    static = getattr(site, "static", None)
    if not static and getattr(site, "instruments", None) is None:
        return run_steps(structure, ground, integrator, site, recorder, progress, control=control, start=start,
                         resume_state=resume_state)
    # static preloads (docs/setups.md): ramped in before the record, held through it, ramped off;
    # an operator's stop (control) ends a ramp where it stands
    stop = (lambda: control.stop_requested) if control is not None else None
    if static:
        excitation(structure, ground)  # a record refused before the preloads move anything
        site.moved = True  # the preloads move the actuators from here
    phase = control.phase if control is not None else ""
    try:
        if control is not None and static:  # the status the operator sees (the page, the socket)
            control.phase = "ramp-in"
        site.preload(stop=stop, pause=_ramp_pause(control, site, recorder, "ramp in", 0))
        _report_preloads_short(site, recorder)
    except BaseException as exc:
        site.hold()
        lost = None
        if recorder is not None and static:  # the ramp as far as it went (a trip: the period that tripped last)
            try:
                recorder.write_tables(site.record_tables())
            except Exception as write_error:  # the stop or trip stays what is raised; the failed write joins it
                lost = f"the preload ramp's tables could not be written to the record: {write_error}"
                exc.add_note(lost)
        if isinstance(exc, RampStopped):
            stop = OperatorStop(f"{control.stop_reason}: {exc}")
            if lost:
                stop.add_note(lost)
            raise stop from None
        raise
    if control is not None:
        control.phase = phase
    try:
        result = run_steps(structure, ground, integrator, site, recorder, progress, control=control, start=start,
                           resume_state=resume_state)
        try:
            if control is not None and static:
                control.phase = "ramp-off"
            site.release(stop=stop, pause=_ramp_pause(control, site, recorder, "ramp off", result.steps))
        except (Exception, KeyboardInterrupt) as exc:  # the record is complete: keep it, say where the ramp stood
            hold = site.hold()
            cause = OperatorStop(control.stop_reason) if isinstance(exc, RampStopped) else exc
            result.stopped = f"the ramp off of the static preloads, after the record: {exc}"
            if recorder is not None:  # the trip (if any), the hold and the stop, as after a stop in the record
                try:
                    write_events(recorder, site, result.steps)
                    recorder.write_event(site.lab_time_s, result.steps, "hold", "", hold.message, commit=False)
                    recorder.write_event(site.lab_time_s, result.steps, "stop", "", result.stopped)
                except Exception:
                    pass  # the record keeps what it has; the stop is raised below
            raise ExperimentStopped(f"run stopped in {result.stopped}; {hold.message}; {result.steps} steps recorded",
                                    result, cause, hold) from None
    except ExperimentStopped as exc:  # the partial result keeps the logs as far as they go
        _site_logs(exc.result, site, static)
        raise
    finally:
        if recorder is not None:
            recorder.write_tables(site.record_tables())
    return _site_logs(result, site, static)


def _site_logs(result: Result, site, static) -> Result:
    """``result`` with the site's preload and instrument logs (docs/setups.md)."""
    if static:
        result.static_log = list(site.static_log)
        result.static_hold_error = site.static_hold_error()
        result.static_ramps = {phase: dict(peaks) for phase, peaks in site.ramp_peaks.items()}
    result.instrument_log = list(site.instrument_log)
    return result
