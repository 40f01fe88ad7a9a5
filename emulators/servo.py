"""An emulated servo-hydraulic controller for one actuator, stepped at the controller rate.

Physics per period dt = 1/rate (explicit, one tick at a time):

* Displacement control: the servo-valve opens in proportion to the loop output; the actuator
  velocity is proportional to the valve flow (velocity-proportional lag):

      v = K_p e + K_i sum(e) dt + K_p lag clip(v_c, -a, a),   e = d_c(t - t_delay) - d_rod

  with K_p = 1 / (lag + dt) because the loop sees the rod position of the previous period. A
  ramp at velocity v then lags by lag (|v| - a) beyond the feed-forward threshold a, and not at
  all below it, between a command and the measurement that follows it: the hockey stick of
  docs/method.md eq. 1 with b d_max = lag. The flow limit saturates |v|.
* Force control: the loop is closed on the load cell, v = K_f (F_c - F_m), with K_f tuned on the
  specimen's initial stiffness so that the force follows with ``force_lag_s``.
* Load train: the specimen sees the rod through a backlash gap and a compliance that shortens
  under the force it carries in the same period (d_spec = backlash(d_rod) - compliance
  F(d_spec), solved each period); the displacement transducer on the specimen reads
  gain * d_spec. Sensors add Gaussian noise and quantise to their resolution; the load cell and
  the transducer may have a finite bandwidth (first-order, ``force_bandwidth_hz``,
  ``displacement_bandwidth_hz``; 0, the default, is ideal). The force loop closes on the load
  cell's reading, so its resolution, noise and bandwidth are what force control can achieve; the
  displacement loop closes on the rod transducer (``resolution_mm``, ``noise_mm``).
  The specimen moves once a period, the move taking dt of lab time: a rate-dependent model (the
  dashpot, friction and moving mass of hsio.specimens.Diagnosed) acts at the lab's velocity.
* Further effects, off by default: a dead band (the loop ignores errors below
  ``dead_band_mm``: e' = e - clip(e, -w, w)); a second-order servo-valve or oil-column mode
  between the rod and the specimen (natural frequency ``servo_frequency_hz``, damping
  ``servo_damping``, bilinear transform of w^2 / (s^2 + 2 zeta w s + w^2)); a transducer drift
  (``sensor_drift_mm_s`` t added to the measured displacement) and a skew of the measured
  displacement channel (it reads the displacement of ``channel_skew_s`` earlier, linear
  interpolation between periods, as a filtered transducer does).
* Interlocks: a measured displacement beyond the stroke or force beyond the capacity trips the
  controller, which then holds its position and refuses commands until reset.

Every effect is off or neutral by default except the lag, the limits and the sensors.
"""

from __future__ import annotations

import collections
import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from hsio.clock import CONTROLLER_RATE_HZ
from hsio.errors import ConfigError
from hsio.interfaces import ControlMode, shown_beyond
from hsio.specimens import Specimen


SERVO_FREQUENCY_MIN_HZ = 1e-3  # a servo-valve / oil-column mode below this is a typing error (0: none)

# Hockey-stick actuators measured in the paper (docs/method.md section 4, eq. 1): velocity threshold a
# (mm/s) and slope b (s/mm) of the execution error normalised by the stroke d_max = 254 mm.
# Select one with ``preset = "structure_I"``; explicit settings override it.
PRESETS: dict[str, dict] = {
    "structure_I": {"a_mm_s": 5.18, "b_s_mm": 7.874e-5},
    "structure_II": {"a_mm_s": 0.51, "b_s_mm": 1.181e-4},
}


def hockey_stick_settings(a_mm_s: float, b_s_mm: float, d_max_mm: float = 254.0) -> dict:
    """Emulator settings whose execution error is eq. (1): d_c - d_m = b d_max (|v| - a) sign v."""
    return {"lag_s": b_s_mm * d_max_mm, "velocity_threshold_mm_s": a_mm_s}


