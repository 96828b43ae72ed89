"""TOML scene files (jgi/scene/files.py, docs/scene-format.md).

* ``scenes/cornell_box.toml`` is the built-in ``cornell_box()`` leaf for leaf;
* every shape, light, material and transform form gives the arrays computed independently here
  (rotations from scipy, meshes from the vertex lists written to the test files);
* every class of bad input is a SceneError naming the file, the key path and what is allowed;
* one tiny render of a loaded scene is finite.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import jax
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import jgi
from jgi.scene import (
    AREA_QUAD,
    AREA_SPHERE,
    AREA_TRIANGLE,
    DIELECTRIC,
    DIFFUSE,
    DIRECTIONAL,
    ENVIRONMENT,
    MIRROR,
    PHONG,
    PLASTIC,
    POINT,
    SPOT,
    SceneError,
)
from jgi.scene.builder import IOR_AIR, IOR_POLYPROPYLENE
from jgi.scene.files import SceneWarning
from jgi.scene.tables import (
    BECKMANN,
    GGX,
    NAMED_METALS,
    ROUGH_CONDUCTOR,
    ROUGH_DIELECTRIC,
    ROUGH_PLASTIC,
)

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
LIGHT = """
[[light]]
type = "point"
position = [0, 3, 0]
intensity = 1
"""
HEAD = CAMERA + MAT + LIGHT  # a valid scene to append shapes to


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def load(tmp_path, text, name="s.toml"):
    return jgi.load_scene(write(tmp_path, text, name))


def rot(axis, deg):
    """Independent reference rotation (scipy), right-handed about ``axis``."""
    a = np.asarray(axis, float)
    return Rotation.from_rotvec(np.radians(deg) * a / np.linalg.norm(a)).as_matrix()


def v3(v, i=None):
    a = np.stack([np.asarray(v.x), np.asarray(v.y), np.asarray(v.z)], -1)
    return a if i is None else a[i]


# ------------------------------------------------------------------------------------------------
# Example files
# ------------------------------------------------------------------------------------------------

def test_material_preview_toml_equals_the_mitsuba_file():
    """scenes/material_preview.toml and .xml: the TOML microfacet types and the Mitsuba
    importer give the same scene, leaf for leaf (Mitsuba's defaults spelt out in the TOML)."""
    a = jgi.load_scene(ROOT / "scenes" / "material_preview.toml", resolution=8)
    b = jgi.load_scene(ROOT / "scenes" / "material_preview.xml", resolution=8)
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb
    for x, y in zip(la, lb):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6, atol=1e-6)
    assert a.materials.kinds == (DIFFUSE, ROUGH_CONDUCTOR, ROUGH_PLASTIC)


def test_cornell_box_toml_equals_the_builtin():
    a = jgi.load_scene(ROOT / "scenes" / "cornell_box.toml")
    b = jgi.scenes.cornell_box()
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb  # same structure and the same static fields (compared explicitly below)
    assert len(la) == len(lb) > 50
    for x, y in zip(la, lb):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype and x.shape == y.shape
        assert np.allclose(x, y, rtol=1e-6, atol=1e-7)
    assert a.name == b.name == "cornell_box"
    assert (a.camera.width, a.camera.height) == (b.camera.width, b.camera.height) == (256, 256)
    assert a.rects.axis_counts == b.rects.axis_counts
    assert a.materials.kinds == b.materials.kinds
    assert a.lights.kinds == b.lights.kinds and a.lights.environment == b.lights.environment
    assert (a.rects.count, a.boxes.count, a.quads.count) == (6, 2, 0)


def test_mesh_demo_loads_the_generated_mesh():
    path = ROOT / "scenes" / "mesh_demo.toml"
    mesh_file = ROOT / "scenes" / "meshes" / "torus.ply"
    assert mesh_file.stat().st_size < 200_000
    s = jgi.load_scene(path)
    mesh = trimesh.load(mesh_file, process=False)
    assert s.triangles.count == len(mesh.faces) == 2304
    # the torus transform: translate * rotate_y(35) * rotate_x(-15) * scale(0.5)
    m = rot([0, 1, 0], 35) @ rot([1, 0, 0], -15) * 0.5
    v0 = mesh.vertices[mesh.faces[:, 0]] @ m.T + [-0.6, 0.66, -0.2]
    np.testing.assert_allclose(v3(s.triangles.v0), v0, atol=1e-5)
    assert set(s.materials.kinds) == {DIFFUSE, PHONG, DIELECTRIC}
    assert set(s.lights.kinds) == {AREA_QUAD, SPOT}


def test_the_documented_example_loads(tmp_path):
    """The complete example in docs/scene-format.md is a valid scene with what it describes."""
    doc = (ROOT / "docs" / "scene-format.md").read_text()
    example = doc.split("## A complete example")[1].split("```toml")[1].split("```")[0]
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "torus.ply").write_bytes(
        (ROOT / "scenes" / "meshes" / "torus.ply").read_bytes())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = load(tmp_path, example)
    assert s.name == "example" and s.resolution == (320, 240)
    assert (s.rects.count, s.spheres.count, s.boxes.count, s.triangles.count) == (2, 1, 1, 2304)
    assert set(s.materials.kinds) == {DIFFUSE, MIRROR, DIELECTRIC, PHONG}
    np.testing.assert_array_equal(np.asarray(s.lights.kind),
                                  [AREA_QUAD, POINT, SPOT, DIRECTIONAL, ENVIRONMENT])
    np.testing.assert_allclose(v3(s.lights.normal, 0), [0, -1, 0])  # the light faces down


