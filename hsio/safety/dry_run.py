"""The dry run before the hydraulics (docs/safety.md section 2).

The test is predicted with the purely numerical simulation (NS: the specimen models in place of
the actuators) and the command generator (:class:`hsio.command.PredictorCorrector` over the NS
targets at the configured test rate and controller period). Per actuator the peak displacement,
force and command velocity are compared with the actuator's limits less a margin (a fraction of
the limit): beyond it, the test is refused before any hardware opens, naming the actuator, the
quantity, the prediction, the limit and the step (and record time) of the peak. A limit that is not
known before the hardware opens (a driver that reads it from the controller) is named as not
checked; the check from the present state, once the hardware is open, takes each actuator's own.

The actuator's lag and the compensation's lead (docs/safety.md section 2, docs/method.md eqs. 1
and 2): a compensated actuator is sent d^a = d^c + L (|v| - a) sign(v) (the lead form of eq. 2,
L = b d_max, v the backward-quadratic step velocity), so its peaks are those of d^a over the NS
targets. An actuator's lag L not compensated delays its restoring force, and the hybrid response
grows beyond NS; its peak displacement is checked with the allowance L |v|_max (an allowance,
not a bound), and its peak command velocity grown in the same proportion, (1 + L |v|_max / d_max)
(the commands follow the grown response; left out, a test let through near the velocity limit is
stopped there in the middle of its record).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from hsio.clock import CONTROLLER_RATE_HZ
from hsio.command import PredictorCorrector
from hsio.compensation.hockey_stick import step_velocity
from hsio.safety.settings import SafetySettings
from hsio.safety.status import DryRunRefused

DRIVER_LAG = "a driver's actuators: not known"
HELD, RAMPS = -1, -2  # the "step" of a static preload's peak: held throughout, in its ramps in and off
QUANTITIES = (("displacement", "stroke_mm", "mm", "stroke_margin"), ("force", "force_kN", "kN", "force_margin"),
              ("velocity", "velocity_mm_s", "mm/s", "velocity_margin"))


@dataclass(frozen=True)
class ActuatorLag:
    """Per actuator: the lag L (s) not compensated, the compensation's lead L (s) and threshold a
    (mm/s) of eq. 2 (0: not compensated), and where the lag comes from."""

    lag_s: np.ndarray
    lead_s: np.ndarray
    a_mm_s: np.ndarray
    source: str = ""

    @classmethod
    def none(cls, n: int, source: str = "") -> "ActuatorLag":
        return cls(np.zeros(n), np.zeros(n), np.zeros(n), source)

    def first(self, n: int) -> "ActuatorLag":
        """That of the first ``n`` actuators."""
        return ActuatorLag(self.lag_s[:n], self.lead_s[:n], self.a_mm_s[:n], self.source)

    def more(self, n: int) -> "ActuatorLag":
        """With ``n`` actuators more, neither lagging nor compensated (preloads in force control)."""
        zeros = np.zeros(n)
        return ActuatorLag(np.concatenate([self.lag_s, zeros]), np.concatenate([self.lead_s, zeros]),
                           np.concatenate([self.a_mm_s, zeros]), self.source)


def compensated(targets: np.ndarray, t_d: float, lead_s: float, a_mm_s: float) -> np.ndarray:
    """The commands the lead form of eq. 2 sends for the per-step ``targets`` d^c:
    d^a_i = d^c_i + L (|v_i| - a) sign(v_i) beyond the threshold, v_i the backward quadratic."""
    targets = np.asarray(targets, dtype=float)
    if lead_s <= 0 or targets.size == 0:
        return targets
    v = step_velocity(targets, t_d, order=2)
    return targets + lead_s * np.clip(np.abs(v) - a_mm_s, 0.0, None) * np.sign(v)


@dataclass(frozen=True)
class Prediction:
    """Per actuator: peak |displacement| (mm), |force| (kN) and |command velocity| (mm/s); where
    known, the step of each peak (``at``: {quantity: steps}, HELD for a preload held throughout,
    RAMPS for the velocity of its ramps),
    the record's dt, the peak |step velocity| (mm/s, backward quadratic over t_d) and the
    actuators' :class:`ActuatorLag` (the peaks are of the commands compensated with its lead)."""

    actuators: tuple[str, ...]
    displacement: np.ndarray
    force: np.ndarray
    velocity: np.ndarray
    steps: int
    static: int = 0  # the last ``static`` actuators hold preloads in force control (docs/setups.md)
    at: dict | None = None
    dt: float = 0.0
    step_velocity: np.ndarray | None = None
    lag: "ActuatorLag | None" = None
    notes: dict | None = None  # {(quantity, actuator index): what the peak comes from}, told beside it

    def lag_allowance(self) -> np.ndarray:
        """L |v|_max per actuator (mm), L the lag not compensated: what it may add to the peak; at
        most the peak itself (a lag as long as the motion's period leaves the actuator behind its
        commands, which the tracking interlock stops, rather than doubling them)."""
        if self.lag is None or self.step_velocity is None:
            return np.zeros(len(self.actuators))
        allowance = self.lag.lag_s * np.asarray(self.step_velocity, dtype=float)
        return np.minimum(allowance, np.abs(np.asarray(self.displacement, dtype=float)))

    def lag_growth(self) -> np.ndarray:
        """1 + L |v|_max / d_max per actuator: the proportion in which the lag allowance grows the
        peak displacement, and so the commands' peak velocity (1 where there is no allowance)."""
        allowance = self.lag_allowance()
        peak = np.abs(np.asarray(self.displacement, dtype=float))
        return 1.0 + np.divide(allowance, peak, out=np.zeros_like(allowance, dtype=float), where=peak > 0)

    def when(self, what: str, k: int) -> str:
        """Where actuator ``k``'s peak of ``what`` is: " at step N (t = T s)", "" if not known."""
        steps = (self.at or {}).get(what)
        if steps is None:
            return ""
        step = int(steps[k])
        if step == RAMPS:
            return " (in the ramps of the static preloads)"
        if step < 0:
            return " (held throughout)"
        return f" at step {step} (t = {step * self.dt:.3f} s)" if self.dt > 0 else f" at step {step}"


