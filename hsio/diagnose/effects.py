"""The candidate causes: each a small extension of the baseline lag with physical parameters.

Each effect names the model parameters it frees (ServoConfig fields of the emulator), their
bounds and starting values (from the record and the baseline fit), and a sentence saying what
the parameter means physically.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Callable

import numpy as np

from hsio.diagnose.record import ActuatorRecord


@dataclass(frozen=True)
class Param:
    name: str
    lower: float
    upper: float
    scale: float  # typical size, for the optimiser's steps


@dataclass(frozen=True)
class Context:
    """What starting values and bounds are derived from."""

    record: ActuatorRecord
    lag_s: float  # the baseline fit
    residual_rms_mm: float  # of the baseline, on the training part
    v_cmd_peak: float  # 99.9th percentile of |command velocity|, mm/s
    v_meas_peak: float  # the same of the measured velocity (smoothed), mm/s
    v_model_peak: float  # the same of the baseline model's velocity, mm/s
    stroke_mm: float  # peak-to-peak command
    force_peak: float  # peak-to-peak force, kN (0 without force)
    residual_peak_hz: float = 0.0  # where the baseline residual's spectrum peaks (above 0.5 Hz)


@dataclass(frozen=True)
class Effect:
    name: str
    title: str
    cause: str  # the physical explanation, for the report
    params: Callable[[Context], tuple[Param, ...]]
    starts: Callable[[Context], list[dict]]  # initial values (effect parameters and lag_s)
    describe: Callable[[dict], str]
    needs_force: bool = False
    primary: str = ""  # the parameter that measures the effect's size


def _lag_param(ctx: Context, name: str = "lag_s") -> Param:
    # The least lag is two periods of the loop (the model's explicit step is stable above it).
    return Param(name, 2.0 * ctx.record.loop_dt, 2.0, max(ctx.lag_s, 2.0 * ctx.record.loop_dt))


BASELINE_PARAMS = _lag_param


def _time_offset(ctx: Context, name: str) -> tuple[Param]:
    """A delay (s): up to four lags or half a second, in steps of about a third of the lag."""
    return (Param(name, 0.0, max(0.5, 4.0 * ctx.lag_s), max(0.3 * ctx.lag_s, ctx.record.dt)),)


def _width(ctx: Context, name: str, share_of_stroke: float) -> tuple[Param]:
    """A width (mm) up to a share of the stroke, in steps of the baseline's residual."""
    return (Param(name, 0.0, share_of_stroke * max(ctx.stroke_mm, 1e-6), max(ctx.residual_rms_mm, 1e-4)),)


def _residual_sized(ctx: Context, name: str, fractions: tuple[float, ...]) -> list[dict]:
    """Starts with ``name`` at fractions of the baseline's residual RMS."""
    return [{name: f * ctx.residual_rms_mm, "lag_s": ctx.lag_s} for f in fractions]


def _lag_shared(ctx: Context, name: str, fractions: tuple[float, ...]) -> list[dict]:
    """Starts that give a fraction f of the baseline's lag to the delay ``name`` and keep the rest as lag."""
    return [{name: f * ctx.lag_s, "lag_s": max((1.0 - f) * ctx.lag_s, 2.0 * ctx.record.loop_dt)} for f in fractions]

EFFECTS: dict[str, Effect] = {}


def _register(effect: Effect) -> Effect:
    EFFECTS[effect.name] = effect
    return effect


_register(Effect(
    "transport_delay", "transport delay",
    "a pure delay in the loop (controller cycle, DAQ and communication latency, valve dead time): "
    "the actuator answers a fixed time late at every frequency, so the phase error grows with frequency "
    "faster than a first-order lag allows",
    lambda c: _time_offset(c, "transport_delay_s"),
    lambda c: _lag_shared(c, "transport_delay_s", (0.3, 0.7)),
    lambda p: f"transport delay {1e3 * p['transport_delay_s']:.2f} ms on top of a lag of {1e3 * p['lag_s']:.2f} ms",
    primary="transport_delay_s",
))

