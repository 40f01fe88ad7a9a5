"""The secant estimator of eq. (11) (docs/method.md section 5) on hand-made samples: the paper's
N_avg = 100 by default, integer input read as numbers, refusals that stay silent (no
RuntimeWarning on a console every step), and errors that say what to do."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.secant import METHODS, SecantEstimator, secant_stiffness


def test_average_defaults_to_the_last_100_samples():
    """150 samples: the first 50 far off, the last 100 on the line R = 20 u: the default estimate
    is exactly 20 (E&M 2007: N_avg = 100)."""
    est = SecantEstimator("average")
    est.begin_step([0.0], [0.0])
    d = np.concatenate([np.full(50, 5.0), np.linspace(0.5, 1.5, 100)])[:, None]
    f = np.concatenate([np.full(50, 0.0), 20.0 * np.linspace(0.5, 1.5, 100)])[:, None]
    u, R, k = est.update(d, f)
    assert u[0] == pytest.approx(1.0) and R[0] == pytest.approx(20.0) and k[0] == pytest.approx(20.0)


@pytest.mark.parametrize("method", METHODS)
def test_integer_input_gives_the_same_estimate_as_floats(method):
    results = []
    for cast in (int, float):
        est = SecantEstimator(method, n_avg=2)
        est.begin_step([cast(1), cast(2)], [cast(10), cast(20)])
        d = [[cast(2), cast(4)], [cast(3), cast(6)]]
        f = [[cast(40), cast(30)], [cast(70), cast(40)]]
        results.append([np.asarray(x, dtype=float) for x in est.update(d, f)])
        results[-1].append(secant_stiffness([cast(3)], [cast(70)], [cast(1)], [cast(10)]))
    for a, b in zip(*results):
        assert np.array_equal(a, b, equal_nan=True)
    assert results[1][2][0] > 0 and results[1][3][0] == pytest.approx(30.0)


@pytest.mark.parametrize("method", METHODS)
def test_refused_estimates_raise_no_warning(method):
    """No increment (0 / 0) and a force change without one (x / 0): nan, silently."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est = SecantEstimator(method, n_avg=1)
        est.begin_step([1.0, 1.0], [5.0, 5.0])
        u, R, k = est.update([[1.0, 1.0]], [[5.0, 7.0]])
        assert np.isnan(k).all()
        assert np.isnan(secant_stiffness([1.0, 1.0], [5.0, 7.0], [1.0, 1.0], [5.0, 5.0])).all()


def test_errors_say_what_is_wrong():
    with pytest.raises(ConfigError, match="method must be one of raw, average, least_squares, got 'median'"):
        SecantEstimator("median")
    with pytest.raises(RuntimeError, match="^secant stiffness: call begin_step\\(\\) first$"):
        SecantEstimator().update([[1.0]], [[1.0]])
