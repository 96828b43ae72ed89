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
standard deviations of log y). Two stacks of renders are compared region by region with
Welch's t-test (:func:`region_agreement`), as the test suite and the peer benchmarks do.
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


class SlopeFit(NamedTuple):
    """A fitted log-log slope with its standard error and confidence interval [lo, hi]."""
    slope: float
    intercept: float
    stderr: float
    lo: float
    hi: float
    confidence: float


def fit_error_slope(x, y, y_se, confidence: float = 0.95) -> SlopeFit:
    """The slope of log y against log x for error measures y (MSE, variance, bias^2) known to
    standard errors ``y_se`` (from the repetitions and pixels of each point, independent
    between points), and its confidence interval.

    Weighted least squares with sigma(log y) = y_se / y (the delta method). The standard error
    is the weights' one, inflated by sqrt(chi^2 / dof) when the points scatter more than their
    own errors allow (the Birge ratio: a curve that is not a power law, or errors stated too
    small, widen the interval rather than narrow it); the interval is slope +- z stderr. A
    residual-only error (``loglog_slope`` without sigma) would treat a handful of points as
    their own noise estimate and, when the points share noise, state too narrow an interval."""
    x, y, y_se = (np.asarray(a, np.float64) for a in (x, y, y_se))
    sigma = np.maximum(y_se / y, 1e-12)
    fit = loglog_slope(x, y, sigma)
    resid = np.log(y) - (fit.slope * np.log(x) + fit.intercept)
    dof = len(x) - 2
    birge = np.sqrt(max(1.0, float(np.sum((resid / sigma) ** 2)) / dof)) if dof > 0 else 1.0
    se = fit.stderr * birge
    z = scipy.stats.norm.ppf(0.5 + confidence / 2)
    return SlopeFit(fit.slope, fit.intercept, float(se), float(fit.slope - z * se),
                    float(fit.slope + z * se), confidence)


def pixel_mean_and_se(per_pixel) -> tuple[float, float]:
    """The image average of a per-pixel error measure ([H, W] or [H, W, C]: channels averaged
    first, since a pixel's channels come from the same paths) and its standard error over
    pixels, which are independent (each has its own random streams)."""
    v = np.asarray(per_pixel, np.float64)
    v = v.reshape(v.shape[0] * v.shape[1], -1).mean(-1) if v.ndim == 3 else v.ravel()
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else 0.0


def combine_chunks(images, samples) -> tuple[np.ndarray, np.ndarray]:
    """One render from independent chunks: ``images`` [n, ...] of ``samples`` [n] samples each.

    The mean weights each chunk by its samples, m = sum(s_i x_i) / S, which is exactly the
    image of S samples. With var(x_i) = sigma^2 / s_i per pixel, sum(s_i (x_i - m)^2) / (n - 1)
    estimates sigma^2 without bias, so the variance of m is that over S. Returns (m, var(m)) per
    pixel; n >= 2."""
    x = np.asarray(images, np.float64)
    s = np.asarray(samples, np.float64).reshape((-1,) + (1,) * (x.ndim - 1))
    if x.shape[0] < 2:
        raise ValueError("combine_chunks needs at least two chunks to estimate a variance")
    total = s.sum()
    mean = (s * x).sum(0) / total
    sigma2 = (s * (x - mean) ** 2).sum(0) / (x.shape[0] - 1)
    return mean.astype(np.float32), (sigma2 / total).astype(np.float32)


def region_stats(images: np.ndarray, regions: int = 4):
    """Per-region means of each repetition -> (mean over repetitions, standard error).

    ``images``: (R, H, W, 3) independent renders (different seeds). Regions are a
    ``regions x regions`` grid; the RGB channels are kept separate."""
    R, H, W, _ = images.shape
    h, w = H // regions, W // regions
    blocks = images[:, : h * regions, : w * regions].reshape(R, regions, h, regions, w, 3)
    per_rep = blocks.mean(axis=(2, 4))  # (R, regions, regions, 3)
    return per_rep.mean(0), per_rep.std(0, ddof=1) / np.sqrt(R)


FAMILY_ALPHA = 1e-4  # probability that two renders of one expectation fail a whole comparison


def critical_t(dof, n_tests: int, alpha: float = FAMILY_ALPHA):
    """Two-sided Student-t critical value with Bonferroni correction over ``n_tests``.

    Standard errors estimated from a handful of repetitions are themselves noisy, so the
    statistic |mean difference| / standard error follows Student's t, not the normal law: with
    6 repetitions, 5 'sigma' is exceeded with probability 4e-3 per comparison, and a 16-region
    RGB image makes 48 comparisons. This threshold keeps the false-alarm rate at ``alpha``."""
    return scipy.stats.t.ppf(1.0 - alpha / (2.0 * n_tests), dof)


class RegionAgreement(NamedTuple):
    """Welch's t per region and channel, its Bonferroni critical value, and the region means."""
    t: np.ndarray
    critical: np.ndarray
    mean_a: np.ndarray
    mean_b: np.ndarray

    @property
    def worst(self) -> tuple:
        """(row, column, channel) of the largest t / critical."""
        return np.unravel_index(np.argmax(self.t / self.critical), self.t.shape)

    @property
    def agree(self) -> bool:
        return bool(np.all(self.t < self.critical))


def region_agreement(a: np.ndarray, b: np.ndarray, regions: int = 4,
                     alpha: float = FAMILY_ALPHA) -> RegionAgreement:
    """Do two stacks of independent renders (R, H, W, 3) estimate the same image? Welch's
    t-test per region and channel, both sides' variances from their repetitions,
    Bonferroni-corrected to a family-wise false-alarm rate ``alpha``."""
    ma, sa = region_stats(a, regions)
    mb, sb = region_stats(b, regions)
    na, nb = len(a), len(b)
    var = sa**2 + sb**2
    # a floor for regions that are exactly deterministic in both (variance 0)
    var = np.maximum(var, (1e-6 * np.maximum(np.abs(ma), 1e-3)) ** 2)
    dof = var**2 / np.maximum(sa**4 / (na - 1) + sb**4 / (nb - 1), 1e-300)  # Welch-Satterthwaite
    t = np.abs(ma - mb) / np.sqrt(var)
    return RegionAgreement(t, critical_t(np.clip(dof, 1.0, None), t.size, alpha), ma, mb)
