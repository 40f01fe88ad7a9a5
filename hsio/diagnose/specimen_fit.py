"""Specimen diagnosis: a linear spring and dashpot fitted to measured displacement and force, and
the effects it misses (docs/diagnose.md, "Specimen diagnosis").

The model is that of :class:`hsio.specimens.diagnosed.Diagnosed`. Given its shape parameters
(theta: yield displacement, gap, exponent, skew, ...), the force is linear in its amplitudes
(k, c, F_c, m, k_gap, f_y and a load-cell offset), so each evaluation solves them by bounded
linear least squares (physical signs: a dashpot, a friction, a mass and a strength are not
negative) and the optimiser moves theta only (variable projection).

The velocity and acceleration are backward differences, as in the specimen model, of the
measured displacement low-passed without phase shift (Butterworth, forward and backward) at a
few times the frequency that holds 99.5 % of its power: the sensor's noise would otherwise
swamp the acceleration. Honest scoring as for the actuator: fit on the first 60 %, choose on
the next 20 %, score on the last 20 % (hsio.diagnose.fitting.blocks).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, signal

from hsio.diagnose import residual as residual_mod
from hsio.diagnose.outcome import NONE, TOO_FEW, UNEXPLAINED, Outcome, grow, parsimonious, ratio, scoring_text, unnamed  # noqa: F401 (re-exported)
from hsio.diagnose.fitting import CHOOSE_FRACTION, TRAIN_FRACTION, blocks, rms
from hsio.diagnose.specimen_effects import EFFECTS, NAMES, Effect  # noqa: F401 (the library, re-exported)
from hsio.diagnose.specimen_record import SpecimenRecord
from hsio.errors import RecordError
from hsio.rths.jit import helper, jit
from hsio.specimens.diagnosed import bouc_wen_step
from hsio.diagnose.threads import one_blas_thread

MARGIN = 1.10
# A cause is named only when the displacement reverses at least this often in the fitting, the
# choosing and the scoring block: a hysteretic, pinched, degrading or gapped specimen shows itself
# at reversals, and a block without one cannot tell a spring from any of them.
MIN_REVERSALS = (2, 1, 1)
# Samples after the rests are cut and long records thinned. Below MIN_SAMPLES no cause is named
# (the choosing and scoring blocks, 20 % each, would hold under 50 samples, as for the actuator);
# below MIN_JUDGED, when no cause is named, neither none nor unexplained is answered but
# too_few_samples: a scoring block of under 100 samples is too few for its RMS error and its
# trend to tell a spring's residual from the sensor floor (docs/diagnose.md).
MIN_SAMPLES = 250
GIVES_OUT = 0.5  # a force whose work over the training part is this share of sum |F du| below zero is refused
# ... or this share, when the force falls as the displacement grows (correlation at most FALLS): only a
# moving mass does that passively, and it takes work too.
GIVES_OUT_FALLING = 0.05
FALLS = -0.5
MIN_JUDGED = 500
REVERSAL_SHARE = 0.05  # a reversal: the displacement turns back by this share of its range (or 3 noise RMS)
RATE_BOUNDS_HZ = (1.0, 1e6)  # below 1 Hz no velocity or acceleration is seen; above 1 MHz no DAQ samples


@dataclass(frozen=True)
class Signals:
    u: np.ndarray  # mm, centred
    v: np.ndarray  # mm/s
    a: np.ndarray  # mm/s^2
    force: np.ndarray
    dt: float
    v_ref: float  # 95th percentile of |v|
    u_peak: float  # 99.5th percentile of |u|
    travel: float  # total sum |du| of the smoothed displacement
    cutoff_hz: float
    u_noise: float  # RMS of the displacement above the cutoff: the transducer's noise, mm


def extension(u: np.ndarray, dt: float, n: int, window: int) -> np.ndarray:
    """``n`` samples continuing ``u`` past its end: the odd extension about the end,
    2 x(0) - x(-t), with its curvature restored, + x2 t^2 (x2 the second derivative at the end), so
    that it matches the signal's value, slope and curvature (its error is of order t^4, where the
    odd extension alone errs by x2 t^2). x(0) and x2 come from a parabola fitted to the last
    ``window`` samples (at least 5), which keeps the end sample's noise out of them."""
    w = int(min(max(window, 5), u.size))
    t = dt * np.arange(-w + 1, 1)
    c2, _, c0 = np.polyfit(t, u[-w:], 2)
    k = np.arange(1, n + 1)
    return 2.0 * c0 - u[-1 - k] + 2.0 * c2 * (k * dt) ** 2


