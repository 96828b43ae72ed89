"""Smooth plastic, as Mitsuba 3's ``plastic`` defines it (``src/bsdfs/plastic.cpp``): a diffuse
base under a smooth dielectric coating of relative index eta = ``ior`` (int_ior / ext_ior).

    f = k_s F(cos_o) delta(wi - reflect(wo)) / |cos_i|                        (coating: Dirac)
      + k_d' (1 - F(cos_o)) (1 - F(cos_i)) / (pi eta^2),   k_d' = k_d / (1 - fdr_int)   (base)

(k_d' = k_d / (1 - k_d fdr_int) with ``nonlinear``), F the unpolarised Fresnel reflectance of
the interface (:func:`.fresnel.fresnel_dielectric`) and fdr_int its diffuse reflectance seen
from inside, Mitsuba's fit of it at 1 / eta (:func:`jgi.scene.rough_coating.
fresnel_diffuse_reflectance`, stored at scene build in ``internal_reflectance``). The base is
roughplastic's with the rough coating's transmittance T replaced by 1 - F (shared:
:func:`.roughplastic.base_albedo`, :func:`.roughplastic.specular_probability`).

Sampling (Mitsuba's): the Dirac lobe with probability p = F w / (F w + (1 - F)(1 - w)),
F = F(cos_o), w = mean(k_s) / (mean(k_d) + mean(k_s)) (its specular_sampling_weight), weight
k_s F / p and ``delta`` set; else a cosine-weighted direction, pdf (1 - p) cos_i / pi and weight
f cos_i / pdf. ``evaluate`` returns the base alone (f and that pdf): the Dirac lobe has no value
and no density, as every Dirac lobe in jgi. So a plastic vertex is not Dirac
(:func:`.common.is_delta`: it can be connected to, store photons, be merged at, through its
base), while a path that leaves it by the coating's reflection has a Dirac bounce there (the
sample's ``delta``, :func:`.common.sampled_delta`). f is symmetric in wo and wi, so radiance
and importance transport are alike. Two-sided like jgi's other opaque materials (Mitsuba's is
one-sided unless wrapped in ``twosided``)."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ...core import warps
from ...core.vec import V3, dot, reflect, where
from . import diffuse
from .common import BSDFSample, MaterialParams, lit
from .fresnel import fresnel_dielectric
from .roughplastic import base_albedo, specular_probability


def reflectance(mp: MaterialParams, cos: Array) -> Array:
    """F(cos) of the coating seen from outside (cos >= 0)."""
    return fresnel_dielectric(cos, mp.ior)


def coating_probability(mp: MaterialParams, cos_o: Array) -> Array:
    """Probability with which :func:`sample` picks the Dirac lobe at |cos theta_o| = cos_o."""
    return specular_probability(mp, 1.0 - reflectance(mp, cos_o))


def evaluate(mp: MaterialParams, cos_o: Array, cos_i: Array) -> tuple[V3, Array]:
    """(f, pdf) of the base for both directions above the surface (the caller masks the
    rest)."""
    t = (1.0 - reflectance(mp, cos_o)) * (1.0 - reflectance(mp, cos_i))
    f = base_albedo(mp) * (t / (jnp.pi * mp.ior * mp.ior))
    pdf = (1.0 - coating_probability(mp, cos_o)) * warps.pdf_cosine_hemisphere(cos_i)
    return f, pdf


def sample(mp: MaterialParams, nf: V3, wo: V3, cos_o: Array, u_lobe: Array, u1: Array,
           u2: Array) -> BSDFSample:
    """The coating's mirror direction (Dirac) with probability :func:`coating_probability`,
    else a cosine-weighted direction; weights as Mitsuba's ``plastic`` returns them."""
    F_o = reflectance(mp, cos_o)
    p = specular_probability(mp, 1.0 - F_o)
    spec = u_lobe < p
    wi = where(spec, reflect(wo, nf), diffuse.sample_direction(nf, u1, u2))
    cos_i = dot(wi, nf)
    ok_o = lit(cos_o)
    f, pdf = evaluate(mp, cos_o, cos_i)
    ok_d = ok_o & lit(cos_i) & (pdf > 0)
    w_d = f * (cos_i / jnp.where(ok_d, pdf, 1.0))
    w_s = mp.ks * (F_o / jnp.where(p > 0, p, 1.0))
    zero = jnp.zeros_like(cos_o)
    Z = V3(zero, zero, zero)
    weight = where(spec, where(ok_o, w_s, Z), where(ok_d, w_d, Z))
    return BSDFSample(wi, weight, jnp.where(spec | ~ok_d, 0.0, pdf), spec & ok_o,
                      jnp.where(spec, ok_o, ok_d))
