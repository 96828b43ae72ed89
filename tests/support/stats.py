"""Statistical comparisons of renders for the tests: :func:`assert_agree` over
:func:`jgi.analysis.stats.region_agreement` (Welch's test per region, Bonferroni-corrected)."""

from __future__ import annotations

import numpy as np

from jgi.analysis.stats import FAMILY_ALPHA, critical_t, region_agreement, region_stats

__all__ = ["FAMILY_ALPHA", "assert_agree", "critical_t", "region_stats"]


def assert_agree(a: np.ndarray, b: np.ndarray, regions: int = 4, label: str = "",
                 alpha: float = FAMILY_ALPHA):
    """Two stacks of independent renders agree per region (Welch's t-test per region and
    channel, Bonferroni-corrected to a family-wise false-alarm rate ``alpha``)."""
    r = region_agreement(a, b, regions, alpha)
    w = r.worst
    assert r.agree, (f"{label}: region {w[:2]} channel {w[2]} differs by "
                     f"t = {r.t[w]:.1f} > {r.critical[w]:.1f} "
                     f"({r.mean_a[w]:.5f} vs {r.mean_b[w]:.5f})")
    return r.t
