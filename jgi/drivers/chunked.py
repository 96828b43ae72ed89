"""The chunked per-path driver: every (pixel, sample) path of a render, in chunks.

An estimator written per path hands the driver a *path function*

    path_fn(scene, seed, pixel, sample) -> [(image, pixel, value), ...]

for [N] arrays of flat pixel indices and sample indices: each contribution is added to image
``image`` (a static int) at flat pixel ``pixel`` ([N] int32, -1: none; the sample's own pixel,
or any pixel it splats into, as light tracing does) with ``value`` (a V3 of [N]).
:func:`accumulate` evaluates it for every (pixel, sample) pair in chunks of ``chunk`` paths,
several chunks per jitted call, summing the images on the device, so memory stays bounded at
any spp. Path (pixel p, sample s) always draws its random numbers from the stream (seed, p, s),
so the image does not depend on chunk sizes, and the sums are scatter-adds in a fixed order, so
it is reproducible bit for bit.

``path_fn`` is a static argument of the jitted :func:`accumulate`: JAX's compile cache keys
on it, so it must be hashable and equal by value (a :class:`jgi.core.configured.Configured`,
not a lambda). One compilation then serves every spp, seed and chunk count, and every scene of
the same structure (its values are arguments, not constants).

:func:`render_paths` is the driver for path functions that return one radiance value for the
sample's own pixel; :func:`jgi.drivers.splat.render_splats` for splatting ones.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import partial
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..core import calls
from ..core.progress import advance
from ..core.sharding import device_mesh, sharded_calls
from ..core.vec import V3
from ..scene.tables import Scene

DEFAULT_CHUNK = 1 << 16
CHUNKS_PER_CALL = 4


@partial(jax.jit, static_argnames=("path_fn", "chunk", "n_images"))
def accumulate(scene: Scene, seed, sample0, pixel0, count, *, path_fn: Callable, chunk: int,
               n_images: int = 1):
    """The sums over paths sample0 * P + pixel0 .. + count - 1 (flat index sample * P + pixel)
    of ``path_fn``'s contributions: images (n_images, P, 3), and how many contributions were
    not finite (dropped). ``count`` is traced: one compilation for any number of chunks."""
    W, H = scene.camera.width, scene.camera.height
    P = W * H
    lane = jnp.arange(chunk, dtype=jnp.int32)

    def body(c, acc):
        img, bad = acc
        local = c * chunk + lane
        flat = pixel0 + local
        pixel = flat % P
        sample = sample0 + flat // P
        valid = local < count
        contribs = path_fn(scene, seed, pixel, sample)
        # stacked to [M, N] first: one finiteness test and one scatter for all of them
        image = jnp.asarray(np.repeat([c[0] for c in contribs], chunk).reshape(-1, chunk))
        px = jnp.stack([jnp.broadcast_to(c[1], (chunk,)) for c in contribs])
        L = V3(*(jnp.stack([c[2][k] for c in contribs]) for k in range(3)))
        finite = jnp.isfinite(L.x) & jnp.isfinite(L.y) & jnp.isfinite(L.z)
        bad = bad + jnp.sum(valid & (px >= 0) & ~finite)
        keep = valid & (px >= 0) & finite
        vals = jnp.stack([jnp.where(keep, c_, 0.0) for c_ in L], -1)
        img = img.at[image.reshape(-1), jnp.where(keep, px, 0).reshape(-1)].add(vals.reshape(-1, 3))
        return img, bad

    init = (jnp.zeros((n_images, P, 3), jnp.float32), jnp.int32(0))
    n_chunks = (count + chunk - 1) // chunk  # traced: one compile for any count
    return jax.lax.fori_loop(0, n_chunks, body, init)


@dataclass(frozen=True)
class AtOwnPixel:
    """A path function ``radiance(scene, seed, pixel, sample) -> V3`` as one contribution to
    image 0 at the sample's own pixel (hashable by value, as ``radiance`` is)."""

    radiance: Callable

    def __call__(self, scene, seed, pixel, sample):
        return [(0, pixel, self.radiance(scene, seed, pixel, sample))]


