"""Statistical comparisons of renders for the tests: :func:`assert_agree` over
:func:`jgi.analysis.stats.region_agreement` (Welch's test per region, Bonferroni-corrected)."""

from __future__ import annotations

import numpy as np

from jgi.analysis.stats import FAMILY_ALPHA, critical_t, region_agreement, region_stats

__all__ = ["FAMILY_ALPHA", "assert_agree", "critical_t", "mean_change", "region_stats",
           "tells_apart"]


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


def mean_change(render, scene, perturbed, seeds=range(16)) -> np.ndarray:
    """The change of the expected image from ``scene`` to ``perturbed`` as a fast estimator
    measures it (``render(scene, seed)``, a stack over ``seeds`` each, seeds of their own)."""
    return (np.mean([render(perturbed, 7000 + s) for s in seeds], 0)
            - np.mean([render(scene, 7000 + s) for s in seeds], 0))


def tells_apart(stack: np.ndarray, reference: np.ndarray, change: np.ndarray,
                regions: int = 4, alpha: float = FAMILY_ALPHA):
    """The power check of an agreement test, without rendering the slow estimator a second
    time: ``stack`` offset by ``change`` (the image a perturbed scene gives, minus the scene's,
    from :func:`mean_change`) must fail the same per-region test against ``reference``. The
    offset stack keeps the estimator's own seed spread, so this is the test's power against a
    bias as large as the perturbation's (what a render of the perturbed scene would check,
    at the cost of a path tracer's renders). Returns the RegionAgreement (``not r.agree``)."""
    return region_agreement(stack + change[None], reference, regions, alpha)
