"""Veach's path-space MLT: perturbation densities, reversible retracing (so T(x->y) = T(y->x)),
the large step's normalisation, and images that agree with the path tracer's per region."""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import jgi
from jgi.core.errors import ParameterError
from jgi.core.vec import V3, dot, normalize
from jgi.estimators import mlt
from tests.support.stats import assert_agree

CFG = mlt.MLTConfig(max_depth=5)
LUM = np.array([0.2126, 0.7152, 0.0722])


@pytest.fixture(scope="module")
def mirror():
    return jgi.scenes.mirror_caustic(resolution=8)


@pytest.fixture(scope="module")
def mirror_paths(mirror):
    paths, c_star, _ = mlt.bootstrap(mirror, CFG, jnp.uint32(3), 65536)
    return paths, np.asarray(c_star)


def _pick(paths, idx):
    idx = jnp.asarray(idx)
    return jax.tree_util.tree_map(lambda a: jnp.take(a, idx, axis=a.ndim - 1), paths)


def test_perturbation_sizes_follow_their_density(rng_np):
    """s = hi exp(-log(hi/lo) xi) has density 1 / (s log(hi/lo)) on [lo, hi] (chi-square);
    rotate_about turns a direction by exactly theta."""
    lo, hi = 0.1, 1.6
    s = np.asarray(mlt.log_uniform(jnp.asarray(rng_np.random(200_000), jnp.float32), lo, hi))
    assert s.min() >= lo * (1 - 1e-5) and s.max() <= hi * (1 + 1e-5)
    edges = np.linspace(lo, hi, 41)
    observed, _ = np.histogram(s, edges)
    expected = np.diff(np.log(edges)) / np.log(hi / lo) * s.size
    assert stats.chisquare(observed, expected).pvalue > 1e-4
    w = normalize(V3(*(jnp.asarray(rng_np.normal(size=1000), jnp.float32) for _ in range(3))))
    theta = jnp.asarray(rng_np.uniform(1e-3, 0.5, 1000), jnp.float32)
    w2 = mlt.rotate_about(w, theta, jnp.asarray(rng_np.uniform(0, 2 * np.pi, 1000), jnp.float32))
    angle = np.arccos(np.clip(np.asarray(dot(w, w2)), -1, 1))
    assert np.abs(angle - np.asarray(theta)).max() < 2e-3


@partial(jax.jit, static_argnames=("cfg",))
def _lens_round_trip(scene, cfg, x, dx, dy):
    y, ok = mlt.retrace_lens(scene, cfg, x, x.fx + dx, x.fy + dy)
    back, ok_back = mlt.retrace_lens(scene, cfg, y, x.fx, x.fy)
    mu = mlt.Mutations().arrays()
    return (y, ok, back, ok_back, mlt.lens_log_density(scene, mu, x, y),
            mlt.lens_log_density(scene, mu, y, x))


@partial(jax.jit, static_argnames=("cfg",))
def _caustic_round_trip(scene, cfg, x, theta, phi):
    j, _ = mlt.caustic_vertex(scene, x)
    w = normalize(mlt._chain_row(x.p, j - 1) - mlt._chain_row(x.p, j))
    y, ok = mlt.retrace_caustic(scene, cfg, x, mlt.rotate_about(w, theta, phi))
    back, ok_back = mlt.retrace_caustic(scene, cfg, y, w)
    mu = mlt.Mutations(caustic_theta2=0.5).arrays()
    return (y, ok, back, ok_back, mlt.caustic_log_density(scene, mu, x, y),
            mlt.caustic_log_density(scene, mu, y, x))


def test_retracing_is_reversible_and_the_perturbations_symmetric(mirror, mirror_paths):
    """Both perturbations are bijections between paths of one type: perturbing x to y and
    retracing y with x's film point (lens) or x's direction (caustic) gives x back, and the
    transition densities computed from the two paths' vertices agree (T(x->y) = T(y->x))."""
    paths, c_star = mirror_paths
    K = CFG.max_depth
    # lens: every path the camera sees through x_1 with a diffuse x_2 (or a light at x_1)
    _, lens_ok = mlt.lens_vertex(mirror, paths)
    idx = np.nonzero(np.asarray(lens_ok) & (c_star > 0))[0][:512]
    assert idx.size >= 64
    x = _pick(paths, idx)
    y, ok, back, ok_back, t_xy, t_yx = _lens_round_trip(mirror, CFG, x, jnp.float32(0.37),
                                                        jnp.float32(-0.21))
    ok = np.asarray(ok)
    assert ok.sum() >= 16 and np.all(np.asarray(ok_back)[ok])
    for a, b in zip(back.p, x.p):
        assert np.abs(np.asarray(a) - np.asarray(b))[:, ok].max() < 2e-3
    assert np.allclose(np.asarray(t_xy)[ok], np.asarray(t_yx)[ok], rtol=1e-4)
    assert np.all(np.isfinite(np.asarray(t_xy)[ok]))
    # caustic: E D S L paths (the floor lit through the mirror)
    _, caustic_ok = mlt.caustic_vertex(mirror, paths)
    idx = np.nonzero(np.asarray(caustic_ok) & (c_star > 0))[0][:512]
    assert idx.size >= 16
    x = _pick(paths, idx)
    theta = 0.05
    y, ok, back, ok_back, t_xy, t_yx = _caustic_round_trip(mirror, CFG, x, jnp.float32(theta),
                                                           jnp.float32(1.3))
    ok = np.asarray(ok)
    assert ok.sum() >= 16 and np.all(np.asarray(ok_back)[ok])
    moved = np.sqrt(sum((np.asarray(a) - np.asarray(b))[1, ok] ** 2 for a, b in zip(y.p, x.p)))
    assert moved.min() > 1e-2  # the floor point really moved
    for a, b in zip(back.p, x.p):
        assert np.abs(np.asarray(a) - np.asarray(b))[: K + 1, ok].max() < 2e-3
    assert np.abs(np.asarray(back.fx) - np.asarray(x.fx))[ok].max() < 2e-3
    expected = -np.log(2 * np.pi * theta * np.sin(theta) * np.log(0.5 / 1e-4))
    assert np.allclose(np.asarray(t_xy)[ok], expected, rtol=2e-3)
    assert np.allclose(np.asarray(t_yx)[ok], expected, rtol=2e-3)


