"""pbrt-v4 import: scene data against jgi's builder, unit conventions, errors, orientation."""

from __future__ import annotations

import math

import equinox as eqx
import numpy as np
import pytest

import jgi
from jgi.core import transform as xf
from jgi.scene import SceneBuilder, SceneError
from jgi.scene.importers import load_pbrt, pbrt
from jgi.scene.tables import (
    DIELECTRIC,
    GGX,
    MIRROR,
    NAMED_METALS,
    ROUGH_CONDUCTOR,
    ROUGH_DIELECTRIC,
)
from tests.support.scenes import leaves_equal, ply_quad
from tests.support.stats import assert_agree

HEADER = """
Scale -1 1 1
LookAt 0 1 5  0 0 0  0 1 0
Camera "perspective" "float fov" [ 40 ]
Sampler "zsobol" "integer pixelsamples" 16
Film "rgb" "integer xresolution" [ 8 ] "integer yresolution" [ 6 ] "string filename" "x.exr"
WorldBegin
"""


def write(tmp_path, body, name="scene.pbrt"):
    p = tmp_path / name
    p.write_text(HEADER + body)
    return p


def test_scene_data_matches_the_builder(tmp_path):
    body = """
    # a comment
    MakeNamedMaterial "red" "string type" "diffuse" "rgb reflectance" [0.6 0.1 0.1]
    AttributeBegin
      Translate 0 0.5 0
      Material "dielectric" "float eta" 1.33
      Shape "sphere" "float radius" 0.5
    AttributeEnd
    NamedMaterial "red"
    Shape "trianglemesh" "point3 P" [-1 0 -1  1 0 -1  1 0 1  -1 0 1]
      "integer indices" [0 1 2  0 2 3]
    LightSource "point" "rgb I" [2 2 2] "point3 from" [0 3 0]
    LightSource "distant" "point3 from" [0 1 0] "point3 to" [0 0 0] "rgb L" [1 0.5 0.25]
    LightSource "uniform" "rgb L" [0.1 0.1 0.1] "float scale" 2
    """
    got = load_pbrt(write(tmp_path, body))
    b = SceneBuilder("scene")
    b.material("_pbrt_material0", "dielectric", ior=1.33)   # created before "red" is used
    b.material("red", "diffuse", diffuse=(0.6, 0.1, 0.1))
    b.sphere((0, 0.5, 0), 0.5, "_pbrt_material0")
    b.mesh([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], [[0, 1, 2], [0, 2, 3]], "red")
    b.point_light((0, 3, 0), (2, 2, 2))
    b.directional_light((0, -1, 0), (1, 0.5, 0.25))
    b.environment_light((0.2, 0.2, 0.2))
    b.camera((0, 1, 5), (0, 0, 0), up=(0, 1, 0), fov=40, width=8, height=6, fov_axis="smaller")
    expected = b.build()
    # material rows are ordered differently (named materials are created at definition)
    np.testing.assert_allclose(sorted(np.asarray(got.materials.ior)),
                               sorted(np.asarray(expected.materials.ior)))
    for field in ("spheres", "triangles", "lights", "camera"):
        leaves_equal(_strip_material(getattr(got, field)),
                     _strip_material(getattr(expected, field)))


def _strip_material(table):
    import equinox as eqx
    if hasattr(table, "material"):
        return eqx.tree_at(lambda t: t.material, table, table.material * 0)
    return table


def test_power_and_scale_conventions(tmp_path):
    body = """
    LightSource "point" "rgb I" [1 2 3] "float power" 100
    LightSource "spot" "rgb I" [1 1 1] "point3 from" [0 4 0] "point3 to" [0 0 0]
      "float coneangle" 30 "float conedelta" 10 "float power" 50
    AttributeBegin
      AreaLightSource "diffuse" "rgb L" [1 1 1] "float power" 20
      Shape "trianglemesh" "point3 P" [0 2 0  1 2 0  0 2 1] "integer indices" [0 2 1]
    AttributeEnd
    LightSource "distant" "rgb L" [2 2 2] "float illuminance" 7
    """
    s = load_pbrt(write(tmp_path, body))
    I = np.array([s.lights.emission.x[1], s.lights.emission.y[1], s.lights.emission.z[1]])
    lum = 0.2126 * 1 + 0.7152 * 2 + 0.0722 * 3
    np.testing.assert_allclose(I, np.array([1, 2, 3]) * 100 / (4 * math.pi * lum), rtol=1e-5)
    c_end, c_start = math.cos(math.radians(30)), math.cos(math.radians(20))
    np.testing.assert_allclose(float(s.lights.emission.x[2]),
                               50 / (2 * math.pi * (1 - 0.5 * (c_start + c_end))), rtol=1e-5)
    # area light: one-sided, power = pi * A * L for a unit-luminance L
    np.testing.assert_allclose(float(s.lights.emission.x[0]), 20 / (math.pi * 0.5), rtol=1e-5)
    np.testing.assert_allclose(float(s.lights.emission.x[4]), 7.0, rtol=1e-5)


