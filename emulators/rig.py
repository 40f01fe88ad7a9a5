"""An emulated rig: several actuators loading one multi-DOF specimen through a setup's geometry.

Every actuator is an emulated controller of its own (:class:`hsio.emulators.servo.ServoController`:
servo loop, lag, load train, sensors, interlocks); what couples them is the specimen between
their rods (docs/setups.md):

* the rods (after each load train) move a rigid platen whose pose, the element's basic
  displacements d, follows from the strokes by the setup's exact geometry
  (:meth:`hsio.setups.Setup.basic_displacements`, Newton from the last pose);
* the specimen model gives the basic forces q(d);
* the actuator forces are the solution of q = J(d)^T f (square setups; with more actuators than
  basic DOFs, ``parallel``, the least-norm one: each actuator's share in proportion to its
  ratio, the actuators not fighting each other), and each controller's load cell reads its own f_i.

The rig is evaluated once per controller period, when the first actuator's controller steps; the
others see the pose of that period with their own strokes of the period before (one controller
period, about 1 ms, of skew while they move, none while they hold).
"""

from __future__ import annotations

import numpy as np

from hsio.emulators.servo import ServoConfig, ServoController
from hsio.errors import ConfigError
from hsio.specimens import Specimen


class _VectorModel:
    """A one-DOF specimen as a model over a vector of one basic DOF."""

    def __init__(self, specimen: Specimen):
        self.specimen = specimen
        self.initial_stiffness = np.array([[specimen.initial_stiffness]])

    def force(self, d) -> np.ndarray:
        return np.array([self.specimen.force(float(d[0]))])

    def revert_to_start(self) -> None:
        self.specimen.revert_to_start()


class RigLeg(Specimen):
    """What one actuator of a rig sees: the rig's force on it at its stroke."""

    kind = "rig_leg"

    def __init__(self, rig: "Rig", index: int):
        self.rig = rig
        self.index = index

    @property
    def initial_stiffness(self) -> float:
        return float(self.rig.leg_stiffness[self.index])

    def trial(self, u: float, dt: float = 0.0) -> float:
        return self.rig.leg_force(self.index, u)

    def revert_to_start(self) -> None:
        self.rig.reset()


class Rig:
    """A setup, a specimen model over its basic DOFs, and one controller per actuator."""

    def __init__(self, setup, model, configs: list[ServoConfig]):
        if setup.n_actuators < setup.n_basic:
            raise ConfigError(f"rig: {setup.n_actuators} actuators for {setup.n_basic} basic DOFs; "
                              "the rig solves q = J^T f and needs at least as many actuators as basic DOFs")
        if len(configs) != setup.n_actuators:
            raise ConfigError(f"rig: {len(configs)} controller settings for {setup.n_actuators} actuators")
        self.setup = setup
        self.model = model if hasattr(model, "n") else _VectorModel(model)
        self._scale = setup.factors.force * setup.factors.displacement
        J0 = setup.jacobian(np.zeros(setup.n_basic))
        K = np.atleast_2d(np.asarray(self.model.initial_stiffness, dtype=float))
        J0_inv = np.linalg.pinv(J0)
        # stroke-to-force stiffness of the rig at rest: f = J^-T K J^-1 s / (force x displacement factors)
        # (pseudo-inverses where several actuators drive one DOF)
        self.leg_stiffness = np.abs(np.diag(J0_inv.T @ K @ J0_inv)) / abs(self._scale)
        self.strokes = np.zeros(setup.n_actuators)
        self.pose = np.zeros(setup.n_basic)
        self.basic_forces = np.zeros(setup.n_basic)
        self.forces = np.zeros(setup.n_actuators)
        self.evaluations = 0
        self.legs = [RigLeg(self, i) for i in range(setup.n_actuators)]
        self.controllers = [ServoController(leg, config) for leg, config in zip(self.legs, configs)]

    def reset(self) -> None:
        self.strokes[:] = 0.0
        self.pose[:] = 0.0
        self.basic_forces[:] = 0.0
        self.forces[:] = 0.0
        if hasattr(self.model, "revert_to_start"):
            self.model.revert_to_start()

    def leg_force(self, index: int, stroke: float) -> float:
        self.strokes[index] = stroke
        if index == 0:
            self._evaluate()
        return float(self.forces[index])

    def _evaluate(self) -> None:
        """The platen's pose from the strokes, the specimen's q, the actuator forces."""
        s, setup = self.strokes, self.setup
        d = self.pose.copy()
        for _ in range(8):
            J = setup.jacobian(d)
            step = np.linalg.lstsq(J, setup.strokes(d) - s, rcond=None)[0]
            d -= step
            if np.max(np.abs(step)) <= 1e-11 * max(1.0, float(np.max(np.abs(d)))):
                break
        else:
            raise ConfigError(f"rig: the setup's geometry does not close at strokes {s.tolist()}")
        self.pose = d
        self.basic_forces = np.asarray(self.model.force(d), dtype=float)
        self.forces = np.linalg.lstsq(J.T * self._scale, self.basic_forces, rcond=None)[0]
        self.evaluations += 1


def rig_for(element, table: dict, seed: int) -> Rig:
    """The rig of an experimental element loaded through a setup, with the [emulator] settings
    ``table``; its controllers get the noise seeds ``seed``, ``seed + 1``, ..."""
    setup = element.make_setup()
    configs = []
    for j in range(setup.n_actuators):
        config = ServoConfig.from_dict(dict(table))
        config.seed = seed + j
        configs.append(config)
    return Rig(setup, element.model(), configs)
