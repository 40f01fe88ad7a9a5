"""Adaptive time series (ATS) compensator (Chae, Kazemibidokhti and Ricles 2013).

The command is a linear combination of the desired displacement and its derivatives,

    x_c = a0 x_t + a1 v_t + a2 acc_t,

where a0 corrects the amplitude and a1, a2 the delay (a1 ~ tau, a2 ~ tau^2/2 for a pure delay
tau). The coefficients are identified online from the actuator's own history: over a moving
window of N samples the past commands are fitted by least squares to the measured response and
its derivatives,

    U = X_m A,   A = (X_m^T X_m)^-1 X_m^T U,   X_m = [x_m, v_m, acc_m],

re-solved every ``update`` samples and clipped to the bounds [A_min, A_max]. The measured
velocity and acceleration are central differences of the measured displacement; since these
amplify the sensor noise, x_m and the command both pass through the same low-pass filter before
the fit (a common filter leaves the linear relation U = X_m A unchanged). v_t and acc_t come from
the numerical substructure. Sums over the window are kept as running sums, so a sample costs
O(1) work and the 3 x 3 normal equations are solved by Gaussian elimination.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from hsio.rths.jit import helper, jit
from hsio.rths.stage import Stage

# layout of the parameter vector p
P_B, P_A = 0, 3  # low-pass biquad: b0 b1 b2, a1 a2 (a0 = 1)
P_DT = 5
P_N = 6  # window length, samples
P_UPDATE = 7  # samples between fits
P_LO = 8  # bounds: a0 a1 a2 lower, then upper
P_HI = 11
P_REG = 14  # ridge term on the normal equations (relative)
P_LEN = 15

# layout of the state vector s
S_A = 0  # a0 a1 a2
S_FM = 3  # filter state of x_m: z1 z2
S_FU = 5  # filter state of the command
S_YM = 7  # last three filtered x_m: y[k], y[k-1], y[k-2]
S_YU = 10  # last three filtered commands
S_U = 13  # last command
S_COUNT = 14  # samples seen
S_SUMS = 15  # running sums: XtX (9), XtU (3)
S_BUF = 27  # ring buffer of regressors: x, v, acc, u per sample


@helper
def _biquad(p, s, i, x):
    y = p[P_B] * x + s[i]
    s[i] = p[P_B + 1] * x - p[P_A] * y + s[i + 1]
    s[i + 1] = p[P_B + 2] * x - p[P_A + 1] * y
    return y


@helper
def solve3(M, b, out):
    """Gaussian elimination with partial pivoting on a 3 x 3 system (row-major M, 9 values);
    returns False when it is singular."""
    a = np.empty((3, 4))
    for i in range(3):
        for j in range(3):
            a[i, j] = M[3 * i + j]
        a[i, 3] = b[i]
    for c in range(3):
        piv = c
        for r in range(c + 1, 3):
            if abs(a[r, c]) > abs(a[piv, c]):
                piv = r
        if abs(a[piv, c]) < 1e-300:
            return False
        if piv != c:
            for j in range(4):
                t = a[c, j]
                a[c, j] = a[piv, j]
                a[piv, j] = t
        for r in range(c + 1, 3):
            f = a[r, c] / a[c, c]
            for j in range(c, 4):
                a[r, j] -= f * a[c, j]
    for i in range(2, -1, -1):
        acc = a[i, 3]
        for j in range(i + 1, 3):
            acc -= a[i, j] * out[j]
        out[i] = acc / a[i, i]
    return True


@jit
def ats_step(p, s, k, x_t, v_t, a_t, x_m):
    dt = p[P_DT]
    n_win = int(p[P_N])
    # filtered histories of the measured displacement and of the command sent last period
    ym = _biquad(p, s, S_FM, x_m)
    yu = _biquad(p, s, S_FU, s[S_U])
    s[S_YM + 2] = s[S_YM + 1]
    s[S_YM + 1] = s[S_YM]
    s[S_YM] = ym
    s[S_YU + 2] = s[S_YU + 1]
    s[S_YU + 1] = s[S_YU]
    s[S_YU] = yu
    count = int(s[S_COUNT])
    if count >= 2:
        # regressors at k-1 (central differences), target: the command of k-1, the one sent last
        # period (s[S_YU]; s[S_YU + 1] is the command of k-2)
        x = s[S_YM + 1]
        v = (s[S_YM] - s[S_YM + 2]) / (2.0 * dt)
        acc = (s[S_YM] - 2.0 * s[S_YM + 1] + s[S_YM + 2]) / (dt * dt)
        u = s[S_YU]
        slot = S_BUF + 4 * ((count - 2) % n_win)
        if count - 2 >= n_win:  # drop the sample leaving the window
            ox = s[slot]
            ov = s[slot + 1]
            oa = s[slot + 2]
            ou = s[slot + 3]
            s[S_SUMS + 0] -= ox * ox
            s[S_SUMS + 1] -= ox * ov
            s[S_SUMS + 2] -= ox * oa
            s[S_SUMS + 4] -= ov * ov
            s[S_SUMS + 5] -= ov * oa
            s[S_SUMS + 8] -= oa * oa
            s[S_SUMS + 9] -= ox * ou
            s[S_SUMS + 10] -= ov * ou
            s[S_SUMS + 11] -= oa * ou
        s[slot] = x
        s[slot + 1] = v
        s[slot + 2] = acc
        s[slot + 3] = u
        s[S_SUMS + 0] += x * x
        s[S_SUMS + 1] += x * v
        s[S_SUMS + 2] += x * acc
        s[S_SUMS + 4] += v * v
        s[S_SUMS + 5] += v * acc
        s[S_SUMS + 8] += acc * acc
        s[S_SUMS + 9] += x * u
        s[S_SUMS + 10] += v * u
        s[S_SUMS + 11] += acc * u
        filled = count - 1
        if filled >= n_win and (count % int(p[P_UPDATE])) == 0:
            M = np.empty(9)
            b = np.empty(3)
            sol = np.empty(3)
            M[0] = s[S_SUMS + 0]
            M[1] = s[S_SUMS + 1]
            M[2] = s[S_SUMS + 2]
            M[3] = M[1]
            M[4] = s[S_SUMS + 4]
            M[5] = s[S_SUMS + 5]
            M[6] = M[2]
            M[7] = M[5]
            M[8] = s[S_SUMS + 8]
            for i in range(3):
                M[4 * i] *= 1.0 + p[P_REG]
                b[i] = s[S_SUMS + 9 + i]
            if M[0] > 0.0 and solve3(M, b, sol):
                for i in range(3):
                    a = sol[i]
                    if a < p[P_LO + i]:
                        a = p[P_LO + i]
                    elif a > p[P_HI + i]:
                        a = p[P_HI + i]
                    s[S_A + i] = a
    s[S_COUNT] = count + 1
    u_cmd = s[S_A] * x_t + s[S_A + 1] * v_t + s[S_A + 2] * a_t
    s[S_U] = u_cmd
    return u_cmd


def make(fs: float, initial=(1.0, 0.025, 3.0e-4), window_s: float = 1.0, update: int = 16,
         lower=(0.8, 0.0, 0.0), upper=(1.25, 0.06, 2.0e-3), cutoff_hz: float = 20.0,
         ridge: float = 1e-9) -> Stage:
    """ATS with a ``window_s`` window re-fitted every ``update`` samples; ``initial`` are the
    coefficients used until the window first fills (a0, a1 in s, a2 in s^2). Parameters it cannot
    run on are a ValueError naming them."""
    numbers = {"window_s": window_s, "cutoff_hz": cutoff_hz, "ridge": ridge}
    for name, value in numbers.items():
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(f"ATS: {name} = {value!r} must be a number")
    n_win = int(round(window_s * fs)) if np.isfinite(window_s) else 0
    if n_win < 3:
        raise ValueError(f"ATS: window_s = {window_s!r} s holds {n_win} samples at {fs:g} Hz; the fit of "
                         "three coefficients needs at least 3")
    if isinstance(update, bool) or not isinstance(update, (int, float, np.integer, np.floating)) \
            or not np.isfinite(update) or int(update) != update or not 1 <= update <= n_win:
        raise ValueError(f"ATS: update = {update!r} must be a whole number of samples from 1 to the window's {n_win}")
    if not 0.0 < cutoff_hz < fs / 2.0:
        raise ValueError(f"ATS: cutoff_hz = {cutoff_hz!r} must lie between 0 and half the rate, {fs / 2.0:g} Hz")
    lo, hi, a_init = (np.asarray(v, dtype=float) for v in (lower, upper, initial))
    if lo.shape != (3,) or hi.shape != (3,) or a_init.shape != (3,) or not np.all(np.isfinite([lo, hi, a_init])) \
            or np.any(lo > a_init) or np.any(a_init > hi):
        raise ValueError(f"ATS: lower <= initial <= upper must hold for each of a0, a1, a2 (three finite numbers each; "
                         f"got lower {tuple(lower)}, initial {tuple(initial)}, upper {tuple(upper)})")
    if not ridge >= 0.0:
        raise ValueError(f"ATS: ridge = {ridge!r} must not be negative")
    b, a = signal.butter(2, cutoff_hz, fs=fs)
    p = np.zeros(P_LEN)
    p[P_B:P_B + 3] = b / a[0]
    p[P_A:P_A + 2] = a[1:] / a[0]
    p[P_DT] = 1.0 / fs
    p[P_N] = n_win
    p[P_UPDATE] = update
    p[P_LO:P_LO + 3] = lower
    p[P_HI:P_HI + 3] = upper
    p[P_REG] = ridge
    s0 = np.zeros(S_BUF + 4 * n_win)
    s0[S_A:S_A + 3] = initial
    return Stage("ats", ats_step, p, s0)
