"""The environment-lit scenes that several test modules render (a sky map with a sun-like
texel, its rotations, a red ball on a floor under it) and the look-ups they share."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jgi.core.vec import V3
from jgi.physics import lights as LT
from jgi.scene import SceneBuilder


def unit_directions(n, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def sphere_midpoints(n, hemisphere: bool = False):
    """The midpoints of an n x 2n (theta, phi) grid over the sphere (n x 4n over the upper
    hemisphere, z >= 0): directions [N, 3] and the solid angle each stands for [N] (midpoint
    rule: sin(theta) dtheta dphi), for integrals over directions."""
    span = np.pi / 2 if hemisphere else np.pi
    th = (np.arange(n) + 0.5) * span / n
    ph = (np.arange((4 if hemisphere else 2) * n) + 0.5) * span / n
    T, P = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    return d, (np.sin(T) * (span / n) ** 2).reshape(-1)


@jax.jit
def _radiance_and_pdf(lights, d):
    v = V3(d[:, 0], d[:, 1], d[:, 2])
    return LT.environment_radiance(lights, v).stack(), LT.environment_pdf(lights, v)


def radiance_and_pdf(lights, d):
    """(radiance [N, 3], solid-angle pdf [N]) of a scene's environment in directions d."""
    L, p = _radiance_and_pdf(lights, jnp.asarray(d, jnp.float32))
    return np.asarray(L, np.float64), np.asarray(p, np.float64)


def sky(H=16, W=32, sun=(4, 9), sun_rgb=(60.0, 50.0, 40.0)):
    """A sky gradient (brighter and bluer towards +y) with a bright sun-like texel."""
    theta = np.pi * np.arange(H) / (H - 1)
    up = 0.5 * (1 + np.cos(theta))[:, None, None]
    img = np.broadcast_to(0.1 + np.array([0.6, 0.8, 1.2]) * up, (H, W, 3)).copy()
    img[:, : W // 3] *= 0.5            # a darker sector in azimuth
    img[sun] = sun_rgb
    return img


def rotation(deg_y=30.0, deg_x=20.0):
    a, b = np.radians(deg_y), np.radians(deg_x)
    ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    m = np.eye(4)
    m[:3, :3] = ry @ rx
    return m


def env_scene(size=16):
    """A red ball on a 6 x 6 floor seen from above (the floor fills the frame), lit by the sky
    map: the ball's shadow, the sun's highlight and interreflections."""
    b = SceneBuilder("env_lit")
    b.material("white", "diffuse", diffuse=0.7)
    b.material("red", "diffuse", diffuse=(0.7, 0.2, 0.2))
    b.sphere((0.0, 0.0, 0.0), 0.8, "red")
    b.quad((-3.0, -0.8, 3.0), (6.0, 0.0, 0.0), (0.0, 0.0, -6.0), "white")
    b.environment_map(sky(), scale=1.0, to_world=rotation(40.0, 0.0))
    b.camera(position=(0, 3, 1.5), look_at=(0, -0.8, 0), fov=40, width=size, height=size)
    return b.build()
