"""The path tracer against closed forms, against itself under every strategy, and for robustness.

Every statistical check uses fixed seeds and a tolerance of 5 standard errors, with the standard
error measured from independent renders (different seeds) of the same configuration.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jgi
from jgi.core.configured import Configured
from jgi.drivers import chunked as R
from jgi.drivers import wavefront as W
from jgi.scene import builtin as scenes
from tests.support.scenes import degenerate_scene, point_light_reference
from tests.support.stats import assert_agree, critical_t, region_stats

SEEDS = range(16)  # enough repetitions for a well-estimated standard error


def renders(scene, seeds=SEEDS, spp=16, **params):
    return np.stack([jgi.render(scene, "pt", spp=spp, seed=s, **params) for s in seeds])


# --- closed forms -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def furnace():
    return scenes.furnace(resolution=8, albedo=0.6, emission=1.5)


@pytest.mark.parametrize("strategy", ["bsdf", "light", "mis"])
@pytest.mark.parametrize("depth", [1, 3, 6])
def test_white_furnace_every_depth(furnace, strategy, depth):
    """Closed box, every wall emits L_e and reflects rho: L = L_e (1 + rho + ... + rho^(D-1))."""
    expected = 1.5 * sum(0.6**k for k in range(depth))
    imgs = renders(furnace, spp=8, strategy=strategy, max_depth=depth, rr_depth=-1)
    mean, se = region_stats(imgs, regions=2)
    if strategy == "bsdf":  # every path carries exactly the expected value
        np.testing.assert_allclose(imgs, expected, rtol=2e-5)
    crit = critical_t(len(imgs) - 1, mean.size)
    assert np.all(np.abs(mean - expected) <= crit * se + 2e-5 * expected), (mean, se, expected)


def test_white_furnace_russian_roulette_is_unbiased(furnace):
    expected = 1.5 * sum(0.6**k for k in range(8))
    imgs = renders(furnace, spp=16, strategy="bsdf", max_depth=8, rr_depth=2)
    mean, se = region_stats(imgs, regions=2)
    assert np.all(se > 0), "Russian roulette should add variance"
    assert np.all(np.abs(mean - expected)
                  <= critical_t(len(imgs) - 1, mean.size) * se), (mean, se, expected)


@pytest.mark.parametrize("strategy", ["light", "mis"])
def test_point_light_over_plane_matches_closed_form(strategy):
    rho, I, h = 0.5, 10.0, 1.0
    scene = scenes.point_light_plane(resolution=16, intensity=I, height=h, albedo=rho)
    imgs = renders(scene, seeds=range(12), spp=8, strategy=strategy, max_depth=2)
    ref = point_light_reference(scene, rho, I, h)
    assert ref.min() > 0
    mean, se = region_stats(imgs, regions=4)
    ref_regions = ref.reshape(4, 4, 4, 4).mean(axis=(1, 3))
    z = np.abs(mean[..., 0] - ref_regions) / se[..., 0]
    assert z.max() < critical_t(len(imgs) - 1, z.size), z
    # grey light and albedo: the three channels carry identical values
    np.testing.assert_array_equal(imgs[..., 0], imgs[..., 2])
    se_total = imgs.mean(axis=(1, 2, 3)).std(ddof=1) / np.sqrt(len(imgs))
    assert abs(imgs.mean() - ref.mean()) < critical_t(len(imgs) - 1, 1) * se_total


def test_bsdf_sampling_cannot_see_point_lights():
    scene = scenes.point_light_plane(resolution=8)
    img = jgi.render(scene, "pt", spp=4, strategy="bsdf")
    assert np.all(img == 0.0)


# --- strategies agree -------------------------------------------------------------------------

@pytest.fixture(scope="module")
def cornell():
    return scenes.cornell_box(resolution=16)


@pytest.fixture(scope="module")
def cornell_reference(cornell):
    return renders(cornell, spp=12, strategy="mis", heuristic="balance")


@pytest.mark.parametrize("params", [
    dict(strategy="bsdf"),
    dict(strategy="light"),
    dict(strategy="mis", heuristic="power", power=2.0),
    dict(strategy="mis", heuristic="balance", light_samples=3),
])
def test_strategies_agree_on_cornell_box(cornell, cornell_reference, params):
    imgs = renders(cornell, spp=12, **params)
    assert_agree(imgs, cornell_reference, regions=4, label=str(params))


def test_path_lengths_sum_to_the_full_image(cornell, cornell_reference):
    """Fixed-length renders (exactly L segments) add up to the max-depth render."""
    depth = 4
    full = renders(cornell, spp=12, max_depth=depth, rr_depth=-1)
    parts = sum(renders(cornell, spp=12, seeds=[100 + 10 * L + s for s in SEEDS], path_length=L,
                        rr_depth=-1) for L in range(1, depth + 1))
    assert_agree(parts, full, regions=4, label="sum of path lengths")
    direct_only = renders(cornell, spp=8, seeds=[0], path_length=1)[0]
    lit = direct_only.max(-1) > 0
    assert 0 < lit.mean() < 0.2  # only the light itself is visible with one segment


# --- multiple importance sampling weights -------------------------------------------------------

def test_mis_weights_sum_to_one(rng_np):
    from jgi.transport import mis

    for power in (1.0, 2.0, 3.5):
        p = (rng_np.exponential(size=(3, 1000)).astype(np.float32)
             * 10.0 ** rng_np.uniform(-6, 6, (3, 1000)))
        n = np.array([1.0, 3.0, 2.0])
        total = sum(mis.heuristic_weight(n[i], p[i], [(n[j], p[j]) for j in range(3) if j != i],
                                         power)
                    for i in range(3))
        np.testing.assert_allclose(np.asarray(total), 1.0, rtol=1e-5)
    # extreme ratios stay finite and in [0, 1]
    w = mis.power(1.0, jnp.float32(1e30), 1.0, jnp.float32(1e-30))
    assert np.isfinite(w) and 0.99 <= float(w) <= 1.0
    assert float(mis.balance(1.0, jnp.float32(0.0), 1.0, jnp.float32(0.0))) == 0.0


# --- determinism, chunking and compilation --------------------------------------------------------

def test_same_seed_same_image_different_seed_independent(cornell):
    a = jgi.render(cornell, "pt", spp=4, seed=7)
    b = jgi.render(cornell, "pt", spp=4, seed=7)
    c = jgi.render(cornell, "pt", spp=4, seed=8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_different_seeds_give_independent_noise():
    """On the furnace (known mean, light-tailed noise) the residuals of two seeds are
    uncorrelated: |r| < 5 / sqrt(n) for n pixels."""
    scene = scenes.furnace(resolution=32, albedo=0.6, emission=1.5)
    expected = 1.5 * sum(0.6**k for k in range(3))
    a = jgi.render(scene, "pt", spp=2, seed=7, max_depth=3)[..., 0].ravel() - expected
    c = jgi.render(scene, "pt", spp=2, seed=8, max_depth=3)[..., 0].ravel() - expected
    assert a.std() > 0
    assert abs(np.corrcoef(a, c)[0, 1]) < 5 / np.sqrt(a.size)


def test_image_does_not_depend_on_chunking(cornell):
    from jgi.estimators.path_tracer import PathTracerConfig, trace_pixels

    fn = Configured(trace_pixels, PathTracerConfig())
    a = R.render_paths(cornell, fn, spp=6, seed=3, chunk=256)
    b = R.render_paths(cornell, fn, spp=6, seed=3, chunk=1024)
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


def compilations() -> int:
    """Compiled versions of the wavefront driver's loop, over every configuration (JAX's compile
    cache keys on the path tracer's step with its settings, and on the scene's structure)."""
    return W.wavefront_call._cache_size()


def test_one_compilation_serves_every_spp_and_seed(cornell):
    jgi.render(cornell, "pt", spp=3, seed=1, max_depth=5)
    before = compilations()
    assert before >= 1
    jgi.render(cornell, "pt", spp=5, seed=2, max_depth=5)
    jgi.render(cornell, "pt", spp=17, seed=3, max_depth=5)
    assert compilations() == before  # no new compilation, of this configuration or any other


def test_scene_values_are_arguments_not_constants(cornell):
    """Changing an albedo reuses the compiled kernel (values are pytree leaves) and changes the
    image."""
    jgi.render(cornell, "pt", spp=2, seed=0, max_depth=5)
    before = compilations()
    brighter = jax.tree_util.tree_map(lambda x: x, cornell)
    import equinox as eqx
    brighter = eqx.tree_at(lambda s: s.materials.diffuse.x, brighter,
                           cornell.materials.diffuse.x * 0.5)
    a = jgi.render(cornell, "pt", spp=2, seed=0, max_depth=5)
    b = jgi.render(brighter, "pt", spp=2, seed=0, max_depth=5)
    assert b[..., 0].mean() < a[..., 0].mean()
    assert compilations() == before   # the changed albedo reused the compiled loop


# --- robustness -----------------------------------------------------------------------------------

@pytest.mark.parametrize("strategy", ["bsdf", "mis"])
def test_no_nan_or_inf_on_degenerate_inputs(strategy):
    scene = degenerate_scene()
    with np.errstate(all="raise"):
        img = jgi.render(scene, "pt", spp=16, seed=0, strategy=strategy)
    assert np.all(np.isfinite(img))
    assert img.max() > 0


def test_bad_parameters_are_refused_with_names():
    scene = scenes.furnace(resolution=4)
    with pytest.raises(jgi.ParameterError, match="strategy.*'bsdf', 'light', 'mis'"):
        jgi.render(scene, "pt", strategy="nee")
    with pytest.raises(jgi.ParameterError, match="no parameter 'max_bounces'.*max_depth"):
        jgi.render(scene, "pt", max_bounces=3)
    with pytest.raises(jgi.ParameterError, match="unknown estimator 'ptx'.*pt"):
        jgi.render(scene, "ptx")
    with pytest.raises(jgi.ParameterError, match="spp"):
        jgi.render(scene, "pt", spp=0)
    with pytest.raises(jgi.ParameterError, match="max_depth.*below the minimum"):
        jgi.render(scene, "pt", max_depth=0)


def test_mirror_conductors_fold_the_fresnel_factor():
    """Veach's GGX plates are perfect-mirror conductors (eta = 0, F = 1): the builder marks the
    scene ``conductor_fresnel = False`` and its kernels skip the Fresnel code; the image equals
    the one rendered with the Fresnel code in, to float rounding."""
    import dataclasses

    import equinox as eqx

    scene = scenes.veach_plates_ggx(resolution=16)
    assert not scene.materials.conductor_fresnel
    assert scenes.cornell_box_rough(resolution=8).materials.conductor_fresnel   # Cu and Au
    mats = dataclasses.replace(scene.materials, conductor_fresnel=True)
    full = eqx.tree_at(lambda s: s.materials, scene, mats)
    a = jgi.render(scene, "pt", spp=4, seed=3, max_depth=4)
    b = jgi.render(full, "pt", spp=4, seed=3, max_depth=4)
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
