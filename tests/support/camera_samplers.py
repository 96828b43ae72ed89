"""Test cameras (:mod:`jgi.physics.camera`), their primary rays and projection on numpy inputs;
used by tests/test_camera.py and the paper's table (paper/chi2_table.py)."""

from __future__ import annotations

import jax
import numpy as np

from jgi.core.vec import V3
from jgi.physics import camera as C
from jgi.scene import SceneBuilder

CAMERAS = {
    "square": dict(position=(0.0, 1.0, 5.0), look_at=(0.0, 1.0, 0.0), up=(0, 1, 0), fov=40.0,
                   width=32, height=32),
    "wide-x": dict(position=(1.0, 2.0, -3.0), look_at=(0.2, 0.5, 1.0), up=(0, 1, 0), fov=75.0,
                   width=48, height=27, fov_axis="x"),
    "tall-mirrored": dict(position=(-2.0, 0.5, 1.0), look_at=(1.0, 0.0, 0.0), up=(0.1, 0, 1),
                          fov=30.0, width=20, height=36, mirror=True),
}


def camera(name):
    """The camera ``CAMERAS[name]`` of a one-sphere scene."""
    b = SceneBuilder(name="cam")
    b.material("m", "diffuse", diffuse=0.5)
    b.sphere((0.0, 0.0, 0.0), 1.0, "m")
    b.camera(**CAMERAS[name])
    return b.build().camera


@jax.jit
def sample_rays(cam, px, py, u1, u2):
    """(origins, directions) of ``C.sample_ray`` through pixels (px, py) at offsets (u1, u2)."""
    o, d = C.sample_ray(cam, px, py, u1, u2)
    return o.stack(), d.stack()


@jax.jit
def _project(cam, p):
    pr = C.project(cam, V3(p[:, 0], p[:, 1], p[:, 2]))
    return dict(px=pr.px, py=pr.py, visible=pr.visible, importance=pr.importance,
                pdf_dir=pr.pdf_dir, dist=pr.dist, wi=pr.wi.stack())


def project(cam, p):
    """``C.project`` of the points p [N, 3], as a dict of numpy arrays."""
    return {k: np.asarray(v) for k, v in _project(cam, np.asarray(p, np.float32)).items()}


def vec(c) -> np.ndarray:
    """A V3 of scalars as a float64 numpy vector."""
    return np.array([float(c.x), float(c.y), float(c.z)])


def primary_rays(cam, n, seed):
    """(px, py, u, origins, directions) of n primary rays through uniformly chosen pixels."""
    rng = np.random.default_rng(seed)
    px = rng.integers(0, cam.width, n).astype(np.int32)
    py = rng.integers(0, cam.height, n).astype(np.int32)
    u = rng.random((2, n), dtype=np.float32)
    o, d = sample_rays(cam, px, py, u[0], u[1])
    return px, py, u, np.asarray(o, np.float64), np.asarray(d, np.float64)


def frame_cone(cam):
    """(axis, 1 - cos) of the smallest cone about the forward axis that contains the frame."""
    fwd, r, u = vec(cam.forward), vec(cam.right), vec(cam.up)
    corner = fwd + r + u
    cos = (corner @ fwd) / np.linalg.norm(corner)
    return fwd, 1.0 - cos
