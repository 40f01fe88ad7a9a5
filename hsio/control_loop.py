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

Every period the interlock monitor (:mod:`hsio.safety.interlocks`, docs/safety.md section 3)
checks the command and the measurement of each actuator. Between steps the loop can pause (every
actuator holds, the hold is read back) and resume from where the commands stand.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from hsio.clock import Clock
from hsio.command import PredictorCorrector
from hsio.errors import HsioError, InterlockError, LimitError
from hsio.interfaces import Actuator, ControlMode
from hsio.safety.hold import HoldReport, read_back


def held_on_failure(actuators, exc: HsioError) -> HsioError:
    """A start-up that failed with the axes enabled: every actuator is told to hold (each is
    tried), the hold is read back, and ``exc`` (returned, to be raised) says how it went."""
    for actuator in actuators:
        try:
            actuator.hold()
        except Exception:
            pass
    return with_hold_report(exc, read_back(actuators))


def with_hold_report(exc: HsioError, report: HoldReport) -> HsioError:
    """``exc`` with the read-back of the hold added to its message."""
    if exc.args:
        exc.args = (f"{exc.args[0]}; {report.message}",) + exc.args[1:]
    return exc


@dataclass
class StepFeedback:
    """What one integration step measured, per actuator."""

    targets: np.ndarray
    commands: np.ndarray  # the last command sent
    displacement: np.ndarray  # measured, averaged over the last n_avg periods
    force: np.ndarray
    samples: np.ndarray | None  # n_samples x n_actuators x 3 (command, displacement, force)
    sample_time: np.ndarray | None = None  # lab time of each sample (s)
    phases: list | None = None  # per sample, the command generator's phase of each actuator
    force_last: np.ndarray | None = None  # measured at the step's last period (an instrument read then pairs with it)