def signals(record: SpecimenRecord) -> Signals:
    u = record.displacement_mm
    fs = record.rate_hz
    f, p = signal.welch(u - u.mean(), fs=fs, nperseg=int(min(u.size, 2 ** int(np.log2(max(4 * fs, 64))))))
    cum = np.cumsum(p) / max(np.sum(p), 1e-300)
    f995 = float(f[min(np.searchsorted(cum, 0.995), f.size - 1)])
    cutoff = min(max(4.0 * f995, 2.0), 0.3 * fs)
    b, a = signal.butter(4, cutoff, fs=fs)
    # Padded over three periods of the cutoff: the filter's start-up transient, which lasts that
    # long, then falls outside the record instead of on its first and last samples.
    pad = min(u.size - 1, int(math.ceil(3.0 * fs / cutoff)))
    window = int(math.ceil(0.5 * fs / cutoff))
    padded = np.r_[extension(u[::-1], record.dt, pad, window)[::-1], u, extension(u, record.dt, pad, window)]
    smooth = signal.filtfilt(b, a, padded, padtype=None)
    # Twicing (Tukey): the low-pass applied again to what it took away. The passband error falls
    # from 1 - H to (1 - H)^2 (2 H - H^2 stays within [0, 1]: no gain on the noise), so the spring's
    # force k u is not left short near the cutoff (a 5 Hz sweep under a 20 Hz cutoff: 1.5e-5 of its
    # amplitude, the whole residual of a noise-free record, where it reads as a cause).
    us = (smooth + signal.filtfilt(b, a, padded - smooth, padtype=None))[pad: pad + u.size]
    v = np.r_[0.0, np.diff(us)] / record.dt
    acc = np.r_[0.0, np.diff(v)] / record.dt
    v_ref = max(float(np.percentile(np.abs(v), 95)), 1e-9)
    return Signals(us, v, acc, record.force_kN, record.dt, v_ref, max(float(np.percentile(np.abs(u), 99.5)), 1e-9),
                   float(np.sum(np.abs(np.diff(us)))), cutoff, rms(u - us))


# The specimen model's exact step, compiled inline with the path below (the model itself stays plain Python).
_step = helper(bouc_wen_step)


@jit
def _bouc_wen_path(u: np.ndarray, u_y: float) -> np.ndarray:
    out = np.empty(u.size)
    z, prev = 0.0, 0.0
    for i in range(u.size):
        z = _step(z, u[i] - prev, u_y)
        prev = u[i]
        out[i] = z
    return out


def bouc_wen(u: np.ndarray, u_y: float) -> np.ndarray:
    """z along a displacement history, from rest (the specimen model's exact step)."""
    return _bouc_wen_path(np.ascontiguousarray(u, dtype=np.float64), float(u_y))


def _shift(x: np.ndarray, samples: float) -> np.ndarray:
    if samples == 0.0:
        return x
    k = np.arange(x.size, dtype=float)
    return np.interp(k - samples, k, x)


