"""The vRTHS benchmark's control plant as a stand-alone emulated device (SI units).

Silva et al. (2020), Table 2, Fig. 11, eqs. 21-22: servo-valve, actuator with control-structure
interaction and the first-storey specimen in the servo-controller's unity displacement loop, at
4096 Hz, behind 18-bit converters with measurement noise and an 8.9 kN force limit. One
:meth:`VrthsPlant.step` is one controller period: the command (m) is quantised and held, the
plant moves, and the measured displacement (m) and force (N) are returned as the A/D converters
read them. It is the same model, operation for operation, as the plant inside the RTHS loop of
``hsio.rths.loop`` (a test checks that both give the same samples), for use outside that loop:
a lab's controller code, a different transport, a hardware-in-the-loop rehearsal.
"""

from __future__ import annotations

import math

import numpy as np

from hsio.rths.plant import PlantParameters

FS = 4096.0


class VrthsPlant:
    def __init__(self, params: PlantParameters, noise_seed=0, fs: float = FS):
        self.params = params
        self.fs = fs
        self.Ad, self.Bd = params.discrete(fs)
        self.rng = np.random.default_rng(noise_seed)
        self.w = np.zeros(5)  # [q, q', F, x, x']

    def _adc(self, value: float, per_volt: float) -> float:
        q = self.params.quantum_V
        return math.floor((value / per_volt + self.rng.normal(0.0, self.params.noise_V)) / q + 0.5) * q * per_volt

    @property
    def displacement(self) -> float:
        """The true actuator displacement (m)."""
        return float(self.w[3])

    @property
    def force(self) -> float:
        """The true actuator force (N)."""
        return float(self.w[2])

    def measure(self) -> tuple[float, float]:
        """(x_m in m, f_m in N) as the converters read them now."""
        p = self.params
        return self._adc(self.w[3], p.m_per_V), self._adc(self.w[2], p.N_per_V)

    def step(self, command_m: float) -> tuple[float, float]:
        """One period with ``command_m`` held; returns the measurements at its end. A command that
        is not a finite number is refused (ValueError) and the plant does not move."""
        if not isinstance(command_m, (int, float, np.number)) or not math.isfinite(command_m):
            raise ValueError(f"VrthsPlant.step: the command must be a finite displacement in m, got {command_m!r}; "
                             "the plant holds its state")
        p = self.params
        u = math.floor(command_m / p.m_per_V / p.quantum_V + 0.5) * p.quantum_V * p.m_per_V
        w = self.Ad @ self.w + self.Bd * u
        w[2] = min(max(w[2], -p.max_force), p.max_force)
        self.w = w
        return self.measure()
