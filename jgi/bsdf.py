"""BSDFs: Lambertian diffuse, perfect mirror, smooth dielectric, and modified Phong.

Conventions (pbrt's): ``wo`` points back along the path (towards the camera for camera paths),
``wi`` is the sampled direction, both leave the surface; ``n`` is the primitive's unit
geometric normal. :func:`evaluate` returns the BSDF value f(wo, wi) *without* the cosine, and its
solid-angle pdf; :func:`sample` returns a direction and the weight f |cos theta_i| / pdf.
Dirac (specular) lobes have no value and no pdf: ``evaluate`` gives 0 for them and ``sample``
flags them with ``delta``. Opaque materials are two-sided (the normal is flipped to ``wo``'s
side); the dielectric uses the normal's orientation to tell entering from leaving. A surface
seen edge-on (|cos theta_o| <= ``vec.EDGE_ON_COS``) scatters nothing, and directions within
that band of the surface have f = 0 and pdf = 0, on every CPU (see ``vec.EDGE_ON_COS``).

* Diffuse:   f = k_d / pi,                pdf = cos(theta_i) / pi.
* Phong:     f = k_d / pi + k_s (n + 2) / (2 pi) cos^n(alpha), alpha the angle between wi and
             the mirror direction of wo (Lafortune & Willems 1994, reciprocal and energy
             conserving for k_d + k_s <= 1); lobe chosen by albedo luminance, pdf = mixture.
* Mirror:    wi = reflect(wo), weight k_s.
* Dielectric: reflect with probability F (Fresnel, unpolarised), else refract (Snell); total
             internal reflection gives F = 1. Radiance is scaled by (eta_i / eta_t)^2 across the
             interface for camera paths (``mode=RADIANCE``), not for light paths (Veach 1997, 5.2).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from . import warps
from ._xla import pow_positive
from .scene import DIELECTRIC, DIFFUSE, MIRROR, PHONG, Materials
from .vec import EDGE_ON_COS, V3, dot, luminance, reflect, to_world, where

RADIANCE, IMPORTANCE = 0, 1


class MaterialParams(NamedTuple):
    kind: Array
    kd: V3
    ks: V3
    exponent: Array
    ior: Array


class BSDFSample(NamedTuple):
    wi: V3
    weight: V3     # f |cos theta_i| / pdf (the Dirac weight for specular lobes)
    pdf: Array     # solid-angle pdf of the sampled direction (0 for Dirac lobes)
    delta: Array   # True if a Dirac lobe was sampled
    valid: Array   # False if the sample was absorbed / fell below the surface


def lookup(mats: Materials, m: Array) -> MaterialParams:
    return MaterialParams(mats.kind[m], V3(mats.diffuse.x[m], mats.diffuse.y[m], mats.diffuse.z[m]),
                          V3(mats.specular.x[m], mats.specular.y[m], mats.specular.z[m]),
                          mats.exponent[m], mats.ior[m])


def is_delta(mp: MaterialParams) -> Array:
    """True for purely specular materials (no lobe that ``evaluate`` or NEE can use)."""
    return (mp.kind == MIRROR) | (mp.kind == DIELECTRIC)


def facing(n: V3, w: V3) -> V3:
    """The normal flipped onto ``w``'s side."""
    return _side(n, w)[0]


def _side(n: V3, wo: V3) -> tuple[V3, Array, Array]:
    """(n flipped onto wo's side, |cos theta_o|, whether it was flipped). Every side test of a BSDF derives from this
    one dot product: recomputing dot(wo, n_flipped) instead can round (XLA contracts it into
    FMAs differently per fusion) to the other sign when wo grazes the surface, making ``valid``
    and ``weight`` disagree."""
    cos_o = dot(n, wo)
    flip = cos_o < 0
    return n * jnp.where(flip, -1.0, 1.0), jnp.abs(cos_o), flip


def _lit(cos: Array) -> Array:
    """A cosine (>= 0 by construction, or signed) counts as above the surface: outside the
    edge-on band, so that an edge-on direction is decided alike on every CPU."""
    return cos > EDGE_ON_COS


def specular_probability(mp: MaterialParams) -> Array:
    ld, ls = luminance(mp.kd), luminance(mp.ks)
    tot = ld + ls
    return jnp.where(tot > 0, ls / jnp.where(tot > 0, tot, 1.0), 0.0)


def _cos2_transmitted(cos_i: Array, eta: Array) -> Array:
    """cos^2(theta_t) = 1 - (1 - cos_i^2) / eta^2 (Snell), <= 0 under total internal reflection.

    Written as (cos_i^2 + eta^2 - 1) / eta^2: the textbook form cancels catastrophically in
    float32 at grazing incidence (for eta = 1 it gave F = 1e-5 at cos_i = 1e-3 instead of 0)."""
    return (cos_i * cos_i + (eta * eta - 1.0)) / (eta * eta)


def fresnel_dielectric(cos_i: Array, eta: Array) -> Array:
    """Unpolarised Fresnel reflectance for relative index eta = eta_t / eta_i, cos_i >= 0."""
    cos2_t = _cos2_transmitted(cos_i, eta)
    tir = cos2_t <= 0.0
    cos_t = jnp.sqrt(jnp.maximum(cos2_t, 0.0))
    r_parl = (eta * cos_i - cos_t) / jnp.maximum(eta * cos_i + cos_t, 1e-12)
    r_perp = (cos_i - eta * cos_t) / jnp.maximum(cos_i + eta * cos_t, 1e-12)
    return jnp.where(tir, 1.0, 0.5 * (r_parl * r_parl + r_perp * r_perp))


