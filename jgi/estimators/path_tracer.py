"""Unidirectional path tracing with BSDF sampling, light sampling, or both combined by MIS.

Estimator (Kajiya 1986; Veach 1997 ch. 9; the lecture's "path sampling" and "multiple importance
sampling"): a camera ray is extended by sampling the BSDF at each vertex x_k. Radiance reaching
the camera is gathered by two strategies:

* **BSDF sampling** (``strategy="bsdf"``): when the sampled ray hits an emitter, add
  beta * L_e. Cannot see point, spot or directional lights (the lecture: "fails for point light
  sources").
* **Light sampling / next-event estimation** (``strategy="light"``): at each non-specular vertex
  draw n_g points on the lights and add (1/n_g) beta f L_i |cos| / p_g when unoccluded;
  emitters hit by BSDF rays then count only after a specular bounce (or straight from the camera).
* **MIS** (``strategy="mis"``): both, weighted by the balance heuristic
  w = n p / (n_f p_f + n_g p_g) or the power heuristic with exponent ``power``
  (jgi.transport.mis), n_f = 1.

beta (path throughput) is multiplied by f |cos| / p at every bounce. Russian roulette after
``rr_depth`` segments keeps the estimator unbiased (beta /= q). ``max_depth`` counts path
segments (1: emitters seen directly, 2: direct lighting; Mitsuba's convention), and
``path_length = L > 0`` keeps only paths of exactly L segments, so that summing over L reproduces
the full image (the lecture's "contributions of different path lengths").

On meshes with vertex normals the BSDF is evaluated and sampled about the interpolated shading
normal (cosines too); rays leave with offsets along the geometric normal (Mitsuba 3's and
pbrt-v4's conventions).

Participating media (a scene filled by a homogeneous medium, ``Scene.medium``): each segment
first samples a free flight (:func:`jgi.physics.media.sample_free_flight`, spectral MIS over the
RGB channels). A medium vertex before the surface takes the surface vertex's place: next-event
estimation with the phase function in place of f |cos| (its density in MIS), the transmittance
of the shadow ray evaluated exactly, and the continuation sampled from the phase function
(:mod:`jgi.physics.phase`); reaching the surface weighs the throughput by T / P. Two more
random numbers per bounce (the channel, the distance) follow the bounce's own. Medium sampling
is always detached for derivatives (Zeltner et al. 2021, as ``gradient="detached"`` does for
BSDFs): free-flight distances, events and phase directions are constants, their weights
T sigma_s / p, T / P and p_g / p carry the dependence on sigma_t, the albedo and g, so jax.grad
estimates the derivative of the expected image without the boundary term that moving sampled
distances across surfaces would need.

A heterogeneous medium (``Scene.medium`` a :class:`jgi.scene.tables.GridMedium`, a static
flag: vacuum and homogeneous scenes compile as before) replaces the closed forms by null-
scattering tracking (:mod:`jgi.physics.grid_media`): free flights by spectral delta tracking,
whose RGB weight multiplies the throughput, shadow rays' transmittance by ratio tracking, both
drawing from a stream hashed from the bounce's two free-flight numbers
(:func:`jgi.core.rng.substream`). Grid media are not differentiated (their sampling and
weights are constants for derivatives): :func:`radiance` refuses, by name, a derivative with
respect to a grid medium's parameters, which would otherwise come out zero.

Derivatives (``gradient``): with ``"attached"`` (default) ``jax.grad`` differentiates the
estimate itself, the sampled directions moving with the parameters (reparametrised sampling;
common random numbers). With ``"detached"`` the sampled directions, their pdfs, the lobe
choices, the MIS weights and Russian roulette's survival probabilities are constants for
derivatives, and each BSDF sample's weight f_theta(wi) |cos| / p keeps f's dependence only
(Zeltner et al. 2021, "Monte Carlo estimators for differential light transport": detached
sampling, Mitsuba 3's default). Its derivative is an unbiased estimate of the derivative of
the expected image wherever the integrand is smooth in the parameters (e.g. roughness, albedo;
not geometry: visibility is not differentiated), the paths stay those of the attached
estimator, and reverse mode compiles in seconds on scenes where the attached program takes
minutes (every microfacet kind in one scene: docs/performance.md#gradients). Dirac samples
keep their sampled weights: the discrete choice of a Dirac lobe (a dielectric's reflection or
refraction) is not differentiated in either mode.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from .. import _xla
from .._xla import materialize
from ..core import rng
from ..core.configured import Configured
from ..core.vec import V3, max_component, where
from ..core.vec import length as length_of
from ..drivers.wavefront import render_wavefront
from ..physics import bsdf, geometry, grid_media, media, medium_interfaces, phase
from ..physics.lights import emitted, environment_pdf, environment_radiance, pdf_li
from ..scene.tables import ROUGH_KINDS, Scene
from ..transport import mis
from ..transport.subpath import (
    at_medium_vertex,
    camera_ray,
    next_event_value,
    sample_next_event,
    shading,
)
from .registry import Estimator, Render, param, register


@dataclass(frozen=True)
class PathTracerConfig:
    """The path tracer's parameters; all static (compile-time), hashable so one compile serves
    all renders with them."""

    strategy: str = param("mis", "which estimator gathers light", choices=("bsdf", "light", "mis"))
    heuristic: str = param("balance", "MIS heuristic", choices=("balance", "power"))
    power: float = param(2.0, "power-heuristic exponent", minimum=0.1, maximum=16)
    light_samples: int = param(1, "n_g: light samples (shadow rays) per vertex", minimum=1,
                               maximum=64)
    max_depth: int = param(8, "maximum path segments (1 = emitters only, 2 = direct light)",
                           minimum=1, maximum=1024)
    rr_depth: int = param(5, "Russian roulette from this many segments (-1 = off)", minimum=-1)
    path_length: int = param(0, "keep only paths with exactly this many segments (0 = all)",
                             minimum=0, maximum=1024)
    gradient: str = param("attached", "what derivatives differentiate: the estimate itself "
                          "('attached') or only f's dependence, sampling held fixed ('detached')",
                          choices=("attached", "detached"))

    @property
    def dims_per_bounce(self) -> int:
        return 4 + 3 * self.light_samples

    @property
    def exponent(self) -> float:
        return 1.0 if self.heuristic == "balance" else float(self.power)


def dims_per_bounce(cfg: PathTracerConfig, scene: Scene) -> int:
    """Random numbers per bounce: the configuration's, and two more for free flight (channel,
    distance) in a scene filled by a medium (scenes without one keep their streams)."""
    return cfg.dims_per_bounce + (2 if scene.has_medium else 0)


class PathState(NamedTuple):
    o: V3                # ray origin
    d: V3                # ray direction (unit)
    beta: V3             # path throughput: product of f |cos| / pdf so far
    L: V3                # radiance accumulated along the path
    active: Array        # lanes still being traced
    prev_pdf: Array      # solid-angle pdf of the BSDF sample that produced d
    prev_delta: Array    # that sample came from a Dirac lobe (no MIS possible)
    prev_p: V3           # the vertex d left from (reference point for pdf_li)
    medium: Array | None = None   # the id of the medium d travels in (scenes with media
                                  # bounded by shapes: jgi.physics.medium_interfaces)


def detach_sample(kinds, mp: bsdf.MaterialParams, n: V3, wo: V3,
                  bs: bsdf.BSDFSample) -> bsdf.BSDFSample:
    """The BSDF sample ``bs`` for detached derivatives: every field a constant except the
    weight's dependence on f. With f = ``B.evaluate`` at the sampled direction the weight
    w = f(wi) |cos| / p becomes w + w (f - stop_gradient(f)) / stop_gradient(f): the same value,
    bit for bit (f - f = 0), and the derivative w df / f = |cos| / p df. Dirac samples, and
    directions where f vanishes, keep their weights as constants."""
    sg = jax.lax.stop_gradient
    bs = jax.tree_util.tree_map(sg, bs)
    f, _ = bsdf.evaluate(kinds, mp, n, wo, bs.wi)

    def relative_change(c):
        live = (c > 0) & ~bs.delta
        safe = jnp.where(live, c, 1.0)   # no 0 / 0 in the derivative where it is not used
        return jnp.where(live, (safe - sg(safe)) / sg(safe), 0.0)

    w = bs.weight
    return bs._replace(weight=w + w * V3(*(relative_change(c) for c in f)))


def _shade(scene: Scene, cfg: PathTracerConfig, s: PathState, hit: geometry.Hit, depth,
           u: Callable[[int], Array]) -> PathState:
    """One path vertex: emission found by the ray, next-event estimation, BSDF sampling and
    Russian roulette. ``depth`` (segments before this one) may be a scalar or per-lane;
    ``u(k)`` is this bounce's k-th random number (dimension 2 + depth * dims_per_bounce + k)."""
    mats, lights = scene.materials, scene.lights
    kinds = mats.kinds
    n_f, n_g = 1.0, float(cfg.light_samples)
    max_depth = cfg.path_length if cfg.path_length > 0 else cfg.max_depth
    has_lights = lights.count > 0
    use_nee = cfg.strategy in ("light", "mis") and has_lights
    detached = cfg.gradient == "detached"
    z = jnp.zeros_like(s.o.x)
    Z = V3(z, z, z)
    wo = -s.d
    length = depth + 1  # segments of the path ending at this hit

    # ---- Free flight in the scene's medium: a medium vertex before the surface, or the surface
    # reached, weighted T sigma_s / p(t) or T / P(s) (jgi.physics.media; spectral MIS) ----
    medium = scene.medium
    grid = scene.has_grid_medium
    # a bounded grid: its lanes are tracked, the others sampled in their homogeneous medium
    in_grid = medium_interfaces.in_grid(scene, s.medium)
    if grid:   # delta (spectral) tracking; not differentiated (jgi.physics.grid_media)
        dm = cfg.dims_per_bounce
        medium = medium_interfaces.held_grid(scene)   # (its phase)
        key_m = rng.substream(u(dm), u(dm + 1))
        gf = medium_interfaces.free_flight(scene, s.medium, s.o, s.d,
                                           jnp.where(hit.valid, hit.t, jnp.inf),
                                           jax.lax.stop_gradient(s.beta), s.active, key_m)
        in_medium = s.active & gf.scattered
        reached = ~gf.scattered
        p_m = s.o + s.d * jnp.where(in_medium, gf.t, 0.0)
        beta_in = s.beta * gf.weight
    if scene.has_medium and (not grid or in_grid is not None):
        medium = medium_interfaces.parameters(scene, s.medium)   # the ray's medium, per lane
        dm = cfg.dims_per_bounce
        sg = jax.lax.stop_gradient   # medium sampling is detached (see the module)
        ff = media.sample_free_flight(sg(medium.sigma_t), sg(medium.albedo), sg(s.beta),
                                      sg(jnp.where(hit.valid, hit.t, jnp.inf)), u(dm), u(dm + 1))
        in_medium_h = s.active & ff.scattered
        t_m = jnp.where(in_medium_h, ff.t, 0.0)          # finite where used
        beta_h = s.beta * media.free_flight_weight(medium.sigma_t, medium.albedo, ff.t,
                                                    ff.scattered, ff.pdf)
        if not grid:
            in_medium, reached, p_m, beta_in = in_medium_h, ~ff.scattered, s.o + s.d * t_m, beta_h
        else:   # (the phase function: the table's g, the grid's on its lanes)
            in_medium = jnp.where(in_grid, in_medium, in_medium_h)
            reached = ~in_medium
            p_m = where(in_grid, p_m, s.o + s.d * t_m)
            beta_in = where(in_grid, beta_in, beta_h)
    if not scene.has_medium:
        in_medium, reached, beta_in = None, True, s.beta

    def counts(length):
        return (length == cfg.path_length) if cfg.path_length > 0 else (length <= max_depth)

    def bsdf_hit_weight(pdf_light):
        first_or_specular = (depth == 0) | s.prev_delta
        if cfg.strategy == "bsdf" or not has_lights:
            return jnp.ones_like(z)
        if cfg.strategy == "light":
            return jnp.where(first_or_specular, 1.0, 0.0)
        w = mis.heuristic_weight(n_f, s.prev_pdf, [(n_g, pdf_light)], cfg.exponent)
        if detached:
            w = jax.lax.stop_gradient(w)
        return jnp.where(first_or_specular, 1.0, w)

    # ---- Emission found by the sampled ray (BSDF sampling strategy) ----
    if has_lights:
        Le = emitted(lights, hit.emitter, hit.n, wo)
        pdf_light = pdf_li(lights, hit.emitter, s.prev_p, hit.p, hit.n)
        take_e = s.active & hit.valid & reached & counts(length)
        L = s.L + where(take_e, beta_in * Le * bsdf_hit_weight(pdf_light), Z)
        if lights.environment >= 0:
            Lenv = environment_radiance(lights, s.d)
            w_env = bsdf_hit_weight(environment_pdf(lights, s.d))
            take_env = s.active & ~hit.valid & reached & counts(length)
            L = L + where(take_env, beta_in * Lenv * w_env, Z)
    else:
        L = s.L
    live = hit.valid if in_medium is None else hit.valid | in_medium
    active = s.active & live & (length < max_depth)
    # with rough materials, whose (f, pdf) are kernels of their own (bsdf._rough), the material
    # row and the light sample are stored once rather than recomputed by each of those kernels
    # (perf: docs/performance.md#glossy-path-tracer)
    store = any(k in kinds for k in ROUGH_KINDS)
    mp = bsdf.lookup_specialised(mats, hit.material, hit.uv, stored=store)
    p_vertex = hit.p if in_medium is None else where(in_medium, p_m, hit.p)

    # ---- Light sampling (next-event estimation): shadow rays and their unoccluded values ----
    shadow = []  # (origin, direction, t_max, contribution if visible)
    if use_nee:
        nee_active = active & counts(length + 1)
        for j in range(cfg.light_samples):
            dj = 4 + 3 * j
            ne = sample_next_event(scene, mp, p_vertex, hit.n, wo, u(dj), u(dj + 1), u(dj + 2),
                                   nee_active, ns=hit.ns, stored=store)
            if in_medium is not None:
                ne = _medium_next_event(medium, ne, in_medium, p_m, s.d, nee_active)
            # the shadow ray's medium (bounded media): the side of the light at a surface
            shadow_medium = medium_interfaces.leaving(scene, s.medium, hit.material, hit.n,
                                                      ne.light.wi, in_medium)
            if cfg.strategy == "mis":
                w_g = mis.heuristic_weight(n_g, ne.light.pdf, [(n_f, ne.pdf_bsdf)], cfg.exponent)
                w_g = jnp.where(ne.light.delta, 1.0, w_g)
                if detached:
                    w_g = jax.lax.stop_gradient(w_g)
            else:
                w_g = jnp.ones_like(z)
            value = next_event_value(ne, beta_in, w_g, n_g)
            if grid:   # transmittance along the shadow ray by ratio tracking
                o_s, d_s, t_s = ne.shadow
                key_j = rng.derive(key_m, rng.SALTS["ratio_tracking"] + j)
                lit = nee_active & (max_component(value) > 0)
                shadow_in_grid = medium_interfaces.in_grid(scene, shadow_medium)
                tr = medium_interfaces.transmittance(scene, shadow_medium, o_s, d_s, t_s, lit,
                                                     key_j)
                if shadow_in_grid is not None:   # the other lanes: their medium's exp(-s d)
                    sigma_t = medium_interfaces.parameters(scene, shadow_medium).sigma_t
                    tr = where(shadow_in_grid, tr,
                               media.transmittance(sigma_t, t_s * length_of(d_s)))
                value = value * tr
            elif scene.has_medium:   # exact transmittance along the shadow ray
                o_s, d_s, t_s = ne.shadow
                sigma_t = medium_interfaces.parameters(scene, shadow_medium).sigma_t
                value = value * media.transmittance(sigma_t, t_s * length_of(d_s))
            shadow.append((*ne.shadow, value))

    # ---- BSDF sampling: extend the path ----
    # the BSDF about the shading normal (meshes with vertex normals); the geometric normal
    # offsets the next ray (Mitsuba 3's path integrator: no further light-leak test)
    bs = bsdf.sample(kinds, mp, shading(hit), wo, u(0), u(1), u(2))
    if detached:
        bs = detach_sample(kinds, mp, shading(hit), wo, bs)
    if in_medium is not None:   # a medium vertex scatters by the phase function (weight 1)
        sg = jax.lax.stop_gradient
        ps = phase.sample(sg(medium.g), sg(s.d), u(0), u(1))
        # weight p_g / p with p a constant: 1, with the derivative of p_g (detached sampling)
        p_g = phase.henyey_greenstein(ps.mu, medium.g)
        one = 1.0 + (p_g - sg(p_g)) / jnp.where(sg(p_g) > 0, sg(p_g), 1.0)
        bs = bsdf.BSDFSample(*(where(in_medium, a, b) if isinstance(a, V3) else
                               jnp.where(in_medium, a, b) for a, b in zip(
                                   _as_bsdf_sample(bs, ps, one), bs)))
    beta = beta_in * bs.weight
    active = active & bs.valid

    # ---- Russian roulette ----
    if cfg.rr_depth >= 0:
        q = jnp.clip(max_component(beta), 0.0, 0.95)
        if detached:
            q = jax.lax.stop_gradient(q)
        roulette = length >= cfg.rr_depth
        survive = u(3) < q
        active = active & (~roulette | survive)
        beta = where(roulette, beta * _xla.recip(jnp.where(q > 0, q, 1.0)), beta)
    o_next = geometry.offset_origin(hit.p, hit.n, bs.wi)
    if in_medium is not None:
        o_next = where(in_medium, p_m, o_next)

    # ---- Shadow rays: add the light samples that are unoccluded ----
    # kept out of the light-sampling kernel (vectorisation; perf: docs/performance.md#shadow-rays)
    if shadow:
        shadow = materialize(shadow)
    for o_s, d_s, t_max, value in shadow:
        L = L + where(~geometry.occluded(scene, o_s, d_s, t_max), value, Z)

    # computed once; downstream reads the path's fate (perf: docs/performance.md#vertex-results)
    # the next ray's medium (bounded media): a surface that bounds media is crossed or not
    medium_next = medium_interfaces.leaving(scene, s.medium, hit.material, hit.n, bs.wi,
                                            in_medium)
    wi, pdf, delta, beta, active, o_next, L = materialize(
        (bs.wi, bs.pdf, bs.delta, beta, active, o_next, L))
    return PathState(o_next, wi, beta, L, active, pdf, delta, p_vertex, medium_next)


