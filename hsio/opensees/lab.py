"""The lab behind the served elements: their actuators, opened per session, and the record.

A *session* starts when the first served element connects and ends when the last one leaves
(DIE, a closed connection, a silent element, an error). It opens the actuators with
:func:`hsio.api.open_site` exactly as `hsio run` does (command generation by the controller-rate
loop, feed-forward compensation, limits), and records each committed step with
:class:`hsio.recording.Recorder`. At its end the actuators hold and are released, and the record
is closed; a trial that was never committed is not written (docs/opensees.md).

Trials are imposed lazily: a setTrialResponse is stored, and the actuators move when a force is
asked for (getForce), once per step unless the trial displacement changes within the step. OpenSees'
AlphaOS sends the predicted displacement twice per step (before and after its corrector, with
corrected velocities); the specimen moves once, as in `hsio run`'s alpha-OS (docs/method.md
section 2).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from hsio import api
from hsio.compensation.stage import CompensationSettings, CompensationStage
from hsio.config import RunConfig
from hsio.diagnose.modelfile import merged_emulator_table
from hsio.errors import ConfigError, HsioError
from hsio.interfaces import ControlMode
from hsio.opensees.protocol import Trial
from hsio.opensees.settings import OpenSeesSettings
from hsio.recording import Recorder
from hsio.structures import ExperimentalElement, Structure


def served_structure(structure: Structure, names) -> Structure:
    """The experimental elements ``names`` of ``structure`` as a structure of their own (one DOF each):
    what :func:`hsio.api.open_site` needs to open their actuators."""
    by_name = {e.name: e for e in structure.experimental}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise ConfigError(f"[opensees] elements: {unknown[0]!r} is not an experimental element of structure "
                          f"{structure.name!r}; known: {', '.join(by_name)}")
    elements = tuple(ExperimentalElement(n, j, by_name[n].specimen) for j, n in enumerate(names))
    return Structure(name=structure.name, dof_names=tuple(names), masses=(1.0,) * len(names),
                     experimental=elements, dt=structure.dt, description=f"served elements of {structure.name}")


class Lab:
    """The served elements' actuators and record.

    Every public method runs in the lab's one worker thread (the actuators' loop and the SQLite
    record belong to one thread), so the connections' threads may call them at any time.
    """

    def __init__(self, settings: OpenSeesSettings, config: RunConfig, structure: Structure, log=print):
        self.settings = settings
        self.config = config
        self.structure = served_structure(structure, settings.elements)
        self.names = list(settings.elements)
        self.n = len(self.names)
        self.K_EI = np.array([e.K_EI for e in self.structure.experimental])
        self.correct = (config["test"]["measured_displacement_correction"] if settings.force_correction is None
                        else settings.force_correction)
        self.log = log
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hsio-opensees-lab")
        self.site = None
        self.recorder: Recorder | None = None
        self.hold_message = "no session was open: no actuators to hold"  # the last session's hold, read back
        self.sessions = 0
        self.active: set[int] = set()
        self._reset_session()

    # --- sessions -------------------------------------------------------------------------
    def _reset_session(self) -> None:
        n = self.n
        self.latest: list[Trial | None] = [None] * n
        self.imposed = np.zeros(n)  # targets sent to the site, mm
        self.has_imposed = np.zeros(n, dtype=bool)
        self.moved_this_step = np.zeros(n, dtype=bool)
        self.committed_flags = np.zeros(n, dtype=bool)
        self.snapshots: list[tuple | None] = [None] * n  # per element, its state at its commit
        self.answered = np.zeros(n)  # the last force answered, kN
        self.steps = 0
        self.failed = ""
        self.site_s = 0.0
        self.record_s = 0.0
        self.started = time.perf_counter()

    def _attach(self, j: int) -> None:
        """Element ``j`` joins the session (the first one opens the actuators)."""
        if not self.active:
            self._open()
        self.active.add(j)

    def _detach(self, j: int, reason: str) -> None:
        """Element ``j`` leaves; the last one ends the session: actuators hold, record closed."""
        self.active.discard(j)
        self.log(f"element {self.names[j]}: {reason}")
        if not self.active:
            self._close(reason)

    def _open(self) -> None:
        self._reset_session()
        self.sessions += 1
        cfg, test, hardware = self.config, self.config["test"], self.config["hardware"]
        emulator = merged_emulator_table(hardware["actuator_model"], cfg["emulator"])
        compensation = CompensationStage(self.names, test["rate"] * self.structure.dt,
                                         CompensationSettings.from_table(cfg["compensation"]))
        self.site = api.open_site(self.structure, hardware["url"], clock=hardware["clock"], test_rate=test["rate"],
                                  hold_fraction=test["hold_fraction"], n_avg=test["n_avg"],
                                  keep_samples=cfg["output"]["samples"],
                                  options=emulator if hardware["url"].startswith("emulator") else cfg["driver"],
                                  compensation=compensation)
        out = Path(self.settings.out)
        path = out / ("run.sqlite" if self.sessions == 1 else f"run-{self.sessions}.sqlite")
        meta = {"config": cfg.tables, "config_source": cfg.source, "structure": self.structure.name,
                "source": "opensees genericClient", "elements": self.names, "dt": self.structure.dt,
                "test_rate": test["rate"], "length_factor": self.settings.length_factor,
                "force_factor": self.settings.force_factor, "force_correction": self.correct,
                "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        try:
            self.recorder = Recorder(path, self.names, self.names, meta)
        except BaseException:
            self.site.close()
            self.site = None
            raise
        self.log(f"session {self.sessions}: actuators of {', '.join(self.names)} open; record {path}")

    def _close(self, reason: str) -> None:
        if self.site is not None:
            try:
                report = self.site.hold()  # every actuator holds; the hold is read back
                self.hold_message = report.message if report is not None else "no actuators to hold"
            except Exception as exc:
                self.hold_message = f"the hold could not be confirmed ({exc})"
            self.log(f"session {self.sessions}: {self.hold_message}")
            try:
                self.site.close()  # every actuator holds, then is released
            except Exception as exc:  # closing must not stop the server
                self.log(f"closing the actuators: {exc}")
            self.site = None
        if self.recorder is not None:
            wall = time.perf_counter() - self.started
            self.recorder.write_summary({"steps": self.steps, "elements": self.names, "end": reason,
                                         "stopped": self.failed, "wall_time_s": round(wall, 3),
                                         "site_time_s": round(self.site_s, 3),
                                         "record_time_s": round(self.record_s, 3)})
            self.recorder.close()
            self.log(f"session {self.sessions} ended ({reason}): {self.steps} committed steps recorded")
            self.recorder = None

    def _hold(self, reason: str) -> None:
        """Stop the session's motion: every actuator holds; later force requests fail."""
        self.failed = self.failed or reason
        if self.site is not None:
            try:
                self.site.hold()
            except Exception:
                pass

    # --- units ----------------------------------------------------------------------------
    def to_mm(self, x):
        return np.asarray(x, dtype=float) * self.settings.length_factor

    def force_to_model(self, F):
        return np.asarray(F, dtype=float) / self.settings.force_factor

    def stiffness_to_model(self, K):
        return np.asarray(K, dtype=float) * self.settings.length_factor / self.settings.force_factor

    # --- actions --------------------------------------------------------------------------
    def _require_site(self):
        if self.failed:
            raise HsioError(f"the session stopped earlier ({self.failed}); the actuators hold")
        if self.site is None:
            raise HsioError("no session is open")
        return self.site

    def _force(self, j: int) -> float:
        """Element ``j``'s force (kN) at its latest trial, moving the actuators if needed."""
        site = self._require_site()
        trial = self.latest[j]
        if trial is None:
            return float(site.committed()[1][j])
        target = float(self.to_mm(trial.d)[0])
        if not self.moved_this_step[j] or target != self.imposed[j]:
            self._impose(site)
        daq = site.get_daq()
        F = float(daq.R[j])
        if self.correct:
            F += float(self.K_EI[j] * (self.imposed[j] - daq.u[j]))
        self.answered[j] = F
        return F

    def _impose(self, site) -> None:
        """Every element with a new trial moves to it; the others stay at their last target."""
        latest = list(self.latest)
        targets = np.where(self.has_imposed, self.imposed, site.committed()[0])
        for k, trial in enumerate(latest):
            if trial is not None:
                targets[k] = float(self.to_mm(trial.d)[0])
        for actuator, value in zip(site.loop.actuators, targets):  # refused before anything moves
            actuator.limits.check(ControlMode.DISPLACEMENT, float(value), f"element {actuator.name!r} trial")
        t0 = time.perf_counter()
        site.set_trial(targets, [ControlMode.DISPLACEMENT] * self.n)
        self.site_s += time.perf_counter() - t0
        self.imposed = targets
        self.has_imposed[:] = True
        for k, trial in enumerate(latest):
            if trial is not None:
                self.moved_this_step[k] = True

    def _displacement(self, j: int) -> float:
        """The measured displacement (mm) of element ``j`` after its last trial."""
        site = self._require_site()
        try:
            return float(site.get_daq().u[j])
        except RuntimeError:
            return float(site.committed()[0][j])

    def _tangent(self, j: int) -> float:
        if self.settings.stiffness == "secant" and self.site is not None:
            try:
                k = float(self.site.get_daq().k[j])
            except RuntimeError:  # no trial yet
                k = float("nan")
            if np.isfinite(k) and k > 0:
                return k
        return float(self.K_EI[j])

    def _commit(self, j: int) -> None:
        """Element ``j`` accepts the step: its state is kept as it is now (the next trial may come
        before the other elements commit); once every connected element has committed, the step is
        recorded. A step in which nothing moved (a commit before any force) is not a step."""
        site = self._require_site()
        if self.moved_this_step[j]:
            daq = site.get_daq()
            trial = self.latest[j]
            motion = (float(self.to_mm(x)[0]) if x.size else 0.0 for x in (trial.d, trial.v, trial.a))
            self.snapshots[j] = (trial.t, *motion, float(self.imposed[j]), float(self.answered[j]),
                                 float(daq.commands[j]), float(daq.u[j]), float(daq.R[j]))
        self.committed_flags[j] = True
        self.moved_this_step[j] = False
        if not all(self.committed_flags[k] for k in self.active):
            return
        rows = [self.snapshots[k] for k in range(self.n)]
        self.snapshots = [None] * self.n
        self.committed_flags[:] = False
        if all(r is None for r in rows):
            return
        samples = site.take_samples()
        site.commit()
        self.steps += 1
        t0 = time.perf_counter()
        blank = (0.0,) * 9
        t, u, v, a, target, answered, command, disp, force = (np.array(c) for c in zip(*(r or blank for r in rows)))
        self.recorder.write_step(self.steps, float(next(r[0] for r in rows if r is not None)), u, v, a, target,
                                 answered, [ControlMode.DISPLACEMENT.value] * self.n, target, command, disp, force,
                                 samples)
        self.record_s += time.perf_counter() - t0

    def _stop(self) -> None:
        self.active.clear()
        self._close("server stopped")

    # --- the worker -----------------------------------------------------------------------
    def _call(self, fn, *args):
        try:
            future = self._worker.submit(fn, *args)
        except RuntimeError:  # the worker has stopped: the server is closing
            raise HsioError("the server is stopping") from None
        return future.result()

    def attach(self, j: int) -> None:
        """Element ``j`` joins the session (the first one opens the actuators)."""
        self._call(self._attach, j)

    def detach(self, j: int, reason: str) -> None:
        """Element ``j`` leaves; the last one ends the session: actuators hold, record closed."""
        self._call(self._detach, j, reason)

    def hold(self, reason: str) -> None:
        """Every actuator holds; later force requests of this session fail."""
        self._call(self._hold, reason)

    def set_trial(self, j: int, trial: Trial) -> None:
        """Store element ``j``'s trial (nothing moves until a force is asked for); no worker hop:
        one reference is replaced, and :meth:`_impose` works on a copy of the list."""
        self.latest[j] = trial

    def force(self, j: int) -> float:
        """Element ``j``'s force (kN) at its latest trial, moving the actuators if needed."""
        return self._call(self._force, j)

    def displacement(self, j: int) -> float:
        """The measured displacement (mm) of element ``j`` after its last trial."""
        return self._call(self._displacement, j)

    def tangent(self, j: int) -> float:
        """kN/mm: K^EI, or the secant of the last trial where it is finite and positive."""
        if self.settings.stiffness == "initial":
            return float(self.K_EI[j])
        return self._call(self._tangent, j)

    def commit(self, j: int) -> None:
        """Element ``j`` accepts the step; once every connected element has, the step is recorded."""
        self._call(self._commit, j)

    def latest_time(self, j: int) -> float:
        trial = self.latest[j]
        return trial.t if trial is not None else 0.0

    def close(self) -> None:
        """End any session (actuators hold, record closed) and stop the worker."""
        try:
            self._call(self._stop)
        finally:
            self._worker.shutdown(wait=True)
