"""A function with its static settings, hashable by value: the key of every compile cache.

The drivers jit their loops with the estimator's path function as a *static* argument
(``jax.jit(..., static_argnames=...)``), so JAX's own compile cache keys on the function that
runs: two renders share a compilation exactly when their path functions are equal. A lambda
or a ``functools.partial`` is equal only to itself, so each render would compile anew, and a
bound method of a settings dataclass compares ``__self__`` by identity (Python >= 3.8), which
fails the same way; a caller-chosen cache key string could name two different functions.
:class:`Configured` is equal to another exactly when both the function and the settings are.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Hashable


@dataclass(frozen=True)
class Configured:
    """``Configured(fn, config)(scene, *args) == fn(scene, config, *args)``.

    ``fn`` is a module-level function (equal only to itself); ``config`` its static settings, a
    frozen dataclass or another value that is hashable and compares by value."""

    fn: Callable
    config: Hashable

    def __call__(self, scene, *args):
        return self.fn(scene, self.config, *args)
