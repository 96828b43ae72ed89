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


def test_mse_slope_intervals_are_calibrated_on_a_closed_form_case():
    """Many independent small studies of the point light over a plane (exact reference): the
    reported 95 % interval of the MSE slope, from the statistics a study computes
    (error_stats, pixel_mean_and_se, fit_error_slope), contains the true -1 in 90-99 % of them.

    The studies are the 400 tiles of 8 x 8 pixels of 160^2 renders: pixels have independent
    random streams, so each tile is its own study of 5 sweep points x 3 repetitions, every
    render with its own seed, as jgi.experiment.plan gives them."""
    import jgi
    from jgi.analysis import closed_form
    from jgi.experiment import run_seed

    scene = jgi.load_scene("point_light_plane", resolution=160)
    reference = closed_form.point_light_plane_image(scene, per_axis=16)
    spps, reps, tile = (1, 2, 4, 8, 16), 3, 8

    def tiles(img):
        return img.reshape(20, tile, 20, tile, 3).swapaxes(1, 2).reshape(400, tile, tile, 3)

    ref_tiles = tiles(reference)
    mse = np.zeros((400, len(spps)))
    se = np.zeros_like(mse)
    for j, spp in enumerate(spps):
        renders = np.stack([tiles(jgi.render(scene, "pt", spp=spp, seed=run_seed(7, 0, j, r)))
                            for r in range(reps)])                       # [reps, 400, 8, 8, 3]
        for k in range(400):
            s = stats.error_stats(renders[:, k], ref_tiles[k])
            mse[k, j], se[k, j] = stats.pixel_mean_and_se(s.mse)
    fits = [stats.fit_error_slope(np.array(spps), mse[k], se[k]) for k in range(400)
            if np.all(mse[k] > 0)]
    covered = np.mean([f.lo <= -1.0 <= f.hi for f in fits])
    assert len(fits) > 380
    assert 0.90 <= covered <= 0.99, covered
