"""A transducer gain error or a compliant load train: when the record can tell them apart.

The model (hsio/diagnose/model.py) reads m = g (x - c F): g the displacement transducer's gain
(scale_error), c the load train's compliance (force_coupling), x the rod's motion the loop
predicts from the command and F the measured force. On a specimen whose force is proportional
to its displacement, F = k m (a linear spring), the two are one model: a gain g gives
m = g x, a compliance gives m = x / (1 + c k), so a gain g and a compliance

    c = (1 - g) / (g k)

predict the same measured displacement and force, sample for sample. The record alone then
cannot tell them apart, except by a sign: a load train shortens under the force it carries
(c >= 0, |m| <= |x| on a spring), so a measurement larger than the rod's motion (g > 1, a
fitted compliance below 0) is a gain error only. Where the gain is below 1 the two stay equally
likely, and what settles it is a second transducer on the specimen, referenced to the reaction
frame (it reads the specimen's own motion through neither the gain nor the load train), or a
known stiffness of the specimen. On a specimen whose force is not
proportional to its displacement (hysteretic, softening, rate dependent) the compliance
distorts the measurement with the force's own shape and the gain only scales it: the fits
differ and the usual selection names one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GAIN, COUPLING = "scale_error", "force_coupling"
PAIR = {GAIN: COUPLING, COUPLING: GAIN}
OPEN = "undecided"
SETTLING = ("a second transducer on the specimen itself, referenced to the reaction frame (with a gain error it "
            "disagrees with the measured displacement by the gain; behind a compliant load train it agrees with it), "
            "or the specimen's stiffness measured apart")


@dataclass(frozen=True)
class GainTie:
    verdict: str  # GAIN (the sign settles it) or OPEN (equally likely)
    reason: str
    gain: float  # the fitted transducer gain
    compliance_mm_per_kN: float  # the fitted compliance
    stiffness_kN_per_mm: float  # the force against the measured displacement, least squares

    def to_json(self) -> dict:
        return {"verdict": self.verdict, "reason": self.reason, "displacement_gain": self.gain,
                "compliance_mm_per_kN": self.compliance_mm_per_kN, "stiffness_kN_per_mm": self.stiffness_kN_per_mm,
                "settling_channel": SETTLING if self.verdict == OPEN else None}


def stiffness(measured: np.ndarray, force: np.ndarray) -> float:
    """k of F = k m + F_0 by least squares."""
    m = measured - measured.mean()
    denominator = float(np.dot(m, m))
    return float(np.dot(m, force - force.mean()) / denominator) if denominator > 0 else 0.0


def tell(gain: float, compliance: float, measured: np.ndarray, force: np.ndarray) -> GainTie:
    """The verdict on a gain and a compliance that predict the record equally well."""
    k = stiffness(measured, force)
    equal = (f"a transducer gain of {gain:.4f} and a load-train compliance of {compliance:.4g} mm/kN predict the "
             f"displacement equally well: the force follows the measured displacement as a spring of "
             f"{k:.4g} kN/mm, and on a spring a gain g is a compliance (1 - g) / (g k) = "
             f"{(1.0 - gain) / (gain * k) if k else float('nan'):.4g} mm/kN")
    if compliance < 0.0:
        return GainTie(GAIN, f"{equal}; but a load train shortens under its force (a compliance is not negative), "
                             f"and the measurement reads {100 * (gain - 1):+.2f} % more than the rod moves: a "
                             "transducer gain error", gain, compliance, k)
    return GainTie(OPEN, f"{equal}; both are equally likely on this record", gain, compliance, k)
