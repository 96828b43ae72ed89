"""Rough plastic, as Mitsuba 3's ``roughplastic`` defines it (``src/bsdfs/roughplastic.cpp``):
a diffuse base under a rough dielectric coating of relative index eta = ``ior``
(int_ior / ext_ior), isotropic roughness alpha.

    f = k_s F(wo.h, eta) D(h) G(wo, wi, h) / (4 cos_o cos_i)                    (coating)
      + k_d' T(cos_o) T(cos_i) / (pi eta^2),   k_d' = k_d / (1 - Ri)              (base)

(k_d' = k_d / (1 - k_d Ri) with ``nonlinear``), where T is the coating's external transmittance
and Ri its internal reflectance, both precomputed at scene build
(:mod:`jgi.scene.rough_coating`) and read here by linear interpolation of the 64-entry table
row (two gathers, as Mitsuba's ``lerp_gather``). The specular lobe is chosen with probability
p = (1 - T(cos_o)) w / ((1 - T(cos_o)) w + T(cos_o) (1 - w)), w = mean(k_s) / (mean(k_d) +
mean(k_s)) (Mitsuba's specular_sampling_weight), else the cosine-weighted base; the pdf is
the mixture p p_spec + (1 - p) cos_i / pi. Two-sided like jgi's other opaque materials
(Mitsuba's is one-sided unless wrapped in ``twosided``)."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ...core import warps
from ...core.vec import V3, dot, normalize, reflect, where
from . import microfacet as mf
from .common import MaterialParams
from .fresnel import fresnel_dielectric


def transmittance(mp: MaterialParams, cos: Array) -> Array:
    """T(cos), linear between the entries i / 63 of the material's row (Mitsuba's
    lerp_gather: index min(floor(63 cos), 62))."""
    table = jnp.asarray(mp.transmittance)
    n = table.shape[-1]
    x = jnp.clip(cos, 0.0, 1.0) * (n - 1)
    i = jnp.minimum(jnp.floor(x), n - 2).astype(jnp.int32)
    w = x - i
    flat = table.reshape(-1)
    base = jnp.asarray(mp.row, jnp.int32) * n + i
    return (1.0 - w) * flat[base] + w * flat[base + 1]


def base_albedo(mp: MaterialParams) -> V3:
    """The base's albedo under the coating, with the light that the coating reflects back
    down (internal reflectance Ri) and the base scatters again, summed:
    k_d / (1 - Ri), or k_d / (1 - k_d Ri) with ``nonlinear`` (Mitsuba's (rough)plastic)."""
    ri = mp.internal_reflectance
    return mp.kd / V3(*(1.0 - jnp.where(mp.nonlinear, c * ri, ri) for c in mp.kd))


def specular_probability(mp: MaterialParams, t_o: Array) -> Array:
    """Probability of sampling the coating's lobe given T(cos_o) = t_o (the smooth
    ``plastic`` passes t_o = 1 - F(cos_o): Mitsuba's two choices are the same formula)."""
    mean = lambda v: (v.x + v.y + v.z) * (1.0 / 3.0)  # noqa: E731
    sd, ss = mean(mp.kd), mean(mp.ks)
    tot = sd + ss
    w = jnp.where(tot > 0, ss / jnp.where(tot > 0, tot, 1.0), 0.0)
    ps, pd = (1.0 - t_o) * w, t_o * (1.0 - w)
    return jnp.where(ps + pd > 0, ps / jnp.where(ps + pd > 0, ps + pd, 1.0), 0.0)


def evaluate(mp: MaterialParams, wo: V3, wi: V3, ok: Array) -> tuple[V3, Array]:
    """(f, pdf) where ``ok`` (both directions lit on the same side), else finite junk the
    caller masks."""
    au, av = mf.alphas(mp.alpha_u, mp.alpha_v)
    h = normalize(wo + wi)
    cos_oh = dot(wo, h)
    good = ok & (cos_oh > 0)
    d = mf.ndf(mp.distribution, h, au, av)
    g = mf.smith_g(mp.distribution, wo, wi, h, au, av)
    F = fresnel_dielectric(jnp.maximum(cos_oh, 0.0), mp.ior)
    spec = F * d * g / jnp.where(good, 4.0 * wo.z * wi.z, 1.0)
    t_o, t_i = transmittance(mp, wo.z), transmittance(mp, wi.z)
    f = mp.ks * spec + base_albedo(mp) * (t_o * t_i / (jnp.pi * mp.ior * mp.ior))
    p = specular_probability(mp, t_o)
    p_spec = mf.pdf_normal(mp.distribution, wo, h, au, av) / jnp.where(good, 4.0 * cos_oh, 1.0)
    pdf = p * jnp.where(good, p_spec, 0.0) + (1.0 - p) * warps.pdf_cosine_hemisphere(wi.z)
    return f, pdf


def sample_direction(mp: MaterialParams, wo: V3, u_lobe: Array, u1: Array, u2: Array) -> V3:
    """The coating's reflection about a sampled normal with probability
    :func:`specular_probability`, else a cosine-weighted direction (local); the zero vector if
    the sampled normal faces away from wo."""
    au, av = mf.alphas(mp.alpha_u, mp.alpha_v)
    m = mf.sample_normal(mp.distribution, wo, au, av, u1, u2)
    spec = reflect(wo, m) * jnp.where(dot(wo, m) > 0, 1.0, 0.0)
    p = specular_probability(mp, transmittance(mp, wo.z))
    return where(u_lobe < p, spec, warps.sample_cosine_hemisphere(u1, u2))
