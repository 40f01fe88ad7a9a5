"""The lab behind the served elements: their actuators, opened per session, and the record.

A *session* starts when the first served element connects and ends when the last one leaves
(DIE, a closed connection, a silent element, an error). It opens the actuators with
:func:`hsio.api.open_site` exactly as `hsio run` does (command generation by the controller-rate
loop, feed-forward compensation, limits), and records each committed step with
:class:`hsio.recording.Recorder`. At its end the actuators hold and are released, and the record
is closed; a trial that was never committed is not written (docs/opensees.md).

The structure's static preloads (``[[static]]``, docs/setups.md) are ramped in when a session
opens, before any trial moves, and held through it; they ramp off when every element ended with
DIE, and stay held when the session ended any other way (as when `hsio run` stops early). The
record has their ``static`` table and the summary their ``static_hold_error``. The compensation
stage records its table (per actuator, one row per motion) and its summary as in `hsio run`, so
`hsio calibrate` reads a session's record as it reads a run's.

A served element has as many basic DOFs as in its structure: one, on one actuator, or several,
on the actuators of its setup (docs/setups.md). Its basic displacements go through the setup's
exact geometry to strokes, and the measured strokes and forces come back as basic displacements
and forces, as in `hsio run` (the site's :class:`hsio.sites.setup_map.SetupMap`).

Trials are imposed lazily: a setTrialResponse is stored, and the actuators move when a force is
asked for (getForce), once per step unless the trial displacement changes within the step. OpenSees'
AlphaOS sends the predicted displacement twice per step (before and after its corrector, with
corrected velocities); the specimen moves once, as in `hsio run`'s alpha-OS (docs/method.md
section 2).

The record says what the model did, as the model said it: a step's time is the committed trial's
time as the element sent it (a static analysis sends its pseudo-time, and a model may set its
clock back, e.g. ``loadConst -time 0``: such a step is flagged ``time_back``). OpenSees cannot
revert a genericClient: when an analysis fails to converge it sends the last committed trial
again and tries the step anew; the step it then commits is flagged ``retried``, with the trial
motions of the abandoned attempts (which the specimen went through) counted in its event. The
safety layer's warnings and trips go to the ``events`` table with their step, as in `hsio run`.
"""

from __future__ import annotations

import contextlib
import math
import sqlite3
import threading
import time
from dataclasses import replace
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np

from hsio import api
from hsio.experiment import write_events
from hsio.compensation.stage import CompensationSettings, CompensationStage
from hsio.config import RunConfig
from hsio.diagnose.modelfile import merged_emulator_table
from hsio.errors import ConfigError, HsioError, LimitError, RecordError
from hsio.interfaces import ControlMode
from hsio.opensees.protocol import Trial
from hsio.opensees.settings import OpenSeesSettings
from hsio.recording import Recorder, RecordExistsError
from hsio.safety.settings import SafetySettings
from hsio.sites.actuators import RampStopped
from hsio.sites.setup_map import SetupMap
from hsio.structures import Damping, ExperimentalElement, Structure, channel_names, rotation_dofs


MAX_SESSION_FILES = 100_000  # record names tried for one session
STEADY_STEPS = 5  # steps in a row with one time step other than the structure's dt: said once


class SessionBusy(HsioError):
    """A client of an element that left the open session: it joins the next one, which did not start."""


def served_structure(structure: Structure, names, source: str = "") -> Structure:
    """The experimental elements ``names`` of ``structure`` as a structure of their own: each
    keeps its basic DOFs (renumbered in the order served), actuators, setup, K^EI and external
    displacement instrument (``displacement_from``, with its outer loop); the static preloads and
    the instruments they need come along: what :func:`hsio.api.open_site` needs to open their
    actuators (docs/setups.md)."""
    by_name = {e.name: e for e in structure.experimental}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise ConfigError(f"{source + ': ' if source else ''}[opensees] elements: {unknown[0]!r} is not an experimental element of structure "
                          f"{structure.name!r}; known: {', '.join(by_name)}")
    elements, dof_names, influence = [], [], []
    rotations = rotation_dofs(structure)
    for name in names:
        e = by_name[name]
        first = len(dof_names)
        index = tuple(range(first, first + len(e.basic_dofs)))
        dof_names += [structure.dof_names[d] for d in e.basic_dofs]
        influence += [0.0 if d in rotations else 1.0 for d in e.basic_dofs]  # a rotation is not loaded by a_g
        elements.append(replace(e, dof=first, dofs=index if e.dofs else (), ref=None))
    # the external instruments that a served element reads its displacement from, or that sit on one
    used = {e.displacement_from for e in elements if e.displacement_from}
    instruments = tuple(i for i in structure.instruments if i.name in used or i.element in names)
    # OpenSees integrates the model: the served structure's mass and damping are placeholders, never used
    return Structure(name=structure.name, dof_names=tuple(dof_names), masses=(1.0,) * len(dof_names),
                     experimental=tuple(elements), damping=Damping(0.0, "mass"), dt=structure.dt,
                     influence=tuple(influence) if any(influence) else None,
                     description=f"served elements of {structure.name}", static=structure.static,
                     instruments=instruments)


