"""Microfacet materials in every estimator (issue 21).

The scene is ``cornell_box_rough`` (16^2): the Cornell room with a glossy copper sphere, a
rough glass sphere, a rough-plastic block and an anisotropic gold block. Unbiased estimators
agree per image region with the path tracer (Welch tests, Bonferroni-corrected: tests/conftest),
the path tracer and BDPT agree with Mitsuba 3's ``path`` integrator on the isotropic version
of the scene built in Mitsuba directly, photon mapping is within its bias budget of the path
tracer per region, and SPPM's error falls with passes. Every image is finite and non-negative.

PSSMLT and MMLT are not rendered here: they evaluate paths with the path tracer's and BDPT's
own code (explicit primary samples in place of the hashed stream), which is tested on this
scene, and their chains do not depend on the materials (tests/test_pssmlt.py,
tests/test_mmlt.py). VCM's microfacet case is the smooth-normal scene's GGX strip
(tests/test_shading_normals.py); its light walks and connections call the BSDFs as BDPT's do.
Each costs a minute of compiles on this scene, and the suite must fit in 15 minutes on two
cores."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import jgi
from jgi.core import transform as xf
from jgi.estimators import mlt
from jgi.scene import SceneBuilder, builtin
from tests.support.mitsuba import load_mitsuba
from tests.support.stats import assert_agree

RES = 16
DEPTH = 4   # direct light and three bounces: every kind in both subpaths, short compiles
SEEDS = range(8)
LUM = np.array([0.2126, 0.7152, 0.0722])


@pytest.fixture(scope="module")
def scene():
    return builtin.cornell_box_rough(resolution=RES)


@pytest.fixture(scope="module")
def pt(scene):
    """The reference stack: path tracing with MIS, no Russian roulette."""
    return np.stack([jgi.render(scene, "pt", spp=128, seed=1000 + s, max_depth=DEPTH,
                                rr_depth=-1) for s in SEEDS])


def _check(images, label):
    assert np.all(np.isfinite(images)) and images.min() >= 0.0, label


@pytest.mark.parametrize("strategy", ["bsdf", "light"])
def test_path_tracer_strategies_agree(scene, pt, strategy):
    imgs = np.stack([jgi.render(scene, "pt", spp=128, seed=s, max_depth=DEPTH, rr_depth=-1,
                                strategy=strategy) for s in SEEDS])
    _check(imgs, strategy)
    assert_agree(imgs, pt, label=f"pt {strategy} vs pt mis, cornell_box_rough")


def test_bdpt_agrees_with_path_tracer(scene, pt):
    imgs = np.stack([jgi.render(scene, "bdpt", spp=32, seed=s, max_depth=DEPTH)
                     for s in SEEDS])
    _check(imgs, "bdpt")
    assert_agree(imgs, pt, label="bdpt vs pt, cornell_box_rough")


def test_light_tracing_agrees_with_path_tracer(scene, pt):
    """Light paths through the rough glass use the importance-transport BTDF (no 1 / eta^2)."""
    imgs = np.stack([jgi.render(scene, "lt", spp=256, seed=s, max_depth=DEPTH)
                     for s in SEEDS])
    _check(imgs, "lt")
    assert_agree(imgs, pt, label="lt vs pt, cornell_box_rough")


def test_veach_mlt_agrees_with_path_tracer(scene, pt):
    """Glossy vertices are not specular for the perturbations: lens perturbations move them
    and the acceptance uses their BSDF like a diffuse vertex's."""
    cfg = replace(mlt.MLTConfig(), chains=1024, bootstrap_samples=65536, max_depth=DEPTH,
                  p_large=0.2, p_lens=0.5, p_caustic=0.3)
    imgs = np.stack([mlt.render(scene, cfg, spp=32, seed=10 + s).image for s in range(8)])
    _check(imgs, "mlt")
    # each render divided by its mean luminance (b's bootstrap noise out: see test_mlt)
    shape = lambda im: im / (im @ LUM).mean(axis=(1, 2))[:, None, None, None]  # noqa: E731
    assert_agree(shape(imgs), shape(pt[:8]), label="mlt vs pt, cornell_box_rough")


