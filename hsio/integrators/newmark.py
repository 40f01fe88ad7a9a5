"""Newmark's average-acceleration method with Newton iterations: the reference ("exact") solution.

Used as the error-free reference of the parametric studies (docs/method.md section 3: average
acceleration at dt = 0.0002 s). Implicit, unconditionally stable, iterated to equilibrium.
"""

from __future__ import annotations

from typing import Callable

import numpy as np


def newmark_average_acceleration(
    M, C, restoring_force: Callable[[np.ndarray], np.ndarray], tangent: Callable[[np.ndarray], np.ndarray],
    P: np.ndarray, dt: float, u0=None, v0=None, tol: float = 1e-10, max_iter: int = 50,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integrate M a + C v + R(u) = P(t) with beta = 1/4, gamma = 1/2.

    ``P`` has one row per step (n_steps x n_dof). ``restoring_force`` must be path-independent
    (elastic): it is evaluated at trial states. Returns u, v, a, each n_steps x n_dof.
    """
    M = np.atleast_2d(np.asarray(M, float))
    C = np.atleast_2d(np.asarray(C, float))
    P = np.asarray(P, float).reshape(len(P), -1)
    n_steps, n = P.shape
    u = np.zeros((n_steps, n))
    v = np.zeros((n_steps, n))
    a = np.zeros((n_steps, n))
    if u0 is not None:
        u[0] = u0
    if v0 is not None:
        v[0] = v0
    a[0] = np.linalg.solve(M, P[0] - C @ v[0] - restoring_force(u[0]))
    beta, gamma = 0.25, 0.5
    c0 = 1.0 / (beta * dt**2)
    c1 = gamma / (beta * dt)
    for i in range(n_steps - 1):
        x = u[i].copy()
        for _ in range(max_iter):
            acc = c0 * (x - u[i]) - v[i] / (beta * dt) - (0.5 / beta - 1.0) * a[i]
            vel = v[i] + dt * ((1 - gamma) * a[i] + gamma * acc)
            residual = P[i + 1] - M @ acc - C @ vel - restoring_force(x)
            K_eff = c0 * M + c1 * C + tangent(x)
            dx = np.linalg.solve(K_eff, residual)
            x = x + dx
            if np.max(np.abs(dx)) <= tol * max(1.0, np.max(np.abs(x))):
                break
        u[i + 1] = x
        a[i + 1] = c0 * (x - u[i]) - v[i] / (beta * dt) - (0.5 / beta - 1.0) * a[i]
        v[i + 1] = v[i] + dt * ((1 - gamma) * a[i] + gamma * a[i + 1])
    return u, v, a
