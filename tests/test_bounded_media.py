"""Media bounded by shapes (issue 34): a medium interface on a material, rays that carry the id
of the medium they travel in, in every estimator that renders media.

Closed form: a glass slab holding an absorbing ink, and in the ink a layer of dye behind
index-matched films (three media nested), seen along its normal against an emitter behind it,
in a room of absorbing air: T_air (1 - R)^2 T / (1 - R^2 T^2) with R the Fresnel reflectance at
normal incidence and T the transmittance across the slab's ink and dye (every internal
reflection summed). Agreement: every estimator that renders media against the path tracer per
image region on a backlit rough glass ball of milk in haze, with the power check
(a 30% denser milk must fail the same test). Tolerances: 4 measured standard errors, or
Welch's test with both sides' seed spreads.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import jgi
from jgi.analysis.stats import region_agreement
from jgi.core.errors import ParameterError
from jgi.scene.builder import SceneBuilder, SceneError
from jgi.scene.importers import load_mitsuba_xml
from jgi.scene.importers._common import ImportError_
from jgi.scene.importers.volgrid import write_vol
from tests.support.media import MITSUBA_FOG_ROOM
from tests.support.scenes import leaves_equal
from tests.support.stats import mean_change, tells_apart

INK, DYE, AIR, IOR = 1.0, 2.0, 0.05, 1.5
DYE_FROM, DYE_TO = 0.25, 0.5      # the dye layer inside the ink


def assert_pt_agrees_with_mitsuba(ours, xml, *, seeds: int, spp: int, others=None, **params):
    """jgi's path tracer on ``ours`` against Mitsuba 3 rendering the XML file ``xml`` (its
    integrator as the file says), ``seeds`` renders of ``spp`` a side, per 3 x 3 region and
    over the image (Welch, both sides' seed spreads); ``others``: more jgi estimators against
    the same renders, name -> render parameters. Skipped without Mitsuba."""
    from tests.support.mitsuba import load_mitsuba
    from tests.support.stats import assert_agree

    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    scene_mi = mi.load_file(str(xml))
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=spp, seed=s))[..., :3]
                       for s in range(seeds)])
    for name, kw in {"pt": dict(spp=spp, **params), **(others or {})}.items():
        mine = np.stack([jgi.render(ours, name, seed=100 + s, **kw) for s in range(seeds)])
        assert np.all(np.isfinite(mine))
        assert_agree(mine, theirs, regions=3,
                     label=f"jgi {name} vs Mitsuba 3 volpath (3 x 3 regions)")
        assert_agree(mine, theirs, regions=1,
                     label=f"jgi {name} vs Mitsuba 3 volpath (whole image)")


def _slab(ink: float = INK, air: float = AIR):
    """A glass slab z in [0, 1] holding ink (absorbing), its faces' normals outwards, and in
    the ink a layer z in [0.25, 0.5] of dye (absorbing more) behind index-matched films (ior
    1.0001: Fresnel reflectance 2.5e-9), so three media nest: air, ink, dye. An emitter of
    radiance 1 at z = 2 faces the slab; the camera at z = -5 looks along +z through a 1
    degree field of view; all in absorbing air (everything else black)."""
    b = SceneBuilder("ink_slab")
    b.material("glass", "dielectric", ior=IOR)
    b.material("film", "dielectric", ior=1.0001)
    b.material("black", "diffuse", diffuse=(0, 0, 0))
    b.bounded_medium("ink", sigma_t=ink, albedo=0.0)
    b.bounded_medium("dye", sigma_t=DYE, albedo=0.0)
    if air > 0:
        b.medium(sigma_t=air, albedo=0.0)
    glass = b.medium_interface("glass", interior="ink")
    film = b.medium_interface("film", interior="dye", exterior="ink")
    c, w = np.array, 50.0
    b.quad(c([-w, -w, 0.0]), c([0, 2 * w, 0]), c([2 * w, 0, 0]), glass)    # normal -z
    b.quad(c([-w, -w, 1.0]), c([2 * w, 0, 0]), c([0, 2 * w, 0]), glass)    # normal +z
    b.quad(c([-w, -w, DYE_FROM]), c([0, 2 * w, 0]), c([2 * w, 0, 0]), film)
    b.quad(c([-w, -w, DYE_TO]), c([2 * w, 0, 0]), c([0, 2 * w, 0]), film)
    b.quad(c([-w, -w, 2.0]), c([0, 2 * w, 0]), c([2 * w, 0, 0]), "black", (1.0, 1.0, 1.0))
    b.camera((0, 0, -5.0), (0, 0, 0), fov=1.0, width=4, height=4)
    return b.build()


def _slab_exact(ink: float = INK, air: float = AIR) -> float:
    r = ((IOR - 1) / (IOR + 1)) ** 2
    dye = DYE_TO - DYE_FROM
    t = np.exp(-ink * (1 - dye) - DYE * dye)   # across the slab: ink, then dye, then ink
    # air: 5 units to the slab, 1 from it to the emitter (rays within 0.5 degrees of the axis:
    # path lengths and Fresnel within 1e-4 of the axis')
    return float(np.exp(-6 * air) * (1 - r) ** 2 * t / (1 - r * r * t * t))


@pytest.mark.parametrize("name", ["pt", "bdpt"])
def test_ink_slab_transmits_its_closed_form(name):
    """The camera sees the emitter through the slab: every path crosses air, glass, ink, film,
    dye, film, ink, glass, air (bouncing inside between the glass faces). Measured: pt
    0.1944 +- 0.0023, bdpt 0.1948 +- 0.0027 against 0.1956; the ink left out would give 0.41,
    the dye left out 0.32, the air left out 0.26."""
    scene = _slab()
    # BDPT to 8 segments: it compiles in 12 s against 40 s at 16, and the paths it leaves out
    # (two round trips between the glass faces and more) carry (R^2 T^2)^2 ~ 1e-8 of the value
    spp, depth = (256, 16) if name == "pt" else (64, 8)
    means = np.stack([jgi.render(scene, name, spp=spp, seed=s, max_depth=depth).reshape(-1, 3)
                      .mean(0) for s in range(6)])
    assert np.all(np.isfinite(means))
    mean, err = means.mean(0), means.std(0, ddof=1) / np.sqrt(len(means))
    print(f"{name}: {mean} +- {err} against {_slab_exact():.4f}")
    np.testing.assert_array_less(np.abs(mean - _slab_exact()), 4 * err)


MILK_RES, MILK_SEEDS, MILK_DEPTH = 16, 16, 6


def _milk(sigma_scale: float = 1.0):
    """milk_ball in haze."""
    return jgi.load_scene("milk_ball", resolution=MILK_RES, haze=0.1,
                          sigma_t=tuple(sigma_scale * s for s in (2.0, 3.0, 5.0)))


@functools.lru_cache(maxsize=None)
def milk_reference() -> np.ndarray:
    scene = _milk()
    return np.stack([jgi.render(scene, "pt", spp=64, seed=1000 + k, max_depth=MILK_DEPTH)
                     for k in range(MILK_SEEDS)])


@functools.lru_cache(maxsize=None)
def denser_milk_change() -> np.ndarray:
    def render(scale, seed):
        return jgi.render(_milk(scale), "pt", spp=64, seed=seed, max_depth=MILK_DEPTH)
    return mean_change(render, 1.0, 1.3, range(MILK_SEEDS))


# sppm and ppm are left out for the suite's time: they run pm's photon tracing, visible points
# and volume estimate (jgi.transport.photons, visible_points, density), which pm checks here;
# lt and mmlt too (measured, see the test): light tracing's subpaths and camera connections are
# BDPT's t = 1 strategies (jgi.transport.subpath, connection), and MMLT evaluates BDPT's
# strategies lane for lane (tests/test_mmlt.py, in fog and in a grid)
MILK_ESTIMATORS = {
    "bdpt": dict(spp=16, max_depth=MILK_DEPTH),
    "vcm": dict(spp=8, max_depth=MILK_DEPTH),
    "pm": dict(spp=8, max_bounces=MILK_DEPTH - 1, photons=200_000, radius=0.1),
}


# The ball holding a density grid (milk_ball(smoke=True)) ran BDPT here too (worst |t| 2.0,
# with the denser milk 15.0, critical 6.5; measured, not run: vcm 2.4 / 8.4, pm 1.8 / 9.2, lt
# 1.8 / 10.1, mmlt 1.7 / 12.9). Bounded grids are now checked against Mitsuba 3 instead, two of
# them at once, with pt and BDPT (test_two_smokes_in_glass_render_like_mitsuba_volpath: the
# same tracking, ratio tracking and distance-density proxies, one grid's lanes at a time).
@pytest.mark.parametrize("name", list(MILK_ESTIMATORS))
def test_estimators_render_a_bounded_medium_like_the_path_tracer(name):
    """Per 3 x 3 region and channel against the path tracer (Welch, both sides' seed spreads),
    and the power check: the estimator's own stack offset by what a 30% denser milk changes
    must fail the same test. Measured worst |t| / offset by the denser milk / critical:
    bdpt 1.8 / 10.6 / 6.5, vcm 2.0 / 8.2 / 6.7, pm 1.5 / 8.9 / 6.5; not run here for the
    suite's time: lt (2048 spp) 4.2 / 11.7 / 6.3, mmlt (128 spp, 4,096 chains) 2.1 / 10.2 /
    6.7. (The milk left out offsets the path tracer's own 16-spp stack by |t| 44.)"""
    scene = _milk()
    stack = np.stack([jgi.render(scene, name, seed=k, **MILK_ESTIMATORS[name])
                      for k in range(MILK_SEEDS)])
    assert np.all(np.isfinite(stack))
    ref = milk_reference()
    r = region_agreement(stack, ref, 3)
    control = tells_apart(stack, ref, denser_milk_change(), 3)
    print(f"{name}: worst |t| {np.abs(r.t).max():.2f}, with the denser milk's change "
          f"{np.abs(control.t).max():.2f} (critical {r.critical[r.worst]:.2f})")
    assert r.agree, f"{name} vs pt: worst t {r.t[r.worst]:.1f} > {r.critical[r.worst]:.1f}"
    assert not control.agree, f"{name}: a 30% denser milk passes too: the test has no power"


def test_medium_interface_errors_name_what_is_allowed():
    b = SceneBuilder("bad")
    b.material("glass", "dielectric", ior=1.5)
    with pytest.raises(SceneError, match="interior names medium 'milk', which is not defined"):
        b.medium_interface("glass", interior="milk")
    b.bounded_medium("milk", sigma_t=2.0, albedo=0.9)
    with pytest.raises(SceneError, match="medium 'milk' is defined twice"):
        b.bounded_medium("milk", sigma_t=1.0)
    with pytest.raises(SceneError, match="medium 'ink': medium albedo"):
        b.bounded_medium("ink", sigma_t=1.0, albedo=2.0)
    # a light inside a bounded medium: refused (lights shine into the scene's own medium)
    lamp = b.medium_interface("glass", exterior="milk")
    b.sphere((0, 0, 0), 1.0, lamp, emission=(1, 1, 1))
    b.camera((0, 0, 5), (0, 0, 0))
    with pytest.raises(SceneError, match="emitting shape and has exterior medium 'milk'"):
        b.build()
    # a point light inside a sphere that holds a medium: refused
    b3 = SceneBuilder("bad_lamp")
    b3.material("glass", "dielectric", ior=1.5)
    b3.bounded_medium("milk", sigma_t=2.0)
    b3.sphere((0, 0, 0), 1.0, b3.medium_interface("glass", interior="milk"))
    b3.point_light((0.2, 0.1, 0.0), (1.0, 1.0, 1.0))
    b3.camera((0, 0, 5), (0, 0, 0))
    with pytest.raises(SceneError, match=r"point or spot light at \[0.2, 0.1, 0.0\] lies in "
                                         r"medium 'milk', inside the sphere at \[0.0, 0.0, 0.0\]"):
        b3.build()
    # the camera inside it: refused
    b4 = SceneBuilder("bad_camera")
    b4.material("glass", "dielectric", ior=1.5)
    b4.bounded_medium("milk", sigma_t=2.0)
    b4.cube(np.diag([2.0, 2.0, 2.0, 1.0]), b4.medium_interface("glass", interior="milk"))
    b4.camera((0, 0, 1.5), (0, 0, 0))
    with pytest.raises(SceneError, match=r"the camera at \[0.0, 0.0, 1.5\] lies in medium "
                                         r"'milk', inside the cube"):
        b4.build()
    # a mesh (a tetrahedron, outward winding) holding milk, and a glass sphere of ink around
    # it: the medium a point lies in is that of the nearest bounding surface's side, so a
    # light between the two surfaces is in the ink, one inside the mesh in the milk, one
    # outside both in the scene's own medium
    def nested(light):
        b5 = SceneBuilder("nested")
        b5.material("glass", "dielectric", ior=1.5)
        b5.bounded_medium("milk", sigma_t=2.0)
        b5.bounded_medium("ink", sigma_t=1.0)
        tetra = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float) * 0.5
        b5.mesh(tetra, [[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]],
                b5.medium_interface("glass", interior="milk", exterior="ink"))
        b5.sphere((0, 0, 0), 2.0, b5.medium_interface("glass", interior="ink"))
        b5.point_light(light, (1.0, 1.0, 1.0))
        b5.camera((0, 0, 5), (0, 0, 0))
        return b5.build()
    with pytest.raises(SceneError, match=r"light at \[0.05, 0.0, 0.0\] lies in medium 'milk', "
                                         r"inside the triangle at"):
        nested((0.05, 0.0, 0.0))
    with pytest.raises(SceneError, match=r"light at \[1.2, 0.0, 0.0\] lies in medium 'ink', "
                                         r"inside the (triangle|sphere) at"):
        nested((1.2, 0.0, 0.0))
    assert nested((2.5, 0.0, 0.0)).bounded_media is not None
    # around a grid medium: refused
    b2 = SceneBuilder("bad_grid")
    b2.material("glass", "dielectric", ior=1.5)
    b2.bounded_medium("milk", sigma_t=2.0)
    b2.sphere((0, 0, 0), 1.0, b2.medium_interface("glass", interior="milk"))
    b2.grid_medium(np.ones((2, 2, 2)), (-2, -2, -2), (2, 2, 2))
    b2.camera((0, 0, 5), (0, 0, 0))
    with pytest.raises(SceneError, match="grid medium around them"):
        b2.build()


def test_estimators_without_bounded_media_refuse_by_name():
    with pytest.raises(ParameterError, match="pm: the beam estimate"):
        jgi.render(_milk(), "pm", spp=1, seed=0, photons=1000, volume="beam")
    with pytest.raises(ParameterError, match="does not render participating media"):
        jgi.render(_milk(), "whitted", spp=1, seed=0)


def test_scenes_without_bounded_media_are_unchanged():
    """No medium ids in a scene without bounded media: its pytree (so its compiled programs)
    is that of a scene before them."""
    scene = jgi.load_scene("cornell_box_fog", resolution=4)
    assert scene.bounded_media is None and scene.medium_interfaces is None
    assert not scene.has_bounded_media


MILK_XML = """<scene version="3.0.0">
  <integrator type="volpath"><integer name="max_depth" value="8"/></integrator>
  <medium type="homogeneous" id="haze">
    <float name="sigma_t" value="0.1"/><float name="albedo" value="0.8"/>
  </medium>
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 0.6, 4" target="0, 0, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
      <rfilter type="box"/></film>
    <ref name="medium" id="haze"/>
  </sensor>
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>
    <translate y="-0.8"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><scale x="4" y="3"/>
    <translate y="2.2" z="-2"/></transform>
    <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter></shape>
  <shape type="sphere"><float name="radius" value="0.8"/>
    <bsdf type="dielectric"><float name="int_ior" value="1.33"/><float name="ext_ior" value="1"/>
    </bsdf>
    <ref name="exterior" id="haze"/>
    <medium type="homogeneous" name="interior">
      <rgb name="sigma_t" value="0.4, 0.6, 1.0"/><float name="scale" value="5"/>
      <rgb name="albedo" value="0.95, 0.9, 0.8"/>
      <phase type="hg"><float name="g" value="0.3"/></phase>
    </medium></shape>
</scene>
"""


def test_a_medium_inside_glass_renders_like_mitsuba_volpath(tmp_path):
    """Mitsuba's shape media: a glass ball whose interior is a nested homogeneous medium (RGB
    sigma_t and albedo, hg phase) and whose exterior is the sensor's haze, which fills the
    rest of the scene; backlit by an emitter behind it (milk_ball's layout). jgi imports the
    ball's interior as a bounded medium and its exterior as the scene's own; its path tracer
    against Mitsuba 3's volpath per 3 x 3 region and over the image, Welch's t with both
    sides' seed spreads. Measured worst |t| 3.9 per region (critical 6.7), 0.7 over the image;
    with jgi's milk 20% denser 7.3 per region (critical 6.8), left out 258."""
    assert MILK_XML.count("<medium") == 2
    xml = tmp_path / "milk.xml"
    xml.write_text(MILK_XML)
    ours = load_mitsuba_xml(xml)
    assert ours.has_bounded_media
    np.testing.assert_allclose([float(c[0]) for c in ours.bounded_media.sigma_t], [2, 3, 5])
    assert abs(float(ours.bounded_media.g[0]) - 0.3) < 1e-7
    assert_pt_agrees_with_mitsuba(ours, xml, seeds=16, spp=64, max_depth=8, rr_depth=5)


MILK_TOML = """[camera]
position = [0, 0, 4]
look_at = [0, 0, 0]
width = 4
height = 4
medium = "haze"
[[medium]]
name = "haze"
type = "homogeneous"
sigma_t = 0.1
[[medium]]
name = "milk"
type = "{milk_type}"
{milk}
[[material]]
name = "glass"
type = "dielectric"
[[shape]]
type = "sphere"
center = [0, 0, 0]
radius = 1
material = "glass"
{sides}
[[light]]
type = "point"
position = [0, 3, 0]
intensity = [1, 1, 1]
"""


def test_toml_shapes_bound_media(tmp_path):
    """A [[shape]]'s interior / exterior name [[medium]] tables (a side left out, or the
    camera's medium, is the scene's own); errors name the file, the key and what is allowed."""
    def load(sides, milk='sigma_t = [1, 2, 3]\nalbedo = 0.9\ng = 0.2', milk_type="homogeneous"):
        f = tmp_path / "milk.toml"
        f.write_text(MILK_TOML.format(sides=sides, milk=milk, milk_type=milk_type))
        return jgi.load_scene(f)

    scene = load('interior = "milk"\nexterior = "haze"')
    np.testing.assert_allclose([float(c[0]) for c in scene.bounded_media.sigma_t], [1, 2, 3])
    row = int(scene.spheres.material[0])
    faces = scene.medium_interfaces
    assert (int(faces.interior[row]), int(faces.exterior[row])) == (1, 0)
    assert float(scene.medium.sigma_t.x) == pytest.approx(0.1)
    cases = [
        ('interior = "cream"', "", r"shape\[0\]\.interior: unknown medium 'cream'; defined: "
                                   r"haze, milk"),
        ("", "", r"medium\[1\]: medium 'milk' is not used"),
    ]
    for sides, kind, message in cases:
        with pytest.raises(SceneError, match=r"milk\.toml: " + message):
            load(sides)
    # a grid [[medium]] as a shape's interior: the scene's grid bounded by shapes
    smoke = ("density = [[[1.0, 2.0]]]\nbbox_min = [-1, -1, -1]\nbbox_max = [1, 1, 1]\n"
             "sigma_t = [1, 2, 3]\nalbedo = 0.5\ng = 0.3\nborder = \"zero\"")
    scene = load('interior = "milk"\nexterior = "haze"', milk=smoke, milk_type="grid")
    (g,) = scene.bounded_grids
    assert g is not None and g.border == "zero" and float(g.g) == pytest.approx(0.3)
    np.testing.assert_array_equal(np.asarray(g.density), [[[1.0, 2.0]]])
    np.testing.assert_allclose([float(c) for c in g.sigma_t], [1, 2, 3])
    row, faces = int(scene.spheres.material[0]), scene.medium_interfaces
    assert (int(faces.interior[row]), int(faces.exterior[row])) == (1, 0)   # the grid's id: 1
    assert scene.bounded_media is None
    f = tmp_path / "two.toml"
    f.write_text(MILK_TOML.format(sides='interior = "milk"', milk=smoke, milk_type="grid")
                 + '[[medium]]\nname = "soot"\ntype = "grid"\n' + smoke
                 + '\n[[shape]]\ntype = "sphere"\ncenter = [0, 0, 0]\nradius = 0.5\n'
                   'material = "glass"\ninterior = "soot"\n')
    two = jgi.load_scene(f)   # two grids bounded by shapes: ids 1 and 2, in the order named
    assert len(two.bounded_grids) == 2
    faces = two.medium_interfaces
    assert [int(faces.interior[int(r)]) for r in two.spheres.material] == [1, 2]


def test_gradients_with_respect_to_a_bounded_medium():
    """jax.grad of the milk ball's image with respect to the milk's sigma_t, albedo and g
    against central differences (:func:`tests.support.media.assert_medium_gradients`): the
    bounded medium's table is as differentiable as the scene's own medium."""
    from tests.support.media import assert_medium_gradients

    scene = jgi.load_scene("milk_ball", resolution=8)
    assert_medium_gradients(scene, lambda s: s.bounded_media)


# --- Mitsuba's volumes in a null cube or sphere -------------------------------------------------

NULL_CUBE_XML = """<scene version="3.0.0">
  <integrator type="volpath"><integer name="max_depth" value="{depth}"/></integrator>
""" + MITSUBA_FOG_ROOM.format(res=16, medium="unused").replace(
    '    <ref name="medium" id="unused"/>\n', "{sensor_medium}").replace(
    "</scene>", """{media}  <shape type="{shape}">
    <transform name="to_world">{to_world}</transform>
    <bsdf type="null"/>
    {medium}
  </shape>
</scene>""")

BOX = '<scale value="0.8, 0.675, 0.8"/><translate y="-0.275"/>'
TILTED = ('<scale value="0.5, 0.4, 0.45"/><rotate x="1" angle="20"/><rotate y="1" angle="35"/>'
          '<translate x="-0.25" y="-0.4" z="0.3"/>')

GRID_MEDIUM = """<medium type="heterogeneous" name="interior">
      <volume name="sigma_t" type="gridvolume">
        <string name="filename" value="density.vol"/>
        <transform name="to_world">{grid_to_world}</transform>
      </volume>
      <rgb name="albedo" value="0.8, 0.6, 0.9"/><float name="scale" value="1.5"/>
      <phase type="hg"><float name="g" value="0.5"/></phase>
    </medium>"""
# the gridvolume's unit box onto BOX, and onto TILTED ([0, 1]^3 to the cube's [-1, 1]^3 first)
GRID_ON_BOX = '<scale value="1.6, 1.35, 1.6"/><translate x="-0.8" y="-0.95" z="-0.8"/>'
GRID_ON_TILTED = '<scale value="2"/><translate value="-1, -1, -1"/>' + TILTED

FOG_MEDIUM = """<medium type="homogeneous" name="interior">
      <rgb name="sigma_t" value="0.4, 0.7, 0.25"/><float name="scale" value="{scale}"/>
      <rgb name="albedo" value="0.8, 0.6, 0.9"/>
      <phase type="hg"><float name="g" value="0.5"/></phase>
    </medium>"""

INTERIOR = '    <ref name="medium" id="fog"/>\n'

FOG_SPHERE = """  <shape type="sphere">
    <transform name="to_world"><scale value="0.3"/><translate x="0.55" y="0.5" z="-0.45"/>
    </transform>
    <bsdf type="null"/>
    {medium}
  </shape>
"""


def null_volume_xml(case: str, depth: int = 64, **changes) -> str:
    """The fog room with a volume bounded by a null shape: ``tilted_grid`` (a .vol grid in a
    rotated, stretched cube, its box the cube's), ``two_volumes`` (that, and a homogeneous
    medium in a sphere above it), ``inside_sphere`` (thin fog in a sphere around
    the camera, the sensor's medium), ``offset_grid`` (an axis-aligned grid in a cube that cuts
    it)."""
    grid, fog = GRID_MEDIUM, FOG_MEDIUM.format(scale=3)
    tilted = dict(shape="cube", to_world=TILTED, medium=grid.format(grid_to_world=GRID_ON_TILTED))
    args = {"tilted_grid": tilted,
            "two_volumes": dict(tilted, media=FOG_SPHERE.format(medium=fog)),
            "inside_sphere": dict(shape="sphere", medium='<ref name="interior" id="fog"/>',
                                  media="  " + FOG_MEDIUM.format(scale=0.6).replace(
                                      'name="interior"', 'id="fog"') + "\n",
                                  sensor_medium=INTERIOR,
                                  to_world='<translate x="0" y="0.1" z="2.6"/>'),
            "offset_grid": dict(shape="cube", to_world=BOX.replace('y="-0.275"', 'y="-0.2"'),
                                medium=grid.format(grid_to_world=GRID_ON_BOX))}[case]
    args = {"sensor_medium": "", "media": "", "depth": depth, **args, **changes}
    return NULL_CUBE_XML.format(**args)


@pytest.mark.parametrize("case", ["two_volumes", "inside_sphere"])
def test_a_volume_in_a_null_shape_renders_like_mitsuba_volpath(tmp_path, case):
    """Mitsuba's usual volume: a shape with a ``null`` bsdf whose interior is the medium, vacuum
    around. jgi imports it as its grid medium cut to the shape (a homogeneous interior as a
    constant grid; :mod:`jgi.physics.grid_media`) and renders it like Mitsuba 3's volpath, per
    3 x 3 region and over the image (Welch, both sides' seed spreads; max_depth 64, so that
    however the two count a crossing of the null surface, paths that long weigh nothing here):
    two volumes, a .vol grid in a rotated, stretched cube (the grid's own frame) and fog in a
    sphere (the convex cut), tracked each on its own stream, the nearest collision taken; and,
    with the camera inside a sphere of fog as its medium, the medium's end where rays leave
    it. Measured worst |t| per 3 x 3 region (critical 6.1-6.8): 1.2 and 3.8; with jgi's
    density 10% lower 6.9 (the cube's alone: 6.9) and 12.7; the cut left out (the world around
    the camera) 10.5; the fog sphere left out 83.1. The light tracer on the two volumes: 2.4
    (critical 7.9). (One volume alone, before several: the tilted grid 3.2 and 7.1 with its
    density 10% lower; the fog sphere 1.5, 5.9, and 39.8 with the medium filling the sphere's
    box.)"""
    z, y, x = np.meshgrid(*(np.linspace(0, 1, n) for n in (5, 6, 7)), indexing="ij")
    write_vol(tmp_path / "density.vol", (0.3 + 1.5 * x * (1 - 0.5 * y)).astype(np.float32))
    xml = tmp_path / "volume.xml"
    xml.write_text(null_volume_xml(case))
    ours = load_mitsuba_xml(xml)
    assert ours.has_grid_medium and not ours.has_bounded_media
    volumes = ours.medium if case == "two_volumes" else (ours.medium,)
    assert [(v.to_local is not None, v.clip is not None, v.clip_shape) for v in volumes] == (
        [(True, True, "sphere"), (True, False, "cube")] if case == "two_volumes"
        else [(True, True, "sphere")])
    # the light tracer too on the two volumes (its connections' ratio tracking through both;
    # BDPT agreed on the fog sphere alone, worst |t| 2.7 against 8.2, but compiles in 48 s)
    others = {"lt": dict(spp=64, max_depth=16)} if case == "two_volumes" else None
    assert_pt_agrees_with_mitsuba(ours, xml, seeds=12, spp=256, max_depth=64, others=others)


def test_null_volumes_import_as_cut_grids(tmp_path):
    """The axis-aligned volume in a cube keeps the axis-aligned grid it always imported as
    (world box, no frame, no cut); a grid offset from its cube is cut to the cube; the sensor
    may come before or after the shape in the file."""
    z, y, x = np.meshgrid(*(np.linspace(0, 1, n) for n in (5, 6, 7)), indexing="ij")
    write_vol(tmp_path / "density.vol", (0.3 + 1.5 * x * (1 - 0.5 * y)).astype(np.float32))
    xml = tmp_path / "volume.xml"
    xml.write_text(null_volume_xml("offset_grid", to_world=BOX))
    aligned = load_mitsuba_xml(xml).medium
    assert aligned.to_local is None and aligned.clip is None
    np.testing.assert_allclose([float(c) for c in aligned.lo], [-0.8, -0.95, -0.8], atol=1e-6)
    np.testing.assert_allclose([float(c) for c in aligned.hi], [0.8, 0.4, 0.8], atol=1e-6)
    xml.write_text(null_volume_xml("offset_grid"))
    cut = load_mitsuba_xml(xml).medium
    assert cut.to_local is None and cut.clip is not None and cut.clip_shape == "cube"
    np.testing.assert_allclose(np.asarray(cut.clip) @ [0.0, 0.475, 0.0, 1.0], [0.0, 1.0, 0.0],
                               atol=1e-6)   # the cube's top face, y = -0.2 + 0.675
    text = null_volume_xml("inside_sphere")
    sensor = text[text.index("  <sensor"):text.index("</sensor>") + len("</sensor>\n")]
    xml.write_text(text.replace(sensor, "").replace("</scene>", sensor + "</scene>"))
    late = load_mitsuba_xml(xml).medium
    xml.write_text(text)
    leaves_equal(late, load_mitsuba_xml(xml).medium)


def test_null_boundaries_jgi_cannot_take_are_refused_by_name(tmp_path):
    write_vol(tmp_path / "density.vol", np.ones((2, 2, 2), np.float32))
    grid = GRID_MEDIUM.format(grid_to_world=GRID_ON_BOX)
    cases = {
        "cylinder": (dict(shape="cylinder"), "cylinder with a 'null' bsdf bounding media: "
                                             "supported is a cube or a sphere"),
        "ellipsoid": (dict(to_world='<scale value="0.4, 0.3, 0.4"/>'),
                      "sphere: to_world must be a uniform scale"),
        "camera inside, in vacuum": (dict(sensor_medium=""),
                                     "the sensor lies inside the sphere but its medium is not "
                                     "the interior"),
        "camera outside, in the medium": (
            dict(to_world='<scale value="0.4"/>'), "the sensor lies outside the sphere in a "
                                                   "medium"),
        "turned grid, other box": (dict(shape="cube", to_world=BOX, sensor_medium="",
                                        medium=GRID_MEDIUM.format(
            grid_to_world=GRID_ON_TILTED)), "a rotated or sheared gridvolume is taken where"),
        "overlapping volumes": (dict(shape="cube", to_world=BOX, sensor_medium="", medium=grid
                                     + """
  </shape>
  <shape type="sphere"><bsdf type="null"/>
    """ + FOG_MEDIUM.format(scale=1)), r"volume 1's bounding box .* overlaps volume 0's"),
        "volumes with two phase functions": (
            dict(shape="cube", to_world=TILTED, sensor_medium="", medium=grid.format(
                grid_to_world=GRID_ON_TILTED), media=FOG_SPHERE.format(
                    medium=FOG_MEDIUM.format(scale=1).replace('value="0.5"', 'value="0.2"'))),
            "volume 1 has g = 0.5, volume 0 g = 0.2; volumes of the scene's own medium share one "
            "phase function"),
        "camera outside both, in one's medium": (
            dict(to_world='<scale value="0.3"/><translate x="-0.5" y="0.3"/>',
                 media=FOG_MEDIUM.format(scale=0.6).replace(
                'name="interior"', 'id="fog"') + "\n" + FOG_SPHERE.format(
                    medium='<ref name="interior" id="fog"/>')),
            "the sensor lies outside the sphere in a medium"),
    }
    for name, (changes, message) in cases.items():
        (tmp_path / "bad.xml").write_text(null_volume_xml("inside_sphere", depth=8, **changes))
        with pytest.raises(ImportError_, match=r"bad\.xml.*" + message):
            load_mitsuba_xml(tmp_path / "bad.xml")


SMOKE_GLASS_XML = MILK_XML.replace(
    """<medium type="homogeneous" name="interior">
      <rgb name="sigma_t" value="0.4, 0.6, 1.0"/><float name="scale" value="5"/>
      <rgb name="albedo" value="0.95, 0.9, 0.8"/>
      <phase type="hg"><float name="g" value="0.3"/></phase>
    </medium>""", """<medium type="heterogeneous" name="interior">
      <volume name="sigma_t" type="gridvolume">
        <string name="filename" value="density.vol"/>
        <transform name="to_world"><scale value="1.6"/><translate value="-0.8, -0.8, -0.8"/>
        </transform>
      </volume>
      <rgb name="albedo" value="0.95, 0.9, 0.8"/><float name="scale" value="4"/>
      <phase type="hg"><float name="g" value="0.3"/></phase>
    </medium>""")


def test_smoke_inside_glass_renders_like_mitsuba_volpath(tmp_path):
    """A heterogeneous medium (a .vol grid over the ball's box) as a glass ball's interior,
    the sensor's haze outside: jgi's bounded grid (tracked on the lanes inside the ball, the
    others sampled in the haze) against Mitsuba 3's volpath per 3 x 3 region and over the
    image, 16 seeds x 64 spp a side. Measured worst |t| 2.6 per region (critical 5.9), 0.2
    over the image; with jgi's grid 20% thinner 17.1, the smoke left out 208."""
    assert SMOKE_GLASS_XML.count("heterogeneous") == 1
    z, y, x = np.meshgrid(*(np.linspace(0, 1, n) for n in (5, 6, 7)), indexing="ij")
    write_vol(tmp_path / "density.vol", (0.2 + 1.5 * x * (1 - 0.5 * y)).astype(np.float32))
    xml = tmp_path / "smoke.xml"
    xml.write_text(SMOKE_GLASS_XML)
    ours = load_mitsuba_xml(xml)
    (grid,) = ours.bounded_grids
    assert not isinstance(ours.medium, type(grid))
    np.testing.assert_allclose([float(c) for c in grid.lo], [-0.8] * 3, atol=1e-6)
    assert_pt_agrees_with_mitsuba(ours, xml, seeds=16, spp=64, max_depth=8, rr_depth=5)


def test_each_bounded_grid_tracks_its_own_lanes():
    """Lanes of four media (the haze, a homogeneous ball, two grids of different shapes and
    constant densities 0.5 and 2, their majorants equal to them) fly 1.5 units through each
    grid's box: per id, delta tracking scatters with probability 1 - exp(-sigma d) and ratio
    tracking's 0 / 1 estimates average exp(-sigma d) (within 4 standard errors, 4,096 lanes an
    id); lanes in no grid neither collide nor lose transmittance. Either grid's lanes tracked in the
    other's would be off by more than 50 standard errors."""
    import jax
    import jax.numpy as jnp

    from jgi.core import rng
    from jgi.core.vec import V3
    from jgi.physics import medium_interfaces

    b = SceneBuilder("two_grids")
    b.material("glass", "dielectric", ior=1.5)
    b.medium(sigma_t=0.1)
    b.bounded_medium("milk", sigma_t=3.0)
    b.bounded_grid_medium("thin", np.full((2, 3, 4), 0.5), (-1, -1, -1), (1, 1, 1))
    b.bounded_grid_medium("thick", np.full((3, 1, 2), 2.0), (-1, -1, -1), (1, 1, 1))
    for k, name in enumerate(("milk", "thin", "thick")):
        b.sphere((3.0 * k, 0, 10), 0.5, b.medium_interface("glass", interior=name))
    b.camera((0, 0, 0), (0, 0, 1), fov=10, width=4, height=4)
    scene = b.build()
    assert medium_interfaces.grid_id(scene) == 2 and len(scene.bounded_grids) == 2
    smoke = jgi.load_scene("milk_ball", resolution=4, smoke=True)   # the built-in's grid: id 1
    (grid,) = smoke.bounded_grids
    assert smoke.bounded_media is None and grid.density.shape == (6, 7, 8)
    assert int(smoke.medium_interfaces.interior[int(smoke.spheres.material[0])]) == 1

    n = 4096
    ids = jnp.repeat(jnp.arange(4, dtype=jnp.int32), n)
    full = lambda v: jnp.full(ids.shape, v, jnp.float32)   # noqa: E731
    o, d = V3(full(0.2), full(-0.1), full(-0.5)), V3(full(0.0), full(0.0), full(1.0))
    u = jax.random.uniform(jax.random.PRNGKey(7), (2, ids.shape[0]))
    t_max, active, key = full(jnp.inf), ids >= 0, rng.substream(u[0], u[1])
    flight = medium_interfaces.free_flight(scene, ids, o, d, t_max, V3(*(full(1.0),) * 3),
                                           active, key)
    tr = medium_interfaces.transmittance(scene, ids, o, d, t_max, active, key)
    scattered = np.asarray(flight.scattered).reshape(4, n)
    transmitted = np.asarray(tr.x).reshape(4, n)
    assert not scattered[:2].any() and np.all(transmitted[:2] == 1.0)
    for row, density in ((2, 0.5), (3, 2.0)):
        exact = np.exp(-density * 1.5)
        for estimate in (1.0 - scattered[row], transmitted[row]):
            se = np.sqrt(exact * (1 - exact) / n)
            assert abs(estimate.mean() - exact) < 4 * se, (row, estimate.mean(), exact)


def _smoke_ball(x: float, vol: str, albedo: str, g: float) -> str:
    return f"""<shape type="sphere"><float name="radius" value="0.5"/>
    <transform name="to_world"><translate x="{x}"/></transform>
    <bsdf type="dielectric"><float name="int_ior" value="1.33"/><float name="ext_ior" value="1"/>
    </bsdf>
    <ref name="exterior" id="haze"/>
    <medium type="heterogeneous" name="interior">
      <volume name="sigma_t" type="gridvolume">
        <string name="filename" value="{vol}"/>
        <transform name="to_world"><translate value="{x - 0.5}, -0.5, -0.5"/></transform>
      </volume>
      <rgb name="albedo" value="{albedo}"/><float name="scale" value="4"/>
      <phase type="hg"><float name="g" value="{g}"/></phase>
    </medium></shape>"""


TWO_SMOKES_XML = MILK_XML[:MILK_XML.index('  <shape type="sphere">')].replace(
    '"max_depth" value="8"', '"max_depth" value="6"') + "\n".join(
    [_smoke_ball(-0.55, "dense.vol", "0.95, 0.9, 0.8", 0.3),
     _smoke_ball(0.55, "light.vol", "0.6, 0.8, 0.95", -0.2), "</scene>"])


def test_two_smokes_in_glass_render_like_mitsuba_volpath(tmp_path):
    """Two glass balls, each holding its own heterogeneous medium (grids of different shapes,
    albedos and phase functions), in haze: jgi's path tracer and BDPT (each grid's lanes tracked
    in it, its connections' transmittance by ratio tracking in it, its own mean extinction as
    the distance densities' proxy) against Mitsuba 3's volpath per 3 x 3 region and over the
    image, 16 seeds a side. Measured worst |t| per region pt 1.6, bdpt 2.1 (critical 5.7-6.0),
    over the image 0.7 and 0.2; with the two .vol files swapped in jgi's scene 38.2 and 26.7."""
    z, y, x = np.meshgrid(*(np.linspace(0, 1, n) for n in (5, 6, 7)), indexing="ij")
    write_vol(tmp_path / "dense.vol", (0.2 + 1.5 * x * (1 - 0.5 * y)).astype(np.float32))
    z, y, x = np.meshgrid(*(np.linspace(0, 1, n) for n in (3, 2, 4)), indexing="ij")
    write_vol(tmp_path / "light.vol", (0.05 + 0.3 * z + 0.2 * y).astype(np.float32))
    xml = tmp_path / "smokes.xml"
    xml.write_text(TWO_SMOKES_XML)
    ours = load_mitsuba_xml(xml)
    assert len(ours.bounded_grids) == 2 and ours.bounded_media is None
    assert [g.density.shape for g in ours.bounded_grids] == [(5, 6, 7), (3, 2, 4)]
    assert_pt_agrees_with_mitsuba(ours, xml, seeds=16, spp=64, max_depth=6, rr_depth=5,
                                  others={"bdpt": dict(spp=16, max_depth=6)})