def test_microfacet_materials_give_the_builder_rows(tmp_path):
    body = """
    MakeNamedMaterial "copper" "string type" "conductor"
    MakeNamedMaterial "gold" "string type" "conductor" "spectrum eta" "metal-Au-eta"
      "spectrum k" "metal-Au-k" "float roughness" 0.01
    MakeNamedMaterial "brushed" "string type" "conductor" "rgb eta" [0.2 0.9 1.1]
      "rgb k" [3.9 2.4 2.2] "float uroughness" 0.09 "float vroughness" 0.09
    MakeNamedMaterial "raw" "string type" "conductor" "float roughness" 0.3
      "bool remaproughness" false
    MakeNamedMaterial "albedo" "string type" "conductor" "rgb reflectance" [0.9 0.5 0.2]
    MakeNamedMaterial "almost_smooth" "string type" "conductor" "float roughness" 5e-7
    MakeNamedMaterial "flat_spectra" "string type" "conductor" "spectrum eta" [400 0.5 700 0.5]
      "spectrum k" [400 3 700 3]
    MakeNamedMaterial "frosted" "string type" "dielectric" "float eta" 1.33
      "float roughness" 0.04
    MakeNamedMaterial "glass" "string type" "dielectric" "spectrum eta" [300 1.4 800 1.4]
    """
    imp = pbrt._Importer(write(tmp_path, body))
    scene = imp.run()
    m = scene.materials

    def row(name):
        i = imp.b.material_names[imp.named[name]]
        return dict(kind=int(m.kind[i]), alpha=(float(m.alpha_u[i]), float(m.alpha_v[i])),
                    distribution=int(m.distribution[i]), ior=float(m.ior[i]),
                    eta=[float(c[i]) for c in (m.eta.x, m.eta.y, m.eta.z)],
                    k=[float(c[i]) for c in (m.k.x, m.k.y, m.k.z)])

    r = np.array([0.9, 0.5, 0.2])
    cu, au = NAMED_METALS["Cu"], NAMED_METALS["Au"]
    expect = {   # alpha = sqrt(roughness) (pbrt-v4's RoughnessToAlpha); pbrt's default is copper
        "copper": dict(kind=MIRROR, eta=cu[0], k=cu[1]),
        "gold": dict(kind=ROUGH_CONDUCTOR, alpha=(0.1, 0.1), distribution=GGX, eta=au[0],
                     k=au[1]),
        "brushed": dict(kind=ROUGH_CONDUCTOR, alpha=(0.3, 0.3), eta=[0.2, 0.9, 1.1],
                        k=[3.9, 2.4, 2.2]),
        "raw": dict(kind=ROUGH_CONDUCTOR, alpha=(0.3, 0.3), eta=cu[0], k=cu[1]),
        "albedo": dict(kind=MIRROR, eta=[1, 1, 1], k=2 * np.sqrt(r) / np.sqrt(1 - r)),
        "almost_smooth": dict(kind=MIRROR),   # alpha 7e-4 < 1e-3: pbrt's EffectivelySmooth
        "flat_spectra": dict(kind=MIRROR, eta=[0.5] * 3, k=[3] * 3),
        "frosted": dict(kind=ROUGH_DIELECTRIC, alpha=(0.2, 0.2), distribution=GGX, ior=1.33),
        "glass": dict(kind=DIELECTRIC, ior=1.4),
    }
    for name, want in expect.items():
        got = row(name)
        for key, value in want.items():
            np.testing.assert_allclose(got[key], value, rtol=1e-6, err_msg=f"{name}.{key}")
    # the reflectance form reflects r at normal incidence: |(eta - 1 + i k) / (eta + 1 + i k)|^2
    k = np.array(row("albedo")["k"])
    np.testing.assert_allclose(k**2 / (4 + k**2), r, rtol=1e-5)


@pytest.mark.parametrize("body, message", [
    ('Shape "curve" "float width" 1',
     'Shape "curve" is not supported.*sphere, disk, cylinder, trianglemesh, plymesh'),
    ('Material "coateddiffuse"', "material 'coateddiffuse' is not supported: pbrt-v4's "
     "coateddiffuse is a stochastic layered BSDF.*Use a Mitsuba XML or TOML scene with a "
     "roughplastic \\(or, for a smooth coating, a plastic\\) instead"),
    ('Material "coateddiffuse" "float roughness" 0 "float thickness" 0.0001',
     "no choice of its parameters equals a jgi material"),
    ('Material "coatedconductor"', "material 'coatedconductor' is not supported; supported: "
     "diffuse, conductor, dielectric"),
    ('Material "conductor" "spectrum eta" "metal-CuZn-eta" "spectrum k" "metal-CuZn-k"',
     "named spectrum 'metal-CuZn-eta' is not supported; supported: metal-Ag-eta/-k"),
    ('Material "conductor" "spectrum eta" "metal-Au-eta" "spectrum k" "metal-Ag-k"',
     "must name the same metal"),
    ('Material "conductor" "spectrum eta" "metal-Au-eta" "rgb k" [3 2 1]',
     "cannot be mixed with an rgb value"),
    ('Material "diffuse" "spectrum reflectance" [500 0.3 400 0.2]',
     "wavelengths must increase"),
    ('Material "diffuse" "spectrum reflectance" [400 0.3 500]', "pairs"),
    ('Material "dielectric" "blackbody eta" 3000', "a blackbody is an emission spectrum"),
    ('Material "conductor" "rgb reflectance" [0.9 0.9 0.9] "rgb eta" [1 1 1]',
     "give either \"reflectance\" or \"eta\" and \"k\""),
    ('Material "conductor" "float roughness" -0.1', "roughness must be >= 0"),
    ('Material "conductor" "float uroughness" 0.01 "float vroughness" 0.04',
     "anisotropic roughness \\(uroughness != vroughness\\) is not supported"),
    ('Material "conductor" "float displacement" 0.1', "displacement is not supported"),
    ('Material "diffuse" "float roughness" 0.5',
     "material 'diffuse': unknown parameter 'roughness'; diffuse takes: reflectance"),
    ('Material "dielectric" "spectrum eta" "glass-BK7"', "varies with wavelength \\(dispersion\\)"),
    ('Material "dielectric" "spectrum eta" [400 1.53 700 1.51]',
     "varies with wavelength \\(dispersion\\)"),
    ('Material "diffuse" "texture reflectance" "wood"',
     "reflectance names texture 'wood', which is not defined before it"),
    ('Texture "wood" "spectrum" "imagemap" "string filename" "wood.png"',
     "bitmap\\): cannot read '.*wood.png'"),
    ('Texture "checks" "float" "scale" "float scale" 8',
     'Texture "checks": only "spectrum" textures .* and "float" checkerboard and imagemap'),
    ('Texture "w" "spectrum" "imagemap" "string filename" "w.png" "string wrap" "clamp"',
     'wrap "clamp" is not supported'),
    ('LightSource "point" "spectrum I" "glass-BK7"', "'glass-BK7' is neither a named "
     "spectrum jgi carries \\(stdillum-D65, stdillum-A"),
    ('LightSource "point" "blackbody I" -300', "temperature must be > 0"),
    ('LightSource "point" "blackbody I" [3000 1]', "blackbody takes one temperature"),
    ('LightSource "distant" "spectrum from" [400 1 500 1]', "spectrum values are supported "
     "for L, I, reflectance"),
    ('CoordSysTransform "nowhere"', 'unknown coordinate system "nowhere"; defined: camera, '
     'world'),
    ('LightSource "goniometric"', 'LightSource "goniometric" is not supported'),
    ('LightSource "infinite" "string filename" "sky.exr"',
     'LightSource "infinite": cannot read "filename" \'.*sky.exr\''),
    ('LightSource "infinite" "point3 portal" [0 0 0  1 0 0  1 1 0  0 1 0]',
     '"portal" is not supported'),
    ('LightSource "infinite" "rgb L" [1 1 1] "string filename" "sky.exr"',
     'either "L" or "filename", not both'),
    ('AreaLightSource "diffuse" "bool twosided" true', "two-sided"),
    ('ObjectBegin "x"', "directive 'ObjectBegin' is not supported"),
    ('NamedMaterial "nope"', 'unknown named material "nope"'),
    ('Shape "trianglemesh" "point3 P" [0 0 0 1 0 0 0 1 0] "normal N" [0 0 1 0 0 1]',
     r'"normal N" needs 3 numbers per vertex'),
    ('Shape "plymesh" "string filename" "missing.ply"', "does not exist"),
    ('AttributeEnd', "without a matching begin"),
])
def test_unsupported_input_names_file_line_and_directive(tmp_path, body, message):
    path = write(tmp_path, body)
    with pytest.raises(SceneError, match=message) as e:
        load_pbrt(path)
    line = HEADER.count("\n") + 1
    assert f"{path}:{line}:" in str(e.value)


