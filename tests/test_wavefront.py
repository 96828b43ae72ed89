"""The wavefront renderer (path regeneration), shadow rays and the fast-path helpers of jgi._xla.

* render_wavefront traces exactly the paths render_paths traces (same (seed, pixel, sample)
  streams), so the two images agree to float rounding, on several devices too;
* shadow rays from a surface parallel to an area light reach the light (the bias fixed in
  28f812e: 18% of light samples were lost on the top of the Cornell box's tall block);
* polynomial sincos and select-based table reads match their numpy references.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jgi
import jgi.render  # noqa: F401  (the module; jgi.render is also the function)
from jgi import geometry as G
from jgi import lights as LT
from jgi import scenes
from jgi._xla import pow_positive, sincos, take
from jgi.estimators import path_tracer as PT
from jgi.scene import SceneBuilder
from jgi.vec import V3

R = sys.modules["jgi.render"]
ROOT = Path(__file__).resolve().parents[1]


def per_path_image(scene, cfg, spp, seed):
    fn = lambda sc, pix, smp, sd: PT.trace_pixels(sc, cfg, sd, pix, smp)  # noqa: E731
    return R.render_paths(scene, fn, spp=spp, seed=seed, cache_key=("test-wavefront-ref", cfg))


@pytest.mark.parametrize("name, params", [
    ("cornell_box", {}),
    ("cornell_box_caustics", dict(strategy="bsdf", max_depth=6)),
    ("cornell_box", dict(path_length=3, rr_depth=-1)),
])
def test_wavefront_equals_per_path_render(name, params):
    """Regeneration changes which lane traces a path, never the path: images agree to rounding
    for spp below, equal to and above the samples per work slot."""
    scene = scenes.cornell_box(resolution=12) if name == "cornell_box" else \
        scenes.cornell_box_caustics(resolution=12)
    cfg = PT.PathTracerConfig(**params)
    for spp in (1, 7, 20):
        a = jgi.render(scene, "pt", spp=spp, seed=5, **params)
        b = per_path_image(scene, cfg, spp, 5)
        assert np.abs(a).max() > 0
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(b).max())


def test_wavefront_lane_slot_and_unroll_counts_do_not_change_the_image():
    """Lane count, slot size and unrolling change which lane traces a path and when, never the
    path: images agree to float rounding of the sums."""
    scene = scenes.cornell_box(resolution=8)
    cfg = PT.PathTracerConfig()

    def render(**kw):
        return R.render_wavefront(scene, PT._start, lambda sc, lane: PT._step(sc, cfg, lane),
                                  spp=5, seed=2, cache_key=("test-wavefront-lanes", cfg), **kw)

    a = render(lanes=256)
    b = render(lanes=16, per_slot=2)       # 16 lanes take 192 slots from the queue
    c = render(lanes=256, per_slot=2)
    d = render(lanes=256, unroll=2)        # small images trace one segment per iteration
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(a, c, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(a, d, rtol=1e-5, atol=1e-7)


def test_wavefront_on_two_devices_matches_one():
    """Runs in a subprocess: the CPU device count is fixed when JAX starts."""
    script = textwrap.dedent("""
        import jax, numpy as np, jgi
        assert len(jax.devices()) == 2
        from jgi.estimators import path_tracer as PT
        import sys, jgi.render
        R = sys.modules["jgi.render"]
        sc = jgi.scenes.cornell_box(resolution=8)
        cfg = PT.PathTracerConfig()
        step = lambda s, l: PT._step(s, cfg, l)
        one = R.render_wavefront(sc, PT._start, step, spp=5, seed=4, cache_key=("t", cfg),
                                 devices=jax.devices()[:1])
        two = R.render_wavefront(sc, PT._start, step, spp=5, seed=4, cache_key=("t", cfg))
        err = np.abs(one - two).max() / np.abs(one).max()
        assert err < 1e-6, err
        print("TWO-DEVICES-OK")
    """)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                       timeout=600, cwd=ROOT)
    assert r.returncode == 0 and "TWO-DEVICES-OK" in r.stdout, r.stdout + r.stderr


def test_shadow_rays_from_a_surface_parallel_to_the_light_reach_it():
    """A floor under a horizontal area light: every unoccluded light sample must be visible.
    Shortening the unshifted distance (the old code) hit the light's own rectangle first for
    samples seen at grazing angles."""
    b = SceneBuilder("parallel")
    b.material("white", "diffuse", diffuse=(0.5, 0.5, 0.5))
    b.quad((-1, 0, -1), (0, 0, 2), (2, 0, 0), "white")                       # floor, normal +y
    b.quad((-0.2, 0.5, -0.2), (0.4, 0, 0), (0, 0, 0.4), "white", emission=(1, 1, 1))  # faces -y
    b.camera(position=(0, 1, 3), look_at=(0, 0, 0), fov=40, width=4, height=4)
    scene = b.build()
    n = 4096
    u = jax.random.uniform(jax.random.PRNGKey(0), (5, n))
    # points spread over a large floor: many see the light at grazing angles
    p = V3(u[0] * 40 - 20, jnp.zeros(n), u[1] * 40 - 20)
    nrm = V3(jnp.zeros(n), jnp.ones(n), jnp.zeros(n))
    ls = LT.sample_li(scene.lights, p, u[2], u[3], u[4])
    assert bool(jnp.all(ls.valid))
    o, d, t_max = G.shadow_ray(p, nrm, ls.wi, ls.dist)
    assert not bool(jnp.any(G.occluded(scene, o, d, t_max)))
    # the segment ends just short of the sampled point
    y = p + ls.wi * ls.dist
    end = o + d * t_max
    gap = jnp.sqrt((y.x - end.x) ** 2 + (y.y - end.y) ** 2 + (y.z - end.z) ** 2)
    assert float(jnp.max(gap / ls.dist)) < 1e-3
    # and an occluder between them is found
    b.quad((-20, 0.25, -20), (0, 0, 40), (40, 0, 0), "white")
    blocked = b.build()
    assert bool(jnp.all(G.occluded(blocked, o, d, t_max)))


def test_shadow_rays_to_directional_lights_are_unbounded():
    p = V3(jnp.zeros(3), jnp.zeros(3), jnp.zeros(3))
    nrm = V3(jnp.zeros(3), jnp.ones(3), jnp.zeros(3))
    wi = V3(jnp.zeros(3), jnp.ones(3), jnp.zeros(3))
    o, d, t_max = G.shadow_ray(p, nrm, wi, jnp.array([jnp.inf, 2.0, 0.0]))
    assert np.isinf(float(t_max[0])) and float(d.y[0]) == 1.0
    assert 0 < float(t_max[1]) < 1 and 0 <= float(t_max[2]) < 1  # a zero distance stays finite
    assert all(np.isfinite(np.asarray(x)).all() for x in (*o, *d))


def test_sincos_matches_float64():
    x = np.linspace(-4096, 4096, 400_001).astype(np.float32)
    x = np.concatenate([x, np.linspace(-np.pi, 2 * np.pi, 100_001, dtype=np.float32),
                        np.float32([0.0, -0.0, np.pi / 2, np.pi, 1e-30])])
    s, c = jax.jit(sincos)(x)
    xd = x.astype(np.float64)
    assert np.abs(np.asarray(s) - np.sin(xd)).max() < 2e-7
    assert np.abs(np.asarray(c) - np.cos(xd)).max() < 2e-7
    assert np.all(np.abs(np.asarray(s) ** 2 + np.asarray(c) ** 2 - 1) < 1e-6)


@pytest.mark.parametrize("rows", [1, 2, 5, 8, 9])
def test_take_equals_gather(rows):
    table = jnp.arange(rows, dtype=jnp.float32) * 1.5 - 2.0
    idx = jnp.asarray(np.random.default_rng(rows).integers(0, rows, 257), jnp.int32)
    np.testing.assert_array_equal(np.asarray(take(table, idx)), np.asarray(table)[np.asarray(idx)])


def test_pow_positive_matches_float64_where_it_matters():
    """exp(y log x) for Phong lobes, over cosines up to 1 and exponents up to 10^4: wherever
    x^y > e^-20, |y log x| < 20, so log's rounding amplified by y gives at most 20 * 2^-23 =
    2.4e-6, plus exp's own error: bound 4e-6 (measured 2.7e-6)."""
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(0, 1, 200_000), 1 - rng.uniform(0, 1e-3, 200_000),
                        [1.0, 0.5, 1e-30]]).astype(np.float32)
    y = np.concatenate([rng.uniform(0, 1e4, 200_000), rng.uniform(0, 1e4, 200_000),
                        [1e4, 0.0, 1.0]]).astype(np.float32)
    got = np.asarray(jax.jit(pow_positive)(x, y), np.float64)
    want = x.astype(np.float64) ** y.astype(np.float64)
    big = want > np.exp(-20.0)
    assert big.sum() > 100_000
    assert np.abs(got[big] / want[big] - 1).max() < 4e-6
    assert np.all(np.isfinite(got)) and np.all(got >= 0) and np.all(got[~big] < 3e-9)
