"""jgi: global-illumination estimators as pure JAX functions, for studying them.

    import jgi
    scene = jgi.load_scene("cornell_box")          # a built-in, or a .toml scene file
    image = jgi.render(scene, "pt", spp=64, seed=0, strategy="mis", heuristic="power")
    image, stats = jgi.render_result(scene, "pssmlt", spp=64)   # with the estimator's statistics

Compiled programs are cached on disk for later processes (:mod:`jgi.compile_cache`:
``JGI_CACHE_DIR``, ``JGI_CACHE_DIR=off``).
"""

from . import _xla  # noqa: F401, I001  (performance flags; must precede JAX's backend start-up)
from . import compile_cache
from . import estimators
from .api import render, render_result
from .core.errors import ParameterError
from .estimators.registry import REGISTRY, Render
from .scene import builtin as scenes
from .scene.builder import SceneBuilder, SceneError
from .scene.tables import Scene
from .scene.files import load_scene

compile_cache.configure_from_environment()   # programs persist between processes (see there)

__version__ = "0.1.0"
__all__ = ["render", "render_result", "Render", "load_scene", "Scene", "SceneBuilder", "SceneError",
           "ParameterError", "REGISTRY", "scenes", "estimators", "compile_cache"]
