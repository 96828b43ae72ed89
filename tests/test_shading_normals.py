"""Shading normals (per-vertex mesh normals): the interpolated normal against its closed form,
Mitsuba's smooth normals, degenerate normals, the importers, and renders: jgi's path tracer
against Mitsuba 3 on a Cornell box holding a smooth low-poly sphere and a smooth bent metal
strip, and the light tracer, BDPT and SPPM against the path tracer on it (light paths carry
Veach's adjoint correction; without it the light tracer is measurably off,
experiments/studies/shading_normals_adjoint.py)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jgi
from jgi.core import transform as xf
from jgi.core.vec import V3
from jgi.physics import geometry as G
from jgi.scene.builder import SceneBuilder, SceneError, smooth_vertex_normals
from jgi.scene.importers.mitsuba import load_mitsuba_xml
from tests.support.mitsuba import load_mitsuba
from tests.support.smooth_cornell import DEPTH, bent_strip, smooth_cornell_xml, uv_sphere, write_obj
from tests.support.stats import assert_agree

SPP = 256       # per render of the path tracer, Mitsuba and the light tracer
# (estimator, parameters, spp) of the renders
CASES = [
    ("pt", dict(max_depth=DEPTH), SPP),
    ("lt", dict(max_depth=DEPTH), SPP),
    # (BDPT's connections are VCM's code, connect_vertices; left out for the suite's time)
    # photons hit max_bounces surfaces: paths of max_bounces + 1 segments, the path tracer's DEPTH
    ("sppm", dict(max_bounces=DEPTH - 1, photons=20_000, passes=8, radius=0.05), 4),
    ("vcm", dict(max_depth=DEPTH, radius=0.03), 16),
]


def _v3(a):
    a = np.asarray(a, np.float32).reshape(-1, 3)
    return V3(*(jnp.asarray(a[:, k]) for k in range(3)))


@pytest.fixture(scope="module")
def smooth_scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("smooth")
    xml = smooth_cornell_xml(folder)
    return xml, load_mitsuba_xml(xml)


# --- the shading normal at a hit -------------------------------------------------------------

@pytest.mark.parametrize("bvh", [False, True])
def test_shading_normal_is_the_normalised_barycentric_interpolation(rng_np, bvh):
    """A triangle carrying a sphere's normals at its corners: ns at a hit is
    normalize(b0 n0 + b1 n1 + b2 n2), the geometric normal unchanged."""
    b = SceneBuilder("t")
    b.material("m", "diffuse", diffuse=0.5)
    b.camera((0, 0, 5), (0, 0, 0), width=4, height=4)
    b.bvh = bvh
    verts = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    centre = np.array([0.3, 0.3, -1.0])            # the corners' normals: a sphere's about it
    normals = (verts - centre) / np.linalg.norm(verts - centre, axis=1, keepdims=True)
    b.mesh(verts, [[0, 1, 2]], "m", normals=normals)
    b.mesh(verts + [0, 0, -3], [[0, 1, 2]], "m")   # flat: ns = n
    scene = b.build()
    assert scene.has_shading_normals and (scene.triangles.bvh is not None) == bvh
    b1, b2 = rng_np.uniform(0.02, 0.48, (2, 40))
    p = b1[:, None] * verts[1] + b2[:, None] * verts[2]
    hit = G.intersect(scene, _v3(p + [0, 0, 1]), _v3(np.tile([0.0, 0, -1], (40, 1))))
    assert np.asarray(hit.valid).all()
    expect = ((1 - b1 - b2)[:, None] * normals[0] + b1[:, None] * normals[1]
              + b2[:, None] * normals[2])
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(np.stack([np.asarray(c) for c in hit.ns], 1), expect, atol=2e-6)
    np.testing.assert_allclose(np.stack([np.asarray(c) for c in hit.n], 1),
                               np.tile([0.0, 0, 1], (40, 1)), atol=1e-7)
    flat = G.intersect(scene, _v3(p + [0, 0, -2]), _v3(np.tile([0.0, 0, -1], (40, 1))))
    np.testing.assert_allclose(np.stack([np.asarray(c) for c in flat.ns]),
                               np.stack([np.asarray(c) for c in flat.n]), atol=1e-6)


def test_smooth_normals_are_mitsubas(tmp_path):
    """jgi's smooth normals equal Mitsuba 3's recompute_vertex_normals (angle-weighted); the
    closed form: Mitsuba's own test (two triangles meeting at a right angle and at
    acos(3/5))."""
    a, b_ = 1.0, 0.5
    v = np.array([[0, 0, 0], [-a, 1, 0], [a, 1, 0], [-b_, 0, 1], [b_, 0, 1]], float)
    n = smooth_vertex_normals(v, [[0, 1, 2], [0, 3, 4]])
    n2 = np.array([0, 0, -1.0]) * np.pi / 2 + np.array([0, 1.0, 0]) * np.arccos(3 / 5)
    np.testing.assert_allclose(n[0], n2 / np.linalg.norm(n2), atol=1e-12)
    np.testing.assert_allclose(n[1:], [[0, 0, -1], [0, 0, -1], [0, 1, 0], [0, 1, 0]], atol=1e-12)
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    sv, sf = uv_sphere(7, 4)
    sv = sv * [1.0, 0.6, 1.3]   # non-uniform: the angle weights matter
    write_obj(tmp_path / "s.obj", sv, sf)
    shape = mi.load_dict({"type": "obj", "filename": str(tmp_path / "s.obj")})
    theirs = np.array(mi.traverse(shape)["vertex_normals"]).reshape(-1, 3)
    np.testing.assert_allclose(smooth_vertex_normals(sv, sf), theirs, atol=2e-6)


def test_degenerate_normals_give_finite_renders(smooth_scene):
    """The smooth Cornell box with degenerate vertex normals on every triangle of the sphere:
    opposed corners (their interpolation vanishes inside the triangle: the hit falls back to
    the geometric normal), a zero normal, and one almost in the triangle's plane. The path
    tracer's and the light tracer's images stay finite (the hit's fallback is shared by every
    estimator; the other estimators are rendered on the regular scene only, to keep compiles
    down)."""
    scene = smooth_scene[1]
    normals = np.asarray(scene.triangles.normals).reshape(-1, 3, 3).copy()
    sphere = np.asarray(scene.triangles.material) == np.asarray(scene.triangles.material)[0]
    tri = np.stack([np.asarray(c) for c in scene.triangles.normal], 1)
    tangent = np.cross(tri, [0.3, 0.9, 0.1])
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normals[sphere, 0] = tri[sphere]
    normals[sphere, 1] = -tri[sphere]
    normals[sphere, 2] = 0.0
    grazing = np.nonzero(sphere)[0][::2]
    normals[grazing, 2] = tangent[grazing] + 1e-4 * tri[grazing]
    bad = eqx.tree_at(lambda s: s.triangles.normals, scene,
                      jnp.asarray(normals.reshape(-1, 9), jnp.float32))
    gx, gz = np.meshgrid(np.linspace(-0.6, -0.1, 8), np.linspace(-0.25, 0.25, 8))
    o = np.stack([gx.ravel(), np.full(64, 0.5), gz.ravel()], 1)
    hit = G.intersect(bad, _v3(o), _v3(np.tile([0.0, -1.0, 0.0], (64, 1))))
    on_sphere = np.asarray(hit.valid) & (np.asarray(hit.p.y) > -1.0 + 1e-3)
    assert on_sphere.sum() > 20 and np.isfinite(np.asarray(hit.ns.stack())).all()
    ns_len = np.linalg.norm(np.asarray(hit.ns.stack()), axis=-1)
    np.testing.assert_allclose(ns_len[on_sphere], 1.0, atol=1e-5)
    for est, kw, spp in CASES[:2]:   # a camera and a light path (its adjoint correction)
        img = np.asarray(jgi.render(bad, est, spp=spp, seed=0, **kw))
        assert np.isfinite(img).all(), est


# --- importers ---------------------------------------------------------------------------------

MINI_XML = """<scene version="3.0.0">
    <sensor type="perspective"><film type="hdrfilm">
        <integer name="width" value="4"/><integer name="height" value="4"/></film></sensor>
    <shape type="{kind}"><string name="filename" value="{file}"/>{extra}</shape>
