"""Visible points: where camera chains end and photons are stored (photon-mapping policy).

A camera path of photon mapping, of Jensen's split, of the irradiance cache and of the Whitted
tracer is followed through surfaces it samples (:func:`samples_through`: Dirac lobes, glossy
lobes too narrow for a density estimate) to its first other vertex, the visible point
(:func:`trace_to_diffuse`, :func:`visible_points`), where a lookup (a photon density estimate, an
irradiance record, a final gather) estimates the rest. Photons are stored exactly on those
lookup surfaces (:func:`is_lookup_surface`), so every path is counted once;
:func:`evaluates_whole` tells density estimates when a lookup surface's BSDF is more than
k_d / pi. Random walks and next-event estimation are :mod:`jgi.transport.subpath`'s.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from ..core import rng
from ..core.vec import V3, where
from ..physics import bsdf, geometry, media, medium_interfaces
from ..physics.lights import emitted, environment_radiance
from ..scene.tables import DIFFUSE, PHONG, PLASTIC, ROUGH_DIELECTRIC, ROUGH_KINDS, Scene
from .subpath import (
    camera_ray,
    next_event_value,
    no_uv,
    sample_next_event,
    shading,
    vertex_ns,
)


def samples_through(mp: bsdf.MaterialParams, lookup_rough: bool = True, kinds=()) -> Array:
    """Vertices a chain of camera (or photon) scattering continues through by sampling the BSDF
    instead of ending there with a lookup (a photon density estimate, an irradiance record, a
    final gather): Dirac lobes; glossy lobes too narrow for a density estimate
    (``bsdf.is_glossy``) and rough dielectrics (whose transmitted photons arrive from the other
    side); with ``lookup_rough=False`` every microfacet material and the smooth plastic
    (Jensen's split and the irradiance cache, whose lookups assume a diffuse or Phong surface:
    glossy light by Monte Carlo, as Jensen prescribes). Photons are stored exactly where chains
    may end, so every path is counted once (:func:`is_lookup_surface`). With lookups, a smooth
    plastic vertex is a lookup surface for its base and is sampled through by its coating's
    Dirac lobe alone, a choice per sample (:func:`trace_to_diffuse`). ``kinds``: the scene's
    (static), to test for plastic only in scenes that have it."""
    through = bsdf.is_delta(mp) | bsdf.is_glossy(mp) | (mp.kind == ROUGH_DIELECTRIC)
    if lookup_rough:
        return through
    through = through | bsdf.is_rough(mp)
    return (through | (mp.kind == PLASTIC)) if PLASTIC in kinds else through


def is_lookup_surface(mp: bsdf.MaterialParams, kinds=()) -> Array:
    """Where photons are stored and density estimates taken: diffuse surfaces, Phong with a
    diffuse part (only k_d / pi of it reflects photons in the estimates), microfacet
    surfaces that chains do not sample through (their estimates use the whole BSDF), and the
    smooth plastic (its base: the non-Dirac part of the BSDF). ``kinds``: the scene's."""
    kd_max = jnp.maximum(jnp.maximum(mp.kd.x, mp.kd.y), mp.kd.z)
    out = ((mp.kind == DIFFUSE) | ((mp.kind == PHONG) & (kd_max > 0))
           | (bsdf.is_rough(mp) & ~samples_through(mp)))
    return (out | (mp.kind == PLASTIC)) if PLASTIC in kinds else out


def has_rough(kinds) -> bool:
    """The static kinds of a scene include a microfacet material."""
    return any(k in kinds for k in ROUGH_KINDS)


def evaluates_whole(kinds) -> bool:
    """Density estimates in a scene of these kinds use the BSDF's value, not k_d / pi, at some
    of its lookup surfaces: the microfacet kinds and the smooth plastic's base."""
    return has_rough(kinds) or PLASTIC in kinds


