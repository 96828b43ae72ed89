"""Rendering entry points: ``render`` (any registered estimator) and the chunked per-path driver.

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

from .estimators import registry
from .scene import Scene
from .vec import V3

DEFAULT_CHUNK = 1 << 16
CHUNKS_PER_CALL = 4

_COMPILED: dict = {}  # compile cache: (estimator key, chunk size) -> jitted fn


def render(scene: Scene | str, estimator: str = "pt", spp: int = 16, seed: int = 0,
           progress: bool = False, **params) -> np.ndarray:
    """Render ``scene`` with a registered estimator; float32 linear radiance, shape (H, W, 3).

    ``params`` are the estimator's parameters (``jgi render --list`` shows them); unknown
    names and out-of-range values raise :class:`jgi.ParameterError`."""
    if isinstance(scene, str):
        from .scenefile import load_scene
        scene = load_scene(scene)
    est = registry.get(estimator)
    if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
        raise registry.ParameterError(f"spp must be a positive integer, got {spp!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**32:
        raise registry.ParameterError(f"seed must be an integer in [0, 2^32), got {seed!r}")
    resolved = est.resolve(params)
    return est.run(scene, spp=int(spp), seed=int(seed), progress=progress, **resolved)


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
    per_call = chunk * CHUNKS_PER_CALL
    img = None
    bad = 0
    t0 = time.perf_counter()
    done = 0
    while done < total:
        sample0, pixel0 = divmod(done, P)
        part, nbad = fn(scene, jnp.uint32(seed), jnp.int32(sample0), jnp.int32(pixel0),
                        jnp.int32(min(per_call, total - done)))
        img = part if img is None else img + part
        bad = bad + nbad
        done += per_call
        if progress:
            _progress(min(done, total), total, time.perf_counter() - t0)
    bad = int(bad)
    out = np.asarray(img, np.float32).reshape(H, W, 3) / np.float32(spp)
    if progress:
        sys.stderr.write("\n")
    if bad:
        warnings.warn(f"{bad} path samples were not finite and were dropped", RuntimeWarning)
    return out


def _progress(done: int, total: int, elapsed: float) -> None:
    frac = done / total
    eta = elapsed / frac - elapsed if frac > 0 else 0.0
    bar = "#" * int(30 * frac)
    rate = done / max(elapsed, 1e-9) / 1e6
    sys.stderr.write(f"\r[{bar:<30}] {100 * frac:5.1f}%  {rate:6.2f} Mpaths/s  ETA {eta:6.1f}s")
    sys.stderr.flush()
