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

from ..core import rng
from ..core.configured import Configured
from ..core.vec import V3
from ..drivers.chunked import render_paths
from ..scene.data import Scene
from ..transport.subpath import camera_ray, trace_to_diffuse
from .registry import Estimator, Param, register


@dataclass(frozen=True)
class WhittedConfig:
    max_depth: int = 8        # maximum number of specular segments followed
    light_samples: int = 1    # shadow rays per diffuse hit


def radiance(scene: Scene, cfg: WhittedConfig, uniform, o: V3, d: V3) -> V3:
    """Emission seen through the specular chain from rays (o, d), plus direct light at its
    first non-specular vertex (:func:`jgi.transport.subpath.trace_to_diffuse`)."""
    return trace_to_diffuse(scene, uniform, o, d, max_depth=cfg.max_depth,
                            light_samples=cfg.light_samples).L


def trace_pixels(scene: Scene, cfg: WhittedConfig, seed, pixel, sample) -> V3:
    key = rng.path_key(seed, pixel, sample)
    uniform = lambda k: rng.uniform(key, k)  # noqa: E731
    o, d = camera_ray(scene.camera, pixel, uniform)
    return radiance(scene, cfg, uniform, o, d)


def _run(scene: Scene, *, spp: int, seed: int, progress: bool = False, **params):
    cfg = WhittedConfig(**params)
    return render_paths(scene, Configured(trace_pixels, cfg), spp=spp, seed=seed,
                        progress=progress)


register(Estimator(
    "whitted", "Whitted ray tracing: direct light at the first diffuse hit, specular chains",
    _run,
    (Param("max_depth", 8, "maximum number of segments (specular chain length + 1)", int, minimum=1, maximum=256),
     Param("light_samples", 1, "shadow rays per diffuse hit", int, minimum=1, maximum=64)),
))