def _rel_error(img, ref):
    return float(np.mean((img - ref) ** 2 / (ref ** 2 + 1e-2)))


def test_photon_mapping_matches_the_path_tracer_per_region(scene, pt):
    """Photons are stored on the rough plastic and gold (full-BSDF estimates there) and pass
    through the glossy copper and the rough glass. Every 4 x 4 pixel region of photon mapping
    (8 seeds, 40 000 photons) within 15% of the path tracer plus
    five standard errors of the difference. 15% is the bias budget: the kernel's blur at
    r = 0.119 and the photons' extra bounce (a visible point plus ``max_bounces`` photon
    segments) give 0.94..1.08 where the regions are precise (the amber rough glass sphere: 1.08
    at t = 4.8, and 1.12 at t = 6.5 when it was clear; the light's region 1.31 at t = 2.0, 1.0
    standard errors beyond the budget; measured 2026-12-03). The standard errors
    are needed in the copper sphere's region: its chains see the light's highlight by BSDF
    sampling alone (no light samples along a glossy chain), so one camera sample in 64 carries
    most of the region; one seed of 32 gave 0.34 where the mean is 0.067 +- 0.014 (PT 0.074
    +- 0.004)."""
    regions = lambda x: x.reshape(RES // 4, 4, RES // 4, 4, 3).mean(axis=(1, 3, 4))  # noqa: E731
    pm = np.stack([regions(jgi.render(scene, "pm", spp=4, seed=s, photons=40_000,
                                      radius=0.15 * 4 ** (-1 / 6), max_bounces=DEPTH))
                   for s in SEEDS])
    ref = np.stack([regions(im) for im in pt])
    excess = np.abs(pm.mean(0) - ref.mean(0)) - 0.15 * ref.mean(0)
    se = np.sqrt(pm.var(0, ddof=1) / len(pm) + ref.var(0, ddof=1) / len(ref))
    assert np.all(excess < 5 * se), np.round(excess / se, 2)


# pm_jensen rendered this scene here too (finite, non-negative, lit: 37 s from an empty cache,
# all of it compile, for a check that weak) until 2026-12-07, when the suite needed the time:
# pm_jensen on microfacet materials is now unchecked (tests/test_photon_mapping.py checks it on
# diffuse and specular scenes). The irradiance cache went the same way on 2026-12-08 (the same
# check, 41 s of a full run from an empty cache, nearly all compile; 5 s warm): its lookups and
# gathers are checked on diffuse scenes, against final gathering and under an environment map
# (tests/test_irradiance_cache.py, tests/test_environment_map.py), its sampling through
# microfacet vertices is the path tracer's BSDF code.
@pytest.mark.parametrize("estimator, params", [
    ("whitted", dict()),
])
def test_other_estimators_render_microfacets(scene, estimator, params):
    """Whitted stops at rough vertices with direct light."""
    img = jgi.render(scene, estimator, spp=1, seed=0, **params)
    _check(img[None], estimator)
    assert img.mean() > 0


# --- against Mitsuba 3 ----------------------------------------------------------------------------

def _mitsuba_scene(mi):
    """``cornell_box_rough`` (isotropic gold: Mitsuba's tangent frame on a cube is not jgi's)
    built from Mitsuba's own ``cornell_box()``, its glass tinted in reflection and (otherwise)
    in transmission."""
    T = mi.ScalarTransform4f
    d = mi.cornell_box()
    for key in ("small-box", "large-box"):
        d.pop(key)
    d["sensor"]["film"]["width"] = d["sensor"]["film"]["height"] = RES
    d["sensor"]["film"]["rfilter"] = {"type": "box"}   # jgi's pixel filter (Mitsuba: Gaussian)
    d["sensor"]["sampler"] = {"type": "independent"}
    d["integrator"] = {"type": "path", "max_depth": DEPTH, "rr_depth": 5}
    d["copper"] = {"type": "sphere", "center": [-0.5, -0.65, 0.35], "radius": 0.35,
                   "bsdf": {"type": "roughconductor", "material": "Cu", "alpha": 0.05,
                            "distribution": "ggx"}}
    d["frosted"] = {"type": "sphere", "center": [0.45, -0.7, 0.45], "radius": 0.3,
                    "bsdf": {"type": "roughdielectric", "alpha": 0.2, "int_ior": 1.5,
                             "ext_ior": 1.0, "distribution": "ggx",
                             "specular_reflectance": {"type": "rgb", "value": [0.85, 0.9, 1.0]},
                             "specular_transmittance": {"type": "rgb",
                                                        "value": [0.9, 0.65, 0.4]}}}
    d["plastic"] = {"type": "cube",
                    "to_world": T().translate([-0.33, -0.45, -0.4]).rotate([0, 1, 0], 18.25)
                    .scale([0.28, 0.55, 0.28]),
                    "bsdf": {"type": "roughplastic", "distribution": "beckmann", "alpha": 0.3,
                             "diffuse_reflectance": {"type": "rgb", "value": [0.2, 0.3, 0.6]}}}
    d["gold"] = {"type": "cube",
                 "to_world": T().translate([0.4, -0.8, -0.35]).rotate([0, 1, 0], -17).scale(0.2),
                 "bsdf": {"type": "roughconductor", "material": "Au", "alpha": 0.15,
                          "distribution": "ggx"}}
    return mi.load_dict(d)


def _jgi_isotropic():
    b = SceneBuilder("cornell_box_rough_iso")
    builtin.cornell_room(b, RES)
    T, R, S = xf.translate, xf.rotate, xf.scale
    b.material("copper", "roughconductor", metal="Cu", alpha=0.05)
    b.material("frosted", "roughdielectric", alpha=0.2, ior=1.5, specular=(0.85, 0.9, 1.0),
               transmittance=(0.9, 0.65, 0.4))
    b.material("plastic", "roughplastic", diffuse=(0.2, 0.3, 0.6), alpha=0.3,
               distribution="beckmann")
    b.material("gold", "roughconductor", metal="Au", alpha=0.15)
    b.sphere((-0.5, -0.65, 0.35), 0.35, "copper")
    b.sphere((0.45, -0.7, 0.45), 0.3, "frosted")
    b.cube(T([-0.33, -0.45, -0.4]) @ R([0, 1, 0], 18.25) @ S([0.28, 0.55, 0.28]), "plastic")
    b.cube(T([0.4, -0.8, -0.35]) @ R([0, 1, 0], -17) @ S(0.2), "gold")
    return b.build()


@pytest.fixture(scope="module")
def mitsuba_renders():
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    scene_mi = _mitsuba_scene(mi)
    return np.stack([np.asarray(mi.render(scene_mi, spp=128, seed=s))[..., :3] for s in SEEDS])


@pytest.mark.parametrize("estimator, spp", [("pt", 128), ("bdpt", 32)])
def test_agrees_with_mitsuba(mitsuba_renders, estimator, spp):
    """jgi's path tracer and BDPT against Mitsuba 3's path integrator: rough conductors (Cu, Au
    named as Mitsuba names them), rough dielectric, Beckmann rough plastic."""
    ours = _jgi_isotropic()
    imgs = np.stack([jgi.render(ours, estimator, spp=spp, seed=500 + s, max_depth=DEPTH)
                     for s in SEEDS])
    assert_agree(imgs, mitsuba_renders, label=f"jgi {estimator} vs Mitsuba 3")


def test_photon_mapping_approaches_mitsuba(mitsuba_renders):
    """SPPM's error against Mitsuba's image falls with passes (it is consistent, not unbiased):
    the scene's twin with isotropic gold, so it stands for SPPM on cornell_box_rough too."""
    ours = _jgi_isotropic()
    ref = mitsuba_renders.mean(0)
    rel = [_rel_error(jgi.render(ours, "sppm", spp=1, seed=4, passes=p, photons=10_000,
                                 radius=0.15, radius_alpha=0.7, max_bounces=DEPTH), ref)
           for p in (1, 4, 16)]
    assert rel[0] > rel[1] > rel[2], rel
