"""The warps of :mod:`jgi.core.warps`, jitted, and the inputs and grids their chi-square tests
use (tests/test_warps.py and the paper's table, paper/chi2_table.py)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jgi.analysis.chi2 import SphereDomain
from jgi.core import warps

N = 200_000  # samples per test unless told


def uniforms(seed: int, n: int = N, k: int = 2) -> np.ndarray:
    """k rows of n float32 uniforms from a fixed-seed numpy generator."""
    return np.random.default_rng(seed).random((k, n), dtype=np.float32)


def stack(v) -> np.ndarray:
    """The components of a warp's result as columns of one array."""
    return np.stack([np.asarray(c) for c in v], axis=-1)


@jax.jit
def sample_cosine(u1, u2):
    """:func:`warps.sample_cosine_hemisphere`, jitted."""
    return warps.sample_cosine_hemisphere(u1, u2)


@jax.jit
def sample_sphere(u1, u2):
    """:func:`warps.sample_uniform_sphere`, jitted."""
    return warps.sample_uniform_sphere(u1, u2)


@jax.jit
def sample_cone(u1, u2, cos_max):
    """:func:`warps.sample_uniform_cone`, jitted."""
    return warps.sample_uniform_cone(u1, u2, cos_max)


@jax.jit
def sample_phong(u1, u2, n):
    """:func:`warps.sample_phong_lobe`, jitted."""
    return warps.sample_phong_lobe(u1, u2, n)


@jax.jit
def sample_disc(u1, u2):
    """:func:`warps.sample_concentric_disc`, jitted."""
    return warps.sample_concentric_disc(u1, u2)


@jax.jit
def sample_triangle(u1, u2):
    """:func:`warps.sample_uniform_triangle`, jitted."""
    return warps.sample_uniform_triangle(u1, u2)


def f32(x):
    return jnp.asarray(x, jnp.float32)


def z_of(d):
    """The z components of directions d [N, 3], as float32."""
    return jnp.asarray(d[:, 2], jnp.float32)


def phong_domain(n: float) -> SphereDomain:
    """Grid for a Phong lobe of exponent n about +z."""
    # geometric rings in a = 1 - cos(alpha) resolve the lobe (width ~ 1/n) for every exponent
    return SphereDomain(a_edges=np.concatenate([[0.0], np.geomspace(0.02 / (n + 1), 1.0, 40)]))
