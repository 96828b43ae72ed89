"""One-sided materials (Mitsuba 3's reflective BSDFs without ``twosided``): black, with pdf 0
and no sample, where wo or wi is on the back side of the normal; unchanged on the front. In the
BSDF functions (so in every estimator), in the visible points of the photon estimators, the
builder, TOML and the Mitsuba importer."""

from __future__ import annotations

import numpy as np
import pytest

import jgi
from jgi.core.vec import V3
from jgi.physics import bsdf
from jgi.scene import SceneBuilder, SceneError
from jgi.scene.importers import load_mitsuba_xml
from tests.support.mitsuba import load_mitsuba
from tests.support.stats import assert_agree

REFLECTIVE = [  # (jgi type, keywords): every type that may be one-sided
    ("diffuse", dict(diffuse=0.6)),
    ("phong", dict(diffuse=0.3, specular=0.4, exponent=10.0)),
    ("mirror", dict(specular=0.9)),
    ("conductor", dict(metal="Au")),
    ("roughconductor", dict(metal="Cu", alpha=0.3)),
    ("plastic", dict(diffuse=0.5)),
    ("roughplastic", dict(diffuse=0.5, alpha=0.3)),
]


def _materials(one_sided: bool):
    b = SceneBuilder("materials")
    for kind, kw in REFLECTIVE:
        b.material(kind, kind, one_sided=one_sided, **kw)
    b.quad((0, 0, 0), (1, 0, 0), (0, 1, 0), "diffuse")
    b.camera((0, 0, 2), (0, 0, 0), width=2, height=2)
    return b.build().materials


