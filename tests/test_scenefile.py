"""TOML scene files: equivalence with the built-ins, every shape/light/transform form, and
named errors for bad input."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np
import pytest

import jgi
from jgi.scene import SceneError

ROOT = Path(__file__).resolve().parents[1]

CAMERA = """
[camera]
position = [0, 1, 5]
look_at = [0, 0, 0]
width = 8
height = 6
"""
MAT = """
[[material]]
name = "m"
type = "diffuse"
diffuse = 0.5
"""


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_cornell_box_toml_equals_the_builtin():
    a = jgi.load_scene(ROOT / "scenes" / "cornell_box.toml")
    b = jgi.scenes.cornell_box()
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb
    for x, y in zip(la, lb):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_shapes_lights_and_transforms(tmp_path):
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    text = CAMERA + MAT + """
[[material]]
name = "glass"
type = "dielectric"
ior = 1.33

[[shape]]
type = "sphere"
material = "glass"
center = [1, 2, 3]
radius = 0.5
transform = { scale = 2, translate = [1, 0, 0] }

[[shape]]
type = "quad"
material = "m"
origin = [0, 0, 0]
edge_u = [1, 0, 0]
edge_v = [0, 1, 1]
emission = 3

[[shape]]
type = "rectangle"
material = "m"
transform = { rotate = [{ axis = [0, 0, 1], angle = 90 }, { axis = [1, 0, 0], angle = 90 }], translate = [0, 5, 0] }

[[shape]]
type = "mesh"
material = "m"
file = "tri.obj"
transform = { matrix = [[1, 0, 0, 0], [0, 1, 0, 7], [0, 0, 1, 0], [0, 0, 0, 1]] }

[[light]]
type = "point"
position = [0, 3, 0]
intensity = [1, 2, 3]

[[light]]
type = "spot"
position = [0, 4, 0]
target = [0, 0, 0]
intensity = 2
cutoff = 25
falloff = 20

[[light]]
type = "directional"
direction = [0, -1, 0]
irradiance = 1

