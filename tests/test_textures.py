"""Textures: surface coordinates of every primitive against closed forms, the texture lookups
against numpy, a checkerboard plane under a point light against its closed form, every
estimator on a textured Cornell box against the path tracer, and untextured scenes rendering
bit for bit as before textures existed."""

from __future__ import annotations

from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import matplotlib.image as mpimg
import numpy as np
import pytest

import jgi
from jgi.core import transform as xf
from jgi.core.imageio import read_image, srgb_decode
from jgi.core.vec import V3
from jgi.estimators.path_tracer import PathTracerConfig, trace_pixels
from jgi.physics import camera as C
from jgi.physics import geometry as G
from jgi.physics import textures as T
from jgi.scene import builtin as scenes
from jgi.scene.builder import SceneBuilder, SceneError
from jgi.scene.importers.mitsuba import load_mitsuba_xml
from tests.support.mitsuba import load_mitsuba
from tests.support.scenes import ply_quad
from tests.support.stats import assert_agree, critical_t, region_stats

DATA = Path(__file__).parent / "data"


def _v3(a):
    a = np.asarray(a, np.float32).reshape(-1, 3)
    return V3(*(jnp.asarray(a[:, k]) for k in range(3)))


def _builder():
    b = SceneBuilder("t")
    b.texture("c", "checkerboard")
    b.material("m", "diffuse", diffuse="c")
    b.camera((0, 0, 5), (0, 0, 0), width=4, height=4)
    return b


def _hit(scene, o, d):
    h = G.intersect(scene, _v3(o), _v3(d))
    return np.asarray(h.uv[0]), np.asarray(h.uv[1]), np.asarray(h.valid)


# --- surface coordinates ---------------------------------------------------------------------

def test_sphere_uv_is_mitsubas_parametrisation(rng_np):
    b = _builder()
    c, r = np.array([0.3, -0.2, 0.1]), 0.7
    b.sphere(c, r, "m")
    scene = b.build()
    theta = rng_np.uniform(0.1, np.pi - 0.1, 64)
    phi = rng_np.uniform(0, 2 * np.pi, 64)
    n = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    u, v, ok = _hit(scene, c + 3 * n, -n)
    assert ok.all()
    np.testing.assert_allclose(u, phi / (2 * np.pi), atol=2e-5)
    np.testing.assert_allclose(v, theta / np.pi, atol=2e-5)


@pytest.mark.parametrize("rect", [True, False])
def test_rectangle_and_quad_uv_are_the_parallelogram_parameters(rng_np, rect):
    b = _builder()
    to_world = (xf.translate([0.1, 0.2, 0.3]) @ xf.rotate([0, 1, 0], 0 if rect else 30)
                @ xf.scale([1.5, 0.5, 1.0]))
    b.rectangle(to_world, "m")
    scene = b.build()
    assert (scene.rects.count, scene.quads.count) == ((1, 0) if rect else (0, 1))
    a, bb = rng_np.uniform(0.02, 0.98, (2, 50))
    # Mitsuba's rectangle: local (x, y) in [-1, 1]^2, uv = ((x + 1) / 2, (y + 1) / 2)
    p = xf.apply_point(to_world, np.stack([2 * a - 1, 2 * bb - 1, np.zeros(50)], 1))
    n = xf.apply_vector(to_world, [0.0, 0.0, 1.0])
    n = n / np.linalg.norm(n)
    u, v, ok = _hit(scene, p + 2 * n, np.broadcast_to(-n, p.shape))
    assert ok.all()
    np.testing.assert_allclose(u, a, atol=2e-5)
    np.testing.assert_allclose(v, bb, atol=2e-5)


@pytest.mark.parametrize("bvh", [False, True])
def test_triangle_uv_interpolates_the_vertex_uvs(rng_np, bvh):
    b = _builder()
    b.bvh = bvh
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    uvs = np.array([[0.1, 0.2], [0.9, 0.3], [0.2, 0.8], [0.7, 0.9]])
    b.mesh(verts, [[0, 1, 2], [1, 3, 2]], "m", uv=uvs)
    b.mesh(verts + [0, 0, -1], [[0, 1, 2]], "m")  # no uvs: Mitsuba's (0,0), (1,0), (0,1)
    scene = b.build()
    assert (scene.triangles.bvh is not None) == bvh
    b1, b2 = rng_np.uniform(0.02, 0.48, (2, 40))
    p = verts[0] + b1[:, None] * (verts[1] - verts[0]) + b2[:, None] * (verts[2] - verts[0])
    u, v, ok = _hit(scene, p + [0, 0, 1], np.broadcast_to([0.0, 0, -1], p.shape))
    assert ok.all()
    expect = uvs[0] + b1[:, None] * (uvs[1] - uvs[0]) + b2[:, None] * (uvs[2] - uvs[0])
    np.testing.assert_allclose(np.stack([u, v], 1), expect, atol=2e-5)
    # the second mesh, seen from below
    u, v, ok = _hit(scene, p + [0, 0, -2], np.broadcast_to([0.0, 0, 1], p.shape))
    assert ok.all()
    np.testing.assert_allclose(np.stack([u, v], 1), np.stack([b1, b2], 1), atol=2e-5)


