"""The narrow interfaces between the experiment and the hardware.

An :class:`Actuator` takes one command sample per controller period, in displacement (mm) or
force (kN) control, and reports measured displacement and force. A :class:`DAQ` reports named
channels with units. Both are implemented by the in-process emulator (``hsio.emulators.local``) and by
the drivers (``hsio.drivers.modbus``, ``hsio.drivers.canopen``), so the experiment does not know which it
drives.

Limits are checked here, before anything is sent: a command beyond a limit raises
:class:`~hsio.errors.LimitError` and is not sent, so the actuator keeps holding its last command.
"""

from __future__ import annotations

import enum
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from urllib.parse import parse_qsl

from hsio.errors import ConfigError, LimitError


class ControlMode(enum.Enum):
    """What an actuator's command means."""

    DISPLACEMENT = "displacement"
    FORCE = "force"


COMPACT_FROM = 1e6  # a refused value this large or larger is shown in significant digits


def shown_beyond(value: float, limit: float, decimals: tuple[int, int] = (3, 1)) -> tuple[str, str]:
    """``value`` and ``limit`` as text for a refusal, with ``decimals`` (value, limit) or as many
    more as it takes for the value shown to lie beyond the limit shown (|value| > limit):
    127.0001 against 127 reads "127.0001" and "127.00", never "127.000" beyond "127.0". A value
    of a million or more (far beyond any limit) reads in six significant digits: 1e308 reads
    "1e+308", not its 309 digits."""
    dv, dl = decimals
    if abs(value) >= COMPACT_FROM and abs(value) > 1.000001 * limit:
        return f"{value:.6g}", f"{limit:.{dl}f}"
    for extra in range(17):
        v, lim = f"{value:.{dv + extra}f}", f"{limit:.{dl + extra}f}"
        if abs(float(v)) > float(lim):
            return v, lim
    return repr(value), repr(limit)


@dataclass(frozen=True)
class Limits:
    """Actuator limits. The stroke is centred on zero: |displacement| <= stroke_mm / 2."""

    stroke_mm: float = 254.0
    force_kN: float = 250.0
    velocity_mm_s: float = 500.0

    @property
    def half_stroke_mm(self) -> float:
        return self.stroke_mm / 2.0

    def check_displacement(self, value: float, where: str) -> None:
        """Refuse a displacement command beyond the stroke or not finite (no clamping)."""
        if not math.isfinite(value):
            raise LimitError(f"{where}: displacement command {value!r} is not a finite number")
        if abs(value) > self.half_stroke_mm:
            shown, limit = shown_beyond(value, self.half_stroke_mm)
            raise LimitError(f"{where}: displacement command {shown} mm is beyond the stroke (+/-{limit} mm); not sent")

    def check_force(self, value: float, where: str) -> None:
        """Refuse a force command beyond the force capacity or not finite (no clamping)."""
        if not math.isfinite(value):
            raise LimitError(f"{where}: force command {value!r} is not a finite number")
        if abs(value) > self.force_kN:
            shown, limit = shown_beyond(value, self.force_kN)
            raise LimitError(f"{where}: force command {shown} kN is beyond the capacity (+/-{limit} kN); not sent")

    def check_velocity(self, value: float, where: str) -> None:
        """Refuse a displacement command that would move faster than the actuator can."""
        if abs(value) > self.velocity_mm_s:
            shown, limit = shown_beyond(value, self.velocity_mm_s, (1, 1))
            raise LimitError(f"{where}: command velocity {shown} mm/s is beyond the limit ({limit} mm/s); not sent")

    def check(self, mode: ControlMode, value: float, where: str) -> None:
        if mode is ControlMode.DISPLACEMENT:
            self.check_displacement(value, where)
        else:
            self.check_force(value, where)


@dataclass(frozen=True)
class ActuatorSpec:
    """What a hardware backend needs to open one actuator: its name (the controller's channel,
    docs/structures.md ``actuator``) and, for an emulator, the specimen model it loads."""

    name: str
    specimen: dict


@dataclass(frozen=True)
class Feedback:
    """One controller-period sample of an actuator's measured response."""

    displacement_mm: float
    force_kN: float
    time_s: float


class Actuator(ABC):
    """One servo-controlled actuator (one control channel).

    The experiment calls :meth:`command` once per controller period and :meth:`feedback` after
    the clock ticked. :meth:`hold` freezes the actuator at its present position (displacement
    control) whatever it was doing; it must be safe to call at any time, also after an error.
    """

    name: str
    limits: Limits

    @property
    @abstractmethod
    def mode(self) -> ControlMode:
        """The present control mode."""

    @abstractmethod
    def set_mode(self, mode: ControlMode) -> None:
        """Switch control mode bumplessly: the new command starts at the present measurement."""

    def command(self, value: float) -> None:
        """Send one command sample (mm or kN by mode). Refused beyond the limits, unsent."""
        self.limits.check(self.mode, value, f"actuator {self.name!r}")
        self._send(value)

    @abstractmethod
    def _send(self, value: float) -> None:
        """Send a command already checked against the limits."""

    @abstractmethod
    def feedback(self) -> Feedback:
        """The latest measured displacement and force."""

    @abstractmethod
    def hold(self) -> None:
        """Hold the present position in displacement control."""

    def holding(self) -> bool | None:
        """Read back whether the controller holds: True, False, or None when this actuator cannot
        tell (the hold could then not be confirmed; docs/safety.md section 3)."""
        return None

    def close(self) -> None:
        """Release the connection. The actuator is left holding."""


@dataclass(frozen=True)
class Channel:
    """A DAQ channel: its name and engineering unit."""

    name: str
    unit: str


class DAQ(ABC):
    """A data acquisition device: named channels with units, read together."""

    @property
    @abstractmethod
    def channels(self) -> tuple[Channel, ...]:
        """The channels this DAQ reads."""

    @abstractmethod
    def read(self) -> dict[str, float]:
        """One reading of every channel, by name, in the channel's unit."""


class ActuatorChannels(DAQ):
    """An actuator's own transducers as DAQ channels: ``<name>.displacement`` (mm) and
    ``<name>.force`` (kN), read through :meth:`Actuator.feedback`."""

    name: str

    @property
    def channels(self) -> tuple[Channel, ...]:
        return (Channel(f"{self.name}.displacement", "mm"), Channel(f"{self.name}.force", "kN"))

    def read(self) -> dict[str, float]:
        fb = self.feedback()
        return {f"{self.name}.displacement": fb.displacement_mm, f"{self.name}.force": fb.force_kN}


def query_pairs(url: str, query: str) -> list[tuple[str, str]]:
    """The ``KEY=VALUE`` settings of a hardware URL's query, each key at most once (a key given
    twice, with one of the values silently winning, is refused: ConfigError naming it)."""
    pairs = parse_qsl(query)
    keys = [k for k, _ in pairs]
    twice = sorted({k for k in keys if keys.count(k) > 1})
    if twice:
        raise ConfigError(f"hardware URL {url!r}: {', '.join(twice)} given more than once; give each setting once")
    return pairs