class DiffuseVertex(NamedTuple):
    """Where a camera path's specular chain ends: the first non-specular hit."""

    L: V3            # emission seen along the chain plus direct light at the vertex
    beta: V3         # throughput of the specular chain
    p: V3            # the vertex (valid where ``found``)
    n: V3            # its geometric normal
    wo: V3           # direction back along the path
    material: Array
    found: Array     # bool: the chain ended on a non-specular surface
    uv: tuple | None = None  # its surface coordinates, in scenes with textures (else None)
    ns: V3 | None = None     # its shading normal, in scenes with vertex normals (else None)
    # a medium interaction (zero normal; its beta includes T sigma_s / p), in scenes filled by
    # a participating medium (else None)
    in_medium: Array | None = None
    # the id of the medium a volume visible point lies in, in scenes with media bounded by
    # shapes (jgi.physics.medium_interfaces; else None)
    medium: Array | None = None
    # with beam estimates (``beams=True``): the chain's segments through the medium, each
    # (origin V3, direction V3, length, throughput V3 at its start) stacked [max_depth, N]
    # (length 0 where unused; inf where the ray escapes)
    segments: tuple | None = None


def trace_to_diffuse(scene: Scene, uniform, o: V3, d: V3, *, max_depth: int,
                     light_samples: int, lookup_rough: bool = True,
                     beams: bool = False) -> DiffuseVertex:
    """Follow rays (o, d) through specular (and glossy: :func:`samples_through`) surfaces (at
    most ``max_depth`` segments) to the first other hit, adding emission seen on the way and
    direct light there (``light_samples`` shadow rays, unweighted next-event estimation).
    Segment k draws ``uniform(2 + k * (1 + 3 light_samples) + ...)``: the lobe choice, then the
    light samples; a glossy lobe's direction draws two more, past all of those
    (``uniform(2 + max_depth (1 + 3 light_samples) + 2 k + ...)``), so scenes without microfacet
    materials keep their streams.

    Smooth plastic (with lookups): its BSDF is sampled first; where the coating's Dirac lobe is
    chosen (probability p) the chain continues with its weight k_s F / p, else it ends there
    with beta / (1 - p) (the lookup and the direct light estimate the base alone): each part of
    the BSDF is counted once, in expectation.

    Participating media (``Scene.medium``): each segment first samples a free flight
    (:func:`jgi.physics.media.sample_free_flight`, the numbers ``uniform(2 + max_depth (3 + 3
    light_samples) + 2 k + ...)``, past the others); an interaction before the surface ends the
    chain there, a *volume* visible point (``in_medium``; its beta times T sigma_s / p), where a
    volume photon estimate (:func:`jgi.transport.density.volume_sum_within`) takes over; the
    surface, reached, weighs the chain by T / P. Only without direct light (light_samples 0).
    A grid medium is tracked (:mod:`jgi.physics.grid_media`: spectral tracking on a stream
    hashed from the same two numbers), its weights the tracking's; no beams there.
    With ``beams``, no free flight is sampled: every segment crosses the medium to its surface,
    weighed by its transmittance T(s), and is returned (``segments``) for the beam radiance
    estimate (:func:`jgi.transport.density.beam_sum`). With media bounded by shapes the chain
    carries the id of the medium it travels in (:mod:`jgi.physics.medium_interfaces`), each
    flight takes that medium's parameters, and a volume visible point keeps its id
    (``medium``); no beams there."""
    mats, lights = scene.materials, scene.lights
    grid = scene.has_grid_medium
    if (grid or scene.has_bounded_media) and beams:
        raise ValueError("trace_to_diffuse: beams (transmittance along whole segments) are not "
                         "implemented in grid media or media bounded by shapes")
    if scene.has_medium and light_samples:
        raise ValueError("trace_to_diffuse: direct light at visible points is not implemented "
                         "in participating media (light_samples must be 0)")
    medium_dim0 = 2 + max_depth * (3 + 3 * light_samples)
    z = jnp.zeros_like(o.x)
    Z = V3(z, z, z)
    dims = 1 + 3 * light_samples
    glossy_dim0 = 2 + max_depth * dims
    kinds = mats.kinds
    rough = has_rough(kinds) or PLASTIC in kinds   # lobes that draw a direction (u1, u2)
    plastic = lookup_rough and PLASTIC in kinds     # a lookup surface with a Dirac lobe

    def step(depth, s):
        o, d, beta, L, active, v, medium_id = s
        hit = geometry.intersect(scene, o, d)
        wo = -d
        base = 2 + depth * dims
        # the grid's lanes (all, or a bounded grid's) are tracked, the others sampled in their
        # homogeneous medium
        in_grid = medium_interfaces.in_grid(scene, medium_id)
        medium = (medium_interfaces.held_grid(scene)
                  if grid and in_grid is None else medium_interfaces.parameters(scene, medium_id))
        scattered = None
        if scene.has_medium and beams:   # the segment, for the beam estimate; T(s)
            t_seg = jnp.where(active, jnp.where(hit.valid, hit.t, jnp.inf), 0.0)
            so, sd, st, sb = v.segments
            put = lambda a, x: a.at[depth].set(x)    # noqa: E731
            v = v._replace(segments=(V3(*map(put, so, o)), V3(*map(put, sd, d)),
                                     put(st, t_seg), V3(*map(put, sb, beta))))
            beta = beta * media.transmittance(medium.sigma_t, jnp.where(active, t_seg, 0.0))
        elif scene.has_medium:   # a free flight first: a volume visible point, or T / P
            dm = medium_dim0 + 2 * depth
            t_hit = jnp.where(hit.valid, hit.t, jnp.inf)
            if grid:   # spectral tracking; weight sigma_s(x) (null products) / (mu P_r)
                ff = medium_interfaces.free_flight(
                    scene, medium_id, o, d, t_hit, beta, active,
                    rng.substream(uniform(dm), uniform(dm + 1)))
            if not grid or in_grid is not None:
                fh = media.sample_free_flight(medium.sigma_t, medium.albedo, beta, t_hit,
                                              uniform(dm), uniform(dm + 1))
                ff = fh if not grid else ff._replace(
                    t=jnp.where(in_grid, ff.t, fh.t),
                    scattered=jnp.where(in_grid, ff.scattered, fh.scattered),
                    weight=where(in_grid, ff.weight, fh.weight))
            scattered = active & ff.scattered
            v = v._replace(
                beta=where(scattered, beta * ff.weight, v.beta),
                p=where(scattered, o + d * jnp.where(scattered, ff.t, 0.0), v.p),
                n=where(scattered, Z, v.n),
                wo=where(scattered, wo, v.wo), found=v.found | scattered,
                in_medium=v.in_medium | scattered,
                medium=None if medium_id is None else jnp.where(scattered, medium_id, v.medium))
            beta = beta * ff.weight     # T / P where the surface is reached
            active = active & ~scattered
        if lights.count:
            L = L + where(active & hit.valid, beta * emitted(lights, hit.emitter, hit.n, wo), Z)
            if lights.environment >= 0:
                L = L + where(active & ~hit.valid, beta * environment_radiance(lights, d), Z)
        active = active & hit.valid
        mp = bsdf.lookup_specialised(mats, hit.material, hit.uv)
        specular = samples_through(mp, lookup_rough, kinds)
        u1, u2 = ((uniform(glossy_dim0 + 2 * depth), uniform(glossy_dim0 + 2 * depth + 1))
                  if rough else (z, z))
        beta_end = beta
        if plastic:   # the lobe sampled at a plastic vertex decides: continue, or end here
            bs = bsdf.sample(kinds, mp, shading(hit), wo, uniform(base), u1, u2)
            is_plastic = mp.kind == PLASTIC
            specular = specular | (is_plastic & bs.delta)
            p_base = 1.0 - bsdf.plastic.coating_probability(mp, bsdf.side(shading(hit), wo)[1])
            beta_end = beta * jnp.where(is_plastic & (p_base > 0),
                                        1.0 / jnp.where(p_base > 0, p_base, 1.0), 1.0)
        diffuse_end = active & ~specular
        if mats.has_one_sided:   # a one-sided surface seen from the back reflects nothing
            beta_end = where(bsdf.back_side(mp, shading(hit), wo), Z, beta_end)
        # ---- direct light at the first non-specular surface ----
        if lights.count:
            for j in range(light_samples):
                dj = base + 1 + 3 * j
                ne = sample_next_event(scene, mp, hit.p, hit.n, wo, uniform(dj), uniform(dj + 1),
                                       uniform(dj + 2), diffuse_end, ns=hit.ns)
                value = next_event_value(ne, beta_end, n_samples=light_samples)
                L = L + where(~geometry.occluded(scene, *ne.shadow), value, Z)
        v = DiffuseVertex(v.L, where(diffuse_end, beta_end, v.beta), where(diffuse_end, hit.p, v.p),
                          where(diffuse_end, hit.n, v.n), where(diffuse_end, wo, v.wo),
                          jnp.where(diffuse_end, hit.material, v.material), v.found | diffuse_end,
                          None if v.uv is None else
                          tuple(jnp.where(diffuse_end, a, b) for a, b in zip(hit.uv, v.uv)),
                          None if v.ns is None else where(diffuse_end, hit.ns, v.ns),
                          v.in_medium, v.medium, v.segments)
        # ---- follow the specular (or glossy) chain ----
        if not plastic:
            bs = bsdf.sample(kinds, mp, shading(hit), wo, uniform(base), u1, u2)
        active = active & specular & bs.valid
        medium_id = medium_interfaces.leaving(scene, medium_id, hit.material, hit.n, bs.wi)
        return (geometry.offset_origin(hit.p, hit.n, bs.wi), bs.wi, beta * bs.weight, L, active, v,
                medium_id)

    one = jnp.ones_like(z)
    segments0 = None
    if scene.has_medium and beams:
        zz = jnp.zeros((max_depth,) + z.shape, z.dtype)
        segments0 = (V3(zz, zz, zz), V3(zz, zz, zz), zz, V3(zz, zz, zz))
    v0 = DiffuseVertex(Z, Z, o, V3(z, z, one), V3(z, z, one), jnp.zeros_like(z, jnp.int32), z > 0,
                       no_uv(scene, z), vertex_ns(scene, V3(z, z, one)),
                       None if not scene.has_medium else z > 0,
                       medium_interfaces.start(scene, z), segments0)
    state = (o, d, V3(one, one, one), Z, z == 0, v0, medium_interfaces.start(scene, z))
    _, _, _, L, _, v, _ = jax.lax.fori_loop(0, max_depth, step, state)
    return v._replace(L=L)


