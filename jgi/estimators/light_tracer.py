"""Light tracing (particle tracing, t = 1): light subpaths connected to the pinhole camera.

Estimator (Veach 1997, sec. 10.2 with t = 1; the lecture's "visualize particles from light"):
a light subpath y_0 y_1 ... is started with ``lights.sample_emission`` (y_0 on a light, beta_1 =
L_e |cos| / (pmf p_pos p_dir)) and extended by BSDF sampling in importance mode. Every
non-specular vertex y_i is connected to the pinhole z_0 by a shadow ray; the contribution

    C = beta_i f(y_{i-1} -> y_i -> z_0) |cos theta_i| W_e(z_0 -> y_i) cos theta_cam / |y_i - z_0|^2

is splatted (scatter-add, ``.at[].add``: deterministic) into the pixel that y_i projects to.
W_e = 1 / (A cos^4) (jgi.physics.camera) integrates to one over the film, so with one light subpath
per pixel sample (P spp paths) the image is the sum of splats divided by spp. Light vertex y_0
of an area light is splatted too (s = 1: emitters seen directly, L_e |cos| / (pmf / area)).

What each direction cannot do (the lecture's "all one-bounce cases"):

* Forward path tracing with pure BSDF sampling **fails for point light sources**: a sampled
  direction never hits a point (or spot, or directional) light, so the image is black; light
  sampling saves the direct part, but L-D-S-E paths (a point light seen in a mirror) remain
  impossible for it.
* Light tracing **fails for a pinhole camera** wherever the camera sees a specular surface:
  the pinhole is a point, so a light path can only reach it by a deterministic connection,
  which a Dirac BSDF (mirror, glass) cannot make: L-...-S-E paths (mirror reflections,
  caustics *seen through* glass) are missing, and so is anything a light subpath would have to
  *hit the lens* to contribute. Directly visible point lights (a finite power on a point of the
  film) are left out as well, matching the path tracer; environment light seen directly is not
  rendered (its y_0 is on a bounding disc, not a surface).
* Light tracing is at its best where path tracing is at its worst: L-S-D-E caustics seen on
  diffuse surfaces (cornell_box_caustics), small or point lights.

Parameters: ``max_depth`` (path segments, as the path tracer's: 1 = emitters seen directly,
2 = direct lighting). No Russian roulette: light subpaths end at ``max_depth`` or absorption.
The light subpath is BDPT's (:func:`jgi.transport.subpath.light_subpath`), the camera
connection BDPT's and VCM's (:func:`jgi.transport.connection.connect_camera`); the splats are
summed by :func:`jgi.drivers.splat.render_splats`.

Participating media (a scene filled by a homogeneous medium): the light subpath samples a free
flight on every segment and scatters at medium vertices by the phase function
(:mod:`jgi.transport.subpath`); every vertex, surface or medium, is connected to the pinhole
with the segment's transmittance T(d) (:func:`~jgi.transport.connection.connect_camera`), and
y_0 seen directly is attenuated by T(d) too. In a grid medium (a density grid in a box) the
subpath's flights are spectral tracking's and each T(d) is ratio tracking's unbiased estimate
(:mod:`jgi.physics.grid_media`) along the shadow ray, on a stream hashed from that ray
(:func:`jgi.transport.connection.shadow_transmittance`).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
from jax import Array

from ..core.configured import Configured
from ..core.vec import V3, dot, max_component, where
from ..drivers.splat import render_splats
from ..physics import camera, geometry
from ..physics.lights import emitted
from ..scene.tables import Scene
from ..transport.connection import connect_camera, occluded_many, transmittance
from ..transport.subpath import light_key, light_subpath, rows
from .registry import Estimator, Render, param, register


@dataclass(frozen=True)
class LightTracerConfig:
    """The light tracer's parameters (static)."""

    max_depth: int = param(8, "maximum path segments (1 = emitters only, 2 = direct light)",
                           minimum=1, maximum=64)


def trace_light_paths(scene: Scene, cfg: LightTracerConfig, seed, pixel: Array, sample: Array):
    """One light subpath per (pixel, sample), connected to the camera at every vertex."""
    lights = scene.lights
    path = light_subpath(scene, light_key(seed, pixel, sample), cfg.max_depth, infinite=True)
    # (the subpath's densities are not read here, so grid media need none)
    v = path.vertices
    out = []
    # ---- s = 1: an area light seen directly (y_0 splatted with L_e / p(y_0)) ----
    y0 = rows(v, 0)
    proj = camera.project(scene.camera, y0.p)
    le = emitted(lights, jnp.where(y0.on_surface, path.element, -1), y0.n, proj.wi)
    d2 = proj.dist * proj.dist
    cos_cam = -dot(proj.wi, scene.camera.forward)
    g = jnp.abs(dot(y0.n, proj.wi)) * cos_cam / jnp.where(d2 > 0, d2, 1.0)
    pdf0 = y0.pdf_fwd
    ok0 = y0.valid & y0.on_surface & proj.visible & (pdf0 > 0)
    val0 = where(ok0, le * (proj.importance * g / jnp.where(ok0, pdf0, 1.0)), V3.full(0.0, g))
    shadow0 = geometry.shadow_ray(y0.p, y0.n, proj.wi, proj.dist)
    if scene.has_medium:   # the light seen through the medium: T(d)
        val0 = val0 * transmittance(scene, proj.dist, shadow0, ok0 & (max_component(val0) > 0),
                                    y0.medium)
    W = scene.camera.width
    pix0 = jnp.where(ok0, jnp.clip(jnp.floor(proj.py).astype(jnp.int32), 0,
                                   scene.camera.height - 1) * W
                     + jnp.clip(jnp.floor(proj.px).astype(jnp.int32), 0, W - 1), -1)
    rays = [shadow0]
    # ---- s >= 2: every surface vertex of the light subpath, all at once ([max_depth - 1, N]) ----
    if cfg.max_depth > 1:
        conn = connect_camera(scene, rows(v, slice(1, None)))
        rays.append(conn.shadow)
    occ = occluded_many(scene, rays)
    out.append((0, jnp.where(occ[0], -1, pix0), val0))
    if cfg.max_depth > 1:
        for i in range(cfg.max_depth - 1):
            out.append((0, jnp.where(occ[1][i], -1, conn.pixel[i]), rows(conn.value, i)))
    return out


def render(scene: Scene, cfg: LightTracerConfig = LightTracerConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """The light-traced image, (H, W, 3) float32 (no stats)."""
    if scene.lights.count == 0:
        H, W = scene.camera.height, scene.camera.width
        return Render(np.zeros((H, W, 3), np.float32), {})
    image = render_splats(scene, Configured(trace_light_paths, cfg), spp=spp, seed=seed,
                          progress=progress)[0]
    return Render(image, {})


register(Estimator("lt", "light tracing: light subpaths splatted onto the pinhole film (t = 1)",
                   render, LightTracerConfig, media=True, grid_media=True))