def _units(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _v3(a):
    return V3(*(np.asarray(c, np.float32) for c in a.T))


def _np(v):
    return np.stack([np.asarray(c) for c in v], -1)


def test_back_side_is_black_front_side_unchanged():
    """For random normals and directions on both sides: a one-sided row's f and pdf equal the
    two-sided row's where wo and wi are on the normal's side and are 0 elsewhere; its samples
    are the two-sided ones where wo is in front (and so is the sample), invalid elsewhere."""
    one, two = _materials(True), _materials(False)
    assert one.has_one_sided and not two.has_one_sided
    rng = np.random.default_rng(3)
    N = 4000
    n, wo, wi = (_units(rng, N) for _ in range(3))
    u = rng.random((3, N)).astype(np.float32)
    front_o, front_i = np.sum(wo * n, 1) > 0, np.sum(wi * n, 1) > 0
    for row, (kind, _) in enumerate(REFLECTIVE):
        m = np.full(N, row, np.int32)
        mp1, mp2 = bsdf.lookup(one, m), bsdf.lookup(two, m)
        f1, p1 = bsdf.evaluate(one.kinds, mp1, _v3(n), _v3(wo), _v3(wi))
        f2, p2 = bsdf.evaluate(two.kinds, mp2, _v3(n), _v3(wo), _v3(wi))
        f1, f2, p1, p2 = _np(f1), _np(f2), np.asarray(p1), np.asarray(p2)
        front = front_o & front_i
        np.testing.assert_array_equal(f1[front], f2[front], err_msg=kind)
        np.testing.assert_array_equal(p1[front], p2[front], err_msg=kind)
        assert np.all(f1[~front] == 0) and np.all(p1[~front] == 0), kind
        if kind not in ("mirror", "conductor"):   # a two-sided one does reflect at the back
            assert np.any(f2[~front_o & ~front_i] > 0), kind
        s1 = bsdf.sample(one.kinds, mp1, _v3(n), _v3(wo), *u)
        s2 = bsdf.sample(two.kinds, mp2, _v3(n), _v3(wo), *u)
        v1, v2 = np.asarray(s1.valid), np.asarray(s2.valid)
        wi2 = _np(s2.wi)
        expect = v2 & front_o & (np.sum(wi2 * n, 1) > 0)
        np.testing.assert_array_equal(v1, expect, err_msg=kind)
        assert v1.sum() > N // 4, kind
        for a, b in ((s1.wi, s2.wi), (s1.weight, s2.weight)):
            np.testing.assert_array_equal(_np(a)[v1], _np(b)[v1], err_msg=kind)
        np.testing.assert_array_equal(np.asarray(s1.pdf)[v1], np.asarray(s2.pdf)[v1])
        assert np.all(_np(s1.weight)[~v1] == 0) and np.all(np.asarray(s1.pdf)[~v1] == 0)


def test_diffuse_evaluates_as_mitsubas_on_both_sides():
    """jgi's f |cos theta_i| and pdf equal Mitsuba 3's eval and pdf for ``diffuse`` (one-sided)
    and ``twosided`` diffuse, with wo and wi on either side of the shading frame."""
    mi = load_mitsuba(vectorized=True)
    if mi is None:
        pytest.skip("mitsuba is not installed")
    rng = np.random.default_rng(5)
    N = 2000
    wo, wi = _units(rng, N), _units(rng, N)
    n = np.tile([0.0, 0.0, 1.0], (N, 1))
    refl = {"type": "rgb", "value": [0.6, 0.6, 0.6]}
    for one_sided, spec in ((True, {"type": "diffuse", "reflectance": refl}),
                            (False, {"type": "twosided",
                                     "b": {"type": "diffuse", "reflectance": refl}})):
        b = mi.load_dict(spec)
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*wo.T)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        theirs = np.array(b.eval(mi.BSDFContext(), si, mi.Vector3f(*wi.T))).T
        their_pdf = np.array(b.pdf(mi.BSDFContext(), si, mi.Vector3f(*wi.T)))
        mats = _materials(one_sided)
        mp = bsdf.lookup(mats, np.zeros(N, np.int32))
        f, pdf = bsdf.evaluate(mats.kinds, mp, _v3(n), _v3(wo), _v3(wi))
        mine = _np(f) * np.abs(wi[:, 2:3])
        np.testing.assert_allclose(mine, theirs, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(np.asarray(pdf), their_pdf, rtol=1e-5, atol=1e-7)
        assert (np.count_nonzero(theirs[:, 0]) < N // 2) == one_sided   # both sides lit: 1/2


def test_builder_and_toml(tmp_path):
    b = SceneBuilder("bad")
    for kind in ("dielectric", "roughdielectric"):
        with pytest.raises(SceneError, match=f"'{kind}' .*\\({kind}\\): cannot be one-sided"):
            b.material(kind, kind, one_sided=True)
    with pytest.raises(SceneError, match="'one_sided' must be true or false"):
        b.material("x", "diffuse", one_sided="yes")
    head = ('[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nwidth = 4\nheight = 4\n'
            '[[shape]]\ntype = "sphere"\ncenter = [0, 0, 0]\nradius = 1\nmaterial = "m"\n')
    (tmp_path / "a.toml").write_text(head + '[[material]]\nname = "m"\ntype = "diffuse"\n'
                                            'one_sided = true\n')
    assert bool(jgi.load_scene(tmp_path / "a.toml").materials.one_sided[0])
    (tmp_path / "b.toml").write_text(head + '[[material]]\nname = "m"\ntype = "diffuse"\n')
    assert not jgi.load_scene(tmp_path / "b.toml").materials.has_one_sided
    (tmp_path / "c.toml").write_text(head + '[[material]]\nname = "m"\ntype = "dielectric"\n'
                                            'one_sided = true\n')
    with pytest.raises(SceneError, match="one_sided"):
        jgi.load_scene(tmp_path / "c.toml")


# --- renders ------------------------------------------------------------------------------------

def _planes_scene(size=16):
    """Two quads in z = 0, normals -z (away from the camera at +z), lit by an area light on
    the camera's side over a two-sided floor: the left one one-sided (seen from its back:
    black, and it reflects nothing onto the floor), the right one two-sided."""
    b = SceneBuilder("planes")
    b.material("one", "diffuse", diffuse=0.7, one_sided=True)
    b.material("two", "diffuse", diffuse=0.7)
    b.material("floor", "diffuse", diffuse=0.5)
    b.material("black", "diffuse", diffuse=0.0)
    b.quad((-0.05, -1, 0), (-1.2, 0, 0), (0, 2, 0), "one")       # normal (-x) x (y) = -z
    b.quad((0.05, -1, 0), (0, 2, 0), (1.2, 0, 0), "two")         # normal (y) x (x) = -z
    b.quad((-3, -1, 3), (6, 0, 0), (0, 0, -6), "floor")         # y = -1, normal +y
    b.quad((-0.4, 1.6, 1.6), (0.8, 0, 0), (0, 0, 0.8), "black", emission=(8.0, 8.0, 8.0))
    b.camera((0, 0.2, 4.5), (0, 0, 0), fov=45.0, width=size, height=size)
    return b.build()


def test_back_seen_one_sided_plane_is_black_and_estimators_agree():
    """PT, VCM and SPPM agree per region (Welch's t, both sides' standard errors from 4
    seeds); where only the back-seen one-sided plane is visible every estimator gives 0, and
    the two-sided plane beside it is lit. (VCM's strategies include light tracing's splats and
    BDPT's connections on the code those estimators share; they are left out for the suite's
    time.)"""
    scene = _planes_scene()
    seeds = range(4)
    runs = {
        "pt": dict(spp=64),
        "vcm": dict(spp=8),
        "sppm": dict(spp=4, photons=20_000, radius=0.08),
    }
    imgs = {e: np.stack([jgi.render(scene, e, seed=10 * k + s, **kw) for s in seeds])
            for k, (e, kw) in enumerate(runs.items())}
    # pixels whose camera ray meets the one-sided plane first: columns 3..6, rows 4..10
    # (camera at x = 0, the plane spans x in [-1.25, -0.05], y in [-1, 1])
    back = (slice(None), slice(4, 11), slice(3, 7))
    lit = (slice(None), slice(4, 11), slice(9, 13))
    for e, img in imgs.items():
        assert float(img[back].max()) == 0.0, e
        assert float(img[lit].mean()) > 0.03, (e, float(img[lit].mean()))
    ts = []
    for e in ("vcm", "sppm"):
        ts.append(assert_agree(imgs[e], imgs["pt"], regions=4, label=f"{e} vs pt").max())
    print("max |t| vs pt (vcm, sppm):", np.round(ts, 2))


@pytest.mark.slow
@pytest.mark.parametrize("estimator, kw", [
    ("pm", dict(photons=20_000, radius=0.08)), ("ppm", dict(photons=20_000, radius=0.08)),
    ("pm_jensen", dict(photons=20_000, radius=0.08)), ("irradiance_cache", {}),
    ("whitted", {}), ("mlt", {}), ("pssmlt", {})])
def test_other_estimators_leave_the_back_seen_plane_black(estimator, kw):
    """The estimators that end camera paths at visible points (their lookups read k_d
    directly) or mutate paths see the one-sided plane's back as black too, and the two-sided
    plane lit (measured means there 0.071-0.088 at 4 spp, PT's 0.083)."""
    img = jgi.render(_planes_scene(), estimator, spp=4, seed=0, **kw)
    assert float(img[4:11, 3:7].max()) == 0.0
    assert float(img[4:11, 9:13].mean()) > 0.03


PLANES_XML = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="8"/></integrator>
  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0,0.2,4.5" target="0,0,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
      <rfilter type="box"/></film></sensor>
  <bsdf type="diffuse" id="one"><rgb name="reflectance" value="0.7,0.6,0.5"/></bsdf>
  <bsdf type="twosided" id="two"><ref id="one"/></bsdf>
  <shape type="rectangle"><transform name="to_world"><scale x="0.6"/><rotate y="1" angle="180"/>
    <translate x="-0.65"/></transform><ref id="one"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale x="0.6"/><rotate y="1" angle="180"/>
    <translate x="0.65"/></transform><ref id="two"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/>
    <translate y="-1"/></transform><ref id="one"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.4"/><rotate x="1" angle="90"/>
    <translate y="1.6" z="1.6"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0,0,0"/></bsdf>
    <emitter type="area"><rgb name="radiance" value="8,8,8"/></emitter></shape>
</scene>
"""


def test_one_sided_and_twosided_planes_render_like_mitsuba(tmp_path):
    """Mitsuba's ``diffuse`` seen from its back (left plane) and wrapped in ``twosided``
    (right plane) over a one-sided floor seen from its front: jgi's path tracer agrees with
    Mitsuba 3's path integrator per 4 x 4 pixel region and over the image (Welch's t, both
    sides' standard errors from 16 seeds); the left plane is black in both. Before one-sided
    materials the left plane's region differed by |t| in the hundreds."""
    xml = tmp_path / "planes.xml"
    xml.write_text(PLANES_XML)
    ours = load_mitsuba_xml(xml)
    # rows: "one", the twosided copy of it, the emitter's black diffuse (one-sided)
    np.testing.assert_array_equal(np.asarray(ours.materials.one_sided), [True, False, True])
    mi = load_mitsuba(vectorized=True)
    if mi is None:
        pytest.skip("mitsuba is not installed")
    scene_mi = mi.load_file(str(xml))
    seeds = range(16)
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=64, seed=s))[..., :3] for s in seeds])
    mine = np.stack([jgi.render(ours, "pt", spp=64, seed=100 + s, max_depth=8, rr_depth=5)
                     for s in seeds])
    back = (slice(None), slice(4, 11), slice(3, 7))
    assert float(theirs[back].max()) == 0.0 and float(mine[back].max()) == 0.0
    t4 = assert_agree(mine, theirs, regions=4, label="jgi vs Mitsuba 3 (4 x 4 regions)")
    t1 = assert_agree(mine, theirs, regions=1, label="jgi vs Mitsuba 3 (whole image)")
    print(f"max |t| {t4.max():.2f} (regions), {t1.max():.2f} (image); means "
          f"{mine.mean():.5f} vs {theirs.mean():.5f}")


def test_flip_normals(tmp_path):
    """A rectangle's flip_normals negates its normal (the side one-sided BSDFs and emitters
    use); on a cube or sphere it is refused, naming the file and line."""
    head = ('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">'
            '<integer name="width" value="4"/><integer name="height" value="4"/></film>'
            '</sensor><bsdf type="diffuse" id="d"/>')
    (tmp_path / "r.xml").write_text(
        head + '<shape type="rectangle"><boolean name="flip_normals" value="true"/>'
        '<ref id="d"/></shape></scene>')
    s = load_mitsuba_xml(tmp_path / "r.xml")
    normals = [np.asarray(c).ravel() for c in (s.rects.normal if s.rects.count else s.quads.normal)]
    np.testing.assert_allclose(np.concatenate(normals), [0, 0, -1], atol=1e-7)
    for shape in ("sphere", "cube"):
        (tmp_path / "s.xml").write_text(
            head + f'<shape type="{shape}"><boolean name="flip_normals" value="true"/>'
            '</shape></scene>')
        with pytest.raises(SceneError, match=rf"s\.xml:1: .*{shape}: flip_normals is not"):
            load_mitsuba_xml(tmp_path / "s.xml")