@partial(jax.jit, static_argnames=("max_depth", "light_samples", "lookup_rough", "beams"))
def visible_points(scene: Scene, seed, pixel, sample, *, max_depth: int,
                   light_samples: int, lookup_rough: bool = True,
                   beams: bool = False) -> DiffuseVertex:
    """The visible point of each camera sample (seed, pixel, sample): its camera ray followed
    through specular (and glossy) surfaces to the first other hit (:func:`trace_to_diffuse`),
    the normal there turned to face the viewer. Where photon mapping estimates its density, and
    where an irradiance cache is queried."""
    key = rng.path_key(seed, pixel, sample)
    uniform = lambda k: rng.uniform(key, k)  # noqa: E731
    o, d = camera_ray(scene.camera, pixel, uniform)
    v = trace_to_diffuse(scene, uniform, o, d, max_depth=max_depth, light_samples=light_samples,
                         lookup_rough=lookup_rough, beams=beams)
    return face_viewer(v)


def face_viewer(v: DiffuseVertex) -> DiffuseVertex:
    """The vertex with its normals (geometric, and shading if any) turned towards ``wo``."""
    v = v._replace(n=bsdf.facing(v.n, v.wo))
    return v if v.ns is None else v._replace(ns=bsdf.facing(v.ns, v.wo))
