"""The chunked per-path driver: every (pixel, sample) path of a render, in chunks.

``render_paths`` evaluates a per-path estimator for every (pixel, sample) pair in chunks of
``chunk`` paths, several chunks per jitted call, accumulating pixel sums on the device, so
memory stays bounded at any spp and one compilation serves every chunk and every render of
scenes with the same structure. Path (pixel p, sample s) always draws its random numbers from
the stream (seed, p, s): the image does not depend on chunk sizes.
"""

from __future__ import annotations

import sys
import time
import warnings
from functools import partial
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..core import calls
from ..core.sharding import device_mesh, sharded_calls
from ..core.vec import V3
from ..scene.data import Scene

DEFAULT_CHUNK = 1 << 16
CHUNKS_PER_CALL = 4

_COMPILED: dict = {}  # compile cache: (estimator key, chunk size) -> jitted fn


def _accumulate(scene: Scene, seed, sample0, pixel0, total_left, *, path_fn, chunk):
    W, H = scene.camera.width, scene.camera.height
    P = W * H
    lane = jnp.arange(chunk, dtype=jnp.int32)

    def body(c, acc):
        img, bad = acc
        local = c * chunk + lane
        flat = pixel0 + local
        pixel = flat % P
        sample = sample0 + flat // P
        valid = local < total_left
        L = path_fn(scene, pixel, sample, seed)
        finite = jnp.isfinite(L.x) & jnp.isfinite(L.y) & jnp.isfinite(L.z)
        keep = valid & finite
        bad = bad + jnp.sum(valid & ~finite)
        vals = jnp.stack([jnp.where(keep, L.x, 0.0), jnp.where(keep, L.y, 0.0),
                          jnp.where(keep, L.z, 0.0)], axis=-1)
        return img.at[pixel].add(vals), bad

    init = (jnp.zeros((P, 3), jnp.float32), jnp.int32(0))
    n_chunks = (total_left + chunk - 1) // chunk  # traced: one compile for any count
    return jax.lax.fori_loop(0, n_chunks, body, init)


def render_paths(scene: Scene, path_fn: Callable[..., V3], *, spp: int, seed: int,
                 cache_key, progress: bool = False, chunk: int | None = None) -> np.ndarray:
    """Average of ``path_fn(scene, pixel, sample, seed) -> V3`` over ``spp`` samples per pixel.

    ``cache_key`` identifies ``path_fn`` (with its static settings) for the compile cache."""
    W, H = scene.camera.width, scene.camera.height
    P = W * H
    total = P * spp
    # the chunk size depends on the image size only, so every spp reuses one compilation
    chunk = chunk or min(DEFAULT_CHUNK, 1 << max(int(np.ceil(np.log2(P))), 8))
    key = (cache_key, chunk)
    fn = _COMPILED.get(key)
    if fn is None:
        fn = jax.jit(partial(_accumulate, path_fn=path_fn, chunk=chunk))
        _COMPILED[key] = fn
    img, bad = sum_path_chunks(fn, scene, seed, total, chunk * CHUNKS_PER_CALL, progress)
    out = img.reshape(H, W, 3) / np.float32(spp)
    if progress:
        sys.stderr.write("\n")
    if bad:
        warnings.warn(f"{bad} path samples were not finite and were dropped", RuntimeWarning)
    return out


def sum_path_chunks(fn, scene: Scene, seed: int, total: int, per_call: int,
                    progress: bool) -> tuple[np.ndarray, int]:
    """Sum of ``fn(scene, seed, sample0, pixel0, count) -> (part, dropped)`` over calls of
    ``per_call`` consecutive paths (flat index sample * P + pixel) until ``total``, with
    calls in flight as :func:`jgi.core.calls.sum_calls` runs them (render_paths, render_splats)."""
    P = scene.camera.width * scene.camera.height
    t0 = time.perf_counter()

    def call(i):
        sample0, pixel0 = divmod(i * per_call, P)
        return fn(scene, jnp.uint32(seed), jnp.int32(sample0), jnp.int32(pixel0),
                  jnp.int32(min(per_call, total - i * per_call)))

    def report(i):
        if progress:
            progress_line(min((i + 1) * per_call, total), total, time.perf_counter() - t0)

    return calls.sum_calls(call, -(-total // per_call), on_done=report)


def progress_line(done: int, total: int, elapsed: float) -> None:
    frac = done / total
    eta = elapsed / frac - elapsed if frac > 0 else 0.0
    bar = "#" * int(30 * frac)
    rate = done / max(elapsed, 1e-9) / 1e6
    sys.stderr.write(f"\r[{bar:<30}] {100 * frac:5.1f}%  {rate:6.2f} Mpaths/s  ETA {eta:6.1f}s")
    sys.stderr.flush()


def render_paths_sharded(scene, path_fn, *, spp: int, seed: int, cache_key, chunk: int,
                         chunks_per_call: int, devices=None) -> np.ndarray:
    """Sharded version of :func:`jgi.drivers.chunked.render_paths` (same arguments, same image)."""
    mesh = device_mesh(devices)
    D = mesh.devices.size
    W, H = scene.camera.width, scene.camera.height
    Pn = W * H
    total = Pn * spp
    per_call = chunk * chunks_per_call
    call = partial(_accumulate, path_fn=path_fn, chunk=chunk)
    fn = sharded_calls(lambda sc, sd, s0, p0, n: call(sc, sd, s0, p0, n)[0], mesh,
                       ("paths", cache_key, chunk))
    img = None
    n_calls = -(-total // per_call)
    for first in range(0, n_calls, D):
        starts = [min(c, n_calls) * per_call for c in range(first, first + D)]
        s0 = jnp.asarray([s // Pn for s in starts], jnp.int32)
        p0 = jnp.asarray([s % Pn for s in starts], jnp.int32)
        cnt = jnp.asarray([max(0, min(per_call, total - s)) for s in starts], jnp.int32)
        parts = np.asarray(fn(scene, jnp.uint32(seed), s0, p0, cnt))
        for k in range(D):  # add in call order: bitwise equal to the single-device sum
            if first + k < n_calls:
                img = parts[k] if img is None else img + parts[k]
    return img.reshape(H, W, 3) / np.float32(spp)
