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

One module per material (:mod:`.diffuse`, :mod:`.phong`, :mod:`.specular` for the mirror and
the dielectric; :mod:`.fresnel` for the interface optics); this module dispatches on the
material kind. ``kinds`` is the static tuple of kinds a scene uses, so a kernel contains only
the lobes it needs, and the kind of each lane is a traced array.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ...core.vec import V3, dot, where
from ...scene.data import DIELECTRIC, DIFFUSE, MIRROR, PHONG
from . import diffuse, phong, specular
from .common import (
    IMPORTANCE,
    RADIANCE,
    BSDFSample,
    MaterialParams,
    facing,
    is_delta,
    lit,
    lookup,
    lookup_specialised,
    no_sample,
    side,
)
from .fresnel import fresnel_dielectric, refract
from .phong import specular_probability

__all__ = ["RADIANCE", "IMPORTANCE", "MaterialParams", "BSDFSample", "lookup",
           "lookup_specialised", "is_delta",
           "facing", "side", "lit", "specular_probability", "fresnel_dielectric", "refract",
           "evaluate", "sample"]


def evaluate(kinds, mp: MaterialParams, n: V3, wo: V3, wi: V3) -> tuple[V3, Array]:
    """(f(wo, wi), pdf(wo -> wi)) for the non-Dirac part of the material."""
    nf, cos_o, _ = side(n, wo)
    cos_i = dot(wi, nf)
    above = lit(cos_i) & lit(cos_o)
    zero = jnp.zeros_like(cos_i)
    f = V3(zero, zero, zero)
    pdf = zero
    if DIFFUSE in kinds:
        sel = mp.kind == DIFFUSE
        f_d, pdf_d = diffuse.evaluate(mp, cos_i)
        f = where(sel, f_d, f)
        pdf = jnp.where(sel, pdf_d, pdf)
    if PHONG in kinds:
        sel = mp.kind == PHONG
        f_p, pdf_p = phong.evaluate(mp, nf, wo, wi, cos_i)
        f = where(sel, f_p, f)
        pdf = jnp.where(sel, pdf_p, pdf)
    f = where(above, f, V3(zero, zero, zero))
    return f, jnp.where(above, pdf, 0.0)


def sample(kinds, mp: MaterialParams, n: V3, wo: V3, u_lobe: Array, u1: Array, u2: Array,
           mode: int = RADIANCE) -> BSDFSample:
    """A direction wi from the material's lobes, with weight f |cos theta_i| / pdf."""
    out = no_sample(u1)

    def choose(sel, s: BSDFSample, acc: BSDFSample) -> BSDFSample:
        return BSDFSample(where(sel, s.wi, acc.wi), where(sel, s.weight, acc.weight),
                          jnp.where(sel, s.pdf, acc.pdf), jnp.where(sel, s.delta, acc.delta),
                          jnp.where(sel, s.valid, acc.valid))

    nf, cos_o, flipped = side(n, wo)
    if DIFFUSE in kinds:
        out = choose(mp.kind == DIFFUSE, diffuse.sample(mp, nf, cos_o, u1, u2), out)
    if PHONG in kinds:
        out = choose(mp.kind == PHONG, phong.sample(mp, nf, wo, cos_o, u_lobe, u1, u2), out)
    if MIRROR in kinds:
        out = choose(mp.kind == MIRROR, specular.sample_mirror(mp, nf, wo, cos_o), out)
    if DIELECTRIC in kinds:
        out = choose(mp.kind == DIELECTRIC,
                     specular.sample_dielectric(mp, nf, wo, cos_o, flipped, u_lobe, mode), out)
    return out