def cornell_pbrt(res, flip):
    """jgi's Cornell box walls, light and boxes as pbrt triangle meshes."""
    scene = jgi.scenes.cornell_box(resolution=res)
    lines = [("Scale -1 1 1" if flip else ""), "LookAt 0 0 3.9  0 0 0  0 1 0",
             'Camera "perspective" "float fov" 39.3077',
             f'Film "rgb" "integer xresolution" {res} "integer yresolution" {res}', "WorldBegin"]
    from jgi.core import transform as xf
    from jgi.scene.builtin import CORNELL_LIGHT, GREEN, RED, WHITE
    T, R, S = xf.translate, xf.rotate, xf.scale

    def quad(m, rgb, emit=None):
        corners = xf.apply_point(m, np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
                                             float))
        out = ["AttributeBegin",
               f'Material "diffuse" "rgb reflectance" [{rgb[0]} {rgb[1]} {rgb[2]}]']
        if emit:
            out.append(f'AreaLightSource "diffuse" "rgb L" [{emit[0]} {emit[1]} {emit[2]}]')
        out.append('Shape "trianglemesh" "point3 P" [' + " ".join(map(str, corners.ravel())) +
                   '] "integer indices" [0 1 2 0 2 3]')
        out.append("AttributeEnd")
        return out
    lines += quad(T([0, 0.99, 0.01]) @ R([1, 0, 0], 90) @ S([0.23, 0.19, 0.19]), WHITE,
                  CORNELL_LIGHT)
    lines += quad(T([0, -1, 0]) @ R([1, 0, 0], -90), WHITE)
    lines += quad(T([0, 1, 0]) @ R([1, 0, 0], 90), WHITE)
    lines += quad(T([0, 0, -1]), WHITE)
    lines += quad(T([1, 0, 0]) @ R([0, 1, 0], -90), GREEN)
    lines += quad(T([-1, 0, 0]) @ R([0, 1, 0], 90), RED)
    for m in (T([0.335, -0.7, 0.38]) @ R([0, 1, 0], -17) @ S(0.3),
              T([-0.33, -0.4, -0.28]) @ R([0, 1, 0], 18.25) @ S([0.3, 0.61, 0.3])):
        for face in (R([0, 1, 0], a) for a in (0, 90, 180, 270)):
            lines += quad(m @ face @ T([0, 0, 1]), WHITE)
        lines += quad(m @ R([1, 0, 0], -90) @ T([0, 0, 1]), WHITE)
        lines += quad(m @ R([1, 0, 0], 90) @ T([0, 0, 1]), WHITE)
    return "\n".join(lines) + "\n", scene


@pytest.mark.parametrize("flip", [True, False])
def test_cornell_box_as_pbrt_renders_like_the_builtin(tmp_path, flip):
    """With pbrt's usual 'Scale -1 1 1' the image matches jgi's; without it pbrt's left-handed
    camera sees the mirror image, which the importer reproduces."""
    text, builtin = cornell_pbrt(16, flip)
    (tmp_path / "cb.pbrt").write_text(text)
    scene = load_pbrt(tmp_path / "cb.pbrt")
    seeds = range(16)
    a = np.stack([jgi.render(scene, "pt", spp=12, seed=s) for s in seeds])
    b = np.stack([jgi.render(builtin, "pt", spp=12, seed=100 + s) for s in seeds])
    if not flip:
        b = b[:, :, ::-1]
    assert_agree(a, b, regions=4, label=f"pbrt cornell flip={flip}")


@pytest.mark.parametrize("names", [("u", "v"), ("texture_s", "texture_t")])
def test_textured_plymesh_takes_the_files_uv(tmp_path, names):
    """A plymesh with a textured material: the triangles' uv are the file's (pbrt-v4's names,
    texture_s / texture_t included; v as written); without uv in the file it is refused."""

    ply_quad(tmp_path / "q.ply", names)
    body = ('Texture "c" "spectrum" "checkerboard" "rgb tex1" [.8 .1 .1] "rgb tex2" [.1 .1 .8]\n'
            'Material "diffuse" "texture reflectance" "c"\n'
            'Shape "plymesh" "string filename" "q.ply"\n')
    tri = load_pbrt(write(tmp_path, body)).triangles
    uv = np.asarray(tri.uv)
    # triangle (0, 1, 2): uv0 and the edges uv1 - uv0, uv2 - uv0
    np.testing.assert_allclose(uv[0], [0.1, 0.2, 0.8, -0.1, 0.7, 0.5], atol=1e-6)
    ply_quad(tmp_path / "q.ply", None)
    with pytest.raises(SceneError, match=r"plymesh 'q.ply' with a textured material needs "
                                         "texture coordinates"):
        load_pbrt(write(tmp_path, body))


def _quad_mesh(z=0.0, reverse_winding=False):
    idx = "0 2 1  0 3 2" if reverse_winding else "0 1 2  0 2 3"
    return (f'Shape "trianglemesh" "point3 P" [-1 -1 {z}  1 -1 {z}  1 1 {z}  -1 1 {z}] '
            f'"integer indices" [{idx}]')


def test_coordinate_systems_load_like_their_explicit_transforms(tmp_path):
    """CoordinateSystem / CoordSysTransform (a saved system, the predefined "camera" and
    "world") give the scene the explicit transforms give: the "camera" system is the
    inverse of the transform at Camera (HEADER's Scale -1 1 1 times LookAt)."""
    named = """
    AttributeBegin
      Translate 1 2 3
      Rotate 30 0 1 0
      CoordinateSystem "tilted"
    AttributeEnd
    AttributeBegin
      CoordSysTransform "tilted"
      Material "diffuse" "rgb reflectance" [0.5 0.4 0.3]
      Shape "sphere" "float radius" 0.5
      """ + _quad_mesh(0.25) + """
      CoordSysTransform "camera"
      Translate 0 0 2
      LightSource "point" "rgb I" [1 2 3] "point3 from" [0.5 0 0]
      CoordSysTransform "world"
      LightSource "point" "rgb I" [3 2 1] "point3 from" [0 4 0]
    AttributeEnd
    """
    pos, look, up = np.array([0.0, 1, 5]), np.zeros(3), np.array([0.0, 1, 0])
    d = (look - pos) / np.linalg.norm(look - pos)
    right = np.cross(up, d)
    right /= np.linalg.norm(right)
    new_up = np.cross(d, right)
    # pbrt's LookAt gives camera-from-world; its inverse has columns right, up, dir, pos, and
    # HEADER's Scale -1 1 1 (applied first) negates the first column
    cols = np.concatenate([-right, [0], new_up, [0], d, [0], pos, [1]])
    explicit = """
    AttributeBegin
      Translate 1 2 3
      Rotate 30 0 1 0
      Material "diffuse" "rgb reflectance" [0.5 0.4 0.3]
      Shape "sphere" "float radius" 0.5
      """ + _quad_mesh(0.25) + """
      Transform [""" + " ".join(f"{x:.17g}" for x in cols) + """]
      Translate 0 0 2
      LightSource "point" "rgb I" [1 2 3] "point3 from" [0.5 0 0]
      Identity
      LightSource "point" "rgb I" [3 2 1] "point3 from" [0 4 0]
    AttributeEnd
    """
    a = load_pbrt(write(tmp_path, named, "named.pbrt"))
    b = load_pbrt(write(tmp_path, explicit, "explicit.pbrt"))
    for field in ("spheres", "triangles", "lights", "camera", "materials"):
        leaves_equal(getattr(a, field), getattr(b, field))