def _medium_next_event(medium, ne, in_medium, p_m: V3, d: V3, active):
    """The light sample ``ne`` (drawn at the medium vertex p_m where ``in_medium``) with the
    phase function in place of the BSDF: f = pdf = p(d, wi), no cosine, a shadow ray from p_m."""
    ne = at_medium_vertex(ne, in_medium, phase.evaluate(medium.g, d, ne.light.wi), active)
    # the shadow ray leaves p_m itself (no surface to offset from)
    o_m, d_m, t_m = geometry.shadow_ray(p_m, ne.light.wi, ne.light.wi, ne.light.dist)
    o_s, d_s, t_s = ne.shadow
    return ne._replace(shadow=(where(in_medium, o_m, o_s), where(in_medium, d_m, d_s),
                               jnp.where(in_medium, t_m, t_s)))


def _as_bsdf_sample(bs: bsdf.BSDFSample, ps: phase.PhaseSample, one) -> tuple:
    """A phase sample in the fields of a BSDF sample (the same order as ``bs``'s)."""
    values = dict(wi=ps.d_out, weight=V3(one, one, one), pdf=ps.pdf,
                  delta=jnp.zeros(one.shape, bool), valid=jnp.ones(one.shape, bool))
    return tuple(values.get(k, getattr(bs, k)) for k in bs._fields)


