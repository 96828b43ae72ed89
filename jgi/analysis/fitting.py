"""Fitting continuous estimator parameters by gradient: MSE objectives and optimistix solvers.

The estimators are pure functions of (scene, parameters, random stream), so the mean squared
error of an estimator as a function of a continuous parameter theta (a photon radius, a cone
filter's k, a Gaussian filter's gauss_alpha and gauss_beta, progressive photon mapping's
radius_alpha) can be estimated by the *sample-average approximation*: fix R random streams
(common random numbers),

    MSE_R(theta) = (1/R) sum_r mean_pixels (X(theta; xi_r) - L)^2,

a deterministic, differentiable function of theta whose minimiser converges to the true
MSE-optimal theta as R grows. ``jax.grad`` differentiates it; optimistix minimises it.

Functions here are generic: the photon-radius and filter study
(``experiments/studies/fit_density.py``) plugs estimators into them;
:mod:`jgi.analysis.density_fit` is the photon-density test bed.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax import Array


def sample_average_mse(estimate: Callable[[Array, Array], Array], reference: Array,
                       streams: Array) -> Callable[[Array], Array]:
    """theta -> MSE_R(theta) for ``estimate(theta, stream) -> values`` (any shape), averaged
    over the fixed ``streams`` (common random numbers, one row per repetition)."""
    def mse(theta):
        err = jax.vmap(lambda s: estimate(theta, s) - reference)(streams)
        return jnp.mean(err * err)
    return mse


class FitResult(NamedTuple):
    theta: Array
    value: Array        # objective at theta
    steps: int
    converged: bool


def minimise(loss: Callable[[Array], Array], theta0, *, rtol: float = 1e-7, atol: float = 1e-9,
             max_steps: int = 256, log_space: bool = False) -> FitResult:
    """Minimise a smooth scalar ``loss`` with BFGS (optimistix). ``log_space`` optimises
    log(theta) for positive parameters such as radii (scale-free steps, positivity kept)."""
    theta0 = jnp.asarray(theta0, jnp.float32)
    if log_space:
        fn = lambda y, _: loss(jnp.exp(y))
        y0 = jnp.log(theta0)
    else:
        fn = lambda y, _: loss(y)
        y0 = theta0
    sol = optx.minimise(fn, optx.BFGS(rtol=rtol, atol=atol), y0, max_steps=max_steps, throw=False)
    theta = jnp.exp(sol.value) if log_space else sol.value
    return FitResult(theta, loss(theta), int(sol.stats["num_steps"]),
                     bool(sol.result == optx.RESULTS.successful))


def least_squares(residuals: Callable[[Array], Array], theta0, *, rtol: float = 1e-8,
                  atol: float = 1e-10, max_steps: int = 256) -> FitResult:
    """Levenberg-Marquardt on ``residuals(theta) -> vector`` (optimistix)."""
    theta0 = jnp.asarray(theta0, jnp.float32)
    sol = optx.least_squares(lambda y, _: residuals(y),
                             optx.LevenbergMarquardt(rtol=rtol, atol=atol),
                             theta0, max_steps=max_steps, throw=False)
    r = residuals(sol.value)
    return FitResult(sol.value, 0.5 * jnp.sum(r * r), int(sol.stats["num_steps"]),
                     bool(sol.result == optx.RESULTS.successful))


def power_law(x, y) -> tuple[float, float, float]:
    """Fit y = c x^p by least squares in log-log space: (p, c, standard error of p)."""
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    A = np.stack([lx, np.ones_like(lx)], axis=1)
    coef, *_ = np.linalg.lstsq(A, ly, rcond=None)
    resid = ly - A @ coef
    dof = max(len(lx) - 2, 1)
    s2 = resid @ resid / dof
    cov = s2 * np.linalg.inv(A.T @ A)
    return float(coef[0]), float(np.exp(coef[1])), float(np.sqrt(cov[0, 0]))
