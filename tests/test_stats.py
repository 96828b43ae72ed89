"""Statistics match direct numpy computations and known truths on synthetic data."""

from __future__ import annotations

import numpy as np

from jgi.analysis import stats
from tests.support.stats import critical_t


def test_error_stats_recover_known_bias_and_variance(rng_np):
    truth, bias, sigma, R = 2.0, 0.3, 0.5, 64
    X = truth + bias + sigma * rng_np.standard_normal((R, 40000))
    s = stats.error_stats(X, np.full(40000, truth))
    # exact agreement with a direct numpy computation
    np.testing.assert_allclose(s.variance, X.var(0, ddof=1))
    np.testing.assert_allclose(s.bias2, (X.mean(0) - truth) ** 2 - X.var(0, ddof=1) / R)
    # and the known truths, within standard errors over pixels
    for est, true in ((s.bias2, bias**2), (s.variance, sigma**2), (s.mse, bias**2 + sigma**2)):
        se = est.std(ddof=1) / np.sqrt(est.size)
        assert abs(est.mean() - true) < critical_t(est.size - 1, 3) * se


def test_bias_of_an_unbiased_estimator_against_a_noisy_reference_is_zero(rng_np):
    R, n = 8, 50000
    X = 1.0 + rng_np.standard_normal((R, n))
    ref_var = 0.25
    Y = 1.0 + np.sqrt(ref_var) * rng_np.standard_normal(n)
    b2 = stats.error_stats(X, Y, reference_variance=ref_var).bias2
    assert abs(b2.mean()) < critical_t(n - 1, 1) * b2.std(ddof=1) / np.sqrt(n)


def test_slopes_recover_power_laws(rng_np):
    x = np.logspace(0, 4, 12)
    exact = stats.loglog_slope(x, 3.0 * x ** -0.5)
    assert abs(exact.slope + 0.5) < 1e-12 and exact.stderr < 1e-10
    # noisy: z-scores of the fitted slope over replicates have unit spread (calibrated stderr)
    zs = []
    for _ in range(400):
        y = 3.0 * x ** -1.0 * np.exp(0.1 * rng_np.standard_normal(x.size))
        s = stats.loglog_slope(x, y)
        zs.append((s.slope + 1.0) / s.stderr)
    zs = np.array(zs)
    assert abs(zs.mean()) < 5 / np.sqrt(len(zs))
    assert 0.8 < zs.std() < 1.25  # t with 10 dof has std 1.12
    w = stats.loglog_slope(x, 3.0 * x ** -2.0, sigma_log_y=np.full(x.size, 0.1))
    assert abs(w.slope + 2.0) < 1e-12


def test_image_average_and_efficiency():
    m, lo, hi = stats.image_average(np.arange(100.0))
    assert lo < m == 49.5 < hi
    assert stats.efficiency(0.5, 4.0) == 0.5
