"""Counter-based random numbers: u = hash(seed, pixel, sample, dimension) -> [0, 1).

Why not ``jax.random``: XLA's CPU backend lowers threefry as a rolled loop that cannot fuse into
the path tracer's bounce kernel (measured 1.2 vs 14 Mpaths/s). A stateless integer hash costs a
handful of fused integer ops per number, and every number is reproducible from its coordinates,
so a path's samples do not depend on chunking, device count or evaluation order.

The mixer is Wellons' ``lowbias32`` (hash-prospector), a bijective 32-bit avalanche function.
Streams for (seed, pixel, sample) are decorrelated by chaining the mixer over each coordinate;
dimensions are then an additive counter with a Weyl increment before mixing.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

_U32 = jnp.uint32
_WEYL = 0x9E3779B9  # 2^32 / golden ratio


def lowbias32(x: Array) -> Array:
    x = x.astype(_U32)
    x = x ^ (x >> 16)
    x = x * _U32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * _U32(0x846CA68B)
    x = x ^ (x >> 16)
    return x


def path_key(seed, pixel, sample) -> Array:
    """A 32-bit stream key for one path, from (seed, pixel index, sample index)."""
    k = lowbias32(jnp.asarray(seed).astype(_U32) ^ _U32(0x5BD1E995))
    k = lowbias32(k ^ jnp.asarray(pixel).astype(_U32))
    k = lowbias32(k + jnp.asarray(sample).astype(_U32) * _U32(_WEYL))
    return k


def uniform(key: Array, dim) -> Array:
    """The ``dim``-th uniform float32 in [0, 1) of stream ``key`` (24 random bits)."""
    return uniform_at(counter(key, dim), 0)


def counter(key: Array, dim) -> Array:
    """The hash input of dimension ``dim`` of stream ``key``; with :func:`uniform_at`, a block of
    consecutive dimensions costs one add each (``uniform(key, dim + k) == uniform_at(counter(key,
    dim), k)`` exactly, by arithmetic modulo 2^32)."""
    return key + (jnp.asarray(dim).astype(_U32) + _U32(1)) * _U32(_WEYL)


def uniform_at(c: Array, k: int) -> Array:
    """Uniform number ``k`` dimensions after the counter ``c`` (see :func:`counter`)."""
    h = lowbias32(c + _U32((k * _WEYL) & 0xFFFFFFFF)) if k else lowbias32(c)
    return (h >> 8).astype(jnp.float32) * jnp.float32(1.0 / 16777216.0)


def uniforms(key: Array, first_dim: int, n: int) -> Array:
    """Dimensions ``first_dim .. first_dim + n - 1`` of stream ``key``, stacked: [n, *key.shape]
    (a vector of primary samples, one column per stream)."""
    # one [n, ...] hash of broadcast counters, the same numbers as stacking uniform(key, dim)
    # (perf: docs/performance.md#mmlt, a stack of n hashes compiled and ran as n kernels)
    key = jnp.asarray(key).astype(_U32)
    offsets = ((np.arange(n, dtype=np.uint64) + first_dim + 1) * _WEYL) & 0xFFFFFFFF
    c = key[None] + jnp.asarray(offsets.astype(np.uint32)).reshape((n,) + (1,) * key.ndim)
    return (lowbias32(c) >> 8).astype(jnp.float32) * jnp.float32(1.0 / 16777216.0)


# Every salt :func:`derive` is given in jgi, named by stream. A stream is
# ``derive(path_key(seed, i, j), salt)``: two streams with one salt and one (seed, i, j) are the
# same numbers, so salts must differ between streams that one estimate uses together. Camera
# paths use ``path_key(seed, pixel, sample)`` itself (no salt), shared by every estimator.
SALTS: dict[str, int] = {
    "photons": 0x1E3779B1,            # photon paths, per photon (transport.photons)
    "light_subpath": 0x2C1B3C6D,      # light subpaths of lt and bdpt, per (pixel, sample)
    "final_gather": 0x1B873593,       # pm_jensen's final-gather rays, per (point, ray)
    "irradiance_gather": 0x3C6EF372,  # the irradiance cache's gather rays, per (point, ray)
    "mcmc": 0x27D4EB2F,               # transport.mcmc chains, per (chain, step)
    "pssmlt": 0x2545F491,             # PSSMLT bootstrap; + 1: its chains, per (chain, step)
    "mmlt": 0x5F3759DF,               # MMLT chains of path length L: + 1 + L, per (chain, step)
    # ratio tracking of shadow ray j through a grid medium: + j, from the bounce's flight stream
    # (substream), per (path, bounce), in the path tracer; the connections of the other
    # estimators (transport.connection.shadow_transmittance): + 0, from the shadow ray (ray_key)
    "ratio_tracking": 0x6A09E667,
    # the trackings of volume v >= 1 of the scene's own medium where it is several (+ v), from
    # the flight's or shadow ray's stream (physics.medium_interfaces)
    "grid_volume": 0x3F84D5B5,
    # Veach's MLT: bootstrap paths; + 1: chain steps. The bootstrap shares its value with
    # "final_gather": harmless, as no estimate uses both (pm_jensen never runs an MLT chain,
    # mlt never final-gathers), and estimators run with one seed are correlated anyway through
    # the shared camera stream; a distinct value would change every mlt image.
    "mlt": 0x1B873593,
}
# Sub-streams of one step's key (``derive(key, k)``, k small), in pssmlt's, mmlt's and mlt's
# chain steps: 7 the small step's signs, 11 the large step's fresh sample, 3 the mutation.


def derive(key: Array, salt) -> Array:
    """An independent sub-stream (e.g. per light subpath, per photon pass); ``salt`` from
    :data:`SALTS`."""
    return lowbias32(key ^ lowbias32(jnp.asarray(salt).astype(_U32) + _U32(0x68E31DA4)))



def substream(u1: Array, u2: Array) -> Array:
    """A stream key that is a pure function of two uniforms of a path's own stream (their 48
    random bits chained through the mixer): an unbounded run of numbers where a loop needs more
    than the fixed dimensions a bounce reserves (the tracking of heterogeneous media,
    :mod:`jgi.physics.grid_media`). Works alike on hashed streams and on primary-sample vectors."""
    bits = [jax.lax.bitcast_convert_type(jax.lax.stop_gradient(jnp.asarray(u, jnp.float32)), _U32)
            for u in (u1, u2)]
    return lowbias32(lowbias32(bits[0] ^ _U32(0x7F4A7C15)) ^ bits[1])


def ray_key(o, d, key: Array) -> Array:
    """A stream key that is a pure function of a ray (origin ``o``, direction ``d``, each three
    float32 arrays) and an integer ``key``: the bits of the seven numbers chained through the
    mixer. The ray is itself random, so this is a fresh stream for every ray, with nothing to
    carry to where it is used (pbrt-v4 seeds its shadow rays' ratio tracking from a hash of the
    ray alike)."""
    h = lowbias32(jnp.asarray(key).astype(_U32) ^ _U32(0x2C1B3C6D))
    for c in (*o, *d):   # (bits have no derivative: the ray's gradient is stopped here)
        bits = jax.lax.bitcast_convert_type(
            jax.lax.stop_gradient(jnp.asarray(c, jnp.float32)), _U32)
        h = lowbias32(h ^ bits)
    return h


def ray_uniform(o, d, key: Array) -> Array:
    """A uniform float32 in [0, 1) that is a pure function of a ray and an integer ``key`` (a
    primitive): the top 24 bits of :func:`ray_key`. pbrt-v4's HashFloat(ray.o, ray.d) for alpha
    masks."""
    return (ray_key(o, d, key) >> 8).astype(jnp.float32) * jnp.float32(1.0 / 16777216.0)
