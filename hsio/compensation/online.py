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
  ``max_rel_std``, and enough motion beyond the threshold (``min_beyond`` samples with |v| > a);
* zero lag: a window that fails that test is taken as b = 0 (the parameters move towards L = 0,
  a kept) when its slope on the excess velocity beyond the threshold in use, sign(v) (|v| - a)
  of eq. 1 fitted through the origin, is within ``ZERO_SIGMAS`` standard deviations of zero, the
  data bound it that tightly (``ZERO_SIGMAS`` sigma at most ``lag_step_s``) and at least
  ``min_beyond`` samples move beyond the threshold. An actuator whose lag falls to zero gives no
  positive b that passes the relative test, and without this the estimate would stay at the last
  lag; a window without motion beyond the threshold still changes nothing.

It starts from a configured guess (a, L) within the bounds (one beyond them is refused, not
clamped) or from nothing (L = 0: no compensation until the
first accepted estimate).
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

import numpy as np

from hsio.compensation import hockey_stick

ZERO_SIGMAS = 2.0  # a slope within this many standard deviations of zero is zero lag


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
        # a starting guess beyond the bounds on the estimate is refused, not clamped
        if not (math.isfinite(a_mm_s) and 0.0 <= a_mm_s <= s.a_max_mm_s):
            raise ValueError(f"starting threshold a = {a_mm_s!r} mm/s is out of bounds: 0 to a_max_mm_s = "
                             f"{s.a_max_mm_s:g} mm/s")
        if not (math.isfinite(lag_s) and 0.0 <= lag_s <= self.lag_limit):
            raise ValueError(f"starting lag b d_max = {lag_s!r} s is out of bounds: 0 to {self.lag_limit:g} s "
                             "(lag_max_s, and at most 0.45 t_d with eq. 2)")
        self.a = float(a_mm_s)
        self.lag = float(lag_s)
        self._v: collections.deque = collections.deque(maxlen=s.window)
        self._e: collections.deque = collections.deque(maxlen=s.window)
        self._since = 0
        self.updates = 0  # accepted estimates (zero-lag ones among them)
        self.zero_updates = 0  # accepted estimates of zero lag
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
            fit = None
        if fit is not None:
            beyond = int(np.count_nonzero(np.abs(v) > fit.a_mm_s))
            rel = fit.b_std / fit.b_s_mm if fit.b_s_mm > 0 else math.inf
            if fit.b_s_mm > 0 and math.isfinite(rel) and rel <= s.max_rel_std and beyond >= s.min_beyond:
                return self._move(fit, min(fit.b_s_mm, self.lag_limit), min(max(fit.a_mm_s, 0.0), s.a_max_mm_s))
        zero = self.zero_fit(v, e)
        if zero is not None:
            self.zero_updates += 1
            return self._move(zero, 0.0, self.a)
        self.rejected += 1
        return False

    def zero_fit(self, v: np.ndarray, e: np.ndarray) -> hockey_stick.HockeyStick | None:
        """The window as zero lag, or None: the slope b of e on x = sign(v) (|v| - a) (eq. 1 at
        the threshold a in use) through the origin, b = x.e / x.x with sigma_b^2 = s^2 / x.x and
        s^2 = |e - b x|^2 / (n - 1), is accepted as zero when |b| <= ZERO_SIGMAS sigma_b <=
        lag_step_s and at least ``min_beyond`` samples move beyond a."""
        s = self.settings
        x = hockey_stick.excess_velocity(v, self.a)
        beyond = int(np.count_nonzero(x))
        xx = float(x @ x)
        if beyond < s.min_beyond or not xx > 0 or v.size < 2:
            return None
        b = float(x @ e) / xx
        r = e - b * x
        b_std = math.sqrt(float(r @ r) / (v.size - 1) / xx)
        if not (math.isfinite(b_std) and abs(b) <= ZERO_SIGMAS * b_std <= s.lag_step_s):
            return None
        return hockey_stick.HockeyStick(self.a, 0.0, float("nan"), b_std, int(v.size),
                                        float(math.sqrt(float(e @ e) / v.size)), 1.0)

    def _move(self, fit: hockey_stick.HockeyStick, target_lag: float, target_a: float) -> bool:
        """The parameters in use move towards an accepted estimate, bounded and rate-limited."""
        s = self.settings
        self.last_fit = fit
        self.lag += float(np.clip(target_lag - self.lag, -s.lag_step_s, s.lag_step_s))
        self.a += float(np.clip(target_a - self.a, -s.a_step_mm_s, s.a_step_mm_s))
        self.updates += 1
        return True
