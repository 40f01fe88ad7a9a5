"""The alpha-OS method in displacement control (E&M 2007 eqs. 3-6; docs/method.md section 2).

Operator splitting: the specimen is driven to the predicted displacement u~_{i+1}, its restoring
force R~_{i+1} is measured, and the correction uses the structure's initial stiffness K_init (the
experimental initial stiffness K^EI plus that of the numerical part), with no iteration on the
specimen:

    M^ a_{i+1} = P^_{i+1}                                                          (4)
    M^ = M + gamma dt (1+alpha) C + beta dt^2 (1+alpha) K_init                        (5)
    P^_{i+1} = (1+alpha) P_{i+1} - alpha P_i - (1+alpha) C v~_{i+1} + alpha C v~_i
               - (1+alpha) R~_{i+1} + alpha R~_i + alpha (gamma dt C + beta dt^2 K_init) a_i   (6)

with alpha in [-1/3, 0], beta = (1-alpha)^2/4, gamma = 1/2 - alpha, predictors
u~_{i+1} = u_i + dt v_i + dt^2 (1/2 - beta) a_i,  v~_{i+1} = v_i + dt (1 - gamma) a_i,
and correctors u_{i+1} = u~_{i+1} + dt^2 beta a_{i+1},  v_{i+1} = v~_{i+1} + dt gamma a_{i+1}.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg

from hsio.errors import ConfigError
from hsio.integrators.base import StepOutcome
from hsio.interfaces import ControlMode
from hsio.structures import incidence


@dataclass(frozen=True)
class AlphaOSState:
    """The state after step i: displacement, velocity, acceleration, and the step's predictors."""

    i: int
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    u_pred: np.ndarray  # u~_i
    v_pred: np.ndarray  # v~_i
    R_tilde: np.ndarray  # R~_i, the restoring force at u~_i (measured on the specimen, plus R^N)
    P: np.ndarray  # P_i


class AlphaOS:
    """alpha-OS for M, C and the initial stiffness K_init (the implicit part of eqs. 5-6), step dt."""

    def __init__(self, M, C, K_init, dt: float, alpha: float = -0.05):
        if not -1.0 / 3.0 - 1e-12 <= alpha <= 0.0:
            raise ConfigError(f"alpha-OS: alpha must be in [-1/3, 0], got {alpha!r}")
        if not dt > 0:
            raise ConfigError(f"alpha-OS: dt must be positive, got {dt!r}")
        self.M = np.atleast_2d(np.asarray(M, dtype=float))
        self.C = np.atleast_2d(np.asarray(C, dtype=float))
        self.K_init = np.atleast_2d(np.asarray(K_init, dtype=float))
        self.dt = float(dt)
        self.alpha = float(alpha)
        self.beta = (1.0 - alpha) ** 2 / 4.0
        self.gamma = 0.5 - alpha
        a, b, g, h = self.alpha, self.beta, self.gamma, self.dt
        self.M_hat = self.M + g * h * (1 + a) * self.C + b * h**2 * (1 + a) * self.K_init  # eq. (5)
        self._M_hat_lu = scipy.linalg.lu_factor(self.M_hat)
        self.state: AlphaOSState | None = None

    @property
    def n_dof(self) -> int:
        return self.M.shape[0]

    def start(self, P0, u0=None, v0=None, R0=None) -> AlphaOSState:
        """Initial state: a_0 from M a_0 = P_0 - C v_0 - R_0."""
        n = self.n_dof
        u0 = np.zeros(n) if u0 is None else np.asarray(u0, dtype=float)
        v0 = np.zeros(n) if v0 is None else np.asarray(v0, dtype=float)
        R0 = np.zeros(n) if R0 is None else np.asarray(R0, dtype=float)
        P0 = np.asarray(P0, dtype=float)
        a0 = np.linalg.solve(self.M, P0 - self.C @ v0 - R0)
        self.state = AlphaOSState(0, u0, v0, a0, u0.copy(), v0.copy(), R0.copy(), P0.copy())
        return self.state

    def predict(self) -> tuple[np.ndarray, np.ndarray]:
        """Predictors u~_{i+1} and v~_{i+1} from the present state."""
        s = self._require_state()
        h = self.dt
        u_pred = s.u + h * s.v + h**2 * (0.5 - self.beta) * s.a
        v_pred = s.v + h * (1.0 - self.gamma) * s.a
        return u_pred, v_pred

    def correct(self, R_tilde, P_next) -> AlphaOSState:
        """Solve eq. (4) with R~_{i+1} measured at u~_{i+1}, correct, and advance to step i+1."""
        s = self._require_state()
        a, b, g, h = self.alpha, self.beta, self.gamma, self.dt
        u_pred, v_pred = self.predict()
        R_tilde = np.asarray(R_tilde, dtype=float)
        P_next = np.asarray(P_next, dtype=float)
        P_hat = (  # eq. (6)
            (1 + a) * P_next
            - a * s.P
            - (1 + a) * self.C @ v_pred
            + a * self.C @ s.v_pred
            - (1 + a) * R_tilde
            + a * s.R_tilde
        )
        # The last term of eq. (6) turns v~_i and R~_i into v_i and R_i through the correctors of
        # step i. The start has neither: v_0 and R_0 are given (start() stores them as v~_0, R~_0).
        if s.i > 0:
            P_hat = P_hat + a * (g * h * self.C + b * h**2 * self.K_init) @ s.a
        acc = scipy.linalg.lu_solve(self._M_hat_lu, P_hat)
        u = u_pred + h**2 * b * acc
        v = v_pred + h * g * acc
        self.state = AlphaOSState(s.i + 1, u, v, acc, u_pred, v_pred, R_tilde.copy(), P_next.copy())
        return self.state

    def step(self, P_next, restoring_force: Callable[[np.ndarray], np.ndarray]) -> AlphaOSState:
        """One step: predict, ask the substructure for R~ at u~_{i+1}, correct."""
        u_pred, _ = self.predict()
        return self.correct(restoring_force(u_pred), P_next)

    def _require_state(self) -> AlphaOSState:
        if self.state is None:
            raise RuntimeError("alpha-OS: call start() before stepping")
        return self.state


