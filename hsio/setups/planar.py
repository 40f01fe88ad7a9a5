"""Actuators in a plane driving a rigid loading platen: one, two, three actuators, an inverted V.

The element's control point moves with the platen: its pose is (u_x, u_y, theta) from the
position at rest, of which the setup's basic DOFs are a subset (the others are held at zero by
the specimen or by bracing). Actuator i is pinned to the reaction at A_i and to the platen at
B_i = C + (u_x, u_y) + R(theta) r_i, where C is the control point at rest and r_i the offset of
the pin from it. Its stroke is its length change, exactly:

    s_i = |B_i(d) - A_i| - |B_i(0) - A_i|

and its row of the Jacobian is e_i . dB_i/dd, with e_i the unit vector from A_i to B_i:
dB/du_x = (1, 0), dB/du_y = (0, 1), dB/dtheta = R'(theta) r_i. Lengths in the lab's mm,
rotations in rad (docs/setups.md).

A mirrored rig (``mirror``: the rig as drawn, reflected left to right, its actuators on the
other side of the specimen) is the reflection x -> -x: the model's pose (u_x, u_y, theta) is the
drawn rig's (-u_x, u_y, -theta), a reflection turning rotations the other way. A negative
displacement factor instead flips every translation and leaves rotations: the rig turned half a
turn in the plane (upside down).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hsio.errors import ConfigError
from hsio.setups.base import Factors, Setup

POSE = ("ux", "uy", "theta")
MAX_LENGTH_MM = 1.0e6  # a rig's lengths: up to a kilometre
MIN_STROKE_RATIO = 0.01  # smallest singular value of the dimensionless J(0): a stroke error at most 100 times in d


@dataclass(frozen=True)
class PlanarActuator:
    """One actuator: pinned at ``fixed`` (x, y) to the reaction and at ``offset`` (x, y) from the
    control point to the platen, both in mm and in the position at rest."""

    name: str
    fixed: tuple[float, float]
    offset: tuple[float, float] = (0.0, 0.0)


@dataclass
class PlanarSetup(Setup):
    """Rigid platen in a plane, ``basic`` DOFs out of (ux, uy, theta), one or more actuators."""

    basic: tuple[str, ...]
    actuators: tuple[PlanarActuator, ...]
    factors: Factors = field(default_factory=Factors)
    mirror: bool = False  # the rig as drawn, mirrored left to right: its actuators on the other side

    def __post_init__(self):
        if not self.basic or any(b not in POSE for b in self.basic) or len(set(self.basic)) != len(self.basic):
            raise ConfigError(f"planar setup: basic DOFs must be distinct names out of {', '.join(POSE)}, got {self.basic}")
        if len(self.actuators) < len(self.basic):
            raise ConfigError(f"planar setup: {len(self.actuators)} actuator(s) cannot control "
                              f"{len(self.basic)} basic DOFs")
        self.n_basic = len(self.basic)
        self.n_actuators = len(self.actuators)
        self._index = [POSE.index(b) for b in self.basic]
        self._A = np.array([a.fixed for a in self.actuators], dtype=float)
        self._r = np.array([a.offset for a in self.actuators], dtype=float)
        self._L0 = np.linalg.norm(self._r - self._A, axis=1)
        if np.any(self._L0 <= 0) or not np.all(np.isfinite(self._L0)):
            raise ConfigError("planar setup: an actuator has no length at rest (its two pins coincide)")
        # model -> lab: translations divide by the displacement factor, rotations do not; a mirrored
        # rig (x -> -x) sees the model's x translation and its rotation with the opposite sign
        flip = {"ux": -1.0 if self.mirror else 1.0, "uy": 1.0, "theta": -1.0 if self.mirror else 1.0}
        self._scale = np.array([flip[b] * (1.0 / self.factors.displacement if b != "theta" else 1.0)
                                for b in self.basic])
        # Conditioning at rest in lab units, dimensionless: mm of stroke per mm of translation, and
        # per mm of arc at the farthest pin for a rotation. Below MIN_STROKE_RATIO in some direction
        # an actuator nearly square to its DOF would move it by a stroke's many times.
        size = max(float(np.max(np.linalg.norm(self._r, axis=1))), 1.0)
        self._lab = np.abs(self._scale) * np.array([size if b == "theta" else 1.0 for b in self.basic])
        J0 = self.jacobian(np.zeros(self.n_basic))
        weakest = self.conditioning(None, J0)
        self._orientation = np.sign(np.linalg.det(J0)) if self.square else 0.0
        if not weakest >= MIN_STROKE_RATIO:
            raise ConfigError(f"planar setup: the actuators cannot move every basic DOF (the Jacobian at rest is "
                              f"singular or nearly: some motion of the element changes their strokes by only "
                              f"{weakest:.3g} of its size, at least {MIN_STROKE_RATIO:g} is needed; an actuator square "
                              "to its DOF, or parallel actuators through one point?)")

    @property
    def square(self) -> bool:
        return self.n_actuators == self.n_basic

    def conditioning(self, d, J=None) -> float:
        """The smallest singular value of the Jacobian at ``d`` (or ``J``, the Jacobian there) in
        lab units, dimensionless: mm of stroke per mm of translation, and per mm of arc at the
        farthest pin for a rotation."""
        J = self.jacobian(d) if J is None else J
        return float(np.linalg.svd(J / self._lab, compute_uv=False)[-1])

    def pose_problem(self, d) -> str:
        """Why the actuators cannot drive the element to basic displacements ``d`` (empty: they
        can). Near a singular pose (an actuator square to the motion it should drive) a stroke
        moves the element many times as far and carries a force many times the basic force; past
        it the strokes no longer tell the pose (the same strokes have a mirror pose on the side
        of rest), so the geometry holds only on the side of rest, as well conditioned as at rest
        is required (:data:`MIN_STROKE_RATIO`). A rotation of half a turn or more is refused too:
        the strokes repeat with every whole turn (the platen turned by 2 pi stands where it stood),
        so such a pose is sent, and measured, as the pose a whole turn back. So is a pose that turns
        an actuator through square to its line at rest (e_i . e_i(0) <= 0: its platen pin beside
        or past its reaction pin): two actuators turned so together leave the Jacobian's sign as
        at rest, and their small strokes would be measured as a pose near rest."""
        pose = self._pose(d)
        if not np.all(np.isfinite(pose)):  # a garbled trial: no geometry to judge
            return "it is not a finite pose (a displacement or rotation that is not a finite number)"
        theta = pose[2]
        if abs(theta) >= math.pi:
            return (f"a rotation of {theta:.6g} rad is half a turn or more: its strokes are those of the pose turned "
                    f"back by a whole turn ({math.remainder(theta, 2 * math.pi):.6g} rad)")
        along = self._pins(pose) - self._A
        turned = np.sum(along * (self._r - self._A), axis=1) <= 0.0  # e_i . e_i(0) <= 0
        if np.any(turned):
            name = self.actuators[int(np.argmax(turned))].name
            return (f"actuator {name!r} would turn through square to its line at rest (its platen pin passes "
                    f"beside or through its reaction pin), where its stroke no longer tells the pose")
        J = self.jacobian(d)
        weakest = self.conditioning(d, J)
        if not weakest >= MIN_STROKE_RATIO:
            return (f"the actuators can hardly move the element there (their strokes change by {weakest:.3g} of "
                    f"some motion's size, at least {MIN_STROKE_RATIO:g} is needed: a pose near a singular one)")
        if self.square and np.sign(np.linalg.det(J)) != self._orientation:
            return ("the pose is past a singular one (an actuator went through square to its motion): its "
                    "strokes are those of another pose on the side of rest")
        return ""

    def _pose(self, d) -> np.ndarray:
        d = np.asarray(d, dtype=float)
        if d.shape != (self.n_basic,):
            raise ConfigError(f"planar setup: {d.size} basic displacements for {self.n_basic} basic DOFs")
        pose = np.zeros(3)
        pose[self._index] = d * self._scale
        return pose

    def _pins(self, pose) -> np.ndarray:
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rotated = self._r @ np.array([[c, s], [-s, c]])  # R(theta) r for each row r
        return rotated + pose[:2]

    def strokes(self, d) -> np.ndarray:
        B = self._pins(self._pose(d))
        return np.linalg.norm(B - self._A, axis=1) - self._L0

    def jacobian(self, d) -> np.ndarray:
        pose = self._pose(d)
        B = self._pins(pose)
        e = (B - self._A) / np.linalg.norm(B - self._A, axis=1)[:, None]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        dB_dtheta = self._r @ np.array([[-s, c], [-c, -s]])  # R'(theta) r
        columns = {"ux": e[:, 0], "uy": e[:, 1], "theta": np.sum(e * dB_dtheta, axis=1)}
        return np.column_stack([columns[b] for b in self.basic]) * self._scale


def one_actuator(length_mm: float, angle_deg: float = 0.0, factors: Factors | None = None,
                 mirror: bool = False) -> PlanarSetup:
    """One actuator of length ``length_mm`` at rest, at ``angle_deg`` from the basic DOF's
    direction (x), pushing the control point along x."""
    if not 0 < length_mm <= MAX_LENGTH_MM:
        raise ConfigError(f"one actuator: length_mm must be positive, at most {MAX_LENGTH_MM:g}, got {length_mm!r}")
    if not -360.0 <= angle_deg <= 360.0:
        raise ConfigError(f"one actuator: angle_deg must be within -360 to 360, got {angle_deg!r}")
    a = math.radians(angle_deg)
    return PlanarSetup(("ux",), (PlanarActuator("actuator", (-length_mm * math.cos(a), -length_mm * math.sin(a))),),
                       factors or Factors(), mirror)


def two_actuators(length_mm: float, spacing_mm: float, factors: Factors | None = None,
                  mirror: bool = False) -> PlanarSetup:
    """A column top in translation (x) and rotation: two horizontal actuators of length
    ``length_mm``, pinned to the platen at the control point and ``spacing_mm`` above it."""
    if not (0 < length_mm <= MAX_LENGTH_MM and 0 < spacing_mm <= MAX_LENGTH_MM):
        raise ConfigError(f"two actuators: length_mm and spacing_mm must be positive, at most {MAX_LENGTH_MM:g}")
    return PlanarSetup(("ux", "theta"), (
        PlanarActuator("lower", (-length_mm, 0.0), (0.0, 0.0)),
        PlanarActuator("upper", (-length_mm, spacing_mm), (0.0, spacing_mm)),
    ), factors or Factors(), mirror)


def three_actuators(length_mm: float, half_span_mm: float, factors: Factors | None = None,
                    mirror: bool = False) -> PlanarSetup:
    """A joint in x, y and rotation: one horizontal actuator at the control point and two
    vertical ones ``half_span_mm`` either side of it, each ``length_mm`` long at rest."""
    if not (0 < length_mm <= MAX_LENGTH_MM and 0 < half_span_mm <= MAX_LENGTH_MM):
        raise ConfigError(f"three actuators: length_mm and half_span_mm must be positive, at most {MAX_LENGTH_MM:g}")
    return PlanarSetup(("ux", "uy", "theta"), (
        PlanarActuator("horizontal", (-length_mm, 0.0), (0.0, 0.0)),
        PlanarActuator("left", (-half_span_mm, -length_mm), (-half_span_mm, 0.0)),
        PlanarActuator("right", (half_span_mm, -length_mm), (half_span_mm, 0.0)),
    ), factors or Factors(), mirror)


def inverted_v_brace(leg_length_mm: float, angle_deg: float, factors: Factors | None = None,
                     mirror: bool = False) -> PlanarSetup:
    """An inverted-V brace: two actuators as its legs, from the apex (the control point, moving in
    x and y) down to pins ``leg_length_mm`` away at ``angle_deg`` from the vertical on either side."""
    if not (0 < leg_length_mm <= MAX_LENGTH_MM and 0 < angle_deg < 90):
        raise ConfigError(f"inverted V: leg_length_mm must be positive, at most {MAX_LENGTH_MM:g}, and angle_deg in (0, 90)")
    a = math.radians(angle_deg)
    dx, dy = leg_length_mm * math.sin(a), leg_length_mm * math.cos(a)
    return PlanarSetup(("ux", "uy"), (
        PlanarActuator("left", (-dx, -dy)),
        PlanarActuator("right", (dx, -dy)),
    ), factors or Factors(), mirror)
