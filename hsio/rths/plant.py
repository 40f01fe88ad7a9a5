"""The benchmark's control plant as an emulator model (Silva et al. 2020, Table 2, Fig. 11).

Servo-valve, actuator with control-structure interaction (CSI) and specimen, in an inner loop of
unity displacement feedback (the servo-controller), eqs. 21-22:

    q'' + b1 q' + b2 q = a1b0 (g u - x)          servo-valve (g: input gain of the D/A stage)
    F'  + a3 F        = q - a2 x'                actuator; a2 x' is the CSI velocity feedback
    m_e x'' + c_e x' + k_e x = F                 specimen (the experimental substructure)

so that x/(g u - x) = a1b0 / ((s^2 + b1 s + b2)((s + a3)(m_e s^2 + c_e s + k_e) + a2 s)).

States w = [q, q', F, x, x'] are discretised exactly (zero-order hold) at 4096 Hz; the actuator
force saturates at 8.9 kN. Converters: the command and both measurements pass through 18-bit
quantisers (span +-3.8 V; 7.89 mm/V for displacement, 1096 N/V for force) and the measurements
carry white noise of 0.002 V RMS. The uncertain parameters a3, b1, b2 and k_e are Gaussian about
their nominal values with the standard deviations of Table 2; a perturbed plant draws them from
a seeded generator (a draw with a non-positive value is drawn again; a parameter that MAX_DRAWS
draws leave non-positive is a ValueError).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import signal

UNCERTAIN = ("a3", "b1", "b2", "ke")
MAX_DRAWS = 1000  # draws of one uncertain parameter before its distribution is taken to give no positive value


@dataclass(frozen=True)
class PlantParameters:
    a1b0: float
    a2: float
    a3: float
    b1: float
    b2: float
    me: float
    ce: float
    ke: float
    input_gain: float
    max_force: float  # N
    m_per_V: float  # displacement sensor and command scale
    N_per_V: float  # load cell scale
    quantum_V: float  # converter resolution, V
    noise_V: float  # measurement noise, V RMS

    def continuous(self) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) of w' = A w + B u, w = [q, q', F, x, x']."""
        p = self
        A = np.array([
            [0.0, 1.0, 0.0, 0.0, 0.0],
            [-p.b2, -p.b1, 0.0, -p.a1b0, 0.0],
            [1.0, 0.0, -p.a3, 0.0, -p.a2],
            [0.0, 0.0, 0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0 / p.me, -p.ke / p.me, -p.ce / p.me],
        ])
        B = np.array([[0.0], [p.a1b0 * p.input_gain], [0.0], [0.0], [0.0]])
        return A, B

    def discrete(self, fs: float) -> tuple[np.ndarray, np.ndarray]:
        A, B = self.continuous()
        Ad, Bd, *_ = signal.cont2discrete((A, B, np.eye(5), np.zeros((5, 1))), 1.0 / fs, method="zoh")
        return np.ascontiguousarray(Ad), np.ascontiguousarray(Bd[:, 0])


def nominal(bm_data: dict) -> PlantParameters:
    p, ex, c = bm_data["plant"], bm_data["experimental_substructure"], bm_data["constraints"]
    return PlantParameters(
        a1b0=float(p["a1b0"]), a2=float(p["a2"]), a3=float(p["a3"]), b1=float(p["b1"]), b2=float(p["b2"]),
        me=float(ex["me_kg"]), ce=float(ex["ce_kg_s"]), ke=float(ex["ke_N_m"]), input_gain=float(p["input_gain"]),
        max_force=float(c["max_force_N"]), m_per_V=float(c["mm_per_V"]) * 1e-3, N_per_V=float(c["N_per_V"]),
        quantum_V=2.0 * float(c["adc_span_V"]) / 2.0 ** int(c["adc_dac_bits"]), noise_V=float(c["noise_rms_V"]))


def perturbed(bm_data: dict, seed: int, count: int) -> list[PlantParameters]:
    """``count`` plants with a3, b1, b2, k_e drawn from N(nominal, std of Table 2); plant k of a
    seed is the same whatever ``count`` is."""
    nom = nominal(bm_data)
    std = bm_data["plant"]["std"]
    rng = np.random.default_rng(seed)
    plants = []
    for _ in range(count):
        values = {}
        for name in UNCERTAIN:
            for _attempt in range(MAX_DRAWS):
                v = rng.normal(getattr(nom, name), float(std[name]))
                if v > 0.0:
                    break
            else:
                raise ValueError(f"plant.{name} = {getattr(nom, name):g} with plant.std.{name} = {float(std[name]):g}: "
                                 f"{MAX_DRAWS} draws gave no positive value; a perturbed plant draws it positive")
            values[name] = float(v)
        plants.append(replace(nom, **values))
    return plants
