"""The one entry point for rendering: ``jgi.render(scene, estimator, spp=, seed=, **params)``.

Dispatches to a registered estimator (:mod:`jgi.estimators.registry`) after checking every
parameter against its declared schema, so a typo is an error naming the key and what is allowed.
:func:`render` returns the image; :func:`render_result` the image and the estimator's
statistics (acceptance rates, photon counts, ...) as a :class:`~jgi.estimators.registry.Render`.
With ``progress=True`` the render is tracked by :func:`jgi.core.progress.tracking`: a bar (or the
study's display) shows compilation apart from rendering, and rates and ETA from render time.
"""

from __future__ import annotations

import numpy as np

from . import estimators  # noqa: F401  (registers every estimator)
from .core.errors import ParameterError
from .core.progress import tracking
from .estimators import registry
from .estimators.registry import Render
from .scene.files import load_scene
from .scene.tables import Scene


def render_result(scene: Scene | str, estimator: str = "pt", spp: int = 16, seed: int = 0,
                  progress: bool = False, **params) -> Render:
    """Render ``scene`` with a registered estimator: ``Render(image, stats)``, the image as
    :func:`render` returns it and a dict of the estimator's statistics ({} if it keeps none;
    each estimator module's ``render`` documents its keys)."""
    if isinstance(scene, str):
        scene = load_scene(scene)
    est = registry.get(estimator)
    if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
        raise ParameterError(f"spp must be a positive integer, got {spp!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**32:
        raise ParameterError(f"seed must be an integer in [0, 2^32), got {seed!r}")
    cfg = est.resolve(params)
    est.refuse_media(scene)
    if not progress:
        return est.run(scene, cfg, spp=int(spp), seed=int(seed), progress=False)
    with tracking(f"{estimator} {spp} spp"):   # compiling shown apart from rendering
        return est.run(scene, cfg, spp=int(spp), seed=int(seed), progress=True)


def render(scene: Scene | str, estimator: str = "pt", spp: int = 16, seed: int = 0,
           progress: bool = False, **params) -> np.ndarray:
    """Render ``scene`` with a registered estimator; float32 linear radiance, shape (H, W, 3).

    ``params`` are the estimator's parameters (``jgi render --list`` shows them); unknown
    names, former names and out-of-range values raise :class:`jgi.ParameterError`. For the
    estimator's statistics as well, use :func:`render_result`."""
    return render_result(scene, estimator, spp=spp, seed=seed, progress=progress, **params).image