</scene>"""


@pytest.mark.parametrize("kind,with_normals", [("obj", False), ("obj", True), ("ply", False),
                                               ("ply", True)])
def test_mitsuba_meshes_without_face_normals_shade_like_mitsuba(tmp_path, kind, with_normals):
    """OBJ and PLY without face_normals: jgi's shading normal at hits equals Mitsuba's
    ray_intersect sh_frame.n (the file's normals, or Mitsuba's computed ones), under a
    non-uniform to_world."""
    mi = load_mitsuba(vectorized=True)
    if mi is None:
        pytest.skip("mitsuba is not installed")
    import trimesh

    v, f, nrm = bent_strip(3)
    nrm = nrm + [0.0, 0.3, 0.0]     # not unit, not the cylinder's: the loader normalises
    if kind == "obj":
        write_obj(tmp_path / "m.obj", v, f, nrm if with_normals else None)
    else:
        mesh = trimesh.Trimesh(v, f, vertex_normals=nrm if with_normals else None, process=False)
        (tmp_path / "m.ply").write_bytes(trimesh.exchange.ply.export_ply(
            mesh, encoding="ascii", vertex_normal=with_normals))
    extra = ('<transform name="to_world"><scale x="1.5" y="0.7" z="1"/>'
             '<rotate y="1" angle="30"/></transform>')
    xml = tmp_path / "m.xml"
    xml.write_text(MINI_XML.format(kind=kind, file=f"m.{kind}", extra=extra))
    rng = np.random.default_rng(1)
    a = rng.uniform(0.05, 0.5 * np.pi - 0.05, 30)
    y = rng.uniform(-0.6, 0.6, 30)
    to_world = xf.rotate([0, 1, 0], 30) @ xf.scale([1.5, 0.7, 1.0])
    target = xf.apply_point(to_world, np.stack([np.cos(a), y, np.sin(a)], 1))
    o = target * [3.0, 1.0, 3.0] + [0.0, 0.0, 0.0]
    o[:, 1] = target[:, 1]
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ray = mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T))
    si = mi.load_file(str(xml)).ray_intersect(ray)
    theirs = np.array(si.sh_frame.n)
    hit = G.intersect(load_mitsuba_xml(xml), _v3(o), _v3(d))
    assert np.asarray(hit.valid).all() and np.array(si.is_valid()).all()
    np.testing.assert_allclose(np.stack([np.asarray(c) for c in hit.ns]), theirs, atol=2e-5)
    np.testing.assert_allclose(np.stack([np.asarray(c) for c in hit.n]), np.array(si.n),
                               atol=2e-5)


PBRT_SMOOTH = """LookAt 0 3 3  0 0 0  0 1 0
Camera "perspective" "float fov" 45
Film "rgb" "integer xresolution" 4 "integer yresolution" 4
WorldBegin
LightSource "point" "rgb I" [5 5 5] "point3 from" [0 2 0]
Material "diffuse"
Shape "trianglemesh" "point3 P" [-1 0 -1  1 0 -1  1 0 1  -1 0 1] "integer indices" [0 1 2 0 2 3]
    "normal N" [-0.5 1 0  0.5 1 0  0.5 1 0  -0.5 1 0]
