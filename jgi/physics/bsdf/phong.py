"""Modified Phong (Lafortune & Willems 1994): f = k_d / pi + k_s (n + 2) / (2 pi) cos^n(alpha),
alpha the angle between wi and the mirror direction of wo; reciprocal and energy conserving for
k_d + k_s <= 1. Sampled by choosing the diffuse or the specular lobe by albedo luminance; the
pdf is the mixture of both lobes' densities."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ..._xla import pow_positive
from ...core import warps
from ...core.vec import V3, dot, luminance, reflect, to_world, where
from . import diffuse
from .common import BSDFSample, MaterialParams, lit


def specular_probability(mp: MaterialParams) -> Array:
    """Probability of sampling the specular lobe: its share of the albedo luminance."""
    ld, ls = luminance(mp.kd), luminance(mp.ks)
    tot = ld + ls
    return jnp.where(tot > 0, ls / jnp.where(tot > 0, tot, 1.0), 0.0)


def evaluate(mp: MaterialParams, nf: V3, wo: V3, wi: V3, cos_i: Array) -> tuple[V3, Array]:
    """(f, pdf) for wi above the surface (the caller masks directions below it)."""
    diffuse_f, diffuse_pdf = diffuse.evaluate(mp, cos_i)
    cos_a = jnp.maximum(dot(wi, reflect(wo, nf)), 0.0)
    # the lobe is the hemisphere about the mirror direction (0^0 = 1 would let an exponent
    # of 0 reflect into the opposite hemisphere too, which sample_phong_lobe never reaches)
    # (the inner where keeps gradients finite: d/dn 0^n = 0 * log 0)
    lobe = jnp.where(cos_a > 0, pow_positive(jnp.where(cos_a > 0, cos_a, 1.0), mp.exponent), 0.0)
    spec_f = mp.ks * ((mp.exponent + 2.0) * jnp.float32(0.5 / jnp.pi) * lobe)
    ps = specular_probability(mp)
    pdf = (1.0 - ps) * diffuse_pdf + ps * warps.pdf_phong_lobe(cos_a, mp.exponent)
    return diffuse_f + spec_f, pdf


def sample(mp: MaterialParams, nf: V3, wo: V3, cos_o: Array, u_lobe: Array, u1: Array,
           u2: Array) -> BSDFSample:
    ps = specular_probability(mp)
    wi_s = to_world(warps.sample_phong_lobe(u1, u2, mp.exponent), reflect(wo, nf))
    wi = where(u_lobe < ps, wi_s, diffuse.sample_direction(nf, u1, u2))
    cos_i = dot(wi, nf)
    f, pdf = evaluate(mp, nf, wo, wi, cos_i)
    zero = jnp.zeros_like(u1)
    above = lit(cos_i) & lit(cos_o)
    f = where(above, f, V3(zero, zero, zero))
    pdf = jnp.where(above, pdf, 0.0)
    ok = pdf > 0
    w = f * (jnp.maximum(dot(wi, nf), 0.0) / jnp.where(ok, pdf, 1.0))
    return BSDFSample(wi, where(ok, w, V3(zero, zero, zero)), pdf, zero > 0, ok)