def test_textured_cube_is_mitsubas_cube_mesh():
    """A cube with a textured material is Mitsuba's twelve-triangle mesh (its uv per face);
    an untextured one stays an oriented box."""
    b = _builder()
    b.material("plain", "diffuse", diffuse=0.5)
    b.cube(xf.scale(0.5), "m")
    b.cube(xf.translate([2.0, 0, 0]), "plain")
    scene = b.build()
    assert (scene.triangles.count, scene.boxes.count, scene.quads.count) == (12, 1, 0)


def test_untextured_hits_carry_no_uv():
    scene = scenes.cornell_box(resolution=4)
    assert not scene.materials.has_textures and scene.rects.origin is None
    assert G.intersect(scene, _v3([0, 0, 3]), _v3([0, 0, -1])).uv is None


# --- lookups ---------------------------------------------------------------------------------

def test_checkerboard_pattern():
    b = SceneBuilder("t")
    b.texture("c", "checkerboard", color0=(1, 0, 0), color1=(0, 0, 1), scale=(2, 4))
    b.material("m", "diffuse", diffuse="c")
    b.camera((0, 0, 5), (0, 0, 0), width=4, height=4)
    tex = b.build().materials.textures
    u, v = np.meshgrid(np.linspace(-1.3, 1.7, 41), np.linspace(-0.9, 2.1, 37))
    u, v = u.ravel().astype(np.float32), v.ravel().astype(np.float32)
    got = T.evaluate(tex, jnp.zeros(u.shape, jnp.int32), (jnp.asarray(u), jnp.asarray(v)))
    su, sv = 2 * u, 4 * v
    same = ((su - np.floor(su)) > 0.5) == ((sv - np.floor(sv)) > 0.5)
    np.testing.assert_array_equal(np.asarray(got.x), np.where(same, 1.0, 0.0))
    np.testing.assert_array_equal(np.asarray(got.z), np.where(same, 0.0, 1.0))


def _bilinear_numpy(img, u, v):
    h, w, _ = img.shape
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    at = lambda yy, xx: img[yy % h, xx % w]  # noqa: E731
    return ((1 - fx) * (1 - fy) * at(y0, x0) + fx * (1 - fy) * at(y0, x0 + 1)
            + (1 - fx) * fy * at(y0 + 1, x0) + fx * fy * at(y0 + 1, x0 + 1))


def test_bilinear_lookup_with_wrap_matches_numpy(rng_np):
    imgs = [rng_np.uniform(0, 1, (5, 7, 3)), rng_np.uniform(0, 1, (3, 4, 3))]
    b = SceneBuilder("t")
    b.texture("c", "checkerboard")
    b.texture("a", "bitmap", data=imgs[0])
    b.texture("b", "bitmap", data=imgs[1], scale=(3, 2), offset=(0.25, -0.5))
    b.material("m", "diffuse", diffuse="a")
    b.camera((0, 0, 5), (0, 0, 0), width=4, height=4)
    tex = b.build().materials.textures
    u, v = rng_np.uniform(-2, 3, (2, 500)).astype(np.float32)
    for row, img, (su, sv, du, dv) in ((1, imgs[0], (1, 1, 0, 0)),
                                       (2, imgs[1], (3, 2, 0.25, -0.5))):
        got = T.evaluate(tex, jnp.full(u.shape, row, jnp.int32), (jnp.asarray(u), jnp.asarray(v)))
        expect = _bilinear_numpy(img, su * u.astype(float) + du, sv * v.astype(float) + dv)
        np.testing.assert_allclose(np.stack([np.asarray(c) for c in got], 1), expect, atol=2e-5)


def test_png_is_srgb_decoded_unless_raw(tmp_path):
    img = np.random.default_rng(3).integers(0, 256, (4, 6, 3)).astype(np.uint8)
    path = tmp_path / "t.png"
    mpimg.imsave(str(path), img)
    lin = read_image(path)
    raw = read_image(path, raw=True)
    np.testing.assert_allclose(raw, img / 255.0, atol=1e-6)
    x = img / 255.0
    expect = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(lin, expect, atol=1e-6)
    np.testing.assert_allclose(srgb_decode([0.0, 1.0]), [0.0, 1.0], atol=1e-12)