"""


def test_pbrt_trianglemesh_normals(tmp_path):
    path = tmp_path / "s.pbrt"
    path.write_text(PBRT_SMOOTH)
    scene = jgi.load_scene(str(path))
    assert scene.has_shading_normals
    x = np.array([-0.5, 0.0, 0.5])
    hit = G.intersect(scene, _v3(np.stack([x, [1.0] * 3, [0.3] * 3], 1)),
                      _v3(np.tile([0.0, -1.0, 0.0], (3, 1))))
    expect = np.stack([x / 2, np.ones(3), np.zeros(3)], 1)   # N is linear in x
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(np.stack([np.asarray(c) for c in hit.ns], 1), expect, atol=1e-5)
    path.write_text(PBRT_SMOOTH.replace('"normal N" [', '"normal N" [0 1 0 '))
    with pytest.raises(SceneError, match="N"):
        jgi.load_scene(str(path))


TOML_MESH = """
name = "smooth"
[camera]
position = [0, 1, 3]
look_at = [0, 0, 0]
width = 4
height = 4
[[material]]
name = "m"
type = "diffuse"
diffuse = 0.5
[[shape]]
type = "mesh"
file = "m.obj"
material = "m"
{extra}
[[light]]
type = "point"
position = [0, 2, 0]
intensity = 5
"""


@pytest.mark.parametrize("extra,smooth", [("", True), ("flat = true", False)])
def test_toml_meshes_keep_their_normals(tmp_path, extra, smooth):
    v, f, nrm = bent_strip(2)
    write_obj(tmp_path / "m.obj", v, f, nrm)
    (tmp_path / "s.toml").write_text(TOML_MESH.format(extra=extra))
    scene = jgi.load_scene(str(tmp_path / "s.toml"))
    assert scene.has_shading_normals == smooth
    if smooth:
        got = np.asarray(scene.triangles.normals).reshape(-1, 3, 3)
        np.testing.assert_allclose(got, nrm[f], atol=1e-6)


# --- renders -----------------------------------------------------------------------------------

def _stack(scene, estimator, seeds, **kw):
    return np.stack([np.asarray(jgi.render(scene, estimator, seed=s, **kw)) for s in seeds])


@pytest.fixture(scope="module")
def pt_reference(smooth_scene):
    return _stack(smooth_scene[1], "pt", range(100, 112), spp=SPP, max_depth=DEPTH)


def test_smooth_cornell_box_renders_like_mitsuba(smooth_scene, pt_reference):
    """jgi's path tracer against Mitsuba's path integrator on the same XML (12 renders each,
    256 spp, 16^2 pixels, max_depth 3), per 4 x 4 region and over the image. Measured with 16
    renders each: max |t| 2.4 (critical 5.9) and 2.2 over the image; jgi shading the same
    meshes flat gives 39 over the regions (experiments/studies/shading_normals_adjoint.py)."""
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    xml, _ = smooth_scene
    scene_mi = mi.load_file(str(xml))
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=SPP, seed=s))[..., :3]
                       for s in range(12)])
    t4 = assert_agree(pt_reference, theirs, regions=4, label="smooth normals: jgi vs Mitsuba 3")
    t1 = assert_agree(pt_reference, theirs, regions=1, label="smooth normals: jgi vs Mitsuba 3")
    print(f"smooth Cornell box vs Mitsuba: max |t| = {t4.max():.2f} (48 region-channels), "
          f"{t1.max():.2f} (image)")


@pytest.mark.parametrize("estimator,params,spp", CASES[1:])
def test_estimators_agree_with_the_path_tracer(smooth_scene, pt_reference, estimator, params,
                                               spp):
    """Light paths (LT, BDPT's light subpaths and connections, SPPM's photons, VCM's light
    subpaths, connections and merges) carry Veach's
    adjoint correction. Measured for the light tracer (16 x 256 spp): max |t| 2.8 (critical
    6.2) with it, 15.0 without it (experiments/studies/shading_normals_adjoint.py). SPPM is
    consistent, not unbiased: its radius is small enough here that the bias is below the
    test's resolution (whole image only)."""
    seeds = {"lt": range(12), "bdpt": range(8), "sppm": range(6), "vcm": range(8)}[estimator]
    imgs = _stack(smooth_scene[1], estimator, seeds, spp=spp, **params)
    regions = 1 if estimator == "sppm" else 4
    t = assert_agree(imgs, pt_reference, regions=regions, label=f"{estimator} vs pt, smooth")
    print(f"{estimator} vs pt (smooth normals): max |t| = {t.max():.2f}")
