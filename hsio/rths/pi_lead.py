"""The benchmark's sample controller: PI plus phase lead (Silva et al. 2020).

    u = G_c(s) (G_T(s) x_t - x_m),   G_c(s) = 2 + 95/s,   G_T(s) = 50.8 (s + 168.6)/(s + 8570)

The phase-lead G_T (unit gain at DC) acts on the desired displacement; the PI closes the outer
loop on the measured displacement. Both are discretised by Tustin's rule at 4096 Hz and run as
first-order sections in transposed direct form II.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from hsio.rths.jit import jit
from hsio.rths.stage import Stage

KP, KI = 2.0, 95.0
LEAD_GAIN, LEAD_ZERO, LEAD_POLE = 50.8, 168.6, 8570.0


def first_order_tustin(num, den, fs: float) -> tuple[float, float, float]:
    """(b0, b1, a1) of a first-order continuous section by Tustin's rule."""
    b, a, _ = signal.cont2discrete((num, den), 1.0 / fs, method="bilinear")
    b = np.ravel(b)
    return float(b[0] / a[0]), float(b[1] / a[0]), float(a[1] / a[0])


@jit
def pi_lead_step(p, s, k, x_t, v_t, a_t, x_m):
    # phase lead on the desired displacement
    r = p[0] * x_t + s[0]
    s[0] = p[1] * x_t - p[2] * r
    # PI on the error
    e = r - x_m
    u = p[3] * e + s[1]
    s[1] = p[4] * e - p[5] * u
    return u


def make(fs: float) -> Stage:
    lead = first_order_tustin([LEAD_GAIN, LEAD_GAIN * LEAD_ZERO], [1.0, LEAD_POLE], fs)
    pi = first_order_tustin([KP, KI], [1.0, 0.0], fs)
    return Stage("pi-lead", pi_lead_step, np.array([*lead, *pi]), np.zeros(2))