def test_gradient_with_respect_to_texels():
    """Texels are pytree leaves: d(image)/d(atlas) exists and matches a finite difference."""
    b = SceneBuilder("t")
    b.texture("img", "bitmap", data=np.full((2, 2, 3), 0.5))
    b.material("m", "diffuse", diffuse="img")
    b.quad((-1, 0, -1), (0, 0, 2), (2, 0, 0), "m")
    b.point_light((0, 1, 0), 5.0)
    b.camera((0, 2, 2), (0, 0, 0), fov=50, width=4, height=4)
    scene = b.build()

    pixel = jnp.tile(jnp.arange(16, dtype=jnp.int32), 4)
    sample = jnp.repeat(jnp.arange(4, dtype=jnp.int32), 16)
    cfg = PathTracerConfig(strategy="light", max_depth=2, rr_depth=-1)

    def estimate(atlas):
        s = eqx.tree_at(lambda s: s.materials.textures.atlas, scene, atlas)
        L = trace_pixels(s, cfg, jnp.uint32(0), pixel, sample)
        return L.x.mean() + 0.5 * L.y.mean()

    atlas = scene.materials.textures.atlas
    value_and_grad = jax.jit(jax.value_and_grad(estimate))   # one program: values and slope
    g = value_and_grad(atlas)[1]
    assert np.all(np.isfinite(np.asarray(g))) and float(jnp.sum(g)) > 0
    # the estimate is linear in the texels (direct light from one point light)
    h = 0.1
    fd = (float(value_and_grad(atlas * (1 + h))[0])
          - float(value_and_grad(atlas * (1 - h))[0])) / (2 * h)
    np.testing.assert_allclose(float(jnp.sum(g * atlas)), fd, rtol=1e-3)


# --- closed form -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def checker_plane():
    """A checkerboard plane under a point light, and its pixel integrals of
    L = (rho(uv) / pi) I cos(theta) / d^2 by a sub-pixel grid of rays."""
    I, h = 10.0, 1.0
    c0, c1 = np.array([0.8, 0.5, 0.2]), np.array([0.1, 0.3, 0.6])
    b = SceneBuilder("checker_plane")
    b.texture("checks", "checkerboard", color0=c0, color1=c1, scale=50)
    b.material("plane", "diffuse", diffuse="checks")
    # u = (z + 50) / 100, v = (x + 50) / 100
    b.quad((-50, 0, -50), (0, 0, 100), (100, 0, 0), "plane")
    b.point_light((0, h, 0), (I, I, I))
    b.camera(position=(0, 3, 3), look_at=(0, 0, 0), fov=50, width=16, height=16)
    scene = b.build()
    cam, sub = scene.camera, 24
    g = (np.arange(sub) + 0.5) / sub
    py, px, gy, gx = np.meshgrid(np.arange(16), np.arange(16), g, g, indexing="ij")
    o, d = C.sample_ray(cam, jnp.asarray(px.ravel()), jnp.asarray(py.ravel()),
                        jnp.asarray(gx.ravel(), jnp.float32), jnp.asarray(gy.ravel(), jnp.float32))
    o, d = np.asarray(o.stack()), np.asarray(d.stack())
    x = o + d * (-o[:, 1] / d[:, 1])[:, None]
    su, sv = 50 * (x[:, 2] + 50) / 100, 50 * (x[:, 0] + 50) / 100
    same = ((su - np.floor(su)) > 0.5) == ((sv - np.floor(sv)) > 0.5)
    rho = np.where(same[:, None], c0, c1)
    d2 = ((np.array([0.0, h, 0.0]) - x) ** 2).sum(1)
    L = rho / np.pi * I * (h / np.sqrt(d2) / d2)[:, None]
    return scene, L.reshape(16, 16, sub * sub, 3).mean(2)


@pytest.mark.parametrize("estimator,params", [
    ("pt", dict(strategy="light", max_depth=2)),
    ("whitted", dict(max_depth=2)),
    ("pm_jensen", dict(photons=2000, final_gather=2)),   # direct light: exact
    ("irradiance_cache", dict()),                                      # no indirect light
])
def test_checkerboard_plane_under_point_light_matches_closed_form(checker_plane, estimator,
                                                                  params):
    scene, ref = checker_plane
    imgs = np.stack([jgi.render(scene, estimator, spp=8, seed=s, **params) for s in range(12)])
    mean, se = region_stats(imgs, regions=4)
    ref_regions = ref.reshape(4, 4, 4, 4, 3).mean(axis=(1, 3))
    z = np.abs(mean - ref_regions) / se
    print(f"checkerboard plane, {estimator}: max |z| = {z.max():.2f}")
    assert z.max() < critical_t(len(imgs) - 1, z.size), z