@dataclass
class DryRunReport:
    """What was checked, what exceeded its allowance, what could not be checked."""

    prediction: Prediction
    limits: dict
    source: str
    lines: list[str] = field(default_factory=list)
    exceeded: list[str] = field(default_factory=list)
    unchecked: list[str] = field(default_factory=list)
    override: bool = False
    per_actuator: list[dict] | None = None  # each actuator's own limits, in the prediction's order

    @property
    def refused(self) -> bool:
        return bool(self.exceeded) and not self.override

    def text(self) -> str:
        head = ("dry run: REFUSED, nothing moved" if self.refused else
                "dry run: exceeded, OVERRIDDEN by the operator" if self.exceeded else "dry run: within the limits")
        out = [f"{head} (NS over {self.prediction.steps} steps; limits from {self.source})", *self.lines]
        if self.unchecked:
            out.append("not checked: " + "; ".join(self.unchecked))
        if self.refused:
            out.append("to run anyway: --override-dry-run or [safety] override = true (recorded in the run and the ledger)")
        return "\n".join(out)

    def as_dict(self) -> dict:
        p = self.prediction
        out = {"refused": self.refused, "override": self.override, "exceeded": self.exceeded,
               "unchecked": self.unchecked, "limits": self.limits, "limits_source": self.source,
               "peak_displacement_mm": p.displacement.tolist(), "peak_force_kN": p.force.tolist(),
               "peak_command_velocity_mm_s": p.velocity.tolist(), "lag_allowance_mm": p.lag_allowance().tolist(),
               "lag_velocity_factor": p.lag_growth().tolist()}
        if p.lag is not None:
            out["lag"] = {"lag_s": p.lag.lag_s.tolist(), "lead_s": p.lag.lead_s.tolist(), "source": p.lag.source}
        if self.per_actuator is not None:
            out["limits_per_actuator"] = dict(zip(p.actuators, self.per_actuator))
        if p.at is not None:
            out["peak_steps"] = {what: [int(k) for k in steps] for what, steps in p.at.items()}
        return out


def peak_command_velocity(targets: np.ndarray, t_d: float, period: float, hold_fraction: float,
                          initial: float = 0.0) -> float:
    """The largest |command velocity| (mm/s) of the predictor-corrector over ``targets``, one per
    step, each landed before the next (as in lockstep; docs/method.md section 1)."""
    return peak_command_velocity_at(targets, t_d, period, hold_fraction, initial)[0]


