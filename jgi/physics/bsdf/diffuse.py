"""Lambertian diffuse reflection: f = k_d / pi, sampled cosine-weighted, pdf = cos(theta_i) / pi.
Two-sided: ``nf`` is the normal on wo's side (:func:`.common.side`)."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ...core import warps
from ...core.vec import V3, dot, to_world, where
from .common import BSDFSample, MaterialParams, lit


def evaluate(mp: MaterialParams, cos_i: Array) -> tuple[V3, Array]:
    """(f, pdf) for a direction at cos(theta_i) = cos_i above the surface (the caller masks
    directions below it)."""
    return mp.kd * jnp.float32(1.0 / jnp.pi), warps.pdf_cosine_hemisphere(cos_i)


def sample_direction(nf: V3, u1: Array, u2: Array) -> V3:
    """A cosine-weighted direction about nf (Malley's method)."""
    return to_world(warps.sample_cosine_hemisphere(u1, u2), nf)


def sample(mp: MaterialParams, nf: V3, cos_o: Array, u1: Array, u2: Array) -> BSDFSample:
    """Weight f cos / pdf = k_d exactly."""
    wi = sample_direction(nf, u1, u2)
    zero = jnp.zeros_like(u1)
    ok = lit(cos_o) & lit(dot(wi, nf))
    return BSDFSample(wi, where(ok, mp.kd, V3(zero, zero, zero)),
                      jnp.where(ok, warps.pdf_cosine_hemisphere(dot(wi, nf)), 0.0), zero > 0, ok)