def test_large_step_normalisation_matches_the_path_tracer():
    """b = E_p[f*/p] from the large step equals the image mean of the path tracer (same
    depth, no Russian roulette), within 5 standard errors."""
    scene = jgi.scenes.cornell_box(resolution=16)
    _, c_star, _ = mlt.bootstrap(scene, CFG, jnp.uint32(1), 65536)
    c = np.asarray(c_star, np.float64)
    pt = np.stack([jgi.render(scene, "pt", spp=64, seed=50 + s, max_depth=5, rr_depth=-1) @ LUM
                   for s in range(4)]).mean(axis=(1, 2))
    se = np.hypot(c.std() / np.sqrt(c.size), pt.std(ddof=1) / 2)
    assert abs(c.mean() - pt.mean()) < 5 * se, (c.mean(), pt.mean(), se)


def _shape(images):
    """Each render divided by its mean luminance: the distribution over the image that the
    chains sample (its total is b, tested above), free of b's bootstrap noise."""
    return images / (images @ LUM).mean(axis=(1, 2))[:, None, None, None]


def test_lens_mlt_matches_path_tracer_per_region():
    """Lens perturbations and large steps on the Cornell box (mostly lens steps, so an error in
    the lens acceptance shows: dropping G(x'_m, x_{m+1}) gives |t| = 9 here)."""
    scene = jgi.scenes.cornell_box(resolution=16)
    cfg = replace(CFG, chains=1024, bootstrap_samples=65536, p_large=0.05, p_lens=0.95,
                  p_caustic=0.0)
    results = [mlt.render(scene, cfg, spp=128, seed=10 + s) for s in range(8)]
    imgs = np.stack([r.image for r in results])
    stats_ = results[0].stats
    pt = np.stack([jgi.render(scene, "pt", spp=64, seed=100 + s, max_depth=5) for s in range(8)])
    assert np.all(np.isfinite(imgs))
    assert_agree(_shape(imgs), _shape(pt), regions=4, label="mlt (lens) vs pt")
    assert 0.2 < stats_["lens_acceptance"] < 1.0 and stats_["caustic_proposed"] == 0
    # b from the path tracer (default) and from the large step's bootstrap estimate one integral
    assert abs(stats_["b"] - stats_["b_bootstrap"]) < 5 * stats_["b_bootstrap_se"]


def test_caustic_mlt_matches_path_tracer_per_region(mirror):
    """Caustic and lens perturbations alone (no large steps) from chains started in the target
    distribution keep it: the floor lit through the mirror agrees with the path tracer."""
    cfg = replace(CFG, chains=1024, bootstrap_samples=65536, p_large=0.0, p_lens=0.5, p_caustic=0.5,
                  caustic_theta2=0.5)
    results = [mlt.render(mirror, cfg, spp=2048, seed=20 + s) for s in range(8)]
    imgs = np.stack([r.image for r in results])
    stats_ = results[0].stats
    pt = np.stack([jgi.render(mirror, "pt", spp=256, seed=200 + s, max_depth=5) for s in range(8)])
    assert_agree(_shape(imgs), _shape(pt), regions=4, label="mlt (caustic) vs pt")
    assert stats_["caustic_applicable"] > 0.1 * stats_["caustic_proposed"]
    assert stats_["caustic_acceptance"] > 0.3


def test_registry_and_clear_errors():
    scene = jgi.scenes.point_light_plane(resolution=4)
    with pytest.raises(ParameterError, match="area emitters"):
        jgi.render(scene, "mlt", spp=1, seed=0)
    with pytest.raises(ParameterError, match="p_large"):
        jgi.render(jgi.scenes.cornell_box(resolution=4), "mlt", spp=1, seed=0, p_large=0.0)
    names = {p.name for p in jgi.estimators.get("mlt").params}
    assert {"p_large", "p_lens", "p_caustic", "max_depth"} <= names
