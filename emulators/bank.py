"""A multi-axis emulated servo controller as a protocol front-end sees it.

One :class:`~hsio.emulators.servo.ServoController` per axis, plus what a real controller adds around
its loops: an enable/hold switch per axis, a host watchdog (the host must change its watchdog
counter within ``watchdog_s``, otherwise the axis holds and the watchdog bit latches until the
host re-enables), range checks on incoming commands (refused, never clamped), and a clock that
either runs in real time (its own 1024 Hz loop in a thread) or in lockstep (it waits for the
host to advance it).

The Modbus server (:mod:`hsio.emulators.modbus`) and the CANopen node (:mod:`hsio.emulators.canopen`)
both serve a :class:`ControllerBank`.
"""

from __future__ import annotations

import math
import random
import threading
import time
from dataclasses import dataclass

from hsio.emulators.servo import ServoController, parse_value
from hsio.clock import RealTimeClock
from hsio.errors import ConfigError
from hsio.interfaces import ControlMode


class CommandRefused(Exception):
    """An incoming command is out of range; it was not applied."""


@dataclass
class AxisState:
    """What the host set on one axis, beside the servo controller's own state."""

    enabled: bool = False
    watchdog_value: float | None = None
    watchdog_seen: float = 0.0  # monotonic time of the last change
    watchdog_expired: bool = False
    refused: bool = False