def length_units(element: ExperimentalElement, length_factor: float) -> np.ndarray:
    """Per basic DOF of ``element``, hsio's units per model unit: ``length_factor`` (mm per model
    length) for a translation, 1 for a rotation (a setup's ``theta``: radians on both sides)."""
    basic = getattr(element.make_setup(), "basic", ()) or ("",) * len(element.basic_dofs)
    return np.array([1.0 if b == "theta" else length_factor for b in basic])


class Lab:
    """The served elements' actuators and record.

    Every public method runs in the lab's one worker thread (the actuators' loop and the SQLite
    record belong to one thread), so the connections' threads may call them at any time.
    """

    def __init__(self, settings: OpenSeesSettings, config: RunConfig, structure: Structure, log=print):
        self.settings = settings
        self.config = config
        self.structure = served_structure(structure, settings.elements, config.source)
        self.names = list(settings.elements)
        self.n = len(self.names)
        elements = self.structure.experimental
        self.channels = channel_names(self.structure)  # one per basic DOF, as `hsio run` records them
        self.blocks: list[slice] = []  # per element, its channels
        for e in elements:
            start = self.blocks[-1].stop if self.blocks else 0
            self.blocks.append(slice(start, start + len(e.basic_dofs)))
        self.n_basic = [b.stop - b.start for b in self.blocks]
        self.n_channels = len(self.channels)
        self.K_EI = [e.K_EI_matrix for e in elements]  # per element, over its basic DOFs (hsio units)
        self.units = [length_units(e, settings.length_factor) for e in elements]
        if config["hardware"]["url"].startswith("emulator"):  # the emulated DAQ reads served elements only
            for inst in self.structure.instruments:
                if inst.element not in self.names:
                    raise ConfigError(f"instrument {inst.name!r} (read by a served element) sits on element "
                                      f"{inst.element!r}, which this server does not serve; the emulated instruments "
                                      f"read served elements only: serve {inst.element!r} too")
        for key in ("mass", "damping"):
            for name, value in getattr(settings, key).items():
                j = self.names.index(name)
                n = self.n_basic[j]
                if not isinstance(value, float) and len(value) != n:
                    dofs = ", ".join(self.channels[self.blocks[j]])
                    raise ConfigError(f"[opensees] {key}.{name}: a {len(value)} x {len(value)} matrix; element {name!r} "
                                      f"has {n} basic DOF{'s' if n > 1 else ''} ({dofs})")
        self.correct = (config["test"]["measured_displacement_correction"] if settings.force_correction is None
                        else settings.force_correction)
        self.log = log
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hsio-opensees-lab")
        self._stepped = threading.Condition()  # notified when a step is recorded or an element leaves
        self.stopping = False  # the server is closing: no element waits for a step any more
        self._work = threading.Lock()
        self._working = 0  # motions of the actuators in progress (a trial, a preload ramp)
        self._worked_at = -math.inf  # time.monotonic() when the last one ended
        self.site = None
        self.compensation: CompensationStage | None = None  # the session's, recorded in its summary
        self.recorder: Recorder | None = None
        self.hold_message = "no session was open: no actuators to hold"  # the last session's hold, read back
        self.sessions = 0
        self.active: set[int] = set()
        self._reset_session()

    # --- sessions -------------------------------------------------------------------------
    def _reset_session(self) -> None:
        n = self.n
        self.latest: list[Trial | None] = [None] * n
        self.imposed = np.zeros(self.n_channels)  # targets sent to the site per channel, mm (rad)
        self.has_imposed = False
        self.moved_this_step = np.zeros(n, dtype=bool)
        self.committed_flags = np.zeros(n, dtype=bool)
        self.snapshots: list[tuple | None] = [None] * n  # per element, its state at its commit
        self.answered = np.zeros(self.n_channels)  # the last basic forces answered, kN (kN mm)
        self.steps = 0
        self.trials = 0  # motions of the actuators, committed or not
        self.trials_recorded = 0  # self.trials when the last step was recorded
        self.committed_trial: list[Trial | None] = [None] * n  # per element, its trial at its last commit
        self.abandoned = 0  # motions of this step's attempts the analysis went back from (0: none)
        self.abandoned_total = 0
        self.retried_steps = 0
        self.last_time: float | None = None  # the time of the last recorded step
        self.time_step_noted = False  # the model's time step was found to differ from dt (said once)
        self.last_increment: float | None = None  # the model's last time step, s
        self.time_steps_alike = 0  # steps in a row with that time step
        self.failed = ""
        self.clean_end = True  # every element that left said DIE (the preloads may ramp off)
        self.left: set[int] = set()  # elements that left this session: a new client joins the next one
        self.site_s = 0.0
        self.record_s = 0.0
        self.started = time.perf_counter()

    def _attach(self, j: int) -> int | None:
        """Element ``j`` joins the session (the first one opens the actuators): None. When ``j``
        has left the session that is still open, nothing is done and that session's number is
        returned: its new client is a new run of the model, which belongs to the next session."""
        if self.stopping:
            raise HsioError("the server is stopping")
        if j in self.left and self.active:
            return self.sessions
        if not self.active:
            self._open()
        self.active.add(j)
        return None

    def _detach(self, j: int, reason: str, clean: bool = False) -> None:
        """Element ``j`` leaves (``clean``: with DIE); the last one ends the session: actuators
        hold, record closed. One that leaves otherwise while others go on is an event (``left``),
        unless the session has stopped (its ``stop`` event says why)."""
        self.active.discard(j)
        self.left.add(j)
        if not clean:
            self.clean_end = False
        self.committed_flags[j] = False  # its snapshot, if it committed this step, stays in the step's row
        self.log(f"element {self.names[j]}: {reason}")
        if not self.active:
            self._close(reason, clean)
        elif self.site is not None:
            if not clean and not self.failed and self.recorder is not None:  # a stopped session: its stop says it
                self.recorder.write_event(self._lab_time(self.site), self.steps + 1, "left", self.names[j],
                                          f"element {self.names[j]} left the session ({reason}); its actuators "
                                          f"keep their last target while the other elements go on")
            if not self.failed:
                self._record_if_all_committed(self.site)
        with self._stepped:
            self._stepped.notify_all()

    def _open(self) -> None:
        self._reset_session()
        self.sessions += 1
        cfg, test, hardware = self.config, self.config["test"], self.config["hardware"]
        emulator = merged_emulator_table(hardware["actuator_model"], cfg["emulator"])
        # per actuator, as `hsio run` (through setups, the setups' actuators, not the basic DOFs)
        actuators = SetupMap.of(self.structure).actuator_names if self.structure.has_setups else self.channels
        self.compensation = compensation = CompensationStage(list(actuators), test["rate"] * self.structure.dt,
                                                             CompensationSettings.from_table(cfg["compensation"]))
        try:
            self.site = api.open_site(self.structure, hardware["url"], clock=hardware["clock"], test_rate=test["rate"],
                                      hold_fraction=test["hold_fraction"], n_avg=test["n_avg"],
                                      keep_samples=cfg["output"]["samples"],
                                      options=emulator if hardware["url"].startswith("emulator") else cfg["driver"],
                                      compensation=compensation, safety=SafetySettings.from_table(cfg["safety"]))
        except BaseException as exc:  # an earlier session's read-back no longer tells how they stand
            self.hold_message = (f"the hold could not be read back: opening the actuators for session {self.sessions} "
                                 f"failed ({exc})")
            raise
        meta = {"config": cfg.tables, "config_source": cfg.source, "structure": self.structure.name,
                "source": "opensees genericClient", "elements": self.names, "channels": self.channels, "dt": self.structure.dt,
                "test_rate": test["rate"], "length_factor": self.settings.length_factor,
                "force_factor": self.settings.force_factor, "force_correction": self.correct,
                "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "start_state": self._state()}
        try:
            self.recorder = self._new_record(Path(self.settings.out), meta)
        except BaseException as exc:
            self.hold_message = (f"the hold could not be read back: the record of session {self.sessions} could not "
                                 f"be written ({exc}); its actuators were opened and closed again")
            self.site.close()
            self.site = None
            raise
        # per step (its last motion's), as `hsio run` records it: what `hsio calibrate` reads (docs/compensation.md)
        compensation.sink = self.recorder.write_compensation
        self.log(f"session {self.sessions}: actuators of {', '.join(self.names)} open; record {self.recorder.path}")
        if self.structure.static:
            loads = ", ".join(f"{s.name} {s.force_kN:g} kN" for s in self.structure.static)
            try:
                with self._moving():
                    self.site.preload(stop=lambda: self.stopping)
            except BaseException as exc:
                self.failed = f"the static preloads could not be ramped in: {exc}"
                self._close(self.failed)
                raise
            self.log(f"session {self.sessions}: static preloads ramped in and held ({loads})")
            for name, short in self.site.preloads_short():
                message = f"{short}; the session runs under it"
                self.log(f"session {self.sessions}: warning: {message}")
                self.recorder.write_event(self._lab_time(self.site), 0, "warning", name, message)

    def _new_record(self, out: Path, meta: dict) -> Recorder:
        """The session's record: ``run.sqlite`` in ``out``, then ``run-2.sqlite``, ... the first
        name that no record (nor a journal SQLite left beside one) takes, from this session's
        number on; the session takes its number. A server started again on a folder with the
        records of an earlier one goes on numbering after them: nothing is overwritten, and no
        client is refused for it."""
        k = self.sessions
        for _ in range(MAX_SESSION_FILES):
            path = out / ("run.sqlite" if k == 1 else f"run-{k}.sqlite")
            if not any(Path(f"{path}{suffix}").exists() for suffix in ("", "-wal", "-journal")):
                try:
                    recorder = Recorder(path, self.channels, self.channels, meta)
                except RecordExistsError:  # taken meanwhile by another process
                    pass
                except (OSError, sqlite3.Error) as exc:  # the folder went away, became a file, the disk is full
                    raise RecordError(f"{out}: the session's record {path.name} cannot be written there: "
                                      f"{getattr(exc, 'strerror', None) or exc}") from None
                else:
                    self.sessions = k
                    return recorder
            k += 1
        first = "run.sqlite" if self.sessions == 1 else f"run-{self.sessions}.sqlite"
        raise HsioError(f"{out}: no free record name among {first} .. run-{k - 1}.sqlite; "
                        "give the server another records folder (--out)")

    def _state(self) -> dict:
        """Measured displacement and force per actuator where they stand, as `hsio run` records
        its ``start_state`` (by the actuators' names)."""
        try:
            feedback = self.site.loop.feedback()
        except Exception as exc:  # a lost link: say so rather than guess
            return {"error": str(exc)}
        return {a.name: {"displacement_mm": f.displacement_mm, "force_kN": f.force_kN}
                for a, f in zip(self.site.loop.actuators, feedback)}

    def _release_preloads(self, reason: str) -> None:
        """At the end of a session: the static preloads ramp off when every element ended with
        DIE and nothing failed; otherwise they stay held with the actuators, as when `hsio run`
        stops early (docs/opensees.md)."""
        site = self.site  # None once the session closed: this runs once per session
        if site is None or not site.static_log:  # no session, or no preload ramped in
            return
        if self.failed or not self.clean_end:
            self.log(f"session {self.sessions}: static preloads held, not ramped off ({self.failed or reason})")
            return
        ramp_s = max(s.ramp_s for s in site.static)
        self.log(f"session {self.sessions}: ramping the static preloads off ({ramp_s:g} s of lab time; a client "
                 f"that connects meanwhile starts the next session after it)")
        try:
            with self._moving():
                site.release(stop=lambda: self.stopping)
            self.log(f"session {self.sessions}: static preloads ramped off")
        except RampStopped as exc:
            self.failed = f"the server stopped: {exc}"
            self.log(f"session {self.sessions}: {exc} (the server is stopping)")
        except Exception as exc:
            self.failed = f"ramping the static preloads off: {exc}"
            self.log(f"session {self.sessions}: {self.failed}; they stay held")

    def _close(self, reason: str, clean: bool = False) -> None:
        """End the session (``clean``: its last element ended with DIE and nothing failed, else it
        stopped: the record gets the hold and the stop as events). With no session open (it
        ended earlier), nothing is left to close or to report."""
        if self.site is None and self.recorder is None:
            with self._stepped:
                self._stepped.notify_all()
            return
        self._release_preloads(reason)
        if self.site is not None and self.recorder is not None:
            self.recorder.write_tables(self.site.record_tables())
        static_error = None
        if self.site is not None and self.site.static and self.site.static_log:
            static_error = {s.name: float(e) for s, e in zip(self.site.static, self.site.static_hold_error())
                            if np.isfinite(e)}
        if self.site is not None:
            confirmed = False
            try:
                report = self.site.hold()  # every actuator holds; the hold is read back
                self.hold_message = report.message if report is not None else "no actuators to hold"
                confirmed = report is None or report.confirmed
            except Exception as exc:
                self.hold_message = f"the hold could not be confirmed ({exc})"
            self.log(f"session {self.sessions}: {self.hold_message}")
            if self.recorder is not None:  # as `hsio run` records a stop: what the safety layer saw, the hold
                self._write_events(self.site, self.steps + 1)
                lab_time = self._lab_time(self.site)
                stopped = bool(self.failed) or not clean
                if stopped or not confirmed:
                    self.recorder.write_event(lab_time, self.steps + 1, "hold", "", self.hold_message, commit=False)
                if stopped:
                    self.recorder.write_event(lab_time, self.steps + 1, "stop", "", self.failed or reason, commit=False)
            try:
                self.site.close()  # every actuator holds, then is released
            except Exception as exc:  # closing must not stop the server
                self.log(f"closing the actuators: {exc}")
            self.site = None
        uncommitted = self.trials - self.trials_recorded
        if uncommitted:  # e.g. an analysis that failed to converge: its trials moved the specimen
            self.log(f"session {self.sessions}: {uncommitted} trial motion(s) of the actuators after the last "
                     f"committed step (step {self.steps}) were never committed by the analysis: the specimen "
                     f"went through them, the record holds no row for them")
        if self.recorder is not None:
            wall = time.perf_counter() - self.started
            self.recorder.write_summary({"steps": self.steps, "elements": self.names, "end": reason,
                                         "stopped": self.failed, "uncommitted_trials": uncommitted,
                                         "retried_steps": self.retried_steps,
                                         "abandoned_trials": self.abandoned_total,
                                         "final_hold": self.hold_message,
                                         **({"compensation": self.compensation.summary()}
                                            if self.compensation is not None else {}),
                                         "wall_time_s": round(wall, 3),
                                         "site_time_s": round(self.site_s, 3),
                                         "record_time_s": round(self.record_s, 3),
                                         **({"static_hold_error": static_error} if static_error is not None else {})})
            self.recorder.close()
            self.log(f"session {self.sessions} ended ({reason}): {self.steps} committed steps recorded")
            self.recorder = None
        with self._stepped:
            self._stepped.notify_all()

    def _hold(self, reason: str, j: int | None = None) -> None:
        """Stop the session's motion: every actuator holds; later force requests fail."""
        if j is not None and j not in self.active:
            return
        self.failed = self.failed or reason
        if self.site is not None:
            try:
                self.site.hold()
            except Exception:
                pass
        with self._stepped:  # elements waiting for the step go on, to be told the session stopped
            self._stepped.notify_all()

    # --- units ----------------------------------------------------------------------------
    # Per basic DOF of element j, hsio's units per model unit are units[j] (length_factor for a
    # translation, 1 for a rotation); a basic force is work-conjugate to its displacement, so
    # q_model = q_hsio units / (force_factor length_factor) and K_model = K_hsio u u^T / (ff lf).
    def to_mm(self, j: int, x) -> np.ndarray:
        """Element ``j``'s displacements (or velocities, accelerations) from model units to mm (rad)."""
        return np.asarray(x, dtype=float) * self.units[j]

    def to_model(self, j: int, x) -> np.ndarray:
        """Element ``j``'s displacements from mm (rad) to model units."""
        return np.asarray(x, dtype=float) / self.units[j]

    def force_to_model(self, j: int, q) -> np.ndarray:
        """Element ``j``'s basic forces from kN (kN mm for a moment) to model units."""
        s = self.settings
        return np.asarray(q, dtype=float) * self.units[j] / (s.force_factor * s.length_factor)

    def matrix(self, j: int, key: str) -> np.ndarray:
        """Element ``j``'s configured ``mass`` or ``damping`` over its basic DOFs, in hsio units: the
        number times the identity, or the matrix given (0 when not configured)."""
        value = getattr(self.settings, key).get(self.names[j], 0.0)
        n = self.n_basic[j]
        return np.eye(n) * value if isinstance(value, float) else np.array(value, dtype=float)

    def stiffness_to_model(self, j: int, K) -> np.ndarray:
        """An n x n matrix over element ``j``'s basic DOFs (stiffness, damping or mass) to model units."""
        s = self.settings
        return np.asarray(K, dtype=float) * np.outer(self.units[j], self.units[j]) / (s.force_factor * s.length_factor)

    # --- actions --------------------------------------------------------------------------
    def _require_site(self, j: int | None = None):
        """The session's site; refused when the session stopped, or when element ``j`` is not in
        it (a client whose element left, or was detached when another element stopped the session,
        never moves the actuators of a later session)."""
        if j is not None and j not in self.active:
            raise HsioError(f"element {self.names[j]} is not in the open session")
        if self.failed:
            raise HsioError(f"the session stopped earlier ({self.failed}); the actuators hold")
        if self.site is None:
            raise HsioError("no session is open")
        return self.site

    def _force(self, j: int) -> np.ndarray:
        """Element ``j``'s basic forces (kN, kN mm) at its latest trial, moving the actuators if needed."""
        site = self._require_site(j)
        b = self.blocks[j]
        trial = self.latest[j]
        if trial is None:
            return site.committed()[1][b].copy()
        if trial is self.committed_trial[j]:  # asked again after the commit (eleForce, a recorder): nothing moves
            return self.answered[b].copy()
        if not self.moved_this_step[j] or np.any(self.to_mm(j, trial.d) != self.imposed[b]):
            self._impose(site)
        daq = site.get_daq()
        q = daq.R[b].copy()
        if self.correct:
            q += self.K_EI[j] @ (self.imposed[b] - daq.u[b])
        self.answered[b] = q
        return q

    def _impose(self, site) -> None:
        """Every element with a new trial moves to it; the others stay at their last target. The
        setups turn the basic displacements into strokes (exact geometry); every stroke is
        checked against its actuator's limits before anything moves."""
        latest = list(self.latest)
        targets = (self.imposed if self.has_imposed else site.committed()[0]).copy()
        for k, trial in enumerate(latest):
            if trial is not None and k in self.active:  # an element that left keeps its last target
                targets[self.blocks[k]] = self.to_mm(k, trial.d)
        strokes = site.setups.strokes(targets) if site.setups is not None else targets
        for actuator, value in zip(site.loop.actuators, strokes):  # refused before anything moves
            actuator.limits.check(ControlMode.DISPLACEMENT, float(value), f"actuator {actuator.name!r} trial")
        t0 = time.perf_counter()
        try:
            with self._moving():
                site.set_trial(targets, [ControlMode.DISPLACEMENT] * self.n_channels)
        except LimitError:  # refused before it was sent: nothing moved
            raise
        except BaseException:  # stopped on the way (an interlock): the specimen went part of it
            self.trials += 1
            raise
        self.site_s += time.perf_counter() - t0
        self.trials += 1
        self.imposed = targets
        self.has_imposed = True
        for k, trial in enumerate(latest):
            if trial is not None and k in self.active:
                self.moved_this_step[k] = True

    def _displacement(self, j: int) -> np.ndarray:
        """The measured basic displacements (mm, rad) of element ``j`` after its last trial."""
        site = self._require_site(j)
        b = self.blocks[j]
        try:
            return site.get_daq().u[b].copy()
        except RuntimeError:
            return site.committed()[0][b].copy()

    def _tangent(self, j: int) -> np.ndarray:
        """A one-DOF element's secant of its last trial where it is finite and positive; K^EI otherwise
        (and always for an element with several basic DOFs)."""
        if self.n_basic[j] == 1 and self.site is not None:
            try:
                k = float(self.site.get_daq().k[self.blocks[j].start])
            except RuntimeError:  # no trial yet
                k = float("nan")
            if np.isfinite(k) and k > 0:
                return np.array([[k]])
        return self.K_EI[j]

    def _commit(self, j: int) -> None:
        """Element ``j`` accepts the step: its state is kept as it is now (the next trial may come
        before the other elements commit); once every connected element has committed, the step is
        recorded. A step in which nothing moved (a commit before any force) is not a step."""
        site = self._require_site(j)
        if self.moved_this_step[j]:
            daq = site.get_daq()
            b = self.blocks[j]
            trial = self.latest[j]
            motion = [self.to_mm(j, x) if x.size else np.zeros(self.n_basic[j]) for x in (trial.d, trial.v, trial.a)]
            self.snapshots[j] = (trial.t, *motion, self.imposed[b].copy(), self.answered[b].copy(),
                                 daq.commands[b].copy(), daq.u[b].copy(), daq.R[b].copy())
        self.committed_flags[j] = True
        self.moved_this_step[j] = False
        self.committed_trial[j] = self.latest[j]
        self._record_if_all_committed(site)

    def _went_back(self, j: int) -> None:
        """Element ``j`` was sent its committed trial again after the actuators moved in this step:
        the analysis abandoned the attempt (it failed to converge) and tries the step again. The
        motions so far are the abandoned ones; the step committed next is flagged ``retried``."""
        self.abandoned = max(self.abandoned, self.trials - self.trials_recorded)

    def _record_if_all_committed(self, site) -> None:
        """Once every connected element has committed, the step is one row of the record; the
        elements waiting in :meth:`wait_for_step` go on."""
        if not self.active or not all(self.committed_flags[k] for k in self.active):
            return
        rows = list(self.snapshots)
        self.snapshots = [None] * self.n
        with self._stepped:
            self.committed_flags[:] = False
            self._stepped.notify_all()
        if all(r is None for r in rows):
            return
        for k, r in enumerate(rows):  # an element that left (or did not move in the step): as its actuators stand
            if r is None:
                rows[k] = self._standing(site, k)
        samples = site.take_samples()
        site.commit()
        self.steps += 1
        self.trials_recorded = self.trials
        t0 = time.perf_counter()
        columns = [np.concatenate([r[c] for r in rows]) for c in range(1, 9)]
        u, v, a, target, answered, command, disp, force = columns
        times = [r[0] for r in rows if math.isfinite(r[0])]
        t_step = float(times[0]) if times else self.steps * self.structure.dt  # elements without time: step x dt
        events = self._write_events(site, self.steps)
        lab_time = self._lab_time(site)
        if self.abandoned:
            self.retried_steps += 1
            self.abandoned_total += self.abandoned
            note = (f"step {self.steps} (t = {t_step:g} s) was committed after the analysis went back to step "
                    f"{self.steps - 1} and tried again: {self.abandoned} trial motion(s) of the actuators before it "
                    f"were abandoned (the specimen went through them; they are no step of the record)")
            events.append(self._note(lab_time, "retried", note))
            self.log(f"session {self.sessions}: {note}")
            self.abandoned = 0
        if self.last_time is not None and not t_step > self.last_time:
            events.append(self._note(lab_time, "time_back", f"step {self.steps}: the model's time {t_step:g} s is not "
                                     f"after the previous step's {self.last_time:g} s; recorded as the model sent it "
                                     f"(a static analysis' pseudo-time, or a clock set back, e.g. loadConst -time)"))
        elif self.last_time is not None and not self.time_step_noted and times:
            note = self._time_step_note(t_step - self.last_time)
            if note and self.time_steps_alike >= STEADY_STEPS:
                self.time_step_noted = True
                events.append(self._note(lab_time, "time_step", note))
                self.log(f"session {self.sessions}: warning: {note}")
        self.last_time = t_step
        self.recorder.write_step(self.steps, t_step, u, v, a, target,
                                 answered, [ControlMode.DISPLACEMENT.value] * self.n_channels, target, command, disp,
                                 force, samples, late_steps=getattr(site, "late_steps", 0),
                                 flags=sorted({e["kind"] for e in events}))
        self.record_s += time.perf_counter() - t0

    def _time_step_note(self, increment: float) -> str:
        """What to say when the model's time step ``increment`` is not the structure's dt (empty
        when it is, within 1 %): each step's motion lasts TR dt of lab time whatever the model's
        step, so the lab's time runs at TR dt / increment times the model's, not at TR. Counts
        the steps in a row with this increment (``time_steps_alike``): a step tried again with a
        shorter dt is no steady time step."""
        dt, rate = self.structure.dt, self.config["test"]["rate"]
        same = self.last_increment is not None and abs(increment - self.last_increment) <= 1e-6 * abs(increment)
        self.time_steps_alike = self.time_steps_alike + 1 if same else 1
        self.last_increment = increment
        if abs(increment - dt) <= 0.01 * dt:
            return ""
        return (f"step {self.steps}: the model's time step {increment:g} s is not the structure's dt {dt:g} s; each "
                f"step's motion lasts TR x dt = {rate * dt:g} s of lab time, so the lab's time runs "
                f"{rate * dt / increment:g} times slower than the model's, not TR = {rate:g} times (a static "
                f"analysis' pseudo-time: no matter; a dynamic one: give the structure the model's dt)")

    def _standing(self, site, j: int) -> tuple:
        """A step's row for element ``j`` without a committed trial in it (it left the session, or
        committed without moving): no model values (time, u, v, a and the force answered are nan:
        NULL in the record), and its actuators as they stand: the target they hold, their last
        command and measurement."""
        b = self.blocks[j]
        blank = np.full(self.n_basic[j], np.nan)
        try:
            daq = site.get_daq()
            command, disp, force = daq.commands[b].copy(), daq.u[b].copy(), daq.R[b].copy()
        except RuntimeError:  # nothing moved yet in this session
            command, (disp, force) = blank, (x[b].copy() for x in site.committed()[:2])
        target = self.imposed[b].copy() if self.has_imposed else site.committed()[0][b].copy()
        return (float("nan"), blank, blank, blank, target, blank, command, disp, force)

    def _write_events(self, site, step: int) -> list[dict]:
        """The safety layer's warnings and trips since the last call, into the record with ``step``
        (committed with the step's row) and the log."""
        events = write_events(self.recorder, site, step)
        for e in events:
            self.log(f"session {self.sessions}, step {step}: {e['kind']}: {e['actuator']}: {e['message']}")
        return events

    def _note(self, lab_time: float | None, kind: str, message: str) -> dict:
        """An event of the server itself (``retried``, ``time_back``), with the step being written."""
        self.recorder.write_event(lab_time, self.steps, kind, "", message, commit=False)
        return {"kind": kind}

    @staticmethod
    def _lab_time(site) -> float | None:
        try:
            return float(site.lab_time_s)
        except Exception:
            return None

    def _stop(self) -> None:
        if self.active:
            self.clean_end = False  # the server stops under a running session
        self.active.clear()
        self._close("server stopped")

    # --- work in progress -----------------------------------------------------------------
    @contextlib.contextmanager
    def _moving(self):
        """A motion of the actuators (a trial, a preload ramp): while it lasts, and until it ends,
        the silence of every element's client is explained (:meth:`silent_since`)."""
        with self._work:
            self._working += 1
        try:
            yield
        finally:
            with self._work:
                self._working -= 1
                self._worked_at = time.monotonic()

    def silent_since(self, start: float) -> float:
        """The time (``time.monotonic()``) from which the silence of a client that has said
        nothing since ``start`` counts against ``timeout_s``: now while the actuators execute a
        motion for any element, else the later of ``start`` and the end of the last motion. An
        element of a model waits, silent, while another element's motion runs (OpenSees asks its
        elements one after the other): with a real-time clock a motion may outlast the timeout."""
        with self._work:
            if self._working:
                return time.monotonic()
            return max(start, self._worked_at)

    # --- the worker -----------------------------------------------------------------------
    def _call(self, fn, *args):
        try:
            future = self._worker.submit(fn, *args)
        except RuntimeError:  # the worker has stopped: the server is closing
            raise HsioError("the server is stopping") from None
        return future.result()

    def attach(self, j: int, timeout_s: float | None = None, log=None) -> None:
        """Element ``j`` joins the session (the first one opens the actuators). An element that
        has left the open session (OpenSees' wipe() says DIE to one element after the other, and
        a model built again at once connects its first element before the others' DIE) joins the
        next one: its client waits, up to ``timeout_s``, for the session's other elements to leave.
        Raises :class:`SessionBusy` when they have not (``timeout_s`` None: [opensees] timeout_s)."""
        timeout_s = self.settings.timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout_s
        for attempt in range(1_000_000):  # each pass waits for the session to end, or ends
            session = self._call(self._attach, j)
            if session is None:
                return
            others = self._call(lambda: ", ".join(self.names[k] for k in sorted(self.active)))  # the worker's set
            if attempt == 0 and log is not None:
                log(f"session {session} goes on with {others} after element {self.names[j]} left it: this "
                    f"client joins the next session")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            with self._stepped:  # the session ends (another may open at once), or the server stops
                self._stepped.wait_for(lambda: not self.active or self.sessions != session or self.stopping,
                                       remaining)
        raise SessionBusy(f"element {self.names[j]} left session {session}, which {others or 'other elements'} "
                          f"did not leave within {timeout_s:g} s; a new client of {self.names[j]} joins the next "
                          f"session")

    def detach(self, j: int, reason: str, clean: bool = False) -> None:
        """Element ``j`` leaves (``clean``: it ended with DIE); the last one ends the session:
        actuators hold, record closed."""
        self.begin_detach(j, reason, clean).result()

    def begin_detach(self, j: int, reason: str, clean: bool = False) -> Future:
        """:meth:`detach`, queued on the worker without waiting for it. The worker runs in
        order, so an element that attaches after this call joins after the detach: a client that
        reconnects while the session closes (its preloads ramping off) opens the next session."""
        try:
            return self._worker.submit(self._detach, j, reason, clean)
        except RuntimeError:  # the worker has stopped: the server is closing
            raise HsioError("the server is stopping") from None

    def hold(self, reason: str, j: int | None = None) -> None:
        """Every actuator holds; later force requests of this session fail. With ``j``: only when
        element ``j`` is in the open session (a client left behind by a session that ended does
        not stop the next one)."""
        self._call(self._hold, reason, j)

    def set_trial(self, j: int, trial: Trial) -> None:
        """Store element ``j``'s trial (nothing moves until a force is asked for); no worker hop:
        one reference is replaced, and :meth:`_impose` works on a copy of the list. A trial equal to
        the element's last committed one (displacement and time) after the actuators moved in this
        step is OpenSees going back after a failed attempt: noted (:meth:`_went_back`)."""
        committed = self.committed_trial[j]
        if (committed is not None and self.trials > self.trials_recorded and trial.t == committed.t
                and np.array_equal(trial.d, committed.d)):
            self._call(self._went_back, j)
        if j not in self.active:  # left, or detached when another element stopped the session
            raise HsioError(f"element {self.names[j]} is not in the open session")
        self.latest[j] = trial

    def force(self, j: int) -> np.ndarray:
        """Element ``j``'s basic forces (kN, kN mm) at its latest trial, moving the actuators if needed."""
        return self._call(self._force, j)

    def displacement(self, j: int) -> np.ndarray:
        """The measured basic displacements (mm, rad) of element ``j`` after its last trial."""
        return self._call(self._displacement, j)

    def tangent(self, j: int) -> np.ndarray:
        """Over element ``j``'s basic DOFs (hsio units): K^EI, or for a one-DOF element the secant
        of the last trial where it is finite and positive (``stiffness = "secant"``)."""
        if self.settings.stiffness == "initial":
            return self.K_EI[j]
        return self._call(self._tangent, j)

    def commit(self, j: int) -> None:
        """Element ``j`` accepts the step; once every connected element has, the step is recorded."""
        self._call(self._commit, j)

    def wait_for_step(self, j: int, timeout_s: float) -> None:
        """After its commit, element ``j`` waits until every connected element has committed the
        same step (the step is recorded), so that no element's next trial runs into a step the
        others have not finished: the served elements step together, as the elements of one
        OpenSees model do. commitState has no reply, so the model is never held up by the wait.
        Raises HsioError after ``timeout_s`` of waiting that no motion explains (:meth:`silent_since`),
        or at once when the server stops (:meth:`release`)."""
        start = time.monotonic()
        with self._stepped:
            def over():
                return not self.committed_flags[j] or self.site is None or self.failed or self.stopping
            done = over()
            # each pass waits until the deadline, which moves only while the actuators move
            for _ in range(1_000_000):
                left = self.silent_since(start) + timeout_s - time.monotonic()
                if done or left <= 0:
                    break
                done = self._stepped.wait_for(over, left)
            if self.stopping:
                raise HsioError("the server is stopping")
        if not done:
            waiting = [self.names[k] for k in sorted(self.active) if not self.committed_flags[k]]
            raise HsioError(f"element {self.names[j]} committed a step; {', '.join(waiting) or 'another element'} "
                            f"did not commit it within {timeout_s:g} s (the elements of one server must belong "
                            f"to one model and step together)")

    def release(self) -> None:
        """The server is stopping: every element waiting in :meth:`wait_for_step` goes on at once
        (to be told so), and none waits again."""
        with self._stepped:
            self.stopping = True
            self._stepped.notify_all()

    def latest_time(self, j: int) -> float:
        trial = self.latest[j]
        return trial.t if trial is not None and math.isfinite(trial.t) else 0.0  # an element without time: 0

    def close(self) -> None:
        """End any session (actuators hold, record closed) and stop the worker."""
        try:
            self._call(self._stop)
        finally:
            self._worker.shutdown(wait=True)
