"""Differentiable fitting recovers known optima on synthetic estimators."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jgi.analysis import fitting


def synthetic_estimator(a=0.5, b=0.02, truth=1.0):
    """X(theta; xi) = truth + a theta^2 + sqrt(b / theta) xi, xi ~ N(0, 1): a biased,
    consistent estimator with bias a theta^2 and variance b / theta, like a density estimate
    whose radius theta trades bias for variance. MSE = a^2 theta^4 + b / theta, minimised at
    theta* = (b / (4 a^2))^(1/5)."""
    def estimate(theta, xi):
        return truth + a * theta**2 + jnp.sqrt(b / theta) * xi
    optimum = (b / (4 * a * a)) ** 0.2
    return estimate, optimum


def test_gradient_of_sample_average_mse_matches_finite_differences():
    est, _ = synthetic_estimator()
    xi = jax.random.normal(jax.random.PRNGKey(0), (512, 16))
    mse = fitting.sample_average_mse(est, jnp.float32(1.0), xi)
    theta = jnp.float32(0.4)
    g = jax.grad(mse)(theta)
    h = 1e-3
    fd = (mse(theta + h) - mse(theta - h)) / (2 * h)
    # float32 central difference error ~ eps * |mse| / h
    assert abs(float(g - fd)) <= 1e-2 * abs(float(g)) + 1e-4


def test_minimise_recovers_the_mse_optimal_parameter():
    est, optimum = synthetic_estimator()
    R = 20000
    xi = jax.random.normal(jax.random.PRNGKey(1), (R, 1))
    mse = fitting.sample_average_mse(est, jnp.float32(1.0), xi)
    fit = fitting.minimise(mse, 1.0, log_space=True)
    assert fit.converged
    # The SAA minimiser has its own noise: the mean of xi shifts the optimum. Bound it by
    # re-fitting on independent stream sets and using their spread.
    fits = [float(fitting.minimise(fitting.sample_average_mse(
        est, jnp.float32(1.0), jax.random.normal(jax.random.PRNGKey(10 + k), (R, 1))), 1.0,
        log_space=True).theta) for k in range(6)]
    se = np.std(fits, ddof=1) / np.sqrt(len(fits))
    from tests.support.stats import critical_t

    crit = critical_t(len(fits) - 1, 1)
    assert abs(np.mean(fits) - optimum) < crit * se + 1e-3 * optimum, (np.mean(fits), optimum, se)
    assert abs(float(fit.theta) - optimum) < 0.05 * optimum


def test_least_squares_recovers_a_power_law():
    x = jnp.logspace(2, 6, 9)
    y = 3.0 * x ** (-1.0 / 6.0)
    fit = fitting.least_squares(lambda th: jnp.log(th[0]) + th[1] * jnp.log(x) - jnp.log(y),
                                jnp.array([1.0, 0.0]))
    assert fit.converged
    np.testing.assert_allclose(np.asarray(fit.theta), [3.0, -1 / 6], rtol=1e-4)
    p, c, se = fitting.power_law(np.asarray(x), np.asarray(y))
    assert abs(p + 1 / 6) < 1e-6 and abs(c - 3) < 1e-5 and se < 1e-6