def peak_command_velocity_at(targets: np.ndarray, t_d: float, period: float, hold_fraction: float,
                             initial: float = 0.0) -> tuple[float, int]:
    """The largest |command velocity| (mm/s) of the predictor-corrector over ``targets`` and the
    index of the target it moves to then (-1 with no targets).

    Each step is the generator's cubic Hermite segment: from the last target with the last
    end velocity to the new target with the slope of the quadratic through the last three
    targets, over one t_d; with ramp-hold, from rest to rest over (1 - h) t_d. Evaluated at every
    controller period of every step at once.
    """
    targets = np.asarray(targets, dtype=float)
    if targets.size == 0:
        return 0.0, -1
    g = PredictorCorrector(t_d, period, initial, hold_fraction=hold_fraction)
    d = np.concatenate([[initial, initial], targets])  # d_{i-2}, d_{i-1} before the first target
    c1 = d[2:]
    c0 = d[1:-1]
    if g.dwell_samples:
        n = max(g.samples_per_step - g.dwell_samples, 1)
        v0 = v1 = np.zeros_like(c1)
    else:
        n = g.samples_per_step
        v1 = 0.5 * (3.0 * d[2:] - 4.0 * d[1:-1] + d[:-2]) / t_d
        v0 = np.concatenate([[0.0], v1[:-1]])
    T = n * period
    s = np.arange(0, n + 1) / n  # sample k of the segment at s = k / n
    s2, s3 = s * s, s * s * s
    h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
    peak, at = 0.0, 0
    for lo in range(0, len(c1), 2048):  # blocks: bounded memory on long records
        sl = slice(lo, lo + 2048)
        pos = (np.outer(c0[sl], h00) + np.outer(T * v0[sl], h10) + np.outer(c1[sl], h01) + np.outer(T * v1[sl], h11))
        rows = np.max(np.abs(np.diff(pos, axis=1)), axis=1)
        k = int(np.argmax(rows))
        if rows[k] > peak:
            peak, at = float(rows[k]), lo + k
    return peak / period, at


def predict(ns, t_d: float, hold_fraction: float, period: float = 1.0 / CONTROLLER_RATE_HZ,
            setups=None, lag: ActuatorLag | None = None) -> Prediction:
    """Peaks of the NS result ``ns`` (a :class:`hsio.result.Result`) per actuator, each with its
    step; with ``lag`` (:func:`actuator_lag`), of the commands its lead compensates.

    With ``setups`` (a :class:`hsio.sites.setup_map.SetupMap`: elements loaded through
    experimental setups, docs/setups.md), the NS channels are turned into actuator strokes and
    forces by the setups' exact geometry first, so that strokes are checked against the stroke
    and forces against the capacity, never a rotation or a moment."""
    if setups is not None:
        d = np.asarray(ns.measured_displacement, dtype=float)
        q = np.asarray(ns.measured_force, dtype=float)
        targets = np.array([setups.strokes(row) for row in np.asarray(ns.targets, dtype=float)])
        displacement = targets
        force = np.array([setups.forces_for(qr, dr) for qr, dr in zip(q, d)])
        names = tuple(setups.actuator_names)
    else:
        targets = np.asarray(ns.targets, dtype=float)
        displacement = np.vstack([targets, ns.measured_displacement])
        force = np.asarray(ns.measured_force, dtype=float)
        names = tuple(ns.element_names)
    return _peaks(names, targets, displacement, force, ns.steps, float(ns.dt), t_d, hold_fraction, period, lag)


def _peaks(names, targets, displacement, force, steps: int, dt: float, t_d: float, hold_fraction: float,
           period: float, lag: ActuatorLag | None) -> Prediction:
    """The peaks of per-step ``targets`` (steps x actuators; the command), ``displacement`` (rows:
    steps, or the targets then the measurements) and ``force``, each with its step; the commands
    and their displacement rows compensated with ``lag``'s lead."""
    n = len(names)
    lag = lag if lag is not None else ActuatorLag.none(n)
    if len(targets) == 0:
        zero = np.zeros(n)
        return Prediction(names, zero, zero, zero, steps, dt=dt, step_velocity=zero, lag=lag)
    rows = len(targets)
    if np.any(lag.lead_s > 0):
        sent = np.column_stack([compensated(targets[:, j], t_d, lag.lead_s[j], lag.a_mm_s[j]) for j in range(n)])
        displacement = np.vstack([sent, displacement[rows:]]) if len(displacement) > rows else sent
        targets = sent
    d_abs, f_abs = np.abs(displacement), np.abs(force)
    velocity = [peak_command_velocity_at(targets[1:, j], t_d, period, hold_fraction, targets[0, j]) for j in range(n)]
    at = {"displacement": np.argmax(d_abs, axis=0) % rows, "force": np.argmax(f_abs, axis=0),
          "velocity": np.array([k + 1 for _, k in velocity])}
    v_step = np.array([float(np.max(np.abs(step_velocity(targets[:, j], t_d, order=2)))) for j in range(n)])
    return Prediction(names, np.max(d_abs, axis=0), np.max(f_abs, axis=0), np.array([v for v, _ in velocity]), steps,
                      at=at, dt=dt, step_velocity=v_step, lag=lag)