def _camera_state(scene: Scene, o: V3, d: V3) -> PathState:
    z = jnp.zeros_like(o.x)
    return PathState(o, d, V3(z + 1, z + 1, z + 1), V3(z, z, z), z == 0, z, z == 0, o,
                     medium_interfaces.start(scene, z))


def radiance(scene: Scene, cfg: PathTracerConfig, uniform: Callable[[Array], Array], o: V3,
             d: V3) -> V3:
    """Radiance arriving along rays (o, d), one path each.

    ``uniform(dim)`` returns the paths' random numbers for dimension ``dim`` (an [N] array), so
    the same code runs on hashed streams (``lambda k: rng.uniform(key, k)``) and on explicit
    primary-sample vectors (Metropolis). Dimensions 0 and 1 are the camera's pixel jitter;
    bounce b uses dimensions 2 + b * cfg.dims_per_bounce onwards."""
    max_depth = cfg.path_length if cfg.path_length > 0 else cfg.max_depth
    if scene.has_grid_medium:   # its derivatives would come out zero: refused by name
        grid_media.refuse_derivatives(medium_interfaces.grids(scene))

    def bounce(depth, s: PathState) -> PathState:
        base = 2 + depth * dims_per_bounce(cfg, scene)
        hit = geometry.intersect(scene, s.o, s.d)
        return _shade(scene, cfg, s, hit, depth, lambda k: uniform(base + k))

    return jax.lax.fori_loop(0, max_depth, bounce, _camera_state(scene, o, d)).L


