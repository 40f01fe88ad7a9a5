"""In-process binding: the emulated controller behind hsio's Actuator interface, no protocol.

In lockstep the experiment's clock steps the controller; in real time the controller runs its
own loop in a thread (:class:`RealTimeLoop`) and the experiment only writes and reads.
"""

from __future__ import annotations

import threading
from urllib.parse import urlsplit

import numpy as np

from hsio.emulators.servo import ServoConfig, ServoController, make_controllers, parse_value, quantise
from hsio.clock import Clock, RealTimeClock
from hsio.errors import ConfigError, InterlockError
from hsio.interfaces import DAQ, Actuator, ActuatorChannels, Channel, ControlMode, Feedback, Limits, query_pairs


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
            if abs(clock.rate_hz - cfg.rate_hz) > 1e-9 * clock.rate_hz:
                raise ConfigError(f"emulator: rate_hz = {cfg.rate_hz:g} differs from the experiment's controller rate "
                                  f"({clock.rate_hz:g} Hz): in lockstep each tick is one period of both; leave rate_hz "
                                  f"out")
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

    def tripped(self) -> str | None:
        """The emulated controller's latched trip (None: none)."""
        with self._lock:
            return f"interlock tripped: {self.controller.tripped}" if self.controller.tripped else None

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
    if parts.netloc or parts.path.strip("/"):
        raise ConfigError(f"hardware URL {url!r}: the in-process emulator takes no host or path "
                          f"(emulator:// or emulator://?KEY=VALUE&...)")
    table = dict(options or {})
    for key, value in query_pairs(url, parts.query):
        table[key] = parse_value(value)
    return table


def check_options(url: str, options: dict | None = None) -> None:
    """Check the [emulator] table (and the URL's settings) as the controller will read them."""
    ServoConfig.from_dict(_settings(url, options))


def _actuator_name(element) -> str:
    """The name of the one actuator behind ``element`` (the structure file's ``actuator``)."""
    names = getattr(element, "actuator_names", None)
    return names[0] if names else element.name


def open_url(url: str, elements, clock: Clock, options: dict | None = None) -> list[Actuator]:
    """Open ``emulator://`` with one emulated controller per experimental element.

    ``options`` is the [emulator] table of the configuration (ServoConfig fields); query
    parameters of the URL override it, e.g. ``emulator://?lag_s=0.03&noise_mm=0``.
    Each controller gets its own noise seed (seed + index).
    """
    table = _settings(url, options)
    if not any(getattr(e, "has_setup", False) or getattr(e, "is_multi_dof", False) for e in elements):
        controllers = make_controllers(elements, table)
        return [EmulatedActuator(_actuator_name(e), c, clock) for e, c in zip(elements, controllers)]
    # elements loaded through setups: one rig each, one emulated controller per actuator (docs/setups.md)
    from hsio.emulators.rig import rig_for

    actuators: list[Actuator] = []
    seed = int(table.get("seed", 0))
    for e in elements:
        if getattr(e, "has_setup", False) or getattr(e, "is_multi_dof", False):
            rig = rig_for(e, table, seed)
            for name, c in zip(e.actuator_names, rig.controllers):
                actuators.append(EmulatedActuator(name, c, clock))
            seed += len(rig.controllers)
        else:
            (c,) = make_controllers([e], {**table, "seed": seed})
            actuators.append(EmulatedActuator(_actuator_name(e), c, clock))
            seed += 1
    return actuators



class EmulatedInstruments(DAQ):
    """External instruments on the emulated specimens, read like a DAQ module (docs/setups.md).

    An ``lvdt`` or ``string_pot`` reads the specimen displacement of its element's controller
    (after the load train: what the rod's own transducer does not see when the load train is
    compliant), a ``load_cell`` its force, a ``strain_gauge`` ``scale`` microstrain per kN. Each
    adds its own Gaussian noise and quantises to its resolution.
    """

    def __init__(self, instruments, controllers: dict, seed: int = 1000):
        self.instruments = list(instruments)
        self.controllers = controllers
        self._rng = np.random.default_rng(seed)
        for inst in self.instruments:
            if inst.element not in controllers:
                raise ConfigError(f"instrument {inst.name!r}: no emulated element {inst.element!r} to read "
                                  f"(elements: {', '.join(controllers)})")

    @property
    def channels(self) -> tuple[Channel, ...]:
        return tuple(Channel(i.name, i.unit) for i in self.instruments)

    def value(self, inst) -> float:
        c = self.controllers[inst.element]
        if inst.kind in ("lvdt", "string_pot"):
            true = inst.scale * c.d_spec
        else:
            true = inst.scale * c.force
        noisy = true + (self._rng.normal(0.0, inst.noise) if inst.noise > 0 else 0.0)
        return quantise(noisy, inst.resolution)

    def read(self) -> dict[str, float]:
        return {inst.name: self.value(inst) for inst in self.instruments}


class _RigPoint:
    """What an instrument on a ``parallel`` rig reads: the one basic DOF's displacement (the pose
    the rods give after their load trains) and force, in the lab's units (mm, kN) as a real
    instrument reads them: d / lambda_d and q / lambda_F (docs/setups.md)."""

    def __init__(self, rig):
        self.rig = rig
        self.factors = rig.setup.factors

    @property
    def d_spec(self) -> float:
        return float(self.rig.pose[0]) / self.factors.displacement

    @property
    def force(self) -> float:
        return float(self.rig.basic_forces[0]) / self.factors.force


def open_instruments(instruments, elements, actuators) -> EmulatedInstruments:
    """The emulated DAQ of ``instruments`` on the controllers behind ``actuators`` (one per element,
    in the elements' order; elements with other setups than ``parallel`` are not read)."""
    controllers = {}
    k = 0
    for e in elements:
        names = getattr(e, "actuator_names", (e.name,))
        if len(names) == 1 and not getattr(e, "has_setup", False):
            controllers[e.name] = actuators[k].controller
        elif getattr(e, "is_parallel", False):
            controllers[e.name] = _RigPoint(actuators[k].controller.specimen.rig)
        k += len(names)
    return EmulatedInstruments(instruments, controllers)