def test_a_loaded_scene_renders():
    scene = jgi.load_scene(ROOT / "scenes" / "mesh_demo.toml", width=16, height=16)
    assert scene.resolution == (16, 16)
    img = jgi.render(scene, "pt", spp=2, progress=False)
    assert img.shape == (16, 16, 3) and np.all(np.isfinite(img)) and img.mean() > 0


# ------------------------------------------------------------------------------------------------
# Each shape, transform, material, light and camera form
# ------------------------------------------------------------------------------------------------

def test_sphere_with_uniform_transform_and_emission(tmp_path):
    s = load(tmp_path, HEAD + """
[[shape]]
type = "sphere"
material = "m"
center = [1, 2, 3]
radius = 0.5
emission = [1, 2, 3]
transform = { scale = 2, rotate = { axis = [0, 0, 1], angle = 90 }, translate = [1, 0, 0] }
""")
    expected = rot([0, 0, 1], 90) @ (2 * np.array([1.0, 2, 3])) + [1, 0, 0]  # = (-3, 2, 6)
    np.testing.assert_allclose(v3(s.spheres.center, 0), expected, atol=1e-6)
    np.testing.assert_allclose(float(s.spheres.radius[0]), 1.0)
    k = int(s.spheres.emitter[0])
    assert int(s.lights.kind[k]) == AREA_SPHERE
    np.testing.assert_allclose(v3(s.lights.emission, k), [1, 2, 3])
    np.testing.assert_allclose(float(s.lights.area[k]), 4 * np.pi, rtol=1e-6)


def test_quad_transform_normal_and_one_sided_emission(tmp_path):
    s = load(tmp_path, HEAD + """
[[shape]]
type = "quad"
material = "m"
origin = [0, 0, 0]
edge_u = [1, 0, 0]
edge_v = [0, 1, 1]
emission = 3
transform = { translate = [0, 0, 2] }
""")
    assert s.quads.count == 1 and s.rects.count == 0
    np.testing.assert_allclose(v3(s.quads.origin, 0), [0, 0, 2])
    np.testing.assert_allclose(v3(s.quads.edge_u, 0), [1, 0, 0])
    np.testing.assert_allclose(v3(s.quads.edge_v, 0), [0, 1, 1])
    n = np.cross([1, 0, 0], [0, 1, 1]) / np.sqrt(2)
    np.testing.assert_allclose(v3(s.quads.normal, 0), n, atol=1e-6)
    k = int(s.quads.emitter[0])
    assert int(s.lights.kind[k]) == AREA_QUAD
    np.testing.assert_allclose(v3(s.lights.normal, k), n, atol=1e-6)
    np.testing.assert_allclose(float(s.lights.area[k]), np.sqrt(2), rtol=1e-6)
    np.testing.assert_allclose(v3(s.lights.emission, k), [3, 3, 3])


def test_rectangle_translate_rotate_scale_corners(tmp_path):
    """translate * rotate * scale: scale first (non-uniform, so the order is visible), then the
    listed rotations in order, then the translation; checked at all four corners."""
    s = load(tmp_path, HEAD + """
[[shape]]
type = "rectangle"
material = "m"
transform = { translate = [1, 2, 3], rotate = [{ axis = [0, 0, 1], angle = 30 }, """
    """{ axis = [1, 1, 0], angle = 50 }], scale = [2, 0.5, 7] }
""")
    assert s.quads.count == 1  # a general orientation: not an axis-aligned rectangle
    M = rot([1, 1, 0], 50) @ rot([0, 0, 1], 30) @ np.diag([2, 0.5, 7])
    corners = np.array([[-1, -1, 0], [1, -1, 0], [-1, 1, 0], [1, 1, 0]], float) @ M.T + [1, 2, 3]
    o, u, v = v3(s.quads.origin, 0), v3(s.quads.edge_u, 0), v3(s.quads.edge_v, 0)
    np.testing.assert_allclose(np.array([o, o + u, o + v, o + u + v]), corners, atol=1e-5)
    # the rectangle's +z normal, rotated (scale keeps it along z)
    n = M @ [0, 0, 1]
    np.testing.assert_allclose(v3(s.quads.normal, 0), n / np.linalg.norm(n), atol=1e-6)


def test_rotation_list_order_and_single_rotation(tmp_path):
    """rotate = [A, B] applies A first; it differs from [B, A]."""
    text = HEAD + """
[[shape]]
type = "quad"
material = "m"
origin = [0, 0, 0]
edge_u = [1, 0, 0]
edge_v = [0, 1, 0]
transform = {{ rotate = {r} }}
"""
    ab = load(tmp_path, text.format(r="[{ axis = [0, 0, 1], angle = 90 }, "
                                      "{ axis = [1, 0, 0], angle = 90 }]"))
    ba = load(tmp_path, text.format(r="[{ axis = [1, 0, 0], angle = 90 }, "
                                      "{ axis = [0, 0, 1], angle = 90 }]"))
    one = load(tmp_path, text.format(r="{ axis = [0, 0, 1], angle = 90 }"))
    A, B = rot([0, 0, 1], 90), rot([1, 0, 0], 90)
    for s, M, axis in ((ab, B @ A, 1), (ba, A @ B, 0), (one, A, 2)):
        assert s.rects.count == 1 and s.rects.axis_counts[axis] == 1
        np.testing.assert_allclose(v3(s.rects.normal, 0), M @ [0, 0, 1], atol=1e-6)
    # [A, B]: edge_u = x -> y -> z and edge_v = y -> -x -> -x: in the plane y = 0, x in [-1, 0]
    # and z in [0, 1]
    r = ab.rects
    np.testing.assert_allclose([float(r.plane[0]), float(r.lo_a[0]), float(r.hi_a[0]),
                                float(r.lo_b[0]), float(r.hi_b[0])], [0, -1, 0, 0, 1], atol=1e-6)


