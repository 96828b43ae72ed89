"""Fresnel reflectance and Snell's law: dielectric interfaces, and conductors (complex index of
refraction eta + i k)."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ...core.optics import cos2_transmitted, fresnel_dielectric_reflectance
from ...core.vec import V3, dot


def _sqrt0(x: Array) -> Array:
    """sqrt(max(x, 0)) with a finite gradient at 0 (inner where)."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def fresnel_dielectric(cos_i: Array, eta: Array) -> Array:
    """Unpolarised Fresnel reflectance for relative index eta = eta_t / eta_i, cos_i >= 0."""
    cos2_t = cos2_transmitted(cos_i, eta)
    tir = cos2_t <= 0.0
    cos_t = _sqrt0(cos2_t)   # finite gradient under total internal reflection
    return jnp.where(tir, 1.0, fresnel_dielectric_reflectance(cos_i, cos_t, eta, jnp))


def refract(wo: V3, n: V3, eta: Array) -> tuple[V3, Array]:
    """Transmitted direction for wo on n's side, eta = eta_t / eta_i; (direction, valid)."""
    cos_i = dot(wo, n)
    cos2_t = cos2_transmitted(cos_i, eta)
    ok = cos2_t > 0.0
    cos_t = _sqrt0(cos2_t)
    return (-wo) / eta + n * (cos_i / eta - cos_t), ok


def fresnel_conductor(cos_i: Array, eta: Array, k: Array) -> Array:
    """Unpolarised Fresnel reflectance of a conductor with relative complex index eta + i k
    (one channel), 0 <= cos_i <= 1: the exact formula (R_s + R_p) / 2, written with
    a^2 + b^2 = |(eta + i k)^2 - sin^2| and a = Re sqrt((eta + i k)^2 - sin^2) (Moeller's
    "Optics"; the same as pbrt-v4's FrComplex and Mitsuba 3's fresnel_conductor).

    eta = 0 (any k, Mitsuba's default "none" has k = 1) reflects everything: F = 1 exactly, so
    the mirror kind, whose eta and k are 0, keeps its weight k_s bit for bit. k = 0 is a
    dielectric from the optically thinner side (total internal reflection for eta < 1)."""
    c = jnp.clip(cos_i, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    t0 = eta * eta - k * k - s2
    a2b2 = _sqrt0(t0 * t0 + 4.0 * eta * eta * k * k)
    a = _sqrt0(0.5 * (a2b2 + t0))
    t1 = a2b2 + c2
    t2 = 2.0 * c * a
    rs = (t1 - t2) / jnp.where(t1 + t2 > 0, t1 + t2, 1.0)
    t3 = a2b2 * c2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / jnp.where(t3 + t4 > 0, t3 + t4, 1.0)
    mirror = eta == 0
    return jnp.where(mirror, 1.0, jnp.clip(0.5 * (rs + rp), 0.0, 1.0))


def fresnel_conductor_rgb(cos_i: Array, eta: V3, k: V3) -> V3:
    """:func:`fresnel_conductor` per RGB channel."""
    return V3(*(fresnel_conductor(cos_i, e, kk) for e, kk in zip(eta, k)))