def design(sig: Signals, effects: tuple[str, ...], theta: dict) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names, columns (n x m) and lower bounds of the linear amplitudes, given theta."""
    skew = theta.get("skew_s", 0.0) / sig.dt if "channel_skew" in effects else 0.0
    u, v, a = _shift(sig.u, skew), _shift(sig.v, skew), _shift(sig.a, skew)
    d = np.ones_like(u)
    if "degradation" in effects:
        s = np.cumsum(np.abs(np.r_[0.0, np.diff(u)]))
        d = 1.0 / (1.0 + theta["degradation_per_mm"] * s)
    names, cols, lower = ["offset_kN", "k"], [np.ones_like(u), d * u], [-np.inf, -np.inf]
    if "rate_dependence" in effects:
        damp = sig.v_ref * np.sign(v) * np.abs(v / sig.v_ref) ** theta["alpha"]
    else:
        damp = v
    names.append("c"), cols.append(damp), lower.append(0.0)
    if "nonlinear_elastic" in effects:
        names.append("k3"), cols.append(d * u**3), lower.append(-np.inf)
    if "friction" in effects:
        names.append("friction_kN"), cols.append(np.tanh(v / theta["friction_v0_mm_s"])), lower.append(0.0)
    if "inertia" in effects:
        names.append("mass_kg"), cols.append(1e-6 * a), lower.append(0.0)
    if "gap" in effects:
        names.append("k_gap"), cols.append(d * np.sign(u) * np.maximum(np.abs(u) - theta["gap_mm"], 0.0)), lower.append(0.0)
    if "hysteresis" in effects or "pinching" in effects:
        uy = theta["uy_mm"]
        z = bouc_wen(u, uy) / uy
        if "pinching" in effects:
            z = z * (1.0 - theta["pinch"] * np.exp(-((u / theta["pinch_width_mm"]) ** 2)))
        names.append("fy_kN"), cols.append(d * z), lower.append(0.0)
    return names, np.column_stack(cols), np.array(lower)


def _theta_specs(effects: tuple[str, ...], sig: Signals) -> list[tuple[str, float, float]]:
    specs, seen = [], set()
    for e in effects:
        for name, lo, hi in EFFECTS[e].theta:
            if name not in seen:
                seen.add(name)
                specs.append((name, lo(sig), hi(sig)))
    return specs


@dataclass
class SpecimenFit:
    effects: tuple[str, ...]
    params: dict
    rms_train_kN: float
    rms_choose_kN: float
    rms_test_kN: float
    prediction: np.ndarray

    @property
    def name(self) -> str:
        return "spring + dashpot" + "".join(f" + {e}" for e in self.effects)

    @property
    def n_params(self) -> int:
        return len(self.params)

    def summary(self) -> dict:
        return {"model": self.name, "effects": list(self.effects), "params": dict(self.params),
                "rms_train_kN": self.rms_train_kN, "rms_choose_kN": self.rms_choose_kN, "rms_test_kN": self.rms_test_kN}


def _solve(names, cols, lower, f):
    res = optimize.lsq_linear(cols, f, bounds=(lower, np.full(lower.size, np.inf)), method="bvls")
    return res.x


def fit(sig: Signals, effects: tuple[str, ...], n_train: int, n_choose: int, starts: list[dict] | None = None,
        max_nfev: int = 60) -> SpecimenFit:
    """Fit theta (least squares, bounded) with the amplitudes solved at each evaluation."""
    specs = _theta_specs(effects, sig)
    f_train = sig.force[:n_train]
    # The optimiser sees the training block only (the model is causal: its prefix is the same).
    train = Signals(sig.u[:n_train], sig.v[:n_train], sig.a[:n_train], f_train, sig.dt, sig.v_ref, sig.u_peak, sig.travel,
                    sig.cutoff_hz, sig.u_noise)

    def amplitudes(theta, signals_=sig):
        names, cols, lower = design(signals_, effects, theta)
        return names, cols, _solve(names, cols[:n_train], lower, f_train)

    def residual(x):
        theta = {s[0]: xi * (s[2] - s[1]) + s[1] for s, xi in zip(specs, x)}
        names, cols, coef = amplitudes(theta, train)
        return f_train - cols @ coef

    best_theta = {}
    if specs:
        best = None
        for start in starts or [{}]:
            x0 = np.array([(start.get(n, 0.5 * (lo + hi)) - lo) / (hi - lo) for n, lo, hi in specs])
            x0 = np.clip(x0, 1e-6, 1 - 1e-6)
            sol = optimize.least_squares(residual, x0, bounds=(0.0, 1.0), max_nfev=max_nfev, diff_step=1e-3,
                                         xtol=1e-8, ftol=1e-10)
            if best is None or sol.cost < best.cost:
                best = sol
        best_theta = {s[0]: float(xi * (s[2] - s[1]) + s[1]) for s, xi in zip(specs, best.x)}
    names, cols, coef = amplitudes(best_theta)
    pred = cols @ coef
    r = sig.force - pred
    params = {**dict(zip(names, map(float, coef))), **best_theta}
    if "rate_dependence" in effects:
        params["v_ref_mm_s"] = sig.v_ref
    return SpecimenFit(tuple(effects), params, rms(r[:n_train]), rms(r[n_train:n_choose]), rms(r[n_choose:]), pred)


@dataclass
class SpecimenCandidate:
    cause: str
    fit: SpecimenFit
    gain: float
    choose_gain: float
    named: bool

    def summary(self) -> dict:
        return {"cause": self.cause, "params": dict(self.fit.params), "rms_choose_kN": self.fit.rms_choose_kN,
                "rms_test_kN": self.fit.rms_test_kN, "gain": self.gain, "choose_gain": self.choose_gain,
                "clears_margin": self.named}


@dataclass
class SpecimenDiagnosis(Outcome):
    record: SpecimenRecord
    sig: Signals
    n_train: int
    n_choose: int
    margin: float
    baseline: SpecimenFit
    candidates: list
    cause: str
    extended: SpecimenFit
    floor: residual_mod.Floor
    structure: residual_mod.Structure
    elapsed_s: float = 0.0
    extra: dict = field(default_factory=dict)
    too_short: str | None = None  # why no cause could be named, when the motion is too short to tell

    @property
    def gain(self) -> float:
        return ratio(self.baseline.rms_test_kN, self.extended.rms_test_kN)

    def to_json(self) -> dict:
        s, fl = self.structure, self.floor
        single = self.single
        return {
            "source": self.record.source, "samples": self.record.n, "rate_hz": self.record.rate_hz,
            "n_train": self.n_train, "n_choose": self.n_choose, "margin": self.margin,
            "scoring": scoring_text(self.n_train, self.n_choose, self.record.n),
            "baseline": self.baseline.summary(), "cause": self.cause, "too_short": self.too_short,
            "single": single.summary() if single else None,
            "combination": list(self.extended.effects), "extended": self.extended.summary(), "gain": self.gain,
            "candidates": [c.summary() for c in self.candidates],
            "residual": {"sensor_floor_kN": fl.sensor_floor_mm, "quantisation_kN": fl.quantisation_mm,
                         "rms_test_kN": s.rms_test_mm, "floors": ratio(s.rms_test_mm, fl.sensor_floor_mm),
                         "explained": self.explained, "lines_hz": [x["hz"] for x in s.lines],
                         "lines": [{"hz": x["hz"], "amplitude_kN": x["amplitude_mm"]} for x in s.lines],
                         "trend_kN_per_s": s.trend_mm_per_s, "r2_motion": s.r2_motion, "correlations": s.correlations},
            "specimen": specimen_table(self.extended), "elapsed_s": self.elapsed_s,
        }


def specimen_table(f: SpecimenFit) -> dict:
    """The extended fit as a specimen table for hsio.specimens.make_specimen (kind 'diagnosed').
    The load-cell offset and a channel skew are measurement effects, not the specimen's."""
    p = f.params
    table = {"kind": "diagnosed", "k": p["k"], "c": p["c"]}
    for key in ("k3", "alpha", "v_ref_mm_s", "friction_kN", "friction_v0_mm_s", "mass_kg", "gap_mm", "k_gap", "fy_kN", "uy_mm",
                "pinch", "pinch_width_mm", "degradation_per_mm"):
        if key in p:
            table[key] = float(p[key])
    return table


