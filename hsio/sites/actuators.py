"""Actuators as an experimental site: trials run through the controller-rate loop.

Each trial is one :meth:`hsio.control_loop.ControlLoop.execute`: the commands are checked
against the limits, generated at the controller rate and reached after t_d = TR dt of lab time
(docs/method.md section 1). The site owns what sits between the integrator and the actuators:

* feed-forward compensation of displacement commands (E&M 2007 eq. 2; docs/method.md section 4):
  the integrator's command d^c becomes d^a before it reaches the loop;
* the measurement of a trial: the loop's average over its last ``n_avg`` periods, or, with a
  :class:`~hsio.secant.SecantEstimator`, the estimator's pair and secant stiffness (eq. 11)
  from the controller-rate samples (docs/method.md section 5); an element whose displacement an
  external instrument gives takes that instrument's reading, read as the trial ends, and the
  force of the trial's last period (docs/setups.md);
* bumpless mode switches (:meth:`hsio.control_loop.ControlLoop.set_mode`);
* with a :class:`~hsio.sites.setup_map.SetupMap`, the setups between the integrator's channels
  (basic DOFs) and the actuators: exact strokes out, basic displacements and forces back
  (docs/setups.md). Elements with setups run in displacement control.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from hsio.control_loop import ControlLoop, with_hold_report
from hsio.errors import ConfigError, HsioError, ImplausibleMeasurementError, LimitError
from hsio.interfaces import ControlMode
from hsio.safety.hold import HoldReport
from hsio.safety.preload_ramp import check_ramp, ramp_steps, ramp_targets
from hsio.safety.ramp_watch import RampWatch
from hsio.safety.settings import SafetySettings
from hsio.safety.status import InterlockTrip
from hsio.secant import SecantEstimator, secant_stiffness
from hsio.sites.base import Daq
from hsio.structures import OuterLoop


def final_hold_warning(report: HoldReport) -> str:
    """The line that says a final hold was not confirmed by read-back, and why."""
    return f"WARNING: the final hold could not be confirmed: {report.message}"


class RampStopped(HsioError):
    """A ramp of the static preloads was stopped on request; the static actuators are left in
    force control at the targets it had reached (the message gives them and the measured forces)."""


class ActuatorSite:
    """The experimental channels on actuators, driven trial by trial: one actuator per channel,
    or several per element through its setup (``setups``); ``static`` preloads
    (:class:`hsio.structures.StaticLoad`) on the actuators after those of the channels, their
    ramps watched against the limits less ``safety``'s stroke and velocity margins."""

    ACTUATOR_LOG_ROWS = 10_000  # trials of the actuators' log kept for the record between its takes

    def __init__(self, loop: ControlLoop, estimator: SecantEstimator | None = None, compensation=None,
                 setups=None, static=(), instruments=None, external=None, relative: bool = False,
                 safety: SafetySettings | None = None):
        self.loop = loop
        self.safety = safety or SafetySettings()
        self.instruments = instruments  # a DAQ of external instruments, read every trial
        # per channel: None (the actuator's transducer) or (instrument name, OuterLoop or None)
        self.external = list(external) if external is not None else []
        # per channel: (noise, resolution) of the external instrument its displacement is read from,
        # one reading a trial (None: the actuator's transducer, averaged by the estimator); eq. (11a)
        self.displacement_instruments = [None] * len(self.external)
        if any(x is not None for x in self.external) and instruments is None:
            raise ConfigError("an element takes its displacement from an external instrument: open the instruments' DAQ")
        self.instrument_log: list[tuple] = []  # (trial, iterations, readings)
        # through setups: (trial, strokes sent, commands, strokes, forces) of each actuator, the rows
        # not yet handed to the record (which takes them every step; without one, the latest only)
        self.actuator_log: deque[tuple] = deque(maxlen=self.ACTUATOR_LOG_ROWS)
        self._tables_taken = {"static": 0, "instruments": 0}  # log rows handed to the record so far
        self._trials = 0
        self.setups = setups
        self.static = list(static)
        self.n_dynamic = len(loop.actuators) - len(self.static)
        # the actuator strokes that move each channel that takes an instrument's reading by 1 mm (its
        # element has no setup, or a parallel one), and the actuator that moves it most, named
        self._strokes_of = {j: setups.external_strokes(j) if setups is not None else np.eye(self.n_dynamic)[j]
                            for j, x in enumerate(self.external) if x is not None}
        self._actuator_of = {j: int(np.argmax(np.abs(v))) for j, v in self._strokes_of.items()}
        self.preload_short: list[tuple[str, float, float]] = []  # preloads the ramp-in left short: name, target, measured
        if setups is not None and setups.n_actuators != self.n_dynamic:
            raise ConfigError(f"the setups drive {setups.n_actuators} actuators; the loop has {self.n_dynamic} "
                              f"beside the static ones")
        if setups is not None and estimator is not None:
            raise ConfigError("the secant estimator works per actuator; elements with setups take the averaged "
                              "measurement (no estimator)")
        self.n_elements = setups.n_channels if setups is not None else self.n_dynamic
        self.estimator = estimator
        if estimator is not None and not loop.keep_samples:
            raise ConfigError("the secant stiffness is estimated from the controller-rate samples: "
                              "open the site with keep_samples=True ([output] samples = true in a run "
                              "configuration)")
        self.compensation = compensation  # hsio.compensation.stage.CompensationStage or None
        driven = [a.name for a in loop.actuators[: self.n_dynamic]]
        if compensation is not None and list(compensation.names) != driven:
            raise ConfigError(f"the compensation stage names the actuators {', '.join(compensation.names)}; the loop "
                              f"drives {', '.join(driven)} (build the stage with these names, in this order)")
        try:
            self.readback = self.read_back()  # every channel, before the first command
            feedback = loop.feedback()[: self.n_dynamic]
        except HsioError as exc:  # the axes are enabled: hold them, and say whether they hold
            raise with_hold_report(exc, loop.close())  # held, read back, released
        # relative trials: the actuators' positions now (at enabling) are the zero of every command,
        # and the readings now of the instruments that give displacements the zero of those
        self.zero = (np.array([f.displacement_mm for f in feedback]) if relative else np.zeros(self.n_dynamic))
        self.instrument_zero = {src[0]: (self.readback[src[0]] if relative else 0.0)
                                for src in self.external if src is not None}
        self._committed = self._to_channels(np.array([f.displacement_mm for f in feedback]) - self.zero,
                                            np.array([f.force_kN for f in feedback]))
        self._committed = (self._external_displacements(self._committed[0], self.readback), self._committed[1])
        self._last = self._committed
        if estimator is not None:
            estimator.begin_step(*self._committed)
        self._samples: list[np.ndarray] = []
        self._sample_meta: list[tuple] = []  # (lab times, phases) beside each block of samples
        self._daq: Daq | None = None
        self.static_targets = np.zeros(len(self.static))
        self.static_log: list[tuple] = []  # (phase, lab time s, targets, forces, displacements)
        # per ramp ("ramp_in", "ramp_off"), per preload: its peak measured rod speed and stroke
        self.ramp_peaks: dict[str, dict[str, dict[str, float]]] = {}
        self._events: list[dict] = []  # the ramp watch's trips, for take_events
        self._phase = "test"
        self.final_hold: HoldReport | None = None  # set by close()

    @property
    def modes(self) -> list[ControlMode]:
        return [a.mode for a in self.loop.actuators[: self.n_dynamic]]

    @property
    def late_steps(self) -> int:
        return self.loop.late_steps

    @property
    def lab_time_s(self) -> float:
        """Controller time spent so far (ticks x period)."""
        return float(self.loop.clock.now_s)

    def committed(self):
        return self._committed

    def set_modes(self, modes) -> list[int]:
        switched = []
        for index, (actuator, mode) in enumerate(zip(self.loop.actuators[: self.n_dynamic], modes)):
            if actuator.mode is not mode:
                self.loop.set_mode(index, mode)
                switched.append(index)
        return switched

    def _to_channels(self, strokes: np.ndarray, forces: np.ndarray, guess=None):
        if self.setups is None:
            return strokes, forces
        return self.setups.basic(strokes, forces, guess)

    def read_back(self) -> dict[str, float]:
        """One reading of every channel: each actuator's displacement and force, each instrument
        (shown before the test starts; docs/setups.md)."""
        out = {}
        for actuator, fb in zip(self.loop.actuators, self.loop.feedback()):
            out[f"{actuator.name}.displacement"] = fb.displacement_mm
            out[f"{actuator.name}.force"] = fb.force_kN
        out.update(self.read_instruments())
        return out

    def _execute(self, dynamic_targets: np.ndarray):
        """One step of the loop: the dynamic actuators' targets (relative to their zero) and the
        static ones' preloads. Returns the feedback with displacements relative to the zero."""
        n = self.n_dynamic
        relative = bool(np.any(self.zero != 0.0))
        targets = dynamic_targets + self.zero if relative else dynamic_targets
        fb = self.loop.execute(np.concatenate([targets, self.static_targets]))
        if relative:
            fb.displacement[:n] -= self.zero
            fb.commands[:n] -= self.zero
            if fb.samples is not None:
                fb.samples[:, :n, 0] -= self.zero
                fb.samples[:, :n, 1] -= self.zero
        if self.static:
            n = self.n_dynamic
            self.static_log.append((self._phase, self.lab_time_s, self.static_targets.copy(),
                                    fb.force[n:].copy(), fb.displacement[n:].copy()))
        return fb

    # -- static preloads ------------------------------------------------------------------------
    # A preload ramped in is reached when every static actuator measures it within this fraction;
    # the ramp in holds its end, at most as many more loop steps as the ramp took, until it is (a
    # load train's lag or compliance leaves the force short of a fast ramp's end).
    PRELOAD_REACHED = 0.005

    def _ramp(self, start: np.ndarray, end: np.ndarray, phase: str, stop=None, pause=None) -> None:
        """Ramp the static actuators' targets from ``start`` to ``end`` over the longest ``ramp_s``,
        the dynamic ones holding; a ramp in then holds ``end`` until the preloads are reached
        (:attr:`PRELOAD_REACHED`), for at most as long again. ``stop`` (a callable) is asked before every step; when it
        answers true the ramp ends where it stands, the static actuators left in force control at
        their present targets, and :class:`RampStopped` says where (target and measured force).
        ``pause`` (a callable) is called before every step: an operator's pause holds the ramp
        there (:meth:`hsio.safety.control.RunControl.checkpoint`), for as long as the operator
        wants, and a stop while paused ends it as ``stop`` does. Every controller period the
        measured rods are watched (:class:`hsio.safety.ramp_watch.RampWatch`): a rod beyond its
        stroke or velocity limit less the margin stops the ramp with an
        :class:`~hsio.safety.status.InterlockTrip`, the period that tripped logged last; the
        ramp's peaks go to :attr:`ramp_peaks`."""
        from hsio.safety.status import OperatorStop

        self._phase = phase
        steps = ramp_steps(max(s.ramp_s for s in self.static), self.loop.t_d)
        hold = np.array([g.command for g in self.loop.generators[: self.n_dynamic]]) - self.zero

        def stopped(done: int) -> RampStopped:
            measured = [f.force_kN for f in self.loop.feedback()[self.n_dynamic:]]
            left = ", ".join(f"{s.name} {t:.4g} kN (measured {f:.4g} kN)"
                             for s, t, f in zip(self.static, self.static_targets, measured))
            return RampStopped(f"the {phase.replace('_', ' ')} of the static preloads was stopped after "
                               f"{done} of {steps} steps; force control left at {left}")

        targets = ramp_targets(start, end, steps)
        settle = steps if phase == "ramp_in" else 0
        if settle:
            self.preload_short = []
        now = self.loop.feedback()[self.n_dynamic:]
        watch = RampWatch(self.static, self.loop.actuators, self.n_dynamic,
                          [(f.displacement_mm, f.force_kN) for f in now], self.lab_time_s, phase,
                          (self.safety.stroke_margin, self.safety.velocity_margin), self.loop.clock.period_s)
        self.loop.watch = watch
        try:
            for k in range(1, steps + settle + 1):
                if pause is not None:
                    try:
                        pause()
                    except OperatorStop:
                        raise stopped(min(k - 1, steps)) from None
                if stop is not None and stop():
                    raise stopped(min(k - 1, steps))
                self.static_targets = targets[min(k, steps) - 1].copy()
                fb = self._execute(hold)
                if k >= steps and np.all(np.abs(fb.force[self.n_dynamic:] - end) <= self.PRELOAD_REACHED * np.abs(end)):
                    break
            else:
                if settle:  # held as long again and still short: the record starts, and says so
                    self.preload_short = [(load.name, float(t), float(f)) for load, t, f
                                          in zip(self.static, end, fb.force[self.n_dynamic:])
                                          if abs(f - t) > self.PRELOAD_REACHED * abs(t)]
        except InterlockTrip as exc:
            if exc.kind == RampWatch.KIND:  # the period that tripped: what the rods measured then
                self.static_log.append((phase, float(watch.last_time), self.static_targets.copy(),
                                        np.array([f for _, f in watch.last]), np.array([d for d, _ in watch.last])))
                self._events.append({"time_s": float(watch.last_time), "kind": "trip", "actuator": exc.actuator,
                                     "message": str(exc)})
            raise
        finally:
            self.loop.watch = None
            self.ramp_peaks[phase] = watch.peaks()
            self._phase = "test"

    def preloads_short(self) -> list[tuple[str, str]]:
        """(name, what it reads against its target) of each preload the last ramp in left short."""
        return [(name, f"static preload {name!r} reads {measured:.4g} kN of its {target:.4g} kN "
                       f"({100 * (measured - target) / target:+.2f} %) after the ramp in and a hold as long again")
                for name, target, measured in self.preload_short]

    def preload(self, stop=None, pause=None) -> None:
        """Switch the static actuators to force control and ramp their preloads in, the others
        holding where they stand (docs/setups.md). Each ramp starts from the force its actuator
        measures now, so a preload left on by an earlier session is not dropped and reapplied.
        ``stop``, ``pause``: see :meth:`_ramp`. Refused before anything moves: a preload beyond
        its actuator's force capacity, and a ramp in or off that would move a rod faster than its
        actuator's velocity limit (:func:`hsio.safety.preload_ramp.check_ramp`)."""
        if not self.static:
            return
        for j, load in enumerate(self.static):
            actuator = self.loop.actuators[self.n_dynamic + j]
            actuator.limits.check(ControlMode.FORCE, load.force_kN, f"static preload {load.name!r} on actuator {actuator.name!r}")
        present = np.array([f.force_kN for f in self.loop.feedback()[self.n_dynamic:]])
        end = np.array([s.force_kN for s in self.static])
        self._check_preload_stroke(present, end)
        self._check_ramp(present, end, "ramp in")
        self._check_ramp(end, np.zeros(len(self.static)), "ramp off")
        for j in range(len(self.static)):
            self.loop.set_mode(self.n_dynamic + j, ControlMode.FORCE)
        present = np.array([f.force_kN for f in self.loop.feedback()[self.n_dynamic:]])
        self.static_targets = present
        self._ramp(present, end, "ramp_in", stop, pause)

    def _check_preload_stroke(self, present: np.ndarray, end: np.ndarray) -> None:
        """Refuse a preload whose rod would stand beyond the stroke less the run's stroke margin:
        where it stands now, moved by the force still to come over the K^EI of what it loads (the
        stroke the dry run predicts, and the one the ramp's watch holds the measured rod to)."""
        keep = 1.0 - self.safety.stroke_margin
        feedback = self.loop.feedback()[self.n_dynamic:]
        for j, load in enumerate(self.static):
            actuator = self.loop.actuators[self.n_dynamic + j]
            allowed = keep * actuator.limits.half_stroke_mm
            d = feedback[j].displacement_mm + (end[j] - present[j]) / load.K_EI
            if not abs(d) <= allowed:
                start = (f" (from {feedback[j].displacement_mm:.3f} mm under {present[j]:.3f} kN)"
                         if abs(feedback[j].displacement_mm) > 0.05 or abs(present[j]) > 0.05 else "")
                raise LimitError(f"static preload {load.name!r} on actuator {actuator.name!r}: {load.force_kN:g} kN "
                                 f"over the K^EI of {load.K_EI:g} kN/mm puts the rod at {d:.3f} mm{start}, beyond the "
                                 f"stroke less the margin (+/-{allowed:g} mm, {100 * keep:g} % of "
                                 f"+/-{actuator.limits.half_stroke_mm:g} mm); not sent")

    def _check_ramp(self, start: np.ndarray, end: np.ndarray, phase: str) -> None:
        """Refuse a ramp of the preloads that would move a rod beyond its actuator's velocity limit
        less the run's velocity margin: the limit the dry run and the ramp's watch of the measured
        rod (:mod:`hsio.safety.ramp_watch`) hold it to."""
        keep = 1.0 - self.safety.velocity_margin
        limits = [None if a.limits.velocity_mm_s is None else keep * a.limits.velocity_mm_s
                  for a in self.loop.actuators[self.n_dynamic:]]
        check_ramp(self.static, start, end, limits, self.loop.t_d, self.loop.clock.period_s,
                   self.loop.hold_fraction, phase,
                   f"{100 * keep:g} % of the actuator's" if self.safety.velocity_margin > 0 else "")

    def release(self, stop=None, pause=None) -> None:
        """Ramp the static preloads off, the others holding where they stand. ``stop``,
        ``pause``: see :meth:`_ramp`."""
        if not self.static:
            return
        self._check_ramp(self.static_targets, np.zeros(len(self.static)), "ramp off")
        self._ramp(self.static_targets.copy(), np.zeros(len(self.static)), "ramp_off", stop, pause)

    def static_hold_error(self) -> np.ndarray:
        """Per static actuator: the largest |measured - preload| / |preload| while the test ran."""
        held = [(t, f) for phase, _, t, f, _ in self.static_log if phase == "test"]
        if not held:
            return np.full(len(self.static), np.nan)
        targets = np.array([t for t, _ in held])
        forces = np.array([f for _, f in held])
        return np.max(np.abs(forces - targets), axis=0) / np.abs([s.force_kN for s in self.static])

    # -- trials -------------------------------------------------------------------------------
    def set_trial(self, commands, modes) -> None:
        targets = np.asarray(commands, dtype=float)
        self._trial_targets = targets.copy()
        if self.setups is not None:
            if any(m is not ControlMode.DISPLACEMENT for m in modes):
                raise ConfigError("elements loaded through setups run in displacement control")
            self.setups.check_poses(targets)
            actuator_targets = self.setups.strokes(targets)
        else:
            self.set_modes(modes)
            actuator_targets = targets
        n = self.n_dynamic
        if self.compensation is not None:  # actuators in force control are not compensated
            displacement = [m is ControlMode.DISPLACEMENT for m in self.modes]
            d_a = self.compensation.adjust(actuator_targets, displacement)
            fb = self._execute(d_a)
            self.compensation.observe(actuator_targets, d_a, fb.displacement[:n], displacement)
        else:
            fb = self._execute(actuator_targets)
        fb, readings, iterations = self._outer_loop(targets, actuator_targets, fb)
        if self.setups is not None:
            self.actuator_log.append((self._trials, np.array(actuator_targets, dtype=float), fb.commands[:n].copy(),
                                      fb.displacement[:n].copy(), fb.force[:n].copy()))
        samples = fb.samples[:, :n] if fb.samples is not None else None
        if samples is not None:
            self._keep_samples(samples, fb.sample_time, fb.phases)
        if self.estimator is not None:
            u, R, k = self.estimator.update(samples[:, :, 1], samples[:, :, 2])
            if any(src is not None for src in self.external):  # eq. (11) on the instrument's reading
                u = self._external_displacements(u, readings)
                R = self._external_forces(R, fb)
                k_ext = secant_stiffness(u, R, *self._committed)
                base = self._committed[0]
                for j, source in enumerate(self.external):
                    if source is not None:
                        k[j] = k_ext[j] if abs(u[j] - base[j]) > self.estimator.min_increment else np.nan
        else:
            u, R = self._to_channels(fb.displacement[:n], fb.force[:n], targets)
            u = self._external_displacements(u, readings)
            R = self._external_forces(R, fb, targets)
            k = secant_stiffness(u, R, *self._committed)
        self._last = (u, R)
        commands = (fb.commands[:n] if self.setups is None
                    else self.setups.basic(fb.commands[:n], fb.force[:n], targets)[0])
        self._daq = Daq(u=u, R=R, k=k, targets=targets.copy(), commands=commands, samples=samples)
        self.last_actuator_feedback = fb

    def read_instruments(self) -> dict[str, float]:
        return self.instruments.read() if self.instruments is not None else {}

    def _external_displacements(self, u: np.ndarray, readings: dict[str, float]) -> np.ndarray:
        """``u`` with each channel that takes its displacement from an instrument set to that
        instrument's reading (less its zero under relative trials)."""
        u = np.array(u, dtype=float)
        for j, source in enumerate(self.external):
            if source is not None:
                u[j] = readings[source[0]] - self.instrument_zero[source[0]]
        return u

    def _external_forces(self, R: np.ndarray, fb, guess=None) -> np.ndarray:
        """``R`` with each channel that takes its displacement from an instrument set to its force
        at the trial's last controller period: the instrument is read once, as the trial ends, and
        its reading pairs with the force measured then, not with an average over the last periods
        (of a specimen still settling, those forces belong to earlier positions)."""
        if fb.force_last is None or not any(src is not None for src in self.external):
            return R
        n = self.n_dynamic
        _, at_end = self._to_channels(fb.displacement[:n], fb.force_last[:n], guess)  # a setup's geometry at the mean strokes
        R = np.array(R, dtype=float)
        for j, source in enumerate(self.external):
            if source is not None:
                R[j] = at_end[j]
        return R

    def _outer_loop(self, targets, actuator_targets, fb):
        """Read the instruments; where an element closes an outer loop on one, correct its
        command by the instrument's error and run the step's command again until the instrument
        reads the target within the tolerance, at most max_iterations times (docs/setups.md).
        Each extra command is one more trial of the loop (t_d of lab time)."""
        readings = self.read_instruments()
        iterations = 0
        loops = [(j, src) for j, src in enumerate(self.external) if src is not None and src[1] is not None]
        if loops and all(m is ControlMode.DISPLACEMENT for m in self.modes):
            commands = np.array(actuator_targets, dtype=float)
            max_iterations = max(src[1].max_iterations for _, src in loops)

            def off_target():
                return {j: targets[j] - (readings[src[0]] - self.instrument_zero[src[0]]) for j, src in loops}

            first = off_target()
            while iterations < max_iterations:
                errors = off_target()
                if all(abs(errors[j]) <= src[1].tolerance_mm for j, src in loops):
                    break
                for j, src in loops:
                    commands += self._strokes_of[j] * errors[j]
                fb = self._execute(commands)
                readings = self.read_instruments()
                iterations += 1
            if iterations:
                self._check_followed(loops, first, off_target(), commands - np.asarray(actuator_targets, dtype=float),
                                     iterations)
        self._trials += 1
        if self.instruments is not None:
            self.instrument_log.append((self._trials, iterations, readings))
        return fb, readings, iterations

    # An outer loop whose instrument is still this fraction of its first error off the target after
    # its corrections has not moved with the actuator (a compliant load train in front of a stiff
    # specimen moves it by k_train / (k_train + k_specimen) of each correction, a detached, stuck
    # or wrongly signed instrument by nothing or the wrong way); judged only on errors beyond
    # BEYOND_TOLERANCE times the tolerance, so that an instrument's noise near the tolerance is not.
    NOT_FOLLOWED = 0.9
    BEYOND_TOLERANCE = 5.0

    def _check_followed(self, loops, first: dict, last: dict, corrections: np.ndarray, iterations: int) -> None:
        """Stop (:class:`ImplausibleMeasurementError`, the actuators hold) where an outer loop's
        instrument did not follow its actuator's corrections: without this, a detached instrument
        would have the loop add its whole error to the command at every correction."""
        for j, (name, outer) in loops:
            judged = max(abs(first[j]), abs(last[j])) > self.BEYOND_TOLERANCE * outer.tolerance_mm
            if judged and abs(last[j]) > outer.tolerance_mm and not abs(last[j]) < self.NOT_FOLLOWED * abs(first[j]):
                k = self._actuator_of[j]
                actuator = self.loop.actuators[k].name
                raise ImplausibleMeasurementError(
                    f"instrument {name!r}: the outer loop moved actuator {actuator!r} {corrections[k]:+.3f} mm beyond "
                    f"its target in {iterations} corrections, and the instrument went from {first[j]:+.3f} to "
                    f"{last[j]:+.3f} mm off the target: it does not follow the actuator (detached, stuck, or its "
                    f"scale of the wrong sign), or it reads more coarsely than the loop's tolerance of "
                    f"{outer.tolerance_mm:g} mm (noise or resolution: the loop then chases them); the run stops")

    def check_instruments_at_rest(self) -> None:
        """Refuse (ConfigError, before any command) a record from rest where an instrument that
        gives an element its displacement reads, at enabling, away from that element's actuator
        transducer by more than BEYOND_TOLERANCE times the larger of the outer loop's tolerance (the
        default tolerance without a loop) and the instrument's noise, plus its resolution (one
        reading of a zeroed instrument is that far off by itself): an instrument not zeroed, whose
        offset the first step would take as the specimen's displacement, and an outer loop would
        drive the actuator by at once."""
        for j, source in enumerate(self.external):
            if source is None:
                continue
            name, outer = source
            k = self._actuator_of[j]
            actuator = self.loop.actuators[k].name
            reading = self.readback[name] - self.instrument_zero[name]
            # the element's displacement by its actuators' transducers (least squares over a parallel setup's)
            v = self._strokes_of[j]
            strokes = np.array([self.readback[f"{a.name}.displacement"] for a in self.loop.actuators[: len(v)]])
            transducer = float(v @ (strokes - self.zero)) / float(v @ v)
            noise, resolution = self.displacement_instruments[j] or (0.0, 0.0)
            limit = self.BEYOND_TOLERANCE * max((outer or OuterLoop()).tolerance_mm, noise) + resolution
            if abs(reading - transducer) > limit:
                raise ConfigError(
                    f"instrument {name!r} reads {reading:+.3f} mm at rest where actuator {actuator!r} reads "
                    f"{transducer:+.3f} mm (more than {limit:g} mm apart): it takes the element's displacement, and "
                    "from rest its offset would be taken as the specimen's (an outer loop would move the actuator "
                    "by it at the first step); zero the instrument (from Python: or open the site with relative=True); "
                    "nothing moved")

    def continue_trials(self, last_trial: int) -> None:
        """Number the trials from ``last_trial`` + 1: a resumed run's instruments and actuators logs
        go on after the ones its record holds."""
        self._trials = int(last_trial)

    def record_tables(self) -> dict[str, list[tuple[int, dict]]]:
        """Extra tables for the record, the rows logged since the last call: ``static`` (the
        preloads' log), ``instruments`` (every trial's readings and outer-loop iterations) and,
        through setups, ``actuators`` (every trial's target, command, stroke and force of each
        actuator, where the per-channel columns hold the linearised geometry's view). The
        experiment loop takes them every step, so that they are committed with the step's row."""
        tables = {}
        if self.setups is not None:
            rows = []
            for trial, *values in self.actuator_log:
                row = {}
                for j, name in enumerate(self.setups.actuator_names):
                    row.update({f"{p}_{name}": v[j] for p, v in zip(("target", "command", "disp", "force"), values)})
                rows.append((trial, row))
            self.actuator_log.clear()
            if rows:
                tables["actuators"] = rows
        if self.static:
            phases = {"ramp_in": 0, "test": 1, "ramp_off": 2}
            first, self._tables_taken["static"] = self._tables_taken["static"], len(self.static_log)
            rows = []
            for k in range(first, len(self.static_log)):
                phase, time_s, targets, forces, disps = self.static_log[k]
                row = {"phase": phases[phase], "lab_time_s": time_s}
                for j, load in enumerate(self.static):
                    name = load.actuator
                    row.update({f"target_{name}": targets[j], f"force_{name}": forces[j], f"disp_{name}": disps[j]})
                rows.append((k, row))
            if rows:
                tables["static"] = rows
        if self.instruments is not None:
            first, self._tables_taken["instruments"] = self._tables_taken["instruments"], len(self.instrument_log)
            rows = [(trial, {"iterations": iterations, **readings})
                    for trial, iterations, readings in self.instrument_log[first:]]
            if rows:
                tables["instruments"] = rows
        return tables

    def get_daq(self) -> Daq:
        if self._daq is None:
            raise RuntimeError("actuator site: get_daq before any trial")
        return self._daq

    def commit(self) -> None:
        self._committed = self._last
        if self.compensation is not None:  # the step's row of Er^cc or Er^ca/Er^aa
            self.compensation.commit()
        if self.estimator is not None:
            self.estimator.begin_step(*self._committed)

    def _keep_samples(self, samples: np.ndarray, times, phases) -> None:
        """The dynamic actuators' samples of one trial (relative to the zero) as the record's
        channels hold them, with their lab times and phases, for :meth:`take_samples`."""
        n = self.n_dynamic
        self._samples.append(self.setups.linearised_samples(samples) if self.setups is not None else samples)
        # phases per recorded channel: the first n actuators' (with setups, those of each
        # channel's element: SetupMap.channel_phases)
        phases = None if phases is None else [list(ph[:n]) if self.setups is None
                                              else self.setups.channel_phases(list(ph[:n])) for ph in phases]
        self._sample_meta.append((times, phases))

    def take_unfinished(self) -> dict | None:
        """After a stop in the middle of a step (docs/safety.md section 1): that step's trial
        targets per channel and its controller-rate samples so far, those of its finished
        trials and the periods of the trial it was in when it stopped (the period that tripped
        an interlock last; a period whose measurement was never read with NaN measurements).
        None when there are none (the stop came between steps, or the run keeps no samples)."""
        pending = self.loop.take_unfinished()
        if pending is not None:
            n = self.n_dynamic
            samples = pending.samples[:, :n].copy()
            if np.any(self.zero != 0.0):
                samples[:, :, 0] -= self.zero
                samples[:, :, 1] -= self.zero
            self._keep_samples(samples, pending.sample_time, pending.phases)
        meta = self.take_sample_meta()
        samples = self.take_samples()
        if samples is None:
            return None
        targets = getattr(self, "_trial_targets", None)
        return {"targets": None if targets is None else np.asarray(targets, dtype=float), "samples": samples,
                "times": None if meta is None else meta[0], "phases": None if meta is None else meta[1]}

    def take_samples(self) -> np.ndarray | None:
        if not self._samples:
            return None
        out = np.concatenate(self._samples, axis=0)
        self._samples = []
        return out

    def take_sample_meta(self) -> tuple[np.ndarray, list] | None:
        """Lab time and generator phases of the samples of the last :meth:`take_samples`."""
        if not self._sample_meta or any(t is None or p is None for t, p in self._sample_meta):
            self._sample_meta = []
            return None
        times = np.concatenate([t for t, _ in self._sample_meta])
        phases = [p for _, ps in self._sample_meta for p in ps]
        self._sample_meta = []
        return times, phases

    def take_events(self) -> list[dict]:
        """Interlock warnings and trips since the last call (docs/safety.md section 3)."""
        events, self._events = self._events, []
        return sorted(events + self.loop.take_events(), key=lambda e: e["time_s"])  # in the order they happened

    def pause(self):
        """Finish nothing more, hold every actuator and read the hold back (a HoldReport)."""
        return self.loop.pause()

    def resume(self) -> None:
        self.loop.resume()

    def keep_alive(self) -> list[str]:
        """While paused: keep the controllers' host watchdogs fed (the actuators keep holding);
        one line per controller that could not be reached."""
        return self.loop.keep_alive()

    def watch_controllers(self) -> list[str]:
        """While paused: the controllers' latched trips, one line each (docs/safety.md section 4)."""
        return self.loop.watch_controllers()

    def keep_alive_period_s(self) -> float | None:
        """A quarter of the shortest host watchdog the controllers report (None: none does)."""
        return self.loop.keep_alive_period_s()

    def hold(self):
        """Every actuator holds; returns the read-back (:class:`hsio.safety.hold.HoldReport`)."""
        self.loop.hold_all()
        return self.loop.confirm_hold()

    def close(self) -> HoldReport:
        """Every actuator holds, the hold is read back, every actuator is released; returns the
        read-back (kept as :attr:`final_hold`; a later call returns it again)."""
        self.final_hold = self.loop.close()
        return self.final_hold

    def report_final_hold(self, recorder=None, notify=None, step: int | None = None) -> dict:
        """After :meth:`close`: the final hold for the summary (``final_hold``, its read-back).
        A hold not confirmed by read-back is also written to the record's events (kind
        ``hold``) and told to ``notify`` as a warning; the run's outcome is left as it is
        (docs/safety.md section 5)."""
        report = self.close()
        items = {"final_hold": report.message}
        if not report.confirmed:
            note = final_hold_warning(report)
            items["warning"] = note
            if recorder is not None:
                recorder.write_event(self.lab_time_s, step, "hold", "", note)
            if notify is not None:
                notify(note)
        return items

    def __enter__(self) -> "ActuatorSite":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
