"""Honest model selection: fit on the first 70 % of the samples, judge on the last 30 %.

A cause is named only when its held-out RMS error is at least ``margin`` times smaller than the
baseline's; otherwise the answer is ``none``. The best single cause is the candidate with the
lowest held-out error among those that clear the margin. The best combination grows from it
greedily: each round adds the effect that lowers the held-out error most, while it still clears
the margin over the combination so far.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from hsio.diagnose.effects import EFFECTS, NAMES, Context, context
from hsio.diagnose.fitting import TRAIN_FRACTION, Fit, fit, split_index
from hsio.diagnose.record import ActuatorRecord
from hsio.errors import RecordError

MARGIN = 1.10  # held-out RMS must fall by at least this factor for a cause to be named
NONE = "none"


@dataclass
class Candidate:
    cause: str
    fit: Fit
    gain: float  # baseline rms_test / candidate rms_test
    named: bool  # clears the margin

    def summary(self) -> dict:
        return {"cause": self.cause, "params": dict(self.fit.params), "rms_train_mm": self.fit.rms_train_mm,
                "rms_test_mm": self.fit.rms_test_mm, "gain": self.gain, "clears_margin": self.named}


@dataclass
class Diagnosis:
    record: ActuatorRecord
    n_train: int
    margin: float
    baseline: Fit
    candidates: list[Candidate]
    cause: str  # the best single cause, or "none"
    extended: Fit  # the best combination (the baseline when the cause is none)
    elapsed_s: float = 0.0
    context: Context | None = field(default=None, repr=False)

    @property
    def gain(self) -> float:
        return self.baseline.rms_test_mm / self.extended.rms_test_mm

    @property
    def single(self) -> Candidate | None:
        return next((c for c in self.candidates if c.cause == self.cause), None)

    def to_json(self) -> dict:
        single = self.single
        return {
            "source": self.record.source,
            "samples": self.record.n,
            "rate_hz": self.record.rate_hz,
            "train_fraction": self.n_train / self.record.n,
            "n_train": self.n_train,
            "margin": self.margin,
            "baseline": {"model": self.baseline.name, "params": dict(self.baseline.params),
                         "rms_train_mm": self.baseline.rms_train_mm, "rms_test_mm": self.baseline.rms_test_mm},
            "cause": self.cause,
            "single": single.summary() if single else None,
            "combination": list(self.extended.effects),
            "extended": self.extended.summary(),
            "gain": self.gain,
            "candidates": [c.summary() for c in self.candidates],
            "elapsed_s": self.elapsed_s,
        }


def estimate_lag(record: ActuatorRecord, n_train: int) -> float:
    """The delay (s) at which the measured displacement best correlates with the command."""
    c = record.command_mm[:n_train] - record.command_mm[:n_train].mean()
    m = record.measured_mm[:n_train] - record.measured_mm[:n_train].mean()
    max_shift = min(n_train // 4, int(round(0.5 / record.dt)))
    xc = signal.correlate(m, c, mode="full", method="fft")
    mid = c.size - 1
    window = xc[mid: mid + max_shift + 1]
    return max(float(np.argmax(window)) * record.dt, 2.0 * record.dt)


def fit_baseline(record: ActuatorRecord, n_train: int) -> Fit:
    lag0 = estimate_lag(record, n_train)
    ctx = Context(record, lag_s=lag0, residual_rms_mm=0.0, v_cmd_peak=0.0, v_meas_peak=0.0, v_model_peak=0.0,
                  stroke_mm=float(np.ptp(record.command_mm)), force_peak=0.0)
    return fit(record, (), ctx, n_train, [{"lag_s": f * lag0} for f in (0.5, 1.0, 2.0)], max_nfev=40)


def _merged_starts(base: Fit, single: Fit) -> list[dict]:
    start = dict(base.params)
    for key, value in single.params.items():
        if key not in ("lag_s", "offset_mm") and key not in start:
            start[key] = value
    return [start]


def diagnose(record: ActuatorRecord, train_fraction: float = TRAIN_FRACTION, margin: float = MARGIN,
             effects: tuple[str, ...] | None = None, max_combination: int = 4) -> Diagnosis:
    """Fit the baseline and every candidate effect; name the cause; grow the best combination."""
    t0 = time.perf_counter()
    if not 0.1 <= train_fraction <= 0.9:
        raise RecordError(f"train fraction must be in [0.1, 0.9], got {train_fraction}")
    n_train = split_index(record, train_fraction)
    if np.ptp(record.command_mm[:n_train]) <= 0:
        raise RecordError(f"{record.source}: the command does not move in the training part")
    baseline = fit_baseline(record, n_train)
    ctx = context(record, baseline.params["lag_s"], baseline.rms_train_mm, baseline.prediction)
    names = [n for n in (effects or NAMES) if not (EFFECTS[n].needs_force and ctx.force_peak == 0.0)]  # no force, or constant
    candidates = []
    for name in names:
        f = fit(record, (name,), ctx, n_train, EFFECTS[name].starts(ctx))
        gain = baseline.rms_test_mm / f.rms_test_mm
        candidates.append(Candidate(name, f, gain, gain >= margin))
    named = [c for c in candidates if c.named]
    if not named:
        return Diagnosis(record, n_train, margin, baseline, candidates, NONE, baseline, time.perf_counter() - t0, ctx)
    best = min(named, key=lambda c: c.fit.rms_test_mm)
    singles = {c.cause: c.fit for c in candidates}
    current = best.fit
    while len(current.effects) < max_combination:
        trials = []
        for name in names:
            if name in current.effects:
                continue
            trials.append(fit(record, (*current.effects, name), ctx, n_train, _merged_starts(current, singles[name])))
        if not trials:
            break
        trial = min(trials, key=lambda f: f.rms_test_mm)
        if current.rms_test_mm / trial.rms_test_mm < margin:
            break
        current = trial
    return Diagnosis(record, n_train, margin, baseline, candidates, best.cause, current, time.perf_counter() - t0, ctx)
