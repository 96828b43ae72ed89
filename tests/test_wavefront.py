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
from jgi import _xla as X
from jgi._xla import pow_positive, sincos, take
from jgi.core import calls as C
from jgi.core import warps
from jgi.core.configured import Configured
from jgi.core.vec import V3
from jgi.drivers import chunked
from jgi.drivers import wavefront as R
from jgi.estimators import path_tracer as PT
from jgi.physics import geometry as G
from jgi.physics import lights as LT
from jgi.scene import SceneBuilder
from jgi.scene import builtin as scenes

ROOT = Path(__file__).resolve().parents[1]


def per_path_image(scene, cfg, spp, seed):
    return chunked.render_paths(scene, Configured(PT.trace_pixels, cfg), spp=spp, seed=seed)


@pytest.mark.parametrize("name, params", [
    ("cornell_box", {}),
    ("cornell_box_caustics", dict(strategy="bsdf", max_depth=6)),
    ("cornell_box", dict(path_length=3, rr_depth=-1)),
    ("metal_ring", dict(max_depth=4)),      # 192 triangles: the closest-hit query loops
])
def test_wavefront_equals_per_path_render(name, params):
    """Regeneration changes which lane traces a path, never the path: images agree to rounding
    for spp below, equal to and above the samples per work slot."""
    scene = getattr(scenes, name)(resolution=12)
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
        return R.render_wavefront(scene, PT._start, Configured(PT._step, cfg), spp=5, seed=2, **kw)

    a = render(lanes=256)
    b = render(lanes=16, per_slot=2)       # 16 lanes take 192 slots from the queue
    c = render(lanes=256, per_slot=2)
    d = render(lanes=256, unroll=2)        # small images trace one segment per iteration
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(a, c, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(a, d, rtol=1e-5, atol=1e-7)


def test_concurrent_streams_trace_the_same_paths(monkeypatch):
    """Work split over concurrent loops (threads sharing one compiled function) gives the image
    of one loop to float rounding, the same image on every run, and is actually split."""
    scene = scenes.cornell_box(resolution=8)
    cfg = PT.PathTracerConfig()
    monkeypatch.setattr(R, "WAVEFRONT_STREAM_SLOTS", 1)
    # a step function of this test's own: its compilations are the cache entries it adds
    step = Configured(_step_of_the_streams_test, cfg)
    compiled = R.wavefront_call._cache_size
    before = compiled()
    pools = []
    real_pool = C.ThreadPoolExecutor

    def pool(n):
        pools.append(n)
        return real_pool(n)

    monkeypatch.setattr(C, "ThreadPoolExecutor", pool)

    def render(streams):
        return R.render_wavefront(scene, PT._start, step, spp=5, seed=2, lanes=16, per_slot=1,
                                  streams=streams)

    one = render(1)
    assert compiled() == before + 1   # one compile serves every stream count
    for streams in (2, 3):
        many = render(streams)
        np.testing.assert_allclose(many, one, rtol=1e-5, atol=1e-7)
        assert np.array_equal(many, render(streams))
    assert compiled() == before + 1 and pools == [2, 2, 3, 3]


def _step_of_the_streams_test(scene, cfg, lane):
    return PT._step(scene, cfg, lane)


def test_wavefront_on_two_devices_matches_one():
    """Runs in a subprocess: the CPU device count is fixed when JAX starts."""
    script = textwrap.dedent("""
        import jax, numpy as np, jgi
        assert len(jax.devices()) == 2
        from jgi.estimators import path_tracer as PT
        from jgi.drivers import wavefront as R
        import jgi.core.calls as C
        sc = jgi.scenes.cornell_box(resolution=8)
        from jgi.core.configured import Configured
        step = Configured(PT._step, PT.PathTracerConfig())
        R.WAVEFRONT_STREAM_SLOTS = 1   # split this small render: 320 slots over 16 lanes
        kw = dict(spp=5, seed=4, lanes=16, per_slot=1)
        one = R.render_wavefront(sc, PT._start, step, devices=jax.devices()[:1], streams=1, **kw)
        pools, Pool = [], C.ThreadPoolExecutor
        C.ThreadPoolExecutor = lambda n: (pools.append(n), Pool(n))[1]
        two = R.render_wavefront(sc, PT._start, step, **kw)   # two devices, two loops each
        assert pools == [4], pools
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


def _log_spaced(lo_exp, hi_exp, n, seed):
    """Positive and negative float32 values, log-uniform over [2^lo_exp, 2^hi_exp]."""
    rng = np.random.default_rng(seed)
    m = np.exp2(rng.uniform(lo_exp, hi_exp, n)).astype(np.float32)
    return np.concatenate([m, -m[: n // 2]])


def test_newton_reciprocals_match_float64():
    """recip, recip_normal, rsqrt, sqrt and div against float64 over the normal float32 range:
    relative error within 2 float32 roundings (2^-22), and no bias (mean error below 1e-8: a
    Newton iteration stopped early errs to one side and darkens images). Special values of recip
    and rsqrt behave like the exact operations."""
    x = _log_spaced(-125.9, 125.9, 400_000, 0)
    xd = x.astype(np.float64)
    for fn, want in ((X.recip, 1 / xd), (X.recip_normal, 1 / xd),
                     (lambda v: X.div(np.float32(3.0), v), 3 / xd)):
        rel = np.asarray(jax.jit(fn)(x), np.float64) / want - 1
        assert np.abs(rel).max() < 2.0 ** -22 and abs(rel.mean()) < 1e-8
    pos = np.abs(x)
    for fn, want in ((X.rsqrt, 1 / np.sqrt(np.abs(xd))), (X.sqrt, np.sqrt(np.abs(xd)))):
        rel = np.asarray(jax.jit(fn)(pos), np.float64) / want - 1
        assert np.abs(rel).max() < 2.0 ** -22 and abs(rel.mean()) < 1e-8
    special = np.float32([0.0, -0.0, np.inf, -np.inf, np.nan, 1e-45, 3e38])
    with np.errstate(divide="ignore", over="ignore"):
        want = np.where(np.abs(special) < 1.1754944e-38, np.copysign(np.inf, special),
                        np.where(np.abs(special) > 8.507059e37, np.copysign(0.0, special),
                                 1 / special))
    np.testing.assert_array_equal(np.asarray(jax.jit(X.recip)(special)), want.astype(np.float32))
    r = np.asarray(jax.jit(X.rsqrt)(np.float32([0.0, np.inf, -1.0, 4.0])))
    assert np.isinf(r[0]) and r[1] == 0 and np.isnan(r[2]) and abs(r[3] - 0.5) < 1e-7


def test_safe_reciprocal_shares_one_reciprocal_accurately():
    """1/d for directions (unit and shadow-ray lengths) via one reciprocal of d_x d_y d_z: six
    roundings at most (x y, then z, the reciprocal's two, y z, the final product; measured 4.4);
    components below SLAB_MIN are finite and positive."""
    rng = np.random.default_rng(1)
    v = rng.normal(size=(3, 200_000)) * np.exp2(rng.uniform(-20, 12, (1, 200_000)))
    v[:, :10] = [[0.0] * 10, [1e-30] * 10, [-1.0] * 10]
    d = V3(*(jnp.asarray(c, jnp.float32) for c in v))
    inv = jax.jit(G.safe_reciprocal)(d)
    for c, got in zip(v.astype(np.float32).astype(np.float64), inv):
        got = np.asarray(got, np.float64)
        big = np.abs(c) >= G.SLAB_MIN
        assert np.abs(got[big] * c[big] - 1).max() < 6 * 2.0 ** -24
        assert (np.all(np.isfinite(got))
                and np.all(got[~big] == np.float32(1 / np.float32(G.SLAB_MIN))))


def test_concentric_disc_matches_the_float64_map():
    """The one-division form of the Shirley-Chiu map equals the textbook map (phi = pi/4 b/a or
    pi/2 - pi/4 a/b) to float32 rounding, centre and square edges included."""
    rng = np.random.default_rng(2)
    u = (rng.integers(0, 2**24, (2, 200_000)) / 2.0**24).astype(np.float32)
    # the centre, square edges, and the smallest nonzero |2u - 1| (2^-24, just below 0.5)
    u[:, :6] = [[0.5, 0.0, 0.5, 0.0, 0.5 - 2**-25, 0.5], [0.5, 0.5, 0.0, 0.0, 0.5, 0.5 - 2**-25]]
    x, y = jax.jit(warps.sample_concentric_disc)(u[0], u[1])
    a, b = 2.0 * u[0].astype(np.float64) - 1, 2.0 * u[1].astype(np.float64) - 1
    first = np.abs(a) > np.abs(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(first, np.pi / 4 * b / a, np.pi / 2 - np.pi / 4 * a / b)
    r = np.where(first, a, b)
    phi = np.where(r == 0, 0.0, phi)
    assert np.abs(np.asarray(x) - r * np.cos(phi)).max() < 4e-7
    assert np.abs(np.asarray(y) - r * np.sin(phi)).max() < 4e-7


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


def test_sum_calls_adds_parts_in_call_order_whatever_finishes_first():
    """Float addition is not associative: parts whose sum depends on the order (1e8 + 1 = 1e8)
    finish in reverse order (later calls sleep less), and the sum must still be the one of the
    sequential loop, for any number of calls in flight."""
    import time

    values = np.float32([1e8, 1.0, 1.0, 1.0, 1.0, -1e8, 0.25, 3.0])  # in order: 3.25; reversed: 0
    n = len(values)

    def call(i):
        time.sleep(0.002 * (n - i))
        return np.full((2, 3), values[i], np.float32), i % 2

    expected = np.zeros((2, 3), np.float32)
    for v in values:
        expected = expected + v
    for streams in (1, 2, 3, 8):
        done = []
        img, bad = C.sum_calls(call, n, streams=streams, on_done=done.append)
        assert np.array_equal(img, expected) and bad == n // 2
        assert done == list(range(n))
    shuffled = np.zeros((2, 3), np.float32)
    for v in values[::-1]:
        shuffled = shuffled + v
    assert not np.array_equal(shuffled, expected)   # the order does matter for these values


def test_render_paths_with_concurrent_calls_is_bit_identical(monkeypatch):
    """Several jitted calls in flight (CALL_STREAMS) give exactly the image of one at a time."""
    scene = scenes.cornell_box(resolution=8)
    fn = Configured(PT.trace_pixels, PT.PathTracerConfig())

    pools = []
    real_pool = C.ThreadPoolExecutor
    monkeypatch.setattr(C, "ThreadPoolExecutor", lambda n: (pools.append(n), real_pool(n))[1])

    def render(streams):
        monkeypatch.setattr(C, "CALL_STREAMS", streams)
        # 64 pixels x 9 spp in calls of 4 chunks of 32 paths: 5 calls
        return chunked.render_paths(scene, fn, spp=9, seed=3, chunk=32)

    assert np.array_equal(render(1), render(3))
    assert pools == [3]           # one call at a time, then three in flight