def from_present(prediction: Prediction, state: dict) -> Prediction:
    """The prediction of a run that starts where the specimen stands (``[test] start = "present"``,
    docs/safety.md section 2): the NS from rest plus, per actuator, the measured displacement and
    force it starts from (superposition: exact for a linear specimen, an estimate otherwise).
    ``state`` is the run's start state {actuator: {displacement_mm, force_kN}}. An actuator the
    state does not name is shifted by the largest offset of those it names. A static actuator is
    not: it ramps from where it stands to its preload, which the prediction holds already."""
    offsets = {name: (abs(float(v["displacement_mm"])), abs(float(v["force_kN"])))
               for name, v in state.items() if isinstance(v, dict)}
    worst = (max((o[0] for o in offsets.values()), default=0.0), max((o[1] for o in offsets.values()), default=0.0))
    dynamic = len(prediction.actuators) - prediction.static
    shift = np.array([offsets.get(name, worst) if k < dynamic else (0.0, 0.0)
                      for k, name in enumerate(prediction.actuators)]).reshape(-1, 2)
    return replace(prediction, displacement=prediction.displacement + shift[:, 0],
                   force=prediction.force + shift[:, 1])


def known_limits(url: str, emulator: dict, driver: dict) -> tuple[dict, str]:
    """The limits known before the hardware opens: {stroke_mm, force_kN, velocity_mm_s} (None:
    unknown) and where they come from. A driver's are those it will use: [driver], the URL's query
    where it sets one (the query wins), the driver's default (velocity_mm_s); stroke and force
    capacity not set there are the controller's, known only once the hardware opens."""
    if url.startswith("emulator"):
        from hsio.emulators.local import _settings
        from hsio.emulators.servo import ServoConfig

        cfg = ServoConfig.from_dict(_settings(url, emulator))
        return ({"stroke_mm": cfg.stroke_mm, "force_kN": cfg.force_limit_kN, "velocity_mm_s": cfg.velocity_limit_mm_s},
                "[emulator]")
    from hsio.drivers.common import COMMON_RULES
    from hsio.hardware import driver_options

    table = driver_options(url, driver)  # as the driver reads them: its defaults, [driver], the URL's query
    if table is None:  # a backend that does not say: [driver] as given
        table = {k: (COMMON_RULES[k].check(url, k, driver[k]) if driver.get(k) is not None else None)
                 for k in ("stroke_mm", "force_kN", "velocity_mm_s")}
    return {k: (float(table[k]) if table.get(k) is not None else None)
            for k in ("stroke_mm", "force_kN", "velocity_mm_s")}, "[driver]"


def actuator_limits(prediction: Prediction, limits: dict, actuators) -> list[dict]:
    """Each actuator's own limits, in the order of ``prediction``: those ``limits`` gives (the
    configuration's, known before the hardware opened) and, where it gives none, the one that
    actuator's controller reported (``actuator.limits``, :class:`hsio.interfaces.Limits`). An
    actuator is found by its name, else by its place (an element's actuator may be named apart
    from the element; the actuators open in the order of the elements, then the preloads)."""
    actuators = list(actuators)
    by_name = {a.name: a for a in actuators}
    out = []
    for k, name in enumerate(prediction.actuators):
        actuator = by_name.get(name, actuators[k] if k < len(actuators) else None)
        reported = getattr(actuator, "limits", None)
        out.append({key: (float(value) if value is not None else
                          float(getattr(reported, key)) if reported is not None else None)
                    for key, value in limits.items()})
    return out