def default_chunk(scene: Scene, largest: int) -> int:
    """Paths per chunk: the image's pixel count rounded up to a power of two (at least 256),
    at most ``largest``. It depends on the image size only, so every spp reuses one
    compilation."""
    P = scene.camera.width * scene.camera.height
    return min(largest, 1 << max(int(np.ceil(np.log2(P))), 8))


def sum_path_chunks(scene: Scene, path_fn: Callable, *, seed: int, total: int, chunk: int,
                    n_images: int, progress: bool) -> tuple[np.ndarray, int]:
    """:func:`accumulate` over paths 0 .. ``total`` - 1 in calls of ``CHUNKS_PER_CALL`` chunks,
    with calls in flight as :func:`jgi.core.calls.sum_calls` runs them: the images
    (n_images, P, 3), summed in call order, and the number of dropped contributions."""
    P = scene.camera.width * scene.camera.height
    per_call = chunk * CHUNKS_PER_CALL

    def call(i):
        sample0, pixel0 = divmod(i * per_call, P)
        return accumulate(scene, jnp.uint32(seed), jnp.int32(sample0), jnp.int32(pixel0),
                          jnp.int32(min(per_call, total - i * per_call)), path_fn=path_fn,
                          chunk=chunk, n_images=n_images)

    def report(i):
        if progress:
            advance(min((i + 1) * per_call, total), total)

    return calls.sum_calls(call, -(-total // per_call), on_done=report)


def render_paths(scene: Scene, radiance: Callable[..., V3], *, spp: int, seed: int,
                 progress: bool = False, chunk: int | None = None) -> np.ndarray:
    """Average of ``radiance(scene, seed, pixel, sample) -> V3`` over ``spp`` samples per
    pixel, each added to its own pixel: (H, W, 3). ``radiance`` must be hashable by value
    (see the module docstring)."""
    W, H = scene.camera.width, scene.camera.height
    img, bad = sum_path_chunks(scene, AtOwnPixel(radiance), seed=seed, total=W * H * spp,
                               chunk=chunk or default_chunk(scene, DEFAULT_CHUNK), n_images=1,
                               progress=progress)
    if bad:
        warnings.warn(f"{bad} path samples were not finite and were dropped", RuntimeWarning)
    return img.reshape(H, W, 3) / np.float32(spp)


@dataclass(frozen=True)
class PathChunks:
    """:func:`accumulate`'s images for one call, as a call of
    :func:`jgi.core.sharding.sharded_calls` (hashable by value)."""

    path_fn: Callable
    chunk: int
    n_images: int = 1

    def __call__(self, scene, seed, sample0, pixel0, count):
        return accumulate.__wrapped__(scene, seed, sample0, pixel0, count, path_fn=self.path_fn,
                                      chunk=self.chunk, n_images=self.n_images)


def render_paths_sharded(scene, radiance, *, spp: int, seed: int, chunk: int,
                         chunks_per_call: int, devices=None) -> np.ndarray:
    """:func:`render_paths` with the calls split over ``devices`` (default: all), the same
    image bit for bit."""
    mesh = device_mesh(devices)
    D = mesh.devices.size
    W, H = scene.camera.width, scene.camera.height
    Pn = W * H
    total = Pn * spp
    per_call = chunk * chunks_per_call
    call = PathChunks(AtOwnPixel(radiance), chunk)
    img, bad = None, 0
    n_calls = -(-total // per_call)
    for first in range(0, n_calls, D):
        starts = [min(c, n_calls) * per_call for c in range(first, first + D)]
        s0 = jnp.asarray([s // Pn for s in starts], jnp.int32)
        p0 = jnp.asarray([s % Pn for s in starts], jnp.int32)
        cnt = jnp.asarray([max(0, min(per_call, total - s)) for s in starts], jnp.int32)
        parts, dropped = sharded_calls(scene, jnp.uint32(seed), s0, p0, cnt, call=call, mesh=mesh)
        parts, dropped = np.asarray(parts), np.asarray(dropped)
        for k in range(D):  # add in call order: bitwise equal to the single-device sum
            if first + k < n_calls:
                img = parts[k] if img is None else img + parts[k]
                bad += int(dropped[k])
    if bad:
        warnings.warn(f"{bad} path samples were not finite and were dropped", RuntimeWarning)
    return img.reshape(H, W, 3) / np.float32(spp)
