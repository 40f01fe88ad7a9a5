"""Actuators as an experimental site: trials run through the controller-rate loop.

Each trial is one :meth:`hsio.control_loop.ControlLoop.execute`: the commands are checked
against the limits, generated at the controller rate and reached after t_d = TR dt of lab time
(docs/method.md section 1). The site owns what sits between the integrator and the actuators:

* feed-forward compensation of displacement commands (E&M 2007 eq. 2; docs/method.md section 4):
  the integrator's command d^c becomes d^a before it reaches the loop;
* the measurement of a trial: the loop's average over its last ``n_avg`` periods, or, with a
  :class:`~hsio.secant.SecantEstimator`, the estimator's pair and secant stiffness (eq. 11)
  from the controller-rate samples (docs/method.md section 5);
* bumpless mode switches (:meth:`hsio.control_loop.ControlLoop.set_mode`);
* with a :class:`~hsio.sites.setup_map.SetupMap`, the setups between the integrator's channels
  (basic DOFs) and the actuators: exact strokes out, basic displacements and forces back
  (docs/setups.md). Elements with setups run in displacement control.
"""

from __future__ import annotations

import numpy as np

from hsio.control_loop import ControlLoop
from hsio.errors import ConfigError
from hsio.interfaces import ControlMode
from hsio.secant import SecantEstimator, secant_stiffness
from hsio.sites.base import Daq


class ActuatorSite:
    """The experimental channels on actuators, driven trial by trial: one actuator per channel,
    or several per element through its setup (``setups``)."""

    def __init__(self, loop: ControlLoop, estimator: SecantEstimator | None = None, compensation=None,
                 setups=None):
        self.loop = loop
        self.setups = setups
        if setups is not None and setups.n_actuators != len(loop.actuators):
            raise ConfigError(f"the setups drive {setups.n_actuators} actuators; the loop has {len(loop.actuators)}")
        if setups is not None and estimator is not None:
            raise ConfigError("the secant estimator works per actuator; elements with setups take the "
                              "averaged measurement (no estimator)")
        self.n_elements = setups.n_channels if setups is not None else len(loop.actuators)
        self.estimator = estimator
        if estimator is not None and not loop.keep_samples:
            raise ConfigError("the secant stiffness is estimated from the controller-rate samples: "
                              "set [output] samples = true")
        self.compensation = compensation  # hsio.compensation.stage.CompensationStage or None
        feedback = loop.feedback()
        self._committed = self._to_channels(np.array([f.displacement_mm for f in feedback]),
                                            np.array([f.force_kN for f in feedback]))
        self.actuator_samples: list[np.ndarray] = []
        self._last = self._committed
        if estimator is not None:
            estimator.begin_step(*self._committed)
        self._samples: list[np.ndarray] = []
        self._daq: Daq | None = None

    @property
    def modes(self) -> list[ControlMode]:
        return [a.mode for a in self.loop.actuators]

    @property
    def late_steps(self) -> int:
        return self.loop.late_steps

    @property
    def lab_time_s(self) -> float:
        """Controller time spent so far (ticks x period)."""
        return float(self.loop.clock.now_s)

    def committed(self):
        return self._committed

    def set_modes(self, modes) -> list[int]:
        switched = []
        for index, (actuator, mode) in enumerate(zip(self.loop.actuators, modes)):
            if actuator.mode is not mode:
                self.loop.set_mode(index, mode)
                switched.append(index)
        return switched

    def _to_channels(self, strokes: np.ndarray, forces: np.ndarray):
        if self.setups is None:
            return strokes, forces
        return self.setups.basic(strokes, forces)

    def set_trial(self, commands, modes) -> None:
        targets = np.asarray(commands, dtype=float)
        if self.setups is not None:
            if any(m is not ControlMode.DISPLACEMENT for m in modes):
                raise ConfigError("elements loaded through setups run in displacement control")
            actuator_targets = self.setups.strokes(targets)
        else:
            self.set_modes(modes)
            actuator_targets = targets
        compensate = self.compensation is not None and all(m is ControlMode.DISPLACEMENT for m in self.modes)
        if compensate:
            d_a = self.compensation.adjust(actuator_targets)
            fb = self.loop.execute(d_a)
            self.compensation.observe(actuator_targets, d_a, fb.displacement)
        else:
            fb = self.loop.execute(actuator_targets)
        if fb.samples is not None:
            if self.setups is not None:
                self.actuator_samples.append(fb.samples)
                self._samples.append(self.setups.linearised_samples(fb.samples))
            else:
                self._samples.append(fb.samples)
        if self.estimator is not None:
            u, R, k = self.estimator.update(fb.samples[:, :, 1], fb.samples[:, :, 2])
        else:
            u, R = self._to_channels(fb.displacement, fb.force)
            k = secant_stiffness(u, R, *self._committed)
        self._last = (u, R)
        commands = fb.commands if self.setups is None else self.setups.basic(fb.commands, fb.force)[0]
        self._daq = Daq(u=u, R=R, k=k, targets=targets.copy(), commands=commands, samples=fb.samples)
        self.last_actuator_feedback = fb

    def get_daq(self) -> Daq:
        if self._daq is None:
            raise RuntimeError("actuator site: get_daq before any trial")
        return self._daq

    def commit(self) -> None:
        self._committed = self._last
        if self.estimator is not None:
            self.estimator.begin_step(*self._committed)

    def take_samples(self) -> np.ndarray | None:
        if not self._samples:
            return None
        out = np.concatenate(self._samples, axis=0)
        self._samples = []
        return out

    def hold(self) -> None:
        """Every actuator holds (confirmed by each actuator's own hold)."""
        self.loop.hold_all()

    def close(self) -> None:
        self.loop.close()

    def __enter__(self) -> "ActuatorSite":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
