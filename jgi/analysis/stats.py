"""Error statistics of estimators, as pure numpy functions usable from research code.

Given R independent renders X_r (repetitions with different seeds) and a reference image Y
(itself an estimate with per-pixel variance var_Y / its own sample count, or exact):

  mean        m = (1/R) sum_r X_r
  variance    s^2 = 1/(R-1) sum_r (X_r - m)^2       (unbiased, per pixel)
  bias^2      (m - Y)^2 - s^2 / R - var(Y)           (unbiased for (E X - E Y)^2: the squared
              difference of two noisy means overestimates the squared bias by their variances)
  MSE         bias^2 + s^2  (the expected squared error of one render)
  rel. MSE    MSE / (Y^2 + eps)   (eps = 1e-2 by default, so black pixels do not dominate)
  efficiency  1 / (MSE * seconds per render)

Image averages come with normal-theory confidence intervals over pixels. Convergence slopes are
least-squares fits of log y on log x with their standard errors (ordinary, or weighted by given
standard deviations of log y).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.stats


class ErrorStats(NamedTuple):
    mean: np.ndarray
    variance: np.ndarray
    bias2: np.ndarray
    mse: np.ndarray
    rel_mse: np.ndarray


def error_stats(renders, reference, reference_variance=0.0, eps: float = 1e-2) -> ErrorStats:
    """Per-pixel statistics of ``renders`` (R, ...) against ``reference`` (...)."""
    X = np.asarray(renders, np.float64)
    if X.shape[0] < 2:
        raise ValueError("need at least two repetitions to estimate a variance")
    Y = np.asarray(reference, np.float64)
    R = X.shape[0]
    m = X.mean(0)
    s2 = X.var(0, ddof=1)
    bias2 = (m - Y) ** 2 - s2 / R - np.asarray(reference_variance, np.float64)
    mse = bias2 + s2
    return ErrorStats(m, s2, bias2, mse, mse / (Y * Y + eps))


def image_average(values, confidence: float = 0.95) -> tuple[float, float, float]:
    """(mean, lower, upper): the average over pixels with a normal confidence interval."""
    v = np.asarray(values, np.float64).ravel()
    m = v.mean()
    se = v.std(ddof=1) / np.sqrt(v.size) if v.size > 1 else 0.0
    z = scipy.stats.norm.ppf(0.5 + confidence / 2)
    return float(m), float(m - z * se), float(m + z * se)


def efficiency(mse: float, seconds: float) -> float:
    return 1.0 / (mse * seconds)


class Slope(NamedTuple):
    slope: float
    intercept: float
    stderr: float


def loglog_slope(x, y, sigma_log_y=None) -> Slope:
    """Fit log y = slope log x + intercept (weighted by 1/sigma^2 when ``sigma_log_y`` given)."""
    lx, ly = np.log(np.asarray(x, np.float64)), np.log(np.asarray(y, np.float64))
    A = np.stack([lx, np.ones_like(lx)], 1)
    if sigma_log_y is None:
        w = np.ones_like(lx)
    else:
        w = 1.0 / np.asarray(sigma_log_y, np.float64) ** 2
    Aw = A * w[:, None]
    cov_unscaled = np.linalg.inv(A.T @ Aw)
    coef = cov_unscaled @ (Aw.T @ ly)
    resid = ly - A @ coef
    dof = max(len(lx) - 2, 1)
    if sigma_log_y is None:
        cov = cov_unscaled * (resid @ resid) / dof
    else:
        cov = cov_unscaled
    return Slope(float(coef[0]), float(coef[1]), float(np.sqrt(cov[0, 0])))