def _light_from(tmp_path, name, body, behind):
    camera = ("LookAt 0 0 -4  0 0 0  0 1 0" if behind else "LookAt 0 0 4  0 0 0  0 1 0")
    text = f"""Scale -1 1 1
{camera}
Camera "perspective" "float fov" [ 20 ]
Film "rgb" "integer xresolution" [ 8 ] "integer yresolution" [ 8 ]
WorldBegin
AttributeBegin
  AreaLightSource "diffuse" "rgb L" [1 0.5 0.25]
  {body}
AttributeEnd
"""
    (tmp_path / name).write_text(text)
    return load_pbrt(tmp_path / name)


def test_reverse_orientation_turns_a_one_sided_area_light(tmp_path):
    """A one-sided area light quad wound towards +z lights +z; under ReverseOrientation, or a
    handedness-swapping Scale, it lights -z (pbrt-v4: reverseOrientation ^
    transformSwapsHandedness): the path tracer sees L from that side and black from the other
    (the quad fills the view, so every pixel is the emitted radiance, with no noise)."""
    L = np.array([1, 0.5, 0.25])
    cases = {"plain": (_quad_mesh(), False),
             "reversed": ("ReverseOrientation\n  " + _quad_mesh(), True),
             "rewound": (_quad_mesh(reverse_winding=True), True),
             "mirrored": ("Scale 1 1 -1\n  " + _quad_mesh(), True),
             "both": ("ReverseOrientation\n  Scale 1 1 -1\n  " + _quad_mesh(), False)}
    for name, (body, lights_minus_z) in cases.items():
        for behind in (False, True):
            scene = _light_from(tmp_path, f"{name}{behind}.pbrt", body, behind)
            img = np.asarray(jgi.render(scene, "pt", spp=2, seed=0))
            want = L if behind == lights_minus_z else np.zeros(3)
            np.testing.assert_allclose(img.reshape(-1, 3), np.broadcast_to(want, (64, 3)),
                                       rtol=1e-6, atol=1e-7, err_msg=f"{name}, behind={behind}")


def test_sphere_area_light_facing_inwards_is_refused(tmp_path):
    body = 'ReverseOrientation\nAreaLightSource "diffuse" "rgb L" [1 1 1]\nShape "sphere"'
    with pytest.raises(SceneError, match="sphere with inward normals"):
        load_pbrt(write(tmp_path, body))


def test_spectra_become_what_pbrts_rgb_film_sees(tmp_path):
    """"spectrum" / "blackbody" values: lights at luminance 1 times their scale (pbrt divides
    a light spectrum by its photometric integral), reflectances under D65, .spd files next
    to the scene file, named illuminants."""
    from jgi.scene import spectra
    (tmp_path / "lamp.spd").write_text("# lamp\n400 0.5\n550 2\n700 4\n")
    body = """
    LightSource "point" "spectrum I" "stdillum-A" "float scale" 3 "point3 from" [0 3 0]
    LightSource "point" "spectrum I" "lamp.spd" "point3 from" [0 3 1]
    LightSource "point" "blackbody I" 2700 "point3 from" [0 3 2]
    LightSource "uniform" "spectrum L" [300 1  800 1]
    Material "diffuse" "spectrum reflectance" [400 0.2  550 0.5  700 0.8]
    Shape "sphere" "float radius" 0.5
    """
    s = load_pbrt(write(tmp_path, body))
    emission = np.stack([np.asarray(getattr(s.lights.emission, c)) for c in "xyz"], 1)
    want = [3 * spectra.pbrt_rgb(spectra.pbrt_named("stdillum-A"), True),
            spectra.pbrt_rgb(([400.0, 550, 700], [0.5, 2, 4]), True),
            spectra.pbrt_rgb(spectra.pbrt_blackbody(2700.0), True),
            spectra.pbrt_rgb(([300.0, 800], [1.0, 1]), True)]
    np.testing.assert_allclose(emission, np.stack(want), rtol=1e-6)
    diffuse = np.array([float(getattr(s.materials.diffuse, c)[-1]) for c in "xyz"])
    np.testing.assert_allclose(
        diffuse, spectra.pbrt_rgb(([400.0, 550, 700], [0.2, 0.5, 0.8]), False), rtol=1e-6)


def _texture_rows(scene):
    t = scene.materials.textures
    return {"color0": np.stack([np.asarray(getattr(t.color0, c)) for c in "xyz"], 1),
            "color1": np.stack([np.asarray(getattr(t.color1, c)) for c in "xyz"], 1),
            "to_uv": np.asarray(t.to_uv), "kind": np.asarray(t.kind),
            "width": np.asarray(t.width), "height": np.asarray(t.height)}


