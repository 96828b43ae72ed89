"""Image-based environment lights (Mitsuba 3's ``envmap``): the radiance lookup against
Mitsuba's own, the direction sampler against its pdf (chi-square), the constant-map furnace,
agreement between estimators and with Mitsuba 3 rendering the same XML, gradients with
respect to the texels, and the estimators that refuse it."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jgi
from jgi.analysis.chi2 import SphereDomain, assert_chi2
from jgi.core.errors import ParameterError
from jgi.core.imageio import read_hdr, write_exr
from jgi.estimators.path_tracer import PathTracerConfig, trace_pixels
from jgi.scene import SceneBuilder
from jgi.scene.builder import SceneError
from jgi.scene.importers.mitsuba import load_mitsuba_xml
from tests.support.environment import (
    env_scene,
    radiance_and_pdf,
    rotation,
    sky,
    sphere_midpoints,
    unit_directions,
)
from tests.support.light_samplers import build, pdf_li, sample_emission, sample_li
from tests.support.mitsuba import load_mitsuba
from tests.support.stats import assert_agree

X = np.array([0.1, -0.2, 0.3])


def map_lights(img=None, scale=1.5, to_world=None):
    img = sky() if img is None else img
    return build(lambda b: b.environment_map(img, scale=scale, to_world=to_world))


def test_radiance_is_mitsubas_envmap_lookup():
    """Orientation, seam, poles, bilinear weights, scale and to_world as Mitsuba 3 evaluates
    its envmap (directions at random and exactly at texel centres)."""
    mi = load_mitsuba(vectorized=True)
    if mi is None:
        pytest.skip("mitsuba is not installed")
    import drjit as dr
    img = np.random.default_rng(3).random((9, 12, 3)) + 0.05
    img[0], img[-1] = img[0].mean(0), img[-1].mean(0)   # Mitsuba's poles are single points
    m = rotation()
    em = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(img.astype(np.float32)),
                       "scale": 1.5, "to_world": mi.ScalarTransform4f(m.tolist())})
    d = unit_directions(4000, 1)
    si = dr.zeros(mi.SurfaceInteraction3f, len(d))
    si.wi = mi.Vector3f(*(-d.T))
    theirs = np.array(em.eval(si)).T
    mine, _ = radiance_and_pdf(map_lights(img, 1.5, m), d)
    np.testing.assert_allclose(mine, theirs, rtol=2e-4, atol=2e-5)


def test_png_map_decodes_as_mitsubas(tmp_path):
    """An 8-bit PNG map is sRGB-decoded as Mitsuba's envmap decodes it: equal radiance."""
    mi = load_mitsuba(vectorized=True)
    if mi is None:
        pytest.skip("mitsuba is not installed")
    import drjit as dr
    import matplotlib.image as mpimg
    mpimg.imsave(tmp_path / "sky.png", np.random.default_rng(5).random((6, 10, 3)))
    em = mi.load_dict({"type": "envmap", "filename": str(tmp_path / "sky.png")})
    d = unit_directions(2000, 6)
    si = dr.zeros(mi.SurfaceInteraction3f, len(d))
    si.wi = mi.Vector3f(*(-d.T))
    theirs = np.array(em.eval(si)).T
    mine, _ = radiance_and_pdf(build(lambda b: b.environment_map(tmp_path / "sky.png")), d)
    np.testing.assert_allclose(mine, theirs, rtol=2e-4, atol=2e-5)


def test_sampler_chi2_against_its_pdf():
    lights = map_lights(to_world=rotation())
    s = sample_li(lights, X, seed=11)
    assert s["valid"].all() and np.all(np.isinf(s["dist"]))
    L, p = radiance_and_pdf(lights, s["wi"])
    np.testing.assert_allclose(s["pdf"], p, rtol=1e-4)    # the sample's pdf is pdf_li's
    np.testing.assert_allclose(s["Li"], L, rtol=1e-4, atol=1e-6)
    r = assert_chi2(s["wi"], lambda w: radiance_and_pdf(lights, w)[1],
                    SphereDomain(n_a=48, n_phi=48), "environment map", total=1.0, nodes=16)
    assert abs(r.pdf_integral - 1.0) < 2e-3, r.pdf_integral