class ControlLoop:
    """Drives a set of actuators at the controller rate for a given test rate."""

    STEP_TIMEOUT_STEPS = 4  # a step that has not landed after this many t_d is an error

    def __init__(self, actuators: list[Actuator], clock: Clock, dt: float, test_rate: float,
                 n_avg: int = 1, keep_samples: bool = True, hold_fraction: float = 0.0, monitor=None):
        if not test_rate > 0:
            raise ValueError(f"test rate must be positive, got {test_rate!r}")
        self.actuators = actuators
        self.clock = clock
        self.t_d = test_rate * dt
        self.n_avg = max(int(n_avg), 1)
        self.keep_samples = keep_samples
        self.hold_fraction = hold_fraction
        try:
            initial = [a.feedback().displacement_mm for a in actuators]
        except HsioError as exc:  # the axes are enabled: hold them, and say whether they hold
            raise held_on_failure(actuators, exc)
        self.generators = [PredictorCorrector(self.t_d, clock.period_s, x0, hold_fraction=hold_fraction) for x0 in initial]
        self.monitor = monitor  # hsio.safety.interlocks.InterlockMonitor or None
        # called as watch(lab time, feedback) every period after the monitor, when set (the watch over
        # a ramp of the static preloads, hsio.safety.ramp_watch); what it raises stops the loop as a trip does
        self.watch = None
        self._samples: list[tuple] = []  # every period since the last step landed
        self._targets = np.full(len(actuators), np.nan)  # the step's targets (none before the first)
        self._unanswered: tuple | None = None  # a period's commands sent, its measurement never read
        self._sample_meta: list[tuple] = []  # (lab time, phases) of each of those periods
        self._phases: list[str] = []
        self._paused = False
        self._paused_at: float | None = None  # lab time when a pause began
        self._paused_modes: list | None = None  # each actuator's mode before the pause's hold
        self._commands: list[float] = []
        self._thread: threading.Thread | None = None
        self._lock = threading.RLock()
        self._done = threading.Event()
        self._stop = threading.Event()
        self._held = False
        self._closed = False
        self._reconnects: dict[int, int] = {}  # per link (id): its reconnections already told
        self._final_hold = HoldReport({})
        self._error: BaseException | None = None
        self._result: StepFeedback | None = None
        if not getattr(clock, "lockstep", False):
            self._thread = threading.Thread(target=self._run_real_time, name="hsio-control-loop", daemon=True)
            self._thread.start()

    @property
    def late_steps(self) -> int:
        return max(g.late_steps for g in self.generators)

    def feedback(self) -> list:
        """The actuators' latest measurements, read between two periods of the loop."""
        with self._lock:
            return [a.feedback() for a in self.actuators]

    def execute(self, targets: np.ndarray) -> StepFeedback:
        """Move every actuator to its target over one step; return what was measured."""
        if self._held:
            raise self._error or HsioError("the control loop holds the actuators after an earlier stop")
        targets = np.asarray(targets, dtype=float)
        for actuator, target in zip(self.actuators, targets):
            try:
                actuator.limits.check(actuator.mode, float(target), f"actuator {actuator.name!r} target")
            except LimitError as exc:
                if self._error is not None:  # the loop had stopped already: that is the cause
                    raise self._error
                with self._lock:  # the controller is asked between two periods, not across the loop's exchange
                    cause = self._trip_instead(actuator, exc)
                if cause is not exc:
                    self._fail(cause)
                raise
        limit = self.STEP_TIMEOUT_STEPS * max(g.samples_per_step for g in self.generators)
        if self._thread is None:
            self._start_step(targets)
            for _ in range(limit):
                self._send()
                sent_at = self.clock.now_s
                try:
                    self.clock.tick()
                except BaseException:  # an interrupt while the period ran: its commands went out
                    self._keep_unanswered(sent_at + self.clock.period_s)
                    raise
                if self._collect():
                    return self._result
        else:
            if self._error is not None:
                raise self._error
            with self._lock:
                self._done.clear()
                self._start_step(targets)
            if self._done.wait(limit * self.clock.period_s + 1.0) and self._error is None:
                return self._result
            if self._error is not None:
                raise self._error
        self.hold_all()
        raise HsioError(f"the step to {np.round(targets, 4).tolist()} did not land within {limit} controller "
                        "periods; every actuator was told to hold")

    @staticmethod
    def _trip_instead(actuator: Actuator, refusal: LimitError) -> HsioError:
        """The cause of ``refusal``, a command of ``actuator`` refused by the limits of its present
        mode: the controller's trip where it tripped (its interlock holds it in displacement
        control, so a force command was judged as a displacement), else the refusal itself."""
        probe = getattr(actuator, "tripped", None)
        try:
            trip = probe() if probe is not None else None
        except Exception:  # the controller cannot be asked: the refusal stands
            trip = None
        return InterlockError(f"actuator {actuator.name!r}: {trip}; holding") if trip else refusal

    def _start_step(self, targets: np.ndarray) -> None:
        """New targets; every generator gets the same segment length so that they land together."""
        self._targets = targets
        n = max(g.planned_samples() for g in self.generators)
        for g, t in zip(self.generators, targets):
            g.new_target(t, samples=n)

    def _send(self) -> None:
        """One command per actuator for this period (velocity and limits checked first)."""
        self._commands = []
        self._phases = []
        actuator = None
        try:
            for g, actuator in zip(self.generators, self.actuators):
                previous = g.command
                c = g.next_sample()
                if actuator.mode is ControlMode.DISPLACEMENT:
                    actuator.limits.check_velocity((c - previous) / self.clock.period_s, f"actuator {actuator.name!r}")
                actuator.command(c)
                self._commands.append(c)
                self._phases.append(g.phase.value)
        except BaseException as exc:
            self._keep_unanswered(self.clock.now_s + self.clock.period_s)
            self._fail(self._trip_instead(actuator, exc) if isinstance(exc, LimitError) else exc)

    def _keep_unanswered(self, lab_time_s: float) -> None:
        """The period whose commands (some or all) went out but whose measurement was never read
        (a refusal, a lost link, an interrupt): kept for :meth:`take_unfinished`."""
        n = len(self.actuators)
        sent = list(self._commands)[:n]
        if not sent:
            return  # nothing went out in that period
        self._unanswered = (sent + [np.nan] * (n - len(sent)), list(self._phases)[:n] + [None] * (n - len(sent)),
                            float(lab_time_s))

    def _collect(self) -> bool:
        """Read the period's measurements. True when every command has landed on its target."""
        commands = self._commands
        try:
            feedback = [a.feedback() for a in self.actuators]
        except BaseException as exc:
            self._keep_unanswered(self.clock.now_s)
            self._fail(exc)
        # kept before the interlocks judge it: the period that trips one is the step's last sample
        self._samples.append((commands, [f.displacement_mm for f in feedback], [f.force_kN for f in feedback]))
        if self.keep_samples:
            self._sample_meta.append((self.clock.now_s, self._phases))
        try:
            if self.monitor is not None:
                self.monitor.check(self.clock.now_s, commands, feedback, [a.mode for a in self.actuators])
            if self.watch is not None:
                self.watch(self.clock.now_s, feedback)
        except BaseException as exc:
            self._fail(exc)
        if not all(g.reached for g in self.generators):
            return False
        tail = np.array(self._samples[-self.n_avg:])  # n x 3 x n_act
        samples = np.array(self._samples).transpose(0, 2, 1) if self.keep_samples else None
        meta, self._sample_meta = self._sample_meta, []
        self._samples = []
        self._result = StepFeedback(
            targets=self._targets.copy(),
            commands=np.array(commands),
            displacement=tail[:, 1, :].mean(axis=0),
            force=tail[:, 2, :].mean(axis=0),
            force_last=tail[-1, 2, :].copy(),
            samples=samples,
            sample_time=np.array([m[0] for m in meta]) if self.keep_samples else None,
            phases=[m[1] for m in meta] if self.keep_samples else None,
        )
        return True

    def _fail(self, exc: BaseException):
        """Hold everything and raise ``exc`` as an HsioError (anything unexpected is wrapped); a
        Ctrl-C stays a KeyboardInterrupt, so that it stops whatever runs the loop (a study too)."""
        self.hold_all()
        if isinstance(exc, (HsioError, KeyboardInterrupt)):
            raise exc
        raise HsioError(f"control loop stopped: {exc!r}") from exc

    def _run_real_time(self) -> None:
        try:
            while not self._stop.is_set():
                with self._lock:
                    active = not self._held and not self._paused
                    if active:
                        self._send()
                self.clock.tick()  # the wait for the next period, outside the lock
                if active:
                    with self._lock:
                        if not self._held and not self._paused and self._collect():
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
            except BaseException as exc:
                self._fail(exc)
            present = fb.force_kN if mode is ControlMode.FORCE else fb.displacement_mm
            old = self.generators[index]
            self.generators[index] = PredictorCorrector(old.t_d, old.period, present, hold_fraction=self.hold_fraction)

    PAUSE_SETTLE_STEPS = 3  # a pause waits at most this many t_d for the commands to come to rest

    def pause(self) -> HoldReport:
        """Between steps: let the commands come to rest (real time), stop commanding, and every
        actuator holds; the hold is read back. :meth:`resume` carries on from the same commands."""
        if self._held:
            raise self._error or HsioError("the control loop holds the actuators after an earlier stop")
        if self._thread is not None:
            deadline = time.monotonic() + self.PAUSE_SETTLE_STEPS * self.t_d + 1.0
            while time.monotonic() < deadline and not all(g.phase.value == "hold" for g in self.generators):
                time.sleep(0.005)
                if self._error is not None:
                    raise self._error
        with self._lock:
            self._paused = True
            self._paused_at = self.clock.now_s
            # a hold is in displacement control: resume puts each actuator back in its own mode
            self._paused_modes = [actuator.mode for actuator in self.actuators]
            for actuator in self.actuators:
                try:
                    actuator.hold()
                except Exception:
                    pass
        return read_back(self.actuators)

    def resume(self) -> None:
        """Command again after :meth:`pause`: the generators go on from where they stand. An
        actuator that was in force control before the hold (a static preload, an element in
        force control) goes back to it, bumplessly (its command starts at the force it measures),
        before its generator's next command, a force, is sent: never as a displacement."""
        with self._lock:
            for actuator, mode in zip(self.actuators, self._paused_modes or ()):
                if actuator.mode is not mode:
                    try:
                        actuator.set_mode(mode)
                    except BaseException as exc:
                        self._fail(exc)
            self._paused_modes = None
            self._paused = False
            if self.monitor is not None and self._paused_at is not None:
                self.monitor.skip(self.clock.now_s - self._paused_at)  # the pause's lab time does not count
            self._paused_at = None

    def keep_alive(self) -> list[str]:
        """While paused: each actuator that has a host watchdog is kept alive (it keeps holding).
        Called by the pause's wait (hsio.safety.control). Returns one line per actuator whose
        controller could not be reached ("<actuator>: <what>"): its hold cannot be confirmed, and
        the pause tells it as the watch tells a trip; the others are still fed."""
        lost = []
        with self._lock:
            if not self._paused:
                return lost
            for actuator in self.actuators:
                keep = getattr(actuator, "keep_alive", None)
                if keep is None:
                    continue
                try:
                    keep()
                except Exception as exc:  # the same words at every wait, however the error's text varies
                    lost.append(f"{actuator.name}: its controller could not be reached to feed its host watchdog "
                                f"({type(exc).__name__}): whether it holds cannot be confirmed")
        return lost

    def watch_controllers(self) -> list[str]:
        """While paused: each controller's latched trip, as "<actuator>: <what>" (the actuators'
        ``tripped``; an actuator without it cannot tell and is not listed; one whose controller
        cannot be read is listed as such). Called by the pause's wait (hsio.safety.control)."""
        out = []
        with self._lock:
            if not self._paused:
                return out
            for actuator in self.actuators:
                ask = getattr(actuator, "tripped", None)
                if ask is None:
                    continue
                try:
                    what = ask()
                except Exception as exc:  # the same words at every watch, however the error's text varies
                    what = f"its controller could not be read ({type(exc).__name__})"
                if what:
                    out.append(f"{actuator.name}: {what}")
        return out

    def keep_alive_period_s(self) -> float | None:
        """How often :meth:`keep_alive` must run (:func:`keep_alive_period_s`)."""
        return keep_alive_period_s(self.actuators)

    def confirm_hold(self) -> HoldReport:
        """Ask every actuator whether it holds (True, False or None: cannot tell)."""
        with self._lock:
            return read_back(self.actuators)

    def take_unfinished(self) -> StepFeedback | None:
        """After a stop in the middle of a step: the periods of that step so far, never returned
        by :meth:`execute` (commands sent, measurements, lab times, phases; a last period whose
        measurement was never read has NaN measurements, and NaN commands where none went out).
        None when no period is pending or the loop keeps no samples. The loop forgets them."""
        with self._lock:
            rows, meta, unanswered = self._samples, self._sample_meta, self._unanswered
            self._samples, self._sample_meta, self._unanswered = [], [], None
        if not self.keep_samples:
            return None
        n = len(self.actuators)
        rows = [(list(c), list(d), list(f)) for c, d, f in rows]
        meta = list(meta)
        if unanswered is not None:
            sent, phases, when = unanswered
            rows.append((sent, [np.nan] * n, [np.nan] * n))
            meta.append((when, phases))
        if not rows:
            return None
        samples = np.array(rows, dtype=float).transpose(0, 2, 1)  # n_samples x n_actuators x 3
        return StepFeedback(targets=np.array(self._targets, dtype=float),
                            commands=samples[-1, :, 0].copy(), displacement=samples[-1, :, 1].copy(),
                            force=samples[-1, :, 2].copy(), samples=samples,
                            sample_time=np.array([m[0] for m in meta], dtype=float), phases=[list(m[1]) for m in meta])

    def take_events(self) -> list[dict]:
        """What the interlock monitor saw since the last call (warnings, trips), and each link to
        a controller made again since then (kind ``link``)."""
        events = self.monitor.take_events() if self.monitor is not None else []
        return events + self._link_events()

    def _link_events(self) -> list[dict]:
        """One event per driver link (Modbus, CANopen) whose count of reconnections grew since the
        last call: the link dropped (or a reply was lost) and was made again; the step went on."""
        out, seen = [], set()
        for actuator in self.actuators:
            link = getattr(actuator, "link", None)
            count = getattr(link, "reconnects", None)
            if link is None or id(link) in seen or isinstance(count, bool) or not isinstance(count, int):
                continue
            seen.add(id(link))
            before = self._reconnects.get(id(link), 0)
            if count > before:
                self._reconnects[id(link)] = count
                out.append({"time_s": float(self.clock.now_s), "kind": "link", "actuator": "",
                            "message": f"{getattr(link, 'url', 'the controller')}: the link was made again after "
                                       f"{count - before} reconnection attempt(s) ({count} in the run so far)"})
        return out

    def hold_all(self) -> None:
        """Stop commanding, and every actuator holds (each is tried; errors while holding are
        ignored). The loop sends nothing more: a new run needs a new loop."""
        self._held = True
        with self._lock:
            for actuator in self.actuators:
                try:
                    actuator.hold()
                except Exception:
                    pass

    def close(self) -> HoldReport:
        """Stop the loop, hold every actuator, read the hold back while the links are still open,
        then release every actuator. Returns the read-back (the final hold: docs/safety.md
        section 3); a later call returns the same report and does nothing else."""
        if self._closed:
            return self._final_hold
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.hold_all()
        self._final_hold = self.confirm_hold()
        for actuator in self.actuators:
            try:
                actuator.close()
            except Exception:
                pass
        return self._final_hold


def keep_alive_period_s(actuators) -> float | None:
    """A quarter of the shortest host watchdog time the actuators report (their ``watchdog_s``,
    0 or absent: none); None when none reports one."""
    times = [float(getattr(a, "watchdog_s", 0.0) or 0.0) for a in actuators]
    times = [t for t in times if t > 0]
    return min(times) / 4.0 if times else None
