"""Environment and directional lights as light-subpath starts (issue 31): BDPT (pbrt-v4's
infinite-light vertices), VCM (SmallVCM's background light) and MMLT take them, and agree with
the path tracer; BDPT's strategies partition paths from the map (their weights with infinite
endpoints against the scalar reference: tests/test_bdpt.py)."""

from __future__ import annotations

import numpy as np
import pytest

import jgi
from jgi.estimators import bdpt as BD
from jgi.scene import SceneBuilder
from tests.support.environment import env_scene, rotation, sky
from tests.support.stats import assert_agree


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
    # VCM's bpt mode is left out: BDPT path for path (tests/test_vcm.py), and the vcm mode below
    # runs its connections to and from the map
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
@pytest.mark.parametrize("estimator,params", [("bdpt", {}), ("vcm", dict(radius=0.05))])
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