def test_pdf_integrates_to_one_and_follows_the_image():
    """Midpoint rule over a fine (theta, phi) grid; the pdf is proportional to the cells'
    luminance, so L / pdf is flat where the map is flat over a cell."""
    lights = map_lights(to_world=rotation())
    d, dw = sphere_midpoints(800)
    _, p = radiance_and_pdf(lights, d)
    integral = (p * dw).sum()
    assert abs(integral - 1.0) < 2e-3, integral
    # pdf_li (the MIS path) is environment_pdf
    k = lights.environment
    q = np.asarray(pdf_li(lights, np.int32(k), np.float32(X), np.float32(X + d[:1000]),
                          np.float32(-d[:1000])))
    np.testing.assert_allclose(q, p[:1000], rtol=1e-5)


def test_emission_directions_and_power():
    lights = map_lights(to_world=rotation())
    R = float(lights.bound_radius)
    e = sample_emission(lights, seed=5)
    w = -e["d"]                                      # towards the environment
    _, p = radiance_and_pdf(lights, w)
    np.testing.assert_allclose(e["pdf_dir"], p, rtol=1e-4)
    assert_chi2(w, lambda v: radiance_and_pdf(lights, v)[1], SphereDomain(n_a=32, n_phi=32),
                "environment map emission", total=1.0, nodes=16)
    # power pi R^2 \int L dw: the integral by a fine midpoint rule over the sphere
    d, dw = sphere_midpoints(600)
    L, _ = radiance_and_pdf(lights, d)
    power = np.pi * R * R * (L * dw[:, None]).sum(0)
    m = e["weight"].mean(0)
    se = e["weight"].std(0) / np.sqrt(len(e["weight"]))
    assert np.all(np.abs(m - power) < 5 * se + 2e-3 * power), (m, power, se)


def test_constant_map_is_the_constant_environment():
    L = np.array([0.8, 1.0, 1.3])
    const = build(lambda b: b.environment_light(L))
    flat = build(lambda b: b.environment_map(np.ones((9, 16, 3)) * L, scale=1.0,
                                             to_world=rotation()))
    d = unit_directions(2000, 2)
    Lc, pc = radiance_and_pdf(const, d)
    Lm, pm = radiance_and_pdf(flat, d)
    np.testing.assert_allclose(Lm, Lc, rtol=1e-6)
    np.testing.assert_allclose(pm, pc, rtol=1e-5)      # uniform: 1 / (4 pi)
    np.testing.assert_allclose(np.asarray(flat.pmf), np.asarray(const.pmf), rtol=1e-5)


def furnace_scene(env, rho=0.5, size=16):
    b = SceneBuilder("furnace")
    b.material("white", "diffuse", diffuse=rho)
    b.sphere((0.0, 0.0, 0.0), 1.0, "white")
    env(b)
    b.camera(position=(0, 0, 4), look_at=(0, 0, 0), fov=40, width=size, height=size)
    return b.build()


def test_furnace_with_a_constant_map():
    """A convex diffuse sphere of albedo rho under a uniform map of radiance L reflects
    rho L everywhere (one bounce, it cannot see itself); the background is L."""
    L, rho = np.array([0.8, 1.0, 1.3]), 0.5
    scene = furnace_scene(lambda b: b.environment_map(np.ones((9, 16, 3)) * L), rho)
    img = np.asarray(jgi.render(scene, "pt", spp=64, seed=1), np.float64)
    yy, xx = np.mgrid[0:16, 0:16]
    r = np.hypot(xx - 7.5, yy - 7.5)
    inside, outside = r < 3.5, r > 7.0       # sphere radius on film ~ 5.9 pixels
    np.testing.assert_allclose(img[outside], np.broadcast_to(L, img[outside].shape), rtol=1e-5)
    vals = img[inside]
    m, se = vals.mean(0), vals.std(0) / np.sqrt(len(vals))
    assert np.all(np.abs(m - rho * L) < 5 * se + 1e-6), (m, rho * L, se)


def test_estimators_agree_on_an_environment_lit_scene():
    """PT (MIS with the map's sampling) against PT with BSDF sampling only. (BDPT rendered this
    scene at 16 x 16 here too until 2026-12-08; tests/test_environment_estimators.py checks it,
    VCM, MMLT and PSSMLT against the path tracer on the same scene at 8 x 8, and the second
    BDPT compile went for the suite's time.)"""
    scene = env_scene()
    seeds = range(6)
    pt = np.stack([jgi.render(scene, "pt", spp=64, seed=s, max_depth=4) for s in seeds])
    bs = np.stack([jgi.render(scene, "pt", spp=64, seed=100 + s, max_depth=4, strategy="bsdf")
                   for s in seeds])
    t = assert_agree(pt, bs, regions=4, label="pt mis vs pt bsdf")
    print(f"max |t|: pt-bsdf {t.max():.2f}")


