"""Fresnel and Smith's masking as array-agnostic formulas: one place for the algebra that both the
JAX BSDFs (:mod:`jgi.physics.bsdf.fresnel`, :mod:`jgi.physics.bsdf.microfacet`, float32, in
every kernel) and the float64 numpy quadrature of roughplastic's coating tables at scene build
(:mod:`jgi.scene.rough_coating`, below physics in the layers) evaluate.

Each function takes its array namespace ``xp`` (``numpy`` or ``jax.numpy``) or the one function
that differs between them, and is written with the operation order the float32 kernels were
measured with (so they compile to the same programs as before the formulas moved here).
Callers keep what is theirs: the masking of back-facing microfacets, total internal reflection,
and how tan^2 is formed (anisotropic in the BSDFs, isotropic in the tables).
"""

from __future__ import annotations

import math

INV_SQRT_PI = 1.0 / math.sqrt(math.pi)


def cos2_transmitted(cos_i, eta):
    """cos^2(theta_t) = 1 - (1 - cos_i^2) / eta^2 (Snell), <= 0 under total internal reflection.

    Written as (cos_i^2 + eta^2 - 1) / eta^2: the textbook form cancels catastrophically in
    float32 at grazing incidence (for eta = 1 it gave F = 1e-5 at cos_i = 1e-3 instead of 0)."""
    return (cos_i * cos_i + (eta * eta - 1.0)) / (eta * eta)


def fresnel_dielectric_reflectance(cos_i, cos_t, eta, xp):
    """Unpolarised Fresnel reflectance (r_parallel^2 + r_perpendicular^2) / 2 for incident and
    transmitted cosines cos_i, cos_t >= 0 and relative index eta = eta_t / eta_i (the caller
    handles total internal reflection, where it is 1)."""
    r_parl = (eta * cos_i - cos_t) / xp.maximum(eta * cos_i + cos_t, 1e-12)
    r_perp = (cos_i - eta * cos_t) / xp.maximum(cos_i + eta * cos_t, 1e-12)
    return 0.5 * (r_parl * r_parl + r_perp * r_perp)


def smith_lambda_ggx(t2, xp):
    """GGX's Smith Lambda from t2 = tan^2(theta) scaled by the roughness:
    (sqrt(1 + t2) - 1) / 2, written without cancellation."""
    return t2 / (2.0 + 2.0 * xp.sqrt(1.0 + t2))


def smith_lambda_beckmann(a, xp, erfc):
    """Beckmann's Smith Lambda from a = 1 / sqrt(t2): (e^{-a^2} / (a sqrt(pi)) - erfc(a)) / 2
    (``erfc``: the namespace's complementary error function)."""
    return 0.5 * (xp.exp(-a * a) * INV_SQRT_PI / a - erfc(a))
