"""The parametric study of docs/method.md section 3 (the paper's Figure 12): FC against DC.

SDOF, unit mass, unit initial period (k0 = 4 pi^2), nonlinear elastic Menegotto-Pinto spring
(eq. 13, normalised: u_y = 1, n = 1), secondary-to-initial stiffness ratio theta, damping ratio
zeta (mass-proportional on the initial frequency), a step load P = 3 k0 u_y from rest over 5 s.

* DC: the alpha method (HHT) iterated on displacement: command u, measure R;
* FC: the same equation (7) solved by eqs. (9)-(12): command R, measure u;

both with the secant stiffness of eq. (11), tolerance 1e-10 on the commanded increments and at most
10 iterations (:class:`hsio.integrators.ImplicitAlpha`). The "exact" solution is the
average-acceleration method at dt = 0.0002 s (:func:`hsio.integrators.newmark_average_acceleration`).
The error is

    Er(%) = sum_i |S_i^Alg - S_i^Exact| / sum_i |S_i^Exact| x 100                        (14)

with S the strain energy of the spring, the exact one sampled at the algorithm's steps. All theta
and zeta values run side by side as independent single-DOF systems (one vectorised run per alpha,
dt and mode; each system stops iterating on its own convergence).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from hsio.errors import ConfigError
from hsio.integrators import ImplicitAlpha, newmark_average_acceleration
from hsio.interfaces import ControlMode
from hsio.secant import secant_stiffness
from hsio.sites.base import Daq

K0 = 4.0 * math.pi**2  # unit mass, unit period
U_Y = 1.0
LOAD = 3.0 * K0 * U_Y
DURATION_S = 5.0
DT_EXACT = 0.0002


def mp_force(u: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Eq. (13) with n = 1, scaled: R = k0 u_y [theta x + (1 - theta) x / (1 + |x|)], x = u / u_y."""
    x = np.asarray(u, dtype=float) / U_Y
    return K0 * U_Y * (theta * x + (1.0 - theta) * x / (1.0 + np.abs(x)))


def mp_tangent(u: np.ndarray, theta: np.ndarray) -> np.ndarray:
    x = np.asarray(u, dtype=float) / U_Y
    return K0 * (theta + (1.0 - theta) / (1.0 + np.abs(x)) ** 2)


