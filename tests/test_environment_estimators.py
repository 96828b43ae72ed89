"""Environment and directional lights as light-subpath starts (issue 31): BDPT (pbrt-v4's
infinite-light vertices), VCM (SmallVCM's background light) and MMLT take them; their MIS
weights over all strategies sum to one, and the estimators agree with the path tracer."""

from __future__ import annotations

import numpy as np
import pytest

import jgi
from jgi.estimators import bdpt as BD
from jgi.scene import SceneBuilder
from tests.support.stats import assert_agree
from tests.test_bdpt import _weights_reference, _weights_rendered
from tests.test_environment_map import env_scene, rotation, sky


def infinite_endpoint_path(rng, n, N, directional: bool):
    """Full paths x_0 .. x_{n-1} whose x_0 is a direction at infinity, with the densities BDPT
    gives such a path (pbrt-v4's measure): p_L[0] the direction's solid-angle density with
    selection, p_E[0] the BSDF's solid-angle density at x_1 towards it, p_L[1] the bounding
    disc's area density times |cos| at x_1; the rest area densities. A directional light's
    direction is Dirac (``delta_light``)."""
    cos = rng.uniform(0.05, 1.0, (n, N))
    d2 = rng.uniform(0.1, 4.0, (n, N))
    pdf_dir = np.exp(rng.uniform(-3, 3, (n, N)))           # BSDF solid-angle densities
    disc = 1.0 / (np.pi * 2.0 ** 2)
    p_L = pdf_dir * cos / d2
    p_E = np.roll(pdf_dir, 1, 0) * cos / d2
    p_L[0] = 1.0 if directional else 0.3 * np.exp(rng.uniform(-4, 4, N))
    p_E[0] = pdf_dir[0]
    p_L[1] = disc * cos[1]
    delta = rng.uniform(size=(n, N)) < 0.25
    delta[0] = delta[-1] = False
    return (p_L.astype(np.float32), p_E.astype(np.float32), delta,
            np.full(N, directional))


@pytest.mark.parametrize("directional", [False, True])
@pytest.mark.parametrize("n", [3, 4, 5])
def test_weights_with_an_infinite_light_endpoint_sum_to_one(n, directional):
    """The scalar reference, the rendered ratio chains and the strategies' full path densities
    p_s = prod_{i<s} p_L[i] prod_{i>=s} p_E[i] (float64) give the same weights (power 2), and
    they sum to one over the strategies that can make the path (no s = 0 for a Dirac
    direction; (1, 1) unused)."""
    rng = np.random.default_rng(31 + n)
    N = 1000
    p_L, p_E, delta, delta_light = infinite_endpoint_path(rng, n, N, directional)
    ref = _weights_reference(p_L, p_E, delta, delta_light, 2.0)
    bat = _weights_rendered(p_L, p_E, delta, delta_light, 2.0)
    L, E = p_L.astype(np.float64), p_E.astype(np.float64)
    valid = {}
    for s in range(n):
        if n == 2 and s == 1:
            valid[s] = np.zeros(N, bool)
        elif s == 0:
            valid[s] = ~delta_light
        else:
            valid[s] = ~delta[s - 1] & ~delta[s]
    # Dirac vertices: remap0 (the zero density of a Dirac lobe counts as 1), as the chain does
    p = {s: np.prod(L[:s], 0) * np.prod(E[s:], 0) for s in range(n)}
    total = sum(np.where(valid[s], p[s] ** 2, 0.0) for s in range(n))
    checked = 0
    for s in range(n):
        ok = valid[s] & (total > 0)
        np.testing.assert_allclose(bat[s][ok], ref[s][ok], rtol=2e-5, atol=1e-7)
        w_true = p[s][ok] ** 2 / total[ok]
        np.testing.assert_allclose(ref[s][ok], w_true, rtol=1e-3, atol=1e-6)
        checked += ok.sum()
    assert checked > N
    w_sum = sum(np.where(valid[s], ref[s], 0.0) for s in range(n))
    np.testing.assert_allclose(w_sum[total > 0], 1.0, rtol=1e-4)


@pytest.mark.slow
def test_bdpt_strategies_of_environment_paths_partition():
    """Paths of two segments under the map (env_scene at 8 x 8, balance heuristic): the
    weighted images of (0, 3) (BSDF sampling escaping to the map), (1, 2) (light sampling) and
    (2, 1) (light tracing from the map) sum to what each strategy estimates unweighted
    (measured: max |t| 1.35, 0.82, 1.34)."""
    scene = env_scene(8)
    cfg = BD.BDPTConfig(max_depth=2, path_length=2, heuristic="balance")
    res = [BD.render_strategies(scene, cfg, spp=32, seed=s) for s in range(6)]
    weighted = np.stack([sum(r[st][1] for st in r) for r in res])
    for st in [(0, 3), (1, 2), (2, 1)]:
        unweighted = np.stack([r[st][0] for r in res])
        assert unweighted.mean() > 0.1, st
        assert_agree(weighted, unweighted, regions=2, label=f"weighted sum vs {st}")


