"""hsio's adaptive model-based compensator (AMB): the inverse of the identified control plant as a
feed-forward of the desired motion, adapted online to the plant actually in the loop.

The benchmark's control plant is all-pole (Silva et al. 2020, eqs. 21-22): x/u = G(s) = n0/d(s)
with d of degree 5, so its inverse is a polynomial in s, and a truncation to order 3,

    u = theta0 x_t + theta1 v_t + theta2 acc_t + theta3 jerk_t,                         (1)

inverts it over the band of the structure (the 4th and 5th order terms are below 1 % up to
10 Hz). x_t, v_t and acc_t come from the numerical substructure's state, so they are exact and
not differentiated from noisy measurements; jerk_t is the backward difference of acc_t, low-pass
filtered. The initial theta is the least-squares fit, over 0.1-25 Hz, of

    G_d(e^{j w T}) P(j w) = e^{j w delta}                                                (2)

with G_d the plant model discretised at the controller rate (zero-order hold, the measurement
one period after the command), P the compensator (1) with its discrete jerk, and delta an
optional lead (0: track x_t itself).

Adaptation is filtered-x normalised least mean squares on the tracking error e = x_t - x_m:
each regressor phi_i of (1), scaled by tau^i (tau = 25 ms, the plant's delay, so that the four
are of one size), is passed through the plant model, psi_i = G_d phi_i, and

    theta_i <- theta_i + mu e psi_i / (eps + psi^T psi),                                  (3)

clipped to bounds about the initial values. A plant that differs from the model (the perturbed
plants of the benchmark) is thereby inverted as it is. The command carries no feedback of the
raw measurement at the controller rate (which would inject the sensor noise into the actuator);
an optional integral term on e removes any slow drift.
"""

from __future__ import annotations

import numpy as np

from hsio.rths.jit import jit
from hsio.rths.stage import Stage

TAU = 0.025  # s, scale of the regressors (the plant's low-frequency delay)
NR = 4  # regressors: x, v, acc, jerk

# p layout
P_SCALE = 0  # tau^i, i = 0..3
P_AD = 4  # 25: plant model, row-major
P_BD = 29  # 5
P_MU = 34
P_EPS = 35
P_FS = 36
P_LO = 37  # 4 bounds on scaled theta
P_HI = 41
P_JA = 45  # jerk low-pass: y += alpha (x - y)
P_KI = 46  # integral gain on e (1/s), times dt inside
P_ADAPT_FROM = 47  # first sample at which adaptation runs
P_LEN = 48

# s layout
S_TH = 0  # scaled theta (4)
S_W = 4  # model states of the 4 filtered regressors (4 x 5)
S_APREV = 24
S_JERK = 25
S_INT = 26
S_LEN = 27


@jit
def amb_step(p, s, k, x_t, v_t, a_t, x_m):
    fs = p[P_FS]
    # jerk of the desired motion: backward difference of acc_t, low-passed
    if k == 0:
        s[S_APREV] = a_t
    j_raw = (a_t - s[S_APREV]) * fs
    s[S_APREV] = a_t
    s[S_JERK] += p[P_JA] * (j_raw - s[S_JERK])
    phi0 = x_t * p[P_SCALE]
    phi1 = v_t * p[P_SCALE + 1]
    phi2 = a_t * p[P_SCALE + 2]
    phi3 = s[S_JERK] * p[P_SCALE + 3]
    # the filtered regressors psi_i = G_d phi_i at this sample (model output: displacement w[3])
    e = x_t - x_m
    if k >= p[P_ADAPT_FROM]:
        norm = p[P_EPS]
        for i in range(NR):
            psi = s[S_W + 5 * i + 3]
            norm += psi * psi
        g = p[P_MU] * e / norm
        for i in range(NR):
            th = s[S_TH + i] + g * s[S_W + 5 * i + 3]
            if th < p[P_LO + i]:
                th = p[P_LO + i]
            elif th > p[P_HI + i]:
                th = p[P_HI + i]
            s[S_TH + i] = th
    s[S_INT] += p[P_KI] * e / fs
    # advance the four model copies with this sample's regressors (the model's coefficients in
    # locals once per sample: the pure-Python loop reads each only once)
    a00, a01, a02, a03, a04 = p[P_AD], p[P_AD + 1], p[P_AD + 2], p[P_AD + 3], p[P_AD + 4]
    a10, a11, a12, a13, a14 = p[P_AD + 5], p[P_AD + 6], p[P_AD + 7], p[P_AD + 8], p[P_AD + 9]
    a20, a21, a22, a23, a24 = p[P_AD + 10], p[P_AD + 11], p[P_AD + 12], p[P_AD + 13], p[P_AD + 14]
    a30, a31, a32, a33, a34 = p[P_AD + 15], p[P_AD + 16], p[P_AD + 17], p[P_AD + 18], p[P_AD + 19]
    a40, a41, a42, a43, a44 = p[P_AD + 20], p[P_AD + 21], p[P_AD + 22], p[P_AD + 23], p[P_AD + 24]
    b0, b1, b2, b3, b4 = p[P_BD], p[P_BD + 1], p[P_BD + 2], p[P_BD + 3], p[P_BD + 4]
    for i in range(NR):
        if i == 0:
            ph = phi0
        elif i == 1:
            ph = phi1
        elif i == 2:
            ph = phi2
        else:
            ph = phi3
        base = S_W + 5 * i
        w0 = s[base]
        w1 = s[base + 1]
        w2 = s[base + 2]
        w3 = s[base + 3]
        w4 = s[base + 4]
        s[base] = a00 * w0 + a01 * w1 + a02 * w2 + a03 * w3 + a04 * w4 + b0 * ph
        s[base + 1] = a10 * w0 + a11 * w1 + a12 * w2 + a13 * w3 + a14 * w4 + b1 * ph
        s[base + 2] = a20 * w0 + a21 * w1 + a22 * w2 + a23 * w3 + a24 * w4 + b2 * ph
        s[base + 3] = a30 * w0 + a31 * w1 + a32 * w2 + a33 * w3 + a34 * w4 + b3 * ph
        s[base + 4] = a40 * w0 + a41 * w1 + a42 * w2 + a43 * w3 + a44 * w4 + b4 * ph
    return (s[S_TH] * phi0 + s[S_TH + 1] * phi1 + s[S_TH + 2] * phi2 + s[S_TH + 3] * phi3) + s[S_INT]