def test_scale_and_mix_textures_fold_into_one_texture(tmp_path):
    """pbrt-v4's "scale" and "mix" of constants, a checkerboard or an imagemap load as the
    texture (or constant) they equal: pbrt's scale texture of a checkerboard is the
    checkerboard of scaled colours; of an imagemap, the imagemap with "float scale"; a mix
    of two constants is their weighted sum."""
    from jgi.core.imageio import write_exr
    rng = np.random.default_rng(1)
    write_exr(tmp_path / "grid.exr", rng.uniform(0, 1, (4, 6, 3)).astype(np.float32))
    quad = ('Shape "trianglemesh" "point3 P" [0 0 0 1 0 0 1 1 0 0 1 0] '
            '"point2 uv" [0 0 1 0 1 1 0 1] "integer indices" [0 1 2 0 2 3]')
    folded = f"""
    Texture "checks" "spectrum" "checkerboard" "float uscale" 4 "float vscale" 2
      "rgb tex1" [0.2 0.4 0.6] "rgb tex2" [0.8 0.1 0]
    Texture "half" "spectrum" "scale" "texture tex" "checks" "float scale" 0.5
    Texture "grey" "spectrum" "mix" "float tex1" 0.2 "rgb tex2" [0.6 0.4 1] "float amount" 0.25
    Texture "toward" "spectrum" "mix" "texture tex1" "half" "rgb tex2" [1 1 1]
      "float amount" 0.5
    Texture "grid" "spectrum" "imagemap" "string filename" "grid.exr" "string encoding" "linear"
    Texture "dim" "spectrum" "scale" "texture tex" "grid" "float scale" 0.3
    Material "diffuse" "texture reflectance" "toward"
    {quad}
    Material "diffuse" "texture reflectance" "dim"
    {quad}
    Material "diffuse" "texture reflectance" "grey"
    {quad}
    """
    explicit = f"""
    Texture "checks" "spectrum" "checkerboard" "float uscale" 4 "float vscale" 2
      "rgb tex1" [0.2 0.4 0.6] "rgb tex2" [0.8 0.1 0]
    Texture "half" "spectrum" "checkerboard" "float uscale" 4 "float vscale" 2
      "rgb tex1" [0.1 0.2 0.3] "rgb tex2" [0.4 0.05 0]
    Texture "grey" "spectrum" "checkerboard" "rgb tex1" [0.3 0.25 0.4] "rgb tex2" [0 0 0]
    Texture "toward" "spectrum" "checkerboard" "float uscale" 4 "float vscale" 2
      "rgb tex1" [0.55 0.6 0.65] "rgb tex2" [0.7 0.525 0.5]
    Texture "grid" "spectrum" "imagemap" "string filename" "grid.exr" "string encoding" "linear"
    Texture "dim" "spectrum" "imagemap" "string filename" "grid.exr" "string encoding" "linear"
      "float scale" 0.3
    Material "diffuse" "texture reflectance" "toward"
    {quad}
    Material "diffuse" "texture reflectance" "dim"
    {quad}
    Material "diffuse" "rgb reflectance" [0.3 0.25 0.4]
    {quad}
    """
    a = load_pbrt(write(tmp_path, folded, "folded.pbrt"))
    b = load_pbrt(write(tmp_path, explicit, "explicit.pbrt"))
    # the explicit file's extra "grey" checkerboard row stands where "folded" has none
    ra, rb = _texture_rows(a), _texture_rows(b)
    keep = [0, 1, 3, 4, 5]
    for key in ra:
        np.testing.assert_allclose(ra[key], rb[key][keep], rtol=1e-6, err_msg=key)
    np.testing.assert_allclose(np.asarray(a.materials.textures.atlas),
                               np.asarray(b.materials.textures.atlas), rtol=1e-6)
    leaves_equal(a.materials.diffuse, b.materials.diffuse)
    leaves_equal(a.triangles, b.triangles)


@pytest.mark.parametrize("body, message", [
    ('Texture "c" "spectrum" "checkerboard"\n'
     'Texture "g" "spectrum" "imagemap" "string filename" "g.exr"\n'
     'Texture "m" "spectrum" "mix" "texture tex1" "c" "texture tex2" "g"',
     'Texture "m" \\("mix"\\): its operands are a checker and a image texture'),
    ('Texture "c" "spectrum" "checkerboard"\n'
     'Texture "m" "spectrum" "mix" "texture tex1" "c" "texture amount" "c"',
     "'amount' is supported as a \"float\" constant only"),
    ('Texture "m" "spectrum" "scale" "texture tex" "nope"',
     "'tex' names texture 'nope', which is not a spectrum texture defined before it"),
])
def test_unsupported_scale_and_mix_are_refused(tmp_path, body, message):
    from jgi.core.imageio import write_exr
    write_exr(tmp_path / "g.exr", np.ones((2, 2, 3), np.float32))
    path = write(tmp_path, body)
    with pytest.raises(SceneError, match=message) as e:
        load_pbrt(path)
    assert f"{path}:" in str(e.value)


def test_included_files_resolve_names_against_the_main_file(tmp_path):
    """pbrt-v4 resolves every relative file name (ResolveFilename) against the main scene
    file's folder, also inside Included files in other folders."""
    from jgi.scene import spectra
    (tmp_path / "spds").mkdir()
    (tmp_path / "spds" / "lamp.spd").write_text("400 1\n700 3\n")
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "lights.pbrt").write_text(
        'LightSource "point" "spectrum I" "spds/lamp.spd"\nInclude "parts/more.pbrt"\n')
    (tmp_path / "parts" / "more.pbrt").write_text('LightSource "point" "blackbody I" 4000\n')
    s = load_pbrt(write(tmp_path, 'Include "parts/lights.pbrt"'))
    emission = np.stack([np.asarray(getattr(s.lights.emission, c)) for c in "xyz"], 1)
    np.testing.assert_allclose(emission, np.stack([
        spectra.pbrt_rgb(([400.0, 700], [1.0, 3]), True),
        spectra.pbrt_rgb(spectra.pbrt_blackbody(4000.0), True)]), rtol=1e-6)


# --- participating media: MakeNamedMedium / MediumInterface -----------------------------------

FOG_HEADER = """
MakeNamedMedium "fog" "string type" "homogeneous" "rgb sigma_a" [0.1 0.2 0.05]
  "rgb sigma_s" [0.3 0.4 0.5] "float scale" 2 "float g" 0.4
MakeNamedMedium "unused" "string type" "homogeneous"
MediumInterface "" "fog"
LookAt 0 1 5  0 0 0  0 1 0
Camera "perspective" "float fov" [ 40 ]
Film "rgb" "integer xresolution" [ 8 ] "integer yresolution" [ 6 ]
WorldBegin
"""


def test_the_medium_outside_the_camera_fills_the_scene(tmp_path):
    """pbrt-v4's camera medium is the outside medium of the MediumInterface current at Camera;
    shapes that are no transition (inside = outside, the default "" "") keep a ray's medium,
    so the fog fills the scene: sigma_t = (sigma_a + sigma_s) scale, albedo sigma_s / sigma_t."""
    p = tmp_path / "fog.pbrt"
    p.write_text(FOG_HEADER + 'Shape "sphere" "float radius" 0.5\n'
                 'AttributeBegin\n MediumInterface "unused" "unused"\n'
                 ' Shape "sphere" "float radius" 0.2\nAttributeEnd\n'
                 'LightSource "point" "rgb I" [1 1 1] "point3 from" [0 2 0]\n')
    m = load_pbrt(p).medium
    np.testing.assert_allclose([float(c) for c in m.sigma_t], [0.8, 1.2, 1.1], rtol=1e-6)
    # glass with fog outside and vacuum inside bounds a medium: vacuum, bounded by the ball
    p.write_text(FOG_HEADER + 'Material "dielectric"\nShape "sphere" "float radius" 0.5\n')
    glass = load_pbrt(p)
    assert glass.has_bounded_media
    assert [float(c[0]) for c in glass.bounded_media.sigma_t] == [0.0, 0.0, 0.0]
    row = int(glass.spheres.material[0])
    assert (int(glass.medium_interfaces.interior[row]),
            int(glass.medium_interfaces.exterior[row])) == (1, 0)
    np.testing.assert_allclose([float(c) for c in m.albedo], [0.3 / 0.4, 0.4 / 0.6, 0.5 / 0.55],
                               rtol=1e-6)
    assert float(m.g) == pytest.approx(0.4)
    # a camera in vacuum: media declared on shapes that are no transition change nothing
    q = tmp_path / "vacuum.pbrt"
    q.write_text(FOG_HEADER.replace('MediumInterface "" "fog"', "")
                 + 'MediumInterface "fog"\nShape "sphere" "float radius" 0.5\n')
    assert not load_pbrt(q).has_medium
    # pbrt-v4's defaults: sigma_a = sigma_s = 1, g = 0; one name sets inside and outside
    r = tmp_path / "defaults.pbrt"
    r.write_text(FOG_HEADER.replace('MediumInterface "" "fog"', 'MediumInterface "unused"'))
    m = load_pbrt(r).medium
    np.testing.assert_allclose([float(c) for c in m.sigma_t], [2, 2, 2])
    np.testing.assert_allclose([float(c) for c in m.albedo], [0.5, 0.5, 0.5])
    assert float(m.g) == 0.0


