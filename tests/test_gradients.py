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


def test_roughness_gradient_matches_central_differences():
    """d(image)/d(alpha) of every microfacet material (rough conductors, dielectric, plastic) on
    cornell_box_rough. Light sampling alone, direct light only: the sampled light points do not
    depend on alpha, so the estimate is a smooth function of it (BSDF sampling would move the
    sampled directions across object edges and make it piecewise constant there)."""
    scene = jgi.scenes.cornell_box_rough(resolution=8)
    pixel = jnp.tile(jnp.arange(64, dtype=jnp.int32), 16)
    sample = jnp.repeat(jnp.arange(16, dtype=jnp.int32), 64)
    cfg = PathTracerConfig(strategy="light", max_depth=2, rr_depth=-1)

    def estimate(scale):
        mats = scene.materials
        sc = eqx.tree_at(lambda s: (s.materials.alpha_u, s.materials.alpha_v), scene,
                         (mats.alpha_u * scale, mats.alpha_v * scale))
        L = trace_pixels(sc, cfg, jnp.uint32(0), pixel, sample)
        return L.x.mean() + L.y.mean() + L.z.mean()

    # forward mode: one parameter. (Reverse mode, jax.grad, through this scene's kernel had not
    # finished compiling after 10 minutes and 11 GB here: left for the gradient-fitting work.)
    # One compiled function gives the value (its primal) and the derivative.
    jvp = jax.jit(lambda x: jax.jvp(estimate, (x,), (jnp.float32(1.0),)))
    f = lambda x: jvp(x)[0]  # noqa: E731
    g = float(jvp(jnp.float32(1.0))[1])
    h = 1e-2
    fd = (float(f(jnp.float32(1 + h))) - float(f(jnp.float32(1 - h)))) / (2 * h)
    f0 = float(f(jnp.float32(1.0)))
    # the estimate is smooth but not polynomial in alpha: the h^2 term of the central
    # difference, estimated from a second step size, bounds the tolerance
    fd2 = (float(f(jnp.float32(1 + 2 * h))) - float(f(jnp.float32(1 - 2 * h)))) / (4 * h)
    tol = abs(fd2 - fd) + 1e-4 * abs(f0)
    assert abs(g - fd) < tol + 2e-3 * abs(fd), (g, fd, fd2)
    assert abs(g) > 10 * tol, (g, tol)   # the roughness really changes the image
