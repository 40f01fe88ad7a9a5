"""What the Modbus and CANopen drivers share: the [driver] options, the actuator limits, the
cyclic submit, closing the link with its last axis, and opening every axis safely.

Opening is in this order (:func:`open_axes`): connect and identify (nothing enabled), read the
limits, check the controller's clock against the experiment's, and only then enable the axes.
A failure at any point holds (disables) whatever was enabled and closes the link.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from urllib.parse import parse_qsl, urlsplit

from hsio.errors import ConfigError
from hsio.interfaces import Limits

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
    "stroke_mm": positive(10000.0, "mm (the total stroke)"),
    "force_kN": positive(100000.0, "kN"),
    "velocity_mm_s": positive(10000.0, "mm/s"),
}


def parse_options(url: str, options: dict | None, defaults: dict, rules: dict[str, Rule]) -> dict:
    """The [driver] table and the URL's query (the query wins), each value checked.

    A key without a rule is a string; a default of None means "not set" (the controller's own).
    """
    table = dict(defaults)
    given = {**(options or {}), **dict(parse_qsl(urlsplit(url).query))}
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


def resolve_limits(url: str, options: dict, stroke_mm: float | None, force_kN: float | None,
                   stroke_why: str = "", force_why: str = "") -> Limits:
    """The actuator limits: [driver] stroke_mm / force_kN where set, else the controller's own.

    Neither is ever guessed: a limit the controller does not report must be configured.
    """
    stroke = options["stroke_mm"] if options["stroke_mm"] is not None else reported(stroke_mm)
    if stroke is None:
        raise ConfigError(f"{url}: the controller does not report its stroke{stroke_why}; set [driver] stroke_mm "
                          "(the total stroke in mm, centred on zero)")
    force = options["force_kN"] if options["force_kN"] is not None else reported(force_kN)
    if force is None:
        raise ConfigError(f"{url}: the controller does not report its force capacity{force_why}; set [driver] "
                          "force_kN (the force capacity in kN)")
    return Limits(float(stroke), float(force), float(options["velocity_mm_s"]))


def check_clock(url: str, lockstep: bool, clock) -> None:
    """The controller's clock and the experiment's must agree (lockstep or real time)."""
    lockstep_clock = bool(getattr(clock, "lockstep", False))
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

    def abort(self) -> None:
        """Opening failed: disable whatever was enabled (best effort), then close."""
        try:
            self.disable()
        except Exception as exc:  # the original error matters more; this one is logged
            log.warning("%s: could not disable the axes while giving up: %s", getattr(self, "url", "?"), exc)
        finally:
            self.close()


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
            check_clock(link.url, link.lockstep, clock)
        if enable:
            link.enable()
        actuators = [make_actuator(name, link, k, limits[k]) for k, name in enumerate(names)]
        link.actuators = actuators
        if clock is not None and link.lockstep:
            clock.attach(link)
        return actuators
    except BaseException:
        link.abort()
        raise
