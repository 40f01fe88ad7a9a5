"""The candidate causes of the specimen diagnosis: each frees shape parameters (theta, with bounds
and starting values from the record's signals) and an amplitude of the model of
hsio.specimens.diagnosed.Diagnosed, with a sentence saying what it means physically."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Effect:
    name: str
    title: str
    cause: str
    theta: tuple  # (name, lower, upper) as functions of Signals
    starts: object  # Signals -> list of theta dicts
    describe: object  # params -> str
    primary: str
    amplitude: str  # the linear coefficient the effect adds ("" when none)


def _effect(name, title, cause, theta, starts, describe, primary, amplitude=""):
    return Effect(name, title, cause, theta, starts, describe, primary, amplitude)


EFFECTS: dict[str, Effect] = {e.name: e for e in (
    _effect("friction", "friction (Coulomb, with the dashpot Bingham)",
        "a force of constant size opposing the motion: dry friction in seals and bearings, or the yield "
        "stress of a field-controlled fluid (an MR damper behaves as a Bingham solid: friction plus viscosity)",
        (("friction_v0_mm_s", lambda s: 0.002 * s.v_ref, lambda s: 0.3 * s.v_ref),),
        lambda s: [{"friction_v0_mm_s": 0.02 * s.v_ref}],
        lambda p: f"friction force {p['friction_kN']:.4g} kN (smoothed over {p['friction_v0_mm_s']:.3g} mm/s)",
        "friction_kN", "friction_kN"),
    _effect("hysteresis", "hysteresis (Bouc-Wen)",
        "an elastic-plastic component: after each reversal the force rises with the elastic stiffness and "
        "saturates at a strength, so the loop encloses energy dissipated by yielding (Bouc-Wen); in an MR "
        "damper, the fluid's passage from its pre-yield to its post-yield state at each reversal",
        (("uy_mm", lambda s: 0.01 * s.u_peak, lambda s: 2.0 * s.u_peak),),
        lambda s: [{"uy_mm": f * s.u_peak} for f in (0.05, 0.3)],
        lambda p: f"strength {p['fy_kN']:.4g} kN reached over {p['uy_mm']:.3g} mm", "fy_kN", "fy_kN"),
    _effect("gap", "gap (stiffening when a gap closes)",
        "a gap or slack in a connection, or a contact that closes: beyond a displacement the specimen "
        "stiffens (a second load path engages)",
        (("gap_mm", lambda s: 0.02 * s.u_peak, lambda s: 0.98 * s.u_peak),),
        lambda s: [{"gap_mm": f * s.u_peak} for f in (0.3, 0.6)],
        lambda p: f"stiffness rises by {p['k_gap']:.4g} kN/mm beyond {p['gap_mm']:.3g} mm", "gap_mm", "k_gap"),
    _effect("degradation", "stiffness and strength degradation",
        "damage accumulates with the cycles (cracking, loosening, fatigue): stiffness and strength fall with "
        "the displacement travelled",
        (("degradation_per_mm", lambda s: 0.0, lambda s: 50.0 / max(s.travel, 1e-9)),),
        lambda s: [{"degradation_per_mm": f / max(s.travel, 1e-9)} for f in (0.1, 1.0)],
        lambda p: f"stiffness and strength divided by 1 + {p['degradation_per_mm']:.4g} per mm of travel",
        "degradation_per_mm"),
    _effect("pinching", "pinched hysteresis",
        "a hysteretic loop pinched near zero deformation: slack connectors or cracks that open and close "
        "carry little force until they bear again (timber joints, cracked concrete)",
        (("uy_mm", lambda s: 0.01 * s.u_peak, lambda s: 2.0 * s.u_peak), ("pinch", lambda s: 0.0, lambda s: 0.98),
         ("pinch_width_mm", lambda s: 0.02 * s.u_peak, lambda s: 2.0 * s.u_peak)),
        lambda s: [{"uy_mm": 0.2 * s.u_peak, "pinch": 0.5, "pinch_width_mm": 0.3 * s.u_peak},
                   {"uy_mm": 0.05 * s.u_peak, "pinch": 0.8, "pinch_width_mm": 0.15 * s.u_peak}],
        lambda p: f"hysteretic strength {p['fy_kN']:.4g} kN over {p['uy_mm']:.3g} mm, pinched by {p['pinch']:.2f} "
                  f"within {p['pinch_width_mm']:.3g} mm of zero", "pinch", "fy_kN"),
    _effect("nonlinear_elastic", "nonlinear elastic stiffness (hardening or softening spring)",
        "the force is a nonlinear but single-valued function of the displacement, F = k u + k_3 u^3: the "
        "stiffness rises (k_3 > 0: geometric stiffening, a membrane or cable that tightens, a rubber bearing "
        "at large strain) or falls (k_3 < 0: buckling, softening contact) with the displacement, while the "
        "loops enclose no more area than the dashpot's: no energy is dissipated by it",
        (), lambda s: [{}],
        lambda p: (f"cubic stiffness k_3 = {p['k3']:.4g} kN/mm^3 ({'hardening' if p['k3'] > 0 else 'softening'}: "
                   f"the tangent stiffness changes by {100 * 3 * p['k3'] / p['k'] if p['k'] else float('inf'):.3g} % per mm^2)"),
        "k3", "k3"),
    _effect("inertia", "inertia (a moving mass)",
        "a mass moves with the specimen (its own, the clevis and load cell between it and the actuator): "
        "a force proportional to the acceleration, which rises with the square of the frequency",
        (), lambda s: [{}], lambda p: f"moving mass {p['mass_kg']:.4g} kg", "mass_kg", "mass_kg"),
    _effect("rate_dependence", "rate dependence (nonlinear damping)",
        "the damping force is not proportional to the velocity: F = c v_ref |v / v_ref|^alpha "
        "(alpha < 1: a shear-thinning fluid or orifice flow that saturates; alpha > 1: turbulent flow)",
        (("alpha", lambda s: 0.05, lambda s: 3.0),), lambda s: [{"alpha": 0.5}, {"alpha": 1.5}],
        lambda p: f"damping exponent alpha = {p['alpha']:.3f} (c = {p['c']:.4g} kN s/mm at {p['v_ref_mm_s']:.3g} mm/s)",
        "alpha"),
    _effect("channel_skew", "channel skew (force late on displacement)",
        "the force channel is recorded late against the displacement (a filtered load cell, a separate "
        "conditioning delay): it shows as negative damping, energy the specimen seems to give back",
        (("skew_s", lambda s: -0.05, lambda s: 0.05),), lambda s: [{"skew_s": 2 * s.dt}, {"skew_s": 10 * s.dt}],
        lambda p: f"force channel {1e3 * p['skew_s']:.3g} ms late", "skew_s"),
)}
NAMES = tuple(EFFECTS)