def test_light_tracing_and_photons_from_the_map():
    """Light tracing starts its subpaths from the map's emission (a direction by the map, an
    origin on the disc covering the scene): it agrees with PT on a frame the floor fills
    (light tracing leaves out the directly seen background)."""
    scene = env_scene()
    seeds = range(6)
    pt = np.stack([jgi.render(scene, "pt", spp=32, seed=s, max_depth=3) for s in seeds])
    lt = np.stack([jgi.render(scene, "lt", spp=64, seed=50 + s, max_depth=3) for s in seeds])
    t = assert_agree(pt, lt, regions=4, label="pt vs lt")
    print(f"max |t| pt-lt {t.max():.2f}")


def balls_scene():
    """Two closed diffuse balls under the sky map (no thin surfaces: photons cannot land on
    the far side of one and be gathered on its near side)."""
    b = SceneBuilder("env_balls")
    b.material("clay", "diffuse", diffuse=(0.7, 0.5, 0.3))
    b.sphere((0.0, 0.0, 0.0), 1.0, "clay")
    b.sphere((0.9, 0.9, 0.3), 0.4, "clay")
    b.environment_map(sky(), to_world=rotation(40.0, 0.0))
    b.camera(position=(0, 0, 3.2), look_at=(0, 0, 0), fov=40, width=8, height=8)
    return b.build()


@pytest.mark.slow
def test_irradiance_caching_counts_the_environment_once():
    """The gather rays that escape carry the environment, which the direct-light shadow rays
    already count: the cache holds what is left (before, images were about twice PT's)."""
    scene = balls_scene()
    seeds = range(6)
    pt = np.stack([jgi.render(scene, "pt", spp=64, seed=s) for s in seeds])
    ic = np.stack([jgi.render(scene, "irradiance_cache", spp=16, seed=40 + s) for s in seeds])
    t = assert_agree(pt, ic, regions=2, label="pt vs irradiance_cache")
    print(f"max |t| pt-irradiance_cache {t.max():.2f}")


@pytest.mark.slow
def test_photon_mapping_from_the_map():
    """SPPM's photons leave the map (directions by its distribution, origins on the bounding
    disc): on two closed balls it agrees with PT (the density estimate's bias is below the
    test's resolution here: measured 1 % at 4 x 64 spp)."""
    scene = balls_scene()
    seeds = range(6)
    pt = np.stack([jgi.render(scene, "pt", spp=64, seed=s) for s in seeds])
    sp = np.stack([jgi.render(scene, "sppm", spp=64, seed=30 + s) for s in seeds])
    t = assert_agree(pt, sp, regions=2, label="pt vs sppm")
    print(f"max |t| pt-sppm {t.max():.2f}")


def test_toml_environment_map(tmp_path):
    write_exr(tmp_path / "sky.exr", sky())
    head = ('[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nwidth = 8\nheight = 8\n'
            '[[material]]\nname = "m"\ntype = "diffuse"\ndiffuse = 0.5\n'
            '[[shape]]\ntype = "sphere"\ncenter = [0, 0, 0]\nradius = 1\nmaterial = "m"\n')
    env = ('[[light]]\ntype = "environment"\nimage = "sky.exr"\nscale = 2.0\n'
           'transform = { rotate = { axis = [0, 1, 0], angle = 30 } }\n')
    (tmp_path / "env.toml").write_text(head + env)
    scene = jgi.load_scene(tmp_path / "env.toml")
    ref = build(lambda b: b.environment_map(sky(), scale=2.0, to_world=rotation(30.0, 0.0)))
    d = unit_directions(500, 4)
    np.testing.assert_allclose(radiance_and_pdf(scene.lights, d)[0],
                               radiance_and_pdf(ref, d)[0], rtol=1e-5, atol=1e-6)
    for bad, match in [(env.replace('image = "sky.exr"', 'image = "no.exr"'), "light.*image"),
                       (env + 'radiance = 1.0\n', "exactly one of"),
                       ('[[light]]\ntype = "environment"\nradiance = 1\nscale = 2\n',
                        "scale.*'image' environment only")]:
        (tmp_path / "bad.toml").write_text(head + bad)
        with pytest.raises(SceneError, match=match):
            jgi.load_scene(tmp_path / "bad.toml")


@pytest.mark.parametrize("estimator", ["mlt"])
def test_estimators_without_environment_maps_refuse_it(estimator):
    scene = env_scene(8)
    with pytest.raises(ParameterError, match=estimator):
        jgi.render(scene, estimator, spp=1, seed=0)


