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
from ..scene.tables import Scene
from ..transport.subpath import camera_ray
from ..transport.visible_points import trace_to_diffuse
from .registry import Estimator, Render, param, register


@dataclass(frozen=True)
class WhittedConfig:
    """Whitted ray tracing's parameters (static)."""

    max_depth: int = param(8, "maximum number of segments (specular chain length + 1)",
                           minimum=1, maximum=256)
    light_samples: int = param(1, "shadow rays per diffuse hit", minimum=1, maximum=64)


def radiance(scene: Scene, cfg: WhittedConfig, uniform, o: V3, d: V3) -> V3:
    """Emission seen through the specular chain from rays (o, d), plus direct light at its
    first non-specular vertex (:func:`jgi.transport.visible_points.trace_to_diffuse`)."""
    return trace_to_diffuse(scene, uniform, o, d, max_depth=cfg.max_depth,
                            light_samples=cfg.light_samples).L


def trace_pixels(scene: Scene, cfg: WhittedConfig, seed, pixel, sample) -> V3:
    key = rng.path_key(seed, pixel, sample)
    uniform = lambda k: rng.uniform(key, k)  # noqa: E731
    o, d = camera_ray(scene.camera, pixel, uniform)
    return radiance(scene, cfg, uniform, o, d)


def render(scene: Scene, cfg: WhittedConfig = WhittedConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """The Whitted image, (H, W, 3) float32 (no stats)."""
    image = render_paths(scene, Configured(trace_pixels, cfg), spp=spp, seed=seed,
                         progress=progress)
    return Render(image, {})


register(Estimator(
    "whitted", "Whitted ray tracing: direct light at the first diffuse hit, specular chains",
    render, WhittedConfig))
