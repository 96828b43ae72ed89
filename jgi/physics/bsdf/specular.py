"""Dirac lobes: the mirror / smooth conductor (wi = reflect(wo), weight k_s F_conductor(cos_o),
F = 1 for the perfect mirror's eta = k = 0) and the smooth dielectric
(reflect with probability F, the unpolarised Fresnel reflectance, else refract by Snell's law;
total internal reflection gives F = 1; reflection tinted by k_s, transmission by k_t, Mitsuba's
specular_reflectance and specular_transmittance). Radiance is scaled by (eta_i / eta_t)^2 across the
interface for camera paths (``mode=RADIANCE``), not for light paths (Veach 1997, 5.2)."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ...core.vec import V3, reflect, where
from .common import IMPORTANCE, BSDFSample, MaterialParams, lit, transmission_tint
from .fresnel import fresnel_conductor_rgb, fresnel_dielectric, refract


def mirror_reflectance(mp: MaterialParams, cos_o: Array) -> V3:
    """The mirror's Dirac coefficient k_s F(cos_o) (Mitsuba's smooth ``conductor``): k_s
    exactly when eta = 0 (the perfect mirror)."""
    return mp.ks * fresnel_conductor_rgb(cos_o, mp.eta, mp.k)


def sample_mirror(mp: MaterialParams, nf: V3, wo: V3, cos_o: Array) -> BSDFSample:
    zero = jnp.zeros_like(cos_o)
    ok = lit(cos_o)
    return BSDFSample(reflect(wo, nf), where(ok, mirror_reflectance(mp, cos_o),
                                             V3(zero, zero, zero)), zero, ok, ok)


def sample_dielectric(mp: MaterialParams, nf: V3, wo: V3, cos_o: Array, flipped: Array,
                      u_lobe: Array, mode: int) -> BSDFSample:
    """``flipped``: wo is on the side opposite the normal, i.e. inside the medium."""
    eta = jnp.where(flipped, 1.0 / mp.ior, mp.ior)  # eta_t / eta_i
    F = fresnel_dielectric(cos_o, eta)
    wt, can_refract = refract(wo, nf, eta)
    reflect_it = (u_lobe < F) | ~can_refract
    wi = where(reflect_it, reflect(wo, nf), wt)
    scale = 1.0 if mode == IMPORTANCE else 1.0 / (eta * eta)
    ok = lit(cos_o)
    w = jnp.where(ok, jnp.where(reflect_it, 1.0, scale), 0.0)
    zero = jnp.zeros_like(cos_o)
    return BSDFSample(wi, where(reflect_it, mp.ks, transmission_tint(mp)) * w, zero, zero == 0,
                      ok)
