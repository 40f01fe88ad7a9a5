"""Online estimation of the hockey stick (docs/method.md section 4, eq. 1) during the test.

The paper calibrated a and b in a separate run and named online estimation as future work. Here
every step adds one sample of the actuator's own execution error e = d^a - d^m (the command it
was sent minus what was measured) against the velocity of that command, to a sliding window. Every
``update_every`` steps the window is refitted with :func:`hsio.compensation.hockey_stick.fit`,
and the estimate is accepted only if it is well determined. The parameters actually used for
compensation then move towards it, bounded and rate-limited, so that a bad estimate cannot
destabilise the test:

* bounds: 0 <= a <= a_max, 0 <= L <= lag_max (L = b d_max);
* rate limits: |change of L| <= lag_step_s and |change of a| <= a_step_mm_s per update;
* acceptance: at least ``min_samples`` samples, b > 0, relative standard deviation of b at most
  ``max_rel_std``, and enough motion beyond the threshold (``min_beyond`` samples with |v| > a).

It starts from a configured guess (a, L) or from nothing (L = 0: no compensation until the
first accepted estimate).
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

import numpy as np

from hsio.compensation import hockey_stick


@dataclass
class EstimatorSettings:
    window: int = 400  # samples (steps) kept
    update_every: int = 10  # steps between refits
    min_samples: int = 40
    min_beyond: int = 20
    max_rel_std: float = 0.25
    lag_max_s: float = 0.1
    a_max_mm_s: float = 50.0
    lag_step_s: float = 0.005
    a_step_mm_s: float = 2.0


class OnlineEstimator:
    """Sliding-window refits of a and L = b d_max for one actuator, bounded and rate-limited."""

    def __init__(self, settings: EstimatorSettings | None = None, a_mm_s: float = 0.0, lag_s: float = 0.0,
                 lag_limit_s: float = math.inf):
        self.settings = s = settings or EstimatorSettings()
        self.lag_limit = min(s.lag_max_s, lag_limit_s)  # a hard ceiling (e.g. eq. 2 stability)
        self.a = float(min(max(a_mm_s, 0.0), s.a_max_mm_s))
        self.lag = float(min(max(lag_s, 0.0), self.lag_limit))
        self._v: collections.deque = collections.deque(maxlen=s.window)
        self._e: collections.deque = collections.deque(maxlen=s.window)
        self._since = 0
        self.updates = 0  # accepted estimates
        self.rejected = 0
        self.last_fit: hockey_stick.HockeyStick | None = None

    def observe(self, velocity_mm_s: float, error_mm: float) -> bool:
        """Add one step's sample; refit when due. True when the parameters changed."""
        if not (math.isfinite(velocity_mm_s) and math.isfinite(error_mm)):
            return False
        self._v.append(float(velocity_mm_s))
        self._e.append(float(error_mm))
        self._since += 1
        if self._since < self.settings.update_every or len(self._v) < self.settings.min_samples:
            return False
        self._since = 0
        return self.update()

    def update(self) -> bool:
        s = self.settings
        v = np.fromiter(self._v, float)
        e = np.fromiter(self._e, float)
        try:
            fit = hockey_stick.fit(v, e, d_max_mm=1.0, a_max=s.a_max_mm_s)  # errors in mm: b is the lag
        except hockey_stick.FitError:
            self.rejected += 1
            return False
        beyond = int(np.count_nonzero(np.abs(v) > fit.a_mm_s))
        rel = fit.b_std / fit.b_s_mm if fit.b_s_mm > 0 else math.inf
        if not (fit.b_s_mm > 0 and math.isfinite(rel) and rel <= s.max_rel_std and beyond >= s.min_beyond):
            self.rejected += 1
            return False
        self.last_fit = fit
        target_lag = min(max(fit.b_s_mm, 0.0), self.lag_limit)
        target_a = min(max(fit.a_mm_s, 0.0), s.a_max_mm_s)
        self.lag += float(np.clip(target_lag - self.lag, -s.lag_step_s, s.lag_step_s))
        self.a += float(np.clip(target_a - self.a, -s.a_step_mm_s, s.a_step_mm_s))
        self.updates += 1
        return True
