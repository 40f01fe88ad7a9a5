"""In-process binding: the emulated controller behind hsio's Actuator interface, no protocol.

In lockstep the experiment's clock steps the controller; in real time the controller runs its
own loop in a thread (:class:`RealTimeLoop`) and the experiment only writes and reads.
"""

from __future__ import annotations

import threading
from urllib.parse import parse_qsl, urlsplit

from hsio.emulators.servo import ServoConfig, ServoController, make_controllers, parse_value
from hsio.clock import Clock, RealTimeClock
from hsio.errors import ConfigError, InterlockError
from hsio.interfaces import Actuator, ActuatorChannels, ControlMode, Feedback, Limits


class RealTimeLoop:
    """Steps a controller at its own rate in a daemon thread until stopped."""

    def __init__(self, controller: ServoController, lock: threading.Lock):
        self.controller = controller
        self.lock = lock
        self.overruns = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="servo-emulator", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)

    def _run(self) -> None:
        clock = RealTimeClock(self.controller.config.rate_hz)
        while not self._stop.is_set():
            with self.lock:
                self.controller.step()
            clock.tick()
            self.overruns = clock.overruns


class EmulatedActuator(Actuator, ActuatorChannels):
    """An emulated controller channel as an Actuator (and its DAQ channels)."""

    def __init__(self, name: str, controller: ServoController, clock: Clock | None = None):
        self.name = name
        self.controller = controller
        cfg = controller.config
        self.limits = Limits(cfg.stroke_mm, cfg.force_limit_kN, cfg.velocity_limit_mm_s)
        self._lock = threading.Lock()
        self._loop: RealTimeLoop | None = None
        if clock is not None and getattr(clock, "lockstep", False):
            clock.attach(controller)
        else:
            self._loop = RealTimeLoop(controller, self._lock)
            self._loop.start()

    @property
    def mode(self) -> ControlMode:
        return self.controller.mode

    def set_mode(self, mode: ControlMode) -> None:
        with self._lock:
            self._raise_if_tripped()
            self.controller.set_mode(mode)

    def _send(self, value: float) -> None:
        with self._lock:
            self._raise_if_tripped()
            self.controller.set_command(value)

    def feedback(self) -> Feedback:
        with self._lock:
            c = self.controller
            return Feedback(c.measured_displacement, c.measured_force, c.time_s)

    def hold(self) -> None:
        with self._lock:
            self.controller.hold()

    def holding(self) -> bool:
        """The emulated controller's own hold flag (set by a hold or a trip, cleared by a command)."""
        with self._lock:
            return bool(self.controller.holding)

    def close(self) -> None:
        self.hold()
        if self._loop is not None:
            self._loop.stop()
            self._loop = None

    def _raise_if_tripped(self) -> None:
        if self.controller.tripped:
            raise InterlockError(f"actuator {self.name!r}: interlock tripped: {self.controller.tripped}; holding")



def _settings(url: str, options: dict | None) -> dict:
    """The [emulator] table with the URL's query parameters on top."""
    parts = urlsplit(url)
    if parts.scheme != "emulator":
        raise ConfigError(f"{url!r} is not an emulator:// URL")
    table = dict(options or {})
    for key, value in parse_qsl(parts.query):
        table[key] = parse_value(value)
    return table


def check_options(url: str, options: dict | None = None) -> None:
    """Check the [emulator] table (and the URL's settings) as the controller will read them."""
    ServoConfig.from_dict(_settings(url, options))


def open_url(url: str, elements, clock: Clock, options: dict | None = None) -> list[Actuator]:
    """Open ``emulator://`` with one emulated controller per experimental element.

    ``options`` is the [emulator] table of the configuration (ServoConfig fields); query
    parameters of the URL override it, e.g. ``emulator://?lag_s=0.03&noise_mm=0``.
    Each controller gets its own noise seed (seed + index).
    """
    controllers = make_controllers(elements, _settings(url, options))
    return [EmulatedActuator(e.name, c, clock) for e, c in zip(elements, controllers)]