@pytest.mark.parametrize("estimator,sizes", [
    ("pm", [dict(photons=20_000, radius=0.3), dict(photons=320_000, radius=0.1)]),
    ("sppm", [dict(photons=20_000, passes=1, radius=0.3), dict(photons=20_000, passes=8,
                                                               radius=0.3)]),
])   # ppm is sppm with the first pass's visible points: the same textured density estimate
def test_photon_mapping_of_the_checkerboard_converges(checker_plane, estimator, sizes):
    """Biased but consistent: the error against the closed form falls with photons (or
    passes): the density estimate blurs the checkerboard less and less."""
    scene, ref = checker_plane
    regions = lambda x: x.reshape(8, 2, 8, 2, 3).mean(axis=(1, 3))  # noqa: E731
    errs = [float(np.sqrt(np.mean((regions(np.asarray(jgi.render(scene, estimator, spp=16, seed=1,
                                                                  max_bounces=2, **kw)))
                                    - regions(ref)) ** 2)) / ref.mean()) for kw in sizes]
    print(f"{estimator}: relative RMS error over 2 x 2 pixel regions {errs[0]:.3f} -> "
          f"{errs[1]:.3f}")
    assert errs[1] < 0.7 * errs[0], errs


# --- scenes without textures: unchanged --------------------------------------------------------

@pytest.mark.parametrize("name,estimator", [("cornell_box", "pt"), ("veach_plates", "pt")])
def test_untextured_scenes_render_bit_for_bit_as_before(name, estimator):
    """References rendered by jgi before textures (main at e294946, 16^2, 4 spp, seed 0, LLVM
    unroll threshold 1000 as in the suite): a scene without textures compiles to the same code."""
    ref = np.load(DATA / f"untextured_{name}_{estimator}.npy")
    img = np.asarray(jgi.render(jgi.load_scene(name).with_resolution(16, 16), estimator, spp=4,
                                seed=0))
    assert np.array_equal(img, ref)


# --- every estimator on a textured scene -------------------------------------------------------

DEPTH = 3   # few path lengths: short compiles
# PSSMLT, MMLT and VCM evaluate vertices with the path tracer's, BDPT's and the shared
# subpath code (the same texture lookups), tested here and on the rough and smooth-normal
# scenes; rendering each here costs close to a minute of compiles (the suite has 15 minutes).


@pytest.fixture(scope="module")
def textured():
    return scenes.cornell_box_textured(resolution=16)


def _stack(scene, estimator, seeds, **kw):
    return np.stack([np.asarray(jgi.render(scene, estimator, seed=s, **kw)) for s in seeds])


@pytest.fixture(scope="module")
def pt_reference(textured):
    return _stack(textured, "pt", range(100, 108), spp=64, max_depth=DEPTH)


# Veach's MLT on textures: tests/test_plastic_estimators.py's coating caustic has a checkerboard
# floor (perturbed vertices keeping a stale uv fail there, t = 8.3 > 7.9); PSSMLT and MMLT
# evaluate paths with the path tracer's and BDPT's code.
@pytest.mark.parametrize("estimator,params,spp", [
    ("lt", dict(max_depth=DEPTH), 64),
    ("bdpt", dict(max_depth=DEPTH), 32),
])
def test_unbiased_estimators_agree_with_the_path_tracer(textured, pt_reference, estimator,
                                                        params, spp):
    imgs = _stack(textured, estimator, range(8), spp=spp, **params)
    t = assert_agree(imgs, pt_reference, regions=4, label=f"{estimator} vs pt, textured")
    print(f"{estimator}: max t = {t.max():.2f}")


# --- against Mitsuba 3 -------------------------------------------------------------------------

TEXTURED_BSDFS = """
    <texture type="bitmap" id="stripes">
        <string name="filename" value="stripes.png"/>
    </texture>
    <bsdf type="diffuse" id="floor">
        <texture type="checkerboard" name="reflectance">
            <rgb name="color0" value="0.8, 0.8, 0.8"/>
            <rgb name="color1" value="0.15, 0.3, 0.6"/>
            <transform name="to_uv"><scale x="4" y="4"/></transform>
        </texture>
    </bsdf>
    <bsdf type="diffuse" id="wall"><ref name="reflectance" id="stripes"/></bsdf>
    <bsdf type="diffuse" id="ball">
        <texture type="bitmap" name="reflectance">
            <string name="filename" value="stripes.png"/>
            <string name="filter_type" value="bilinear"/>
            <string name="wrap_mode" value="repeat"/>
            <transform name="to_uv"><scale x="2" y="1"/></transform>
        </texture>
    </bsdf>
"""


