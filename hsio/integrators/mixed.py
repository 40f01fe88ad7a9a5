"""Mixed variables: DC and FC side by side, switched per element between steps (E&M 2007 section 5;
docs/method.md section 5).

Every iteration of :class:`hsio.integrators.implicit.ImplicitAlpha` computes both the displacement and
the force of each element from one solve of eq. (7) (DC and FC in parallel over the whole history);
the element's mode decides which is commanded. At the end of each step :class:`SwitchingRule`
decides, per element, the mode of the next step from the measured secant stiffness (or the
restoring force), with two thresholds for hysteresis:

* to FC when the quantity rises above the upper threshold (K_f: the DOF is stiff, its displacement
  increments are small against the sensor resolution - unloading branches of wood walls, infill);
* back to DC when it falls below the lower threshold (K_d: the DOF is flexible again).

A switch is bumpless: the actuator and its command generator restart from the present measurement
of the new quantity. :class:`ImplicitMethod` runs ``implicit_dc``, ``force_control`` or ``mixed``
as a method of the experiment loop and reports the switches.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from hsio.errors import ConfigError
from hsio.integrators.base import StepOutcome
from hsio.integrators.implicit import ImplicitAlpha, instrument_uncertainty
from hsio.interfaces import ControlMode
from hsio.result import Switch

METHODS = ("implicit_dc", "force_control", "mixed")
DC = ControlMode.DISPLACEMENT
FC = ControlMode.FORCE
RATIO_F, RATIO_D = 1.2, 0.8  # the paper's thresholds, as multiples of K^EI
LINE_TOLERANCE = 0.01  # FC only on an element NS keeps within this share of its peak force of its K^EI line


@dataclass(frozen=True)
class SwitchingRule:
    """Two thresholds per element on the secant stiffness (kN/mm) or on |R| (kN).

    ``on = "stiffness"``: to FC when k > upper (K_f), to DC when k < lower (K_d).
    ``on = "force"``: to FC when |R| > upper, to DC when |R| < lower (specimens that stiffen
    with load, e.g. a closing gap).
    ``uncertainty``: ((sigma_u, delta_u) mm, (sigma_F, delta_F) kN), the instruments' noise and
    resolution when the rule is built from them (:meth:`from_instruments`; None otherwise);
    :class:`ImplicitMethod` hands them to the secant update of its FC elements (eq. 11a,
    :class:`ImplicitAlpha`).
    """

    upper: np.ndarray
    lower: np.ndarray
    on: str = "stiffness"
    uncertainty: tuple | None = None

    def __post_init__(self):
        if self.on not in ("stiffness", "force"):
            raise ConfigError(f"switching rule: 'on' must be 'stiffness' or 'force', got {self.on!r}")
        try:
            upper = np.atleast_1d(np.asarray(self.upper, dtype=float))
            lower = np.atleast_1d(np.asarray(self.lower, dtype=float))
        except (TypeError, ValueError):
            raise ConfigError(f"switching rule: thresholds must be numbers, one per element or one for all, got "
                              f"{self.upper!r:.60}, {self.lower!r:.60}") from None
        if upper.ndim != 1 or lower.ndim != 1 or not (upper.size == lower.size or 1 in (upper.size, lower.size)):
            raise ConfigError(f"switching rule: {upper.size} upper and {lower.size} lower threshold(s): give one per "
                              f"element, or one for all")
        # upper = +inf: the element never goes to FC (e.g. a specimen predicted to dissipate energy)
        if np.any(np.isnan(upper)) or np.any(upper == -np.inf) or np.any(~np.isfinite(lower)) or np.any(lower < 0):
            raise ConfigError(f"switching rule: thresholds must be finite (the upper one may be infinite: never "
                              f"FC) and not negative, got {upper}, {lower}")
        if np.any(lower >= upper):
            raise ConfigError(f"switching rule: the lower threshold (to DC, {lower.tolist()}) must be below "
                              f"the upper one (to FC, {upper.tolist()})")
        object.__setattr__(self, "upper", upper)
        object.__setattr__(self, "lower", lower)

    @classmethod
    def from_initial_stiffness(cls, K_EI, K_f: float = 0.0, K_d: float = 0.0, ratio_f: float = RATIO_F,
                               ratio_d: float = RATIO_D) -> "SwitchingRule":
        """K_f, K_d in kN/mm, or (when zero) ratio_f K^EI and ratio_d K^EI per element."""
        for name, value in (("K_f", K_f), ("K_d", K_d), ("ratio_f", ratio_f), ("ratio_d", ratio_d)):
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not value >= 0:
                raise ConfigError(f"switching rule: {name} must be a number, zero or positive (kN/mm; 0: from "
                                  f"K^EI), got {value!r}")
        return cls(*initial_stiffness_thresholds(K_EI, K_f, K_d, ratio_f, ratio_d), "stiffness")

    @classmethod
    def from_instruments(cls, K_EI, resolution_mm: float, force_resolution_kN: float, margin: float = 0.03,
                         hysteresis: float = 2.0, noise_mm: float = 0.0, force_noise_kN: float = 0.0) -> "SwitchingRule":
        """Thresholds from the instruments (docs/force_control.md, "choosing K_f and K_d").

        In DC the integrator reads both instruments every step: the load cell's s_F, and the
        transducer's uncertainty s_u as a force error k s_u on a branch of stiffness k (it enters
        the base of eq. 9). In FC with the complementary base the load cell's noise moves the
        specimen (by about s_F / k) rather than the integrator's force, and the transducer enters
        only through the drift correction. Each instrument's standard uncertainty combines its
        noise (standard deviation sigma) and its resolution delta (a uniform quantisation error,
        delta / sqrt(12)): s = sqrt(sigma^2 + delta^2 / 12). FC pays off where k s_u > c s_F:
        K_f = c s_F / s_u, and K_d = K_f / h with h > 1 the hysteresis. Both are per element (the
        same instruments on every actuator). The default c = 0.03 is measured
        (docs/force_control.md): FC is the closer to NS wherever its secant is right, unless the
        load cell is some 30 times the worse instrument in force terms.
        """
        values = (resolution_mm, force_resolution_kN, noise_mm, force_noise_kN, margin, hysteresis)
        if not all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in values):
            raise ConfigError(f"switching rule: resolutions, noises, margin and hysteresis must be numbers, got "
                              f"{values!r}")
        if not all(np.isfinite(values)) or not (margin > 0 and hysteresis > 1) or min(values[:4]) < 0:
            raise ConfigError("switching rule: resolutions and noises must be zero or positive, margin positive, "
                              "hysteresis above 1")
        s_u, s_F = instrument_uncertainty(resolution_mm, noise_mm), instrument_uncertainty(force_resolution_kN,
                                                                                           force_noise_kN)
        if not (s_u > 0 and s_F > 0):
            raise ConfigError("switching rule: the transducer and the load cell each need a resolution or a noise "
                              "above 0")
        try:
            K_EI = np.atleast_1d(np.asarray(K_EI, dtype=float))
        except (TypeError, ValueError):
            raise ConfigError(f"switching rule: K_EI must be numbers, one per element, got {K_EI!r:.80}") from None
        K_f = margin * s_F / s_u
        return cls(np.full(K_EI.shape, K_f), np.full(K_EI.shape, K_f / hysteresis), "stiffness",
                   ((float(noise_mm), float(resolution_mm)), (float(force_noise_kN), float(force_resolution_kN))))

    def elastic_only(self, ns, structure, max_ratio: float) -> "SwitchingRule":
        """This rule while NS (``ns``, of ``structure`` and the run's record) predicts every
        experimental element elastic (:func:`predicted_elastic`); otherwise every element stays
        in DC. Once one element cracks or yields, the response that follows depends on the path
        to it, and FC on any element changes that path more than its better force reading gains
        (docs/force_control.md)."""
        dissipates = not bool(np.all(predicted_elastic(ns, structure, max_ratio)))
        return self.never_fc(np.full(self.upper.shape, dissipates))

    def never_fc(self, elements) -> "SwitchingRule":
        """This rule with the given elements (a boolean mask) kept in DC: their upper threshold is
        infinite."""
        keep = np.broadcast_to(np.asarray(elements, dtype=bool), self.upper.shape)
        return SwitchingRule(np.where(keep, np.inf, self.upper), self.lower, self.on, self.uncertainty)

    def as_dict(self) -> dict:
        """``on`` and the thresholds per element as plain numbers; upper None: the element never goes to FC."""
        return {"on": self.on, "upper": [float(v) if np.isfinite(v) else None for v in self.upper],
                "lower": self.lower.tolist()}

    def next_modes(self, modes: list[ControlMode], k: np.ndarray, R: np.ndarray) -> list[ControlMode]:
        q = np.asarray(k, dtype=float) if self.on == "stiffness" else np.abs(np.asarray(R, dtype=float))
        upper = np.broadcast_to(self.upper, q.shape)
        lower = np.broadcast_to(self.lower, q.shape)
        out = []
        for m, value, up, lo in zip(modes, q, upper, lower):
            if m is DC and value > up:
                out.append(FC)
            elif m is FC and value < lo:
                out.append(DC)
            else:
                out.append(m)
        return out


def initial_stiffness_thresholds(K_EI, K_f: float = 0.0, K_d: float = 0.0, ratio_f: float = RATIO_F,
                                 ratio_d: float = RATIO_D) -> tuple[np.ndarray, np.ndarray]:
    """(K_f, K_d) per element: as given (kN/mm), or where zero ratio_f K^EI and ratio_d K^EI."""
    K_EI = np.asarray(K_EI, dtype=float)
    upper = np.full(K_EI.shape, K_f) if K_f > 0 else ratio_f * K_EI
    lower = np.full(K_EI.shape, K_d) if K_d > 0 else ratio_d * K_EI
    return upper, lower


def _check_guards(fallback_after, refractory_steps, explored_fraction, j_max, fc_force_limit=None, n_elements=1,
                  no_fc_at_reversal=False) -> None:
    """The guards of mixed control as :class:`ImplicitMethod` takes them (their bounds as in a run
    configuration, docs/config.md)."""
    def whole(value) -> bool:
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)

    if not isinstance(no_fc_at_reversal, (bool, np.bool_)):
        raise ConfigError(f"no_fc_at_reversal must be True or False, got {no_fc_at_reversal!r}")
    if fc_force_limit is not None:
        try:
            limit = np.asarray(fc_force_limit, dtype=float)
        except (TypeError, ValueError):
            limit = None
        ok = (limit is not None and not np.iscomplexobj(fc_force_limit) and limit.ndim <= 1
              and limit.size in ((1, n_elements) if limit.ndim == 1 else (1,))
              and not isinstance(fc_force_limit, (bool, np.bool_, str))
              and bool(np.all(np.isfinite(limit) & (limit > 0))))
        if not ok:
            raise ConfigError(f"fc_force_limit must be None (off) or a force in kN above 0, one for every element or "
                              f"one per experimental element ({n_elements}), got {fc_force_limit!r}")

    if fallback_after is not None and not (whole(fallback_after) and fallback_after >= 0
                                           and (fallback_after == 0 or not whole(j_max)  # ImplicitAlpha names j_max
                                                or fallback_after < j_max)):
        raise ConfigError(f"fallback_after must be None or 0 (off), or a whole number of FC commands below j_max "
                          f"({j_max}), after which the step's remaining commands go in DC; got {fallback_after!r}")
    if not (whole(refractory_steps) and 0 <= refractory_steps <= 10**9):
        raise ConfigError(f"refractory_steps must be a whole number of steps in 0..1e9, got {refractory_steps!r}")
    if explored_fraction is not None and not (isinstance(explored_fraction, numbers.Real)
                                              and not isinstance(explored_fraction, bool)
                                              and 0 < explored_fraction <= 1):
        raise ConfigError(f"explored_fraction must be None (off) or a number in (0, 1], got {explored_fraction!r}")


def _over_history(u, R, K_EI, measure) -> float:
    """``measure(u, R, K)`` of an element's history as (steps x basic DOF) arrays and its K^EI
    matrix: infinity where a value is not finite (an NS that diverged), 0 for an empty history."""
    u, R = np.asarray(u, dtype=float), np.asarray(R, dtype=float)
    if u.ndim == 1:
        u, R = u[:, None], R[:, None]
    K = np.atleast_2d(np.asarray(K_EI, dtype=float))
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(R)) and np.all(np.isfinite(K))):
        return float("inf")
    return measure(u, R, K) if u.shape[0] else 0.0


def hysteretic_ratio(u, R, K_EI) -> float:
    """Energy an element dissipates over a history, against its elastic energy at the peak:
    (W - R_end K^+ R_end / 2) / max(u K u / 2), W the work of R on u (trapezoidal rule), the energy
    still stored at the end taken as that of unloading along K = K^EI (K^+ its pseudo-inverse). ``u``, ``R``: one value per
    step, or one row per step and a column per basic DOF with ``K_EI`` the element's matrix. 0 for
    a linear elastic element (and below 0 for one that stiffens elastically, a closing gap); for an
    elastic-perfectly plastic one (yield at u_y) loaded to u_max, then cycled once between -u_max
    and u_max: (2 + 8) u_y (u_max - u_y) / u_max^2 (the first loading, the loop). A history with
    a value that is not finite (an NS that diverged) gives infinity: nothing is known to be
    elastic."""
    def measure(u, R, K):
        peak = 0.5 * float(np.max(np.einsum("ki,ij,kj->k", u, K, u)))
        if not peak > 0:
            return 0.0
        work = float(np.sum(0.5 * (R[1:] + R[:-1]) * np.diff(u, axis=0)))
        stored = 0.5 * float(R[-1] @ np.linalg.pinv(K) @ R[-1])
        return (work - stored) / peak

    return _over_history(u, R, K_EI, measure)


def off_line_ratio(u, R, K_EI) -> float:
    """How far an element's force leaves its K^EI line over a history: max |R - K^EI u| as a share
    of max |R|, per basic DOF, the largest over them (``u``, ``R`` as in :func:`hysteretic_ratio`).
    0 for a linear element whose K^EI is its stiffness; 0.2 for a linear one whose K^EI is declared
    1.2 times its stiffness; for a closing gap or a nonlinear elastic (Menegotto-Pinto) element, the
    curvature of its branch. FC moves an element along a line of eq. (9) through its last state, so
    an element far off the line of K^EI has no line FC can follow. A history with a value that is
    not finite gives infinity."""
    def measure(u, R, K):
        off = np.max(np.abs(R - u @ K.T), axis=0)
        peak = np.max(np.abs(R), axis=0)
        return float(np.max(np.where(peak > 0, off / np.where(peak > 0, peak, 1.0), np.where(off > 0, np.inf, 0.0))))

    return _over_history(u, R, K_EI, measure)


def check_ns(ns, structure) -> None:
    """``ns`` is a :class:`hsio.result.Result` of ``structure``: its name, its DOFs, its
    experimental channels and its time step (a look-alike with other elements, such as
    structure_II beside structure_II_infill, differs by name)."""
    from hsio.result import Result

    if not isinstance(ns, Result):
        raise ConfigError(f"ns must be the Result of run_numerical(structure, ground), got {type(ns).__name__} {ns!r:.80}")
    mine = (tuple(structure.dof_names), tuple(structure.experimental_dofs))
    theirs = (tuple(ns.dof_names), tuple(ns.element_dofs))
    if ns.structure != structure.name or mine != theirs or np.shape(ns.u)[1:] != (structure.n_dof,) or not math.isclose(ns.dt, structure.dt):
        raise ConfigError(f"ns is the NS of structure {ns.structure!r} (DOFs {list(ns.dof_names)}, experimental DOFs "
                          f"{list(ns.element_dofs)}, dt {ns.dt:g} s), not of structure {structure.name!r} (DOFs "
                          f"{list(mine[0])}, experimental DOFs {list(mine[1])}, dt {structure.dt:g} s)")


def predicted_elastic(ns, structure, max_ratio: float) -> np.ndarray:
    """Per experimental element of ``structure``, whether the purely numerical simulation ``ns``
    (a :class:`hsio.result.Result` of that structure) predicts it to stay elastic: its hysteretic
    ratio (over all its basic DOFs, with its K^EI matrix) below ``max_ratio``, and its force within
    ``LINE_TOLERANCE`` of its K^EI line (:func:`off_line_ratio`). Force control follows an elastic
    specimen with the load cell's accuracy and runs away on one that dissipates energy (a pinched
    wall, a cracking infill, a yielding storey), where a force error leaves a displacement offset
    that nothing brings back; and it moves the element along a secant line (eq. 9), which a
    specimen whose branch curves (a nonlinear elastic one), or whose K^EI is not its stiffness,
    does not follow."""
    check_ns(ns, structure)
    elastic, channel = [], 0
    for element in structure.experimental:
        K = element.K_EI_matrix
        basic = slice(channel, channel + K.shape[0])
        u, R = ns.measured_displacement[:, basic], ns.measured_force[:, basic]
        elastic.append(hysteretic_ratio(u, R, K) < max_ratio and off_line_ratio(u, R, K) <= LINE_TOLERANCE)
        channel += K.shape[0]
    return np.array(elastic)


class ImplicitMethod:
    """``implicit_dc``, ``force_control`` or ``mixed`` as a method of the experiment loop.

    ``K_N`` is the stiffness of the numerical part, which must be linear (the secant model of
    eq. 9 covers the experimental elements only). In ``mixed`` each element starts in the mode its
    rule gives at K^EI (at rest it is on its initial branch: a stiff one starts in FC, without a
    first DC step whose transducer noise the anchored line of eq. 9 would carry into the state),
    and an element in FC whose secant
    falls below the lower threshold during a step goes on in DC for the rest of the step
    (:meth:`ImplicitAlpha.step`, ``fallback_below``).

    Non-converged FC (``fallback_after``, None: off): an FC element still not converged after
    that many commands of a step finishes the step in DC; it is listed in ``not_converged`` (and
    as a within-step switch). An element that went on in DC within a step (not converging, or
its secant below K_d) stays in DC for ``refractory_steps`` steps: it has shown that it softens
faster than FC can follow. ``fc_blend``: the
    base displacement of FC elements (:class:`ImplicitAlpha`). ``explored_fraction`` (rho, None:
    off): an FC element whose force would leave rho times the force range it has carried so far
    runs that step in DC (``fc_force_range``; a cracking specimen softens in new territory, and
    its strength deteriorates with cycles, hence rho < 1). ``fc_force_limit`` (kN per element,
    None: off): FC only while the step's force stays within +/- this limit (e.g. a fraction of
    the cracking force that the infill models predict); with ``explored_fraction`` the larger
    of the two ranges. ``no_fc_at_reversal``: no switch DC -> FC in a step where the element's
    displacement reverses (near a peak the increments are of the order of the transducer's
    resolution and the secant of eq. 11 is stale or noisy, so it says little about the branch
    ahead); the rule decides again the next step. FC -> DC is never deferred: the secant below
    K_d is the rule's reason (the specimen softens). ``reset_at_reversal``: a stale secant is set
    back to K^EI at a reversal (:class:`ImplicitAlpha`). ``anchor_dc`` (:class:`ImplicitAlpha`) is on
    by default; the other defaults are the behaviour without these guards.
    ``secant_uncertainty`` (the instruments' (noise, resolution), :class:`ImplicitAlpha`; default:
    the rule's ``uncertainty`` in ``mixed``, None where the instruments are not known): FC elements
    take a new secant only beyond the instruments' noise (eq. 11a, :class:`ImplicitAlpha`).
    """

    def __init__(self, M, C, K_N, element_dofs, K_EI, dt: float, alpha: float = -0.05, method: str = "mixed",
                 rule: SwitchingRule | None = None, dof_names=None, j_max: int = 3,
                 tol_displacement: float = 0.02, tol_force: float = 0.05, fc_blend: float = 1.0,
                 fallback_after: int | None = None, refractory_steps: int = 0,
                 explored_fraction: float | None = None, blend_dc: bool = False, fc_force_limit=None,
                 no_fc_at_reversal: bool = False, anchor_dc=True, reset_at_reversal: bool = False,
                 secant_uncertainty=None, element_refs=None):
        if method not in METHODS:
            raise ConfigError(f"integrator method must be one of {', '.join(METHODS)}, got {method!r}")
        _check_guards(fallback_after, refractory_steps, explored_fraction, j_max, fc_force_limit,
                      np.size(element_dofs), no_fc_at_reversal)
        guards = {"fallback_after": fallback_after not in (None, 0), "refractory_steps": refractory_steps != 0,
                  "explored_fraction": explored_fraction is not None, "fc_force_limit": fc_force_limit is not None,
                  "no_fc_at_reversal": bool(no_fc_at_reversal)}
        given = [k for k, on in guards.items() if on]
        if method != "mixed" and given:
            raise ConfigError(f"{given[0]}: a guard of method 'mixed', not of {method!r} (it would change the "
                              f"method: e.g. force control falling back to DC for good)")
        if rule is not None and not isinstance(rule, SwitchingRule):
            raise ConfigError(f"rule must be a SwitchingRule or None, got {rule!r:.80}")
        self.method = method
        if secant_uncertainty is None and method == "mixed" and rule is not None:
            secant_uncertainty = rule.uncertainty
        self.core = ImplicitAlpha(M, C, K_N, element_dofs, K_EI, dt, alpha, j_max=j_max,
                                  tol_displacement=tol_displacement, tol_force=tol_force, fc_blend=fc_blend,
                                  blend_dc=blend_dc, anchor_dc=anchor_dc, reset_at_reversal=reset_at_reversal,
                                  secant_uncertainty=secant_uncertainty, element_refs=element_refs)
        if method == "mixed" and rule is None:
            rule = SwitchingRule.from_initial_stiffness(self.core.K_EI)
        self.rule = rule if method == "mixed" else None
        self.dofs = self.core.dofs
        n_e = self.dofs.size
        self.dof_names = list(dof_names) if dof_names is not None else [str(d) for d in range(self.core.n_dof)]
        if len(self.dof_names) != self.core.n_dof:
            raise ConfigError(f"dof_names: {len(self.dof_names)} names for {self.core.n_dof} DOFs")
        if self.rule is not None and self.rule.upper.size not in (1, n_e) or (
                self.rule is not None and self.rule.lower.size not in (1, n_e)):
            raise ConfigError(f"switching rule: {self.rule.upper.size} threshold(s) for {n_e} experimental "
                              f"element(s); give one per element, or one for all")
        self.modes = [FC if method == "force_control" else DC] * n_e
        if self.rule is not None:  # at rest an element is on its initial branch: its rule's mode at K^EI
            self.modes = self.rule.next_modes(self.modes, self.core.K_EI, np.zeros(n_e))
        self.fallback_after = fallback_after or None  # 0: off, as in a run configuration
        self.refractory_steps = int(refractory_steps)
        self._dc_until = np.zeros(n_e, dtype=int)  # an element that did not converge in FC stays in DC
        self.explored_fraction = explored_fraction
        self.fc_force_limit = None if fc_force_limit is None else np.broadcast_to(
            np.asarray(fc_force_limit, dtype=float), (n_e,)).copy()
        self._explored = (np.zeros(n_e), np.zeros(n_e))  # the force range measured so far, per element
        self.guarded_steps = 0
        self.no_fc_at_reversal = bool(no_fc_at_reversal)
        self._last_u = np.zeros(n_e)
        self._last_du = np.zeros(n_e)
        self.deferred_at_reversal = 0
        self.not_converged: list[dict] = []  # FC elements that did not converge and went on in DC
        self.fallback = self.rule.lower if self.rule is not None and self.rule.on == "stiffness" else None
        self.thresholds = None if self.rule is None else self.rule.as_dict()

    @property
    def secant_refused(self) -> list[int] | None:
        """FC estimates of eq. (11) turned away per element (eq. 11a); None where the rule is off."""
        return None if self.core.secant_uncertainty is None else [int(x) for x in self.core.secant_refused]

    def start(self, P0, site, numerical) -> StepOutcome:
        site.set_modes(self.modes)
        state = self.core.start(P0, site)
        u_b, R_b = site.committed()
        n_e = self.dofs.size
        return StepOutcome(u=state.u, v=state.v, a=state.a, u_pred=state.u_pred, R=state.R, modes=list(self.modes),
                           targets=np.zeros(n_e), commands=np.zeros(n_e), measured_u=np.asarray(u_b, dtype=float),
                           measured_R=np.asarray(R_b, dtype=float), iterations=np.zeros(n_e, dtype=int), converged=True,
                           secant=self.core.k.copy(), u_solution=np.zeros(n_e), R_solution=np.zeros(n_e))

    def _switch(self, step: int, time_s: float, j: int, to: ControlMode, within: bool, k, R,
                reason: str = "rule") -> Switch:
        return Switch(step=step, time_s=float(time_s), dof=self.dof_names[self.dofs[j]], to=to.value,
                      within_step=within, secant_kN_mm=float(k[j]), force_kN=float(R[j]), reason=reason)

    @staticmethod
    def _fallback_reason(report, j: int) -> str:
        if report.guarded[j]:
            return "force outside the FC range"
        return "not converging" if report.not_converging[j] else "secant below K_d"

    def step(self, P_next, site, numerical, step: int = 0, time_s: float = 0.0) -> StepOutcome:
        rng = None
        if self.explored_fraction is not None:
            rng = (self.explored_fraction * self._explored[0], self.explored_fraction * self._explored[1])
        if self.fc_force_limit is not None:
            lim = self.fc_force_limit
            rng = (-lim, lim) if rng is None else (np.minimum(rng[0], -lim), np.maximum(rng[1], lim))
        state, report = self.core.step(P_next, site, self.modes, self.fallback, self.fallback_after, rng)
        self._explored = (np.minimum(self._explored[0], report.measured_R),
                          np.maximum(self._explored[1], report.measured_R))
        self.guarded_steps += int(report.guarded.any())
        for j in np.flatnonzero(report.not_converging):
            self.not_converged.append({"step": step, "time_s": float(time_s), "dof": self.dof_names[self.dofs[j]]})
        for j in np.flatnonzero(report.fell_back & ~report.guarded):
            self._dc_until[j] = step + self.refractory_steps
        switches = [self._switch(step, time_s, j, DC, True, report.k, report.measured_R,
                                 self._fallback_reason(report, j)) for j in np.flatnonzero(report.fell_back)]
        self.modes = report.modes
        ended_in = list(self.modes)
        if self.rule is not None:
            new = self.rule.next_modes(self.modes, report.k, report.measured_R)
            new = [DC if (m is FC and self.modes[j] is DC and step < self._dc_until[j]) else m
                   for j, m in enumerate(new)]
            if self.no_fc_at_reversal:
                du = report.u_solution - self._last_u
                reversal = du * self._last_du < 0
                deferred = [j for j, m in enumerate(new) if m is FC and self.modes[j] is DC and reversal[j]]
                self.deferred_at_reversal += len(deferred)
                new = [DC if j in deferred else m for j, m in enumerate(new)]
                self._last_du = np.where(du != 0, du, self._last_du)
                self._last_u = report.u_solution.copy()
            changed = [j for j in range(len(new)) if new[j] is not self.modes[j]]
            if changed:
                site.set_modes(new)
                switches += [self._switch(step, time_s, j, new[j], False, report.k, report.measured_R) for j in changed]
                self.modes = new
        daq = site.get_daq()
        return StepOutcome(u=state.u, v=state.v, a=state.a, u_pred=state.u_pred, R=state.R, modes=ended_in,
                           targets=report.commands, commands=daq.commands, measured_u=report.measured_u,
                           measured_R=report.measured_R, iterations=report.iterations, converged=report.converged,
                           secant=report.k, u_solution=report.u_solution, R_solution=report.R_solution,
                           switches=switches)