_register(Effect(
    "velocity_threshold", "velocity threshold (hockey stick)",
    "velocity feed-forward up to a threshold speed a: below it the actuator follows the command with "
    "no error, above it the error grows as lag (|v| - a) (E&M 2007, eq. (1))",
    lambda c: (Param("velocity_threshold_mm_s", 0.0, c.v_cmd_peak, max(0.05 * c.v_cmd_peak, 1e-3)),),
    lambda c: [{"velocity_threshold_mm_s": f * c.v_cmd_peak, "lag_s": c.lag_s} for f in (0.02, 0.1, 0.3)],
    lambda p: f"no error below {p['velocity_threshold_mm_s']:.3g} mm/s, then lag {1e3 * p['lag_s']:.2f} ms x (|v| - a)",
    primary="velocity_threshold_mm_s",
))

_register(Effect(
    "velocity_saturation", "velocity saturation",
    "the servo-valve's flow limit: the actuator cannot move faster than a maximum velocity, so fast "
    "parts of the command fall behind and the error grows where the commanded speed exceeds it",
    lambda c: (Param("velocity_limit_mm_s", 0.05 * max(c.v_cmd_peak, 1e-3), 5.0 * max(c.v_cmd_peak, 1e-3),
                     max(0.1 * c.v_meas_peak, 1e-3)),),
    # The limit must bind on the baseline's own motion to be felt: start below its peak speed.
    lambda c: [{"velocity_limit_mm_s": f * max(c.v_model_peak, 1e-3), "lag_s": c.lag_s} for f in (0.6, 0.9)],
    lambda p: f"velocity limited to {p['velocity_limit_mm_s']:.4g} mm/s",
    primary="velocity_limit_mm_s",
))

_register(Effect(
    "backlash", "backlash",
    "slop in the load train (clevises, pins, swivels): at each reversal the rod travels across a gap "
    "before the specimen moves, so the measured displacement stalls after every change of direction",
    lambda c: _width(c, "backlash_mm", 0.5),
    lambda c: _residual_sized(c, "backlash_mm", (1.0, 3.0)),
    lambda p: f"gap of {p['backlash_mm']:.4g} mm taken up at each reversal",
    primary="backlash_mm",
))

_register(Effect(
    "asymmetric_lag", "asymmetric lag",
    "different lags extending and retracting: unequal piston areas of a single-ended actuator or an "
    "asymmetric servo-valve, so the loop is faster one way than the other",
    lambda c: (_lag_param(c, "lag_retract_s"),),
    lambda c: [{"lag_retract_s": c.lag_s, "lag_s": c.lag_s}],
    lambda p: f"lag {1e3 * p['lag_s']:.2f} ms extending, {1e3 * p['lag_retract_s']:.2f} ms retracting",
    primary="lag_retract_s",
))

_register(Effect(
    "force_coupling", "force coupling",
    "an error proportional to the measured force: compliance of the load train and reaction frame "
    "(control-structure interaction) lets the specimen's force push the measured displacement away "
    "from the rod's",
    lambda c: (Param("compliance_mm_per_kN", -10.0 * c.stroke_mm / max(c.force_peak, 1e-9),
                     10.0 * c.stroke_mm / max(c.force_peak, 1e-9), max(c.residual_rms_mm / max(c.force_peak, 1e-9), 1e-9)),),
    lambda c: [{"compliance_mm_per_kN": 0.0, "lag_s": c.lag_s}],
    lambda p: f"compliance {p['compliance_mm_per_kN']:.4g} mm/kN",
    needs_force=True,
    primary="compliance_mm_per_kN",
))

_register(Effect(
    "scale_error", "scale error",
    "a transducer gain error (calibration of the displacement transducer or of the command scale): "
    "the error is proportional to the displacement itself",
    lambda c: (Param("displacement_gain", 0.5, 2.0, 0.01),),
    lambda c: [{"displacement_gain": 1.0, "lag_s": c.lag_s}],
    lambda p: f"transducer gain {p['displacement_gain']:.4f} ({100 * (p['displacement_gain'] - 1):+.2f} %)",
    primary="displacement_gain",
))

