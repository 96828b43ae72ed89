"""pbrt-v4 import: scene data against jgi's builder, unit conventions, errors, orientation."""

from __future__ import annotations

import math

import numpy as np
import pytest

import jgi
from jgi.scene import SceneBuilder, SceneError
from jgi.scene.importers import load_pbrt
from tests.conftest import assert_agree
from tests.test_import_mitsuba import leaves_equal

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


@pytest.mark.parametrize("body, message", [
    ('Shape "disk" "float radius" 1',
     'Shape "disk" is not supported.*sphere, trianglemesh, plymesh'),
    ('Material "coateddiffuse"', "material 'coateddiffuse' is not supported"),
    ('Material "conductor" "spectrum eta" "metal-Cu-eta"', "spectrum values are not supported"),
    ('Material "conductor"', "perfect mirror"),
    ('Material "dielectric" "float roughness" 0.1', "roughness 0"),
    ('LightSource "goniometric"', 'LightSource "goniometric" is not supported'),
    ('LightSource "infinite" "string filename" "sky.exr"', "environment map"),
    ('AreaLightSource "diffuse" "bool twosided" true', "two-sided"),
    ('ObjectBegin "x"', "directive 'ObjectBegin' is not supported"),
    ('NamedMaterial "nope"', 'unknown named material "nope"'),
    ('Shape "trianglemesh" "point3 P" [0 0 0 1 0 0 0 1 0] "normal N" [0 0 1 0 0 1 0 0 1]',
     "shading normals"),
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
