"""Light tracing (t = 1) against a closed form, against the path tracer, and for robustness.

Statistical checks use fixed seeds and Student-t thresholds (Bonferroni over regions and
channels) on standard errors measured from independent renders, as in test_path_tracer.
"""

from __future__ import annotations

import numpy as np
import pytest

import jgi
from jgi.scene import builtin as scenes
from tests.support.scenes import degenerate_scene, point_light_reference
from tests.support.stats import assert_agree, critical_t, region_stats

SEEDS = range(12)


def renders(scene, estimator="lt", seeds=SEEDS, spp=16, **params):
    return np.stack([jgi.render(scene, estimator, spp=spp, seed=s, **params) for s in seeds])


def test_point_light_over_plane_matches_closed_form():
    """Light tracing renders the point light's direct illumination of a diffuse plane, which
    pure BSDF sampling cannot (jgi.estimators.light_tracer's docstring)."""
    rho, I, h = 0.5, 10.0, 1.0
    scene = scenes.point_light_plane(resolution=16, intensity=I, height=h, albedo=rho)
    imgs = renders(scene, spp=32, max_depth=2)
    ref = point_light_reference(scene, rho, I, h)
    mean, se = region_stats(imgs, regions=4)
    ref_regions = ref.reshape(4, 4, 4, 4).mean(axis=(1, 3))
    assert np.all(se[..., 0] > 0)
    z = np.abs(mean[..., 0] - ref_regions) / se[..., 0]
    assert z.max() < critical_t(len(imgs) - 1, z.size), z
    se_total = imgs.mean(axis=(1, 2, 3)).std(ddof=1) / np.sqrt(len(imgs))
    assert abs(imgs.mean() - ref.mean()) < critical_t(len(imgs) - 1, 1) * se_total


def test_agrees_with_path_tracer_on_cornell_box():
    scene = scenes.cornell_box(resolution=16)
    lt = renders(scene, spp=64, max_depth=3)
    pt = renders(scene, "pt", spp=64, max_depth=3, rr_depth=-1)
    assert_agree(lt, pt, regions=4, label="lt vs pt, cornell_box")


def test_reproducible_and_seed_dependent():
    scene = scenes.point_light_plane(resolution=16)
    a = jgi.render(scene, "lt", spp=4, seed=3, max_depth=2)
    b = jgi.render(scene, "lt", spp=4, seed=3, max_depth=2)
    c = jgi.render(scene, "lt", spp=4, seed=4, max_depth=2)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_no_nan_or_inf_on_degenerate_inputs():
    """Zero-area and zero-radius lights, point/spot/directional/environment lights, total
    internal reflection, an index-matched sphere and a camera in the floor plane."""
    with np.errstate(all="raise"):
        img = jgi.render(degenerate_scene(), "lt", spp=8, seed=0, max_depth=3)
    assert np.all(np.isfinite(img))
    assert img.max() > 0


def test_parameters_are_checked():
    with pytest.raises(jgi.ParameterError, match="max_depth"):
        jgi.render(scenes.furnace(resolution=4), "lt", max_depth=0)
