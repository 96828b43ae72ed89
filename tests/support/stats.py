"""Statistical comparisons of renders: per-region means, Student-t critical values with a
Bonferroni correction, and Welch's test between two stacks of independent renders."""

from __future__ import annotations

import numpy as np
from scipy import stats


def region_stats(images: np.ndarray, regions: int = 4):
    """Per-region means of each repetition -> (mean over repetitions, standard error).

    ``images``: (R, H, W, 3) independent renders (different seeds). Regions are a
    ``regions x regions`` grid; the luminance-free RGB channels are kept separate."""
    R, H, W, _ = images.shape
    h, w = H // regions, W // regions
    blocks = images[:, : h * regions, : w * regions].reshape(R, regions, h, regions, w, 3)
    per_rep = blocks.mean(axis=(2, 4))  # (R, regions, regions, 3)
    mean = per_rep.mean(0)
    se = per_rep.std(0, ddof=1) / np.sqrt(R)
    return mean, se


FAMILY_ALPHA = 1e-4  # probability that a correct estimator fails one whole comparison


def critical_t(dof, n_tests: int, alpha: float = FAMILY_ALPHA):
    """Two-sided Student-t critical value with Bonferroni correction over ``n_tests``.

    Standard errors estimated from a handful of repetitions are themselves noisy, so the
    statistic |mean difference| / standard error follows Student's t, not the normal law: with
    6 repetitions, 5 'sigma' is exceeded with probability 4e-3 per comparison, and a 16-region
    RGB image makes 48 comparisons. This threshold keeps the false-alarm rate at ``alpha``."""
    return stats.t.ppf(1.0 - alpha / (2.0 * n_tests), dof)


def assert_agree(a: np.ndarray, b: np.ndarray, regions: int = 4, label: str = "",
                 alpha: float = FAMILY_ALPHA):
    """Two stacks of independent renders agree per region (Welch's t-test per region and
    channel, Bonferroni-corrected to a family-wise false-alarm rate ``alpha``)."""
    ma, sa = region_stats(a, regions)
    mb, sb = region_stats(b, regions)
    na, nb = len(a), len(b)
    var = sa**2 + sb**2
    # a floor for regions that are exactly deterministic in both (variance 0)
    var = np.maximum(var, (1e-6 * np.maximum(np.abs(ma), 1e-3)) ** 2)
    dof = var**2 / np.maximum(sa**4 / (na - 1) + sb**4 / (nb - 1), 1e-300)  # Welch-Satterthwaite
    t = np.abs(ma - mb) / np.sqrt(var)
    crit = critical_t(np.clip(dof, 1.0, None), t.size, alpha)
    ratio = t / crit
    worst = np.unravel_index(np.argmax(ratio), ratio.shape)
    assert ratio.max() < 1.0, (f"{label}: region {worst[:2]} channel {worst[2]} differs by "
                               f"t = {t[worst]:.1f} > {crit[worst]:.1f} "
                               f"({ma[worst]:.5f} vs {mb[worst]:.5f})")
    return t