def test_pbrt_shapes_bound_media(tmp_path):
    """A Shape whose MediumInterface differs inside and outside bounds media as in pbrt-v4:
    inside on the side away from its normal; the camera's medium is jgi's scene medium and
    other homogeneous media become bounded ones, a uniformgrid the grid bounded by shapes.
    Refused by name: a second such grid, an area light whose outside is not the camera's
    medium."""
    head = FOG_HEADER.replace('MakeNamedMedium "unused" "string type" "homogeneous"',
                              'MakeNamedMedium "milk" "string type" "homogeneous" '
                              '"rgb sigma_a" [0.1 0.1 0.1] "rgb sigma_s" [2 3 4] "float g" 0.3')
    p = tmp_path / "milk.pbrt"
    p.write_text(head + 'Material "dielectric"\nMediumInterface "milk" "fog"\n'
                 'Shape "sphere" "float radius" 0.5\n'
                 'Shape "trianglemesh" "point3 P" [-1 -1 -1  1 -1 -1  1 -1 1]\n'
                 '  "integer indices" [0 1 2]\n')
    scene = load_pbrt(p)
    np.testing.assert_allclose([float(c[0]) for c in scene.bounded_media.sigma_t], [2.1, 3.1, 4.1],
                               rtol=1e-6)
    assert float(scene.bounded_media.g[0]) == pytest.approx(0.3)
    faces = scene.medium_interfaces
    for table in (scene.spheres, scene.triangles):
        row = int(table.material[0])
        assert (int(faces.interior[row]), int(faces.exterior[row])) == (1, 0)
    # a uniformgrid inside glass: a grid bounded by shapes (id after the
    # homogeneous ones), its densities x fastest, box p0 p1, pbrt's zero border
    smoke = ('MakeNamedMedium "smoke" "string type" "uniformgrid" "float density" [1 2 3 4 5 6] '
             '"integer nx" 3 "integer ny" 2 "integer nz" 1 "point3 p0" [-1 -1 -1] '
             '"point3 p1" [1 1 1] "rgb sigma_a" [1 1 1] "rgb sigma_s" [1 2 3] "float g" 0.5\n')
    grid = tmp_path / "grid.pbrt"
    grid.write_text(head + smoke + 'Material "dielectric"\nMediumInterface "smoke" "fog"\n'
                    'Shape "sphere" "float radius" 0.5\nMediumInterface "milk" "fog"\n'
                    'Shape "sphere" "float radius" 0.2\n')
    scene = load_pbrt(grid)
    (g,) = scene.bounded_grids
    assert g is not None and g.border == "zero" and float(g.g) == pytest.approx(0.5)
    np.testing.assert_array_equal(np.asarray(g.density), np.arange(1, 7).reshape(1, 2, 3))
    np.testing.assert_allclose([float(c) for c in g.sigma_t], [2, 3, 4], rtol=1e-6)
    np.testing.assert_allclose([float(c) for c in g.albedo], [0.5, 2 / 3, 0.75], rtol=1e-6)
    rows = [int(r) for r in scene.spheres.material]
    faces = scene.medium_interfaces
    assert [(int(faces.interior[r]), int(faces.exterior[r])) for r in rows] == [(2, 0), (1, 0)]
    twice = tmp_path / "twice.pbrt"
    twice.write_text(head + smoke + smoke.replace('"smoke"', '"soot"')
                     + 'Material "dielectric"\nMediumInterface "smoke" "fog"\n'
                     'Shape "sphere" "float radius" 0.5\nMediumInterface "soot" "fog"\n'
                     'Shape "sphere" "float radius" 0.2\n')
    two = load_pbrt(twice)   # two grids bounded by shapes: ids 1 and 2, in the order used
    assert len(two.bounded_grids) == 2
    faces = two.medium_interfaces
    assert [int(faces.interior[int(r)]) for r in two.spheres.material] == [1, 2]
    lamp = tmp_path / "lamp.pbrt"
    lamp.write_text(head + 'AreaLightSource "diffuse" "rgb L" [1 1 1]\n'
                    'MediumInterface "fog" "milk"\nShape "sphere" "float radius" 0.5\n')
    with pytest.raises(SceneError, match=r'lamp\.pbrt:12: Shape "sphere" is an area light with '
                                         r'outside medium "milk"'):
        load_pbrt(lamp)


def test_a_pbrt_fog_renders_like_the_same_fog_built_in_jgi(tmp_path):
    """The medium is all that MediumInterface adds: the scene equals the fog-free file's scene
    leaf for leaf but for ``medium``, and its render is finite and dimmer (the fog attenuates
    and scatters light out of view; the estimator itself is tested against Mitsuba 3)."""
    p = tmp_path / "fog.pbrt"
    p.write_text(FOG_HEADER + 'Material "diffuse" "rgb reflectance" [0.5 0.5 0.5]\n'
                 'Shape "trianglemesh" "point3 P" [-2 0 -2  2 0 -2  2 0 2  -2 0 2]\n'
                 '  "integer indices" [0 1 2  0 2 3]\n'
                 'LightSource "point" "rgb I" [3 3 3] "point3 from" [0 2 0]\n')
    ours = load_pbrt(p)
    without = tmp_path / "nofog.pbrt"
    without.write_text(p.read_text().replace('MediumInterface "" "fog"', ""))
    b_scene = load_pbrt(without)
    leaves_equal(eqx.tree_at(lambda s: s.medium, ours, None, is_leaf=lambda x: x is None),
                 b_scene)
    a = jgi.render(ours, "pt", spp=4, seed=3, max_depth=3)
    c = jgi.render(b_scene, "pt", spp=4, seed=3, max_depth=3)
    assert np.isfinite(a).all() and a.mean() > 0
    assert a.mean() < 0.9 * c.mean()      # the fog attenuates what the camera sees


