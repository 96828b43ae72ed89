"""Whitted-style ray tracing (Whitted 1980; the lecture's example code in "ray tracing" mode).

From the camera, rays follow perfect mirror reflection and refraction through specular
surfaces; at the first non-specular surface the estimator adds direct light only (shadow rays
to point, spot, directional and area lights) and stops: no diffuse interreflection, no
caustics. Emitters and the environment seen directly or through a specular chain are added.
It estimates exactly the light paths E S* D L and E S* L, which is what photon mapping adds
to (see ``tests/test_whitted.py``).

At a dielectric Whitted traces both the reflected and the refracted ray; in a vectorised
wavefront jgi picks one with the Fresnel probability instead, which has the same expectation
(the image converges to Whitted's) at a fixed cost per path. Area lights are sampled with
``light_samples`` shadow rays (the deterministic original used one point per light).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from ..core import rng
from ..core.vec import V3, dot, where
from ..drivers.chunked import render_paths
from ..physics import bsdf as B
from ..physics import camera as C
from ..physics import geometry as G
from ..physics import lights as LT
from ..scene.data import Scene
from .registry import Estimator, Render, param, register


@dataclass(frozen=True)
class WhittedConfig:
    """Whitted ray tracing's parameters (static)."""

    max_depth: int = param(8, "maximum number of segments (specular chain length + 1)",
                           minimum=1, maximum=256)
    light_samples: int = param(1, "shadow rays per diffuse hit", minimum=1, maximum=64)


class DiffuseVertex(NamedTuple):
    """Where a camera path's specular chain ends: the first non-specular hit."""

    L: V3            # emission seen along the chain plus direct light at the vertex
    beta: V3         # throughput of the specular chain
    p: V3            # the vertex (valid where ``found``)
    n: V3            # its geometric normal
    wo: V3           # direction back along the path
    material: Array
    found: Array     # bool: the chain ended on a non-specular surface


def trace_to_diffuse(scene: Scene, cfg: WhittedConfig, uniform, o: V3, d: V3) -> DiffuseVertex:
    """Follow rays (o, d) through specular surfaces to the first non-specular hit, adding
    emission seen on the way and direct light (shadow rays) at that hit."""
    mats, lights = scene.materials, scene.lights
    z = jnp.zeros_like(o.x)
    Z = V3(z, z, z)
    dims = 1 + 3 * cfg.light_samples

    def step(depth, s):
        o, d, beta, L, active, v = s
        hit = G.intersect(scene, o, d)
        wo = -d
        base = 2 + depth * dims
        if lights.count:
            L = L + where(active & hit.valid, beta * LT.emitted(lights, hit.emitter, hit.n, wo), Z)
            if lights.environment >= 0:
                L = L + where(active & ~hit.valid, beta * LT.environment_radiance(lights, z), Z)
        active = active & hit.valid
        mp = B.lookup(mats, hit.material)
        specular = B.is_delta(mp)
        diffuse_end = active & ~specular
        # ---- direct light at the first non-specular surface ----
        if lights.count:
            for j in range(cfg.light_samples):
                dj = base + 1 + 3 * j
                ls = LT.sample_li(lights, hit.p, uniform(dj), uniform(dj + 1), uniform(dj + 2))
                f, _ = B.evaluate(mats.kinds, mp, hit.n, wo, ls.wi)
                visible = ~G.occluded(scene, *G.shadow_ray(hit.p, hit.n, ls.wi, ls.dist))
                ok = diffuse_end & ls.valid & visible & (ls.pdf > 0)
                scale = jnp.abs(dot(ls.wi, hit.n)) / (cfg.light_samples * jnp.where(ok, ls.pdf, 1.0))
                L = L + where(ok, beta * f * ls.Li * scale, Z)
        v = DiffuseVertex(v.L, where(diffuse_end, beta, v.beta), where(diffuse_end, hit.p, v.p),
                          where(diffuse_end, hit.n, v.n), where(diffuse_end, wo, v.wo),
                          jnp.where(diffuse_end, hit.material, v.material), v.found | diffuse_end)
        # ---- follow the specular chain ----
        bs = B.sample(mats.kinds, mp, hit.n, wo, uniform(base), z, z)
        active = active & specular & bs.valid
        return (G.offset_origin(hit.p, hit.n, bs.wi), bs.wi, beta * bs.weight, L, active, v)

    one = jnp.ones_like(z)
    v0 = DiffuseVertex(Z, Z, o, V3(z, z, one), V3(z, z, one), jnp.zeros_like(z, jnp.int32), z > 0)
    state = (o, d, V3(one, one, one), Z, z == 0, v0)
    _, _, _, L, _, v = jax.lax.fori_loop(0, cfg.max_depth, step, state)
    return v._replace(L=L)


def radiance(scene: Scene, cfg: WhittedConfig, uniform, o: V3, d: V3) -> V3:
    return trace_to_diffuse(scene, cfg, uniform, o, d).L


def trace_pixels(scene: Scene, cfg: WhittedConfig, seed, pixel, sample) -> V3:
    key = rng.path_key(seed, pixel, sample)
    W = scene.camera.width
    o, d = C.sample_ray(scene.camera, pixel % W, pixel // W, rng.uniform(key, 0), rng.uniform(key, 1))
    return radiance(scene, cfg, lambda k: rng.uniform(key, k), o, d)


def render(scene: Scene, cfg: WhittedConfig = WhittedConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """The Whitted image, (H, W, 3) float32 (no stats)."""
    image = render_paths(scene, lambda sc, pix, smp, sd: trace_pixels(sc, cfg, sd, pix, smp),
                         spp=spp, seed=seed, progress=progress, cache_key=("whitted", cfg))
    return Render(image, {})


register(Estimator(
    "whitted", "Whitted ray tracing: direct light at the first diffuse hit, specular chains",
    render, WhittedConfig))