class ControllerBank:
    """The axes of one emulated controller, their watchdog and their clock."""

    def __init__(self, controllers: list[ServoController], names: list[str] | None = None,
                 lockstep: bool = True, watchdog_s: float = 1.0):
        if not controllers:
            raise ConfigError("emulated controller: no axes")
        if not watchdog_s >= 0:
            raise ConfigError(f"emulated controller: watchdog_s must be zero (off) or positive, got {watchdog_s!r}")
        self.controllers = controllers
        self.names = names or [f"axis{k}" for k in range(len(controllers))]
        self.axes = [AxisState() for _ in controllers]
        self.lockstep = lockstep
        self.watchdog_s = float(watchdog_s)
        # False: the watchdog watches the axes the host commands (enabled); True: also the axes it
        # holds, as on controllers whose watchdog watches the host link itself. Either way a host
        # that stops changing the counter of a watched axis latches its watchdog bit (docs/modbus.md).
        self.watch_holding = False
        self.rate_hz = controllers[0].config.rate_hz
        self.boot_id = float(random.SystemRandom().randrange(1, 1 << 24))
        self.lock = threading.RLock()
        self.faults = None  # a hsio.emulators.faults.FaultSchedule (docs/faults.md)
        self.restarts = 0
        self.ticks = 0
        self.overruns = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        for c in controllers:
            c.hold()

    # -- life cycle ------------------------------------------------------------------------------
    def start(self) -> None:
        """Start the clock thread: the 1024 Hz loop in real time, the watchdog alone in lockstep."""
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="servo-bank", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def _run(self) -> None:
        # In lockstep the thread only watches the host (every 20 ms); the host steps the clock.
        clock = RealTimeClock(self.rate_hz if not self.lockstep else 50.0)
        while not self._stop.is_set():
            with self.lock:
                self.check_watchdog()
                if not self.lockstep:
                    self._step()
            clock.tick()
            self.overruns = clock.overruns

    def _step(self) -> None:
        for c in self.controllers:
            c.step()
        self.ticks += 1

    # -- clock (lockstep) --------------------------------------------------------------------------
    def advance_to(self, target: int) -> None:
        """Run the loop until the tick count reaches ``target`` (idempotent: a repeated request
        for a tick already reached does nothing)."""
        if not self.lockstep:
            raise CommandRefused("the clock runs in real time; it cannot be advanced")
        with self.lock:
            n = int(target) - self.ticks
            if n > 10 * int(self.rate_hz):
                raise CommandRefused(f"advance to tick {target} is {n} ticks ahead (at most {10 * int(self.rate_hz)})")
            self.check_watchdog()
            for _ in range(max(n, 0)):
                self._step()

    # -- host commands -----------------------------------------------------------------------------
    def check_command(self, axis: int, mode: ControlMode, value: float) -> None:
        """Refuse a command value out of range (not finite, beyond the stroke or capacity)."""
        cfg = self.controllers[axis].config
        if not math.isfinite(value):
            raise CommandRefused(f"axis {axis}: {mode.value} command {value!r} is not finite")
        bound = 0.5 * cfg.stroke_mm if mode is ControlMode.DISPLACEMENT else cfg.force_limit_kN
        if abs(value) > bound:
            raise CommandRefused(f"axis {axis}: {mode.value} command {value:.3f} beyond +/-{bound:.1f}")

    def apply(self, axis: int, mode: ControlMode, value: float, enable: bool, watchdog: float | None) -> None:
        """The host's cyclic write for one axis (already checked with :meth:`check_command`)."""
        with self.lock:
            state, c = self.axes[axis], self.controllers[axis]
            state.refused = False
            if watchdog is not None and watchdog != state.watchdog_value:
                state.watchdog_value = watchdog
                state.watchdog_seen = time.monotonic()
            if not enable:
                if state.enabled or not c.holding:
                    c.hold()
                state.enabled = False
                return
            if not state.enabled:  # re-enable: re-arms the watchdog
                state.watchdog_expired = False
                state.watchdog_seen = time.monotonic()
                state.enabled = True
            if state.watchdog_expired:
                return
            c.set_mode(mode)
            c.set_command(value)

    def refuse(self, axis: int) -> None:
        with self.lock:
            self.axes[axis].refused = True

    def hold(self, axis: int) -> None:
        with self.lock:
            self.controllers[axis].hold()
            self.axes[axis].enabled = False

    def check_watchdog(self) -> None:
        if self.watchdog_s <= 0:
            return
        now = time.monotonic()
        for state, c in zip(self.axes, self.controllers):
            if (state.enabled or self.watch_holding) and state.watchdog_value is not None and not state.watchdog_expired \
                    and now - state.watchdog_seen > self.watchdog_s:
                state.watchdog_expired = True
                c.hold()

    # -- faults and resets (docs/faults.md, docs/modbus.md) -------------------------------------------
    def fault_due(self):
        """The request fault due now (drop, delay, corrupt, duplicate, restart) or None; the
        other kinds that fall due are armed (docs/faults.md)."""
        return self.faults.due(self.ticks) if self.faults else None

    def measured(self, axis: int) -> tuple[float, float]:
        """What axis ``axis``'s transducers report (displacement mm, force kN), faults applied."""
        return self.displacement(axis), self.force(axis)

    def displacement(self, axis: int) -> float:
        """What axis ``axis``'s displacement transducer reports, faults applied (a valve failure
        that fell due trips the axis at this read)."""
        c = self.controllers[axis]
        if not self.faults:
            return c.measured_displacement
        if axis == 0 and self.faults.take_valve():
            c.tripped = "servo-valve failure (the axis does not follow its command)"
            c.hold()
        return self.faults.measured(axis, self.ticks, c.measured_displacement)

    def force(self, axis: int) -> float:
        """What axis ``axis``'s load cell reports, faults applied."""
        c = self.controllers[axis]
        if not self.faults:
            return c.measured_force
        return self.faults.measured_force(axis, self.ticks, c.measured_force)

    def ignores_mode(self, axis: int) -> bool:
        """Whether axis ``axis`` ignores the host's mode switches (the ``mode`` fault, axis 0)."""
        return axis == 0 and bool(self.faults) and self.faults.mode_ignored

    def restart(self) -> None:
        """The controller restarts: a new boot id, the clock at zero, every axis at rest, holding."""
        with self.lock:
            self.boot_id = float(random.SystemRandom().randrange(1, 1 << 24))
            self.ticks = 0
            self.restarts += 1
            for k, c in enumerate(self.controllers):
                c.reset()
                c.hold()
                self.axes[k] = AxisState()

    def reset_interlocks(self) -> None:
        """Clear the latched interlock and watchdog of every axis (docs/modbus.md, "Interlock
        reset"). Refused while an axis is enabled or while a cause persists (a measurement
        still beyond the stroke or the capacity)."""
        with self.lock:
            for k, (state, c) in enumerate(zip(self.axes, self.controllers)):
                if state.enabled:
                    raise CommandRefused(f"axis {k} is enabled: disable every axis before the reset")
                cfg = c.config
                if abs(c.measured_displacement) > 0.5 * cfg.stroke_mm or abs(c.measured_force) > cfg.force_limit_kN:
                    raise CommandRefused(f"axis {k}: the cause persists (measurement beyond the stroke or capacity)")
            for state, c in zip(self.axes, self.controllers):
                c.clear_trip()
                c.hold()
                state.watchdog_expired = False
                state.refused = False

    # -- status ------------------------------------------------------------------------------------
    def flags(self, axis: int) -> dict[str, bool]:
        state, c = self.axes[axis], self.controllers[axis]
        return {
            "enabled": state.enabled and not state.watchdog_expired and not c.tripped,
            "force_mode": c.mode is ControlMode.FORCE,
            "holding": c.holding,
            "interlock": bool(c.tripped),
            "watchdog": state.watchdog_expired,
            "refused": state.refused,
            "lockstep": self.lockstep,
        }


def parse_settings(pairs) -> dict:
    """``KEY=VALUE`` strings (the CLI's --set) as an [emulator] table."""
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise ConfigError(f"--set {pair!r}: expected KEY=VALUE")
        out[key.strip()] = parse_value(value.strip())
    return out