@pytest.mark.parametrize("body, message", [
    ('MakeNamedMedium "g" "string type" "rgbgrid" "float density" [1]',
     'medium type "rgbgrid" is not supported yet; supported: homogeneous, uniformgrid'),
    ('MakeNamedMedium "g" "string type" "uniformgrid" "float temperature" [1]',
     r"emissive media \(temperature\)"),
    ('MakeNamedMedium "g" "string type" "uniformgrid" "float sigma_t" [1]',
     "unknown parameter 'sigma_t'; uniformgrid takes: type, density"),
    ('MakeNamedMedium "g" "string type" "smoke"', 'medium type "smoke" is unknown'),
    ('MakeNamedMedium "g" "string type" "homogeneous" "float density" 1',
     "unknown parameter 'density'"),
    ('MakeNamedMedium "g" "string type" "homogeneous" "string preset" "Ketchup"',
     '"preset"'),
    ('MakeNamedMedium "g" "string type" "homogeneous" "rgb Le" [1 1 1]', "emissive media"),
    ('MakeNamedMedium "g" "rgb sigma_a" [1 1 1]', 'needs "string type"'),
    ('MediumInterface "nothing" ""\nMaterial "dielectric"\nShape "sphere"',
     r'MediumInterface names medium "nothing", which no MakeNamedMedium defines'),
    ('MediumInterface\nShape "sphere"', "MediumInterface expects one or two quoted"),
])
def test_unsupported_media_name_file_line_and_what_is_allowed(tmp_path, body, message):
    path = write(tmp_path, 'MakeNamedMedium "fog" "string type" "homogeneous"\n' + body)
    with pytest.raises(SceneError, match=message) as e:
        load_pbrt(path)
    assert f"{path}:" in str(e.value)


def test_a_camera_medium_nobody_defines_is_refused(tmp_path):
    p = tmp_path / "x.pbrt"
    p.write_text(FOG_HEADER.replace('MediumInterface "" "fog"', 'MediumInterface "" "mist"'))
    with pytest.raises(SceneError, match=r'x\.pbrt:7: the Camera\'s MediumInterface names '
                                         r'medium "mist".*defined: fog, unused'):
        load_pbrt(p)


GRID_HEADER = """MakeNamedMedium "unused" "string type" "homogeneous"
MediumInterface "" "{camera_medium}"
LookAt 0 1 5  0 0 0  0 1 0
Camera "perspective" "float fov" [ 40 ]
Film "rgb" "integer xresolution" [ 8 ] "integer yresolution" [ 6 ]
WorldBegin
AttributeBegin
{transform}
MakeNamedMedium "smoke" "string type" "uniformgrid" "integer nx" 3 "integer ny" 2 "integer nz" 2
  "float density" [ {density} ] "point3 p0" [ -1 0 -1 ] "point3 p1" [ 1 1 1 ]
  "rgb sigma_a" [ 0.2 0.3 0.4 ] "rgb sigma_s" [ 0.6 0.5 0.4 ] "float scale" 2 "float g" 0.3
AttributeEnd
Material "diffuse"
Shape "trianglemesh" "point3 P" [-2 -0.5 -2  2 -0.5 -2  2 -0.5 2  -2 -0.5 2]
  "integer indices" [0 1 2  0 2 3]
LightSource "point" "rgb I" [3 3 3] "point3 from" [0 2 0]
"""


def _grid_file(tmp_path, transform="", density=None, camera_medium="smoke"):
    """A uniformgrid medium outside the Camera (pbrt-v4's camera medium), defined in the world
    block under ``transform`` (pbrt-v4 resolves medium names after parsing, as jgi does)."""
    density = " ".join(map(str, range(1, 13))) if density is None else density
    p = tmp_path / "smoke.pbrt"
    p.write_text(GRID_HEADER.format(transform=transform, density=density,
                                    camera_medium=camera_medium))
    return p


def test_uniformgrid_is_a_grid_medium_with_pbrts_zero_border(tmp_path):
    """pbrt-v4's uniformgrid as the camera's medium: densities x fastest ([nz, ny, nx]), the box
    p0 p1 through the transform current at MakeNamedMedium (a scale and a translation, and a
    mirrored x that reverses the samples), extinction (sigma_a + sigma_s) scale d, albedo
    sigma_s / sigma_t, pbrt's zero border; it renders, finite and dimmer than an empty grid."""
    m = load_pbrt(_grid_file(tmp_path)).medium
    assert m.border == "zero"
    np.testing.assert_array_equal(np.asarray(m.density), 2 * np.arange(1, 13).reshape(2, 2, 3))
    np.testing.assert_allclose([float(c) for c in m.lo], [-1, 0, -1])
    np.testing.assert_allclose([float(c) for c in m.hi], [1, 1, 1])
    np.testing.assert_allclose([float(c) for c in m.sigma_t], [0.8, 0.8, 0.8], rtol=1e-6)
    np.testing.assert_allclose([float(c) for c in m.albedo], [0.75, 0.625, 0.5], rtol=1e-6)
    assert float(m.g) == pytest.approx(0.3)
    t = load_pbrt(_grid_file(tmp_path, "Translate 0 1 0\nScale -2 1 0.5")).medium
    np.testing.assert_allclose([float(c) for c in t.lo], [-2, 1, -0.5])
    np.testing.assert_allclose([float(c) for c in t.hi], [2, 2, 0.5])
    np.testing.assert_array_equal(np.asarray(t.density), np.asarray(m.density)[:, :, ::-1])
    # rotated: the box p0 p1 stays in the grid's frame, which the transform maps to the world
    r = load_pbrt(_grid_file(tmp_path, "Translate 0 1 0\nRotate 30 0 1 0")).medium
    np.testing.assert_allclose([float(c) for c in r.lo], [-1, 0, -1])
    np.testing.assert_array_equal(np.asarray(r.density), np.asarray(m.density))
    corner = np.asarray(xf.translate([0, 1, 0]) @ xf.rotate([0, 1, 0], 30) @ [1, 1, 1, 1])
    np.testing.assert_allclose(np.asarray(r.to_local) @ corner, [1, 1, 1], atol=1e-6)
    a = jgi.render(load_pbrt(_grid_file(tmp_path)), "pt", spp=4, seed=3, max_depth=3)
    c = jgi.render(load_pbrt(_grid_file(tmp_path, density=" ".join(["0"] * 12))), "pt", spp=4,
                   seed=3, max_depth=3)
    assert np.isfinite(a).all() and 0 < a.mean() < 0.95 * c.mean()


@pytest.mark.parametrize("transform, density, message", [
    ("Scale 1 0 1", None, "projects or flattens the grid; allowed: an invertible affine"),
    ("", "1 2 3", r'"density" has 3 values; nx ny nz = 3 x 2 x 2 needs 12'),
])
def test_unsupported_uniformgrids_name_file_line_and_what_is_allowed(tmp_path, transform,
                                                                     density, message):
    path = _grid_file(tmp_path, transform, density)
    with pytest.raises(SceneError, match=message) as e:
        load_pbrt(path)
    assert f"{path}:" in str(e.value)


