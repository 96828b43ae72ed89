"""The splatting driver: light paths whose contributions land anywhere on the film.

Light tracing and BDPT's t = 1 strategies connect light-subpath vertices to the pinhole, so a
sample contributes to the pixel its vertex projects to, not (only) to its own. Their path
functions return contribution lists (see :mod:`jgi.drivers.chunked`), summed by the same
:func:`jgi.drivers.chunked.accumulate` as every per-path estimator; several images at once
(BDPT's per-strategy images) are indexed by each contribution's image number.
"""

from __future__ import annotations

import warnings
from typing import Callable

import numpy as np

from ..scene.tables import Scene
from .chunked import default_chunk, sum_path_chunks

DEFAULT_CHUNK = 1 << 13   # smaller than render_paths': a light path carries max_depth splats


def render_splats(scene: Scene, path_fn: Callable, *, spp: int, seed: int, n_images: int = 1,
                  progress: bool = False, chunk: int | None = None) -> np.ndarray:
    """Sum over spp samples per pixel of ``path_fn(scene, seed, pixel, sample)``'s contributions,
    each (image index, flat pixel (-1: none), V3 value) and splatted anywhere in the film, divided
    by spp: shape (n_images, H, W, 3). ``path_fn`` must be hashable by value (it keys the compile
    cache, see :mod:`jgi.drivers.chunked`). Path (pixel, sample) draws from the stream (seed,
    pixel, sample) whatever the chunking; the scatter-add is sequential, so results are
    reproducible."""
    W, H = scene.camera.width, scene.camera.height
    img, bad = sum_path_chunks(scene, path_fn, seed=seed, total=W * H * spp,
                               chunk=chunk or default_chunk(scene, DEFAULT_CHUNK),
                               n_images=n_images, progress=progress)
    if bad:
        warnings.warn(f"{bad} path contributions were not finite and were dropped", RuntimeWarning)
    return img.reshape(n_images, H, W, 3) / np.float32(spp)
