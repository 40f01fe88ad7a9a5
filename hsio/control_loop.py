"""The controller-rate loop: commands out, measurements in, one controller period at a time.

:meth:`ControlLoop.execute` takes one target per actuator (the integrator's u~_{i+1}), checks
them against the actuators' limits before anything moves, and runs the predictor-corrector
(:mod:`hsio.command`) until every actuator's command has landed on its target, t_d = TR dt later.
It returns the measurements at the end of the step (averaged over the last ``n_avg`` periods)
and, on request, every sample of the step.

In lockstep the loop runs in the caller's thread and the clock steps the emulators. In real
time it runs in its own thread: while the integrator computes, the commands are extrapolated.
Any error (a refused command, an interlock, a lost link) makes every actuator hold, and is
raised in the caller's thread.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from hsio.clock import Clock
from hsio.command import PredictorCorrector
from hsio.errors import HsioError
from hsio.interfaces import Actuator, ControlMode


@dataclass
class StepFeedback:
    """What one integration step measured, per actuator."""

    targets: np.ndarray
    commands: np.ndarray  # the last command sent
    displacement: np.ndarray  # measured, averaged over the last n_avg periods
    force: np.ndarray
    samples: np.ndarray | None  # n_samples x n_actuators x 3 (command, displacement, force)


class ControlLoop:
    """Drives a set of actuators at the controller rate for a given test rate."""

    def __init__(self, actuators: list[Actuator], clock: Clock, dt: float, test_rate: float,
                 n_avg: int = 1, keep_samples: bool = True, hold_fraction: float = 0.0):
        if not test_rate > 0:
            raise ValueError(f"test rate must be positive, got {test_rate!r}")
        self.actuators = actuators
        self.clock = clock
        self.t_d = test_rate * dt
        self.n_avg = max(int(n_avg), 1)
        self.keep_samples = keep_samples
        self.hold_fraction = hold_fraction
        initial = [a.feedback().displacement_mm for a in actuators]
        self.generators = [PredictorCorrector(self.t_d, clock.period_s, x0, hold_fraction=hold_fraction) for x0 in initial]
        self._samples: list[tuple] = []
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._result: StepFeedback | None = None
        if not getattr(clock, "lockstep", False):
            self._thread = threading.Thread(target=self._run_real_time, name="hsio-control-loop", daemon=True)
            self._thread.start()

    @property
    def late_steps(self) -> int:
        return max(g.late_steps for g in self.generators)

    def execute(self, targets: np.ndarray) -> StepFeedback:
        """Move every actuator to its target over one step; return what was measured."""
        targets = np.asarray(targets, dtype=float)
        for actuator, target in zip(self.actuators, targets):
            actuator.limits.check(actuator.mode, float(target), f"actuator {actuator.name!r} target")
        if self._thread is None:
            with self._lock:
                self._start_step(targets)
            while True:
                if self._tick():
                    return self._result
        if self._error is not None:
            raise self._error
        with self._lock:
            self._done.clear()
            self._start_step(targets)
        while not self._done.wait(0.05):
            if not self._thread.is_alive():
                break
        if self._error is not None:
            raise self._error
        return self._result

    def _start_step(self, targets: np.ndarray) -> None:
        self._targets = targets
        self._samples = []
        for g, t in zip(self.generators, targets):
            g.new_target(t)

    def _tick(self) -> bool:
        """One controller period. True when every command has landed on its target."""
        commands = []
        try:
            for g, actuator in zip(self.generators, self.actuators):
                previous = g.command
                c = g.next_sample()
                if actuator.mode is ControlMode.DISPLACEMENT:
                    actuator.limits.check_velocity((c - previous) / self.clock.period_s, f"actuator {actuator.name!r}")
                actuator.command(c)
                commands.append(c)
            self.clock.tick()
            feedback = [a.feedback() for a in self.actuators]
        except BaseException:
            self.hold_all()
            raise
        self._samples.append((commands, [f.displacement_mm for f in feedback], [f.force_kN for f in feedback]))
        if not all(g.reached for g in self.generators):
            return False
        tail = np.array(self._samples[-self.n_avg:])  # n x 3 x n_act
        samples = np.array(self._samples).transpose(0, 2, 1) if self.keep_samples else None
        self._result = StepFeedback(
            targets=self._targets.copy(),
            commands=np.array(commands),
            displacement=tail[:, 1, :].mean(axis=0),
            force=tail[:, 2, :].mean(axis=0),
            samples=samples,
        )
        return True

    def _run_real_time(self) -> None:
        try:
            while not self._stop.is_set():
                with self._lock:
                    finished = self._tick()
                if finished:
                    self._done.set()
        except BaseException as exc:  # surfaced in the caller's thread
            self._error = exc if isinstance(exc, HsioError) else HsioError(f"control loop stopped: {exc!r}")
            self._done.set()

    def set_mode(self, index: int, mode: ControlMode) -> None:
        """Switch actuator ``index`` to ``mode`` between steps, bumplessly: the actuator starts its
        new command at the present measurement, and so does a fresh command generator."""
        actuator = self.actuators[index]
        with self._lock:
            if actuator.mode is mode:
                return
            try:
                actuator.set_mode(mode)
                fb = actuator.feedback()
            except BaseException:
                self.hold_all()
                raise
            present = fb.force_kN if mode is ControlMode.FORCE else fb.displacement_mm
            old = self.generators[index]
            self.generators[index] = PredictorCorrector(old.t_d, old.period, present, hold_fraction=self.hold_fraction)

    def hold_all(self) -> None:
        """Every actuator holds; errors while holding are ignored (each is tried)."""
        for actuator in self.actuators:
            try:
                actuator.hold()
            except Exception:
                pass

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        self.hold_all()
        for actuator in self.actuators:
            try:
                actuator.close()
            except Exception:
                pass