BOX = ('Shape "trianglemesh" "point3 P" [-1 -1 -1  1 -1 -1  1 1 -1  -1 1 -1  -1 -1 1  1 -1 1  '
       '1 1 1  -1 1 1]\n  "integer indices" [0 2 1 0 3 2  4 5 6 4 6 7  0 1 5 0 5 4  2 3 7 2 7 6  '
       '1 2 6 1 6 5  0 4 7 0 7 3]\n')


def test_an_interface_box_holding_a_medium_is_a_grid_medium(tmp_path):
    """pbrt-v4's usual volume: a box-shaped mesh or a sphere with the "interface" material (no
    surface), a medium inside and vacuum outside: jgi's grid medium cut to the shape (a
    homogeneous medium a constant grid; a uniformgrid its own box, cut to the mesh's where it
    differs); an interface shape without a transition is left out; the camera may sit inside
    with the inside medium as its own, and several such shapes are several volumes. Refused by
    name: a mesh that is no box, a partial sphere, the camera inside in another medium, outside
    in a medium."""
    head = FOG_HEADER.replace('MediumInterface "" "fog"\n', "")
    grid = ('MakeNamedMedium "smoke" "string type" "uniformgrid" "float density" [1 2 3 4 5 6 7 8]'
            ' "integer nx" 2 "integer ny" 2 "integer nz" 2 "point3 p0" [-1 -1 -1]'
            ' "point3 p1" [1 1 1]\n')
    body = ('AttributeBegin\n Translate 0 0.5 0\n Scale 0.5 0.5 0.5\n Material "interface"\n'
            ' MediumInterface "{inside}" ""\n ' + BOX + 'AttributeEnd\n'
            'Material "interface"\nShape "sphere" "float radius" 3\n'
            'LightSource "point" "rgb I" [1 1 1] "point3 from" [0 2 0]\n')
    p = tmp_path / "box.pbrt"
    p.write_text(head + body.format(inside="fog"))
    fog = load_pbrt(p)
    assert fog.has_grid_medium and fog.spheres.count == 0 and fog.triangles.count == 0
    assert fog.medium.to_local is None and fog.medium.clip is None
    np.testing.assert_allclose([float(c) for c in fog.medium.lo], [-0.5, 0.0, -0.5], atol=1e-6)
    np.testing.assert_allclose([float(c) for c in fog.medium.hi], [0.5, 1.0, 0.5], atol=1e-6)
    # extinction (sigma_a + sigma_s) scale density: the scale 2 folded into the density
    np.testing.assert_allclose(np.asarray(fog.medium.density), 2.0)
    np.testing.assert_allclose([float(c) for c in fog.medium.sigma_t], [0.4, 0.6, 0.55],
                               rtol=1e-6)
    # a uniformgrid made in the box's frame (MakeNamedMedium under the same transform)
    p.write_text(head + body.format(inside="smoke").replace(
        ' Material "interface"\n', ' ' + grid + ' Material "interface"\n', 1))
    smoke = load_pbrt(p)
    assert np.asarray(smoke.medium.density).shape == (2, 2, 2) and smoke.medium.clip is None
    # a uniformgrid over another box: cut to the mesh's (its top face y = 1 at the clip's 1)
    p.write_text(head + body.format(inside="smoke").replace("AttributeBegin\n",
                                                            grid + "AttributeBegin\n"))
    cut = load_pbrt(p).medium
    assert cut.clip is not None and cut.clip_shape == "cube"
    np.testing.assert_allclose(np.asarray(cut.clip) @ [0.2, 1.0, 0.1, 1.0], [0.4, 1.0, 0.2],
                               atol=1e-6)
    # a turned box and a stretched sphere (an ellipsoid, as pbrt intersects it in object space)
    p.write_text(head + body.format(inside="fog").replace("Scale 0.5",
                                                          "Rotate 40 1 0 1\n Scale 0.5"))
    turned = load_pbrt(p).medium
    assert turned.to_local is not None and turned.clip is None
    world = xf.translate([0, 0.5, 0]) @ xf.rotate([1, 0, 1], 40) @ xf.scale(0.5)
    np.testing.assert_allclose(np.asarray(turned.to_local) @ world @ [1, -1, 1, 1], [1, -1, 1],
                               atol=1e-5)
    p.write_text(head + body.format(inside="fog").replace(BOX, 'Shape "sphere"\n').replace(
        "Scale 0.5 0.5 0.5", "Scale 0.5 0.3 0.4"))
    ball = load_pbrt(p).medium
    assert ball.clip is not None and ball.clip_shape == "sphere"
    np.testing.assert_allclose(np.asarray(ball.clip) @ [0.0, 0.8, 0.0, 1.0], [0, 1, 0], atol=1e-6)
    # the camera (at 0 1 5) inside a big ball of fog that is its medium
    # (the header's MediumInterface would make the unit sphere after the box bound fog too)
    inside = body.format(inside="fog").replace(BOX, 'Shape "sphere"\n').replace(
        "Scale 0.5 0.5 0.5", "Scale 9 9 9").replace('Shape "sphere" "float radius" 3\n', "")
    p.write_text(FOG_HEADER + inside)
    assert load_pbrt(p).medium.clip_shape == "sphere"
    # and a box of fog far behind it: two volumes, the camera in one with its medium
    box_alone = body.format(inside="fog").split('Material "interface"\nShape')[0]
    p.write_text(FOG_HEADER + inside + box_alone.replace("Translate 0 0.5 0",
                                                         "Translate 0 0.5 -12"))
    two = load_pbrt(p).medium
    assert [v.clip_shape for v in two] == ["sphere", "cube"]
    np.testing.assert_allclose([float(c) for c in two[1].lo], [-0.5, 0.0, -12.5], atol=1e-6)
    cases = {
        "not a box": (body.format(inside="fog").replace("-1 1 1]", "-1 1 0.5]"),
                      "its vertices are not the corners of a box"),
        "partial sphere": (body.format(inside="fog").replace(
            BOX, 'Shape "sphere" "float zmax" 0.5\n'), r'a partial sphere \("zmax"\)'),
        "cylinder": (body.format(inside="fog").replace(BOX, 'Shape "cylinder"\n'),
                     'Shape "cylinder" with the "interface" material bounding media'),
        "camera inside": (inside, "the camera lies inside the sphere but its medium is \"\""),
    }
    for name, (text, message) in cases.items():
        p.write_text(head + text)
        with pytest.raises(SceneError, match=message):
            load_pbrt(p)
    p.write_text(FOG_HEADER + box_alone)
    with pytest.raises(SceneError, match='the camera lies outside the box in medium "fog"'):
        load_pbrt(p)
