"""The compensation stage between the integrator's commands and the actuators (docs/method.md section 4).

Per step, for each actuator: the integrator's command d^c goes in, the adjusted command d^a
(eq. 2, :mod:`~hsio.compensation.feedforward`) goes to the control loop, and after the step the
measurement d^m comes back. The stage records, normalised by the stroke d_max,

* without compensation: Er^cc = (d^c - d^m) / d_max;
* with compensation: Er^ca = (d^c - d^m) / d_max (what is left of the error against the
  integrator's command) and Er^aa = (d^a - d^m) / d_max (the actuator's own error on what it was
  sent, which still follows the hockey stick and feeds the online estimator).

Modes: ``off`` (record Er^cc only), ``offline`` (fixed a and b from a calibration), ``online``
(a and b re-estimated during the test, :mod:`~hsio.compensation.online`). Each actuator can be
left out of the compensation. a and b (offline: the values used; online: the starting guess) are
shared by the actuators unless ``by_actuator`` gives an actuator its own (each actuator has its
own hockey stick, as ``hsio calibrate`` fits one per actuator).

With mixed control (docs/method.md section 5) only the actuators in displacement control are
compensated: eq. 2 describes a displacement loop, and an actuator in force control is sent a
force. A step in force control breaks the actuator's history of displacement commands, so after
it the velocity of eq. 2 starts again from the first displacement command, and the online
estimator takes no sample of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Callable

import numpy as np

from hsio.compensation.feedforward import FORMS, FeedForward
from hsio.compensation.hockey_stick import D_MAX_MM, last_velocity
from hsio.compensation.online import EstimatorSettings, OnlineEstimator
from hsio.errors import ConfigError
from hsio.ground_motion import MAX_STEPS

MODES = ("off", "offline", "online")
PARAMETERS = ("a_mm_s", "b_s_mm")  # what by_actuator may give an actuator


@dataclass
class CompensationSettings:
    """The [compensation] table of a run configuration."""

    mode: str = "off"
    a_mm_s: float = 0.0  # threshold a of eq. 1 (offline; the starting guess online)
    b_s_mm: float = 0.0  # slope b of eq. 1 (offline; the starting guess online, 0 = from nothing)
    by_actuator: dict = field(default_factory=dict)  # actuator -> {a_mm_s, b_s_mm}: its own (default: the above)
    actuators: list = field(default_factory=list)  # names of the compensated actuators; empty = all
    form: str = "lead"
    d_max_mm: float = D_MAX_MM
    estimator: EstimatorSettings = field(default_factory=EstimatorSettings)

    @classmethod
    def from_table(cls, table: dict, where: str = "[compensation]") -> "CompensationSettings":
        table = dict(table)
        est_keys = {f.name for f in fields(EstimatorSettings)}
        est = {k: table.pop(k) for k in list(table) if k in est_keys}
        known = {f.name for f in fields(cls)} - {"estimator"}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(known | est_keys))}")
        s = cls(**table, estimator=EstimatorSettings(**est))
        s.check(where)
        return s

    def check(self, where: str = "[compensation]") -> None:
        if self.mode not in MODES:
            raise ConfigError(f"{where}: mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.form not in FORMS:
            raise ConfigError(f"{where}: form must be one of {', '.join(FORMS)}, got {self.form!r}")
        for name in PARAMETERS:
            _parameter(where, name, getattr(self, name))
        if not isinstance(self.by_actuator, dict):
            raise ConfigError(f"{where}: by_actuator must be a table of actuator = {{a_mm_s, b_s_mm}}, "
                              f"got {self.by_actuator!r}")
        for actuator, own in self.by_actuator.items():
            if not isinstance(own, dict) or not own:
                raise ConfigError(f"{where}: by_actuator.{actuator} must be a table with a_mm_s and/or b_s_mm, "
                                  f"got {own!r}")
            unknown = sorted(set(own) - set(PARAMETERS))
            if unknown:
                raise ConfigError(f"{where}: by_actuator.{actuator}: unknown key {unknown[0]!r}; known: "
                                  f"{', '.join(PARAMETERS)}")
            for name, value in own.items():
                _parameter(where, f"by_actuator.{actuator}.{name}", value)
        if not (isinstance(self.d_max_mm, (int, float)) and self.d_max_mm > 0):
            raise ConfigError(f"{where}: d_max_mm must be positive, got {self.d_max_mm!r}")
        if self.mode == "offline" and not self.b_s_mm > 0 and not self.by_actuator:
            raise ConfigError(f"{where}: mode = 'offline' needs the calibrated b_s_mm (and a_mm_s); "
                              "run `hsio calibrate` on an uncompensated continuous run")
        if not isinstance(self.actuators, list) or not all(isinstance(n, str) for n in self.actuators):
            raise ConfigError(f"{where}: actuators must be a list of actuator names, got {self.actuators!r}")
        e = self.estimator
        for name in ("window", "update_every", "min_samples", "min_beyond"):
            value = getattr(e, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"{where}: {name} must be a whole number of steps, at least 1, got {value!r}")
        for name in ("min_samples", "min_beyond"):  # beyond the window no fit could ever be accepted
            if getattr(e, name) > e.window:
                raise ConfigError(f"{where}: {name} ({getattr(e, name)}) must not exceed window ({e.window})")
        for name in ("max_rel_std", "lag_max_s", "a_max_mm_s", "lag_step_s", "a_step_mm_s"):
            value = getattr(e, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{where}: {name} must be a positive number, got {value!r}")
        # Sanity bounds (docs/faults.md): the same as a run's steps, an actuator's stroke and
        # velocity ([driver] stroke_mm, velocity_mm_s) and a lag of seconds, not of hours.
        bounds = {"window": (MAX_STEPS, ""), "update_every": (MAX_STEPS, ""), "min_samples": (MAX_STEPS, ""),
                  "min_beyond": (MAX_STEPS, ""), "d_max_mm": (10000.0, " mm"), "a_mm_s": (10000.0, " mm/s"),
                  "a_max_mm_s": (10000.0, " mm/s"), "lag_s": (10.0, " s"), "lag_max_s": (10.0, " s")}
        for name, (high, unit) in bounds.items():
            value = getattr(e, name, None) if hasattr(e, name) else getattr(self, name)
            if value > high:
                what = "b_s_mm x d_max_mm (the lag)" if name == "lag_s" else name
                raise ConfigError(f"{where}: {what} = {value!r} is out of bounds: at most {high:g}{unit}")
        for actuator in self.by_actuator:  # an actuator's own values: the same bounds
            a, b = self.parameters(actuator)
            of = f"by_actuator.{actuator}."
            if a > bounds["a_mm_s"][0]:
                raise ConfigError(f"{where}: {of}a_mm_s = {a!r} is out of bounds: at most {bounds['a_mm_s'][0]:g} mm/s")
            if b * self.d_max_mm > bounds["lag_s"][0]:
                raise ConfigError(f"{where}: {of}b_s_mm x d_max_mm (the lag) = {b * self.d_max_mm!r} is out of "
                                  f"bounds: at most {bounds['lag_s'][0]:g} s")
        # Online, the estimates stay within 0..a_max_mm_s and 0..lag_max_s: a starting guess beyond
        # them is refused, not clamped.
        if self.mode == "online":
            for actuator in (None, *self.by_actuator):
                a, b = self.parameters(actuator)
                of = "" if actuator is None else f"by_actuator.{actuator}."
                if a > e.a_max_mm_s:
                    raise ConfigError(f"{where}: the starting {of}a_mm_s = {a:g} is beyond a_max_mm_s = "
                                      f"{e.a_max_mm_s:g}, the bound on the online estimate; raise a_max_mm_s or lower "
                                      f"{of}a_mm_s")
                if b * self.d_max_mm > e.lag_max_s:
                    raise ConfigError(f"{where}: the starting lag {of}b_s_mm x d_max_mm = {b * self.d_max_mm:g} s is "
                                      f"beyond lag_max_s = {e.lag_max_s:g} s, the bound on the online estimate; raise "
                                      f"lag_max_s or lower {of}b_s_mm")

    def parameters(self, actuator: str | None = None) -> tuple[float, float]:
        """(a_mm_s, b_s_mm) of ``actuator``: its own from ``by_actuator``, else the shared ones."""
        own = self.by_actuator.get(actuator, {}) if actuator is not None else {}
        return float(own.get("a_mm_s", self.a_mm_s)), float(own.get("b_s_mm", self.b_s_mm))

    @property
    def lag_s(self) -> float:
        return self.b_s_mm * self.d_max_mm


def _parameter(where: str, name: str, value) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value >= 0):
        raise ConfigError(f"{where}: {name} must be a number, zero or positive, got {value!r}")


class CompensationStage:
    """Adjusts each step's commands (eq. 2) and records the execution errors, per actuator."""

    def __init__(self, names, t_d: float, settings: CompensationSettings | None = None,
                 sink: Callable[[int, dict], None] | None = None):
        self.names = list(names)
        self.t_d = float(t_d)
        self.settings = s = settings or CompensationSettings()
        s.check()  # settings built in code get the checks of the [compensation] table
        unknown = [n for n in s.actuators if n not in self.names]
        if unknown:
            raise ConfigError(f"[compensation] actuators: unknown actuator(s) {', '.join(unknown)}; "
                              f"known: {', '.join(self.names)}")
        chosen = set(s.actuators) if s.actuators else set(self.names)
        self.enabled = [s.mode != "off" and n in chosen for n in self.names]
        for name in s.by_actuator:
            if name not in self.names:
                raise ConfigError(f"[compensation] by_actuator.{name}: unknown actuator {name!r}; known: "
                                  f"{', '.join(self.names)}")
            if name not in chosen:
                raise ConfigError(f"[compensation] by_actuator.{name}: actuator {name!r} is not compensated "
                                  f"(actuators = {s.actuators}); give it in actuators or remove its values")
        lag_limit = 0.45 * self.t_d if s.form == "eq2" else math.inf
        for name, on in zip(self.names, self.enabled):
            if not on:
                continue
            a, b = s.parameters(name)
            lag, which = b * s.d_max_mm, f"actuator {name!r}: " if len(self.names) > 1 else ""
            if s.mode == "offline" and not b > 0:
                raise ConfigError(f"[compensation] {which}mode = 'offline' needs the calibrated b_s_mm (and a_mm_s), "
                                  f"shared or in by_actuator.{name}; run `hsio calibrate` on an uncompensated "
                                  "continuous run")
            if s.mode == "offline" and s.form == "eq2" and lag >= 0.5 * self.t_d:
                raise ConfigError(f"[compensation] {which}form = 'eq2' is unstable here: b d_max = {lag:.4g} s >= "
                                  f"t_d / 2 = {0.5 * self.t_d:.4g} s (raise the test rate or use form = 'lead')")
            if s.mode == "online" and lag > lag_limit:
                raise ConfigError(f"[compensation] {which}form = 'eq2': the starting lag b d_max = {lag:.4g} s is "
                                  f"beyond 0.45 t_d = {lag_limit:.4g} s, the bound on the online estimate that keeps "
                                  "eq. 2 stable (raise the test rate, lower b_s_mm or use form = 'lead')")
        self.feedforward: list[FeedForward] = []
        self.estimators: list[OnlineEstimator | None] = []
        for name, on in zip(self.names, self.enabled):
            est = None
            a, b = s.parameters(name)
            a, lag = (a, b * s.d_max_mm) if on else (0.0, 0.0)
            if on and s.mode == "online":
                est = OnlineEstimator(s.estimator, a, lag, lag_limit)
                a, lag = est.a, est.lag
            self.feedforward.append(FeedForward(self.t_d, a, lag, s.form))
            self.estimators.append(est)
        self.sink = sink
        self.step = 0  # steps committed
        self._commands = 0  # commands observed (with the implicit methods, several per step)
        self._row: dict | None = None  # the row of the step's last command, recorded at commit()
        self._errors: list[float | None] = [None] * len(self.names)  # its d^c - d^m per actuator (None: FC)
        self._sent: list[list[float]] = [[] for _ in self.names]  # last adjusted commands, per actuator
        self._sq = np.zeros(len(self.names))  # sum of (d^c - d^m)^2 over the steps in displacement control
        self._n = np.zeros(len(self.names), dtype=int)  # and their count

    @property
    def active(self) -> bool:
        return any(self.enabled)

    def adjust(self, d_c, displacement=None) -> np.ndarray:
        """d^a for this step's commands d^c (unchanged for actuators not compensated).

        ``displacement``: per actuator, whether it is in displacement control (None: all are);
        an actuator in force control gets its command unchanged and its history is restarted."""
        d_c = np.asarray(d_c, dtype=float)
        dc = [True] * len(d_c) if displacement is None else [bool(x) for x in displacement]
        out = np.empty(len(d_c))
        for j, (ff, x) in enumerate(zip(self.feedforward, d_c)):
            if dc[j]:
                out[j] = ff.adjust(x)  # lag 0 when not compensated
            else:
                ff.restart()
                self._sent[j] = []
                out[j] = x
        return out

    def _sent_velocity(self, j: int, d_a: float) -> float:
        h = self._sent[j] = [*self._sent[j][-2:], d_a]
        return last_velocity(h, self.t_d, 1 if self.settings.form == "eq2" else 2)

    def observe(self, d_c, d_a, d_m, displacement=None) -> dict:
        """After a command: Er^cc or Er^ca/Er^aa, and the online estimates updated. Returns the row.
        Actuators in force control (``displacement`` False) record no error and add no sample.

        The implicit methods send several commands per step (one per iteration): each one adds its
        sample to the online estimate, and the step's row is that of its last command, recorded
        by :meth:`commit` (one row per step, as the ``steps`` table)."""
        self._commands += 1
        d_max = self.settings.d_max_mm
        row: dict[str, float | None] = {}
        errors: list[float | None] = [None] * len(self.names)
        for j, name in enumerate(self.names):
            c, a, m = float(d_c[j]), float(d_a[j]), float(d_m[j])
            ff = self.feedforward[j]
            if displacement is not None and not displacement[j]:
                row.update({f"dc_{name}": None, f"da_{name}": None, f"v_{name}": None, f"er_cc_{name}": None,
                            f"er_ca_{name}": None, f"er_aa_{name}": None, f"a_{name}": ff.a,
                            f"b_{name}": ff.lag / d_max})
                continue
            v_sent = self._sent_velocity(j, a)
            on = self.enabled[j]
            row[f"dc_{name}"] = c
            row[f"da_{name}"] = a
            row[f"v_{name}"] = ff.velocity
            row[f"er_cc_{name}"] = None if on else (c - m) / d_max
            row[f"er_ca_{name}"] = (c - m) / d_max if on else None
            row[f"er_aa_{name}"] = (a - m) / d_max if on else None
            est = self.estimators[j]
            if est is not None and self._commands > 2 and len(self._sent[j]) > 1 and est.observe(v_sent, a - m):
                ff.set_parameters(est.a, est.lag)
            row[f"a_{name}"] = ff.a
            row[f"b_{name}"] = ff.lag / d_max
            errors[j] = c - m
        self._row, self._errors = row, errors
        return row

    def commit(self) -> None:
        """The step is accepted: its row (its last command's) goes to the record and its errors to
        the RMS of :meth:`summary`. A step without a command records nothing."""
        self.step += 1
        if self._row is None:
            return
        for j, error in enumerate(self._errors):
            if error is not None:
                self._sq[j] += error ** 2
                self._n[j] += 1
        row, self._row = self._row, None
        if self.sink is not None:
            self.sink(self.step, row)

    def summary(self) -> dict:
        """The compensation used: mode, form and, per actuator, the parameters at the end."""
        s = self.settings
        out = {"mode": s.mode, "form": s.form, "d_max_mm": s.d_max_mm, "actuators": {}}
        for j, name in enumerate(self.names):
            ff, est = self.feedforward[j], self.estimators[j]
            entry = {"enabled": self.enabled[j], "a_mm_s": ff.a, "b_s_mm": ff.lag / s.d_max_mm, "lag_s": ff.lag,
                     "rms_error_mm": float(math.sqrt(self._sq[j] / self._n[j])) if self._n[j] else None}
            if est is not None:
                a, b = s.parameters(name)
                entry.update(updates=est.updates, zero_lag_updates=est.zero_updates, rejected=est.rejected,
                             start={"a_mm_s": a, "b_s_mm": b})
            out["actuators"][name] = entry
        return out
