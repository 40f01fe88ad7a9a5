"""The RTHS loop at the controller rate (Silva et al. 2020): numerical substructure,
tracking controller, control plant, converters, restoring force back to the numerical model.

Sample k: the numerical substructure gives x_t, v_t, a_t; the controller turns them and the
measured x_m into the command u, which the D/A converter quantises and holds for one period; the
plant moves; the A/D converters sample displacement and force with their noise. The restoring
force reaches the numerical substructure one period after it is sampled (the force channel's
transfer latency): over period k the numerical model is loaded by a_g[k] and f_m[k-1], both held.
With this latency the loop reproduces the benchmark's Table 3 for the sample controller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hsio.rths.jit import jit, pick


@jit
def rths_kernel(step, p, s, Ap, Bp, max_force, An, Bn, Ca, Da, ag, noise_x, noise_f,
                quantum, m_per_V, N_per_V, out_xt, out_xm, out_floors, out_u, out_f, out_x, w, w1, z, z1):
    # arrays under numba; lists in the pure-Python loop (element access is several times faster)
    n = len(ag)
    x_m = math.floor(noise_x[0] / quantum + 0.5) * quantum * m_per_V
    f_m = math.floor(noise_f[0] / quantum + 0.5) * quantum * N_per_V
    f_prev = f_m
    for k in range(n):
        x_t = z[0]
        v_t = z[3]
        a_t = (Da[0] * ag[k] + Da[1] * f_m + Ca[0] * z[0] + Ca[1] * z[1] + Ca[2] * z[2]
               + Ca[3] * z[3] + Ca[4] * z[4] + Ca[5] * z[5])
        out_xt[k] = x_t
        out_xm[k] = x_m
        out_floors[k][0] = x_m
        out_floors[k][1] = z[1]
        out_floors[k][2] = z[2]
        u = step(p, s, k, x_t, v_t, a_t, x_m)
        if not math.isfinite(u):  # nothing reaches the D/A converter: the run stops at this sample
            return k
        u = math.floor(u / m_per_V / quantum + 0.5) * quantum * m_per_V
        out_u[k] = u
        # the control plant over one period, command held (rows written out: the same sums in
        # the same order as a loop over j, several times faster in the pure-Python loop)
        for i in range(5):
            r = Ap[i]
            w1[i] = Bp[i] * u + r[0] * w[0] + r[1] * w[1] + r[2] * w[2] + r[3] * w[3] + r[4] * w[4]
        for i in range(5):
            w[i] = w1[i]
        if w[2] > max_force:
            w[2] = max_force
        elif w[2] < -max_force:
            w[2] = -max_force
        out_x[k] = w[3]
        out_f[k] = w[2]
        # the numerical substructure over the same period, a_g[k] and f_m[k-1] held
        g = ag[k]
        for i in range(6):
            r = An[i]
            b = Bn[i]
            z1[i] = (b[0] * g + b[1] * f_prev + r[0] * z[0] + r[1] * z[1] + r[2] * z[2] + r[3] * z[3]
                     + r[4] * z[4] + r[5] * z[5])
        for i in range(6):
            z[i] = z1[i]
        # converters
        f_prev = f_m
        if k + 1 < n:
            x_m = math.floor((w[3] / m_per_V + noise_x[k + 1]) / quantum + 0.5) * quantum * m_per_V
            f_m = math.floor((w[2] / N_per_V + noise_f[k + 1]) / quantum + 0.5) * quantum * N_per_V
    return n


class NonFiniteCommandError(ValueError):
    """A controller stage gave a command that is not a finite number; ``result`` holds the samples
    before it (the plant never received it)."""

    def __init__(self, message: str, result: "Result"):
        super().__init__(message)
        self.result = result


@dataclass
class Result:
    x_t: np.ndarray  # desired first-floor displacement, m
    x_m: np.ndarray  # measured first-floor displacement, m
    floors: np.ndarray  # n x 3: x_m and the numerical floors 2 and 3, m
    u: np.ndarray  # command, m
    force: np.ndarray  # actuator force, N
    x: np.ndarray  # true actuator displacement, m


def run(stage, plant, sub, ag, fs: float, noise_seed: int = 0, use_numba: bool | None = None) -> Result:
    """One RTHS run of ``stage`` on ``plant`` (PlantParameters) with numerical substructure ``sub``."""
    n = ag.size
    rng = np.random.default_rng(noise_seed)
    noise_x = rng.normal(0.0, plant.noise_V, n)
    noise_f = rng.normal(0.0, plant.noise_V, n)
    Ap, Bp = plant.discrete(fs)
    out = Result(np.zeros(n), np.zeros(n), np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros(n))
    kernel = pick(rths_kernel, use_numba)
    step = pick(stage.step, use_numba)
    compiled = kernel is rths_kernel and hasattr(rths_kernel, "py_func") and rths_kernel.py_func is not rths_kernel
    p, s = stage.p, stage.fresh_state()
    args = [Ap, Bp, plant.max_force, sub.Ad, sub.Bd, sub.Ca, sub.Da, np.ascontiguousarray(ag), noise_x, noise_f,
            plant.quantum_V, plant.m_per_V, plant.N_per_V]
    outs = [out.x_t, out.x_m, out.floors, out.u, out.force, out.x]
    work = [np.zeros(5), np.zeros(5), np.zeros(6), np.zeros(6)]
    if compiled:
        done = kernel(step, p, s, *args, *outs, *work)
    else:
        # the pure-Python loop on lists: the same operations in the same order, the same numbers
        as_list = lambda a: a.tolist() if isinstance(a, np.ndarray) else a  # noqa: E731
        outs_l = [a.tolist() for a in outs]
        done = kernel(step, p.tolist(), s.tolist(), *[as_list(a) for a in args], *outs_l, *[a.tolist() for a in work])
        for a, l in zip(outs, outs_l):
            a[...] = np.asarray(l)
    if done < n:
        kept = Result(*(a[:done] for a in outs))
        raise NonFiniteCommandError(f"controller {stage.name!r}: the command at sample {done} ({done / fs:.6f} s) is not "
                                    "a finite number: it never reaches the plant, and the run stops there",
                                    kept)
    return out
