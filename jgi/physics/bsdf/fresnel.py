"""Fresnel reflectance and Snell's law for smooth dielectric interfaces."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ...core.vec import V3, dot


def cos2_transmitted(cos_i: Array, eta: Array) -> Array:
    """cos^2(theta_t) = 1 - (1 - cos_i^2) / eta^2 (Snell), <= 0 under total internal reflection.

    Written as (cos_i^2 + eta^2 - 1) / eta^2: the textbook form cancels catastrophically in
    float32 at grazing incidence (for eta = 1 it gave F = 1e-5 at cos_i = 1e-3 instead of 0)."""
    return (cos_i * cos_i + (eta * eta - 1.0)) / (eta * eta)


def fresnel_dielectric(cos_i: Array, eta: Array) -> Array:
    """Unpolarised Fresnel reflectance for relative index eta = eta_t / eta_i, cos_i >= 0."""
    cos2_t = cos2_transmitted(cos_i, eta)
    tir = cos2_t <= 0.0
    cos_t = jnp.sqrt(jnp.maximum(cos2_t, 0.0))
    r_parl = (eta * cos_i - cos_t) / jnp.maximum(eta * cos_i + cos_t, 1e-12)
    r_perp = (cos_i - eta * cos_t) / jnp.maximum(cos_i + eta * cos_t, 1e-12)
    return jnp.where(tir, 1.0, 0.5 * (r_parl * r_parl + r_perp * r_perp))


def refract(wo: V3, n: V3, eta: Array) -> tuple[V3, Array]:
    """Transmitted direction for wo on n's side, eta = eta_t / eta_i; (direction, valid)."""
    cos_i = dot(wo, n)
    cos2_t = cos2_transmitted(cos_i, eta)
    ok = cos2_t > 0.0
    cos_t = jnp.sqrt(jnp.maximum(cos2_t, 0.0))
    return (-wo) / eta + n * (cos_i / eta - cos_t), ok
