"""Smooth plastic (Mitsuba's ``plastic``) in every estimator.

A plastic vertex is connectable, stores photons and is a merge point through its base, while a
path that leaves it by the coating's Dirac reflection has a Dirac bounce there (per-sample
``delta``; pbrt-v4's Vertex::delta). The scene is the Cornell room (8^2, three segments: direct
light and two bounces) with a smooth plastic floor, whose coating mirrors the lamp, and a
plastic ball. Unbiased estimators agree per image region with the path tracer (Welch tests,
Bonferroni-corrected: tests/conftest); VCM's merging with a small radius too (its bias is below
the test's resolution there); SPPM converges to it. The path tracer itself is checked against
Mitsuba 3 in tests/test_import_mitsuba.py (test_smooth_plastic_renders_like_mitsuba).

Light tracing runs on a scene whose plastic the camera does not see (see its test). PSSMLT
stands for the Metropolis estimators: it values paths with the path tracer's code, and
MMLT with BDPT's (tested here); Veach's path-space MLT refuses plastic scenes."""

from __future__ import annotations

import numpy as np
import pytest

import jgi
from jgi.core.errors import ParameterError
from jgi.scene import SceneBuilder, builtin
from tests.conftest import assert_agree

RES = 8
DEPTH = 3
SEEDS = range(8)


def plastic_room(resolution: int = RES):
    b = SceneBuilder("cornell_plastic")
    b.material("floor", "plastic", diffuse=(0.6, 0.55, 0.5))
    builtin.cornell_room(b, resolution, floor="floor")
    b.material("ball", "plastic", diffuse=(0.1, 0.2, 0.7), specular=0.9, int_ior=1.7,
               nonlinear=True)
    b.sphere((0.3, -0.6, 0.2), 0.4, "ball")
    return b.build()


@pytest.fixture(scope="module")
def scene():
    return plastic_room()


@pytest.fixture(scope="module")
def pt(scene):
    return np.stack([jgi.render(scene, "pt", spp=256, seed=1000 + s, max_depth=DEPTH,
                                rr_depth=-1) for s in SEEDS])


def _agree(imgs, pt, label):
    assert np.all(np.isfinite(imgs)) and imgs.min() >= 0.0, label
    t = assert_agree(imgs, pt, label=f"{label} vs pt, plastic room")
    print(f"{label}: max |t| = {t.max():.2f}")


@pytest.mark.parametrize("estimator, spp, params", [
    ("bdpt", 32, {}),
    ("vcm", 8, dict(radius=0.02)),
    ("pssmlt", 32, {}),
])
def test_estimators_agree_with_path_tracer(scene, pt, estimator, spp, params):
    imgs = np.stack([jgi.render(scene, estimator, spp=spp, seed=s, max_depth=DEPTH, **params)
                     for s in SEEDS])
    _agree(imgs, pt, estimator)


def test_light_tracing_agrees_with_path_tracer():
    """Light tracing cannot reach paths whose first bounce from the camera is Dirac (the
    coating's reflection of anything, seen by the camera: as with mirrors), so its scene hides
    the plastic from the camera: a plastic wall behind it, facing the room, which reflects the
    light back into the room through both lobes."""
    b = SceneBuilder("cornell_plastic_behind")
    builtin.cornell_room(b, RES)
    b.material("coat", "plastic", diffuse=(0.7, 0.6, 0.3), int_ior=1.9)
    b.quad((-1.0, -1.0, 4.5), (0.0, 2.0, 0.0), (2.0, 0.0, 0.0), "coat")
    scene = b.build()
    pt = np.stack([jgi.render(scene, "pt", spp=128, seed=1000 + s, max_depth=DEPTH,
                              rr_depth=-1) for s in SEEDS])
    imgs = np.stack([jgi.render(scene, "lt", spp=128, seed=s, max_depth=DEPTH)
                     for s in SEEDS])
    _agree(imgs, pt, "lt")


def test_sppm_converges_to_path_tracer(scene, pt):
    """Photons are stored on the plastic (its base) and the camera chains continue through
    the coating's reflection: the error falls with passes."""
    ref = pt.mean(0)
    err = []
    for passes in (1, 4, 16):
        img = jgi.render(scene, "sppm", spp=1, seed=3, passes=passes, photons=4000,
                         radius=0.15, radius_alpha=0.7, max_depth=DEPTH)
        err.append(float(np.mean((img - ref) ** 2 / (ref ** 2 + 1e-2))))
    assert err[0] > err[1] > err[2], err


def test_veach_mlt_refuses_plastic(scene):
    with pytest.raises(ParameterError, match="does not support smooth plastic"):
        jgi.render(scene, "mlt", spp=1, seed=0)
