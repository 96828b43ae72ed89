"""Scenes and references the tests share: a point light over a plane in closed form, a scene
of degenerate inputs, a textured PLY quad, and scene equality."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jgi.physics import camera
from jgi.scene import SceneBuilder


def point_light_reference(scene, rho, intensity, height, sub=12):
    """Pixel integrals of L = (rho / pi) I cos(theta) / d^2 by a sub-pixel grid of rays."""
    cam = scene.camera
    W, H = cam.width, cam.height
    u = (np.arange(sub) + 0.5) / sub
    py, px, v, w = np.meshgrid(np.arange(H), np.arange(W), u, u, indexing="ij")
    o, d = camera.sample_ray(cam, jnp.asarray(px.ravel()), jnp.asarray(py.ravel()),
                             jnp.asarray(w.ravel(), jnp.float32),
                             jnp.asarray(v.ravel(), jnp.float32))
    o, d = np.asarray(o.stack()), np.asarray(d.stack())
    t = -o[:, 1] / d[:, 1]
    x = o + d * t[:, None]
    to_light = np.array([0.0, height, 0.0]) - x
    d2 = (to_light**2).sum(1)
    cos = height / np.sqrt(d2)
    L = np.where(t > 0, rho / np.pi * intensity * cos / d2, 0.0)
    return L.reshape(H, W, sub * sub).mean(-1)


def degenerate_scene():
    """Zero-area and zero-radius lights, total internal reflection, an index-matched sphere, a
    near-mirror Phong lobe, every light kind and an eye in the floor plane: renders must stay
    finite."""
    b = SceneBuilder("degenerate")
    b.material("white", "diffuse", diffuse=(0.8, 0.8, 0.8))
    b.material("glass", "dielectric", ior=1.5)
    b.material("same", "dielectric", ior=1.0)
    b.material("shiny", "phong", diffuse=(0.2, 0.2, 0.2), specular=(0.7, 0.7, 0.7), exponent=5000)
    b.quad((-5, 0, -5), (0, 0, 10), (10, 0, 0), "white")            # floor, seen edge-on below
    b.quad((0, 1, 0), (0, 0, 0), (1, 0, 0), "white", emission=(5, 5, 5))  # zero-area light
    b.quad((-1, 2, -1), (0, 0, 0.5), (0.5, 0, 0), "white", emission=(5, 5, 5))
    b.sphere((0, 0.5, 0), 0.0, "white", emission=(3, 3, 3))         # zero-radius light
    b.sphere((0.8, 0.5, 0.2), 0.4, "glass")                          # total internal reflection
    b.sphere((-0.8, 0.5, 0.2), 0.4, "same")                          # index-matched
    b.sphere((0.0, 0.3, -1.0), 0.3, "shiny")
    b.point_light((0, 3, 0), (2, 2, 2))
    b.spot_light((2, 3, 0), (0, 0, 0), (5, 5, 5), cutoff_deg=30)
    b.directional_light((0.3, -1, 0.1), (0.5, 0.5, 0.5))
    b.environment_light((0.1, 0.1, 0.1))
    # eye in the floor plane
    b.camera(position=(0, 0.0, 4), look_at=(0, 0.0, 0), fov=60, width=12, height=12)
    return b.build()


def ply_quad(path, names, binary=False):
    """The square of tests/test_textures.py's OBJ_QUAD (corners (+-1, +-1, 0)) as a PLY file
    whose texture coordinates are the vertex properties ``names`` (None: none), with vertex
    normals."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    uv = np.array([[0.1, 0.2], [0.9, 0.1], [0.8, 0.7], [0.2, 0.9]])
    props = ["x", "y", "z", "nx", "ny", "nz"] + list(names or ())
    rows = np.c_[v, np.tile([0.0, 0.0, 1.0], (4, 1))] if names is None else \
        np.c_[v, np.tile([0.0, 0.0, 1.0], (4, 1)), uv]
    head = (f"ply\nformat {'binary_little_endian' if binary else 'ascii'} 1.0\n"
            "element vertex 4\n" + "".join(f"property float {p}\n" for p in props)
            + "element face 2\nproperty list uchar int vertex_indices\nend_header\n")
    if binary:
        faces = b"".join(np.uint8(3).tobytes() + np.asarray(f, "<i4").tobytes()
                         for f in ([0, 1, 2], [0, 2, 3]))
        path.write_bytes(head.encode() + rows.astype("<f4").tobytes() + faces)
    else:
        path.write_text(head + "".join(" ".join(map(str, r)) + "\n" for r in rows)
                        + "3 0 1 2\n3 0 2 3\n")


def leaves_equal(a, b):
    """Two pytrees (scenes) hold the same leaves, to float32 round-off."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6, atol=1e-7)
