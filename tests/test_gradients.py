"""Differentiability: with common random numbers the path-traced estimate is a smooth function
of albedos and emission (no Russian roulette before max_depth), so jax.grad must match central
differences of the same estimator; the XLA materialisation trick must not block derivatives.
With respect to roughness the path tracer's detached derivatives (sampling held fixed) are
checked statistically against central differences of the expected image."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
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

    value_and_grad = jax.jit(jax.value_and_grad(estimate))   # one program: values and slope
    g = float(value_and_grad(jnp.float32(1.0))[1])
    h = 1e-2
    f = lambda x: float(value_and_grad(jnp.float32(x))[0])   # noqa: E731
    fd = (f(1 + h) - f(1 - h)) / (2 * h)
    # float32 rounding of the estimate (~1e-7 relative) over 2h bounds the difference quotient's
    # error; the albedo enters as a polynomial, so h^2 curvature terms are below 1e-4 relative
    # as well
    assert g == pytest.approx(fd, rel=2e-3), (g, fd)
    assert g > 0


def _rough_spheres():
    """Four microfacet spheres under a white sky, one of each kind: GGX copper, rough glass,
    Beckmann rough plastic, anisotropic gold (alpha 0.3; gold 0.3 x 0.1)."""
    b = jgi.scenes.SceneBuilder("rough_spheres")
    b.material("copper", "roughconductor", metal="Cu", alpha=0.3)
    b.material("glass", "roughdielectric", alpha=0.3, ior=1.5)
    b.material("plastic", "roughplastic", diffuse=(0.2, 0.3, 0.6), alpha=0.3,
               distribution="beckmann")
    b.material("gold", "roughconductor", metal="Au", alpha_u=0.3, alpha_v=0.1)
    for (x, y), m in zip([(-0.55, 0.55), (0.55, 0.55), (-0.55, -0.55), (0.55, -0.55)],
                         ["copper", "glass", "plastic", "gold"]):
        b.sphere((x, y, 0.0), 0.5, m)
    b.environment_light((1.0, 1.0, 1.0))
    b.camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), fov=30.0, width=8, height=8)
    return b.build()


def test_detached_roughness_gradient_in_reverse_mode():
    """jax.grad (reverse mode) of an image with respect to the roughness of every microfacet
    kind in one scene, by the path tracer's detached derivatives (MIS, three segments): an
    unbiased estimate of the derivative of the expected image, so over 8 seeds its mean agrees
    with central differences of the (attached) estimate on the same streams within five
    standard errors of the paired difference, plus the difference quotient's h^2 error (bounded
    by a second step size). Measured 2026-12-03 (16 seeds): -0.112 +- 0.009 against -0.107 +-
    0.007; with the weights' derivative dropped (every sample field detached) the mean is
    +0.028 and the paired t 13.9. (Attached reverse mode through all four kinds at once had not
    compiled after 7 minutes; detached compiles in about 20 s.)"""
    scene = _rough_spheres()
    spp = 16
    pixel = jnp.tile(jnp.arange(64, dtype=jnp.int32), spp)
    sample = jnp.repeat(jnp.arange(spp, dtype=jnp.int32), 64)

    cfg = PathTracerConfig(strategy="mis", max_depth=3, rr_depth=-1, gradient="detached")

    def estimate(scale, seed):
        mats = scene.materials
        sc = eqx.tree_at(lambda s: (s.materials.alpha_u, s.materials.alpha_v), scene,
                         (mats.alpha_u * scale, mats.alpha_v * scale))
        L = trace_pixels(sc, cfg, seed, pixel, sample)
        return L.x.mean() + L.y.mean() + L.z.mean()

    # one compiled program: detached derivatives leave the value the attached estimate's (the
    # sampled weights' w + w (f - f) / f), so its values give the central differences too
    value_and_grad = jax.jit(jax.value_and_grad(estimate))
    f = lambda x, s: float(value_and_grad(jnp.float32(x), jnp.uint32(s))[0])  # noqa: E731
    h = 2e-2
    g, fd, fd2 = (np.array(x) for x in zip(*[
        (float(value_and_grad(jnp.float32(1.0), jnp.uint32(s))[1]),
         (f(1 + h, s) - f(1 - h, s)) / (2 * h), (f(1 + 2 * h, s) - f(1 - 2 * h, s)) / (4 * h))
        for s in range(8)]))
    se = lambda x: x.std(ddof=1) / np.sqrt(len(x))  # noqa: E731
    curvature = abs(fd2.mean() - fd.mean())
    assert abs(g.mean() - fd.mean()) < 5 * se(g - fd) + curvature, (g.mean(), fd.mean(), se(g - fd))
    assert abs(g.mean()) > 5 * se(g), (g.mean(), se(g))   # the roughness changes the image
