"""Experimental channels <-> actuators through the elements' setups (docs/setups.md).

A channel is one basic DOF of one experimental element, in the structure's order
(:attr:`hsio.structures.Structure.experimental_dofs`); an element loaded through a setup has as
many actuators as basic DOFs. :class:`SetupMap` sends the exact strokes of every setup to its
actuators and turns the measured strokes and forces back into basic displacements (Newton on the
exact geometry) and basic forces (q = J(d)^T f at the measured pose).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hsio.command import Phase
from hsio.errors import ConfigError, ImplausibleMeasurementError, LimitError

URGENCY = tuple(p.value for p in Phase)  # the command generator's phases, least urgent first


@dataclass
class _Block:
    name: str
    channels: slice
    actuators: slice
    setup: object


class SetupMap:
    """The setups of a structure's experimental elements, channel by channel."""

    def __init__(self, elements):
        self.blocks: list[_Block] = []
        c = a = 0
        for e in elements:
            setup = e.make_setup()
            self.blocks.append(_Block(e.name, slice(c, c + setup.n_basic), slice(a, a + setup.n_actuators), setup))
            c += setup.n_basic
            a += setup.n_actuators
        self.n_channels, self.n_actuators = c, a
        self.actuator_names = [n for e in elements for n in e.actuator_names]
        self._J0 = [b.setup.jacobian(np.zeros(b.setup.n_basic)) for b in self.blocks]

    @classmethod
    def of(cls, structure) -> "SetupMap":
        return cls(structure.experimental)

    def external_strokes(self, channel: int) -> np.ndarray:
        """The actuator strokes (one per actuator of the map) that move ``channel`` by 1 mm, for an
        external displacement's outer loop: the channel's own actuator where its element has no
        setup (stroke = displacement), every actuator of a ``parallel`` element by its ratio. A
        channel whose strokes come through a geometry, or scaled by a displacement factor (an
        instrument reads the lab's mm), takes no external displacement."""
        from hsio.setups.factory import IdentitySetup
        from hsio.setups.parallel import ParallelSetup

        for b in self.blocks:
            if b.channels.start <= channel < b.channels.stop:
                s = b.setup
                if not isinstance(s, (IdentitySetup, ParallelSetup)) or s.factors.displacement != 1.0:
                    raise ConfigError(f"setups: channel {channel} of element {b.name!r} is loaded through a setup: an "
                                      "external displacement is taken for elements without setups or with a "
                                      "'parallel' one (displacement factor 1) only")
                out = np.zeros(self.n_actuators)
                out[b.actuators] = s.jacobian(np.zeros(s.n_basic))[:, channel - b.channels.start]
                return out
        raise ConfigError(f"setups: no channel {channel} (the structure has {self.n_channels})")

    def strokes(self, d) -> np.ndarray:
        """Actuator strokes (lab mm) for channel displacements ``d`` (exact geometry)."""
        d = np.asarray(d, dtype=float)
        if d.shape != (self.n_channels,):
            raise ConfigError(f"setups: {d.size} displacements for {self.n_channels} channels")
        out = np.empty(self.n_actuators)
        for b in self.blocks:
            out[b.actuators] = b.setup.strokes(d[b.channels])
        return out

    def check_poses(self, d) -> None:
        """Refuse (:class:`LimitError`, nothing sent) channel displacements ``d`` that put an
        element where its setup's actuators cannot drive it: near or past a singular pose of its
        geometry (:meth:`hsio.setups.planar.PlanarSetup.pose_problem`)."""
        d = np.asarray(d, dtype=float)
        for b in self.blocks:
            problem = b.setup.pose_problem(d[b.channels])
            if problem:
                pose = ", ".join(f"{x:.6g}" for x in d[b.channels])
                raise LimitError(f"element {b.name!r}: trial ({pose}) refused: {problem}; not sent")

    def first_pose_problem(self, rows) -> tuple[int, str] | None:
        """The first row (step) of channel displacements ``rows`` that :meth:`check_poses` refuses,
        with the refusal; None if every row stands (the dry run's check of a prediction)."""
        for k, row in enumerate(np.asarray(rows, dtype=float)):
            try:
                self.check_poses(row)
            except LimitError as exc:
                return k, str(exc)
        return None

    def basic(self, strokes, forces, guess=None) -> tuple[np.ndarray, np.ndarray]:
        """Channel displacements and forces from measured actuator strokes and forces; ``guess``,
        the channel displacements commanded, starts each setup's inverse (the pose nearest it)."""
        strokes = np.asarray(strokes, dtype=float)
        guess = None if guess is None else np.asarray(guess, dtype=float)
        forces = np.asarray(forces, dtype=float)
        u = np.empty(self.n_channels)
        q = np.empty(self.n_channels)
        for b in self.blocks:
            try:
                d = b.setup.basic_displacements(strokes[b.actuators],
                                                guess=None if guess is None else guess[b.channels])
            except ConfigError as exc:  # strokes no pose gives: a transducer's fault, not the geometry's
                measured = ", ".join(f"{x:.6g}" for x in strokes[b.actuators])
                raise ImplausibleMeasurementError(f"element {b.name!r}: the measured strokes ({measured}) mm put its "
                                                  f"platen in no pose of its setup ({exc})") from None
            u[b.channels] = d
            q[b.channels] = b.setup.basic_forces(forces[b.actuators], d)
        return u, q

    def forces_for(self, q, d) -> np.ndarray:
        """Actuator forces (lab kN) that carry basic forces ``q`` at basic displacements ``d``:
        the solution of q = J(d)^T f (square setups); with more actuators than basic DOFs
        (``parallel``) the least-norm one, each actuator's share in proportion to its ratio."""
        q = np.asarray(q, dtype=float)
        d = np.asarray(d, dtype=float)
        f = np.empty(self.n_actuators)
        for b in self.blocks:
            s = b.setup
            J = s.jacobian(d[b.channels]) * s.factors.force * s.factors.displacement
            f[b.actuators] = np.linalg.lstsq(J.T, q[b.channels], rcond=None)[0]
        return f

    def channel_phases(self, phases) -> list[str]:
        """The command generator's phase per channel from its phase per actuator (``phases``, the
        actuators in order): a channel moves with every actuator of its element, so it takes the
        most urgent of their phases (in the order interpolate, dwell, extrapolate, slow, hold;
        the same phase where they agree, as they do when the loop steps them together)."""
        out: list[str] = []
        for b in self.blocks:
            own = list(phases[b.actuators])
            phase = max(own, key=lambda p: URGENCY.index(p) if p in URGENCY else -1) if own else ""
            out += [phase] * (b.channels.stop - b.channels.start)
        return out

    def linearised_samples(self, samples: np.ndarray) -> np.ndarray:
        """Controller-rate samples (n x actuators x 3: command, stroke, force) in channel space
        by the linearised geometry J(0): what the recorder's per-channel columns hold (commands
        and strokes by its pseudo-inverse: with several actuators on one DOF, their least-squares
        displacement; forces by J(0)^T: their ratio-weighted sum)."""
        n = samples.shape[0]
        out = np.empty((n, self.n_channels, 3))
        for b, J0 in zip(self.blocks, self._J0):
            s = b.setup
            inv = np.linalg.pinv(J0)
            out[:, b.channels, 0] = samples[:, b.actuators, 0] @ inv.T
            out[:, b.channels, 1] = samples[:, b.actuators, 1] @ inv.T
            out[:, b.channels, 2] = samples[:, b.actuators, 2] @ J0 * s.factors.force * s.factors.displacement
        return out