@pytest.mark.slow
@pytest.mark.parametrize("estimator,params,spp", [
    ("bdpt", {}, 16),
    ("vcm", dict(mode="bpt"), 16),
    ("vcm", dict(mode="vcm", radius=0.05), 16),
    ("mmlt", dict(chains=256, bootstrap_samples=4096), 16),
    ("pssmlt", dict(chains=256, bootstrap_samples=4096), 16),
])
def test_estimators_agree_with_the_path_tracer_under_the_map(estimator, params, spp):
    scene = env_scene(8)
    pt = np.stack([jgi.render(scene, "pt", spp=64, seed=s, max_depth=4) for s in range(6)])
    other = np.stack([jgi.render(scene, estimator, spp=spp, seed=300 + s, max_depth=4, **params)
                      for s in range(6)])
    assert np.all(np.isfinite(other))
    t = assert_agree(pt, other, regions=2, label=f"pt vs {estimator} {params}")
    print(f"max |t| pt-{estimator}: {t.max():.2f}")


def directional_scene(size=8):
    """A ball on a floor lit by a directional (sun) light at an angle, the camera above."""
    b = SceneBuilder("directional")
    b.material("white", "diffuse", diffuse=0.7)
    b.material("red", "diffuse", diffuse=(0.7, 0.2, 0.2))
    b.sphere((0.0, 0.0, 0.0), 0.8, "red")
    b.quad((-3.0, -0.8, 3.0), (6.0, 0.0, 0.0), (0.0, 0.0, -6.0), "white")
    b.directional_light((0.4, -1.0, 0.3), (2.0, 2.0, 2.0))
    b.camera(position=(0, 3, 1.5), look_at=(0, -0.8, 0), fov=40, width=size, height=size)
    return b.build()


@pytest.mark.slow
@pytest.mark.parametrize("estimator,params", [("bdpt", {}), ("vcm", dict(mode="bpt")),
                                              ("vcm", dict(radius=0.05))])
def test_directional_light_estimators_agree_with_the_path_tracer(estimator, params):
    scene = directional_scene()
    pt = np.stack([jgi.render(scene, "pt", spp=32, seed=s, max_depth=4) for s in range(6)])
    other = np.stack([jgi.render(scene, estimator, spp=16, seed=300 + s, max_depth=4, **params)
                      for s in range(6)])
    t = assert_agree(pt, other, regions=2, label=f"pt vs {estimator} {params}")
    print(f"max |t| pt-{estimator}: {t.max():.2f}")


def caustic_scene(size=8):
    """A glass ball over a diffuse floor under the sky map (sun included): the ball focuses the
    sun onto the floor, a caustic that only light subpaths from the map find well."""
    b = SceneBuilder("env_caustic")
    b.material("white", "diffuse", diffuse=0.8)
    b.material("glass", "dielectric", ior=1.5)
    b.sphere((0.0, 0.0, 0.0), 0.6, "glass")
    b.quad((-2.0, -0.6, 2.0), (4.0, 0.0, 0.0), (0.0, 0.0, -4.0), "white")
    b.environment_map(sky(sun_rgb=(2000.0, 1800.0, 1500.0)), to_world=rotation(40.0, 0.0))
    b.camera(position=(0, 3.5, 0.01), look_at=(0, -0.6, 0), fov=45, width=size, height=size)
    return b.build()


@pytest.mark.slow
def test_light_subpaths_from_the_map_reduce_caustic_variance():
    """Same time-independent budget (spp): BDPT's per-pixel variance over seeds on the floor
    caustic scene is below the path tracer's (their means agree)."""
    scene = caustic_scene()
    pt = np.stack([jgi.render(scene, "pt", spp=16, seed=s, max_depth=5) for s in range(6)])
    bd = np.stack([jgi.render(scene, "bdpt", spp=16, seed=100 + s, max_depth=5)
                   for s in range(6)])
    assert_agree(pt, bd, regions=2, label="pt vs bdpt (caustic)")
    ratio = float(np.mean(bd.var(0)) / np.mean(pt.var(0)))
    print(f"variance ratio bdpt / pt: {ratio:.3f}")
    assert ratio < 0.7, ratio


def test_mlt_refuses_environment_lights_by_name():
    with pytest.raises(jgi.ParameterError, match="mlt.*environment"):
        jgi.render(env_scene(8), "mlt", spp=1, seed=0)

