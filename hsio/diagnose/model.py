"""The actuator model replayed against a command: the emulator's physics, vectorised where it can be.

Per controller period k (dt = 1 / the loop's rate; hsio/diagnose/loop_rate.py reads it at a
slower record's samples), the same explicit step as emulators/servo.py:

    c_d[k] = c(t_k - transport_delay)                                     (transport_delay_s)
    v_ff   = clip((c_d[k] - c_d[k-1]) / dt, -a, a) K_p lag                (velocity_threshold_mm_s)
    e      = c_d[k] - x[k-1], less its dead band: e - clip(e, -w, w)      (dead_band_mm)
             K_p = 1 / (lag_s + dt) if e >= 0 else 1 / (lag_retract_s + dt)
    x[k]   = x[k-1] + dt clip(K_p e + v_ff, -v_max, v_max)                (velocity_limit_mm_s)
    x'     = H(z) x, the servo-valve / oil-column mode w^2 / (s^2 + 2 zeta w s + w^2) by the
             bilinear transform                                      (servo_frequency_hz, servo_damping)
    y[k]   = backlash(x')[k]  (play operator, gap backlash_mm)
    m[k]   = displacement_gain (y - compliance F)(t_k - skew) + drift t_k + offset_mm
                                                        (channel_skew_s, sensor_drift_mm_s)

F[k] is the force of the same sample: the load train shortens under the force it carries now,
as the emulator solves it in each period (d = y - compliance F(d)).

With a = 0 this is the first-order lag of the command: since the loop sees the previous
period's position, K_p = 1 / (lag + dt) makes a ramp at velocity v lag by lag (|v| - a) between
a command and the measurement that follows it, the hockey stick of E&M 2007, eq. (1) with
b d_max = lag_s. Without asymmetric lag and flow limit the state equation is linear,
x[k] = (1 - K_p dt) x[k-1] +
K_p dt c_d[k] + dt v_ff[k], and runs as one scipy.signal.lfilter call; otherwise it runs as a
tight loop. The state starts at rest on the first command sample. A record that starts in
motion (cut from a longer test: starting it at rest would put the model off by more than
START_MOTION_SHARE of the command's range) starts on a lead-in instead: the command extended backwards as
the ramp it starts on, long enough (LEAD_IN_TIMES the loop's time constants, at most
LEAD_IN_MAX_S) for the start-up transient to die out, so the model enters the record already
tracking it, as the actuator did.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from hsio.rths.jit import jit

# Every parameter of the model, with its neutral value (the effect is absent). Names are the
# emulator's ServoConfig fields, so a fitted model configures the emulator directly.
NEUTRAL: dict[str, float | None] = {
    "lag_s": None,  # required
    "transport_delay_s": 0.0,
    "velocity_threshold_mm_s": 0.0,
    "velocity_limit_mm_s": math.inf,
    "backlash_mm": 0.0,
    "lag_retract_s": None,  # None: the same as lag_s
    "compliance_mm_per_kN": 0.0,
    "displacement_gain": 1.0,
    "offset_mm": 0.0,
    "dead_band_mm": 0.0,
    "servo_frequency_hz": 0.0,  # 0: no mode
    "servo_damping": 0.7,
    "sensor_drift_mm_s": 0.0,
    "channel_skew_s": 0.0,
}


def delayed(command: np.ndarray, delay_samples: float) -> np.ndarray:
    """The command delayed by a (fractional) number of samples, linear interpolation; the
    first value is held before the record starts."""
    if delay_samples <= 0.0:
        return command
    k = np.arange(command.size, dtype=float)
    return np.interp(k - delay_samples, k, command)


def feed_forward(cd: np.ndarray, dt: float, a: float, gain_up: float, gain_down: float) -> np.ndarray:
    """v_ff = clip(v_cmd, -a, a) K_p lag: the part of the command velocity the valve passes ahead
    of the error (the gain is lag / (lag + dt), by direction of the command)."""
    v = np.empty_like(cd)
    v[0] = 0.0
    np.subtract(cd[1:], cd[:-1], out=v[1:])
    v /= dt
    return np.clip(v, -a, a) * np.where(v >= 0.0, gain_up, gain_down)


def _linear_lag(cd: np.ndarray, vff: np.ndarray | None, dt: float, lag: float) -> np.ndarray:
    k = dt / (lag + dt)
    u = k * cd if vff is None else k * cd + dt * vff
    return signal.lfilter([1.0], [1.0, -(1.0 - k)], u, zi=[(1.0 - k) * cd[0]])[0]


@jit
def _loop_kernel(cd: np.ndarray, ff: np.ndarray, dt: float, kp_e: float, kp_r: float, vmax: float,
                 w: float) -> np.ndarray:
    x = cd[0]
    out = np.empty(cd.size)
    for i in range(cd.size):
        e = cd[i] - x
        if w > 0.0:
            if -w <= e <= w:
                e = 0.0
            elif e > 0.0:
                e = e - w
            else:
                e = e + w
        v = (kp_e if e >= 0.0 else kp_r) * e + ff[i]
        if v > vmax:
            v = vmax
        elif v < -vmax:
            v = -vmax
        x += v * dt
        out[i] = x
    return out


def _loop_lag(cd: np.ndarray, vff: np.ndarray | None, dt: float, lag: float, lag_retract: float, vmax: float,
              dead_band: float = 0.0) -> np.ndarray:
    ff = vff if vff is not None else np.zeros(cd.size)
    return _loop_kernel(np.ascontiguousarray(cd, dtype=np.float64), np.ascontiguousarray(ff, dtype=np.float64),
                        dt, 1.0 / (lag + dt), 1.0 / (lag_retract + dt), vmax, dead_band)


@jit
def _play_kernel(x: np.ndarray, h: float) -> np.ndarray:
    y = x[0]
    out = np.empty(x.size)
    for i in range(x.size):
        if x[i] - y > h:
            y = x[i] - h
        elif x[i] - y < -h:
            y = x[i] + h
        out[i] = y
    return out


def play(x: np.ndarray, gap: float) -> np.ndarray:
    """Backlash (play operator): the output follows x only once the gap is taken up."""
    return _play_kernel(np.ascontiguousarray(x, dtype=np.float64), 0.5 * gap)


LEAD_IN_TIMES = 10.0  # the lead-in lasts this many time constants of the loop (lag, delay, mode)
LEAD_IN_MAX_S = 2.0
# A record starts in motion when starting it at rest would put the model off by more than this
# share of the command's range (lag |v0| + lag^2 |a0|, the lag's error on the parabola it starts on).
START_MOTION_SHARE = 1e-3


def start_motion(command: np.ndarray, dt: float, window: int) -> tuple[float, float]:
    """The command's velocity and acceleration at the record's first sample (a least-squares
    parabola over ``window`` samples)."""
    w = int(min(max(window, 3), command.size))
    if w < 3:
        return 0.0, 0.0
    t = np.arange(w) * dt
    a2, a1, _ = np.polyfit(t, command[:w], 2)
    return float(a1), float(2.0 * a2)


def lead_in_samples(p: dict, dt: float) -> int:
    """The lead-in's length: LEAD_IN_TIMES the loop's time constants (lags, transport delay,
    channel skew, a servo mode's decay 1 / (zeta w)), at most LEAD_IN_MAX_S."""
    lags = p["lag_s"] + (p["lag_retract_s"] or 0.0) + p["transport_delay_s"] + p["channel_skew_s"]
    if p["servo_frequency_hz"] > 0.0:
        lags += 1.0 / (2.0 * math.pi * p["servo_frequency_hz"] * max(p["servo_damping"], 1e-3))
    return int(math.ceil(min(LEAD_IN_TIMES * lags, LEAD_IN_MAX_S) / dt))


def simulate(command: np.ndarray, dt: float, params: dict, force: np.ndarray | None = None,
             n: int | None = None) -> np.ndarray:
    """The measured displacement the model predicts for ``command`` (mm), first ``n`` samples."""
    p = {**NEUTRAL, **params}
    if n is not None:
        command = command[:n]
        force = force[:n] if force is not None else None
    command = np.asarray(command, dtype=float)
    lag = float(p["lag_s"])
    v0, a0 = start_motion(command, dt, int(round(2.0 * lag / dt)))
    if lag * abs(v0) + lag * lag * abs(a0) > START_MOTION_SHARE * float(np.ptp(command)):
        lead = lead_in_samples(p, dt)
        t = dt * np.arange(-lead, 0)
        before = command[0] + v0 * t + 0.5 * a0 * t * t
        held = None if force is None else np.r_[np.full(lead, force[0]), force]
        m = _simulate(np.r_[before, command], dt, p, held)[lead:]
        # The drift counts from the record's first sample.
        return m - p["sensor_drift_mm_s"] * dt * lead
    return _simulate(command, dt, p, force)


def _simulate(command: np.ndarray, dt: float, p: dict, force: np.ndarray | None) -> np.ndarray:
    lag = float(p["lag_s"])
    cd = delayed(np.asarray(command, dtype=float), p["transport_delay_s"] / dt)
    a = p["velocity_threshold_mm_s"]
    lag_retract = p["lag_retract_s"] if p["lag_retract_s"] is not None else lag
    vff = feed_forward(cd, dt, a, lag / (lag + dt), lag_retract / (lag_retract + dt)) if a > 0.0 else None
    vmax = p["velocity_limit_mm_s"]
    w = p["dead_band_mm"]
    if lag_retract == lag and not math.isfinite(vmax) and w <= 0.0:
        x = _linear_lag(cd, vff, dt, lag)
    else:
        x = _loop_lag(cd, vff, dt, lag, lag_retract, vmax if math.isfinite(vmax) else 1e300, w)
    if p["servo_frequency_hz"] > 0.0:
        x = servo_mode(x, dt, p["servo_frequency_hz"], p["servo_damping"])
    if p["backlash_mm"] > 0.0:
        x = play(x, p["backlash_mm"])
    if p["compliance_mm_per_kN"] != 0.0 and force is not None:
        x = x - p["compliance_mm_per_kN"] * force
    m = p["displacement_gain"] * x
    if p["channel_skew_s"] > 0.0:
        m = delayed(m, p["channel_skew_s"] / dt)
    if p["sensor_drift_mm_s"] != 0.0:
        m = m + p["sensor_drift_mm_s"] * dt * np.arange(1, m.size + 1)
    return m + p["offset_mm"]


def mode_filter(frequency_hz: float, damping: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) of w^2 / (s^2 + 2 zeta w s + w^2) by the bilinear transform s = K (z - 1) / (z + 1),
    K = 2 / dt: the emulator's filter (emulators/servo.py, servo_mode_filter) in closed form."""
    w = 2.0 * math.pi * frequency_hz
    k = 2.0 / dt
    a0 = k * k + 2.0 * damping * w * k + w * w
    b = np.array([w * w, 2.0 * w * w, w * w]) / a0
    a = np.array([1.0, (2.0 * w * w - 2.0 * k * k) / a0, (k * k - 2.0 * damping * w * k + w * w) / a0])
    return b, a


def servo_mode(x: np.ndarray, dt: float, frequency_hz: float, damping: float) -> np.ndarray:
    """The rod's motion through a second-order mode (the emulator's filter), at rest on x[0]."""
    b, a = mode_filter(frequency_hz, damping, dt)
    # At rest on x[0] (unit DC gain): the direct form II transposed state of a constant input.
    zi = x[0] * np.array([b[1] + b[2] - a[1] - a[2], b[2] - a[2]])
    return signal.lfilter(b, a, x, zi=zi)[0]