[[light]]
type = "environment"
radiance = 0.1
"""
    s = jgi.load_scene(write(tmp_path, text))
    np.testing.assert_allclose([float(s.spheres.center.x[0]), float(s.spheres.center.y[0]),
                                float(s.spheres.center.z[0])], [3, 4, 6])
    np.testing.assert_allclose(float(s.spheres.radius[0]), 1.0)
    assert s.quads.count == 1 and s.rects.count == 1 and s.triangles.count == 1
    np.testing.assert_allclose(float(s.triangles.v0.y[0]), 7.0)
    # the rotated rectangle: z-rotation then x-rotation maps the z = 0 plane to y = const
    np.testing.assert_allclose(float(s.rects.plane[0]), 5.0, atol=1e-6)
    assert s.rects.axis_counts == (0, 1, 0)
    assert sorted(s.lights.kinds) == [0, 3, 4, 5, 6]
    np.testing.assert_allclose(float(s.lights.cos_total[2]), np.cos(np.radians(25)), rtol=1e-6)
    assert s.camera.width == 8 and s.camera.height == 6


BAD = [
    ("[camera]\nposition = [0, 0, 1]\n", "camera.look_at: missing"),
    (CAMERA + "[[material]]\nname = 'm'\ntype = 'plastic'\n", r"material\[0\].type: unknown type 'plastic'; allowed: diffuse, mirror, dielectric, phong"),
    (CAMERA + MAT + "[[shape]]\ntype = 'sphere'\nmaterial = 'm'\ncenter = [0, 0, 0]\nradius = -1\n", r"shape\[0\].radius: must be >= 0"),
    (CAMERA + MAT + "[[shape]]\ntype = 'sphere'\nmaterial = 'm'\ncenter = [0, 0]\nradius = 1\n", r"shape\[0\].center: expected 3 numbers"),
    (CAMERA + MAT + "[[shape]]\ntype = 'sphere'\nmaterial = 'm'\ncenter = [0, 0, 0]\nradius = 'big'\n", r"shape\[0\].radius: expected a finite number"),
    (CAMERA + MAT + "[[shape]]\ntype = 'sphere'\nmaterial = 'm'\ncenter = [0, 0, 0]\nradius = nan\n", r"shape\[0\].radius: expected a finite number"),
    (CAMERA + MAT + "[[shape]]\ntype = 'sphere'\nmaterial = 'gold'\ncenter = [0, 0, 0]\nradius = 1\n", r"shape\[0\].material: unknown material 'gold'; defined: m"),
    (CAMERA + MAT + "[[shape]]\ntype = 'sphere'\nmaterial = 'm'\ncentre = [0, 0, 0]\nradius = 1\n", r"shape\[0\].centre: unknown key; allowed:"),
    (CAMERA + MAT + "[[shape]]\ntype = 'torus'\nmaterial = 'm'\n", r"shape\[0\].type: unknown type 'torus'; allowed: sphere, quad, rectangle, cube, mesh"),
    (CAMERA + MAT + "[[shape]]\ntype = 'quad'\nmaterial = 'm'\norigin = [0,0,0]\nedge_u = [1,0,0]\nedge_v = [2,0,0]\n", r"shape\[0\]: edge_u and edge_v are parallel"),
    (CAMERA + MAT + "[[shape]]\ntype = 'cube'\nmaterial = 'm'\ntransform = { scale = 0 }\n", r"shape\[0\].transform: the transform is degenerate"),
    (CAMERA + MAT + "[[shape]]\ntype = 'cube'\nmaterial = 'm'\ntransform = { shear = 1 }\n", r"shape\[0\].transform.shear: unknown key"),
    (CAMERA + MAT + "[[shape]]\ntype = 'mesh'\nmaterial = 'm'\nfile = 'missing.obj'\n", r"shape\[0\].file.*does not exist"),
    (CAMERA + "[[light]]\ntype = 'area'\n", r"light\[0\].type: unknown type 'area'; allowed: point, spot, directional, environment"),
    (CAMERA + "[[light]]\ntype = 'point'\nposition = [0, 1, 0]\n", r"light\[0\].intensity: missing"),
    (CAMERA + "[[light]]\ntype = 'point'\nposition = [0, 1, 0]\nintensity = [-1, 1, 1]\n", r"light\[0\].intensity: colours must be non-negative"),
    (CAMERA + "[[light]]\ntype = 'environment'\nradiance = 1\n[[light]]\ntype = 'environment'\nradiance = 1\n", r"light\[1\]: only one environment light"),
    (CAMERA.replace("width = 8", "width = 0"), r"camera.width: width and height must be positive"),
    (CAMERA.replace("[camera]", "[camera]\nfov = 200"), r"camera.fov: must be in \(0, 180\)"),
    (CAMERA + "[renderer]\nspp = 3\n", r"renderer: unknown table or key; allowed: camera, light, material, name, shape"),
    (CAMERA + "[[shape]\n", r"TOML syntax error"),
]


@pytest.mark.parametrize("text, message", BAD)
def test_bad_scene_files_name_the_file_the_key_and_what_is_allowed(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(SceneError, match=message) as e:
        jgi.load_scene(path)
    assert str(path) in str(e.value)


def test_unknown_source_and_formats(tmp_path):
    with pytest.raises(SceneError, match="not a built-in scene"):
        jgi.load_scene("no_such_scene")
    p = tmp_path / "x.xml"
    p.write_text("<scene version='3.0.0'><sensor type='perspective'/></scene>")
    assert jgi.load_scene(p).camera.width == 768  # Mitsuba's default film


def test_a_loaded_scene_renders(tmp_path):
    scene = jgi.load_scene(ROOT / "scenes" / "cornell_box.toml").with_resolution(8, 8)
    img = jgi.render(scene, "pt", spp=2)
    assert img.shape == (8, 8, 3) and np.all(np.isfinite(img)) and img.mean() > 0
