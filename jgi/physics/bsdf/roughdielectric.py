"""Rough dielectric (Walter et al. 2007, "Microfacet Models for Refraction through Rough
Surfaces"; Mitsuba 3's ``roughdielectric``): a rough interface between two dielectrics with
relative index ``ior`` = inside / outside. The normal's orientation tells the sides apart, as
for the smooth dielectric: eta = eta_t / eta_i = ior seen from outside (wo on the normal's
side), 1 / ior from inside.

Local directions (:mod:`.microfacet`): wo_z = cos_o > 0, wi_z > 0 for reflection and < 0 for
transmission. With m the microfacet normal (m_z > 0) that maps wo to wi,

* reflection, m = normalize(wo + wi): f = k_s F D G / (4 cos_o |cos_i|), dm/dwi = 1 / (4 |wi.m|);
* transmission, m = +-normalize(wo + eta wi): f = k_s (1 - F) D G |wi.m| |wo.m|
  / (cos_o |cos_i| (wo.m + eta wi.m)^2) for radiance (camera paths, ``mode=RADIANCE``: Walter's
  BTDF, which carries the 1 / eta^2 of radiance crossing the interface) and eta^2 times that for
  importance (light paths; Veach 1997, sec. 5.2), dm/dwi = eta^2 |wi.m| / (wo.m + eta wi.m)^2;

F = F_dielectric(wo.m, eta), D and the separable G of :mod:`.microfacet`. The sampler draws m
(:func:`.microfacet.sample_normal`), reflects with probability F, else refracts, so
pdf(wi) = p(m) (F or 1 - F) dm/dwi; a sample is valid when it lands on the side its lobe says.
The pdf is a function of (wo, wi) alone, so the reverse density pdf(wi -> wo) that BDPT needs is
``evaluate`` with the arguments swapped. Radiance-mode f obeys the generalized reciprocity
f(wo, wi) / eta_wi^2 = f(wi, wo) / eta_wo^2 (indices on each direction's side).

ior = 1 exactly is no interface at all: light passes straight through (a Dirac transmission,
wi = -wo, weight k_s) and ``evaluate`` is 0 (the half-vector of Walter's BTDF degenerates).
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ...core.vec import V3, dot, normalize, reflect, where
from . import microfacet as mf
from .common import IMPORTANCE, MaterialParams, transmission_tint
from .fresnel import fresnel_dielectric, refract


def relative_eta(mp: MaterialParams, flipped: Array) -> Array:
    """eta_t / eta_i seen from wo: ior from outside, 1 / ior from inside."""
    return jnp.where(flipped, 1.0 / mp.ior, mp.ior)


def passes_through(mp: MaterialParams) -> Array:
    """ior = 1: no interface (a Dirac transmission)."""
    return mp.ior == 1.0


def evaluate(mp: MaterialParams, wo: V3, wi: V3, eta: Array, ok: Array,
             mode: int) -> tuple[V3, Array]:
    """(f, pdf) where ``ok`` (wo and wi lit, on either side), else finite junk the caller
    masks."""
    f, pdf, _ = evaluate_lobes(mp, wo, wi, eta, ok, mode)
    return f, pdf


def evaluate_lobes(mp: MaterialParams, wo: V3, wi: V3, eta: Array, ok: Array,
                   mode: int) -> tuple[V3, Array, Array]:
    """(f, pdf, the pdf of wi's lobe alone): the last is the density of a sampler that always
    takes wi's lobe (reflection or transmission) instead of choosing it with probability F or
    1 - F (pbrt-v4's PDF with BxDFReflTransFlags Reflection or Transmission), what the layered
    BSDF's random walk uses."""
    au, av = mf.alphas(mp.alpha_u, mp.alpha_v)
    refl = wi.z > 0
    h = normalize(wo + wi * jnp.where(refl, 1.0, eta))
    h = h * jnp.where(h.z < 0, -1.0, 1.0)
    cos_oh, cos_ih = dot(wo, h), dot(wi, h)
    # the microfacet must face both directions from their own sides
    side_ok = ok & (cos_oh > 0) & (cos_ih * wi.z > 0) & ~passes_through(mp)
    d = mf.ndf(mp.distribution, h, au, av)
    g = mf.smith_g(mp.distribution, wo, wi, h, au, av)
    F = fresnel_dielectric(jnp.maximum(cos_oh, 0.0), eta)
    abs_ih = jnp.abs(cos_ih)
    cos_io = jnp.where(side_ok, wo.z * jnp.abs(wi.z), 1.0)
    # reflection
    f_r = F * d * g / (4.0 * cos_io)
    jac_r = 1.0 / jnp.where(side_ok, 4.0 * abs_ih, 1.0)
    # transmission
    s = cos_oh + eta * cos_ih
    s2 = jnp.where(side_ok & (s != 0), s * s, 1.0)
    f_t = (1.0 - F) * d * g * abs_ih * cos_oh / (cos_io * s2)
    if mode == IMPORTANCE:
        f_t = f_t * (eta * eta)
    jac_t = eta * eta * abs_ih / s2
    p_m = mf.pdf_normal(mp.distribution, wo, h, au, av)
    f = jnp.where(side_ok, jnp.where(refl, f_r, f_t), 0.0)
    pdf = jnp.where(side_ok, p_m * jnp.where(refl, F * jac_r, (1.0 - F) * jac_t), 0.0)
    # (no transmission lobe under total internal reflection, F = 1)
    pdf_lobe = jnp.where(side_ok, p_m * jnp.where(refl, jac_r, jnp.where(F < 1.0, jac_t, 0.0)),
                         0.0)
    return where(refl, mp.ks, transmission_tint(mp)) * f, pdf, pdf_lobe


def sample_direction(mp: MaterialParams, wo: V3, eta: Array, u_lobe: Array, u1: Array,
                     u2: Array) -> V3:
    """wo reflected about a sampled normal m with probability F(wo.m), else refracted through
    it (local); -wo when ior = 1; the zero vector (no sample) if m faces away from wo or the
    direction leaves on the wrong side for its lobe."""
    au, av = mf.alphas(mp.alpha_u, mp.alpha_v)
    m = mf.sample_normal(mp.distribution, wo, au, av, u1, u2)
    cos_om = dot(wo, m)
    F = fresnel_dielectric(jnp.maximum(cos_om, 0.0), eta)
    wt, can_refract = refract(wo, m, eta)
    refl = (u_lobe < F) | ~can_refract
    wi = where(refl, reflect(wo, m), wt)
    # a reflection below the surface (or a refraction above it) is no sample: evaluate would
    # read it as the other lobe's direction, whose density is not the one it was drawn with
    ok = (cos_om > 0) & jnp.where(refl, wi.z > 0, wi.z < 0)
    wi = wi * jnp.where(ok, 1.0, 0.0)
    return where(passes_through(mp), -wo, wi)