def _jerk_response(z, fs, alpha):
    """Discrete jerk from acc: low-pass(alpha) of the backward difference, as a factor on acc."""
    return (1.0 - 1.0 / z) * fs * alpha / (1.0 - (1.0 - alpha) / z)


def initial_theta(plant, fs: float, delta: float = 0.0, alpha: float = 0.2, f_max: float = 25.0) -> np.ndarray:
    """The least-squares inverse (2) of the plant model, as unscaled theta (4)."""
    Ad, Bd = plant.discrete(fs)
    f = np.linspace(0.1, f_max, 400)
    w = 2 * np.pi * f
    z = np.exp(1j * w / fs)
    Gd = np.array([(np.linalg.solve(zi * np.eye(5) - Ad, Bd))[3] for zi in z])
    s = 1j * w
    cols = np.stack([np.ones_like(s), s, s ** 2, s ** 2 * _jerk_response(z, fs, alpha)], axis=1)
    A = Gd[:, None] * cols
    target = np.exp(1j * w * delta)
    weight = 1.0 / (1.0 + (f / 10.0) ** 2)  # the structure's band first
    Ar = np.vstack([(A * weight[:, None]).real, (A * weight[:, None]).imag])
    br = np.concatenate([(target * weight).real, (target * weight).imag])
    scale = TAU ** np.arange(NR)
    th_scaled, *_ = np.linalg.lstsq(Ar * scale, br, rcond=None)
    return th_scaled * scale


def make(fs: float, plant, delta: float = 0.0, mu: float = 2e-3, ki: float = 0.0, bound: float = 0.5,
         jerk_alpha: float = 0.2, adapt_from_s: float = 0.5) -> Stage:
    """AMB on the model ``plant`` (PlantParameters, normally the nominal plant of Table 2).
    Parameters it cannot run on are a ValueError naming them."""
    for name, value, ok, what in (("delta", delta, lambda v: v >= 0.0, "not negative (s)"),
                                  ("mu", mu, lambda v: 0.0 < v < 2.0, "between 0 and 2 (the step of NLMS, eq. 3)"),
                                  ("ki", ki, lambda v: v >= 0.0, "not negative"),
                                  ("bound", bound, lambda v: v >= 0.0, "not negative"),
                                  ("jerk_alpha", jerk_alpha, lambda v: 0.0 < v <= 1.0, "in (0, 1]"),
                                  ("adapt_from_s", adapt_from_s, lambda v: v >= 0.0, "not negative (s)")):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not (np.isfinite(value) and ok(value)):
            raise ValueError(f"AMB: {name} = {value!r} must be a finite number, {what}")
    Ad, Bd = plant.discrete(fs)
    scale = TAU ** np.arange(NR)
    th0 = initial_theta(plant, fs, delta, jerk_alpha) / scale
    p = np.zeros(P_LEN)
    p[P_SCALE:P_SCALE + NR] = scale
    p[P_AD:P_AD + 25] = Ad.ravel()
    p[P_BD:P_BD + 5] = Bd
    p[P_MU] = mu
    p[P_EPS] = 1e-12
    p[P_FS] = fs
    p[P_LO:P_LO + NR] = th0 - bound * np.maximum(np.abs(th0), 0.05)
    p[P_HI:P_HI + NR] = th0 + bound * np.maximum(np.abs(th0), 0.05)
    p[P_JA] = jerk_alpha
    p[P_KI] = ki
    p[P_ADAPT_FROM] = adapt_from_s * fs
    s0 = np.zeros(S_LEN)
    s0[S_TH:S_TH + NR] = th0
    return Stage("amb", amb_step, p, s0)
