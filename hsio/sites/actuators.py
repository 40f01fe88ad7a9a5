"""Actuators as an experimental site: trials run through the controller-rate loop.

Each trial is one :meth:`hsio.control_loop.ControlLoop.execute`: the commands are checked
against the limits, generated at the controller rate and reached after t_d = TR dt of lab time
(docs/method.md section 1). The site owns what sits between the integrator and the actuators:

* feed-forward compensation of displacement commands (E&M 2007 eq. 2; docs/method.md section 4):
  the integrator's command d^c becomes d^a before it reaches the loop;
* the measurement of a trial: the loop's average over its last ``n_avg`` periods, or, with a
  :class:`~hsio.secant.SecantEstimator`, the estimator's pair and secant stiffness (eq. 11)
  from the controller-rate samples (docs/method.md section 5);
* bumpless mode switches (:meth:`hsio.control_loop.ControlLoop.set_mode`).
"""

from __future__ import annotations

import numpy as np

from hsio.control_loop import ControlLoop
from hsio.errors import ConfigError
from hsio.interfaces import ControlMode
from hsio.secant import SecantEstimator, secant_stiffness
from hsio.sites.base import Daq


class ActuatorSite:
    """One actuator per experimental element (identity setup), driven trial by trial."""

    def __init__(self, loop: ControlLoop, estimator: SecantEstimator | None = None, compensation=None):
        self.loop = loop
        self.n_elements = len(loop.actuators)
        self.estimator = estimator
        if estimator is not None and not loop.keep_samples:
            raise ConfigError("the secant stiffness is estimated from the controller-rate samples: "
                              "set [output] samples = true")
        self.compensation = compensation  # hsio.compensation.stage.CompensationStage or None
        feedback = loop.feedback()
        self._committed = (np.array([f.displacement_mm for f in feedback]), np.array([f.force_kN for f in feedback]))
        self._last = self._committed
        if estimator is not None:
            estimator.begin_step(*self._committed)
        self._samples: list[np.ndarray] = []
        self._sample_meta: list[tuple] = []  # (lab times, phases) beside each block of samples
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

    def set_trial(self, commands, modes) -> None:
        self.set_modes(modes)
        targets = np.asarray(commands, dtype=float)
        compensate = self.compensation is not None and all(m is ControlMode.DISPLACEMENT for m in self.modes)
        if compensate:
            d_a = self.compensation.adjust(targets)
            fb = self.loop.execute(d_a)
            self.compensation.observe(targets, d_a, fb.displacement)
        else:
            fb = self.loop.execute(targets)
        if fb.samples is not None:
            self._samples.append(fb.samples)
            self._sample_meta.append((fb.sample_time, fb.phases))
        if self.estimator is not None:
            u, R, k = self.estimator.update(fb.samples[:, :, 1], fb.samples[:, :, 2])
        else:
            u, R = fb.displacement, fb.force
            k = secant_stiffness(u, R, *self._committed)
        self._last = (u, R)
        self._daq = Daq(u=u, R=R, k=k, targets=targets.copy(), commands=fb.commands, samples=fb.samples)

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

    def take_sample_meta(self) -> tuple[np.ndarray, list] | None:
        """Lab time and generator phases of the samples of the last :meth:`take_samples`."""
        if not self._sample_meta or any(t is None for t, _ in self._sample_meta):
            self._sample_meta = []
            return None
        times = np.concatenate([t for t, _ in self._sample_meta])
        phases = [p for _, ps in self._sample_meta for p in ps]
        self._sample_meta = []
        return times, phases

    def take_events(self) -> list[dict]:
        """Interlock warnings and trips since the last call (docs/safety.md section 3)."""
        return self.loop.take_events()

    def pause(self):
        """Finish nothing more, hold every actuator and read the hold back (a HoldReport)."""
        return self.loop.pause()

    def resume(self) -> None:
        self.loop.resume()

    def hold(self):
        """Every actuator holds; returns the read-back (:class:`hsio.safety.hold.HoldReport`)."""
        self.loop.hold_all()
        return self.loop.confirm_hold()

    def close(self) -> None:
        self.loop.close()

    def __enter__(self) -> "ActuatorSite":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