def mp_displacement(R: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """The inverse of eq. (13), n = 1: theta x^2 + (1 - r) x - r = 0 for r = |R| / (k0 u_y) >= 0."""
    R = np.asarray(R, dtype=float)
    r = np.abs(R) / (K0 * U_Y)
    b = 1.0 - r
    root = np.sqrt(b * b + 4.0 * theta * r)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(b >= 0.0, 2.0 * r / (b + root), (root - b) / (2.0 * theta))
    return np.sign(R) * x * U_Y


def mp_energy(u: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Strain energy, the integral of eq. (13) from 0 to u."""
    x = np.abs(np.asarray(u, dtype=float)) / U_Y
    return K0 * U_Y**2 * (0.5 * theta * x * x + (1.0 - theta) * (x - np.log1p(x)))


class MenegottoPintoBatch:
    """Many elastic Menegotto-Pinto springs (one per DOF) as an experimental site
    (:class:`hsio.sites.ExperimentalSite`): exact, vectorised response."""

    def __init__(self, theta: np.ndarray):
        self.theta = np.asarray(theta, dtype=float)
        self._base = (np.zeros(self.theta.size), np.zeros(self.theta.size))
        self._last = self._base

    def committed(self):
        return self._base

    def set_modes(self, modes):
        return []

    def set_trial(self, commands, modes):
        fc = np.array([m is ControlMode.FORCE for m in modes])
        u = np.where(fc, mp_displacement(commands, self.theta), commands)
        R = np.where(fc, commands, mp_force(commands, self.theta))
        self._last = (u, R)
        self._daq = Daq(u=u, R=R, k=secant_stiffness(u, R, *self._base), targets=commands, commands=commands)

    def get_daq(self) -> Daq:
        return self._daq

    def commit(self):
        self._base = self._last


@dataclass(frozen=True)
class Row:
    alpha: float
    zeta: float
    dt: float
    theta: float
    er_dc_pct: float
    er_fc_pct: float


THETA_MAX = 1000.0  # the largest theta of the study's spring (eq. 13) taken from Python


def thetas(count: int = 15, low: float = 0.2, high: float = 5.0) -> np.ndarray:
    if count < 2:
        raise ConfigError(f"study: need at least 2 theta values, got {count}")
    return np.geomspace(low, high, count)


def exact_energy(theta: np.ndarray, zeta: np.ndarray, duration_s: float = DURATION_S, dt_exact: float = DT_EXACT) -> np.ndarray:
    """Strain energy history (one column per system) by average acceleration at dt_exact."""
    theta = np.asarray(theta, dtype=float)
    n = theta.size
    omega = math.sqrt(K0)
    M = np.eye(n)
    C = np.diag(2.0 * np.asarray(zeta, dtype=float) * omega)
    steps = int(round(duration_s / dt_exact)) + 1
    P = np.full((steps, n), LOAD)
    u, _, _ = newmark_average_acceleration(M, C, lambda x: mp_force(x, theta), lambda x: np.diag(mp_tangent(x, theta)), P, dt_exact)
    return mp_energy(u, theta)


def run_algorithm(theta: np.ndarray, zeta: np.ndarray, alpha: float, dt: float, mode: ControlMode,
                  duration_s: float = DURATION_S, j_max: int = 10, tol: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """Displacement history of each system by DC or FC (eqs. 7-12). Returns (u, iterations)."""
    theta = np.asarray(theta, dtype=float)
    n = theta.size
    omega = math.sqrt(K0)
    M = np.eye(n)
    C = np.diag(2.0 * np.asarray(zeta, dtype=float) * omega)
    integ = ImplicitAlpha(M, C, None, np.arange(n), np.full(n, K0), dt, alpha, j_max=j_max,
                                 tol_displacement=tol, tol_force=tol, independent=True)
    elements = MenegottoPintoBatch(theta)
    P = np.full(n, LOAD)
    integ.start(P, elements)
    steps = int(round(duration_s / dt)) + 1
    u = np.zeros((steps, n))
    its = np.zeros((steps, n), dtype=int)
    modes = [mode] * n
    for i in range(1, steps):
        state, report = integ.step(P, elements, modes)
        u[i] = state.u
        its[i] = report.iterations
    return u, its


def energy_error_pct(S_alg: np.ndarray, S_exact: np.ndarray) -> np.ndarray:
    """Eq. (14), per column."""
    return np.sum(np.abs(S_alg - S_exact), axis=0) / np.sum(np.abs(S_exact), axis=0) * 100.0


def fc_vs_dc(theta_values=None, alphas=(0.0, -0.3), zetas=(0.0, 0.05), dts=(0.02, 0.005),
             duration_s: float = DURATION_S, dt_exact: float = DT_EXACT) -> list[Row]:
    """The whole study: one row per (alpha, zeta, dt, theta)."""
    if theta_values is None:
        theta_values = thetas()
    else:
        try:
            theta_values = np.asarray(theta_values, dtype=float)
        except (TypeError, ValueError):
            raise ConfigError(f"study: theta_values must be numbers, got {theta_values!r}") from None
        if theta_values.ndim != 1 or theta_values.size == 0 or not np.all(np.isfinite(theta_values)):
            raise ConfigError(f"study: theta_values must be a non-empty list of finite numbers, got {theta_values!r}")
        bad = theta_values[~((theta_values > 0) & (theta_values <= THETA_MAX))]
        if bad.size:
            raise ConfigError(f"study: theta = {bad[0]:g} is out of bounds: within (0, {THETA_MAX:g}] (the spring of "
                              f"eq. 13 must stiffen monotonically for FC to find the displacement of a force, and its "
                              f"energy stay finite)")
    for dt in dts:
        ratio = dt / dt_exact
        if abs(ratio - round(ratio)) > 1e-9:
            raise ConfigError(f"study: dt = {dt} is not a multiple of the reference step {dt_exact}")
    grid_theta = np.tile(theta_values, len(zetas))
    grid_zeta = np.repeat(np.asarray(zetas, dtype=float), theta_values.size)
    S_ref = exact_energy(grid_theta, grid_zeta, duration_s, dt_exact)
    rows = []
    for alpha in alphas:
        for dt in dts:
            stride = int(round(dt / dt_exact))
            errors = {}
            for mode in (ControlMode.DISPLACEMENT, ControlMode.FORCE):
                u, _ = run_algorithm(grid_theta, grid_zeta, alpha, dt, mode, duration_s)
                S_exact = S_ref[::stride][: len(u)]
                errors[mode] = energy_error_pct(mp_energy(u[: len(S_exact)], grid_theta), S_exact)
            for c in range(grid_theta.size):
                rows.append(Row(float(alpha), float(grid_zeta[c]), float(dt), float(grid_theta[c]),
                                float(errors[ControlMode.DISPLACEMENT][c]), float(errors[ControlMode.FORCE][c])))
    return rows


def rows_as_dicts(rows: list[Row]) -> list[dict]:
    return [asdict(r) for r in rows]


def plot(rows: list[Row], path) -> None:
    """Er against theta, one panel per (alpha, zeta), DC and FC for each dt (the paper's Figure 12)."""
    import matplotlib
    import matplotlib.ticker

    import matplotlib.pyplot as plt

    alphas = sorted({r.alpha for r in rows}, reverse=True)
    zetas = sorted({r.zeta for r in rows})
    dts = sorted({r.dt for r in rows}, reverse=True)
    fig, axes = plt.subplots(len(zetas), len(alphas), figsize=(5.2 * len(alphas), 4.0 * len(zetas)), squeeze=False, sharex=True)
    for zi, zeta in enumerate(zetas):
        for ai, alpha in enumerate(alphas):
            ax = axes[zi, ai]
            for di, dt in enumerate(dts):
                sel = sorted((r for r in rows if r.alpha == alpha and r.zeta == zeta and r.dt == dt), key=lambda r: r.theta)
                th = [r.theta for r in sel]
                ax.plot(th, [r.er_dc_pct for r in sel], color=f"C{di}", lw=2.4, alpha=0.45, label=f"DC, dt = {dt:g} s")
                ax.plot(th, [r.er_fc_pct for r in sel], color=f"C{di}", lw=1.0, ls="--", marker="o", ms=3, label=f"FC, dt = {dt:g} s")
            ax.set_xscale("log")
            ax.set_xticks([0.2, 0.5, 1.0, 2.0, 5.0])
            ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            ax.set_title(f"alpha = {alpha:g}, zeta = {zeta * 100:g} %", fontsize=10)
            ax.set_xlabel("theta (secondary / initial stiffness)")
            ax.set_ylabel("Er (%)")
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize=7)
    fig.suptitle("Energy error of FC and DC against theta (step load 3 k0 u_y, 5 s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
