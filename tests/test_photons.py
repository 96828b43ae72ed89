"""Photon tracing: power bookkeeping, caustic flags and determinism."""

from __future__ import annotations

import numpy as np
import pytest

from jgi.scene import SceneBuilder
from jgi.scene import builtin as scenes
from jgi.scene.builtin import _inward_box_faces
from jgi.transport.photons import trace_photons


def closed_box_with_specular_spheres(albedo: float, intensity: float = 2.0):
    b = SceneBuilder("closed_specular")
    b.material("wall", "diffuse", diffuse=(albedo, albedo, albedo))
    b.material("glass", "dielectric", ior=1.5)
    b.material("mirror", "mirror", specular=(1.0, 1.0, 1.0))
    for c, u, v in _inward_box_faces():
        b.quad(c, u, v, "wall")
    b.sphere((0.3, -0.4, 0.0), 0.4, "glass")
    b.sphere((-0.4, -0.5, 0.3), 0.3, "mirror")
    b.point_light((0.0, 0.6, 0.0), (intensity, intensity, intensity))
    b.camera((0, 0, 0.9), (0, 0, 0), width=4, height=4)
    return b.build()


def test_power_is_conserved_through_specular_chains():
    """In a closed box with black walls, every photon is stored once (at its first diffuse
    hit) after any number of lossless specular bounces: the stored powers sum to the light's
    power 4 pi I exactly (each photon carries 4 pi I / n)."""
    scene = closed_box_with_specular_spheres(albedo=0.0, intensity=2.0)
    n = 20000
    pm = trace_photons(scene, n, seed=3, max_depth=16)
    assert np.all(pm.depth == pm.depth)  # arrays materialised
    first = pm.power.x  # black walls absorb: exactly one stored photon per path
    assert pm.count <= n
    np.testing.assert_allclose(first, 4 * np.pi * 2.0 / n, rtol=1e-5)
    assert pm.count >= n * 0.999  # only photons still bouncing after 16 specular events are lost
    assert 0 < pm.caustic.sum() < pm.count  # some went through the spheres first


def test_russian_roulette_keeps_expected_power():
    """Closed grey box of albedo rho, no specular objects: a photon survives each diffuse bounce
    with probability rho and keeps its power, so the power stored after k bounces is
    Binomial(n, rho^k) * P0 with P0 = 4 pi I / n: expected rho^k 4 pi I."""
    rho, I, n = 0.6, 2.0, 40000
    b = SceneBuilder("grey_box")
    b.material("wall", "diffuse", diffuse=(rho, rho, rho))
    for c, u, v in _inward_box_faces():
        b.quad(c, u, v, "wall")
    b.point_light((0.0, 0.2, 0.1), (I, I, I))
    b.camera((0, 0, 0.9), (0, 0, 0), width=4, height=4)
    pm = trace_photons(b.build(), n, seed=5, max_depth=6)
    P0 = 4 * np.pi * I / n
    np.testing.assert_allclose(pm.power.x, P0, rtol=1e-5)  # equal-power photons
    for k in range(6):
        stored = pm.power.x[pm.depth == k].sum()
        p = rho**k
        expected, se = P0 * n * p, P0 * np.sqrt(n * p * (1 - p))
        assert abs(stored - expected) <= 5 * se + 1e-6 * expected, (k, stored, expected, se)
    assert not pm.caustic.any()


def test_caustic_flag_marks_L_S_D_paths():
    scene = scenes.glass_sphere(resolution=8)
    pm = trace_photons(scene, 20000, seed=1)
    assert pm.caustic.any()
    assert np.all(pm.depth[pm.caustic] >= 1)          # at least one specular bounce first
    # caustic photons land under the sphere (the light is above it, at x ~ 1)
    r = np.hypot(pm.position.x[pm.caustic] - 0.0, pm.position.z[pm.caustic])
    assert np.median(r) < 1.2


def test_photon_map_is_deterministic_and_chunk_independent():
    scene = scenes.cornell_box(resolution=8)
    a = trace_photons(scene, 5000, seed=2, chunk=1024)
    b = trace_photons(scene, 5000, seed=2, chunk=4096)
    assert a.count == b.count
    np.testing.assert_array_equal(np.sort(a.position.x), np.sort(b.position.x))
    c = trace_photons(scene, 5000, seed=3, chunk=1024)
    assert not np.array_equal(np.sort(a.position.x), np.sort(c.position.x))


def test_photon_map_order_does_not_depend_on_calls_in_flight(monkeypatch):
    """Chunks traced concurrently (jgi.core.calls) are stored in chunk order: the same arrays, in
    the same order, as one chunk at a time."""
    import jax

    from jgi.core import calls

    scene = scenes.cornell_box(resolution=8)
    pools, real_pool = [], calls.ThreadPoolExecutor
    monkeypatch.setattr(calls, "ThreadPoolExecutor", lambda n: (pools.append(n), real_pool(n))[1])
    maps = []
    for streams in (1, 3):
        monkeypatch.setattr(calls, "CALL_STREAMS", streams)
        maps.append(trace_photons(scene, 5000, seed=2, chunk=1024, devices=jax.devices()[:1]))
    assert pools == [3]   # one chunk at a time, then three in flight (5 chunks)
    for x, y in zip(jax.tree_util.tree_leaves(maps[0]), jax.tree_util.tree_leaves(maps[1])):
        np.testing.assert_array_equal(x, y)


def test_no_lights_is_an_error():
    b = SceneBuilder("dark")
    b.material("m", "diffuse", diffuse=0.5)
    b.sphere((0, 0, 0), 1.0, "m")
    b.camera((0, 0, 5), (0, 0, 0), width=4, height=4)
    with pytest.raises(ValueError, match="no lights"):
        trace_photons(b.build(), 10)