def test_matrix_transform_on_cube_and_emissive_cube(tmp_path):
    s = load(tmp_path, HEAD + """
[[shape]]
type = "cube"
material = "m"
transform = { matrix = [[0, -2, 0, 1], [1, 0, 0, 2], [0, 0, 3, 3], [0, 0, 0, 1]] }

[[shape]]
type = "cube"
material = "m"
emission = 1
transform = { translate = [5, 0, 0], scale = 0.5 }
""")
    assert s.boxes.count == 1
    np.testing.assert_allclose(v3(s.boxes.center, 0), [1, 2, 3])
    # columns of the matrix: x -> (0, 1, 0), y -> (-2, 0, 0), z -> (0, 0, 3)
    np.testing.assert_allclose(v3(s.boxes.half, 0), [1, 2, 3])
    np.testing.assert_allclose(np.abs(v3(s.boxes.axis_u, 0)), [0, 1, 0], atol=1e-7)
    np.testing.assert_allclose(np.abs(v3(s.boxes.axis_v, 0)), [1, 0, 0], atol=1e-7)
    # the emissive cube: six outward-facing quad emitters of area 1 around (5, 0, 0)
    assert s.rects.count == 6 and sum(s.rects.axis_counts) == 6
    em = np.asarray(s.rects.emitter)
    assert np.all(em >= 0) and np.all(np.asarray(s.lights.kind)[em] == AREA_QUAD)
    np.testing.assert_allclose(np.asarray(s.lights.area)[em], 1.0, rtol=1e-6)
    centers = np.asarray(s.lights.p0.x)[em] + 0.5 * (np.asarray(s.lights.e1.x)[em]
                                                     + np.asarray(s.lights.e2.x)[em])
    normals_x = np.asarray(s.lights.normal.x)[em]
    # faces at x = 5.5 point to +x, at x = 4.5 to -x
    assert (np.all(normals_x[np.isclose(centers, 5.5)] == 1)
            and np.all(normals_x[np.isclose(centers, 4.5)] == -1))


OBJ = """# a unit square (one quad face, triangulated by trimesh) and a triangle
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 2
vn 0 0 1
f 1 2 3 4
f 1 2 5
"""
PLY = """ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
element face 2
property list uchar int vertex_indices
end_header
0 0 0
1 0 0
1 1 0
0 0 2
3 0 1 2
3 0 1 3
"""


def triangle_set(t):
    v0 = v3(t.v0)
    pts = np.stack([v0, v0 + v3(t.edge1), v0 + v3(t.edge2)], 1)
    return sorted(tuple(np.round(sorted(map(tuple, tri)), 5).ravel()) for tri in pts)


@pytest.mark.parametrize("fmt", ["obj", "ply", "stl", "glb"])
def test_mesh_files(tmp_path, fmt):
    d = tmp_path / "meshes"
    d.mkdir()
    if fmt == "obj":
        (d / "m.obj").write_text(OBJ)  # its vertex normal is accepted and ignored
        tris = [[0, 1, 2], [0, 2, 3], [0, 1, 4]]
        verts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 2]], float)
    elif fmt == "ply":
        (d / "m.ply").write_text(PLY)
        tris = [[0, 1, 2], [0, 1, 3]]
        verts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 2]], float)
    else:
        verts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 2]], float)
        tris = [[0, 1, 2], [0, 3, 1]]
        trimesh.Trimesh(verts, tris, process=False).export(d / f"m.{fmt}")
    s = load(tmp_path, HEAD + f"""
[[shape]]
type = "mesh"
file = "meshes/m.{fmt}"
material = "m"
emission = 2
transform = {{ translate = [0, 1, 0], scale = 3 }}
""")
    assert s.triangles.count == len(tris)
    world = verts * 3 + [0, 1, 0]
    ref = jgi.SceneBuilder()
    ref.material("m", "diffuse")
    ref.mesh(world, tris, "m")
    ref.camera((0, 0, 5), (0, 0, 0))
    assert triangle_set(s.triangles) == triangle_set(ref.build().triangles)
    em = np.asarray(s.triangles.emitter)
    assert np.all(np.asarray(s.lights.kind)[em] == AREA_TRIANGLE)
    areas = [0.5 * np.linalg.norm(np.cross(world[b] - world[a], world[c] - world[a]))
             for a, b, c in tris]
    np.testing.assert_allclose(sorted(np.asarray(s.lights.area)[em]), sorted(areas), rtol=1e-5)


def test_materials_and_defaults(tmp_path):
    s = load(tmp_path, CAMERA + LIGHT + """
[[material]]
name = "d"
type = "diffuse"

[[material]]
name = "mir"
type = "mirror"
specular = [0.9, 0.8, 0.7]

[[material]]
name = "glass"
type = "dielectric"
ior = 1.33

[[material]]
name = "ph"
type = "phong"
diffuse = 0.2
specular = [0.5, 0.6, 0.7]
exponent = 80

[[material]]
name = "mirror_default"
type = "mirror"

[[material]]
name = "glass_default"
type = "dielectric"

[[material]]
name = "phong_default"
type = "phong"
specular = 0.3
exponent = 0
""")
    mt = s.materials
    np.testing.assert_array_equal(np.asarray(mt.kind), [DIFFUSE, MIRROR, DIELECTRIC, PHONG,
                                                        MIRROR, DIELECTRIC, PHONG])
    np.testing.assert_allclose(v3(mt.diffuse), [[0.5] * 3, [0] * 3, [0] * 3, [0.2] * 3,
                                                [0] * 3, [0] * 3, [0] * 3], atol=1e-7)
    np.testing.assert_allclose(v3(mt.specular), [[0] * 3, [0.9, 0.8, 0.7], [1] * 3, [0.5, 0.6, 0.7],
                                                 [1] * 3, [1] * 3, [0.3] * 3], atol=1e-7)
    np.testing.assert_allclose(np.asarray(mt.ior)[[2, 5]], [1.33, 1.5], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(mt.exponent)[[3, 6]], [80, 0])


