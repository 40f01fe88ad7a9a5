"""The dry run before the hydraulics (docs/safety.md section 2).

The test is predicted with the purely numerical simulation (NS: the specimen models in place of
the actuators) and the command generator (:class:`hsio.command.PredictorCorrector` over the NS
targets at the configured test rate and controller period). Per actuator the peak displacement,
force and command velocity are compared with the actuator's limits less a margin (a fraction of
the limit): beyond it, the test is refused before any hardware opens. A limit that is not known
before the hardware opens (a driver that reads it from the controller) is named as not checked.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hsio.clock import CONTROLLER_RATE_HZ
from hsio.command import PredictorCorrector
from hsio.safety.settings import SafetySettings
from hsio.safety.status import DryRunRefused

QUANTITIES = (("displacement", "stroke_mm", "mm", "stroke_margin"), ("force", "force_kN", "kN", "force_margin"),
              ("velocity", "velocity_mm_s", "mm/s", "velocity_margin"))


@dataclass(frozen=True)
class Prediction:
    """Per actuator: peak |displacement| (mm), |force| (kN) and |command velocity| (mm/s)."""

    actuators: tuple[str, ...]
    displacement: np.ndarray
    force: np.ndarray
    velocity: np.ndarray
    steps: int
    static: int = 0  # the last ``static`` actuators hold preloads in force control (docs/setups.md)


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
        return {"refused": self.refused, "override": self.override, "exceeded": self.exceeded,
                "unchecked": self.unchecked, "limits": self.limits, "limits_source": self.source,
                "peak_displacement_mm": p.displacement.tolist(), "peak_force_kN": p.force.tolist(),
                "peak_command_velocity_mm_s": p.velocity.tolist()}


def peak_command_velocity(targets: np.ndarray, t_d: float, period: float, hold_fraction: float,
                          initial: float = 0.0) -> float:
    """The largest |command velocity| (mm/s) of the predictor-corrector over ``targets``, one per
    step, each landed before the next (as in lockstep; docs/method.md section 1).

    Each step is the generator's cubic Hermite segment: from the last target with the last
    end velocity to the new target with the slope of the quadratic through the last three
    targets, over one t_d; with ramp-hold, from rest to rest over (1 - h) t_d. Evaluated at every
    controller period of every step at once.
    """
    targets = np.asarray(targets, dtype=float)
    if targets.size == 0:
        return 0.0
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
    peak = 0.0
    for lo in range(0, len(c1), 2048):  # blocks: bounded memory on long records
        sl = slice(lo, lo + 2048)
        pos = (np.outer(c0[sl], h00) + np.outer(T * v0[sl], h10) + np.outer(c1[sl], h01) + np.outer(T * v1[sl], h11))
        peak = max(peak, float(np.max(np.abs(np.diff(pos, axis=1)))))
    return peak / period


def predict(ns, t_d: float, hold_fraction: float, period: float = 1.0 / CONTROLLER_RATE_HZ,
            setups=None) -> Prediction:
    """Peaks of the NS result ``ns`` (a :class:`hsio.result.Result`) per actuator.

    With ``setups`` (a :class:`hsio.sites.setup_map.SetupMap`: elements loaded through
    experimental setups, docs/setups.md), the NS channels are turned into actuator strokes and
    forces by the setups' exact geometry first, so that strokes are checked against the stroke
    and forces against the capacity, never a rotation or a moment."""
    if setups is not None:
        return _predict_actuators(ns, t_d, hold_fraction, period, setups)
    targets = np.asarray(ns.targets, dtype=float)
    disp = np.max(np.abs(np.vstack([targets, ns.measured_displacement])), axis=0) if len(targets) else np.zeros(0)
    force = np.max(np.abs(ns.measured_force), axis=0) if len(targets) else np.zeros(0)
    velocity = np.array([peak_command_velocity(targets[1:, j], t_d, period, hold_fraction, targets[0, j])
                         for j in range(targets.shape[1])])
    return Prediction(tuple(ns.element_names), disp, force, velocity, ns.steps)


def _predict_actuators(ns, t_d: float, hold_fraction: float, period: float, setups) -> Prediction:
    d = np.asarray(ns.measured_displacement, dtype=float)
    q = np.asarray(ns.measured_force, dtype=float)
    strokes = np.array([setups.strokes(row) for row in np.asarray(ns.targets, dtype=float)])
    forces = np.array([setups.forces_for(qr, dr) for qr, dr in zip(q, d)])
    disp = np.max(np.abs(strokes), axis=0)
    force = np.max(np.abs(forces), axis=0)
    velocity = np.array([peak_command_velocity(strokes[1:, j], t_d, period, hold_fraction, strokes[0, j])
                         for j in range(strokes.shape[1])])
    return Prediction(tuple(setups.actuator_names), disp, force, velocity, ns.steps)


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
    return Prediction(prediction.actuators, prediction.displacement + shift[:, 0], prediction.force + shift[:, 1],
                      prediction.velocity, prediction.steps, prediction.static)


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


def check(prediction: Prediction, limits: dict, source: str, settings: SafetySettings) -> DryRunReport:
    """Compare the prediction with the limits less the margins."""
    report = DryRunReport(prediction, dict(limits), source, override=settings.override)
    for what, key, unit, margin_key in QUANTITIES:
        limit = limits.get(key)
        if limit is None:
            report.unchecked.append(f"{what} (no {source} {key}: the controller reports it only when the hardware "
                                    f"opens; the commands are still checked against it then)")
            continue
        full = limit / 2.0 if key == "stroke_mm" else limit
        margin = getattr(settings, margin_key)
        allowed = (1.0 - margin) * full
        width = max((len(name) for name in prediction.actuators), default=0)
        for name, value in zip(prediction.actuators, getattr(prediction, what)):
            ok = value <= allowed
            verdict = "ok" if ok else "EXCEEDS"
            report.lines.append(f"  {name:<{width}} {what:<12} predicted {value:9.3f} {unit:<4} limit +/-{full:g} {unit}, "
                                f"margin {margin:.0%}: allowed {allowed:.3f} {unit}  {verdict}")
            if not ok:
                report.exceeded.append(f"{name} {what} {value:.3f} {unit} > {allowed:.3f} {unit}")
    return report


def with_static(prediction: Prediction, static) -> Prediction:
    """``prediction`` and the static actuators (:class:`hsio.structures.StaticLoad`, docs/setups.md)
    holding their preloads: the force is the preload, the displacement the preload over the
    initial stiffness of what it loads, the command velocity nil (force control)."""
    if not static:
        return prediction
    force = np.array([abs(load.force_kN) for load in static])
    disp = np.array([abs(load.force_kN) / load.model().initial_stiffness for load in static])
    return Prediction(prediction.actuators + tuple(load.actuator for load in static),
                      np.concatenate([prediction.displacement, disp]), np.concatenate([prediction.force, force]),
                      np.concatenate([prediction.velocity, np.zeros(len(static))]), prediction.steps,
                      prediction.static + len(static))


def dry_run(ns, t_d: float, hold_fraction: float, url: str, emulator: dict, driver: dict,
            settings: SafetySettings, setups=None, static=()) -> DryRunReport:
    """Predict and check (the static preloads too); the report says whether the test is refused."""
    limits, source = known_limits(url, emulator, driver)
    return check(with_static(predict(ns, t_d, hold_fraction, setups=setups), static), limits, source, settings)


def enforce(report: DryRunReport) -> None:
    """Raise :class:`DryRunRefused` if the report refuses the test."""
    if report.refused:
        raise DryRunRefused(report.text())
