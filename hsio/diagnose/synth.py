"""Records from the emulator: a command history driven through hsio.emulators.servo.ServoController.

Used by the tests (effects hidden in the emulator, to be found again) and by the benchmark.
The controller runs at its own rate; at each sample the command is set, the controller steps
one period and the measurement is read, as hsio's control loop does.
"""

from __future__ import annotations

import math

import numpy as np

from hsio.diagnose.record import ActuatorRecord
from hsio.ground_motion import synthetic_record
from hsio.specimens import PinchedWood, Specimen


def seismic_command(duration_s: float, rate_hz: float, peak_mm: float = 20.0, f_n_hz: float = 1.5,
                    zeta: float = 0.05, seed: int = 7) -> np.ndarray:
    """The displacement response of an SDOF structure (f_n, zeta) to a synthetic ground motion
    (hsio.ground_motion.synthetic_record), scaled to ``peak_mm``, with a short rest at the start."""
    from scipy import signal

    dt = 1.0 / rate_hz
    ground = synthetic_record(duration_s=duration_s, dt=dt, pga_g=0.3, seed=seed)
    w = 2 * math.pi * f_n_hz
    # u'' + 2 zeta w u' + w^2 u = -a_g: relative displacement, bilinear discretisation.
    b, a = signal.bilinear([-1.0], [1.0, 2 * zeta * w, w * w], fs=rate_hz)
    u = signal.lfilter(b, a, ground.accel_g)
    u *= peak_mm / np.max(np.abs(u))
    return u[: int(round(duration_s * rate_hz))]


def chirp_command(duration_s: float, rate_hz: float, amplitude_mm: float = 5.0, f0_hz: float = 0.2,
                  f1_hz: float = 4.0, rest_s: float = 0.5) -> np.ndarray:
    """A linear sine sweep from f0 to f1 with a cosine ramp in and out and a rest at each end."""
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    sweep = max(duration_s - 2 * rest_s, 1e-9)
    ts = np.clip(t - rest_s, 0.0, sweep)
    phase = 2 * math.pi * (f0_hz * ts + 0.5 * (f1_hz - f0_hz) * ts**2 / sweep)
    ramp = np.clip(np.minimum(ts, sweep - ts) / min(1.0, 0.1 * sweep), 0.0, 1.0)
    envelope = 0.5 - 0.5 * np.cos(math.pi * ramp)
    return amplitude_mm * envelope * np.sin(phase)


def default_specimen() -> Specimen:
    """A pinched, hysteretic wood wall: its force is not a function of the displacement alone."""
    return PinchedWood(k0=2.0, F0=20.0)


def emulate(command: np.ndarray, config=None, specimen: Specimen | None = None, source: str = "emulator") -> ActuatorRecord:
    """Drive a ServoController with ``command`` (one value per controller period) and record it."""
    from hsio.emulators.servo import ServoConfig, ServoController

    config = config or ServoConfig()
    controller = ServoController(specimen or default_specimen(), config)
    n = len(command)
    measured = np.empty(n)
    force = np.empty(n)
    for k, value in enumerate(np.asarray(command, dtype=float).tolist()):
        controller.set_command(value)
        controller.step()
        measured[k] = controller.measured_displacement
        force[k] = controller.measured_force
    if controller.tripped:
        raise RuntimeError(f"emulator tripped: {controller.tripped}")
    return ActuatorRecord(source, 1.0 / config.rate_hz, np.asarray(command, dtype=float), measured, force)


def emulate_specimen(specimen: Specimen, displacement_mm: np.ndarray, rate_hz: float, noise_mm: float = 0.005,
                     resolution_mm: float = 0.01, force_noise_kN: float = 0.01, force_resolution_kN: float = 0.005,
                     skew_s: float = 0.0, seed: int = 0, source: str = "emulated specimen"):
    """A specimen record: ``specimen`` driven along ``displacement_mm`` (one value per sample, the
    move taking 1 / rate_hz), both channels with Gaussian noise and quantised; ``skew_s`` records
    the force that much late (linear interpolation)."""
    from hsio.diagnose.model import delayed
    from hsio.diagnose.specimen_record import SpecimenRecord

    dt = 1.0 / rate_hz
    u = np.asarray(displacement_mm, dtype=float)
    specimen.revert_to_start()
    force = np.array([specimen.force(x, dt) for x in u.tolist()])
    if skew_s > 0:
        force = delayed(force, skew_s / dt)
    rng = np.random.default_rng(seed)

    def sensor(x, noise, step):
        x = x + rng.normal(0.0, noise, x.size) if noise > 0 else x
        return np.round(x / step) * step if step > 0 else x

    return SpecimenRecord(source, dt, sensor(u, noise_mm, resolution_mm), sensor(force, force_noise_kN, force_resolution_kN))
