"""Differentiability: with common random numbers the path-traced estimate is a smooth function
of albedos and emission (no Russian roulette before max_depth), so jax.grad must match central
differences of the same estimator; the XLA materialisation trick must not block derivatives."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import pytest

import jgi
from jgi.estimators.path_tracer import PathTracerConfig, trace_pixels


@pytest.fixture(scope="module")
def setup():
    scene = jgi.scenes.cornell_box(resolution=8)
    pixel = jnp.tile(jnp.arange(64, dtype=jnp.int32), 8)
    sample = jnp.repeat(jnp.arange(8, dtype=jnp.int32), 64)
    return scene, pixel, sample


@pytest.mark.parametrize("what, strategy",
                         [("albedo", "bsdf"), ("albedo", "mis"), ("emission", "mis")])
def test_gradient_matches_central_differences(setup, strategy, what):
    scene, pixel, sample = setup
    cfg = PathTracerConfig(strategy=strategy, max_depth=4, rr_depth=-1)

    def estimate(scale):
        if what == "albedo":
            sc = eqx.tree_at(lambda s: s.materials.diffuse.x, scene,
                             scene.materials.diffuse.x * scale)
        else:
            sc = eqx.tree_at(lambda s: s.lights.emission, scene,
                             jax.tree_util.tree_map(lambda c: c * scale, scene.lights.emission))
        L = trace_pixels(sc, cfg, jnp.uint32(0), pixel, sample)
        return L.x.mean() + 0.5 * L.y.mean()

    f = jax.jit(estimate)
    g = float(jax.grad(estimate)(jnp.float32(1.0)))
    h = 1e-2
    fd = (float(f(jnp.float32(1 + h))) - float(f(jnp.float32(1 - h)))) / (2 * h)
    # float32 rounding of the estimate (~1e-7 relative) over 2h bounds the difference quotient's
    # error; the albedo enters as a polynomial, so h^2 curvature terms are below 1e-4 relative
    # as well
    assert g == pytest.approx(fd, rel=2e-3), (g, fd)
    assert g > 0