def _choose(named: list) -> SpecimenCandidate:
    """Fewer parameters within PARSIMONY win; at equal size the lower choosing error (on a chirp a
    moving mass and a degrading stiffness both soften the force as the sweep goes on, and can
    come within 2 % of each other on the choosing block: the library's order would name the worse)."""
    return parsimonious(named, lambda c: c.fit.rms_choose_kN, lambda c: c.fit.n_params, None)


MAX_SAMPLES = 8000  # longer records are thinned after the low-pass (the Bouc-Wen replay is a loop)


def moving_part(record: SpecimenRecord, margin_s: float = 0.1) -> SpecimenRecord:
    """The record from the first to the last motion (rests before and after say nothing of the
    specimen, and would fill the scoring block)."""
    u = record.displacement_mm
    w = max(int(round(0.1 / record.dt)), 5)
    n = u.size // w
    spans = np.ptp(u[: n * w].reshape(n, w), axis=1)
    moving = np.flatnonzero(spans > 0.05 * np.max(spans))
    if moving.size == 0:
        return record
    m = int(round(margin_s / record.dt))
    a, b = max(moving[0] * w - m, 0), min((moving[-1] + 1) * w + m, u.size)
    if b - a < 100 or (a == 0 and b == u.size):
        return record
    return SpecimenRecord(record.source, record.dt, u[a:b], record.force_kN[a:b])


