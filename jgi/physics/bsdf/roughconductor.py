"""Rough conductor (Mitsuba 3's ``roughconductor``): microfacet reflection off a metal,
f = k_s F(wo.h) D(h) G(wo, wi, h) / (4 cos_o cos_i), h = normalize(wo + wi), F the conductor
Fresnel reflectance of eta + i k (:func:`.fresnel.fresnel_conductor`; eta = 0 reflects
everything). Sampled by reflecting wo about a sampled normal (:func:`.microfacet.sample_normal`:
GGX's visible normals, Beckmann's D cos), pdf = p(h) / (4 wo.h).

Local directions (:mod:`.microfacet`): z along the normal on wo's side; the caller masks
directions below the surface. Two-sided, like jgi's other opaque materials."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ...core.vec import V3, dot, normalize, reflect
from . import microfacet as mf
from .common import MaterialParams
from .fresnel import fresnel_conductor_rgb


def evaluate(mp: MaterialParams, wo: V3, wi: V3, ok: Array) -> tuple[V3, Array]:
    """(f, pdf) where ``ok`` (both directions lit on the same side), else finite junk that the
    caller masks."""
    au, av = mf.alphas(mp.alpha_u, mp.alpha_v)
    h = normalize(wo + wi)
    cos_oh = dot(wo, h)
    d = mf.ndf(mp.distribution, h, au, av)
    g = mf.smith_g(mp.distribution, wo, wi, h, au, av)
    den = jnp.where(ok, 4.0 * wo.z * wi.z, 1.0)
    F = fresnel_conductor_rgb(cos_oh, mp.eta, mp.k)
    f = mp.ks * F * (d * g / den)
    pdf = mf.pdf_normal(mp.distribution, wo, h, au, av) / jnp.where(ok & (cos_oh > 0),
                                                                     4.0 * cos_oh, 1.0)
    return f, jnp.where(cos_oh > 0, pdf, 0.0)


def sample_direction(mp: MaterialParams, wo: V3, u1: Array, u2: Array) -> V3:
    """wo mirrored about a sampled microfacet normal (local); the zero vector (no sample) if
    the normal faces away from wo (Beckmann's D cos sampling draws such normals)."""
    au, av = mf.alphas(mp.alpha_u, mp.alpha_v)
    m = mf.sample_normal(mp.distribution, wo, au, av, u1, u2)
    return reflect(wo, m) * jnp.where(dot(wo, m) > 0, 1.0, 0.0)