def _textured_cornell_xml(tmp_path) -> Path:
    """Mitsuba's Cornell box with a checkerboard floor, a bitmap (an 8-bit sRGB PNG) on the back
    wall and on a sphere in place of the blocks."""
    img = (255 * scenes.stripes_image(8) ** (1 / 2.2)).round().astype(np.uint8)
    mpimg.imsave(str(tmp_path / "stripes.png"), img)
    xml = (DATA / "cornell_box_mitsuba.xml").read_text().replace('value="256"', 'value="16"')
    head, _, rest = xml.partition("    <shape type=\"cube\">")
    head = head.replace('<bsdf type="diffuse" id="white">',
                        TEXTURED_BSDFS + '    <bsdf type="diffuse" id="white">', 1)
    walls = head.split("<ref id=\"white\"/>")
    # shapes in order: light, floor, ceiling, back wall, ...
    head = "".join(w + r for w, r in zip(walls, ["<ref id=\"white\"/>", "<ref id=\"floor\"/>",
                                                 "<ref id=\"white\"/>", "<ref id=\"wall\"/>"]
                                         + [""] * (len(walls) - 4)))
    sphere = """    <shape type="sphere">
        <point name="center" x="0.3" y="-0.6" z="0.1"/><float name="radius" value="0.4"/>
        <ref id="ball"/>
    </shape>
</scene>
"""
    path = tmp_path / "cornell_textured.xml"
    path.write_text(head + sphere)
    return path


def test_textured_cornell_box_renders_like_mitsuba(tmp_path):
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    xml = _textured_cornell_xml(tmp_path)
    scene_mi = mi.load_file(str(xml))
    ours = load_mitsuba_xml(xml)
    assert ours.materials.has_textures
    seeds = range(16)
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=64, seed=s))[..., :3] for s in seeds])
    mine = np.stack([jgi.render(ours, "pt", spp=64, seed=s, max_depth=8, rr_depth=5)
                     for s in seeds])
    t4 = assert_agree(mine, theirs, regions=4, label="textured: jgi vs Mitsuba 3 (4 x 4)")
    t1 = assert_agree(mine, theirs, regions=1, label="textured: jgi vs Mitsuba 3 (image)")
    print(f"textured Cornell box vs Mitsuba: max |t| = {t4.max():.2f} (48 region-channels), "
          f"{t1.max():.2f} (image); means {mine.mean((0, 1, 2))} vs {theirs.mean((0, 1, 2))}")


# --- scene files ---------------------------------------------------------------------------------

TOML_SCENE = """
name = "textured"
[camera]
position = [0, 1, 3]
look_at = [0, 0, 0]
width = 8
height = 8
[[texture]]
name = "checks"
type = "checkerboard"
color0 = [0.8, 0.1, 0.1]
color1 = 0.3
scale = [4, 2]
[[texture]]
name = "img"
type = "bitmap"
filename = "img.png"
[[material]]
name = "floor"
type = "diffuse"
diffuse = "checks"
[[material]]
name = "metal"
type = "roughconductor"
specular = "img"
alpha = "checks"
[[shape]]
type = "rectangle"
material = "floor"
[[shape]]
type = "sphere"
center = [0, 0.5, 0]
radius = 0.3
material = "metal"
[[light]]
type = "point"
position = [0, 2, 0]
intensity = 5
"""


def _toml(tmp_path, text):
    mpimg.imsave(str(tmp_path / "img.png"), np.full((2, 3, 3), 128, np.uint8))
    path = tmp_path / "s.toml"
    path.write_text(text)
    return path


def test_toml_textures(tmp_path):
    scene = jgi.load_scene(str(_toml(tmp_path, TOML_SCENE)))
    tex = scene.materials.textures
    assert tex.count == 2 and scene.materials.textured == (0, 1, 2)
    np.testing.assert_allclose(np.asarray(tex.to_uv[0]), [4, 0, 0, 0, 2, 0])
    np.testing.assert_allclose(np.asarray(tex.atlas), srgb_decode(128 / 255), rtol=1e-6)
    assert np.isfinite(jgi.render(scene, "pt", spp=2)).all()
    aniso = TOML_SCENE.replace('alpha = "checks"', 'alpha_u = "checks"\nalpha_v = 0.2')
    mats = jgi.load_scene(str(_toml(tmp_path, aniso))).materials
    assert mats.textured == (0, 1, 2, 3) and float(mats.alpha_v[1]) == pytest.approx(0.2)


@pytest.mark.parametrize("old,new,match", [
    ('diffuse = "checks"', 'diffuse = "chex"', r"material\[0\].diffuse: unknown texture 'chex'"),
    ('filename = "img.png"', 'filename = "nope.png"', r"texture\[1\].filename: file .* does not"),
    ('type = "checkerboard"', 'type = "wood"', r"texture\[0\].type: unknown type 'wood'; "
                                               "allowed: checkerboard, bitmap"),
    ('scale = [4, 2]', 'scale = [4, 2, 1]', r"texture\[0\].scale: expected one number or 2"),
    ('color1 = 0.3', 'colour1 = 0.3', r"texture\[0\].colour1: unknown key .*did you mean"),
    ('alpha = "checks"', 'alpha_u = "checks"', r"material\[1\].alpha_v: missing: alpha_u and "
                                               "alpha_v go together"),
])
def test_toml_texture_errors(tmp_path, old, new, match):
    with pytest.raises(SceneError, match=match):
        jgi.load_scene(str(_toml(tmp_path, TOML_SCENE.replace(old, new))))


