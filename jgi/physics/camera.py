"""Pinhole camera: primary rays, and the importance function for connecting light paths.

Film coordinates (sx, sy) in [-1, 1]^2 map to the direction forward + sx right + sy up, where
``right`` and ``up`` are scaled to the half-extents of the image plane at distance 1 (see
:class:`jgi.scene.Camera`). With A the area of that plane, the pinhole's importance for a
direction at angle theta to the axis is W_e = 1 / (A cos^4 theta) inside the frame (pbrt-v4's
PerspectiveCamera::We), normalised so that the importance over the whole film integrates to 1; the
solid-angle pdf of primary-ray directions is 1 / (A cos^3 theta).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from ..core.vec import V3, dot, length, normalize
from ..scene.tables import Camera


def sample_ray(cam: Camera, px: Array, py: Array, u1: Array, u2: Array) -> tuple[V3, V3]:
    """Ray through raster position (px + u1, py + u2); row 0 is the top of the image."""
    sx = 2.0 * (px.astype(jnp.float32) + u1) / cam.width - 1.0
    sy = 1.0 - 2.0 * (py.astype(jnp.float32) + u2) / cam.height
    d = normalize(cam.forward + cam.right * sx + cam.up * sy)
    o = V3(*(jnp.broadcast_to(c, sx.shape) for c in cam.position))
    return o, d


def film_area(cam: Camera) -> Array:
    """Area A of the image plane at unit distance."""
    return 4.0 * length(cam.right) * length(cam.up)


class CameraProjection(NamedTuple):
    px: Array         # raster x (float; pixel index = floor)
    py: Array         # raster y
    visible: Array    # inside the frame and in front of the camera
    importance: Array  # W_e(direction) = 1 / (A cos^4 theta); 0 outside
    pdf_dir: Array    # 1 / (A cos^3 theta)
    dist: Array       # distance from the pinhole to the point
    wi: V3            # unit direction from the point towards the pinhole


def project(cam: Camera, p: V3) -> CameraProjection:
    """Where the point p appears on the film, and the camera's importance in its direction."""
    v = p - cam.position
    dist = jnp.sqrt(dot(v, v))
    dist_safe = jnp.where(dist > 0, dist, 1.0)
    d = v / dist_safe
    cos_t = dot(d, cam.forward)
    front = cos_t > 1e-6
    inv_cos = 1.0 / jnp.where(front, cos_t, 1.0)
    r2, u2 = dot(cam.right, cam.right), dot(cam.up, cam.up)
    sx = dot(d, cam.right) * inv_cos / r2
    sy = dot(d, cam.up) * inv_cos / u2
    visible = front & (jnp.abs(sx) <= 1.0) & (jnp.abs(sy) <= 1.0) & (dist > 0)
    px = (sx + 1.0) * 0.5 * cam.width
    py = (1.0 - sy) * 0.5 * cam.height
    A = film_area(cam)
    inv_cos2 = inv_cos * inv_cos
    importance = jnp.where(visible, inv_cos2 * inv_cos2 / A, 0.0)
    pdf_dir = jnp.where(visible, inv_cos2 * inv_cos / A, 0.0)
    return CameraProjection(px, py, visible, importance, pdf_dir, dist, -d)