def refract(wo: V3, n: V3, eta: Array) -> tuple[V3, Array]:
    """Transmitted direction for wo on n's side, eta = eta_t / eta_i; (direction, valid)."""
    cos_i = dot(wo, n)
    cos2_t = _cos2_transmitted(cos_i, eta)
    ok = cos2_t > 0.0
    cos_t = jnp.sqrt(jnp.maximum(cos2_t, 0.0))
    return (-wo) / eta + n * (cos_i / eta - cos_t), ok


# --- evaluation ---------------------------------------------------------------------------------

def evaluate(kinds, mp: MaterialParams, n: V3, wo: V3, wi: V3) -> tuple[V3, Array]:
    """(f(wo, wi), pdf(wo -> wi)) for the non-Dirac part of the material."""
    nf, cos_o, _ = _side(n, wo)
    cos_i = dot(wi, nf)
    above = _lit(cos_i) & _lit(cos_o)
    zero = jnp.zeros_like(cos_i)
    f = V3(zero, zero, zero)
    pdf = zero
    if DIFFUSE in kinds or PHONG in kinds:
        diffuse_f = mp.kd * jnp.float32(1.0 / jnp.pi)
        diffuse_pdf = warps.pdf_cosine_hemisphere(cos_i)
    if DIFFUSE in kinds:
        sel = mp.kind == DIFFUSE
        f = where(sel, diffuse_f, f)
        pdf = jnp.where(sel, diffuse_pdf, pdf)
    if PHONG in kinds:
        sel = mp.kind == PHONG
        cos_a = jnp.maximum(dot(wi, reflect(wo, nf)), 0.0)
        # the lobe is the hemisphere about the mirror direction (0^0 = 1 would let an exponent
        # of 0 reflect into the opposite hemisphere too, which sample_phong_lobe never reaches)
        # (the inner where keeps gradients finite: d/dn 0^n = 0 * log 0)
        lobe = jnp.where(cos_a > 0, pow_positive(jnp.where(cos_a > 0, cos_a, 1.0), mp.exponent), 0.0)
        spec_f = mp.ks * ((mp.exponent + 2.0) * jnp.float32(0.5 / jnp.pi) * lobe)
        ps = specular_probability(mp)
        phong_pdf = (1.0 - ps) * diffuse_pdf + ps * warps.pdf_phong_lobe(cos_a, mp.exponent)
        f = where(sel, diffuse_f + spec_f, f)
        pdf = jnp.where(sel, phong_pdf, pdf)
    f = where(above, f, V3(zero, zero, zero))
    return f, jnp.where(above, pdf, 0.0)


# --- sampling -----------------------------------------------------------------------------------

def sample(kinds, mp: MaterialParams, n: V3, wo: V3, u_lobe: Array, u1: Array, u2: Array,
           mode: int = RADIANCE) -> BSDFSample:
    zero = jnp.zeros_like(u1)
    one = jnp.ones_like(u1)
    out = BSDFSample(V3(zero, zero, one), V3(zero, zero, zero), zero, zero > 0, zero > 0)

    def choose(sel, s: BSDFSample, acc: BSDFSample) -> BSDFSample:
        return BSDFSample(where(sel, s.wi, acc.wi), where(sel, s.weight, acc.weight),
                          jnp.where(sel, s.pdf, acc.pdf), jnp.where(sel, s.delta, acc.delta),
                          jnp.where(sel, s.valid, acc.valid))

    nf, cos_o, leaving = _side(n, wo)
    if DIFFUSE in kinds or PHONG in kinds:
        wi_d = to_world(warps.sample_cosine_hemisphere(u1, u2), nf)
    if DIFFUSE in kinds:
        ok = _lit(cos_o) & _lit(dot(wi_d, nf))
        s = BSDFSample(wi_d, where(ok, mp.kd, V3(zero, zero, zero)),
                       jnp.where(ok, warps.pdf_cosine_hemisphere(dot(wi_d, nf)), 0.0), zero > 0, ok)
        out = choose(mp.kind == DIFFUSE, s, out)
    if PHONG in kinds:
        ps = specular_probability(mp)
        wi_s = to_world(warps.sample_phong_lobe(u1, u2, mp.exponent), reflect(wo, nf))
        wi = where(u_lobe < ps, wi_s, wi_d)
        f, pdf = evaluate((PHONG,), mp, n, wo, wi)
        ok = pdf > 0
        w = f * (jnp.maximum(dot(wi, nf), 0.0) / jnp.where(ok, pdf, 1.0))
        s = BSDFSample(wi, where(ok, w, V3(zero, zero, zero)), pdf, zero > 0, ok)
        out = choose(mp.kind == PHONG, s, out)
    if MIRROR in kinds:
        ok = _lit(cos_o)
        s = BSDFSample(reflect(wo, nf), where(ok, mp.ks, V3(zero, zero, zero)), zero, ok, ok)
        out = choose(mp.kind == MIRROR, s, out)
    if DIELECTRIC in kinds:
        eta = jnp.where(leaving, 1.0 / mp.ior, mp.ior)  # eta_t / eta_i; wo inside if flipped
        F = fresnel_dielectric(cos_o, eta)
        wt, can_refract = refract(wo, nf, eta)
        reflect_it = (u_lobe < F) | ~can_refract
        wi = where(reflect_it, reflect(wo, nf), wt)
        scale = 1.0 if mode == IMPORTANCE else 1.0 / (eta * eta)
        ok = _lit(cos_o)
        w = jnp.where(ok, jnp.where(reflect_it, 1.0, scale), 0.0)
        s = BSDFSample(wi, mp.ks * w, zero, one > 0, ok)
        out = choose(mp.kind == DIELECTRIC, s, out)
    return out