def test_gradient_with_respect_to_texels():
    """d mean(image) / d texels by reverse mode (PT, MIS, detached) equals a central difference
    on one block of texels (same paths: the sampling tables are kept, so both differentiate
    one estimator; the radiance is linear in the texels, the MIS weights held fixed)."""
    scene = furnace_scene(lambda b: b.environment_map(sky(9, 16, sun=(2, 5))), size=8)
    pixel = jnp.tile(jnp.arange(64, dtype=jnp.int32), 8)
    sample = jnp.repeat(jnp.arange(8, dtype=jnp.int32), 64)
    cfg = PathTracerConfig(max_depth=2, rr_depth=-1, gradient="detached")

    @jax.jit
    def estimate(texels):
        s = eqx.tree_at(lambda q: q.lights.envmap.texels, scene, texels)
        L = trace_pixels(s, cfg, jnp.uint32(4), pixel, sample)
        return L.x.mean() + L.y.mean() + L.z.mean()

    tex = scene.lights.envmap.texels
    g = np.asarray(jax.jit(jax.grad(estimate))(tex))
    assert np.all(np.isfinite(g)) and np.abs(g).sum() > 0
    mask = np.zeros(tex.shape, np.float32)
    mask[1:4, 3:8, 1] = 1.0                    # a block of green texels around the sun
    h = 0.05
    fd = (float(estimate(tex + h * mask)) - float(estimate(tex - h * mask))) / (2 * h)
    ad = float((g * mask).sum())
    assert fd > 0 and abs(ad - fd) < 1e-3 * abs(fd), (ad, fd)


def test_bad_maps_are_refused():
    b = SceneBuilder("bad")
    with pytest.raises(SceneError, match="H >= 2"):
        b.environment_map(np.ones((1, 4, 3)))
    with pytest.raises(SceneError, match="finite and non-negative"):
        b.environment_map(np.full((4, 4, 3), np.nan))
    with pytest.raises(SceneError, match="cannot read"):
        b.environment_map("/nonexistent/sky.exr")
    # a black map: finite renders, nothing from the environment
    scene = furnace_scene(lambda b: b.environment_map(np.zeros((4, 8, 3))), size=8)
    img = np.asarray(jgi.render(scene, "pt", spp=4, seed=0))
    assert np.all(img == 0)


def write_rgbe(path, rgbe: np.ndarray, rle: bool):
    """A Radiance file of the [H, W, 4] RGBE bytes: flat, or new-style run-length encoded
    (runs of equal bytes and literal stretches, per channel)."""
    H, W, _ = rgbe.shape
    out = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {H} +X {W}\n".encode())
    for y in range(H):
        if not rle:
            out += rgbe[y].tobytes()
            continue
        out += bytes([2, 2, W >> 8, W & 255])
        for c in range(4):
            row, x = rgbe[y, :, c], 0
            while x < W:
                n = 1
                while x + n < W and n < 127 and row[x + n] == row[x]:
                    n += 1
                if n >= 3:
                    out += bytes([128 + n, row[x]])
                else:
                    n = min(W - x, 128)
                    for k in range(x, min(W, x + 128) - 2):   # stop a literal before a run
                        if row[k] == row[k + 1] == row[k + 2]:
                            n = max(k - x, 1)
                            break
                    out += bytes([n]) + row[x:x + n].tobytes()
                x += n
    path.write_bytes(bytes(out))


@pytest.mark.parametrize("rle", [False, True])
def test_radiance_hdr_reads_as_mitsuba_reads_it(tmp_path, rle):
    rng = np.random.default_rng(7)
    rgbe = rng.integers(0, 256, (6, 20, 4), dtype=np.uint8)
    rgbe[:, 5:12] = rgbe[:, 5:6]            # runs
    rgbe[2, :, 3] = 0                        # a black row (e = 0)
    path = tmp_path / ("sky_rle.hdr" if rle else "sky.hdr")
    write_rgbe(path, rgbe, rle)
    mine = read_hdr(path)
    e = rgbe[..., 3].astype(int)
    expected = np.where(e[..., None] > 0, rgbe[..., :3] * np.ldexp(1.0, e - 136)[..., None], 0.0)
    np.testing.assert_array_equal(mine, expected.astype(np.float32))
    mi = load_mitsuba()
    if mi is not None:
        np.testing.assert_array_equal(mine, np.array(mi.Bitmap(str(path)))[..., :3])
    b = SceneBuilder("hdr")
    b.environment_map(path)
    assert b.lights[0]["envmap"].shape == (6, 20)
    (tmp_path / "bad.hdr").write_bytes(b"#?RADIANCE\n\n+Y 2 +X 2\n" + bytes(16))
    with pytest.raises(SceneError, match="resolution line"):
        b2 = SceneBuilder("bad")
        b2.environment_map(tmp_path / "bad.hdr")


