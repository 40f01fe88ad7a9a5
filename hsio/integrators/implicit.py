"""The implicit alpha method solved by secant iteration, each element in DC or FC (E&M 2007 eqs. 7-12;
docs/method.md sections 3 and 5).

The alpha method (HHT) written as an equivalent static problem at step i+1:

    K* u_{i+1} + (1+alpha) R_{i+1} = P*_{i+1}                                              (7)
    K* = M / (beta dt^2) + (1+alpha) gamma C / (beta dt)                                   (8)
    P*_{i+1} = (1+alpha) P_{i+1} - alpha P_i - (1+alpha) C v~_{i+1} + alpha C v_i
               + K* u~_{i+1} + alpha R_i                                                   (10)

R = E^T R^E + K_N u: the experimental elements (one per DOF, each to the ground or to another DOF
through the incidence E; diagonal experimental stiffness over the elements) and the numerical
linear springs K_N, which may link the DOF. Each experimental element is modelled over
the step by its secant line through the base state (u_b, R_b) measured at the end of step i,

    u^j = u_b + [k^j]^{-1} (R^j - R_b)                                                     (9)

with k^1 = the last converged secant and k^j from eq. (11) on what iteration j-1 measured. With
this model eq. (7) is linear; for a single DOF its solution for the force is eq. (12),

    { K* [k^j]^{-1} + (1+alpha) } R^j = P* + K* [k^j]^{-1} R_b - K* u_b                    (12)

and in general it is one linear solve per iteration. Each iteration both the displacement u^j and
the force R^j of every element come out of the same solve (DC and FC are computed in parallel);
the mode of the element decides which is commanded:

* FC: command R^j, measure u^j (force control, section 3);
* DC: command u^j, measure R^j (displacement control iterated to equilibrium, section 5).

The loop stops when the change of the commanded quantity between iterations is below its
tolerance (force for FC, displacement for DC) or after ``j_max`` commands. The step is accepted at
the solution of eq. (7) with the last secant, and
a_{i+1} = (u_{i+1} - u~_{i+1}) / (beta dt^2),  v_{i+1} = v~_{i+1} + gamma dt a_{i+1}.

For a linear specimen the secant is exact and DC, FC and any mix give the same solution, the
alpha method's. DOF physically coupled (a non-diagonal experimental stiffness) are outside the
method and are refused.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from hsio.errors import ConfigError
from hsio.interfaces import ControlMode
from hsio.structures import incidence

DC = ControlMode.DISPLACEMENT
FC = ControlMode.FORCE
J_MAX_LIMIT = 100  # commands per step at most (the bound of [integrator] j_max)
SECANT_Z = 4.0  # an FC element's new secant must differ from the one in use by this many sigma_k (eq. 11a)
INFORMATIVE = 0.25  # an estimate turned away confirms the secant in use only when sigma_k is below this share of |k|


@dataclass
class ImplicitState:
    """The state after step i."""

    i: int
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    R: np.ndarray  # total restoring force per DOF (elements + numerical springs)
    P: np.ndarray
    u_pred: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class StepReport:
    """What one step did, per element: iterations (commands sent), converged, secant, the last
    displacement and force solutions (DC and FC in parallel), and the last commands sent."""

    iterations: np.ndarray
    converged: bool
    k: np.ndarray
    u_solution: np.ndarray
    R_solution: np.ndarray
    commands: np.ndarray
    measured_u: np.ndarray
    measured_R: np.ndarray
    modes: list = field(default_factory=list)  # the modes at the end of the step
    fell_back: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # FC -> DC within the step
    not_converging: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # of those: FC did not converge
    guarded: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # of those: force outside the range
    secant_refused: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))  # FC estimates turned away (eq. 11a)


class ImplicitAlpha:
    """The alpha method solved by secant iteration, each element in DC or FC (eqs. 7-12).

    The same solve serves implicit displacement control (every element in DC), implicit force
    control (every element in FC) and mixed control; :class:`hsio.integrators.mixed.ImplicitMethod`
    chooses the modes.

    ``M``, ``C``, ``K_N`` are n x n; ``element_dofs`` gives the DOF of each experimental element,
    ``element_refs`` its other end (None, or None for an element: the ground); ``K_EI`` their
    initial stiffness (a vector, or a matrix that must be diagonal). Element e's displacement is
    (E u)_e and its force acts on the DOFs as E^T R, E the elements' incidence
    (:func:`hsio.structures.incidence`): eq. (7) with R = E^T R^E + K_N u.
    A secant estimate above ``max_stiffness_ratio`` K^EI (a noise spike) is refused and the
    previous secant kept.

    ``fc_blend`` (lambda, in (0, 1]) sets the base displacement u_b of eq. (9) for an element in
    FC. With 1 (the default) it is the measured displacement, so the transducer's resolution
    delta_u enters the force model as k delta_u, exactly as in DC. With lambda < 1 it is the
    complementary estimate u_b = u_s + lambda (u_meas - u_s) of the step before, where
    u_s = u_sol + (R_meas - R_sol) / k is the element's solution of eq. (7) moved along its secant
    to the measured force (carried by the accurate load cell; the transducer only corrects its
    drift): the transducer noise enters scaled by about sqrt(lambda / (2 - lambda)).
    The estimate is kept for every element, so that one switching from DC to FC starts from
    its DC solution moved to the measured force (within the transducer's noise of the
    measurement, not offset by it). Before the first step it is the initial state, the one
    reading at rest weighted by lambda (with ``secant_uncertainty`` given; :meth:`_at_rest`), and
    the base force likewise the initial state's (:meth:`_force_at_rest`). ``blend_dc=True`` uses
    the same estimate for elements in DC (their measured force, through the secant, locates the
    specimen better than a coarse transducer), so that the base stays continuous across switches.
    ``anchor_dc`` (default True; a bool per element, or one for all): an element in DC is modelled, after each command, by the line of
    slope k through the pair just measured. Where eq. (11) gave k this is the line of eq. (9)
    (through the base and the measurement); where the estimate was refused (an increment below
    the estimator's ``min_increment``, typical of a stiff specimen whose increments are tenths of a
    millimetre) the previous slope is kept but the line still passes through the measurement, so
    that a stale secant cannot misplace the force: the accepted force is the measured one plus
    the slope times the actuator's remaining tracking gap. Off (the line through the base), a DC
    step after the infill of structure II cracks extrapolates the uncracked stiffness from the
    base, and every such step adds its error (HS-vs-NS 4.8 to 18.8 % at PGA 0.18 to 0.25 g against
    1.8 to 3.0 % anchored; docs/force_control.md). The complementary estimate below always uses
    the line through the base.
    ``reset_at_reversal`` (default False): an FC element whose measured force reverses in a step
    that gave no estimate of eq. (11) (every increment below the estimator's ``min_increment``, or
    only estimates turned away that are not informative, eq. 11a below) takes K^EI as its secant
    from then on: the branch ahead unloads, and unloading is stiff, while the secant kept from
    before may come from a soft branch (the cracked envelope of an infill, ten times softer). A
    stale soft secant moves the complementary estimate ten times too far for every change of force;
    FC alone on the cracking infill of structure II (0.18 to 0.25 g, TR 10, ramp-hold) is 19 to 60
    % off NS with the reset against 47 to 1066 % without (docs/force_control.md).
    ``secant_uncertainty`` (the transducer's and the load cell's (noise, resolution): each a
    standard deviation sigma or a pair (sigma, delta) with delta the resolution, in mm and kN;
    None: unknown): an element in FC takes a new estimate of eq. (11) only when it differs from
    the secant in use by more than ``secant_z`` (4: a run judges hundreds of estimates, and at 3
    one in 370 of an unchanged specimen would pass) times its standard uncertainty from the
    instruments (eq. 11a),

        sigma_k = |k| sqrt(var(du) / du^2 + var(dR) / dR^2)
        var(du) = sum over both ends of sigma_u^2 / n_end + delta_u^2 / 12              (11a)

    du, dR the measured increments from the base, n_end the samples averaged at that end (the
    site's estimator, :func:`samples_averaged`; the base of the first step is the one feedback
    sample the site starts from; a displacement read from an external instrument, the site's
    ``displacement_instruments``, is one reading of that instrument at each end, and its force
    the load cell's at the trial's last controller period, one sample at each end): the noise
    averages down, the quantisation of a reading does not. With the same n at both ends and no
    resolution it is |k| sqrt(2/n) sqrt((s_u/du)^2 + (s_F/dR)^2). FC moves the displacement along
    its secant by every change of force (eq. 9), so a secant that follows the transducer's noise
    moves it by a noise-sized fraction of every force change, step after step. The estimates turned
    away (``secant_refused``, per element) are pooled until the secant is next set: their mean
    weighted by 1 / sigma_k^2, of standard uncertainty 1 / sqrt(sum 1 / sigma_k^2), is taken when
    it differs from the secant in use by more than ``secant_z`` times that (a pool of one estimate
    is that estimate: it is judged as one). A change is therefore
    taken in the step whose own estimate shows it beyond ``secant_z`` sigma_k (a crack or a yield
    over an increment of a few sigma_u / (change of k / k)), or, over smaller increments, as soon
    as the estimates turned away since the secant was set show it together. An estimate turned away
    counts as a confirmation of the secant in use (no reset at a reversal, below) only when it is
    informative, sigma_k < ``INFORMATIVE`` |k|. Elements in DC take every estimate, as without it.
    ``independent=True`` treats every DOF as a separate system (M, C, K_N diagonal, one element
    per DOF) and stops iterating each one on its own convergence: it runs many single-DOF cases
    side by side (the parametric study).
    """

    def __init__(self, M, C, K_N, element_dofs, K_EI, dt: float, alpha: float = 0.0, j_max: int = 10,
                 tol_displacement: float = 1e-10, tol_force: float = 1e-10, independent: bool = False,
                 max_stiffness_ratio: float = 20.0, fc_blend: float = 1.0, blend_dc: bool = False,
                 anchor_dc=True, reset_at_reversal: bool = False, secant_uncertainty=None,
                 secant_z: float = SECANT_Z, element_refs=None):
        if not -1.0 / 3.0 - 1e-12 <= alpha <= 0.0:
            raise ConfigError(f"implicit alpha method: alpha must be in [-1/3, 0], got {alpha!r}")
        if isinstance(dt, bool) or not isinstance(dt, numbers.Real) or not (math.isfinite(dt) and dt > 0):
            raise ConfigError(f"implicit alpha method: dt must be positive (a number of seconds), got {dt!r}")
        if isinstance(j_max, bool) or not isinstance(j_max, numbers.Integral) or not 1 <= j_max <= J_MAX_LIMIT:
            raise ConfigError(f"implicit alpha method: j_max (commands per step) must be a whole number in 1..{J_MAX_LIMIT}, "
                              f"got {j_max!r}")
        for name, tol in (("tol_displacement", tol_displacement), ("tol_force", tol_force)):
            if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not (math.isfinite(tol) and tol >= 0):
                raise ConfigError(f"implicit alpha method: {name} must be a number, zero or positive, got {tol!r}")
        self.M = _matrix("M", M)
        n = self.M.shape[0]
        if self.M.ndim != 2 or self.M.shape != (n, n):
            raise ConfigError(f"implicit alpha method: M must be a square matrix, got shape {self.M.shape}")
        if not np.all(np.linalg.eigvalsh(0.5 * (self.M + self.M.T)) > 0):
            raise ConfigError("implicit alpha method: M must be positive definite (a mass on every DOF)")
        self.C = _matrix("C", C)
        self.K_N = np.zeros((n, n)) if K_N is None else _matrix("K_N", K_N)
        for name, mat in (("C", self.C), ("K_N", self.K_N)):
            if mat.shape != (n, n):
                raise ConfigError(f"implicit alpha method: {name} is {mat.shape}, M is {(n, n)}")
        dofs = np.atleast_1d(np.asarray(element_dofs, dtype=object))
        if dofs.ndim != 1 or not all(isinstance(d, numbers.Integral) and not isinstance(d, bool) for d in dofs):
            raise ConfigError(f"implicit alpha method: element_dofs must be whole DOF numbers, one per element, "
                              f"got {element_dofs!r:.80}")
        self.dofs = dofs.astype(int)
        if len(set(self.dofs.tolist())) != len(self.dofs):
            raise ConfigError("implicit alpha method: two experimental elements act on the same DOF; the secant "
                              "stiffness of eq. (11) is per DOF and cannot split a DOF's force between them")
        if self.dofs.size and (self.dofs.min() < 0 or self.dofs.max() >= n):
            raise ConfigError(f"implicit alpha method: element DOF {self.dofs.tolist()} not all in 0..{n - 1}")
        K_EI = np.asarray(K_EI, dtype=float)
        if K_EI.ndim == 2:
            off = K_EI - np.diag(np.diag(K_EI))
            if np.any(np.abs(off) > 1e-12 * max(np.max(np.abs(K_EI)), 1e-300)):
                raise ConfigError(
                    "implicit alpha method: the experimental stiffness is not diagonal (DOF coupled by physical "
                    "springs); the implicit methods (docs/method.md section 3) need DOF linked only by "
                    "numerical springs - run this setup in displacement control (alpha_os)")
            K_EI = np.diag(K_EI)
        if K_EI.shape != self.dofs.shape:
            raise ConfigError(f"implicit alpha method: {K_EI.size} initial stiffnesses for {self.dofs.size} elements")
        if np.any(~np.isfinite(K_EI)) or np.any(K_EI <= 0):
            raise ConfigError(f"implicit alpha method: every element's initial stiffness must be positive, got {K_EI.tolist()}")
        self.K_EI = K_EI
        self.dt = float(dt)
        self.alpha = float(alpha)
        self.beta = (1.0 - alpha) ** 2 / 4.0
        self.gamma = 0.5 - alpha
        self.j_max = int(j_max)
        if not max_stiffness_ratio > 1:
            raise ConfigError(f"implicit alpha method: max_stiffness_ratio must exceed 1, got {max_stiffness_ratio!r}")
        self.max_stiffness_ratio = float(max_stiffness_ratio)  # secant estimates above ratio x K^EI are refused
        if isinstance(fc_blend, bool) or not isinstance(fc_blend, numbers.Real) or not 0 < fc_blend <= 1:
            raise ConfigError(f"implicit alpha method: fc_blend must be in (0, 1] (a number), got {fc_blend!r}")
        for name, flag in (("blend_dc", blend_dc), ("reset_at_reversal", reset_at_reversal)):
            if not isinstance(flag, (bool, np.bool_)):
                raise ConfigError(f"implicit alpha method: {name} must be True or False, got {flag!r}")
        self.fc_blend = float(fc_blend)
        self.blend_dc = bool(blend_dc)
        # per element (one bool for all): DC elements modelled through their last measurement
        self.anchor_dc = np.broadcast_to(np.asarray(anchor_dc, dtype=bool), self.dofs.shape).copy()
        self.reset_at_reversal = bool(reset_at_reversal)
        self.secant_uncertainty = None if secant_uncertainty is None else _instruments(secant_uncertainty)
        if isinstance(secant_z, bool) or not isinstance(secant_z, numbers.Real) or not (math.isfinite(secant_z)
                                                                                           and secant_z >= 0):
            raise ConfigError(f"implicit alpha method: secant_z must be a number, zero or positive, got {secant_z!r}")
        self.secant_z = float(secant_z)
        # FC estimates of eq. (11) within secant_z sigma_k of the secant in use, per element; those
        # turned away since the secant was last set, pooled: sum of 1 / sigma_k^2 and of k / sigma_k^2
        self.secant_refused = np.zeros(self.dofs.size, dtype=int)
        self._pool = (np.zeros(self.dofs.size), np.zeros(self.dofs.size))
        self._last_dR = np.zeros(self.dofs.size)  # the last nonzero measured force increment, per element
        self.reversal_resets = 0
        self._u_fc = np.full(self.dofs.size, np.nan)  # base displacement of FC elements (fc_blend < 1)
        self._R_fc = np.full(self.dofs.size, np.nan)  # their base force before the first step
        self.tol_displacement = float(tol_displacement)
        self.tol_force = float(tol_force)
        a, b, g, h = self.alpha, self.beta, self.gamma, self.dt
        self.K_star = self.M / (b * h**2) + (1 + a) * g * self.C / (b * h)  # eq. (8)
        self.independent = bool(independent)
        if self.independent:
            diagonal = all(np.count_nonzero(m - np.diag(np.diag(m))) == 0 for m in (self.M, self.C, self.K_N))
            grounded = element_refs is None or all(r is None for r in element_refs)
            if not diagonal or self.dofs.tolist() != list(range(n)) or not grounded:
                raise ConfigError("implicit alpha method: independent=True needs diagonal M, C, K_N and element j at DOF j "
                                  "to the ground")
        self._E = incidence(self.dofs, element_refs, n)
        self.k = K_EI.copy()  # the last converged secant, per element
        self.state: ImplicitState | None = None

    @property
    def n_dof(self) -> int:
        return self.M.shape[0]

    def start(self, P0, site, u0=None, v0=None) -> ImplicitState:
        """Initial state: a_0 from M a_0 = P_0 - C v_0 - R_0 with R_0 from the site's committed state."""
        n = self.n_dof
        u0 = np.zeros(n) if u0 is None else np.asarray(u0, dtype=float)
        v0 = np.zeros(n) if v0 is None else np.asarray(v0, dtype=float)
        u_b, R_b = site.committed()
        R0 = self._E.T @ np.asarray(R_b, dtype=float) + self.K_N @ u0
        self._u_fc = self._at_rest(self._E @ u0, np.asarray(u_b, dtype=float))
        self._R_fc = self._force_at_rest(self.K_EI * (self._E @ u0), np.asarray(R_b, dtype=float))
        P0 = np.asarray(P0, dtype=float)
        a0 = np.linalg.solve(self.M, P0 - self.C @ v0 - R0)
        self.state = ImplicitState(0, u0, v0, a0, R0, P0.copy(), u0.copy())
        return self.state

    def _at_rest(self, ue0: np.ndarray, u_meas: np.ndarray) -> np.ndarray:
        """The complementary estimate before the first step (``fc_blend`` < 1 and the instruments
        known): the specimen stands where the initial state puts it, its transducer zeroed there, and
        the one reading at rest is weighted by lambda as every later reading is. Without the
        instruments, or with a reading beyond 5 s_u + delta_u of the initial state, the reading."""
        if self.secant_uncertainty is None or not self.fc_blend < 1:
            return np.full(self.dofs.size, np.nan)
        (sigma_u, delta_u), _ = self.secant_uncertainty
        near = np.abs(u_meas - ue0) <= 5.0 * instrument_uncertainty(delta_u, sigma_u) + delta_u
        return np.where(near, ue0 + self.fc_blend * (u_meas - ue0), np.nan)

    def _force_at_rest(self, Re0: np.ndarray, R_meas: np.ndarray) -> np.ndarray:
        """The FC elements' base force before the first step, as :meth:`_at_rest` their displacement:
        the force of the initial state (on the K^EI line, the load cell zeroed at rest), the one
        reading weighted by lambda; the reading where it is beyond 5 s_F + delta_F of that force (a
        preload, an offset), or without the instruments."""
        if self.secant_uncertainty is None or not self.fc_blend < 1:
            return np.full(self.dofs.size, np.nan)
        _, (sigma_F, delta_F) = self.secant_uncertainty
        near = np.abs(R_meas - Re0) <= 5.0 * instrument_uncertainty(delta_F, sigma_F) + delta_F
        return np.where(near, Re0 + self.fc_blend * (R_meas - Re0), np.nan)

    def predict(self) -> tuple[np.ndarray, np.ndarray]:
        s = self._require_state()
        h = self.dt
        return s.u + h * s.v + h**2 * (0.5 - self.beta) * s.a, s.v + h * (1.0 - self.gamma) * s.a

    def _solve(self, P_star, k, u_b, R_b):
        """Eq. (7) with each element on its secant line through the base: u, and R per element."""
        a = self.alpha
        rhs = P_star - (1 + a) * (self._E.T @ (R_b - k * u_b))
        if self.independent:
            A = np.diag(self.K_star) + (1 + a) * (np.diag(self.K_N) + self._E.T @ k)
            u = rhs / A
        else:
            A = self.K_star + (1 + a) * (self.K_N + self._E.T @ np.diag(k) @ self._E)
            u = np.linalg.solve(A, rhs)
        ue = self._E @ u
        return u, ue, R_b + k * (ue - u_b)

    def step(self, P_next, site, modes: list[ControlMode],
             fallback_below=None, fallback_after: int | None = None,
             fc_force_range=None) -> tuple[ImplicitState, StepReport]:
        """One step: iterate eq. (7) with the elements in ``modes``; accept and advance.

        ``fallback_below`` (per element, kN/mm; None: off): an FC element whose secant estimate
        falls below it during the step goes on in DC for the rest of the step (where a command is
        left: after the step's last command the step stays in FC, as its command was sent). The FC iteration
        converges only while the secant it uses is below twice the stiffness of the branch
        ahead; at the end of a stiff branch (the specimen softens within the step) it would
        oscillate, whereas the DC iteration, dominated by K*, converges.

        ``fallback_after`` (None: off): an FC element whose force command still changes by more
        than the tolerance after this many commands goes on in DC for the remaining commands of
        the step (``StepReport.not_converging``), so that the step ends with the specimen at the
        displacement of the accepted solution rather than at an unconverged force.

        ``fc_force_range`` ((lo, hi) per element, kN; None: off): an FC element whose first force
        command of the step falls outside [lo, hi] runs the whole step in DC
        (``StepReport.guarded``): force control only where the specimen has already carried
        that force, never into new territory where it may crack and soften within the step.
        """
        s = self._require_state()
        a, b, g, h = self.alpha, self.beta, self.gamma, self.dt
        if len(modes) != self.dofs.size:
            raise ConfigError(f"implicit alpha method: {len(modes)} modes for {self.dofs.size} elements")
        fc = np.array([m is FC for m in modes], dtype=bool)
        tol = np.where(fc, self.tol_force, self.tol_displacement)
        P_next = np.asarray(P_next, dtype=float)
        u_pred, v_pred = self.predict()
        P_star = (1 + a) * P_next - a * s.P - (1 + a) * self.C @ v_pred + a * self.C @ s.v + self.K_star @ u_pred + a * s.R  # eq. (10)
        u_b, R_b = (np.asarray(x, dtype=float) for x in site.committed())
        u_b_measured = u_b
        R_b_measured = R_b.copy()
        n_avg = samples_averaged(site)
        n_base = 1 if s.i == 0 else n_avg  # the first step's base: the one feedback sample the site starts from
        external = getattr(site, "displacement_instruments", None)  # channels read by an external instrument
        refused = np.zeros(self.dofs.size, dtype=int)
        last_turned = np.zeros(self.dofs.size, dtype=bool)  # the step's last estimate turned away
        last_w, last_k = np.zeros(self.dofs.size), np.zeros(self.dofs.size)
        if self.fc_blend < 1:
            u_b = np.where((fc | self.blend_dc) & np.isfinite(self._u_fc), self._u_fc, u_b)
            if s.i == 0:  # the first base: the force of the state at rest (_force_at_rest)
                R_b = np.where((fc | self.blend_dc) & np.isfinite(self._R_fc), self._R_fc, R_b)
        k = self.k.copy()
        active = np.ones(self.dofs.size, dtype=bool)
        iterations = np.zeros(self.dofs.size, dtype=int)
        previous = None
        fell_back = np.zeros(self.dofs.size, dtype=bool)
        not_converging = np.zeros(self.dofs.size, dtype=bool)
        estimated = np.zeros(self.dofs.size, dtype=bool)  # eq. (11) gave a secant in this step
        if fallback_below is not None:
            fallback_below = np.broadcast_to(np.asarray(fallback_below, dtype=float), self.dofs.shape)
        u_m, R_m = u_b.copy(), R_b.copy()
        base = (u_b.copy(), R_b.copy())  # the line of eq. (9) through the base, for the estimate below
        converged = False
        u, ue, Re = self._solve(P_star, k, u_b, R_b)
        guarded = np.zeros(self.dofs.size, dtype=bool)
        if fc_force_range is not None:  # FC only inside the force range already explored
            lo, hi = (np.broadcast_to(np.asarray(x, dtype=float), self.dofs.shape) for x in fc_force_range)
            guarded = fc & ((Re > hi) | (Re < lo))
            if guarded.any():
                modes = [DC if guarded[e] else m for e, m in enumerate(modes)]
                fc = fc & ~guarded
                tol = np.where(fc, self.tol_force, self.tol_displacement)
                u_b = np.where(guarded, u_b_measured, u_b)
                R_b = np.where(guarded, R_b_measured, R_b)  # the pair it reads, as a DC element's
                base = (u_b.copy(), R_b.copy())  # a guarded element's step starts from its measurement
                u, ue, Re = self._solve(P_star, k, u_b, R_b)
                fell_back |= guarded
        sent = np.where(fc, Re, ue)
        for j in range(self.j_max + 1):
            if j > 0:
                u_new, ue_new, Re_new = self._solve(P_star, k, u_b, R_b)
                if self.independent:
                    u = np.where(active, u_new, u)
                    ue, Re = np.where(active, ue_new, ue), np.where(active, Re_new, Re)
                else:
                    u, ue, Re = u_new, ue_new, Re_new
            commands = np.where(fc, Re, ue)
            if previous is not None:
                with np.errstate(invalid="ignore"):
                    change = np.abs(commands - previous) <= tol
                if self.independent:
                    active &= ~change
                    if not active.any():
                        converged = True
                        break
                elif change.all():
                    converged = True
                    break
                elif fallback_after is not None and j >= fallback_after and j < self.j_max:
                    stuck = fc & ~change  # FC not converging: the remaining commands in DC
                    if stuck.any():
                        modes = [DC if stuck[e] else m for e, m in enumerate(modes)]
                        fc = fc & ~stuck
                        tol = np.where(fc, self.tol_force, self.tol_displacement)
                        commands = np.where(fc, Re, ue)
                        fell_back |= stuck
                        not_converging |= stuck
            if j == self.j_max:
                break
            site.set_trial(commands, modes)
            daq = site.get_daq()
            m_u, m_R, k_new = daq.u, daq.R, daq.k
            u_m = np.where(active, m_u, u_m)
            R_m = np.where(active, m_R, R_m)
            plausible = np.isfinite(k_new) & (k_new <= self.max_stiffness_ratio * self.K_EI)
            if self.secant_uncertainty is not None:  # FC: a new secant only beyond the instruments' noise
                judged = fc & plausible & active
                # at the secant in use, not at the estimate: an estimate pulled low by noise would
                # otherwise carry a smaller sigma and a larger weight than one pulled high
                sigma = self.sigma_k(k, m_u - u_b_measured, m_R - R_b_measured, n_avg, n_base, external)
                with np.errstate(divide="ignore", invalid="ignore"):
                    w = np.where(np.isfinite(sigma) & (sigma > 0), 1.0 / sigma**2, 0.0)
                    W, Wk = self._pool[0] + w, self._pool[1] + w * np.where(w > 0, k_new, 0.0)
                    pooled = np.where(W > 0, Wk / W, k)
                    pooled_sigma = 1.0 / np.sqrt(W)
                alone = self.beyond(k_new, k, sigma)
                together = ~alone & (W > 0) & self.beyond(pooled, k, pooled_sigma)
                k_new = np.where(judged & together, pooled, k_new)
                within = judged & ~alone & ~together
                refused += within
                last_turned = np.where(judged, within, last_turned)
                last_w, last_k = np.where(judged, w, last_w), np.where(judged, k_new, last_k)
                plausible &= ~within
                estimated |= within & (sigma < INFORMATIVE * np.abs(k))  # an informative estimate confirms k
            k = np.where(active & plausible, k_new, k)
            estimated |= active & plausible
            set_now = active & plausible  # the secant set: its pool starts afresh
            self._pool = (np.where(set_now, 0.0, self._pool[0]), np.where(set_now, 0.0, self._pool[1]))
            last_turned &= ~set_now
            if self.anchor_dc.any():  # DC elements: the secant line through the last measurement
                at_measured = self.anchor_dc & active & ~fc & ~fell_back & ~(self.blend_dc & (self.fc_blend < 1))
                u_b = np.where(at_measured, u_m, u_b)
                R_b = np.where(at_measured, R_m, R_b)
            iterations += active
            previous = commands
            sent = commands
            if fallback_below is not None and j < self.j_max - 1:  # a command is left to send in DC
                soft = fc & np.isfinite(k_new) & (k_new < fallback_below)
                if soft.any():
                    modes = [DC if soft[e] else m for e, m in enumerate(modes)]
                    fc = fc & ~soft
                    tol = np.where(fc, self.tol_force, self.tol_displacement)
                    previous = np.where(soft, np.nan, previous)  # a new kind of command: iterate again
                    fell_back |= soft
        site.commit()
        if self.reset_at_reversal:  # a reversal without an estimate: the branch ahead unloads at K^EI
            dR = R_m - base[1]
            reset = fc & (dR * self._last_dR < 0) & ~estimated & (k != self.K_EI)
            k = np.where(reset, self.K_EI, k)
            self.reversal_resets += int(reset.sum())
            self._pool = (np.where(reset, 0.0, self._pool[0]), np.where(reset, 0.0, self._pool[1]))
            last_turned &= ~reset
            self._last_dR = np.where(dR != 0, dR, self._last_dR)
        self.k = k
        # the step's last estimate turned away joins the pool (one per step: a step's estimates share its base)
        self._pool = (self._pool[0] + np.where(last_turned, last_w, 0.0),
                      self._pool[1] + np.where(last_turned, last_w * last_k, 0.0))
        self.secant_refused += refused
        if self.fc_blend < 1:  # the complementary estimate of the FC elements' displacement
            on_secant = base[0] + (R_m - base[1]) / k  # the base moved along the secant to the measured force
            self._u_fc = on_secant + self.fc_blend * (u_m - on_secant)  # every element: ready for a switch
        acc = (u - u_pred) / (b * h**2)
        vel = v_pred + g * h * acc
        R = self._E.T @ Re + self.K_N @ u
        self.state = ImplicitState(s.i + 1, u, vel, acc, R, P_next.copy(), u_pred)
        report = StepReport(iterations, converged, k.copy(), ue.copy(), Re.copy(), sent.copy(), u_m, R_m,
                            list(modes), fell_back, not_converging, guarded, refused)
        return self.state, report

    def sigma_k(self, k_new, du, dR, n: int, n_base: int | None = None, external=None) -> np.ndarray:
        """The standard uncertainty of each estimate ``k_new`` of eq. (11) from the instruments, its
        increments (du, dR) the difference of an ``n``-sample average and one of ``n_base`` samples
        at the base (default ``n``; eq. 11a). ``external`` (per element, None or (noise,
        resolution)): an element whose displacement an external instrument gives, one reading of
        it at each end (an instrument that states neither, (0, 0), counts as the transducer), and
        one force, the load cell's at the trial's last controller period, the one its reading pairs
        with (docs/setups.md)."""
        (nu, ru), (nF, rF) = self.secant_uncertainty
        n_base = n if n_base is None else n_base
        k_new, du, dR = (np.asarray(x, dtype=float) for x in (k_new, du, dR))
        var_u = np.full(np.shape(du), nu**2 / n + nu**2 / n_base + 2 * ru**2 / 12.0)
        var_F = np.full(np.shape(dR), nF**2 / n + nF**2 / n_base + 2 * rF**2 / 12.0)
        for e, instrument in enumerate(external or []):
            if instrument is None:
                continue
            var_F[e] = 2 * (nF**2 + rF**2 / 12.0)  # the last period's force at each end, not an average
            if any(x > 0 for x in instrument):  # (0, 0): not known, the transducer's
                noise, resolution = instrument
                var_u[e] = 2 * (noise**2 + resolution**2 / 12.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            sigma = np.abs(k_new) * np.sqrt(var_u / du**2 + var_F / dR**2)
        return np.where(np.isnan(sigma), np.inf, sigma)  # no increment: nothing known

    def beyond(self, k_new, k, sigma) -> np.ndarray:
        """Whether each estimate differs from the secant ``k`` in use by more than ``secant_z`` ``sigma``."""
        with np.errstate(invalid="ignore"):
            return ~(np.abs(np.asarray(k_new, dtype=float) - np.asarray(k, dtype=float)) <= self.secant_z * sigma)

    def significant(self, k_new, k, du, dR, n: int, n_base: int | None = None) -> np.ndarray:
        """Whether each estimate ``k_new`` of eq. (11), from the increments (du, dR) of ``n``-sample
        averages (``n_base`` at the base), differs from the secant ``k`` in use by more than
        ``secant_z`` sigma_k (eq. 11a)."""
        return self.beyond(k_new, k, self.sigma_k(k_new, du, dR, n, n_base))

    def _require_state(self) -> ImplicitState:
        if self.state is None:
            raise RuntimeError("implicit alpha method: call start() before stepping")
        return self.state


def instrument_uncertainty(resolution: float, noise: float) -> float:
    """Standard uncertainty of an instrument: its noise (standard deviation) and its resolution (a
    uniform quantisation error, resolution / sqrt(12)) combined in quadrature."""
    return float(np.hypot(noise, resolution / np.sqrt(12.0)))


def _matrix(name: str, value) -> np.ndarray:
    """``value`` as a 2-D array of finite numbers (M, C, K_N), else a ConfigError naming it."""
    try:
        out = np.atleast_2d(np.asarray(value, dtype=float))
    except (TypeError, ValueError):
        raise ConfigError(f"implicit alpha method: {name} must be a matrix of numbers, got {value!r:.80}") from None
    if not np.all(np.isfinite(out)):
        raise ConfigError(f"implicit alpha method: {name} must be finite, got {out.tolist()!r:.80}")
    return out


def _instruments(given) -> tuple:
    """``secant_uncertainty`` as ((sigma_u, delta_u), (sigma_F, delta_F)): each instrument a noise
    sigma, or a pair (sigma, delta); zero or positive, finite, not all zero."""
    def one(x):
        if isinstance(x, numbers.Real) and not isinstance(x, bool):
            return float(x), 0.0
        sigma, delta = x
        return float(sigma), float(delta)

    try:
        if isinstance(given, (str, bytes)):
            raise TypeError
        u, F = given
        out = (one(u), one(F))
    except (TypeError, ValueError):
        out = ((math.nan, math.nan), (math.nan, math.nan))
    values = [v for pair in out for v in pair]
    if not (all(math.isfinite(v) and v >= 0 for v in values) and sum(values) > 0):
        raise ConfigError(f"implicit alpha method: secant_uncertainty must be None or the transducer's and the "
                          f"load cell's noise (mm, kN), each a number or a pair (noise, resolution), zero or "
                          f"positive and not both zero, got {given!r:.80}")
    return out


def samples_averaged(site) -> int:
    """The samples averaged at each end of an increment of eq. (11): the site's estimator's
    ``n_avg`` when it averages (``average``), else 1 (the last sample; a least-squares fit is
    counted as one, the conservative choice)."""
    estimator = getattr(site, "estimator", None)
    if getattr(estimator, "method", None) == "average":
        return max(int(estimator.n_avg), 1)
    return 1
