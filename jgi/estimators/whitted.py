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

import jax
import jax.numpy as jnp

from .. import bsdf as B
from .. import camera as C
from .. import geometry as G
from .. import lights as LT
from .. import rng
from ..scene import Scene
from ..vec import V3, dot, where
from .registry import Estimator, Param, register


@dataclass(frozen=True)
class WhittedConfig:
    max_depth: int = 8        # maximum number of specular segments followed
    light_samples: int = 1    # shadow rays per diffuse hit


def radiance(scene: Scene, cfg: WhittedConfig, uniform, o: V3, d: V3) -> V3:
    mats, lights = scene.materials, scene.lights
    z = jnp.zeros_like(o.x)
    Z = V3(z, z, z)
    dims = 1 + 3 * cfg.light_samples

    def step(depth, s):
        o, d, beta, L, active = s
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
        # ---- follow the specular chain ----
        bs = B.sample(mats.kinds, mp, hit.n, wo, uniform(base), z, z)
        active = active & specular & bs.valid
        return (G.offset_origin(hit.p, hit.n, bs.wi), bs.wi, beta * bs.weight, L, active)

    one = jnp.ones_like(z)
    state = (o, d, V3(one, one, one), Z, z == 0)
    return jax.lax.fori_loop(0, cfg.max_depth, step, state)[3]


def trace_pixels(scene: Scene, cfg: WhittedConfig, seed, pixel, sample) -> V3:
    key = rng.path_key(seed, pixel, sample)
    W = scene.camera.width
    o, d = C.sample_ray(scene.camera, pixel % W, pixel // W, rng.uniform(key, 0), rng.uniform(key, 1))
    return radiance(scene, cfg, lambda k: rng.uniform(key, k), o, d)


def _run(scene: Scene, *, spp: int, seed: int, progress: bool = False, **params):
    from ..render import render_paths

    cfg = WhittedConfig(**params)
    return render_paths(scene, lambda sc, pix, smp, sd: trace_pixels(sc, cfg, sd, pix, smp),
                        spp=spp, seed=seed, progress=progress, cache_key=("whitted", cfg))


register(Estimator(
    "whitted", "Whitted ray tracing: direct light at the first diffuse hit, specular chains",
    _run,
    (Param("max_depth", 8, "maximum number of segments (specular chain length + 1)", int, minimum=1, maximum=256),
     Param("light_samples", 1, "shadow rays per diffuse hit", int, minimum=1, maximum=64)),
))