def trace_pixels(scene: Scene, cfg: PathTracerConfig, seed, pixel: Array, sample: Array) -> V3:
    """Radiance samples for (pixel, sample) index arrays: the per-path estimator, for
    :func:`jgi.drivers.chunked.render_paths` as ``Configured(trace_pixels, cfg)``."""
    key = rng.path_key(seed, pixel, sample)
    uniform = lambda dim: rng.uniform(key, dim)  # noqa: E731
    o, d = camera_ray(scene.camera, pixel, uniform)
    return radiance(scene, cfg, uniform, o, d)


# --- the same estimator as a per-segment step, for the wavefront renderer ----------------------

class _Lane(NamedTuple):
    path: PathState
    depth: Array     # segments traced so far
    key: Array       # the path's random stream, rng.path_key(seed, pixel, sample)


def _start(scene: Scene, seed, pixel: Array, sample: Array) -> _Lane:
    key = rng.path_key(seed, pixel, sample)
    c = rng.counter(key, 0)
    o, d = camera_ray(scene.camera, pixel, lambda k: rng.uniform_at(c, k))
    return _Lane(_camera_state(scene, o, d), jnp.zeros_like(pixel), key)


def _step(scene: Scene, cfg: PathTracerConfig, lane: _Lane):
    """Trace one more segment of every lane's path: exactly one iteration of :func:`radiance`'s
    loop, with the lane's own depth, so paths are identical to :func:`trace_pixels`'."""
    max_depth = cfg.path_length if cfg.path_length > 0 else cfg.max_depth
    s = lane.path
    # stored: not recomputed per reading kernel (perf: docs/performance.md#ray-and-stream-key)
    if geometry.traversal_loops(scene):
        o, d, key = materialize((s.o, s.d, lane.key))
        hit = geometry.intersect(scene, o, d)
    else:
        hit = geometry.intersect(scene, s.o, s.d, stored=False)
        hit, d, key = materialize((hit, s.d, lane.key))
    s, lane = s._replace(d=d), lane._replace(key=key)
    c = rng.counter(lane.key, 2 + lane.depth * dims_per_bounce(cfg, scene))
    s = _shade(scene, cfg, s, hit, lane.depth, lambda k: rng.uniform_at(c, k))
    depth = lane.depth + 1
    alive = s.active & (depth < max_depth)
    return _Lane(s, depth, lane.key), alive, s.L


def render(scene: Scene, cfg: PathTracerConfig = PathTracerConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """The path-traced image, (H, W, 3) float32, traced by the wavefront driver (no stats)."""
    image = render_wavefront(scene, _start, Configured(_step, cfg), spp=spp, seed=seed,
                             progress=progress)
    return Render(image, {})


register(Estimator("pt", "path tracing with BSDF sampling, light sampling or MIS", render,
                   PathTracerConfig, renamed={"beta": "power"}, media=True,
                   grid_media=True))