def test_radiance_hdr_centred_decoding_removes_the_writers_truncation(tmp_path):
    """Writers (Walter's, SmallVCM's) truncate each channel to its 8-bit step: the plain decoding
    is low by half a step on average, the centred one is not (what a peer benchmark compares)."""
    rng = np.random.default_rng(3)
    rgb = rng.uniform(0.05, 1.0, (64, 64, 3)) * rng.uniform(0.1, 10.0, (64, 64, 1))
    v = rgb.max(-1)
    mantissa, e = np.frexp(v)
    scale = mantissa * 256.0 / v
    rgbe = np.concatenate([np.floor(rgb * scale[..., None]), (e + 128)[..., None]], -1)
    path = tmp_path / "truncated.hdr"
    write_rgbe(path, rgbe.astype(np.uint8), rle=False)
    plain, centred = read_hdr(path), read_hdr(path, centred=True)
    step = np.ldexp(1.0, e - 8)[..., None]                 # one quantisation step per pixel
    err_plain, err_centred = (plain - rgb) / step, (centred - rgb) / step
    assert np.all((err_plain <= 1e-3) & (err_plain > -1.0 - 1e-3))   # truncation: [-1, 0) step
    assert abs(err_plain.mean() + 0.5) < 0.01                        # mean -1/2 step (n = 12288)
    assert abs(err_centred.mean()) < 0.01 and np.abs(err_centred).max() <= 0.5 + 1e-3

ENVMAP_XML = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="4"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, 0.6, 4" target="0, -0.2, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
      <rfilter type="box"/></film>
  </sensor>
  <bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.7, 0.2, 0.2"/></bsdf>
  <bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf>
  <shape type="sphere"><float name="radius" value="0.8"/><ref id="red"/></shape>
  <shape type="sphere"><point name="center" x="0" y="-101" z="0"/>
    <float name="radius" value="100.2"/><ref id="white"/></shape>
  <emitter type="envmap">
    <string name="filename" value="sky.exr"/>
    <float name="scale" value="0.8"/>
    <transform name="to_world"><rotate y="1" angle="40"/><rotate x="1" angle="15"/></transform>
  </emitter>
</scene>
"""


def test_mitsuba_envmap_xml_loads(tmp_path):
    write_exr(tmp_path / "sky.exr", sky())
    (tmp_path / "env.xml").write_text(ENVMAP_XML)
    scene = load_mitsuba_xml(tmp_path / "env.xml")
    assert scene.lights.envmap is not None
    np.testing.assert_allclose(np.asarray(scene.lights.envmap.texels), sky(), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(scene.lights.emission.stack())[0], 0.8)
    (tmp_path / "bad.xml").write_text(ENVMAP_XML.replace("sky.exr", "none.exr"))
    with pytest.raises(SceneError, match="none.exr"):
        load_mitsuba_xml(tmp_path / "bad.xml")


def test_envmap_scene_renders_like_mitsuba(tmp_path):
    """jgi's path tracer and Mitsuba 3's path integrator on the same XML and EXR map: Welch's
    t per 4 x 4 region and channel, both sides' variances from 16 seeds."""
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    write_exr(tmp_path / "sky.exr", sky())
    xml = tmp_path / "env.xml"
    xml.write_text(ENVMAP_XML)
    ours = load_mitsuba_xml(xml)
    scene_mi = mi.load_file(str(xml))
    seeds, spp = range(16), 64
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=spp, seed=s))[..., :3]
                       for s in seeds])
    mine = np.stack([jgi.render(ours, "pt", spp=spp, seed=s, max_depth=4) for s in seeds])
    t4 = assert_agree(mine, theirs, regions=4, label="envmap: jgi vs Mitsuba 3 (regions)")
    t1 = assert_agree(mine, theirs, regions=1, label="envmap: jgi vs Mitsuba 3 (image)")
    print(f"envmap vs Mitsuba: max |t| {t4.max():.2f} (48 region-channels), "
          f"{t1.max():.2f} (image); mean ratio {mine.mean() / theirs.mean():.4f}")