def check(prediction: Prediction, limits: dict, source: str, settings: SafetySettings,
          per_actuator: list[dict] | None = None) -> DryRunReport:
    """Compare the prediction with the limits less the margins: ``limits`` for every actuator, or
    ``per_actuator`` (one table of limits per actuator of ``prediction``, in its order: each its
    own). The displacement is checked with the lag allowance (:meth:`Prediction.lag_allowance`), the
    command velocity grown in the same proportion (:meth:`Prediction.lag_growth`)."""
    report = DryRunReport(prediction, dict(limits), source, override=settings.override, per_actuator=per_actuator)
    tables = per_actuator if per_actuator is not None else [limits] * len(prediction.actuators)
    width = max((len(name) for name in prediction.actuators), default=0)
    allowance = prediction.lag_allowance()
    growth = prediction.lag_growth()
    for what, key, unit, margin_key in QUANTITIES:
        margin = getattr(settings, margin_key)
        unknown = [name for name, table in zip(prediction.actuators, tables) if table.get(key) is None]
        if unknown:
            whose = "" if len(unknown) == len(prediction.actuators) else f" of {', '.join(unknown)}"
            report.unchecked.append(f"{what}{whose} (no {source} {key}: the controller reports it only when the "
                                    f"hardware opens; the commands are still checked against it then)")
        for k, (name, table) in enumerate(zip(prediction.actuators, tables)):
            limit = table.get(key)
            if limit is None:
                continue
            full = limit / 2.0 if key == "stroke_mm" else limit
            allowed = (1.0 - margin) * full
            value = float(getattr(prediction, what)[k])
            lag = ""
            if what == "displacement" and allowance[k] > 0:
                capped = allowance[k] < prediction.lag.lag_s[k] * prediction.step_velocity[k]
                lag = (f"; NS peak {value:.3f} mm + lag allowance {prediction.lag.lag_s[k]:g} s x "
                       f"{prediction.step_velocity[k]:.3f} mm/s" + (" (at most the peak)" if capped else ""))
                value += float(allowance[k])
            if what == "velocity" and growth[k] > 1.0:
                lag = (f"; {value:.3f} mm/s over the NS targets x {growth[k]:.3f}, grown as the displacement "
                       f"by the lag allowance")
                value *= float(growth[k])
            if what != "force" and prediction.lag is not None and prediction.lag.lead_s[k] > 0:
                lag += f"; commands compensated with lead {prediction.lag.lead_s[k]:g} s"
            lag += (prediction.notes or {}).get((what, k), "")
            ok = value <= allowed
            verdict = "ok" if ok else "EXCEEDS"
            when = prediction.when(what, k)
            report.lines.append(f"  {name:<{width}} {what:<12} predicted {value:9.3f} {unit:<4} limit +/-{full:g} {unit}, "
                                f"margin {margin:.0%}: allowed {allowed:.3f} {unit}  {verdict}{when}{lag}")
            if not ok:
                report.exceeded.append(f"{name} {what} {value:.3f} {unit} > {allowed:.3f} {unit} (limit +/-{full:g} "
                                       f"{unit}){when}")
    if prediction.lag is not None and prediction.lag.source.startswith(DRIVER_LAG):
        report.lines.append("  lag: a driver does not report its actuators' lag; the margins are what is left for it")
    return report


def with_static(prediction: Prediction, static, t_d: float, hold_fraction: float,
                period: float = 1.0 / CONTROLLER_RATE_HZ) -> Prediction:
    """``prediction`` and the static actuators (:class:`hsio.structures.StaticLoad`, docs/setups.md)
    holding their preloads: the force is the preload and the displacement the preload over the
    stiffness K^EI of what it loads (:attr:`hsio.structures.StaticLoad.K_EI`), held throughout;
    the velocity that of the ramps in and off (:func:`hsio.safety.preload_ramp.ramp_velocity`:
    the command generator's force rate over the loop steps of the longest ``ramp_s``, over K^EI)."""
    if not static:
        return prediction
    from hsio.safety.preload_ramp import ramp_velocity

    force = np.array([abs(load.force_kN) for load in static])
    stiffness = np.array([load.K_EI for load in static])
    disp = force / np.abs(stiffness)
    _, ramp = ramp_velocity(np.zeros(len(static)), force, stiffness, max(load.ramp_s for load in static), t_d,
                            period, hold_fraction)
    zeros = np.zeros(len(static))
    ramp_s = max(load.ramp_s for load in static)
    n = len(prediction.actuators)
    notes = dict(prediction.notes or {})
    notes.update({("velocity", n + j): f"; static preload {load.name!r}: {force[j]:g} kN over {stiffness[j]:g} kN/mm, "
                                       f"ramped in and off over {ramp_s:g} s in loop steps of {t_d:g} s"
                  for j, load in enumerate(static)})
    at = None if prediction.at is None else {
        what: np.concatenate([steps, np.full(len(static), RAMPS if what == "velocity" else HELD)])
        for what, steps in prediction.at.items()}

    def more(values):
        return None if values is None else np.concatenate([np.asarray(values, dtype=float), zeros])

    return replace(prediction, actuators=prediction.actuators + tuple(load.actuator for load in static),
                   displacement=np.concatenate([prediction.displacement, disp]),
                   force=np.concatenate([prediction.force, force]),
                   velocity=np.concatenate([prediction.velocity, ramp]), static=prediction.static + len(static),
                   at=at, step_velocity=more(prediction.step_velocity), notes=notes,
                   lag=None if prediction.lag is None else prediction.lag.more(len(static)))


