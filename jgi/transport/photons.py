"""Photon tracing (Jensen 1996/2001; the lecture's "photon emission", "photon tracing", "photon
storage"): the first pass of photon mapping.

Each photon starts from ``lights.sample_emission`` (point lights: uniform directions;
directional lights: parallel rays over the scene's bounding disc; area lights: uniform positions,
cosine-distributed directions; several lights chosen in proportion to power) with power
P_photon = P_light / n_e, i.e. ``EmissionSample.weight / n_emitted``.

At every hit on a surface where density estimates are taken (diffuse, Phong with k_d > 0, smooth
plastic, and microfacet surfaces too rough to sample through:
:func:`jgi.transport.visible_points.is_lookup_surface`)
the photon is *stored*:
position, power (RGB), incident direction (towards where it came from) and geometric surface
normal. On meshes with vertex normals the BSDF is sampled about the shading normal, and the
weight carries Veach's adjoint correction (:func:`jgi.physics.bsdf.adjoint_correction`). It
is then scattered by Russian roulette: the BSDF is sampled (importance transport) giving the
weight f |cos| / pdf, the photon survives with probability q = min(1, max(weight)), and its
power is multiplied by weight / q, so the expected power is unchanged while photons keep roughly
equal power (Jensen's reflect/transmit/absorb decision). Mirrors and dielectrics pass photons on
without storing them (Fresnel chooses reflection or transmission).

In a scene filled by a participating medium (``Scene.medium``), each segment first samples a
free flight (:func:`jgi.physics.media.sample_free_flight`, two more numbers per bounce, after
all the vacuum layout's). At a medium interaction x the photon is stored as a *volume photon*
(zero normal: surface lookups, which test the normal, never take it) with the power
P T(t) / p(t): the free-flight weight without sigma, so that sum_p P_p delta(x - x_p) h(w_p)
estimates int L_i(x, w) h(w) dw, the in-scattered radiance's integrand; a volume radiance
estimate (:func:`jgi.transport.density.volume_sum_within`) divides by the kernel's volume.
The photon then continues with the weight T sigma_s / p (Russian roulette on it) in a direction
sampled from the phase function. Reaching a surface weighs it by T / P. In a grid medium the
flight is spectral tracking's (:mod:`jgi.physics.grid_media`, on a stream hashed from the two
numbers) and its weight at a collision carries sigma_s(x): the photon is stored with that
weight divided by sigma_s(x), the grid's T / p. With media bounded by shapes each photon carries
the id of the medium it travels in (:mod:`jgi.physics.medium_interfaces`) and each flight takes
that medium's parameters.

Two maps are distinguished by a flag per stored photon:
  * global: every non-specular hit;
  * caustic: photons whose path so far is L S+ D (one or more specular, microfacet or smooth
    plastic bounces, then the first diffuse or Phong hit).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._xla import materialize
from ..core import rng
from ..core.calls import ordered_calls
from ..core.compaction import live_indices, padded_size
from ..core.sharding import device_mesh, sharded_calls
from ..core.vec import V3, dot, max_component, where
from ..physics import bsdf, geometry, media, medium_interfaces, phase
from ..physics.lights import sample_emission
from ..scene.tables import Scene
from .visible_points import is_lookup_surface, samples_through

DIMS_PER_BOUNCE = 4
_SALT = rng.SALTS["photons"]  # photon streams are independent of camera streams for the same seed


class PhotonMap(NamedTuple):
    """Stored photons, struct of arrays (host or device arrays of one length)."""

    position: V3
    power: V3        # flux carried (W), already divided by the number of emitted photons
    wi: V3           # unit direction towards the photon's previous vertex
    normal: V3       # geometric normal of the surface it was stored on, on the arrival side
    caustic: Array   # bool: L S+ D path
    depth: Array     # int32: number of bounces before storage (0 = direct from the light)

    @property
    def count(self) -> int:
        return int(self.caustic.shape[0])

    @property
    def volume(self):
        """Volume photons (stored in a medium: zero normal)."""
        n = self.normal
        return (n.x == 0) & (n.y == 0) & (n.z == 0)

    def select(self, mask) -> "PhotonMap":
        return jax.tree_util.tree_map(lambda a: a[mask], self)


def trace_photon_paths(scene: Scene, seed, photon_index: Array, n_emitted, max_depth: int):
    """Trace photons ``photon_index`` ([N] int32); return per-bounce records of shape
    [max_depth, N] (a slot is valid where a photon was stored) as a PhotonMap plus ``valid``."""
    lights, mats = scene.lights, scene.materials
    key = rng.derive(rng.path_key(seed, photon_index, 0), _SALT)
    u = lambda d: rng.uniform(key, d)
    em = sample_emission(lights, u(0), u(1), u(2), u(3), u(4))
    inv_n = 1.0 / jnp.asarray(n_emitted, jnp.float32)
    power = em.weight * inv_n
    z = jnp.zeros_like(power.x)
    # o, d, power, alive, specular_seen, only_specular, the medium id (bounded media)
    state = (em.p, em.d, power, power.x >= 0, z > 0, z == 0, medium_interfaces.start(scene, z))

    grid = scene.has_grid_medium   # rendered, not differentiated (jgi.physics.grid_media)

    def bounce(state, depth):
        o, d, pw, alive, spec_seen, only_spec, medium_id = state
        hit = geometry.intersect(scene, o, d)
        base = 5 + depth * DIMS_PER_BOUNCE
        # the grid's lanes (all, or a bounded grid's) are tracked, the others sampled in their
        # homogeneous medium (the table's row of a bounded grid: a vacuum with its g)
        in_grid = medium_interfaces.in_grid(scene, medium_id)
        medium = (medium_interfaces.held_grid(scene)
                  if grid and in_grid is None else medium_interfaces.parameters(scene, medium_id))
        in_medium = None
        if scene.has_medium:   # a free flight before the surface (see the module)
            dm = 5 + max_depth * DIMS_PER_BOUNCE + 2 * depth
            t_hit = jnp.where(hit.valid, hit.t, jnp.inf)
            if grid:   # spectral tracking; its weight at a collision carries sigma_s(x)
                gf = medium_interfaces.free_flight(scene, medium_id, o, d, t_hit, pw, alive,
                                                   rng.substream(u(dm), u(dm + 1)))
                ff_t, ff_scattered, ff_weight = gf.t, gf.scattered, gf.weight
            if not grid or in_grid is not None:
                ff = media.sample_free_flight(medium.sigma_t, medium.albedo, pw, t_hit, u(dm),
                                              u(dm + 1))
                if not grid:
                    ff_t, ff_scattered, ff_weight = ff.t, ff.scattered, ff.weight
                else:
                    ff_t = jnp.where(in_grid, ff_t, ff.t)
                    ff_scattered = jnp.where(in_grid, ff_scattered, ff.scattered)
                    ff_weight = where(in_grid, ff_weight, ff.weight)
            in_medium = alive & ff_scattered
            pw_arrival = pw
            pw = where(in_medium, pw, pw * ff_weight)    # T / P where it reaches the surface
            alive = alive & (hit.valid | in_medium)
            hit = hit._replace(valid=hit.valid & ~in_medium)
        alive = alive & hit.valid if not scene.has_medium else alive
        mp = bsdf.lookup_specialised(mats, hit.material, hit.uv)
        store = alive & is_lookup_surface(mp, mats.kinds)
        # caustic: L S+ D with S what Jensen's split samples through (Dirac and microfacet
        # lobes) and D a diffuse or Phong surface, where its camera chains end
        through = samples_through(mp, lookup_rough=False, kinds=mats.kinds)
        # the normal of the side the photon arrived on: a query (whose normal faces its viewer)
        # then takes no photon that reached the other side of a thin surface
        n_arrival = where(dot(hit.n, d) > 0, -hit.n, hit.n)
        # on a masked surface only a fraction opacity of the arriving photons stop: their
        # stored power is divided by it, so the map estimates the flux arriving there (the
        # flux the surface scatters where it stops a ray), unbiased in expectation
        stored_pw = pw if not mats.has_masks else pw * (1.0 / geometry.hit_opacity(scene, hit))
        ns = hit.n if hit.ns is None else hit.ns
        bs = materialize(bsdf.sample(mats.kinds, mp, ns, -d, u(base), u(base + 1), u(base + 2),
                                     mode=bsdf.IMPORTANCE))
        if hit.ns is not None:   # Veach's adjoint correction for shading normals
            bs = bs._replace(weight=bs.weight * bsdf.adjoint_correction(ns, hit.n, -d, bs.wi))
        p_at, n_at, origin = hit.p, n_arrival, None
        if scene.has_medium:
            # a medium interaction takes the surface's place: stored with the free-flight
            # weight without sigma (T / p), continued with T sigma_s / p along a phase sample
            x = o + d * jnp.where(in_medium, ff_t, 0.0)
            ph = phase.sample(medium.g, d, u(base), u(base + 1))
            if grid:   # the tracking's weight without sigma_s(x): its T / p
                sigma_s = medium_interfaces.scattering(scene, medium_id, x)
                t_over_p = V3(*(jnp.where(sc > 0, wc / jnp.where(sc > 0, sc, 1.0), 0.0)
                                for wc, sc in zip(ff_weight, sigma_s)))
            if not grid or in_grid is not None:
                pdf = jnp.where(ff.pdf > 0, ff.pdf, 1.0)
                t_over_p_h = V3(*(jnp.where(ff.pdf > 0, c / pdf, 0.0)
                                  for c in media.transmittance(medium.sigma_t, ff.t)))
                t_over_p = t_over_p_h if not grid else where(in_grid, t_over_p, t_over_p_h)
            stored_pw = where(in_medium, pw_arrival * t_over_p, stored_pw)
            store = store | in_medium
            through = through & ~in_medium
            zero = jnp.zeros_like(x.x)
            p_at = where(in_medium, x, hit.p)
            n_at = where(in_medium, V3(zero, zero, zero), n_arrival)
            origin = where(in_medium, x, geometry.offset_origin(hit.p, hit.n, bs.wi))
            bs = bsdf.BSDFSample(where(in_medium, ph.d_out, bs.wi),
                                 where(in_medium, ff_weight, bs.weight),
                                 jnp.where(in_medium, ph.pdf, bs.pdf), bs.delta & ~in_medium,
                                 bs.valid | in_medium)
        record = (p_at, stored_pw, -d, n_at, store & ~through & spec_seen & only_spec, store)
        q = jnp.clip(max_component(bs.weight), 0.0, 1.0)
        survive = alive & bs.valid & (u(base + 3) < q)
        pw = where(survive, pw * bs.weight / jnp.where(q > 0, q, 1.0), pw)
        o_next = geometry.offset_origin(hit.p, hit.n, bs.wi) if origin is None else origin
        only_spec = only_spec & (bs.delta | through)
        spec_seen = spec_seen | bs.delta | through
        medium_id = medium_interfaces.leaving(scene, medium_id, hit.material, hit.n, bs.wi,
                                              in_medium)
        return materialize(((o_next, bs.wi, pw, survive, spec_seen, only_spec, medium_id),
                            record))

    _, rec = jax.lax.scan(bounce, state, jnp.arange(max_depth))
    p, pw, wi, n, caustic, valid = rec
    depth = jnp.broadcast_to(jnp.arange(max_depth, dtype=jnp.int32)[:, None], caustic.shape)
    return PhotonMap(p, pw, wi, n, caustic, depth), valid


@partial(jax.jit, static_argnames=("chunk", "max_depth"))
def _trace_chunk(scene, seed, start, n_emitted, *, chunk, max_depth):
    """Photons start .. start + chunk - 1: their stored records in (bounce, photon) order,
    compacted to the front, and how many there are. The compaction runs here, fused with the
    tracing: on the host, boolean indexing of the 14 [max_depth, chunk] fields took as long as
    the tracing itself (perf: docs/performance.md#photon-passes)."""
    idx = start + jnp.arange(chunk, dtype=jnp.int32)
    pm, valid = trace_photon_paths(scene, seed, idx, n_emitted, max_depth)
    valid = (valid & (idx < n_emitted)[None, :]).reshape(-1)
    stored = live_indices(valid, fill=0)
    return jax.tree_util.tree_map(lambda a: a.reshape(-1)[stored], pm), jnp.sum(valid)


@dataclass(frozen=True)
class PhotonChunk:
    """Photons start .. start + chunk - 1 of n_emitted, as a call of
    :func:`jgi.core.sharding.sharded_calls` (hashable by value: its compile-cache key)."""

    chunk: int
    max_depth: int

    def __call__(self, scene, seed, start, _pixel0, n_emitted):
        return _trace_chunk.__wrapped__(scene, seed, start, n_emitted, chunk=self.chunk,
                                        max_depth=self.max_depth)


def trace_photons(scene: Scene, n_photons: int, seed: int = 0, max_depth: int = 8,
                  chunk: int = 1 << 16, devices=None) -> PhotonMap:
    """Emit ``n_photons`` photons and return the stored ones (numpy arrays, compacted).

    Photon i uses random stream (seed, i), so the map does not depend on ``chunk`` or on the
    number of ``devices`` (default: all visible; chunks are split over them with
    :mod:`jgi.core.sharding`); chunks keep memory bounded (13 floats per stored photon)."""
    if scene.lights.count == 0:
        raise ValueError("the scene has no lights to emit photons from")
    # lanes: four sizes per octave, not the next power of two (20,000 photons: 20,480 lanes,
    # not 32,768)
    chunk = int(min(chunk, padded_size(max(n_photons, 1), minimum=256)))
    starts = list(range(0, n_photons, chunk))
    devices = list(devices if devices is not None else jax.devices())
    parts = []

    def keep(pm, count):
        n = int(count)
        parts.append(jax.tree_util.tree_map(lambda a: np.asarray(a)[:n], pm))

    if len(devices) == 1:
        def call(i):
            pm, count = _trace_chunk(scene, jnp.uint32(seed), jnp.int32(starts[i]),
                                     jnp.int32(n_photons), chunk=chunk, max_depth=max_depth)
            return jax.tree_util.tree_map(np.asarray, pm), np.asarray(count)

        for pm, count in ordered_calls(call, len(starts)):
            keep(pm, count)
    else:
        mesh = device_mesh(devices)
        D = len(devices)
        for first in range(0, len(starts), D):
            group = [starts[min(first + k, len(starts) - 1)] for k in range(D)]
            pm, count = sharded_calls(scene, jnp.uint32(seed), jnp.asarray(group, jnp.int32),
                                      jnp.zeros(D, jnp.int32), jnp.full(D, n_photons, jnp.int32),
                                      call=PhotonChunk(chunk, max_depth), mesh=mesh)
            for k in range(min(D, len(starts) - first)):  # in chunk order, as on one device
                keep(jax.tree_util.tree_map(lambda a: a[k], pm), count[k])
    return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs), *parts)