def reversals(u: np.ndarray, noise: float) -> np.ndarray:
    """Indices where the displacement turns back by more than REVERSAL_SHARE of its range (at
    least three times its noise) from its furthest point since the last reversal."""
    h = max(REVERSAL_SHARE * float(np.ptp(u)), 3.0 * noise, 1e-12)
    out, direction, extreme, at = [], 0, float(u[0]), 0
    for i, x in enumerate(u.tolist()):
        if direction == 0:  # not yet moved by h from the start
            if abs(x - extreme) > h:
                direction, extreme, at = (1 if x > extreme else -1), x, i
        elif (x - extreme) * direction > 0:
            extreme, at = x, i
        elif (extreme - x) * direction > h:
            out.append(at)
            direction, extreme, at = -direction, x, i
    return np.array(out, dtype=int)


def too_short(sig: Signals, n_train: int, n_choose: int) -> str | None:
    """Why no cause can be named on this record (too few reversals in a block), or None."""
    turns = reversals(sig.u, sig.u_noise)
    counts = (int(np.sum(turns < n_train)), int(np.sum((turns >= n_train) & (turns < n_choose))),
              int(np.sum(turns >= n_choose)))
    if all(c >= m for c, m in zip(counts, MIN_REVERSALS)):
        return None
    return (f"too short to tell: the displacement reverses {counts[0]}, {counts[1]} and {counts[2]} times in the "
            f"fitting, choosing and scoring blocks; naming a cause needs at least {MIN_REVERSALS[0]}, "
            f"{MIN_REVERSALS[1]} and {MIN_REVERSALS[2]} (a longer record, or more cycles)")


def too_few(n: int, least: int, scoring: int) -> str | None:
    """Why a record of ``n`` samples is too short to judge (fewer than ``least``), or None."""
    if n >= least:
        return None
    return (f"too few samples to judge ({n} < {least}): the scoring block holds {scoring}, too few for its error to "
            "tell a spring from a cause or from the sensor floor (a longer record)")


def thinned(sig: Signals, force: np.ndarray) -> tuple[Signals, int]:
    """Every q-th sample of the low-passed signals when the record is long (q keeps the cutoff
    below 0.8 of the new Nyquist frequency)."""
    n = sig.u.size
    q = int(min(math.ceil(n / MAX_SAMPLES), max(math.floor(0.4 / (sig.dt * sig.cutoff_hz)), 1)))
    if q <= 1:
        return sig, 1
    return Signals(sig.u[::q], sig.v[::q], sig.a[::q], force[::q], sig.dt * q, sig.v_ref, sig.u_peak, sig.travel,
                   sig.cutoff_hz, sig.u_noise), q


def check_passive(record: SpecimenRecord, n_train: int) -> None:
    """Refuse a force that gives energy out instead of taking it: a passive specimen takes work
    from the actuator over a record, W = sum F du >= 0. On the training part, W at or below
    -GIVES_OUT of sum |F du| (most of the motion against the force) with a force that does not
    grow with the displacement either (correlation at most 0) is a force channel of the wrong
    sign, not a specimen (a late force channel on a spring also shows negative work, but its
    force still follows the displacement). A force that clearly falls as the displacement grows
    (correlation at most FALLS) and gives out more than GIVES_OUT_FALLING is refused too: a
    spring or a hysteretic wall read with the wrong sign gives out only what it dissipates, a
    small share of sum |F du| (about 20 to 45 %), and only a moving mass falls passively, taking
    work all the same."""
    u, f = record.displacement_mm[:n_train], record.force_kN[:n_train]
    du, fm = np.diff(u), 0.5 * (f[1:] + f[:-1])
    total = float(np.sum(np.abs(fm * du)))
    if total == 0.0 or np.ptp(u) == 0.0 or np.ptp(f) == 0.0:
        return
    share = float(np.sum(fm * du)) / total
    r_u = float(np.corrcoef(u, f)[0, 1])
    if (share <= -GIVES_OUT and r_u <= 0.0) or (share <= -GIVES_OUT_FALLING and r_u <= FALLS):
        raise RecordError(f"{record.source}: the force gives energy out over the training part (sum F du is "
                          f"{100 * share:+.0f} % of sum |F du|) and does not grow with the displacement (correlation "
                          f"{r_u:+.2f}): a passive specimen takes work from the actuator; the force channel's sign is "
                          "reversed (a column's sign, or --force-scale of a DAQ export) or its wires are")