@dataclass
class ServoConfig:
    """Parameters of the emulated controller, actuator, load train and sensors (kN, mm, s)."""

    rate_hz: float = CONTROLLER_RATE_HZ
    lag_s: float = 0.020  # displacement-loop lag when extending (b d_max of docs/method.md eq. 1)
    lag_retract_s: float | None = None  # lag when retracting (asymmetric lag); None: same
    ki_per_s2: float = 0.0  # integral gain of the displacement loop
    velocity_threshold_mm_s: float = 0.0  # a: velocity feed-forward up to this speed
    transport_delay_s: float = 0.0  # pure delay of the command inside the loop
    force_lag_s: float = 0.020  # force-loop lag on the specimen's initial stiffness
    stroke_mm: float = 254.0  # total stroke, centred on zero
    force_limit_kN: float = 250.0
    velocity_limit_mm_s: float = 500.0  # servo-valve flow limit
    backlash_mm: float = 0.0  # total slop of the load train
    compliance_mm_per_kN: float = 0.0  # load-train compliance
    displacement_gain: float = 1.0  # transducer gain (1 = exact)
    resolution_mm: float = 0.025
    noise_mm: float = 0.01  # standard deviation
    force_resolution_kN: float = 0.001
    force_noise_kN: float = 0.002
    # Sensor bandwidths (first-order low-pass before noise and quantisation; 0: ideal, today's
    # behaviour). The force loop closes on the load cell, so its bandwidth also slows that loop.
    force_bandwidth_hz: float = 0.0  # load cell
    displacement_bandwidth_hz: float = 0.0  # displacement transducer on the specimen
    seed: int = 0
    dead_band_mm: float = 0.0  # the displacement loop ignores errors smaller than this
    servo_frequency_hz: float = 0.0  # second-order servo-valve / oil-column mode (0: none)
    servo_damping: float = 0.7  # its damping ratio
    sensor_drift_mm_s: float = 0.0  # slow trend of the displacement transducer
    channel_skew_s: float = 0.0  # the measured displacement channel reads this much late

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "lag_retract_s" and value is None:
                continue
            wanted = int if f.name == "seed" else (int, float)
            if isinstance(value, bool) or not isinstance(value, wanted) or not math.isfinite(value):
                kind = "a whole number" if f.name == "seed" else "a finite number"
                raise ConfigError(f"emulator: {f.name} must be {kind}, got {value!r}")
        positive = ("rate_hz", "lag_s", "force_lag_s", "stroke_mm", "force_limit_kN", "velocity_limit_mm_s")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"emulator: {name} must be positive, got {getattr(self, name)!r}")
        non_negative = ("ki_per_s2", "velocity_threshold_mm_s", "transport_delay_s", "backlash_mm",
                        "compliance_mm_per_kN", "resolution_mm", "noise_mm", "force_resolution_kN", "force_noise_kN",
                        "dead_band_mm", "servo_frequency_hz", "servo_damping", "channel_skew_s",
                        "force_bandwidth_hz", "displacement_bandwidth_hz")
        for name in non_negative:
            if not getattr(self, name) >= 0:
                raise ConfigError(f"emulator: {name} must be zero or positive, got {getattr(self, name)!r}")
        instruments = {"resolution_mm": (10.0, "mm"), "noise_mm": (10.0, "mm"), "force_resolution_kN": (100.0, "kN"),
                       "force_noise_kN": (100.0, "kN"), "force_bandwidth_hz": (self.rate_hz / 2, "Hz"),
                       "displacement_bandwidth_hz": (self.rate_hz / 2, "Hz")}  # bandwidths up to Nyquist
        for name, (high, unit) in instruments.items():
            if not getattr(self, name) <= high:
                raise ConfigError(f"emulator: {name} = {getattr(self, name)!r} is out of bounds: it must be "
                                  f"within 0..{high:g} {unit}")
        if self.lag_retract_s is not None and not self.lag_retract_s > 0:
            raise ConfigError(f"emulator: lag_retract_s must be positive, got {self.lag_retract_s!r}")
        # Sanity bounds (docs/faults.md): beyond them the emulator would overflow its buffers, step
        # a different clock from the host's or stand for no actuator; the limits match [driver]'s.
        sanity = {"seed": (0, 2**32 - 1, ""), "rate_hz": (10.0, 100000.0, "Hz"), "lag_s": (0.0, 3600.0, "s"),
                  "lag_retract_s": (0.0, 3600.0, "s"), "force_lag_s": (0.0, 3600.0, "s"),
                  "transport_delay_s": (0.0, 3600.0, "s"), "channel_skew_s": (0.0, 3600.0, "s"),
                  "stroke_mm": (0.0, 10000.0, "mm"), "force_limit_kN": (0.0, 100000.0, "kN"),
                  "velocity_limit_mm_s": (0.0, 10000.0, "mm/s"), "backlash_mm": (0.0, self.stroke_mm, "mm"),
                  "dead_band_mm": (0.0, self.stroke_mm, "mm"), "servo_frequency_hz": (0.0, self.rate_hz / 2, "Hz"),
                  "displacement_gain": (-10.0, 10.0, ""),
                  "ki_per_s2": (0.0, self.rate_hz * self.rate_hz, "1/s^2"),  # ki dt^2 <= 1: the discrete PI loop stays stable
                  "compliance_mm_per_kN": (0.0, 1000.0, "mm/kN")}
        for name, (low, high, unit) in sanity.items():
            value = getattr(self, name)
            if value is not None and not low <= value <= high:
                raise ConfigError(f"emulator: {name} = {value!r} is out of bounds: it must be within "
                                  f"{low:g}..{high:g}{' ' + unit if unit else ''}")
        if self.displacement_gain == 0:
            raise ConfigError("emulator: displacement_gain must not be 0 (the transducer would read nothing)")
        if 0 < self.servo_frequency_hz < SERVO_FREQUENCY_MIN_HZ:
            raise ConfigError(f"emulator: servo_frequency_hz = {self.servo_frequency_hz!r} is out of bounds: 0 (no "
                              f"servo mode) or within {SERVO_FREQUENCY_MIN_HZ:g}..{self.rate_hz / 2:g} Hz")

    @classmethod
    def from_dict(cls, table: dict) -> "ServoConfig":
        table = dict(table)
        preset = table.pop("preset", None)
        if preset is not None:
            if not isinstance(preset, str) or preset not in PRESETS:
                raise ConfigError(f"emulator: unknown preset {preset!r}; known: {', '.join(PRESETS)}")
            table = {**hockey_stick_settings(**PRESETS[preset]), **table}
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ConfigError(f"emulator: unknown setting(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
        return cls(**table)

    def to_dict(self) -> dict:
        return asdict(self)


def parse_value(text: str):
    """A setting given as text (a URL query, ``--set KEY=VALUE``): a number where it reads as one."""
    if text.lower() in ("none", "null"):
        return None
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def make_controllers(elements, table: dict) -> list["ServoController"]:
    """One controller per experimental element, with the [emulator] settings ``table`` and its
    own noise seed (seed + index): the same controllers in process and behind any protocol."""
    from hsio.specimens import make_specimen

    controllers = []
    for index, element in enumerate(elements):
        config = ServoConfig.from_dict({**table, "seed": table.get("seed", 0)})
        config.seed += index
        controllers.append(ServoController(make_specimen(element.specimen), config))
    return controllers


def servo_mode_filter(frequency_hz: float, damping: float, rate_hz: float) -> tuple[list, list]:
    """(b, a) of the mode w^2 / (s^2 + 2 zeta w s + w^2) by the bilinear transform at rate_hz."""
    from scipy import signal

    w = 2 * math.pi * frequency_hz
    b, a = signal.bilinear([w * w], [1.0, 2 * damping * w, w * w], fs=rate_hz)
    return [float(v) for v in b], [float(v) for v in a]


def quantise(value: float, resolution: float) -> float:
    """``value`` to the nearest multiple of ``resolution`` (0: as it is; so is a resolution so fine
    that ``value`` counts more steps of it than a float holds: finer than the number itself)."""
    steps = value / resolution if resolution > 0 else math.inf
    return round(steps) * resolution if math.isfinite(steps) else value


class ServoController:
    """One emulated controller channel with its actuator and specimen.

    :meth:`step` advances one controller period. Commands and reads go through
    :meth:`set_command`, :meth:`set_mode`, :meth:`hold`; measurements are attributes.
    """

    NOISE_BLOCK = 4096

    def __init__(self, specimen: Specimen, config: ServoConfig | None = None):
        self.config = config or ServoConfig()
        self.specimen = specimen
        c = self.config
        self.dt = 1.0 / c.rate_hz
        # The loop sees the position of the previous period, so K_p = 1 / (lag + dt) makes a ramp
        # lag by exactly lag_s between a command and the measurement that follows it.
        # The feed-forward is scaled alike so that the ramp error is lag (|v| - a) beyond a.
        self.kp_extend = 1.0 / (c.lag_s + self.dt)
        self.kp_retract = 1.0 / ((c.lag_retract_s or c.lag_s) + self.dt)
        self.ff_extend = c.lag_s * self.kp_extend
        self.ff_retract = (c.lag_retract_s or c.lag_s) * self.kp_retract
        self.kf = 1.0 / (c.force_lag_s * max(specimen.initial_stiffness, 1e-9))
        self._rng = np.random.default_rng(c.seed)
        self._delay = collections.deque(maxlen=max(int(round(c.transport_delay_s * c.rate_hz)), 0) + 1)
        self._mode = servo_mode_filter(c.servo_frequency_hz, c.servo_damping, c.rate_hz) if c.servo_frequency_hz > 0 else None
        skew = c.channel_skew_s * c.rate_hz
        self._skew_frac = skew - math.floor(skew)
        self._skew = collections.deque(maxlen=int(math.floor(skew)) + 2)
        self.reset()

    def reset(self) -> None:
        """Back to rest at zero, in displacement control, interlocks cleared."""
        self.specimen.revert_to_start()
        self.mode = ControlMode.DISPLACEMENT
        self.command = 0.0
        self.ticks = 0
        self.d_rod = 0.0
        self.d_spec = 0.0
        self.force = 0.0  # true specimen force
        self._integral = 0.0
        self._last_loop_cmd = 0.0
        self._d_engaged = 0.0  # where the specimen side of the backlash gap stands
        self._delay.clear()
        self._mode_state = [0.0, 0.0]
        self._skew.clear()
        self.tripped = ""
        self.holding = False
        self._noise_d = np.empty(0)
        self._noise_f = np.empty(0)
        self._noise_i = 0
        self._sensed_d = 0.0  # sensor outputs before noise (low-passed when a bandwidth is set)
        self._sensed_f = 0.0
        self.measured_displacement = 0.0
        self.measured_force = 0.0
        self._measure()

    @property
    def time_s(self) -> float:
        return self.ticks * self.dt

    # -- commands ---------------------------------------------------------------------------
    def set_command(self, value: float) -> None:
        if self.tripped:
            return
        self.holding = False
        self.command = float(value)

    def set_mode(self, mode: ControlMode) -> None:
        """Switch bumplessly: the command starts from the present measurement."""
        if mode is self.mode:
            return
        self.mode = mode
        self.command = self.measured_force if mode is ControlMode.FORCE else self.measured_displacement
        self._delay.clear()
        self._last_loop_cmd = self.command
        self._integral = 0.0

    def hold(self) -> None:
        """Hold the present rod position in displacement control."""
        self.mode = ControlMode.DISPLACEMENT
        self.command = self.d_rod
        self._delay.clear()
        self._last_loop_cmd = self.d_rod
        self._integral = 0.0
        self.holding = True

    def clear_trip(self) -> None:
        self.tripped = ""

    # -- physics ------------------------------------------------------------------------------
    def advance(self, ticks: int) -> None:
        for _ in range(ticks):
            self.step()

    def step(self) -> None:
        """One controller period."""
        c = self.config
        dt = self.dt
        self._delay.append(self.command)
        loop_cmd = self._delay[0]
        if self.mode is ControlMode.DISPLACEMENT:
            error = loop_cmd - self._rod_feedback
            w = c.dead_band_mm
            if w > 0.0:
                error = 0.0 if -w <= error <= w else error - math.copysign(w, error)
            self._integral += error * dt
            kp = self.kp_extend if error >= 0.0 else self.kp_retract
            v_cmd = (loop_cmd - self._last_loop_cmd) / dt
            a = c.velocity_threshold_mm_s
            v_ff = v_cmd if v_cmd <= a and v_cmd >= -a else math.copysign(a, v_cmd)
            v_ff *= self.ff_extend if v_cmd >= 0.0 else self.ff_retract
            velocity = kp * error + c.ki_per_s2 * self._integral + v_ff
        else:
            velocity = self.kf * (loop_cmd - self.measured_force)
        self._last_loop_cmd = loop_cmd
        vmax = c.velocity_limit_mm_s
        if velocity > vmax:
            velocity = vmax
        elif velocity < -vmax:
            velocity = -vmax
        self.d_rod += velocity * dt
        self._load_train()
        self.ticks += 1
        self._measure()
        self._check_interlocks()

    def _load_train(self) -> None:
        c = self.config
        d = self.d_rod
        if self._mode is not None:
            # Direct form II transposed of the mode's discrete filter (b, a).
            b, a = self._mode
            z = self._mode_state
            y = b[0] * d + z[0]
            z[0] = b[1] * d - a[1] * y + z[1]
            z[1] = b[2] * d - a[2] * y
            d = y
        if c.backlash_mm > 0.0:
            # The rod moves freely inside the gap; the specimen follows once the gap is taken up.
            half = 0.5 * c.backlash_mm
            if d - self._d_engaged > half:
                self._d_engaged = d - half
            elif d - self._d_engaged < -half:
                self._d_engaged = d + half
            d = self._d_engaged
        if c.compliance_mm_per_kN > 0.0:
            self.d_spec, self.force = self._behind_compliance(d)
        else:
            self.d_spec = d
            self.force = self.specimen.force(d, self.dt)

    COMPLIANCE_ITERATIONS = 20  # bounds the solve of d = x - c F(d) in a period
    COMPLIANCE_TOLERANCE_MM = 1e-10

    def _behind_compliance(self, x: float) -> tuple[float, float]:
        """Where the specimen stands behind a compliant load train whose rod end is at ``x``, and
        its force: the train shortens elastically under the force it carries now, d = x - c F(d).
        Solved by Newton steps on d + c F(d) = x, the slope 1 + c k from the specimen's initial
        stiffness, then from the secant of the last two trials: one step lands exactly on a linear
        spring (d = x / (1 + c k)); a nonlinear one takes a few. The last trial is committed to the
        specimen: the solution within COMPLIANCE_TOLERANCE_MM, or, on a branch where the steps do
        not converge (a snap at a crack), where COMPLIANCE_ITERATIONS steps left it."""
        cf = self.config.compliance_mm_per_kN
        specimen = self.specimen
        slope = 1.0 + cf * max(specimen.initial_stiffness, 0.0)
        d = x - cf * self.force  # the start: the force of the period before
        force = specimen.trial(d, self.dt)
        for _ in range(self.COMPLIANCE_ITERATIONS):
            residual = d + cf * force - x
            if abs(residual) <= self.COMPLIANCE_TOLERANCE_MM:
                break
            d_next = d - residual / slope
            f_next = specimen.trial(d_next, self.dt)
            if d_next != d:
                secant = 1.0 + cf * (f_next - force) / (d_next - d)
                if secant > 0.0:
                    slope = secant
            d, force = d_next, f_next
        specimen.commit()  # the last trial
        return d, force

    def _next_noise(self) -> tuple[float, float]:
        if self._noise_i >= self._noise_d.size:
            c = self.config
            self._noise_d = self._rng.normal(0.0, c.noise_mm, self.NOISE_BLOCK) if c.noise_mm > 0 else np.zeros(self.NOISE_BLOCK)
            self._noise_f = self._rng.normal(0.0, c.force_noise_kN, self.NOISE_BLOCK) if c.force_noise_kN > 0 else np.zeros(self.NOISE_BLOCK)
            self._noise_i = 0
        i = self._noise_i
        self._noise_i += 1
        return float(self._noise_d[i]), float(self._noise_f[i])

    def _sense(self, previous: float, value: float, bandwidth_hz: float) -> float:
        if bandwidth_hz <= 0.0:
            return value
        return previous + (1.0 - math.exp(-2.0 * math.pi * bandwidth_hz * self.dt)) * (value - previous)

    def _measure(self) -> None:
        c = self.config
        nd, nf = self._next_noise()
        shown = c.displacement_gain * self.d_spec
        if c.channel_skew_s > 0.0:
            self._skew.append(shown)
            older = self._skew[0]
            newer = self._skew[1] if len(self._skew) > 1 else older
            if len(self._skew) < self._skew.maxlen:  # before the record reaches back that far: at rest
                older = newer = self._skew[0]
            shown = (1.0 - self._skew_frac) * newer + self._skew_frac * older
        if c.sensor_drift_mm_s != 0.0:
            shown += c.sensor_drift_mm_s * self.time_s
        self._sensed_d = self._sense(self._sensed_d, shown, c.displacement_bandwidth_hz)
        self._sensed_f = self._sense(self._sensed_f, self.force, c.force_bandwidth_hz)
        self.measured_displacement = quantise(self._sensed_d + nd, c.resolution_mm)
        self.measured_force = quantise(self._sensed_f + nf, c.force_resolution_kN)
        # The loop is closed on the rod's own transducer (same sensor quality).
        self._rod_feedback = quantise(self.d_rod + nd, c.resolution_mm)

    def _check_interlocks(self) -> None:
        if self.tripped:
            return
        c = self.config
        if abs(self.measured_displacement) > 0.5 * c.stroke_mm:
            shown, limit = shown_beyond(self.measured_displacement, 0.5 * c.stroke_mm)
            self.tripped = f"displacement {shown} mm beyond the stroke (+/-{limit} mm)"
        elif abs(self.measured_force) > c.force_limit_kN:
            shown, limit = shown_beyond(self.measured_force, c.force_limit_kN)
            self.tripped = f"force {shown} kN beyond the capacity (+/-{limit} kN)"
        if self.tripped:
            self.hold()