_register(Effect(
    "servo_dynamics", "servo-valve or oil-column mode",
    "a second-order stage in series with the lag: the servo-valve spool's own dynamics or the "
    "oil-column resonance (the piston and specimen mass on the compressibility of the oil), so the "
    "actuator overshoots and rings near that frequency instead of only falling behind",
    lambda c: (Param("servo_frequency_hz", 0.5, 0.45 / c.record.dt, 5.0), Param("servo_damping", 0.02, 2.0, 0.1)),
    lambda c: [{"servo_frequency_hz": f, "servo_damping": z, "lag_s": c.lag_s}
               for f, z in ((max(c.residual_peak_hz, 1.0), 0.15),
                            (min(1.0 / (2 * math.pi * max(c.lag_s, c.record.dt)) * 3.0, 0.4 / c.record.dt), 0.7))],
    lambda p: f"mode at {p['servo_frequency_hz']:.2f} Hz with damping {p['servo_damping']:.3f} after a lag of "
              f"{1e3 * p['lag_s']:.2f} ms",
    primary="servo_frequency_hz",
))

_register(Effect(
    "sensor_drift", "transducer drift",
    "the displacement transducer or its conditioning drifts slowly (temperature of the LVDT and its "
    "amplifier, a creeping zero): the measurement walks away from the actuator at a steady rate",
    lambda c: (Param("sensor_drift_mm_s", -c.stroke_mm / c.record.duration_s, c.stroke_mm / c.record.duration_s,
                     max(c.residual_rms_mm, 1e-4) / c.record.duration_s),),
    lambda c: [{"sensor_drift_mm_s": 0.0, "lag_s": c.lag_s}],
    lambda p: f"drift {1e3 * p['sensor_drift_mm_s']:.4g} um/s",
    primary="sensor_drift_mm_s",
))

_register(Effect(
    "channel_skew", "channel skew",
    "the measured displacement channel is recorded late against the command and force channels (a "
    "filtered transducer, a conditioning amplifier or DAQ channel with its own delay): the actuator "
    "moves in time with the force, only its displacement reading is late",
    lambda c: _time_offset(c, "channel_skew_s"),
    lambda c: _lag_shared(c, "channel_skew_s", (0.5,)),
    lambda p: f"displacement channel {1e3 * p['channel_skew_s']:.2f} ms late, lag {1e3 * p['lag_s']:.2f} ms",
    primary="channel_skew_s",
))

_register(Effect(
    "dead_band", "dead band",
    "the loop does not answer errors smaller than a width (servo-valve overlap, spool stiction, a "
    "controller dead zone): the actuator stops short of small commands and moves in steps",
    lambda c: _width(c, "dead_band_mm", 0.25),
    lambda c: _residual_sized(c, "dead_band_mm", (0.5, 2.0)),
    lambda p: f"no response to loop errors below {p['dead_band_mm']:.4g} mm",
    primary="dead_band_mm",
))

NAMES = tuple(EFFECTS)


def _speed(x: np.ndarray, dt: float) -> np.ndarray:
    # Differences over 5 samples: sensor quantisation makes single differences noisy.
    w = max(1, min(5, x.size // 20))
    return np.abs(x[w:] - x[:-w]) / (w * dt)


def peak_frequency(residual: np.ndarray, dt: float, lowest_hz: float = 0.5) -> float:
    """Where the residual's amplitude spectrum peaks, above ``lowest_hz`` (Hz)."""
    from scipy import signal

    fs = 1.0 / dt
    f, p = signal.welch(residual - residual.mean(), fs=fs, nperseg=int(min(residual.size, 2 ** int(np.log2(max(fs * 4, 64))))))
    keep = f >= lowest_hz
    return float(f[keep][np.argmax(p[keep])]) if keep.any() else 0.0


def context(record: ActuatorRecord, lag_s: float, residual_rms_mm: float, baseline_prediction: np.ndarray) -> Context:
    v_cmd = np.abs(record.command_velocity())
    force_peak = float(np.ptp(record.force_kN)) if record.force_kN is not None else 0.0
    # A command that moves in fewer than 0.1 % of its samples (steps) has a zero percentile: its largest speed then.
    v_cmd_peak = float(np.percentile(v_cmd, 99.9)) or float(np.max(v_cmd))
    return Context(record, lag_s, residual_rms_mm, v_cmd_peak,
                   float(np.percentile(_speed(record.measured_mm, record.dt), 99.9)),
                   float(np.percentile(_speed(baseline_prediction, record.dt), 99.9)), float(np.ptp(record.command_mm)), force_peak,
                   peak_frequency(record.measured_mm - baseline_prediction, record.dt))