def test_microfacet_materials_and_defaults(tmp_path):
    """The rough types and the conductor: keys as the builder's, defaults as documented."""
    s = load(tmp_path, CAMERA + LIGHT + """
[[material]]
name = "gold"
type = "roughconductor"
metal = "Au"
alpha = 0.2

[[material]]
name = "brushed"
type = "roughconductor"
eta = [0.2, 0.9, 1.1]
k = [3.9, 2.4, 2.2]
specular = 0.8
alpha_u = 0.05
alpha_v = 0.3
distribution = "beckmann"

[[material]]
name = "chrome"
type = "conductor"
metal = "Cr"

[[material]]
name = "perfect"
type = "conductor"

[[material]]
name = "frosted"
type = "roughdielectric"
ior = 1.33
alpha = 0.15

[[material]]
name = "frosted_default"
type = "roughdielectric"

[[material]]
name = "plastic"
type = "roughplastic"
diffuse = [0.1, 0.2, 0.6]
int_ior = 1.6
alpha = 0.3
distribution = "beckmann"
nonlinear = true

[[material]]
name = "plastic_default"
type = "roughplastic"

[[material]]
name = "glass"
type = "dielectric"
int_ior = 1.5
ext_ior = 1.25

[[material]]
name = "smooth_plastic"
type = "plastic"
diffuse = [0.1, 0.2, 0.6]
int_ior = 1.6
nonlinear = true

[[material]]
name = "smooth_plastic_default"
type = "plastic"
""")
    mt = s.materials
    np.testing.assert_array_equal(np.asarray(mt.kind), [
        ROUGH_CONDUCTOR, ROUGH_CONDUCTOR, MIRROR, MIRROR, ROUGH_DIELECTRIC, ROUGH_DIELECTRIC,
        ROUGH_PLASTIC, ROUGH_PLASTIC, DIELECTRIC, PLASTIC, PLASTIC])
    rough = [0, 1, 4, 5, 6, 7]
    np.testing.assert_allclose(np.asarray(mt.alpha_u)[rough], [0.2, 0.05, 0.15, 0.1, 0.3, 0.1],
                               rtol=1e-6)
    np.testing.assert_allclose(np.asarray(mt.alpha_v)[rough], [0.2, 0.3, 0.15, 0.1, 0.3, 0.1],
                               rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(mt.distribution)[rough],
                                  [GGX, BECKMANN, GGX, GGX, BECKMANN, GGX])
    eta, k = v3(mt.eta), v3(mt.k)
    np.testing.assert_allclose(eta[[0, 1, 2, 3]], [NAMED_METALS["Au"][0], [0.2, 0.9, 1.1],
                                                   NAMED_METALS["Cr"][0], NAMED_METALS["none"][0]],
                               rtol=1e-6)
    np.testing.assert_allclose(k[[0, 1, 2, 3]], [NAMED_METALS["Au"][1], [3.9, 2.4, 2.2],
                                                 NAMED_METALS["Cr"][1], NAMED_METALS["none"][1]],
                               rtol=1e-6)
    np.testing.assert_allclose(v3(mt.specular)[[0, 1, 2, 4, 6]], [[1] * 3, [0.8] * 3, [1] * 3,
                                                                  [1] * 3, [1] * 3], atol=1e-7)
    np.testing.assert_allclose(np.asarray(mt.ior)[[4, 5, 6, 7, 8]],
                               [1.33, 1.5, 1.6 / IOR_AIR, IOR_POLYPROPYLENE / IOR_AIR, 1.2],
                               rtol=1e-6)
    np.testing.assert_allclose(v3(mt.diffuse)[[6, 7]], [[0.1, 0.2, 0.6], [0.5] * 3], atol=1e-7)
    np.testing.assert_array_equal(np.asarray(mt.nonlinear)[[6, 7]], [True, False])
    # smooth plastic: roughplastic's parameters without the roughness, the same defaults;
    # Ri is Mitsuba's fdr_int (its fit of the coating's diffuse reflectance from inside)
    np.testing.assert_allclose(np.asarray(mt.ior)[[9, 10]],
                               [1.6 / IOR_AIR, IOR_POLYPROPYLENE / IOR_AIR], rtol=1e-6)
    np.testing.assert_allclose(v3(mt.diffuse)[[9, 10]], [[0.1, 0.2, 0.6], [0.5] * 3], atol=1e-7)
    np.testing.assert_allclose(v3(mt.specular)[[9, 10]], [[1] * 3] * 2, atol=1e-7)
    np.testing.assert_array_equal(np.asarray(mt.nonlinear)[[9, 10]], [True, False])
    np.testing.assert_allclose(np.asarray(mt.internal_reflectance)[10], 0.5904790, rtol=1e-6)


