"""Gradient fitting of photon-density parameters against the exact irradiance of a point light
over a plane (jgi.analysis.density_fit)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jgi.analysis import density_fit as D
from jgi.analysis import fitting as F


@pytest.fixture(scope="module")
def problem():
    return D.point_light_problem(5000, 4, r_max=1.0, candidates=4096, seed=3)


def test_estimate_matches_the_kernel_smoothed_irradiance(problem):
    """The estimate's expectation is the kernel-smoothed irradiance, int W(|y - x|) E(y) dy / K,
    computed here by quadrature: the mean over maps of E_hat / E matches it within 5 standard
    errors (no allowance for the kernel's bias, which the expectation contains)."""
    r = 0.3
    u = np.linspace(-0.8, 0.8, 8)  # point_light_problem's default query grid
    px, pz = (a.ravel() for a in np.meshgrid(u, u))
    rho = (np.arange(200) + 0.5) / 200 * r
    phi = (np.arange(256) + 0.5) / 256 * 2 * np.pi
    R, P = np.meshgrid(rho, phi, indexing="ij")
    area = (r / 200) * (2 * np.pi / 256) * R  # polar area elements
    w = (1 - (R / r) ** 2) * area / (0.5 * np.pi * r * r)
    smoothed = np.array([np.sum(w * D.irradiance(np.hypot(x + R * np.cos(P), z + R * np.sin(P)),
                                                 10.0, 1.0))
                         for x, z in zip(px, pz)])
    expected = (smoothed / np.asarray(problem.exact)).mean()
    ratio = np.asarray(D.estimate(problem, r)) / np.asarray(problem.exact)
    per_map = ratio.mean(1)  # maps are independent; points of one map are not
    se = per_map.std(ddof=1) / np.sqrt(per_map.size)
    assert abs(per_map.mean() - expected) < 5 * se, (per_map.mean(), expected, se)
    assert expected < 0.995  # the kernel's bias is real here: the test distinguishes it


def test_gradient_matches_central_differences(problem):
    f = jax.jit(lambda r: D.relative_mse(problem, r))
    for r in (0.3, 0.55, 0.8):
        g = float(jax.grad(lambda r: D.relative_mse(problem, r))(np.float32(r)))
        h = 1e-3 * r
        fd = (float(f(np.float32(r + h))) - float(f(np.float32(r - h)))) / (2 * h)
        assert abs(g - fd) <= 0.02 * abs(fd) + 1e-4, (r, g, fd)


def test_fitted_radius_is_the_minimum_of_the_objective(problem):
    loss = jax.jit(lambda r: D.relative_mse(problem, r))
    fit = F.minimise(loss, 0.3, log_space=True)
    assert fit.converged
    grid = np.geomspace(0.2, 0.95, 200)
    values = np.array([float(loss(r)) for r in grid])
    best = grid[values.argmin()]
    assert (abs(float(fit.theta) - best)
            <= 2 * (grid[1] - grid[0]) * best / grid[0]), (float(fit.theta), best)
    assert float(fit.value) <= values.min() * (1 + 1e-3)
    # an interior optimum: bias dominates above it, variance below
    b2_hi, v_hi = (float(x) for x in D.mse_terms(problem, 0.9))
    b2_lo, v_lo = (float(x) for x in D.mse_terms(problem, 0.25))
    assert b2_hi > b2_lo and v_lo > v_hi


def test_fitted_gaussian_is_no_worse_than_jensens(problem):
    import jax.numpy as jnp

    def gauss(theta):
        return D.relative_mse(problem, 0.55, "gaussian", normalised=False, gauss_alpha=theta[0],
                              gauss_beta=jnp.exp(theta[1]))

    start = jnp.array([0.918, np.log(1.953)], jnp.float32)
    fit = F.minimise(gauss, start)
    assert float(fit.value) < float(gauss(start))
    # Jensen's filter divided by pi r^2 integrates to 0.53 of the disc: it underestimates by half
    # unless normalised; the fitted scale brings the estimate back towards unbiased.
    from jgi.transport.density import gaussian_normaliser
    assert float(gaussian_normaliser(0.918, 1.953)) == pytest.approx(0.531, abs=1e-3)
    assert 0.75 < float(gaussian_normaliser(fit.theta[0], jnp.exp(fit.theta[1]))) < 1.1


def test_progressive_single_pass_is_the_kernel_estimate(problem):
    one = D.progressive_estimate(problem, 1, 0.5, 0.7)
    np.testing.assert_allclose(np.asarray(one), np.asarray(D.estimate(problem, 0.5)), rtol=2e-5,
                               atol=1e-6)


def test_progressive_alpha_gradient_and_fit():
    """PPM's alpha fitted by gradient: the derivative matches central differences and the fit is
    the minimum of the sample-average objective over a dense grid of alpha."""
    import jax.numpy as jnp

    prob = D.point_light_problem(2000, 16, r_max=1.0, candidates=2048, seed=11)
    loss = jax.jit(lambda a: D.progressive_relative_mse(prob, 4, 0.8, a))
    for a in (0.3, 0.6, 0.9):
        g = float(jax.grad(lambda a: D.progressive_relative_mse(prob, 4, 0.8, a))(jnp.float32(a)))
        h = 1e-3
        fd = (float(loss(jnp.float32(a + h))) - float(loss(jnp.float32(a - h)))) / (2 * h)
        assert abs(g - fd) <= 0.02 * abs(fd) + 1e-5, (a, g, fd)
    fit = F.minimise(lambda y: loss(jax.nn.sigmoid(y)), jnp.float32(0.0))
    alpha = float(jax.nn.sigmoid(fit.theta))
    grid = np.linspace(0.02, 0.98, 97)
    values = np.array([float(loss(jnp.float32(a))) for a in grid])
    # The objective is continuous but its derivative jumps where a photon crosses a shrinking
    # radius (the kernel's slope at r), so BFGS stops within such a kink of the optimum.
    assert float(loss(jnp.float32(alpha))) <= values.min() * 1.01, (alpha, grid[values.argmin()])
    assert abs(alpha - grid[values.argmin()]) < 0.05
    assert values[0] > 2 * values.min() and values.argmin() > 0  # an interior optimum