@pytest.mark.parametrize("option,match", [
    ('<string name="filter_type" value="nearest"/>', "filter_type 'nearest' is not supported"),
    ('<string name="wrap_mode" value="mirror"/>', "wrap_mode 'mirror' is not supported"),
    ('<float name="gamma" value="2"/>', "unknown parameter 'gamma'"),
])
def test_mitsuba_unsupported_texture_options_are_refused(tmp_path, option, match):
    xml = _textured_cornell_xml(tmp_path)
    text = xml.read_text().replace('<string name="filename" value="stripes.png"/>',
                                   '<string name="filename" value="stripes.png"/>' + option, 1)
    xml.write_text(text)
    with pytest.raises(SceneError, match=match):
        load_mitsuba_xml(xml)


PBRT_SCENE = """
LookAt 0 3 3  0 0 0  0 1 0
Camera "perspective" "float fov" 45
Film "rgb" "integer xresolution" 8 "integer yresolution" 8
WorldBegin
LightSource "point" "rgb I" [5 5 5] "point3 from" [0 2 0]
Texture "checks" "spectrum" "checkerboard" "float uscale" 3 "float vscale" 5
    "rgb tex1" [.8 .1 .1] "rgb tex2" [.1 .1 .8]
Texture "img" "spectrum" "imagemap" "string filename" "rows.png" "string encoding" "linear"
AttributeBegin
Material "diffuse" "texture reflectance" "checks"
Shape "trianglemesh" "point3 P" [-1 0 -1  1 0 -1  1 0 1  -1 0 1] "integer indices" [0 1 2 0 2 3]
    "point2 uv" [0 0 1 0 1 1 0 1]
AttributeEnd
Material "diffuse" "texture reflectance" "img"
Shape "trianglemesh" "point3 P" [-1 0 -1.5  1 0 -1.5  1 1 -1.5] "point2 uv" [0 0 1 0 1 1]
"""


def test_pbrt_checkerboard_and_imagemap(tmp_path):
    """pbrt-v4's conventions: checkerboard tex1 where floor(s) + floor(t) is even, (s, t) =
    (uscale u, vscale v); imagemap rows from the top at t = 1 - v."""
    rows = np.zeros((2, 1, 3), np.uint8)
    rows[0] = 255                     # top row white, bottom row black
    mpimg.imsave(str(tmp_path / "rows.png"), rows)
    path = tmp_path / "s.pbrt"
    path.write_text(PBRT_SCENE)
    tex = jgi.load_scene(str(path)).materials.textures
    u, v = np.random.default_rng(5).uniform(0.01, 0.99, (2, 200)).astype(np.float32)
    uv = (jnp.asarray(u), jnp.asarray(v))
    checks = T.evaluate(tex, jnp.zeros(u.shape, jnp.int32), uv)
    even = (np.floor(3 * u) + np.floor(5 * v)) % 2 == 0
    np.testing.assert_allclose(np.asarray(checks.x), np.where(even, 0.8, 0.1), atol=1e-6)
    img = T.evaluate(tex, jnp.ones(2, jnp.int32), (jnp.asarray([0.5, 0.5]),
                                                   jnp.asarray([0.75, 0.25])))
    np.testing.assert_allclose(np.asarray(img.x), [1.0, 0.0], atol=1e-6)   # v = 0.75: top row
    with pytest.raises(SceneError, match="shape \"sphere\" with a textured material"):
        path.write_text(PBRT_SCENE + 'Shape "sphere"\n')
        jgi.load_scene(str(path))


OBJ_QUAD = """v -1 -1 0
v 1 -1 0
v 1 1 0
v -1 1 0
vt 0.1 0.2
vt 0.9 0.1
vt 0.8 0.7
vt 0.2 0.9
f 1/1 2/2 3/3
f 1/1 3/3 4/4
"""


@pytest.mark.parametrize("with_vt", [True, False])
def test_obj_uv_matches_mitsubas(tmp_path, with_vt):
    """A textured OBJ imported from Mitsuba XML: jgi's hit uv equals Mitsuba's ray_intersect
    uv (Mitsuba flips the file's v; without vt each triangle has (0,0), (1,0), (0,1))."""
    mi = load_mitsuba(vectorized=True)
    if mi is None:
        pytest.skip("mitsuba is not installed")
    text = OBJ_QUAD if with_vt else "".join(
        line + "\n" for line in OBJ_QUAD.splitlines() if line[:2] == "v ") + "f 1 2 3\nf 1 3 4\n"
    (tmp_path / "q.obj").write_text(text)
    xml = tmp_path / "q.xml"
    xml.write_text('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">'
                   '<integer name="width" value="4"/><integer name="height" value="4"/></film>'
                   '</sensor><shape type="obj"><string name="filename" value="q.obj"/>'
                   '<boolean name="face_normals" value="true"/><bsdf type="diffuse">'
                   '<texture type="checkerboard" name="reflectance"/></bsdf></shape></scene>')
    rng = np.random.default_rng(0)
    o = np.c_[rng.uniform(-0.95, 0.95, (20, 2)), np.full(20, 2.0)]
    d = np.tile([0.0, 0.0, -1.0], (20, 1))
    ray = mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T))
    theirs = np.array(mi.Vector2f(mi.load_file(str(xml)).ray_intersect(ray).uv))
    u, v, ok = _hit(load_mitsuba_xml(xml), o, d)
    assert ok.all()
    np.testing.assert_allclose(np.stack([u, v]), theirs, atol=1e-6)