def smoothing_floor(record: SpecimenRecord, sig: Signals, baseline: SpecimenFit, n_choose: int) -> float:
    """What the low-passed displacement costs the force prediction, in kN. The displacement
    transducer's noise reaches the prediction through the stiffness, k times the RMS the low-pass
    took away. When what it took on the scoring block is not white (its white part, from second
    differences, under half of its RMS: a nearly noise-free transducer) what it took is motion
    above the cutoff (a sweep's ramp, a kink), which reaches the force as the baseline's spring and
    dashpot move with it, k d + c d', and no model of the low-passed motion predicts it."""
    lost = record.displacement_mm - sig.u
    k, c = baseline.params["k"], baseline.params["c"]
    noise_part = abs(k) * sig.u_noise
    held = lost[n_choose:]
    if residual_mod.high_frequency_rms(held) >= 0.5 * rms(held):
        return noise_part
    motion = k * lost + c * np.r_[0.0, np.diff(lost)] / sig.dt
    return max(noise_part, rms(motion[n_choose:]))


@one_blas_thread
def diagnose_specimen(record: SpecimenRecord, train_fraction: float = TRAIN_FRACTION,
                      choose_fraction: float = CHOOSE_FRACTION, margin: float = MARGIN,
                      effects: tuple[str, ...] | None = None, max_combination: int = 3) -> SpecimenDiagnosis:
    t0 = time.perf_counter()
    if not RATE_BOUNDS_HZ[0] <= record.rate_hz <= RATE_BOUNDS_HZ[1]:
        raise RecordError(f"{record.source}: sampled at {record.rate_hz:.6g} Hz; a specimen record's rate must be within "
                          f"{RATE_BOUNDS_HZ[0]:g}..{RATE_BOUNDS_HZ[1]:g} Hz (is the time column in seconds?)")
    record = moving_part(record)
    sig, q = thinned(signals(record), record.force_kN)
    record = SpecimenRecord(record.source, sig.dt, record.displacement_mm[::q], record.force_kN[::q])
    n_train, n_choose = blocks(record.n, train_fraction, choose_fraction)
    if np.ptp(record.displacement_mm[:n_train]) <= 0:
        raise RecordError(f"{record.source}: the displacement does not move in the training part")
    if np.ptp(record.force_kN[:n_train]) <= 0:
        raise RecordError(f"{record.source}: the force does not change in the training part, while the displacement "
                          "moves: the load cell reads nothing (its channel or scale?)")
    check_passive(record, n_train)
    baseline = fit(sig, (), n_train, n_choose)
    short = too_few(record.n, MIN_SAMPLES, record.n - n_choose) or too_short(sig, n_train, n_choose)
    names = list(effects or NAMES)
    candidates = []
    for name in names:
        f = fit(sig, (name,), n_train, n_choose, EFFECTS[name].starts(sig))
        cg = ratio(baseline.rms_choose_kN, f.rms_choose_kN)
        candidates.append(SpecimenCandidate(name, f, ratio(baseline.rms_test_kN, f.rms_test_kN), cg,
                                            cg >= margin and short is None))
    named = [c for c in candidates if c.named]
    floor = residual_mod.sensor_floor(record.displacement_mm, record.force_kN, record.force_kN - baseline.prediction, record.dt)
    floor = residual_mod.Floor(math.hypot(floor.sensor_floor_mm, smoothing_floor(record, sig, baseline, n_choose)),
                               floor.quantisation_mm,
                               floor.still_rms_mm, floor.high_frequency_rms_mm)
    cause, current = None, baseline
    if named:
        best = _choose(named)
        cause, current = best.cause, best.fit
        singles = {c.cause: c.fit for c in candidates}

        def may_join(current: SpecimenFit, name: str) -> bool:
            return not (name in current.effects or {name, *current.effects} >= {"hysteresis", "pinching"})

        def fit_with(current: SpecimenFit, name: str) -> SpecimenFit:
            start = {**singles[name].params, **current.params}
            return fit(sig, (*current.effects, name), n_train, n_choose, [start])

        current = grow(current, names, may_join, fit_with, lambda f: f.rms_choose_kN, margin, max_combination)
    r = record.force_kN - current.prediction
    s = residual_mod.structure(r, n_choose, record.dt, floor.sensor_floor_mm, sig.v, None)
    if cause is None and record.n < MIN_JUDGED:
        cause = TOO_FEW
        short = short if record.n < MIN_SAMPLES else "; ".join(filter(None, (too_few(record.n, MIN_JUDGED, record.n - n_choose), short)))
    elif cause is None:
        cause = unnamed(s, floor)
    return SpecimenDiagnosis(record, sig, n_train, n_choose, margin, baseline, candidates, cause, current, floor, s,
                             time.perf_counter() - t0, too_short=short)