class OperatorSplitting:
    """alpha-OS as a method of the experiment loop: one trial per step, no iteration (Figure 9).

    The site is driven to the predicted displacement E u~_{i+1} of each experimental element and
    its measured force brought to the target with the measured displacement (docs/method.md
    section 2; off with ``correct_measured_displacement=False``):

        R~^E = R_measured + K^EI (E u~ - u_measured)

    E is the elements' incidence (``element_dofs``, and ``element_refs``, the other end of each
    element, None for the ground: :func:`hsio.structures.incidence`); the elements' forces act on
    the DOFs as E^T R~^E. The numerical part adds R~^N at u~_{i+1}; eq. (4) gives the acceleration. ``K_EI`` is one
    stiffness per channel, or a matrix over the channels when an element loaded through a setup
    couples its basic DOFs (docs/setups.md): the correction is then K^EI (u~ - u_measured) as a
    matrix product.
    """

    method = "alpha_os"
    thresholds = None

    def __init__(self, M, C, K_init, dt: float, alpha: float, element_dofs, K_EI,
                 correct_measured_displacement: bool = True, element_refs=None):
        self.core = AlphaOS(M, C, K_init, dt, alpha)
        self.dofs = np.asarray(element_dofs, dtype=int)
        self.E = incidence(self.dofs, element_refs, self.core.n_dof)
        self.K_EI = np.asarray(K_EI, dtype=float)
        n_e = self.dofs.size
        if self.K_EI.shape not in ((n_e,), (n_e, n_e)):
            raise ConfigError(f"alpha-OS: K_EI must be {n_e} stiffnesses or a {n_e} x {n_e} matrix, got shape {self.K_EI.shape}")
        self.correct_measured_displacement = bool(correct_measured_displacement)

    def _outcome(self, state: AlphaOSState, daq, iterations: int):
        n_e = self.dofs.size
        nan = np.full(n_e, np.nan)
        return StepOutcome(
            u=state.u, v=state.v, a=state.a, u_pred=state.u_pred, R=state.R_tilde,
            modes=[ControlMode.DISPLACEMENT] * n_e,
            targets=daq.targets if daq is not None else self.E @ state.u,
            commands=daq.commands if daq is not None else self.E @ state.u,
            measured_u=daq.u if daq is not None else np.zeros(n_e),
            measured_R=daq.R if daq is not None else np.zeros(n_e),
            iterations=np.full(n_e, iterations), converged=True, secant=nan,
            u_solution=self.E @ state.u, R_solution=nan)

    def start(self, P0, site, numerical):
        """a_0 from M a_0 = P_0 (at rest, unloaded)."""
        return self._outcome(self.core.start(P0), None, 0)

    def step(self, P_next, site, numerical, step: int = 0, time_s: float = 0.0):
        u_pred, _ = self.core.predict()
        targets = self.E @ u_pred
        site.set_trial(targets, [ControlMode.DISPLACEMENT] * self.dofs.size)
        daq = site.get_daq()
        F = daq.R.copy()
        if self.correct_measured_displacement:
            F += (self.K_EI @ (targets - daq.u)) if self.K_EI.ndim == 2 else self.K_EI * (targets - daq.u)
        state = self.core.correct(self.E.T @ F + numerical.trial(u_pred), P_next)
        numerical.commit()
        site.commit()
        return self._outcome(state, daq, 1)
