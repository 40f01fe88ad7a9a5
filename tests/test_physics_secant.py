"""The secant stiffness of eq. (11) (E&M 2007, eq. (11))
from controller-rate samples, by the three estimators, against values computed here; and the
refusal rules (increment too small, not a finite positive number)."""

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.secant import SecantEstimator, secant_stiffness

U_B = np.array([1.0, -2.0])
R_B = np.array([3.0, 5.0])


def samples(n=50, seed=3):
    """Two elements: displacements ramping away from the base with a ripple, forces on 2.0 and
    7.0 kN/mm secants plus an offset ripple, so that every estimator gives a different value."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.1, 1.0, n)
    u = U_B + np.outer(s, [0.8, -0.5]) + 0.01 * rng.standard_normal((n, 2))
    R = R_B + (u - U_B) * [2.0, 7.0] + 0.02 * rng.standard_normal((n, 2))
    return u, R


def test_raw_estimate_uses_the_last_sample():
    u, R = samples()
    est = SecantEstimator("raw")
    est.begin_step(U_B, R_B)
    um, Rm, k = est.update(u, R)
    assert np.array_equal(um, u[-1]) and np.array_equal(Rm, R[-1])
    assert np.allclose(k, (R[-1] - R_B) / (u[-1] - U_B), rtol=1e-14)


@pytest.mark.parametrize("n_avg", [1, 7, 50, 80])
def test_average_estimate_uses_the_mean_of_the_last_n_avg_samples(n_avg):
    u, R = samples()
    est = SecantEstimator("average", n_avg=n_avg)
    est.begin_step(U_B, R_B)
    um, Rm, k = est.update(u, R)
    tail = slice(-n_avg, None)
    assert np.allclose(um, u[tail].mean(axis=0), rtol=1e-14)
    assert np.allclose(Rm, R[tail].mean(axis=0), rtol=1e-14)
    assert np.allclose(k, (R[tail].mean(axis=0) - R_B) / (u[tail].mean(axis=0) - U_B), rtol=1e-12)
    assert np.allclose(k, [2.0, 7.0], rtol=0.1)


def test_least_squares_fits_every_sample_of_the_step_through_the_base():
    u, R = samples(60)
    est = SecantEstimator("least_squares", n_avg=10)
    est.begin_step(U_B, R_B)
    est.update(u[:25], R[:25])  # iteration 1
    um, Rm, k = est.update(u[25:], R[25:])  # iteration 2: the fit takes both
    du, dR = u - U_B, R - R_B
    assert np.allclose(k, np.sum(du * dR, axis=0) / np.sum(du * du, axis=0), rtol=1e-12)
    assert np.allclose(um, u[-10:].mean(axis=0), rtol=1e-14)  # the pair is the average of the last n_avg
    assert np.allclose(Rm, R[-10:].mean(axis=0), rtol=1e-14)
    est.begin_step(u[-1], R[-1])  # a new step forgets the old samples
    u2 = u[-1] + np.outer(np.linspace(0.1, 0.5, 20), [1.0, 1.0])
    R2 = R[-1] + (u2 - u[-1]) * [3.0, 4.0]
    _, _, k2 = est.update(u2, R2)
    assert np.allclose(k2, [3.0, 4.0], rtol=1e-12)


@pytest.mark.parametrize("method", ["raw", "average"])
def test_estimates_are_refused_when_not_a_finite_positive_secant(method):
    est = SecantEstimator(method, n_avg=1, min_increment=0.05)
    est.begin_step([0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 1.0])
    u = np.array([[0.04, 0.06, -0.5, 0.0, 0.5]])
    R = np.array([[0.4, 0.6, 1.0, 0.3, 1.0]])
    _, _, k = est.update(u, R)
    # increment below min_increment; accepted; negative secant; no increment; zero secant
    assert np.isnan(k[0]) and k[1] == pytest.approx(10.0) and np.isnan(k[2]) and np.isnan(k[3]) and np.isnan(k[4])
    assert est.last_estimate[0] == pytest.approx(10.0) and est.last_estimate[2] == pytest.approx(-2.0)
    edge = SecantEstimator(method, n_avg=1, min_increment=0.25)
    edge.begin_step([0.0], [0.0])
    assert np.isnan(edge.update([[0.25]], [[1.0]])[2][0])  # an increment equal to the minimum is refused
    assert edge.update([[0.2500001]], [[1.0]])[2][0] == pytest.approx(4.0, rel=1e-6)


def test_least_squares_is_refused_without_any_increment():
    est = SecantEstimator("least_squares")
    est.begin_step([1.0], [2.0])
    _, _, k = est.update(np.full((5, 1), 1.0), np.full((5, 1), 2.5))
    assert np.isnan(k[0])
    _, _, k = est.update(np.array([[1.5]]), np.array([[1.0]]))  # a negative slope
    assert np.isnan(k[0])


def test_update_before_begin_step_and_bad_arguments():
    with pytest.raises(RuntimeError, match="begin_step"):
        SecantEstimator().update([[1.0]], [[1.0]])
    with pytest.raises(ConfigError, match="method must be one of"):
        SecantEstimator("median")
    with pytest.raises(ConfigError, match="n_avg must be a whole number of samples, at least 1"):
        SecantEstimator(n_avg=0)
    SecantEstimator(n_avg=1, min_increment=0.0)
    with pytest.raises(ConfigError, match="min_increment"):
        SecantEstimator(min_increment=-1e-3)


def test_secant_of_exact_values():
    k = secant_stiffness([1.0, 2.0, 3.0, 4.0], [2.0, -1.0, 5.0, 0.0], [0.0, 0.0, 3.0, 2.0], [0.0, 0.0, 1.0, 0.0])
    assert k[0] == pytest.approx(2.0) and np.isnan(k[1]) and np.isnan(k[2]) and np.isnan(k[3])
    assert secant_stiffness([3.0], [7.0], [1.0], [1.0])[0] == pytest.approx(3.0)


@pytest.mark.parametrize("method", ["raw", "average", "least_squares"])
def test_a_soft_secant_below_one_is_accepted(method):
    est = SecantEstimator(method, n_avg=2)
    est.begin_step([2.0], [1.0])
    _, _, k = est.update(np.array([[2.5], [3.0]]), np.array([[1.25], [1.5]]))
    assert k[0] == pytest.approx(0.5, rel=1e-12)
    assert secant_stiffness([3.0], [1.5], [2.0], [1.0])[0] == pytest.approx(0.5, rel=1e-12)