def actuator_lag(url: str, emulator: dict, compensation=None, names=(), steps: int = 0) -> ActuatorLag:
    """Per actuator of ``names`` (the compensation stage's, in the order of the prediction): the
    emulated actuator's lag (``emulator://``: the larger of ``lag_s`` and ``lag_retract_s``, plus
    ``transport_delay_s``; a driver's is not known: 0) and the lead of ``compensation`` (a
    :class:`hsio.compensation.stage.CompensationSettings`) on the actuators it compensates:
    offline b d_max and a, each actuator's own (``by_actuator``) or the shared ones; online the
    most the lead can reach over ``steps`` steps (each actuator's start moved by ``lag_step_s``
    every ``update_every`` steps, at most ``lag_max_s``) and a = 0. The lag left is the
    actuator's less the lead, not below 0."""
    n = len(names)
    lag, source = np.zeros(n), DRIVER_LAG
    if url.startswith("emulator"):
        from hsio.emulators.local import _settings
        from hsio.emulators.servo import ServoConfig

        cfg = ServoConfig.from_dict(_settings(url, emulator))
        lag[:] = max(cfg.lag_s, cfg.lag_retract_s or cfg.lag_s) + cfg.transport_delay_s
        source = "[emulator] lag_s"
    lead, a = np.zeros(n), np.zeros(n)
    if compensation is not None and compensation.mode != "off":
        chosen = set(compensation.actuators) if compensation.actuators else set(names)
        for k, name in enumerate(names):
            if name not in chosen:
                continue
            threshold, b = compensation.parameters(name)
            value = b * compensation.d_max_mm
            if compensation.mode == "online":
                e = compensation.estimator
                value = min(e.lag_max_s, value + e.lag_step_s * -(-max(int(steps), 0) // e.update_every))
                threshold = 0.0
            lead[k], a[k] = value, threshold
        shown = ", ".join(f"{v:g}" for v in sorted(set(lead[[n in chosen for n in names]].tolist()))) or "0"
        source += f"; [compensation] {compensation.mode} lead {shown} s"
    return ActuatorLag(np.clip(lag - lead, 0.0, None), lead, a, source)


def dry_run(ns, t_d: float, hold_fraction: float, url: str, emulator: dict, driver: dict,
            settings: SafetySettings, setups=None, static=(), lag: ActuatorLag | None = None) -> DryRunReport:
    """Predict and check (the static preloads too); the report says whether the test is refused.
    ``lag``: the actuators' (:func:`actuator_lag`)."""
    limits, source = known_limits(url, emulator, driver)
    prediction = predict(ns, t_d, hold_fraction, setups=setups, lag=lag)
    report = check(with_static(prediction, static, t_d, hold_fraction), limits, source, settings)
    # a pose a setup cannot drive to (near or past a singular one) is refused by the site at that
    # trial; the stroke limits need not see it (its strokes may be small): refuse it here first
    pose = setups.first_pose_problem(ns.targets) if setups is not None else None
    if pose is not None:
        step, problem = pose
        when = f" at step {step} (t = {step * float(ns.dt):.3f} s)"
        report.lines.append(f"  pose: {problem}  EXCEEDS{when}")
        report.exceeded.append(f"pose: {problem}{when}")
    return report


def enforce(report: DryRunReport) -> None:
    """Raise :class:`DryRunRefused` if the report refuses the test."""
    if report.refused:
        raise DryRunRefused(report.text())
