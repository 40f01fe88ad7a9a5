"""Honest model selection in three blocks of time: fit on the first 60 %, choose on the next
20 %, score on the last 20 %.

A cause is named only when its RMS error on the choosing block is at least ``margin`` times
smaller than the baseline's. The best single cause is the candidate with the lowest choosing
error among those that clear the margin. The best combination grows from it greedily: each round
adds the effect that lowers the choosing error most, while it still clears the margin over the
combination so far. Every gain reported is measured on the scoring block, which neither the fit
nor the choice saw.

A record whose choosing or scoring block is too short to name a cause (:func:`too_short`)
answers ``too_few_samples``: such a block is also too short to judge the floor. Otherwise,
when no candidate clears the margin, the answer depends on the sensor floor
(:mod:`~hsio.diagnose.residual`): ``none`` when the baseline's held-out error is within
``FLOOR_FACTOR`` floors and holds no line or trend (the lag explains the record as well as
the sensors allow), unless the baseline misses the fitting block by more than that
(:func:`quiet_held_out`: the held-out blocks no longer tell, ``too_few_samples``); otherwise
``unexplained``, with what remains in the residual (lines, trend, correlation with the motion).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import fft, signal

from hsio.diagnose.effects import EFFECTS, NAMES, Context, context
from hsio.diagnose import residual as residual_mod
from hsio.diagnose import gain_tie as gain_mod
from hsio.diagnose import loop_rate
from hsio.diagnose import timing as timing_mod
from hsio.diagnose.outcome import NONE, PARSIMONY, TOO_FEW, UNEXPLAINED, Outcome, grow, parsimonious, ratio, scoring_text, unnamed  # noqa: F401
from hsio.diagnose.fitting import CHOOSE_FRACTION, TRAIN_FRACTION, Fit, blocks, fit
from hsio.diagnose.record import ActuatorRecord
from hsio.errors import RecordError
from hsio.diagnose.threads import one_blas_thread

MARGIN = 1.10  # held-out RMS must fall by at least this factor for a cause to be named
RATE_BOUNDS_HZ = (10.0, 1e6)  # an actuator record's rate: a time column in seconds
HELPS = 1.01  # an effect whose single fit gains less than this on the choosing block joins no combination
RESONANT_DAMPING = 0.5  # a servo mode fitted below this damping rings: a signature no delay mimics
# A cause is named only when the choosing and the scoring block each last this many time constants
# of the fitted lag (stretches of error the loop has forgotten) and hold this many samples: on
# shorter blocks an RMS error is too uncertain for a margin of 10 % to mean anything.
MIN_BLOCK_LAGS = 10.0
MIN_BLOCK_SAMPLES = 50
# The measured displacement follows the command: it correlates with it at this normalised
# cross-correlation or better and lags it, or leads it by no more than this (s).
FOLLOW_CORRELATION = 0.5
FOLLOW_LEAD_S = 0.005
# ... and moves this many times as far as its command through the first-order lag it follows
# (following_gain): a transducer's gain error; the mistakes of units are factors of 10 (V at
# 10 mm/V, cm), 25.4 (inches) or 1000 (m).
FOLLOW_SCALE = (0.2, 5.0)
FOLLOW_LAG_MAX_S, FOLLOW_LAGS = 1.0, 30  # the first-order lags the gain is taken through (s; log-spaced from dt)
FOLLOW_TIE = 0.001  # correlations this close are a tie
REVERSED_FIT = 2.0  # the command predicted from the measurement fits this many times better: channels swapped
STILL_SHARE = 0.01  # a held-out block whose command moves less than this share of the record's range is at rest


@dataclass
class Candidate:
    cause: str
    fit: Fit
    gain: float  # baseline rms_test / candidate rms_test (the scoring block)
    named: bool  # clears the margin on the choosing block
    choose_gain: float = 1.0  # baseline rms_choose / candidate rms_choose

    def summary(self) -> dict:
        return {"cause": self.cause, "params": dict(self.fit.params), "rms_train_mm": self.fit.rms_train_mm,
                "rms_choose_mm": self.fit.rms_choose_mm, "rms_test_mm": self.fit.rms_test_mm, "gain": self.gain,
                "choose_gain": self.choose_gain, "clears_margin": self.named}


@dataclass
class Diagnosis(Outcome):
    record: ActuatorRecord
    n_train: int
    margin: float
    baseline: Fit
    candidates: list[Candidate]
    cause: str  # the best single cause, "none", "unexplained", "too_few_samples" or "slow_record"
    extended: Fit  # the best combination (the baseline when no cause is named)
    elapsed_s: float = 0.0
    context: Context | None = field(default=None, repr=False)
    n_choose: int = 0  # [n_train, n_choose) chooses, [n_choose, n) scores
    floor: residual_mod.Floor | None = None
    structure: residual_mod.Structure | None = None
    timing: timing_mod.Timing | None = None  # a late channel against a delay in the loop, by the force
    too_short: str | None = None  # why no cause could be named, when the blocks are too short to tell
    gain_tie: gain_mod.GainTie | None = None  # a transducer gain against a compliant load train, when they tie
    slow_record: str | None = None  # why no cause is named on a record slower than a loop, its rate not given

    @property
    def equivalent(self) -> Candidate | None:
        """A candidate that predicts the displacement as well as the cause (within PARSIMONY) and
        that the force's timing could not tell from it (a delay in the loop or in the channel)."""
        if self.timing is not None and self.timing.verdict != timing_mod.OPEN:
            return None
        if self.gain_tie is not None and self.gain_tie.verdict != gain_mod.OPEN:
            return None
        other = EQUIVALENT.get(self.cause) or (gain_mod.PAIR.get(self.cause) if self.gain_tie is not None else None)
        c = next((c for c in self.candidates if c.cause == other), None)
        single = self.single
        if c is None or single is None or not c.named:
            return None
        return c if c.fit.rms_choose_mm <= PARSIMONY * single.fit.rms_choose_mm else None

    def residual_json(self) -> dict:
        s = self.structure
        return {**self.floor.to_json(), "rms_test_mm": s.rms_test_mm, "floors": ratio(s.rms_test_mm, self.floor.sensor_floor_mm),
                "explained": self.explained, "lines_hz": [line["hz"] for line in s.lines], "lines": s.lines,
                "trend_mm_per_s": residual_mod.trend(self.record.measured_mm - self.baseline.prediction, self.record.dt),
                "trend_after_mm_per_s": s.trend_mm_per_s, "trend_significant": s.trend_significant,
                "r2_motion": s.r2_motion, "correlations": s.correlations,
                "remains": residual_mod.remains(s, self.floor)}

    @property
    def gain(self) -> float:
        return ratio(self.baseline.rms_test_mm, self.extended.rms_test_mm)

    def to_json(self) -> dict:
        single = self.single
        return {
            "source": self.record.source,
            "samples": self.record.n,
            "rate_hz": self.record.rate_hz,
            "controller_rate_hz": None if self.record.controller_dt is None else 1.0 / self.record.controller_dt,
            "train_fraction": self.n_train / self.record.n,
            "n_train": self.n_train,
            "n_choose": self.n_choose,
            "scoring": scoring_text(self.n_train, self.n_choose, self.record.n),
            "margin": self.margin,
            "baseline": {"model": self.baseline.name, "params": dict(self.baseline.params),
                         "rms_train_mm": self.baseline.rms_train_mm, "rms_choose_mm": self.baseline.rms_choose_mm,
                         "rms_test_mm": self.baseline.rms_test_mm},
            "cause": self.cause,
            "too_short": self.too_short,
            "slow_record": self.slow_record,
            "single": single.summary() if single else None,
            "equivalent": self.equivalent.summary() if self.equivalent else None,
            "timing": self.timing.to_json() if self.timing else None,
            "gain_tie": self.gain_tie.to_json() if self.gain_tie else None,
            "combination": list(self.extended.effects),
            "extended": self.extended.summary(),
            "gain": self.gain,
            "candidates": [c.summary() for c in self.candidates],
            "residual": self.residual_json(),
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
    return max(float(np.argmax(window)) * record.dt, 2.0 * record.loop_dt)


def check_following(record: ActuatorRecord, n_train: int) -> None:
    """Refuse a record whose measured displacement does not follow its command: on the training
    part the two correlate best (normalised cross-correlation r, shifts up to half a second)
    against each other (r <= -FOLLOW_CORRELATION: a scale of the wrong sign) or with the
    measurement ahead of the command by more than FOLLOW_LEAD_S (an actuator cannot move before
    it is told to: the two channels swapped, or the command channel recorded late), or following
    it with a gain (:func:`following_gain`) outside FOLLOW_SCALE (the channels in different
    units). Either way no effect of the library applies, and a fit would name a cause with an
    unphysical value."""
    c = record.command_mm[:n_train] - record.command_mm[:n_train].mean()
    m = record.measured_mm[:n_train] - record.measured_mm[:n_train].mean()
    norm = math.sqrt(float(np.dot(c, c)) * float(np.dot(m, m)))
    if norm == 0.0:
        return
    max_shift = min(n_train // 4, int(round(0.5 / record.dt)))
    mid = c.size - 1
    xc = signal.correlate(m, c, mode="full", method="fft")[mid - max_shift: mid + max_shift + 1] / norm
    k = int(np.argmax(np.abs(xc)))
    r, shift_s = float(xc[k]), (k - max_shift) * record.dt
    if r <= -FOLLOW_CORRELATION:
        raise RecordError(f"{record.source}: the measured displacement moves against the command (correlation "
                          f"{r:+.2f} on the training part): the sign of a channel's scale is reversed "
                          "(a column's sign, or --command-scale / --measured-scale of a DAQ export) or the transducer is wired the other way")
    if r >= FOLLOW_CORRELATION and -shift_s > max(FOLLOW_LEAD_S, 2.0 * record.dt):
        raise RecordError(f"{record.source}: the measured displacement leads the command by {1e3 * -shift_s:.4g} ms "
                          f"(cross-correlation {r:.2f} on the training part), and an actuator cannot move before it is "
                          "commanded: the command and measured channels are swapped (the columns, or --command-channel / "
                          "--measured-channel of a DAQ export) or the command channel is recorded late")
    gain = following_gain(record, n_train) if r >= FOLLOW_CORRELATION else 1.0
    if not FOLLOW_SCALE[0] <= gain <= FOLLOW_SCALE[1]:
        raise RecordError(f"{record.source}: the measured displacement moves {gain:.4g} times its command (least "
                          "squares against the command through the first-order lag and shift it follows best, on "
                          f"the training part), beyond the {FOLLOW_SCALE[0]:g}..{FOLLOW_SCALE[1]:g} that a transducer's "
                          "gain error gives: the "
                          "two channels are in different units (--command-scale / --measured-scale of a DAQ export, a "
                          "column in V, inches or m)")


def following_gain(record: ActuatorRecord, n_train: int) -> float:
    """The gain g of m = g L(c) on the training part, by least squares: L the first-order lag of
    the model (docs/diagnose.md; K_p dt = dt / (lag + dt)) and a shift of up to half a second,
    the pair whose output correlates best with the measurement (of near ties, the least shift,
    then the least lag: on a single sine a shift and a lag each match the phase, the lag's
    attenuation with it). A lag attenuates a fast motion as well as delaying it (a 120 ms lag
    moves 8 to 11 Hz 0.2 times as far), which no unit mistake does: through the lag the
    attenuation leaves the gain, and a factor of units stays in it."""
    c = record.command_mm[:n_train]
    m = record.measured_mm[:n_train] - record.measured_mm[:n_train].mean()
    max_shift = min(n_train // 4, int(round(0.5 / record.dt)))
    size = fft.next_fast_len(c.size + max_shift, real=True)  # no wrap-around within the shifts
    m_f = np.conj(np.fft.rfft(m, size))
    best = []
    for lag in (0.0, *np.geomspace(record.dt, FOLLOW_LAG_MAX_S, FOLLOW_LAGS)):
        alpha = record.dt / (lag + record.dt)
        y = signal.lfilter([alpha], [1.0, alpha - 1.0], c - c[0]) + c[0]
        y = y - y.mean()
        yy = float(np.dot(y, y))
        if yy == 0.0:
            continue
        xc = np.fft.irfft(np.fft.rfft(y, size) * m_f, size)  # xc[s] = sum_k y[k + s] m[k]
        xc = np.concatenate([xc[size - max_shift:], xc[: max_shift + 1]])[::-1]  # m against y shifted by -max..max
        k = int(np.argmax(xc))
        r = float(xc[k]) / math.sqrt(yy * float(np.dot(m, m)))
        best.append((r, abs(k - max_shift), lag, float(xc[k]) / yy))
    if not best:
        return 1.0
    top = max(b[0] for b in best)
    return min((b for b in best if b[0] >= top - FOLLOW_TIE), key=lambda b: (b[1], b[2]))[3]


def check_not_reversed(record: ActuatorRecord, n_train: int, baseline: Fit) -> None:
    """Refuse a record whose command follows its measurement: the baseline's lag sits at its
    least value (two loop periods: the measurement does not trail the command) while the
    same lag fitted the other way round, the command predicted from the measurement, trails
    by more than twice that and fits REVERSED_FIT times better. Cross-correlation cannot tell
    which channel leads on a slow motion (a 1 Hz swing hides 26 ms of lead in a flat peak, and
    DAQ noise common to both channels pulls it to zero); the fit of a lag can."""
    least = 2.0 * record.loop_dt
    if baseline.params["lag_s"] > 1.01 * least:
        return
    flipped = fit_baseline(dataclasses.replace(record, command_mm=record.measured_mm, measured_mm=record.command_mm),
                           n_train)
    lag = flipped.params["lag_s"]
    if lag > 2.0 * least and REVERSED_FIT * flipped.rms_train_mm <= baseline.rms_train_mm:
        raise RecordError(f"{record.source}: the command follows the measured displacement: read the other way "
                          f"round, the command trails it by a lag of {1e3 * lag:.4g} ms (RMS "
                          f"{flipped.rms_train_mm:.4g} mm on the training part, against {baseline.rms_train_mm:.4g} mm "
                          "with the measurement following the command at the least lag), and an actuator cannot move "
                          "before it is commanded: the command and measured channels are swapped (the columns, or "
                          "--command-channel / --measured-channel of a DAQ export) or the command channel is recorded late")


def too_short(record: ActuatorRecord, n_train: int, n_choose: int, lag_s: float) -> str | None:
    """Why no cause can be named on this record (a block too short to tell), or None. The least
    number of samples M is the one whose shorter block would hold what a block needs."""
    shortest = min(n_choose - n_train, record.n - n_choose)
    if shortest * record.dt >= MIN_BLOCK_LAGS * lag_s and shortest >= MIN_BLOCK_SAMPLES:
        return None
    need = max(MIN_BLOCK_SAMPLES, math.ceil(MIN_BLOCK_LAGS * lag_s / record.dt))
    least = math.ceil(need * record.n / max(shortest, 1))
    return (f"too few samples to judge ({record.n} < {least}), too short to tell: the choosing and scoring blocks "
            f"hold {n_choose - n_train} and {record.n - n_choose} "
            f"samples ({1e3 * (n_choose - n_train) * record.dt:.4g} and {1e3 * (record.n - n_choose) * record.dt:.4g} ms); "
            f"naming a cause needs at least {MIN_BLOCK_SAMPLES} samples and {MIN_BLOCK_LAGS:g} lags "
            f"({1e3 * MIN_BLOCK_LAGS * lag_s:.4g} ms) in each (a longer record)")


def still_block(record: ActuatorRecord, n_train: int, n_choose: int) -> str | None:
    """Why no cause can be judged when the choosing or the scoring block holds no motion (its
    command moves less than STILL_SHARE of the record's range: a long rest at the end of the
    record), or None. A block at rest tells no model from another, and its error says nothing of
    how the model follows a motion: without this, a delay hidden in the motion would answer none."""
    span = float(np.ptp(record.command_mm))
    for name, (a, b) in (("choosing", (n_train, n_choose)), ("scoring", (n_choose, record.n))):
        moves = float(np.ptp(record.command_mm[a:b])) if b > a else 0.0
        if moves < STILL_SHARE * span:
            return (f"the {name} block (samples {a} to {b}) holds no motion: its command moves {moves:.4g} mm, under "
                    f"{100 * STILL_SHARE:g} % of the record's {span:.4g} mm; cut the rest off the record")
    return None


def quiet_held_out(baseline: Fit, floor: residual_mod.Floor) -> str | None:
    """Why no verdict can be drawn when the baseline misses the fitting block by more than
    FLOOR_FACTOR sensor floors, or None. The held-out blocks then show less of what the
    fitting block shows (an earthquake's free-vibration tail, slower than its strong motion):
    an error at the floor there says the record stops telling the models apart, not that the
    baseline explains it, so the answer is neither none nor a cause judged there."""
    limit = residual_mod.FLOOR_FACTOR * floor.sensor_floor_mm
    if baseline.rms_train_mm <= limit:
        return None
    return (f"the baseline misses the fitting block by {baseline.rms_train_mm:.4g} mm RMS, "
            f"{baseline.rms_train_mm / floor.sensor_floor_mm:.3g} sensor floors of {floor.sensor_floor_mm:.4g} mm, "
            f"but no candidate clears the margin on the choosing block ({baseline.rms_choose_mm:.4g} mm): "
            "the held-out blocks hold too little of the motion that shows the error to judge a cause; "
            "move the blocks into the motion (a smaller --train-fraction and --choose-fraction) or cut "
            "the quiet end off the record")


def with_controller_rate(record: ActuatorRecord, controller_rate_hz: float | None) -> ActuatorRecord:
    """The record with the servo loop's period, when its rate is given (checked by
    :func:`~hsio.diagnose.loop_rate.checked_controller_dt`); an hsio run's record keeps its own."""
    if controller_rate_hz is None:
        return record
    dt_c = loop_rate.checked_controller_dt(controller_rate_hz, record.rate_hz, record.n, record.source)
    if record.controller_dt is not None and not math.isclose(dt_c, record.controller_dt, rel_tol=1e-9):
        raise RecordError(f"{record.source}: --controller-rate {controller_rate_hz:g} Hz, but the record holds every "
                          f"period of its controller at {1.0 / record.controller_dt:.6g} Hz: leave the option out")
    return dataclasses.replace(record, controller_dt=dt_c)


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


def _distinct(c: Candidate) -> bool:
    """A candidate whose fit shows its own signature, which no simpler rival can mimic."""
    return c.cause == "servo_dynamics" and c.fit.params["servo_damping"] < RESONANT_DAMPING


def choose_single(named: list[Candidate], ctx: Context, record: ActuatorRecord) -> Candidate:
    """The best named candidate on the choosing block; among those within PARSIMONY of it, the one
    with the fewest parameters (then the earliest in the library), unless the best shows a
    distinct signature. A late displacement channel (channel_skew) and a transport delay predict
    the same displacement from the command (a delay commutes with the loop), so they tie; the
    tie goes to transport_delay here, and :func:`settle_timing` settles it by the force."""
    best = min(named, key=lambda c: c.fit.rms_choose_mm)
    if _distinct(best):
        return best
    return parsimonious(named, lambda c: c.fit.rms_choose_mm, lambda c: len(EFFECTS[c.cause].params(ctx)), NAMES)


EQUIVALENT = {"transport_delay": "channel_skew", "channel_skew": "transport_delay"}


def settle_timing(best: Candidate, named: list[Candidate], record: ActuatorRecord,
                  floor: residual_mod.Floor) -> tuple[Candidate, timing_mod.Timing | None]:
    """When a transport delay and a channel skew tie on the displacement, the force's timing
    (hsio/diagnose/timing.py) names the one it shows; undecided, ``best`` stays."""
    other = next((c for c in named if c.cause == EQUIVALENT.get(best.cause)), None)
    if other is None or other.fit.rms_choose_mm > PARSIMONY * best.fit.rms_choose_mm:
        return best, None
    skew = best if best.cause == timing_mod.SKEW else other
    t = timing_mod.tell(record, skew.fit.params["channel_skew_s"], floor.sensor_floor_mm)
    if t.verdict == timing_mod.OPEN:
        return best, t
    return (best if best.cause == t.verdict else other), t


def settle_gain(best: Candidate, named: list[Candidate], record: ActuatorRecord) -> tuple[Candidate, gain_mod.GainTie | None]:
    """When a transducer gain error and a load-train compliance tie on the displacement (a linear
    spring: hsio/diagnose/gain_tie.py), the sign of the compliance names the gain error where it
    is negative; otherwise both stay, equally likely, and ``best`` is named with the other as its
    equivalent."""
    other = next((c for c in named if c.cause == gain_mod.PAIR.get(best.cause)), None)
    if other is None or record.force_kN is None or other.fit.rms_choose_mm > PARSIMONY * best.fit.rms_choose_mm:
        return best, None
    gain, coupling = (best, other) if best.cause == gain_mod.GAIN else (other, best)
    t = gain_mod.tell(gain.fit.params["displacement_gain"], coupling.fit.params["compliance_mm_per_kN"],
                      record.measured_mm, record.force_kN)
    return (gain if t.verdict == gain_mod.GAIN else best), t


def _finish(record: ActuatorRecord, n_train: int, n_choose: int, margin: float, baseline: Fit, candidates: list,
            cause: str | None, extended: Fit, t0: float, ctx: Context, floor: residual_mod.Floor,
            timing: timing_mod.Timing | None = None, short: str | None = None,
            tie: gain_mod.GainTie | None = None, slow: str | None = None) -> Diagnosis:
    """Measure the residual's structure, and settle none against unexplained."""
    r = record.measured_mm - extended.prediction
    s = residual_mod.structure(r, n_choose, record.dt, floor.sensor_floor_mm, record.smoothed_velocity(), record.force_kN)
    if cause is None:
        cause = loop_rate.SLOW if slow else TOO_FEW if short else unnamed(s, floor)
        if cause == NONE:
            short = quiet_held_out(baseline, floor)
            cause = TOO_FEW if short else NONE
    return Diagnosis(record, n_train, margin, baseline, candidates, cause, extended, time.perf_counter() - t0, ctx,
                     n_choose, floor, s, timing, short, tie, slow)


@one_blas_thread
def diagnose(record: ActuatorRecord, train_fraction: float = TRAIN_FRACTION, margin: float = MARGIN,
             effects: tuple[str, ...] | None = None, max_combination: int = 3,
             choose_fraction: float = CHOOSE_FRACTION, controller_rate_hz: float | None = None) -> Diagnosis:
    """Fit the baseline and every candidate effect; name the cause; grow the best combination.
    ``controller_rate_hz``: the servo loop's rate, when the record is sampled slower than the loop
    runs (hsio/diagnose/loop_rate.py)."""
    t0 = time.perf_counter()
    if not 0.1 <= train_fraction <= 0.8:
        raise RecordError(f"train_fraction (--train-fraction) must be in [0.1, 0.8], got {train_fraction}")
    if not 0.05 <= choose_fraction <= 0.95 - train_fraction:
        raise RecordError(f"choose_fraction (--choose-fraction) must be in [0.05, {0.95 - train_fraction:.2f}] (the rest "
                          f"scores), got {choose_fraction}")
    if not RATE_BOUNDS_HZ[0] <= record.rate_hz <= RATE_BOUNDS_HZ[1]:
        raise RecordError(f"{record.source}: sampled at {record.rate_hz:.6g} Hz; an actuator record is sampled "
                          f"within {RATE_BOUNDS_HZ[0]:g}..{RATE_BOUNDS_HZ[1]:g} Hz "
                          "(is the time column in seconds?)")
    record = with_controller_rate(record, controller_rate_hz)
    n_train, n_choose = blocks(record.n, train_fraction, choose_fraction)
    if np.ptp(record.command_mm[:n_train]) <= 0:
        raise RecordError(f"{record.source}: the command does not move in the training part")
    if np.ptp(record.measured_mm[:n_train]) <= 0:
        raise RecordError(f"{record.source}: the measured displacement does not move in the training part, while "
                          "the command does: the actuator did not follow (hydraulics off, interlock) or the "
                          "channel is not the displacement")
    check_following(record, n_train)
    baseline = fit_baseline(record, n_train)
    check_not_reversed(record, n_train, baseline)
    ctx = context(record, baseline.params["lag_s"], baseline.rms_train_mm, baseline.prediction)
    names = [n for n in (effects or NAMES) if not (EFFECTS[n].needs_force and ctx.force_peak == 0.0)]  # no force, or constant
    slow = loop_rate.slow_record(record)
    short = slow or still_block(record, n_train, n_choose) or too_short(record, n_train, n_choose, baseline.params["lag_s"])
    # A baseline that already predicts the choosing block to rounding (a noise-free record of the
    # model itself) leaves nothing to explain: gains between rounding errors name nothing.
    resolved = baseline.rms_choose_mm > residual_mod.precision_floor(record.measured_mm)
    candidates = []
    for name in names:
        f = fit(record, (name,), ctx, n_train, EFFECTS[name].starts(ctx))
        choose_gain = ratio(baseline.rms_choose_mm, f.rms_choose_mm)
        candidates.append(Candidate(name, f, ratio(baseline.rms_test_mm, f.rms_test_mm),
                                    choose_gain >= margin and short is None and resolved, choose_gain))
    named = [c for c in candidates if c.named]
    floor = residual_mod.sensor_floor(record.command_mm, record.measured_mm, record.measured_mm - baseline.prediction, record.dt)
    if not named:
        return _finish(record, n_train, n_choose, margin, baseline, candidates, None, baseline, t0, ctx, floor,
                       short=None if slow else short, slow=slow)
    best, timing = settle_timing(choose_single(named, ctx, record), named, record, floor)
    best, tie = settle_gain(best, named, record)
    singles = {c.cause: c.fit for c in candidates}
    gains = {c.cause: c.choose_gain for c in candidates}

    def may_join(current: Fit, name: str) -> bool:
        # An effect that did nothing alone, or one the record cannot tell from an effect
        # already in, is not tried (it saves most of the time on long records).
        return not (name in current.effects or gains[name] < HELPS or EQUIVALENT.get(name) in current.effects)

    current = grow(best.fit, names, may_join,
                   lambda current, name: fit(record, (*current.effects, name), ctx, n_train, _merged_starts(current, singles[name])),
                   lambda f: f.rms_choose_mm, margin, max_combination)
    return _finish(record, n_train, n_choose, margin, baseline, candidates, best.cause, current, t0, ctx, floor, timing,
                   tie=tie)
