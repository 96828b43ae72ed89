"""Estimators register themselves in :mod:`jgi.estimators.registry` when imported here."""

from . import path_tracer  # noqa: F401
from . import whitted  # noqa: F401
from . import pssmlt  # noqa: F401
from . import photon_mapping  # noqa: F401
from . import light_tracer  # noqa: F401
from . import bdpt  # noqa: F401
from . import mmlt  # noqa: F401
from . import mlt  # noqa: F401
from .. import irradiance_cache  # noqa: F401  (registers "irradiance_cache")
from .registry import REGISTRY, Estimator, Param, ParameterError, get, register

__all__ = ["REGISTRY", "Estimator", "Param", "ParameterError", "get", "register"]
