"""The model run at the controller's rate and compared at the record's samples.

The model (hsio/diagnose/model.py) steps once per controller period dt_c: the loop sees the
position of one period earlier, and the least lag it fits is two periods. A record sampled
slower than the loop runs (a DAQ at dt_r = R dt_c beside it) carries the loop's dynamics between
its samples. With the controller's rate given, the command is carried to the controller's
periods t_i = i dt_c by the cubic spline through the record's samples (a DAQ samples a command
the controller moves smoothly: an analog reference, or hsio's predictor-corrector of
docs/method.md section 1, cubic between targets; a spline's error falls as (2 pi f dt_r)^4, a
straight line's only as (2 pi f dt_r)^2, which at 50 Hz on a 4 Hz chirp of 5 mm is 0.03 mm RMS,
three times the sensor's noise), the model steps at dt_c, and its prediction is read at the record's
times t_j = j dt_r (linear interpolation between periods when R is not a whole number). The
force, which only the load train's compliance reads, is carried the same way.

Without the controller's rate the record's rate is taken as the loop's. A record sampled below
SERVO_LOOP_MIN_HZ is then answered ``slow_record`` (:func:`slow_record`): no servo-hydraulic loop
runs that slowly, and the model's one-period delay and two-period least lag would be read as
the actuator's.
"""

from __future__ import annotations

import math

import numpy as np

from hsio.errors import RecordError
from hsio.diagnose.model import simulate

SERVO_LOOP_MIN_HZ = 500.0  # servo-hydraulic controllers close their loop at 500 Hz to several kHz
MAX_PERIODS = 5_000_000  # controller periods simulated per record: about 80 minutes at 1 kHz
SLOW = "slow_record"


def checked_controller_dt(controller_rate_hz, record_rate_hz: float, n: int, source: str) -> float:
    """The controller period (s) of a loop running at ``controller_rate_hz`` beside a record
    sampled at ``record_rate_hz``; refused (RecordError) unless it is a finite rate at or above
    the record's and the record spans at most MAX_PERIODS periods."""
    try:
        rate = float(controller_rate_hz)
    except (TypeError, ValueError):
        raise RecordError(f"--controller-rate must be a number of hertz, got {controller_rate_hz!r}") from None
    if not math.isfinite(rate) or rate <= 0.0:
        raise RecordError(f"--controller-rate must be a positive number of hertz (the servo loop's rate), got {rate:g}")
    if rate < record_rate_hz * (1.0 - 1e-9):
        raise RecordError(f"--controller-rate {rate:g} Hz is below the record's rate ({record_rate_hz:.6g} Hz, "
                          f"{source}): the loop closes at least once per sample recorded; give the controller's rate, "
                          "or leave the option out for a record at the loop's rate")
    periods = (n - 1) * rate / record_rate_hz
    if periods > MAX_PERIODS:
        raise RecordError(f"--controller-rate {rate:g} Hz over {source} ({n} samples at {record_rate_hz:.6g} Hz) is "
                          f"{periods:.3g} controller periods, more than the {MAX_PERIODS:g} diagnose simulates: "
                          "cut the record into parts")
    return 1.0 / rate


def upsampled(x: np.ndarray, ratio: float, periods: int) -> np.ndarray:
    """``x`` (one value per record sample) at the controller's periods i = 0 .. periods - 1, with
    ``ratio`` periods per sample: the cubic spline through the samples (not-a-knot ends)."""
    from scipy.interpolate import CubicSpline

    t = np.minimum(np.arange(periods) / ratio, x.size - 1)
    if x.size < 4:
        return np.interp(t, np.arange(x.size, dtype=float), x)
    return CubicSpline(np.arange(x.size, dtype=float), x)(t)


def predict(record, params: dict, n: int | None = None) -> np.ndarray:
    """The model's measured displacement at the record's first ``n`` samples (all by default):
    stepped at the controller's period when the record carries one, else at the record's."""
    n = record.n if n is None else n
    dt_c = record.controller_dt
    if dt_c is None or dt_c >= record.dt * (1.0 - 1e-9):
        return simulate(record.command_mm, record.dt, params, record.force_kN, n=n)
    ratio = record.dt / dt_c
    periods = int(math.floor((n - 1) * ratio + 1e-9)) + 1
    command = upsampled(record.command_mm[:n], ratio, periods)
    force = None if record.force_kN is None else upsampled(record.force_kN[:n], ratio, periods)
    m = simulate(command, dt_c, params, force)
    k = np.arange(n) * ratio
    whole = np.abs(k - np.round(k)) < 1e-9
    if whole.all():
        return m[np.round(k).astype(int)]
    return np.interp(k, np.arange(periods, dtype=float), m)


def slow_record(record) -> str | None:
    """Why no cause can be named on a record sampled below a servo loop's rate without the
    controller's rate given, or None."""
    if record.controller_dt is not None or record.rate_hz >= SERVO_LOOP_MIN_HZ:
        return None
    return (f"the record is sampled at {record.rate_hz:.6g} Hz, below the {SERVO_LOOP_MIN_HZ:g} Hz or more at which a servo "
            "loop runs: taken as the loop's rate, its sample period would be read as the actuator's own delay and "
            "least lag; give the controller's rate with --controller-rate HZ (controller_rate_hz in the API), or "
            f"--controller-rate {record.rate_hz:.6g} if the loop runs at the record's rate")