MI_SHAPE = ('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">'
            '<integer name="width" value="4"/><integer name="height" value="4"/></film>'
            '</sensor><shape type="{kind}">{inner}<bsdf type="diffuse">'
            '<texture type="checkerboard" name="reflectance"/></bsdf></shape></scene>')


def _mitsuba_uv(mi, xml, o, d):
    """Mitsuba's ray_intersect: (uv [2, N], hit [N])."""
    si = mi.load_file(str(xml)).ray_intersect(mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T)))
    return np.array(mi.Vector2f(si.uv)), np.array(si.is_valid())


def test_cube_uv_matches_mitsubas(tmp_path):
    """A textured cube under a rotation, a non-uniform scale and a translation: jgi's hit uv
    equals Mitsuba's ray_intersect uv on every face (rays from all directions)."""
    mi = load_mitsuba(vectorized=True)
    if mi is None:
        pytest.skip("mitsuba is not installed")
    xml = tmp_path / "c.xml"
    xml.write_text(MI_SHAPE.format(kind="cube", inner=(
        '<transform name="to_world"><scale x="0.5" y="0.7" z="0.9"/>'
        '<rotate x="0.6" y="0.8" z="0" angle="25"/><translate x="0.1" y="0.2" z="-0.3"/>'
        '</transform>')))
    rng = np.random.default_rng(0)
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.array([0.1, 0.2, -0.3]) - 4 * d + 0.2 * rng.normal(size=(200, 3))
    theirs, hit = _mitsuba_uv(mi, xml, o, d)
    u, v, ok = _hit(load_mitsuba_xml(xml), o, d)
    assert hit.all() and ok.all()
    np.testing.assert_allclose(np.stack([u, v]), theirs, atol=1e-5)


@pytest.mark.parametrize("names,smooth,binary", [
    (("u", "v"), False, False), (("s", "t"), True, True), (("texture_u", "texture_v"), True,
                                                            False),
    (("texture_s", "texture_t"), False, False),   # Mitsuba does not read these: no uv
    (None, False, True),
])
def test_ply_uv_matches_mitsubas(tmp_path, names, smooth, binary):
    """A textured PLY mesh imported from Mitsuba XML: jgi's hit uv equals Mitsuba's (the file's
    u, v under Mitsuba's three names, v not flipped; (0,0), (1,0), (0,1) per triangle
    without them), flat and smooth-shaded, ASCII and binary."""
    mi = load_mitsuba(vectorized=True)
    if mi is None:
        pytest.skip("mitsuba is not installed")
    ply_quad(tmp_path / "q.ply", names, binary)
    xml = tmp_path / "q.xml"
    xml.write_text(MI_SHAPE.format(kind="ply", inner=(
        '<string name="filename" value="q.ply"/>'
        f'<boolean name="face_normals" value="{str(not smooth).lower()}"/>')))
    rng = np.random.default_rng(1)
    o = np.c_[rng.uniform(-0.95, 0.95, (20, 2)), np.full(20, 2.0)]
    d = np.tile([0.0, 0.0, -1.0], (20, 1))
    theirs, hit = _mitsuba_uv(mi, xml, o, d)
    u, v, ok = _hit(load_mitsuba_xml(xml), o, d)
    assert hit.all() and ok.all()
    np.testing.assert_allclose(np.stack([u, v]), theirs, atol=1e-6)


TOML_MESH = """
[camera]
position = [0, 0, 3]
look_at = [0, 0, 0]
width = 4
height = 4
[[texture]]
name = "checks"
type = "checkerboard"
[[material]]
name = "m"
type = "diffuse"
diffuse = "checks"
[[shape]]
type = "mesh"
file = "{file}"
material = "m"
[[shape]]
type = "cube"
material = "m"
transform = {{ translate = [0, 0, -3] }}
[[light]]
type = "point"
position = [0, 2, 2]
intensity = 1
"""