def test_lights(tmp_path):
    s = load(tmp_path, CAMERA + """
[[light]]
type = "point"
position = [0, 3, 0]
intensity = [1, 2, 3]

[[light]]
type = "spot"
position = [0, 4, 0]
target = [0, 0, 3]
intensity = 2
cutoff = 25
falloff = 20

[[light]]
type = "spot"
position = [0, 4, 0]
target = [0, 0, 0]
intensity = 2

[[light]]
type = "directional"
direction = [0, -2, 0]
irradiance = 1.5

[[light]]
type = "environment"
radiance = 0.1
""")
    L = s.lights
    np.testing.assert_array_equal(np.asarray(L.kind), [POINT, SPOT, SPOT, DIRECTIONAL, ENVIRONMENT])
    np.testing.assert_allclose(v3(L.p0, 0), [0, 3, 0])
    np.testing.assert_allclose(v3(L.emission), [[1, 2, 3], [2] * 3, [2] * 3, [1.5] * 3, [0.1] * 3],
                               rtol=1e-6)
    np.testing.assert_allclose(v3(L.direction, 1), [0, -0.8, 0.6], atol=1e-6)
    np.testing.assert_allclose(float(L.cos_total[1]), np.cos(np.radians(25)), rtol=1e-6)
    np.testing.assert_allclose(float(L.cos_falloff[1]), np.cos(np.radians(20)), rtol=1e-6)
    # defaults: cutoff 30 degrees, falloff 0.75 cutoff
    np.testing.assert_allclose(float(L.cos_total[2]), np.cos(np.radians(30)), rtol=1e-6)
    np.testing.assert_allclose(float(L.cos_falloff[2]), np.cos(np.radians(22.5)), rtol=1e-6)
    np.testing.assert_allclose(v3(L.direction, 3), [0, -1, 0])
    assert L.environment == 4


@pytest.mark.parametrize("axis, w, h, tx, ty", [
    ("x", 8, 4, 1.0, 0.5), ("y", 8, 4, 2.0, 1.0), ("smaller", 8, 4, 2.0, 1.0),
    ("smaller", 4, 8, 1.0, 2.0)])
def test_camera_fov_axis(tmp_path, axis, w, h, tx, ty):
    s = load(tmp_path, MAT + LIGHT + f"""
[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
up = [0, 1, 0]
fov = 90
fov_axis = "{axis}"
width = {w}
height = {h}
""")
    c = s.camera
    assert (c.width, c.height) == (w, h)
    np.testing.assert_allclose(v3(c.forward), [0, 0, -1], atol=1e-7)
    # tan(90 / 2) = 1 along the fov axis, scaled by the aspect ratio along the other
    np.testing.assert_allclose(np.linalg.norm(v3(c.right)), tx, rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(v3(c.up)), ty, rtol=1e-6)
    np.testing.assert_allclose(v3(c.up) / ty, [0, 1, 0], atol=1e-6)


def test_camera_defaults_and_scene_name(tmp_path):
    s = load(tmp_path, MAT + LIGHT + '[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n',
             name="my_scene.toml")
    assert s.name == "my_scene" and s.resolution == (256, 256)
    np.testing.assert_allclose(np.linalg.norm(v3(s.camera.up)), np.tan(np.radians(20)), rtol=1e-6)
    assert load(tmp_path, 'name = "named"\n' + HEAD).name == "named"


def test_load_scene_options(tmp_path):
    assert jgi.load_scene("cornell_box", resolution=16).resolution == (16, 16)
    with pytest.raises(SceneError, match="unknown option 'spp'; allowed: resolution"):
        jgi.load_scene("cornell_box", spp=4)
    p = write(tmp_path, HEAD)  # 8 x 6 film
    assert jgi.load_scene(p, resolution=16).resolution == (16, 12)
    assert jgi.load_scene(p, height=3).resolution == (4, 3)
    assert jgi.load_scene(p, width=5, height=5).resolution == (5, 5)
    with pytest.raises(SceneError, match="unknown option 'spp' for a scene file; allowed: "
                                         "resolution, width, height"):
        jgi.load_scene(p, spp=4)
    with pytest.raises(SceneError, match="width: expected a positive integer"):
        jgi.load_scene(p, width=0)


def test_unknown_source_and_other_formats(tmp_path):
    with pytest.raises(SceneError, match="not a built-in scene .*cornell_box.*not a scene file"):
        jgi.load_scene("no_such_scene")
    p = tmp_path / "x.xml"
    p.write_text("<scene version='3.0.0'><sensor type='perspective'/></scene>")
    assert jgi.load_scene(p).camera.width == 768  # Mitsuba's default film


def test_warnings_for_a_scene_without_light_and_degenerate_mesh_triangles(tmp_path):
    with pytest.warns(SceneWarning, match="no light"):
        load(tmp_path, CAMERA + MAT)
    (tmp_path / "d.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n")
    with pytest.warns(SceneWarning, match="1 zero-area triangles"):
        s = load(tmp_path, HEAD + '[[shape]]\ntype = "mesh"\nfile = "d.obj"\nmaterial = "m"\n')
    assert s.triangles.count == 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load(tmp_path, HEAD)  # a valid scene warns about nothing


# ------------------------------------------------------------------------------------------------
# Bad input: SceneError naming the file, the key path and what is allowed
# ------------------------------------------------------------------------------------------------

def sphere(**kw):
    d = dict(material="'m'", center="[0, 0, 0]", radius="1")
    d.update(kw)
    return (HEAD + "[[shape]]\ntype = 'sphere'\n"
            + "".join(f"{k} = {v}\n" for k, v in d.items() if v is not None))


def quad(**kw):
    d = dict(material="'m'", origin="[0, 0, 0]", edge_u="[1, 0, 0]", edge_v="[0, 1, 0]")
    d.update(kw)
    return (HEAD + "[[shape]]\ntype = 'quad'\n"
            + "".join(f"{k} = {v}\n" for k, v in d.items() if v is not None))


def cube(transform):
    return HEAD + f"[[shape]]\ntype = 'cube'\nmaterial = 'm'\ntransform = {transform}\n"


