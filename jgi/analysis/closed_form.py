"""Closed-form images of built-in scenes: exact references for bias and convergence studies.

``IMAGES[name](scene, **terms)`` is the expected image of scene ``name`` (the pixel integral of
the radiance over each pixel's footprint, by stratified quadrature), for the paths the scene's
docstring names. Experiment configs use them as ``reference = { closed_form = "name" }``.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..physics import camera
from ..scene.builtin import MIRROR_SDS
from ..scene.tables import Scene


def _film_rays(scene: Scene, per_axis: int):
    """Primary ray directions [H, W, n, 3] at per_axis^2 stratified points of each pixel."""
    cam = scene.camera
    W, H = cam.width, cam.height
    t = (np.arange(per_axis) + 0.5) / per_axis
    u1, u2 = np.meshgrid(t, t, indexing="ij")
    py, px = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    px = np.broadcast_to(px[..., None], (H, W, per_axis * per_axis))
    py = np.broadcast_to(py[..., None], (H, W, per_axis * per_axis))
    u1 = np.broadcast_to(u1.reshape(-1), px.shape)
    u2 = np.broadcast_to(u2.reshape(-1), px.shape)
    o, d = camera.sample_ray(cam, jnp.asarray(px), jnp.asarray(py), jnp.asarray(u1, jnp.float32),
                             jnp.asarray(u2, jnp.float32))
    return (np.stack([np.asarray(c, np.float64) for c in o], -1),
            np.stack([np.asarray(c, np.float64) for c in d], -1))


def mirror_sds_image(scene: Scene, intensity: float = 10.0, albedo: float = 0.5,
                     mirror: float = 0.9, direct: bool = True, sds: bool = True,
                     per_axis: int = 8) -> np.ndarray:
    """:func:`jgi.scene.builtin.mirror_sds` with paths of at most 4 segments: a pixel sees the
    floor point x in the mirror, L = rho_m (rho_d / pi) E(x), with the floor's irradiance from
    the light (``direct``: L D S E) and from its mirror image at height 2 h_m - h_l (``sds``:
    L S D S E, times rho_m): E = I h / d^3 for a source at height h and distance d."""
    g = MIRROR_SDS
    o, d = _film_rays(scene, per_axis)
    h_m = g["mirror_height"]
    t_m = (h_m - o[..., 1]) / d[..., 1]
    m = o + d * t_m[..., None]
    r = d * np.array([1.0, -1.0, 1.0])               # reflected off the horizontal mirror
    x = m + r * (h_m / -r[..., 1])[..., None]         # down to the floor y = 0
    light = np.array(g["light"])
    E = np.zeros(x.shape[:-1])
    for on, h, gain in ((direct, light[1], 1.0), (sds, 2 * h_m - light[1], mirror)):
        if on:
            v = x - np.array([light[0], h, light[2]])
            dist = np.sqrt(np.sum(v * v, -1))
            E = E + gain * intensity * h / dist ** 3
    L = mirror * albedo / np.pi * E
    ok = (d[..., 1] > 0)
    L = np.where(ok, L, 0.0).mean(-1)
    return np.repeat(L[..., None], 3, -1).astype(np.float32)


def point_light_plane_image(scene: Scene, per_axis: int = 8) -> np.ndarray:
    """:func:`jgi.scene.builtin.point_light_plane` (its intensity, height and albedo read from
    the scene's tables): a pixel sees the plane y = 0 at x, lit by the point light at height h
    and distance d, L = (rho / pi) I cos(theta) / d^2 = (rho / pi) I h / d^3 per channel; the
    only paths are L D E (nothing else reflects)."""
    o, d = _film_rays(scene, per_axis)
    lights, mats = scene.lights, scene.materials
    light = np.array([float(c[0]) for c in lights.p0])
    intensity = np.array([float(c[0]) for c in lights.emission])
    albedo = np.array([float(c[0]) for c in mats.diffuse])
    r = scene.rects     # the builder stores the axis-aligned plane as a rectangle (a = x, b = z)
    lo = np.array([float(r.lo_a[0]), float(r.lo_b[0])])
    hi = np.array([float(r.hi_a[0]), float(r.hi_b[0])])
    down = d[..., 1] < 0
    t = np.where(down, -o[..., 1] / np.where(down, d[..., 1], -1.0), 0.0)
    x = o + d * t[..., None]
    inside = down & np.all((x[..., [0, 2]] >= lo) & (x[..., [0, 2]] <= hi), -1)
    v = x - light
    dist = np.sqrt(np.sum(v * v, -1))
    E = np.where(inside, light[1] / np.maximum(dist, 1e-12) ** 3, 0.0).mean(-1)
    return (E[..., None] * intensity * albedo / np.pi).astype(np.float32)


IMAGES = {"mirror_sds": mirror_sds_image, "point_light_plane": point_light_plane_image}