@pytest.mark.parametrize("file", ["q.ply", "q.obj"])
def test_toml_meshes_and_cubes_take_mitsubas_uv(tmp_path, file):
    """A TOML scene reads a textured mesh's texture coordinates as Mitsuba does (PLY u, v as
    written, OBJ vt with v flipped) and makes a textured cube Mitsuba's cube mesh."""
    ply_quad(tmp_path / "q.ply", ("u", "v"))
    (tmp_path / "q.obj").write_text(OBJ_QUAD)
    path = tmp_path / "s.toml"
    path.write_text(TOML_MESH.format(file=file))
    tri = jgi.load_scene(str(path)).triangles
    assert tri.count == 2 + 12
    uv0 = np.asarray(tri.uv)[0, :2]
    np.testing.assert_allclose(uv0, [0.1, 0.2] if file == "q.ply" else [0.1, 0.8], atol=1e-6)
    np.testing.assert_allclose(np.asarray(tri.uv)[2:, :2].reshape(6, 2, 2)[:, 0], [[0, 1]] * 6)


def test_textured_alpha_u_and_alpha_v_lookup():
    """alpha_u and alpha_v each take their own texture's luminance, or stay constant; an
    isotropic textured alpha drives both."""
    from jgi.physics.bsdf import common as B

    b = SceneBuilder("t")
    b.texture("lo", "checkerboard", color0=0.3, color1=0.3)
    b.texture("hi", "checkerboard", color0=0.6, color1=0.6)
    b.material("u", "roughconductor", alpha_u="lo", alpha_v=0.05)
    b.material("v", "roughdielectric", alpha_u=0.07, alpha_v="hi")
    b.material("iso", "roughconductor", alpha="hi")
    b.material("both", "roughconductor", alpha_u="hi", alpha_v="lo")
    mats = b._build_materials()
    uv = (jnp.full(4, 0.3), jnp.full(4, 0.6))
    mp = B.lookup(mats, jnp.arange(4), uv)
    np.testing.assert_allclose(np.asarray(mp.alpha_u), [0.3, 0.07, 0.6, 0.6], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(mp.alpha_v), [0.05, 0.6, 0.6, 0.3], rtol=1e-6)


TEXGAPS_XML = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="8"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="50"/>
        <transform name="to_world"><lookat origin="0, 2.5, 4" target="0, 0.3, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"/>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
            <rfilter type="box"/></film>
    </sensor>
    <shape type="ply">
        <string name="filename" value="q.ply"/>
        <transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
            <rgb name="color0" value="0.8, 0.8, 0.8"/><rgb name="color1" value="0.15, 0.3, 0.6"/>
            <transform name="to_uv"><scale x="4" y="4"/></transform></texture></bsdf>
    </shape>
    <shape type="cube">
        <transform name="to_world"><scale value="0.5"/><rotate y="1" angle="30"/>
            <translate x="0.6" y="0.5" z="0.3"/></transform>
        <bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
            <rgb name="color0" value="0.9, 0.6, 0.1"/><rgb name="color1" value="0.1, 0.5, 0.2"/>
            <transform name="to_uv"><scale x="3" y="2"/></transform></texture></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale x="2" y="1"/><translate y="1" z="-1.5"/></transform>
        <bsdf type="roughconductor">
            <string name="material" value="Au"/><string name="distribution" value="ggx"/>
            <texture type="checkerboard" name="alpha_u">
                <rgb name="color0" value="0.05"/><rgb name="color1" value="0.5"/>
                <transform name="to_uv"><scale x="3" y="2"/></transform></texture>
            <float name="alpha_v" value="0.15"/>
        </bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.5"/><rotate x="1" angle="90"/>
            <translate y="3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="10"/></emitter>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="0.1"/></emitter>
</scene>
"""


def test_textured_ply_cube_and_anisotropic_roughness_render_like_mitsuba(tmp_path):
    """A textured PLY floor (the file's uv), a textured cube (Mitsuba's per-face uv) and a gold
    wall whose alpha_u is a checkerboard (alpha_v constant) under an area light: jgi's path
    tracer and Mitsuba's path integrator agree per 4 x 4 region and over the image."""
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    ply_quad(tmp_path / "q.ply", ("u", "v"))
    xml = tmp_path / "texgaps.xml"
    xml.write_text(TEXGAPS_XML)
    ours = load_mitsuba_xml(xml)
    assert ours.triangles.count == 2 + 12 and ours.materials.textured == (0, 2, 3)
    scene_mi = mi.load_file(str(xml))
    seeds = range(16)
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=64, seed=s))[..., :3] for s in seeds])
    mine = np.stack([jgi.render(ours, "pt", spp=64, seed=s, max_depth=8, rr_depth=5)
                     for s in seeds])
    t4 = assert_agree(mine, theirs, regions=4, label="PLY / cube / alpha_u: jgi vs Mitsuba 3")
    t1 = assert_agree(mine, theirs, regions=1, label="PLY / cube / alpha_u (image)")
    print(f"textured PLY, cube, alpha_u vs Mitsuba: max |t| = {t4.max():.2f} (48 region-"
          f"channels), {t1.max():.2f} (image); means {mine.mean((0, 1, 2))} vs "
          f"{theirs.mean((0, 1, 2))}")
