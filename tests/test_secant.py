"""Secant stiffness from controller-rate feedback (docs/method.md eq. 11, section 5)."""

import numpy as np
import pytest

from hsio.emulators.local import open_url
from hsio.clock import LockstepClock
from hsio.control_loop import ControlLoop
from hsio.errors import ConfigError
from hsio.secant import SecantEstimator, secant_stiffness
from hsio.structures import sdof

K_TRUE = 2.6


def estimates_near_peak(seed: int) -> dict[str, np.ndarray]:
    """Drive an emulated linear specimen (default noise 0.01 mm, resolution 0.025 mm) up a sine
    towards its peak, steps of 0.09 down to 0.013 mm, and estimate k each step by each method."""
    dt = 0.004
    structure = sdof(k=K_TRUE, m=0.011, dt=dt)
    clock = LockstepClock()
    actuators = open_url(f"emulator://?seed={seed}", structure.experimental, clock, {})
    loop = ControlLoop(actuators, clock, dt, 64.0, n_avg=1, keep_samples=True, hold_fraction=0.5)
    estimators = {m: SecantEstimator(m, n_avg=100) for m in ("raw", "average", "least_squares")}
    fb0 = actuators[0].feedback()
    base = {m: (np.array([fb0.displacement_mm]), np.array([fb0.force_kN])) for m in estimators}
    out = {m: [] for m in estimators}
    t = np.arange(0.0, 0.2445, dt)
    for i, target in enumerate(10.0 * np.sin(2 * np.pi * t)[1:], start=1):
        samples = loop.execute(np.array([target])).samples
        for m, est in estimators.items():
            est.begin_step(*base[m])
            u, R, _ = est.update(samples[:, :, 1], samples[:, :, 2])
            base[m] = (u, R)
            if t[i] > 0.19:  # the last 14 steps before the peak
                out[m].append(est.last_estimate[0] / K_TRUE)
    loop.close()
    return {m: np.array(v) for m, v in out.items()}


def test_raw_estimate_spikes_near_a_peak_averaged_and_least_squares_do_not():
    ratios = {m: np.concatenate([estimates_near_peak(s)[m] for s in (0, 3)]) for m in ("raw", "average", "least_squares")}
    raw = ratios["raw"]
    assert np.any(~np.isfinite(raw) | (raw <= 0) | (np.abs(raw - 1) > 0.5)), raw
    for m in ("average", "least_squares"):
        r = ratios[m]
        assert np.all(np.isfinite(r)), (m, r)
    assert np.all((ratios["average"] > 0.7) & (ratios["average"] < 1.3)), ratios["average"]
    # least squares through the base is biased low by the noise on du, but bounded
    assert np.all((ratios["least_squares"] > 0.25) & (ratios["least_squares"] < 1.25)), ratios["least_squares"]


def test_estimator_refuses_small_increments_and_non_positive_values():
    est = SecantEstimator("raw", min_increment=0.05)
    est.begin_step([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    u, R, k = est.update(np.array([[0.01, 1.0, 1.0]]), np.array([[0.03, -2.0, 3.0]]))
    assert np.isnan(k[0])  # below min_increment
    assert np.isnan(k[1])  # negative
    assert k[2] == pytest.approx(3.0)


def test_average_and_least_squares_on_exact_samples():
    d = np.linspace(0.0, 2.0, 50)[:, None]
    f = 3.0 * d
    for method in ("average", "least_squares"):
        est = SecantEstimator(method, n_avg=10)
        est.begin_step([0.0], [0.0])
        _, _, k = est.update(d, f)
        assert k[0] == pytest.approx(3.0, rel=1e-12)
    assert secant_stiffness([1.0], [2.0], [0.0], [0.0])[0] == pytest.approx(2.0)
    assert np.isnan(secant_stiffness([0.0], [2.0], [0.0], [0.0])[0])


def test_bad_settings_are_refused():
    with pytest.raises(ConfigError, match="method"):
        SecantEstimator("median")
    with pytest.raises(ConfigError, match="n_avg"):
        SecantEstimator("average", n_avg=0)
