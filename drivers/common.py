"""What the Modbus and CANopen drivers share: the [driver] options, the actuator limits, the
cyclic submit, closing the link with its last axis, and opening every axis safely.

Opening is in this order (:func:`open_axes`): connect and identify (nothing enabled), read the
limits, check the controller's clock against the experiment's, and only then enable the axes.
A failure at any point holds (disables) whatever was enabled and closes the link; the error then
says whether the axes were disabled.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from urllib.parse import urlsplit

from hsio.errors import ConfigError, HsioError
from hsio.interfaces import Limits, query_pairs

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Rule:
    """A numeric [driver] option: its type and the range a sane value lies in."""

    kind: type  # int or float
    low: float
    high: float
    low_open: bool = False  # True: the value must be greater than ``low``
    text: str = ""

    def check(self, url: str, key: str, value):
        where = f"[driver] for {url!r}: {key}"
        if isinstance(value, bool):
            raise ConfigError(f"{where} must be a number, got {value!r}")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{where} must be a number, got {value!r}") from None
        if self.kind is int:
            if not number.is_integer():
                raise ConfigError(f"{where} must be a whole number, got {value!r}")
            number = int(number)
        if not math.isfinite(number) or number > self.high or number < self.low \
                or (self.low_open and number == self.low):
            raise ConfigError(f"{where} must be {self.text}, got {value!r}")
        return number


def positive(high: float, unit: str) -> Rule:
    return Rule(float, 0.0, high, True, f"positive and at most {high:g} {unit}")


def whole(low: int, high: int) -> Rule:
    return Rule(int, low, high, False, f"a whole number in {low}..{high}")


# The options both drivers have.
COMMON_RULES = {
    "timeout_s": positive(60.0, "s"),
    "retries": whole(0, 20),
    "reconnect_delay_s": Rule(float, 0.0, 10.0, False, "between 0 and 10 s"),
    "stroke_mm": positive(10000.0, "mm (the total stroke)"),
    "force_kN": positive(100000.0, "kN"),
    "velocity_mm_s": positive(10000.0, "mm/s"),
}


def parse_options(url: str, options: dict | None, defaults: dict, rules: dict[str, Rule]) -> dict:
    """The [driver] table and the URL's query (the query wins), each value checked.

    A key without a rule is a string; a default of None means "not set" (the controller's own).
    """
    table = dict(defaults)
    given = {**(options or {}), **dict(query_pairs(url, split_url(url).query))}
    for key, value in given.items():
        if key not in defaults:
            raise ConfigError(f"[driver] for {url!r}: unknown key {key!r}; known: {', '.join(defaults)}")
        rule = rules.get(key)
        if rule is None:
            table[key] = str(value)
        elif value is None and defaults[key] is None:
            table[key] = None
        else:
            table[key] = rule.check(url, key, value)
    return table


def reported(value) -> float | None:
    """A limit the controller reported, or None when it gave none (absent, zero, not finite)."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) and value > 0 else None


WIDER_TOLERANCE = 1e-6  # relative: a float32 register rounds a limit by less


def resolve_limits(url: str, options: dict, stroke_mm: float | None, force_kN: float | None,
                   stroke_why: str = "", force_why: str = "", stroke_from: str = "", force_from: str = "") -> Limits:
    """The actuator limits: [driver] stroke_mm / force_kN where set, else the controller's own.

    Neither is ever guessed: a limit the controller does not report must be configured. A
    configured limit tighter than the controller's is a software limit inside the hardware's
    and is taken; one wider than the controller's reported limit is refused (:func:`configured`).
    ``*_why`` says why the controller reports none, ``*_from`` where a reported one comes from.
    """
    stroke = configured(url, options, "stroke_mm", reported(stroke_mm), "stroke", "mm", stroke_from)
    if stroke is None:
        raise ConfigError(f"{url}: the controller does not report its stroke{stroke_why}; set [driver] stroke_mm "
                          "(the total stroke in mm, centred on zero)")
    force = configured(url, options, "force_kN", reported(force_kN), "force capacity", "kN", force_from)
    if force is None:
        raise ConfigError(f"{url}: the controller does not report its force capacity{force_why}; set [driver] "
                          "force_kN (the force capacity in kN)")
    return Limits(float(stroke), float(force), float(options["velocity_mm_s"]))


def configured(url: str, options: dict, key: str, controller: float | None, what: str, unit: str,
               source: str = "") -> float | None:
    """[driver] ``key`` where set, else the controller's reported limit (None: neither).

    A configured limit may be tighter than the controller's, never wider: a limit beyond the
    hardware's would let commands past that the controller cannot carry out, and the dry run
    and every check on the host would judge against a range the actuator does not have. So a
    configured value above the reported one (by more than the rounding of a float32 register)
    is a ConfigError naming the key and both values, raised before anything is enabled.
    """
    value = options[key]
    if value is None:
        return controller
    if controller is not None and value > controller * (1.0 + WIDER_TOLERANCE):
        raise ConfigError(f"{url}: [driver] {key} = {value:g} {unit} is wider than the {what} the controller reports, "
                          f"{controller:g} {unit}{source}; a configured limit may be tighter than the controller's, "
                          f"never wider: set {key} to at most {controller:g} or leave it out")
    return float(value)


def check_clock(url: str, lockstep: bool, clock, rate_hz: float | None = None) -> None:
    """The controller's clock and the experiment's must agree (lockstep or real time); in
    lockstep each tick is one period of both, so the controller's loop rate (``rate_hz``, where
    it reports one) must be the experiment's."""
    lockstep_clock = bool(getattr(clock, "lockstep", False))
    if lockstep and lockstep_clock and rate_hz is not None and abs(rate_hz - clock.rate_hz) > 1e-9 * clock.rate_hz:
        raise ConfigError(f"{url}: the controller runs in lockstep at {rate_hz:g} Hz (its loop rate), the experiment "
                          f"at {clock.rate_hz:g} Hz: each tick is one period of both, so the controller's time would "
                          "not be the experiment's; run the controller at the experiment's rate")
    if lockstep and not lockstep_clock:
        raise ConfigError(f"{url}: the controller runs in lockstep (emulator) but the experiment's clock is real "
                          "time; set [hardware] clock = \"lockstep\" or start the emulator with --realtime")
    if not lockstep and lockstep_clock:
        raise ConfigError(f"{url}: the controller runs on its own clock (real time) but the experiment's clock is "
                          "lockstep; set [hardware] clock = \"realtime\"")


class AxisLink:
    """The part of a link its axes share: the cyclic submit and closing with the last axis.

    A subclass sets ``n``, ``lockstep``, ``submitted`` and ``actuators`` and implements
    ``open(enable)``, ``axis_limits()``, ``enable()``, ``cycle()``, ``disable()`` and ``close()``.
    """

    def submit(self, axis: int) -> None:
        """An axis has a new command; in real time, send once every axis has one."""
        self.submitted.add(axis)
        if not self.lockstep and len(self.submitted) == self.n:
            self.cycle()

    def axis_closed(self) -> None:
        """Close the link once every axis on it is closed."""
        if all(getattr(a, "_closed", True) for a in self.actuators):
            self.close()

    def may_be_enabled(self) -> bool:
        """Whether an axis on the link may have been enabled (opening got that far)."""
        drives = getattr(self, "drives", None)
        if drives is not None:
            return any(getattr(d, "enabling", False) for d in drives)
        return bool(getattr(self, "enabling", False))

    def abort(self) -> str:
        """Opening failed: disable whatever was enabled (best effort), then close. Returns what
        became of the axes, for the error's message ("" when none had been enabled). The hold
        is not read back here: the message says so, and says when the disable itself failed."""
        enabled = self.may_be_enabled()
        try:
            self.disable()
            outcome = "the axes were disabled (the controller acknowledged; the hold not read back)"
        except Exception as exc:
            log.warning("%s: could not disable the axes while giving up: %s", getattr(self, "url", "?"), exc)
            outcome = f"WARNING: the axes could not be disabled ({exc}); the hold could not be confirmed"
        finally:
            self.close()
        return outcome if enabled else ""


def close_axis(actuator) -> None:
    """Close one axis: hold it, and close the link when it was the last open axis."""
    if actuator._closed:
        return
    actuator._closed = True
    try:
        actuator.hold()
    finally:
        actuator.link.axis_closed()


def open_axes(link: AxisLink, names: list[str], clock, make_actuator, enable: bool = True) -> list:
    """Identify, read the limits, check the clock, then enable; on any failure hold what was
    enabled and close. ``clock=None`` skips the clock check (diagnostics decide the clock from
    ``link.lockstep``)."""
    try:
        link.open(enable=False)
        limits = link.axis_limits()
        if clock is not None:
            check_clock(link.url, link.lockstep, clock, getattr(link, "reported_rate_hz", None))
        if enable:
            link.enable()
        actuators = [make_actuator(name, link, k, limits[k]) for k, name in enumerate(names)]
        link.actuators = actuators
        if clock is not None and link.lockstep:
            clock.attach(link)
        return actuators
    except BaseException as exc:
        outcome = link.abort()
        if outcome and isinstance(exc, HsioError) and exc.args:  # the message says how the axes were left
            exc.args = (f"{exc.args[0]}; {outcome}",) + exc.args[1:]
        raise


def split_url(url: str):
    """``urlsplit`` whose refusal (a broken IPv6 address, a bad port) is a ConfigError naming the URL."""
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 (raises ValueError for a bad port)
        return parts
    except ValueError as exc:
        raise ConfigError(f"hardware URL {url!r} is malformed ({exc}); expected SCHEME://HOST:port or a device path") from None


def url_port(url: str, default: int) -> int:
    """The port of a URL; a port that is not a number in 1..65535 is a ConfigError naming the URL."""
    try:
        port = urlsplit(url).port
    except ValueError as exc:
        raise ConfigError(f"hardware URL {url!r}: bad port ({exc}); expected a number in 1..65535") from None
    if port is None:
        return default
    if not 1 <= port <= 65535:
        raise ConfigError(f"hardware URL {url!r}: port {port} is not in 1..65535")
    return port


def emcy_code(text: str) -> int:
    """A CANopen EMCY error code written as text (hexadecimal with 0x, or decimal): 0x0100..0xFFFF
    (0x00xx is the error reset). ValueError, with the reason, for anything else."""
    try:
        code = int(text, 0)
    except ValueError:
        raise ValueError(f"{text!r} is not an EMCY code (e.g. 0x4210)") from None
    if not 0x0100 <= code <= 0xFFFF:
        raise ValueError(f"{text} is not an EMCY error code (0x0100..0xFFFF; 0x00xx is the error reset)")
    return code


# [driver] options of the plausibility check (docs/faults.md), shared by both drivers.
PLAUSIBILITY_DEFAULTS = {"jump_floor_mm": 2.0, "stuck_samples": 512, "stuck_mm": 5.0, "force_stuck_samples": 512,
                         "force_stuck_mm": 1.0}
PLAUSIBILITY_RULES = {
    "jump_floor_mm": positive(1000.0, "mm"),
    "stuck_samples": whole(0, 1_000_000),
    "force_stuck_samples": whole(0, 1_000_000),
    "force_stuck_mm": positive(1000.0, "mm"),
    "stuck_mm": positive(1000.0, "mm"),
}


class Plausibility:
    """Checks every measured sample of one axis before the experiment sees it (docs/faults.md).

    Refused, as :class:`~hsio.errors.ImplausibleMeasurementError` (an interlock: the run stops, holds
    the actuators and reads the hold back):

    * a value that is not finite (NaN, infinity);
    * a displacement beyond twice the half stroke, a force beyond twice the capacity;
    * a displacement that moved faster than twice the velocity limit since the last sample (plus
      ``jump_floor_mm`` for noise and quantisation), a force that changed by more than half the
      capacity between two samples;
    * a stuck transducer: the same displacement reading, bit for bit, for ``stuck_samples``
      samples in a row while the command's range over those samples (its highest less its
      lowest value since the reading froze) exceeds ``stuck_mm`` (0 samples: off). A command
      that moves less than ``stuck_mm`` in all is not judged here: a still reading is then what
      a quantised transducer shows of a small or slow motion.
    * a stuck load cell (a broken cable, an amplifier saturated at its full scale): the same force
      reading, bit for bit, for ``force_stuck_samples`` samples in a row while the measured
      displacement's range over those samples exceeds ``force_stuck_mm``, in displacement control
      (in force control the loop holds the force reading still; 0 samples: off). A specimen
      on a flat plateau read by a noise-free load cell shows the same; a real load cell's noise
      moves its last digit every few samples.
    """

    def __init__(self, where: str, limits: Limits, period_s: float, options: dict | None = None):
        o = {**PLAUSIBILITY_DEFAULTS, **{k: v for k, v in (options or {}).items() if k in PLAUSIBILITY_DEFAULTS}}
        self.where = where
        self.max_d = float(limits.stroke_mm)  # 2 x the half stroke
        self.max_f = 2.0 * float(limits.force_kN)
        self.max_v = 2.0 * float(limits.velocity_mm_s)
        self.max_df = 0.5 * float(limits.force_kN)
        self.period_s = float(period_s)
        self.jump_floor = float(o["jump_floor_mm"])
        self.stuck_samples = int(o["stuck_samples"])
        self.stuck_mm = float(o["stuck_mm"])
        self.force_stuck_samples = int(o["force_stuck_samples"])
        self.force_stuck_mm = float(o["force_stuck_mm"])
        self.force_same = 0
        self.displacement_range: tuple[float, float] | None = None  # measured, since the force reading froze
        self.last: tuple[float, float, float] | None = None
        self.same = 0
        self.command_range: tuple[float, float] | None = None  # the command's (lowest, highest) since the reading froze
        self.rejected = 0

    def _refuse(self, what: str):
        from hsio.errors import ImplausibleMeasurementError

        self.rejected += 1
        raise ImplausibleMeasurementError(f"{self.where}: implausible measurement: {what}; not passed on, the run "
                                          "stops (its stop line says whether the hold was confirmed)")

    def check(self, displacement: float, force: float, t: float, command: float | None = None) -> None:
        if not math.isfinite(displacement):
            self._refuse(f"displacement {displacement!r} is not finite")
        if not math.isfinite(force):
            self._refuse(f"force {force!r} is not finite")
        if abs(displacement) > self.max_d:
            self._refuse(f"displacement {displacement:.6g} mm beyond twice the half stroke (+/-{self.max_d:g} mm)")
        if abs(force) > self.max_f:
            self._refuse(f"force {force:.6g} kN beyond twice the capacity (+/-{self.max_f:g} kN)")
        if self.last is not None:
            d0, f0, t0 = self.last
            elapsed = t - t0 if math.isfinite(t) and t > t0 else self.period_s
            step = self.max_v * max(elapsed, self.period_s) + self.jump_floor
            if abs(displacement - d0) > step:
                self._refuse(f"displacement jumped {displacement - d0:+.6g} mm in {elapsed:.4g} s (at most {step:.4g} mm)")
            if abs(force - f0) > self.max_df:
                self._refuse(f"force jumped {force - f0:+.6g} kN between two samples (at most {self.max_df:g} kN)")
            if command is None:  # force control or holding: neither count carries over into the next commands
                self.same, self.command_range, self.force_same, self.displacement_range = 0, None, 0, None
            if self.stuck_samples and command is not None:
                self.same, self.command_range, moved = _frozen(displacement == d0, self.same, self.command_range,
                                                               command, command)
                if self.same >= self.stuck_samples and moved > self.stuck_mm:
                    self._refuse(f"displacement stuck at {displacement:.6g} mm for {self.same} samples while the "
                                 f"command moved over {moved:.4g} mm ({self.command_range[0]:+.4g} to "
                                 f"{self.command_range[1]:+.4g} mm; a stuck transducer)")
            if self.force_stuck_samples and command is not None:  # in force control the loop holds the force
                self.force_same, self.displacement_range, moved = _frozen(
                    force == f0, self.force_same, self.displacement_range, d0, displacement)
                if self.force_same >= self.force_stuck_samples and moved > self.force_stuck_mm:
                    self._refuse(f"force stuck at {force:.6g} kN for {self.force_same} samples while the "
                                 f"displacement moved over {moved:.4g} mm ({self.displacement_range[0]:+.4g} to "
                                 f"{self.displacement_range[1]:+.4g} mm; a stuck or saturated load cell; a specimen "
                                 "on a flat plateau read by a noise-free load cell reads the same: [driver] "
                                 "force_stuck_samples = 0 turns this check off)")
        self.last = (displacement, force, t)


def _frozen(same: bool, count: int, span: tuple[float, float] | None, start: float, value: float):
    """One sample of a frozen-reading check: the count of samples the reading has stayed the same,
    and the (lowest, highest) of the other signal since it froze (``start``: its value then) with
    that range; a reading that moved starts both again."""
    if not same:
        return 0, None, 0.0
    low, high = span or (start, start)
    span = (min(low, value), max(high, value))
    return count + 1, span, span[1] - span[0]
