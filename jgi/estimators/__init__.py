"""Estimators register themselves in :mod:`jgi.estimators.registry` when imported here."""

from ..core.errors import ParameterError
from . import (
    bdpt,  # noqa: F401
    irradiance_cache,  # noqa: F401  (registers "irradiance_cache")
    light_tracer,  # noqa: F401
    mlt,  # noqa: F401
    mmlt,  # noqa: F401
    path_tracer,  # noqa: F401
    photon_mapping,  # noqa: F401
    pssmlt,  # noqa: F401
    vcm,  # noqa: F401
    whitted,  # noqa: F401
)
from .registry import REGISTRY, Estimator, Param, Render, get, param, params_of, register

__all__ = ["REGISTRY", "Estimator", "Param", "ParameterError", "Render", "get", "param",
           "params_of", "register"]