def material(body):
    return CAMERA + LIGHT + "[[material]]\nname = 'x'\n" + body


def light(body):
    return CAMERA + "[[light]]\n" + body


def camera(**kw):
    d = dict(position="[0, 1, 5]", look_at="[0, 0, 0]")
    d.update(kw)
    return (MAT + LIGHT + "[camera]\n"
            + "".join(f"{k} = {v}\n" for k, v in d.items() if v is not None))


def mesh(file):
    return HEAD + f"[[shape]]\ntype = 'mesh'\nmaterial = 'm'\nfile = '{file}'\n"


# (scene text, key path, what is allowed): each must appear in the message, after the file name
BAD = {
    # unknown tables and keys (typos), with a suggestion where one is close
    "top-level table": (HEAD + "[renderer]\nspp = 3\n", "renderer",
                        "allowed: name, camera, texture, material, shape, light"),
    "top-level typo": (HEAD + "[[materials]]\nname = 'y'\n", "materials",
                       "did you mean 'material'?"),
    "camera key": (camera(lookat="[0, 0, 0]"), "camera.lookat", "did you mean 'look_at'?"),
    "material key for its type": (material("type = 'mirror'\nior = 1.5\n"), "material[0].ior",
                                  "allowed: name, one_sided, opacity, specular, type"),
    "shape key": (sphere(centre="[0, 0, 0]", center=None), "shape[0].centre",
                  "allowed: center, emission, exterior, interior, material, radius, transform, "
                  "type"),
    "light key": (light("type = 'point'\nposition = [0, 1, 0]\nintensity = 1\npower = 3\n"),
                  "light[0].power", "allowed: intensity, position, type"),
    "transform key": (cube("{ shear = 1 }"), "shape[0].transform.shear",
                      "allowed: matrix, translate, rotate, scale"),
    "rotate key": (cube("{ rotate = { axis = [0, 1, 0], degrees = 3 } }"),
                   "shape[0].transform.rotate.degrees", "allowed: angle, axis"),
    # missing required keys
    "no camera": (MAT + LIGHT, "camera", "a [camera] table with at least position and look_at"),
    "camera.look_at": (camera(look_at=None), "camera.look_at", "required keys: position, look_at"),
    "material name": (CAMERA + LIGHT + "[[material]]\ntype = 'diffuse'\n", "material[0].name",
                      "missing"),
    "missing material type": (CAMERA + LIGHT + "[[material]]\nname = 'x'\n", "material[0].type",
                      "allowed: diffuse, mirror, dielectric, phong"),
    "phong exponent": (material("type = 'phong'\nspecular = 0.5\n"), "material[0].exponent",
                       "required keys: name, specular, exponent"),
    "shape material": (sphere(material=None), "shape[0].material", "missing"),
    "sphere radius": (sphere(radius=None), "shape[0].radius",
                      "required keys: type, material, center, radius"),
    "quad edge": (quad(edge_v=None), "shape[0].edge_v", "missing"),
    "mesh file key": (HEAD + "[[shape]]\ntype = 'mesh'\nmaterial = 'm'\n", "shape[0].file",
                      "missing"),
    "light intensity": (light("type = 'point'\nposition = [0, 1, 0]\n"), "light[0].intensity",
                        "required keys: position, intensity"),
    "rotate angle": (cube("{ rotate = [{ axis = [0, 1, 0] }] }"),
                     "shape[0].transform.rotate[0].angle", "missing"),
    # wrong types and vector lengths
    "string for a number": (sphere(radius="'big'"), "shape[0].radius",
                            "expected a number, got 'big' (a string)"),
    "boolean for a number": (sphere(radius="true"), "shape[0].radius", "expected a number"),
    "short vector": (sphere(center="[0, 0]"), "shape[0].center", "expected 3 numbers [x, y, z]"),
    "rgb of 4": (sphere(emission="[1, 1, 1, 1]"), "shape[0].emission",
                 "expected 3 numbers [r, g, b] or one number"),
    "vector of strings": (camera(position="['0', '1', '5']"), "camera.position",
                          "expected 3 numbers"),
    "float width": (camera(width="2.5"), "camera.width", "expected an integer"),
    "transform not a table": (cube("3"), "shape[0].transform", "expected a table"),
    "matrix shape": (cube("{ matrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]] }"),
                     "shape[0].transform.matrix", "expected 4 rows of 4 numbers"),
    "matrix strings": (cube("{ matrix = [['a', 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], "
                            "[0, 0, 0, 1]] }"),
                       "shape[0].transform.matrix", "expected 4 rows of 4 numbers"),
    "single [material]": (CAMERA + LIGHT + "[material]\nname = 'x'\ntype = 'diffuse'\n", "material",
                          "write [[material]]"),
    "name not a string": ("name = 3\n" + HEAD, "name", "expected a string"),
    "type not a string": (HEAD + "[[shape]]\ntype = 3\n", "shape[0].type",
                          "allowed: sphere, quad, rectangle, cube, mesh"),
    # non-finite numbers
    "nan radius": (sphere(radius="nan"), "shape[0].radius", "expected a finite number"),
    "inf in a vector": (sphere(center="[0, inf, 0]"), "shape[0].center", "expected finite numbers"),
    "inf in a matrix": (cube("{ matrix = [[inf, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], "
                             "[0, 0, 0, 1]] }"),
                        "shape[0].transform.matrix", "expected finite numbers"),
    "nan angle": (cube("{ rotate = { axis = [0, 1, 0], angle = nan } }"),
                  "shape[0].transform.rotate.angle", "expected a finite number"),
    # out-of-range values
    "negative radius": (sphere(radius="-1"), "shape[0].radius", "must be > 0"),
    "zero radius": (sphere(radius="0"), "shape[0].radius", "must be > 0"),
    "negative emission": (sphere(emission="[1, -1, 1]"), "shape[0].emission",
                          "must be non-negative"),
    "albedo above 1": (material("type = 'diffuse'\ndiffuse = [0.5, 1.5, 0.5]\n"),
                       "material[0].diffuse", "reflectance must be in [0, 1]"),
    "phong energy": (material("type = 'phong'\ndiffuse = 0.6\nspecular = 0.6\nexponent = 10\n"),
                     "material[0].specular", "diffuse + specular must be <= 1"),
    "negative exponent": (material("type = 'phong'\nspecular = 0.5\nexponent = -1\n"),
                          "material[0].exponent", "must be >= 0"),
    "zero ior": (material("type = 'dielectric'\nior = 0\n"), "material[0].ior", "must be > 0"),
    "zero alpha": (material("type = 'roughconductor'\nalpha = 0\n"), "material[0].alpha",
                   "must be > 0"),
    "negative alpha_u": (material("type = 'roughdielectric'\nalpha_u = -0.1\nalpha_v = 0.1\n"),
                         "material[0].alpha_u", "must be > 0"),
    "alpha and alpha_u": (material("type = 'roughconductor'\nalpha = 0.1\nalpha_u = 0.1\n"
                                   "alpha_v = 0.2\n"), "material[0].alpha",
                          "either alpha (isotropic) or alpha_u and alpha_v"),
    "alpha_u alone": (material("type = 'roughconductor'\nalpha_u = 0.1\n"),
                      "material[0].alpha_v", "missing: alpha_u and alpha_v go together"),
    "unknown metal": (material("type = 'roughconductor'\nmetal = 'gold'\n"),
                      "material[0].metal",
                      "unknown metal 'gold' (did you mean 'Au'?); allowed: none, a-C, Ag, Al"),
    "metal and eta": (material("type = 'conductor'\nmetal = 'Au'\neta = 0.2\nk = 3\n"),
                      "material[0].metal", "either metal or eta and k"),
    "eta without k": (material("type = 'conductor'\neta = 0.2\n"), "material[0].k",
                      "missing: eta and k go together"),
    "unknown distribution": (material("type = 'roughplastic'\ndistribution = 'phong'\n"),
                             "material[0].distribution",
                             "unknown distribution 'phong'; allowed: ggx, beckmann"),
    "anisotropic roughplastic": (material("type = 'roughplastic'\nalpha_u = 0.1\n"
                                          "alpha_v = 0.2\n"), "material[0].alpha_u",
                                 "unknown key for type 'roughplastic'"),
    "roughness on a conductor": (material("type = 'conductor'\nmetal = 'Au'\nalpha = 0.1\n"),
                                 "material[0].alpha", "unknown key for type 'conductor'"),
    "ior on a conductor": (material("type = 'roughconductor'\nior = 1.5\n"), "material[0].ior",
                           "unknown key for type 'roughconductor'"),
    "nonlinear not a boolean": (material("type = 'roughplastic'\nnonlinear = 1\n"),
                                "material[0].nonlinear", "expected true or false"),
    "metal not a string": (material("type = 'conductor'\nmetal = 3\n"), "material[0].metal",
                           "expected a string"),
    "equal plastic indices": (material("type = 'roughplastic'\nint_ior = 1.3\next_ior = 1.3\n"),
                              "material[0].int_ior", "allowed: ior != 1, int_ior != ext_ior"),
    "ior and int_ior": (material("type = 'roughdielectric'\nior = 1.5\nint_ior = 1.5\n"),
                        "material[0].ior", "either ior (inside / outside) or int_ior"),
    "zero ext_ior": (material("type = 'dielectric'\next_ior = 0\n"), "material[0].ext_ior",
                     "must be > 0"),
    "conductor specular above 1": (material("type = 'conductor'\nspecular = 1.2\n"),
                                   "material[0].specular", "reflectance must be in [0, 1]"),
    "negative k": (material("type = 'conductor'\neta = 0.2\nk = -1\n"), "material[0].k",
                   "must be non-negative"),
    "glass transmittance above 1": (material("type = 'dielectric'\ntransmittance = [1, 1.3, 1]\n"),
                                    "material[0].transmittance",
                                    "transmittance must be in [0, 1]"),
    "transmittance on a mirror": (material("type = 'mirror'\ntransmittance = 0.5\n"),
                                  "material[0].transmittance", "unknown key for type 'mirror'"),
    "fov": (camera(fov="200"), "camera.fov", "must be in (0, 180) degrees"),
    "width": (camera(width="0"), "camera.width", "must be a positive number of pixels"),
    "spot cutoff": (light("type = 'spot'\nposition = [0, 1, 0]\ntarget = [0, 0, 0]\n"
                          "intensity = 1\ncutoff = 120\n"),
                    "light[0].cutoff", "must be in (0, 90] degrees"),
    "spot falloff": (light("type = 'spot'\nposition = [0, 1, 0]\ntarget = [0, 0, 0]\n"
                           "intensity = 1\ncutoff = 20\nfalloff = 30\n"),
                     "light[0].falloff", "must be in [0, cutoff = 20.0] degrees"),
    # degenerate geometry (refused)
    "zero-area quad": (quad(edge_v="[2, 0, 0]"), "shape[0]", "allowed: two non-parallel edges"),
    "zero edge": (quad(edge_u="[0, 0, 0]"), "shape[0]", "the quad has no area"),
    "zero scale": (cube("{ scale = 0 }"), "shape[0].transform", "allowed: an invertible transform"),
    "flattening scale": (cube("{ scale = [1, 0, 1] }"), "shape[0].transform",
                         "the transform is singular"),
    "projective matrix": (cube("{ matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], "
                               "[0, 0, 1, 1]] }"),
                          "shape[0].transform.matrix", "the last row must be [0, 0, 0, 1]"),
    "matrix and translate": (cube("{ matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], "
                                  "[0, 0, 0, 1]], translate = [1, 0, 0] }"),
                             "shape[0].transform", "either matrix or translate/rotate/scale"),
    "zero rotation axis": (cube("{ rotate = { axis = [0, 0, 0], angle = 3 } }"),
                           "shape[0].transform.rotate.axis", "must be non-zero"),
    "non-uniform sphere": (sphere(transform="{ scale = [1, 2, 1] }"), "shape[0].transform",
                           "a sphere allows only uniform scaling"),
    "camera look_at = position": (camera(look_at="[0, 1, 5]"), "camera.look_at",
                                  "allowed: any other point"),
    "camera up parallel": (camera(up="[0, -1, -5]"), "camera.up",
                           "parallel to the viewing direction"),
    "spot target = position": (light("type = 'spot'\nposition = [0, 1, 0]\n"
                                     "target = [0, 1, 0]\nintensity = 1\n"),
                               "light[0].target", "allowed: any other point"),
    "directional zero": (light("type = 'directional'\ndirection = [0, 0, 0]\nirradiance = 1\n"),
                         "light[0].direction", "must be non-zero"),
    # names and type values
    "unknown material": (sphere(material="'gold'"), "shape[0].material",
                         "unknown material 'gold'; defined: m"),
    "duplicate material": (HEAD + MAT, "material[1].name", "defined twice"),
    "material type": (material("type = 'velvet'\n"), "material[0].type",
                      "unknown type 'velvet'; allowed: diffuse, mirror, dielectric, phong, "
                      "conductor, roughconductor, roughdielectric, roughplastic, plastic"),
    "smooth plastic with a roughness": (material("type = 'plastic'\nalpha = 0.1\n"),
                                        "material[0].alpha", "unknown key for type 'plastic'"),
    "smooth plastic of ior 1": (material("type = 'plastic'\nior = 1\n"), "material[0].ior",
                                "allowed: ior != 1, int_ior != ext_ior"),
    "smooth plastic too bright": (material("type = 'plastic'\ndiffuse = [0.5, 1.5, 0.5]\n"),
                                  "material[0].diffuse", "reflectance must be in [0, 1]"),
    "smooth plastic nonlinear": (material("type = 'plastic'\nnonlinear = 'yes'\n"),
                                 "material[0].nonlinear", "expected true or false"),
    "shape type": (HEAD + "[[shape]]\ntype = 'torus'\nmaterial = 'm'\n", "shape[0].type",
                   "unknown type 'torus'; allowed: sphere, quad, rectangle, cube, mesh"),
    "light type": (light("type = 'area'\n"), "light[0].type",
                   "unknown type 'area'; allowed: point, spot, directional, environment"),
    "fov_axis": (camera(fov_axis="'diagonal'"), "camera.fov_axis", "allowed: x, y, smaller"),
    "two environments": (light("type = 'environment'\nradiance = 1\n[[light]]\n"
                               "type = 'environment'\nradiance = 1\n"),
                         "light[1]", "allowed: at most one"),
    # mesh files
    "missing mesh": (mesh("missing.obj"), "shape[0].file",
                     "does not exist (paths are relative to the scene file)"),
    "mesh is a directory": (mesh("dir.obj"), "shape[0].file", "is not a file"),
    "mesh format": (mesh("m.txt"), "shape[0].file", "allowed: .obj, .ply, .stl, .off, .glb, .gltf"),
    "garbage ply": (mesh("bad.ply"), "shape[0].file",
                    "expected a valid PLY file that trimesh can read"),
    "empty obj": (mesh("empty.obj"), "shape[0].file", "has no faces"),
    # TOML syntax (with the line from tomllib and the offending line quoted)
    "syntax": (CAMERA + "[[shape]\n", "TOML syntax error",
               "(at line 7, column 8)\n    7 | [[shape]"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_scene_files_name_the_file_the_key_and_what_is_allowed(tmp_path, case):
    text, key, allowed = BAD[case]
    (tmp_path / "dir.obj").mkdir()
    (tmp_path / "m.txt").write_text("v 0 0 0\n")
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
                                       b"garbage")
    (tmp_path / "empty.obj").write_text("# nothing\n")
    path = write(tmp_path, text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        with pytest.raises(SceneError) as e:
            jgi.load_scene(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: {key}: "), msg  # the file, then the key path
    assert allowed in msg, msg


def test_file_level_errors(tmp_path):
    with pytest.raises(SceneError, match="cannot read the scene file"):
        jgi.load_scene(tmp_path / "nope.toml")
    p = tmp_path / "bin.toml"
    p.write_bytes(b"name = '\xff\xfe'\n")
    with pytest.raises(SceneError, match=r"bin.toml: not a UTF-8 text file"):
        jgi.load_scene(p)
    # the syntax error quotes the offending line
    p = write(tmp_path, CAMERA + "fov = = 3\n")
    with pytest.raises(SceneError, match=r"line 7.*\n    7 \| fov = = 3"):
        jgi.load_scene(p)


@pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() == 0, reason="root reads any file")
def test_unreadable_mesh(tmp_path):
    (tmp_path / "m.obj").write_text(OBJ)
    os.chmod(tmp_path / "m.obj", 0)
    with pytest.raises(SceneError, match=r"shape\[0\].file: cannot read mesh file"):
        load(tmp_path, mesh("m.obj"))
