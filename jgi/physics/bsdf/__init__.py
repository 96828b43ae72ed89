"""BSDFs: Lambertian diffuse, mirror / smooth conductor, smooth dielectric, modified Phong,
smooth plastic, and the microfacet kinds: rough conductor, rough dielectric and rough plastic
(Mitsuba 3's).

Conventions (pbrt's): ``wo`` points back along the path (towards the camera for camera paths),
``wi`` is the sampled direction, both leave the surface; ``n`` is the normal the BSDF is
evaluated about: the primitive's unit geometric normal, or on smooth meshes the shading normal
(Mitsuba 3 and pbrt-v4 evaluate BSDFs in the shading frame alone: its side tests, two-sided
flip, one-sided materials' back side and the dielectric's entering or leaving; callers keep
the geometric normal for ray offsets and area densities, and apply :func:`adjoint_correction` in importance mode). :func:`evaluate` returns the BSDF value f(wo, wi) *without* the cosine, and its
solid-angle pdf; :func:`sample` returns a direction and the weight f |cos theta_i| / pdf.
Dirac (specular) lobes have no value and no pdf: ``evaluate`` gives 0 for them and ``sample``
flags them with ``delta``. Opaque materials are two-sided (the normal is flipped to ``wo``'s
side), except one-sided ones (Mitsuba's reflective BSDFs without ``twosided``: the material
table's ``one_sided``), which are black, with pdf 0 and no sample, where wo or wi is on the
back side of ``n`` (:func:`back_side`); the dielectric uses the normal's orientation to tell
entering from leaving. A surface seen edge-on (|cos theta_o| <= ``vec.EDGE_ON_COS``) scatters nothing, and directions within
that band of the surface have f = 0 and pdf = 0, on every CPU (see ``vec.EDGE_ON_COS``).
Reflection-only kinds give f = 0 for wi on the other side from wo; the rough dielectric gives
its transmission lobe there, whose value depends on the transport ``mode`` (radiance or
importance, Veach 1997 sec. 5.2), as the smooth dielectric's sampled weight does. The rough
kinds are never Dirac (:func:`is_delta`), however small alpha; :func:`is_glossy` tells the
sharp ones. The smooth plastic has a Dirac lobe (its coating's reflection) beside a non-Dirac
one (its base): :func:`is_delta` (no non-Dirac lobe: not connectable) is False for it, and
whether a *sampled* direction is Dirac is the sample's ``delta`` (:func:`sampled_delta`).

One module per material (:mod:`.diffuse`, :mod:`.phong`, :mod:`.specular` for the mirror and
the dielectric, :mod:`.plastic`, :mod:`.roughconductor`, :mod:`.roughdielectric`, :mod:`.roughplastic`;
:mod:`.microfacet` for the distributions, :mod:`.fresnel` for the interface optics); this
module dispatches on the material kind. ``kinds`` is the static tuple of kinds a scene uses, so
a kernel contains only the lobes it needs, and the kind of each lane is a traced array.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ..._xla import materialize
from ...core.vec import V3, dot, where
from ...scene.tables import (
    DIELECTRIC,
    DIFFUSE,
    MIRROR,
    PHONG,
    PLASTIC,
    ROUGH_CONDUCTOR,
    ROUGH_DIELECTRIC,
    ROUGH_KINDS,
    ROUGH_PLASTIC,
)
from . import diffuse, phong, plastic, roughconductor, roughdielectric, roughplastic, specular
from . import microfacet as mf
from .common import (
    GLOSSY_ALPHA,
    IMPORTANCE,
    RADIANCE,
    BSDFSample,
    MaterialParams,
    adjoint_correction,
    facing,
    is_delta,
    is_glossy,
    is_rough,
    lit,
    lookup,
    lookup_specialised,
    no_sample,
    sampled_delta,
    shading_ratio,
    side,
    transmission_tint,
)
from .fresnel import fresnel_conductor, fresnel_conductor_rgb, fresnel_dielectric, refract
from .phong import specular_probability
from .specular import mirror_reflectance

__all__ = ["RADIANCE", "IMPORTANCE", "GLOSSY_ALPHA", "MaterialParams", "BSDFSample", "lookup",
           "lookup_specialised", "is_delta", "sampled_delta", "is_glossy", "is_rough",
           "facing", "side", "lit", "specular_probability", "fresnel_dielectric", "refract",
           "fresnel_conductor", "fresnel_conductor_rgb", "mirror_reflectance",
           "adjoint_correction", "shading_ratio", "evaluate", "sample", "transmission_tint",
           "back_side"]


def _rough(kinds, mp: MaterialParams, flipped: Array, wo_l: V3, wi_l: V3,
           mode: int) -> tuple[V3, Array]:
    """(f, pdf) of the rough kinds present, for local directions (0 where unlit)."""
    lit_o = lit(wo_l.z)
    same = lit_o & lit(wi_l.z)
    zero = jnp.zeros_like(wo_l.z)
    f, pdf = V3(zero, zero, zero), zero
    if ROUGH_CONDUCTOR in kinds:
        sel = (mp.kind == ROUGH_CONDUCTOR) & same
        f_c, pdf_c = roughconductor.evaluate(mp, wo_l, wi_l, same)
        f, pdf = where(sel, f_c, f), jnp.where(sel, pdf_c, pdf)
    if ROUGH_PLASTIC in kinds:
        sel = (mp.kind == ROUGH_PLASTIC) & same
        f_p, pdf_p = roughplastic.evaluate(mp, wo_l, wi_l, same)
        f, pdf = where(sel, f_p, f), jnp.where(sel, pdf_p, pdf)
    if ROUGH_DIELECTRIC in kinds:
        both = lit_o & lit(jnp.abs(wi_l.z))
        sel = (mp.kind == ROUGH_DIELECTRIC) & both
        eta = roughdielectric.relative_eta(mp, flipped)
        f_t, pdf_t = roughdielectric.evaluate(mp, wo_l, wi_l, eta, both, mode)
        f, pdf = where(sel, f_t, f), jnp.where(sel, pdf_t, pdf)
    # computed once: f and pdf feed several consumers (value, MIS weight, reverse density), and
    # XLA would otherwise copy the whole microfacet evaluation into each
    # (perf: docs/performance.md#microfacet-evaluation)
    return materialize((f, pdf))


def _local(n: V3, nf: V3, cos_o: Array, wo: V3) -> tuple[V3, V3, V3]:
    """(s, t, wo in local coordinates), wo_z = cos_o exactly (the side test's value)."""
    s, t = mf.frame(n)
    return s, t, V3(dot(wo, s), dot(wo, t), cos_o)


def evaluate(kinds, mp: MaterialParams, n: V3, wo: V3, wi: V3,
             mode: int = RADIANCE) -> tuple[V3, Array]:
    """(f(wo, wi), pdf(wo -> wi)) for the non-Dirac part of the material. ``mode`` (static)
    matters for the rough dielectric's transmission only."""
    nf, cos_o, flipped = side(n, wo)
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
    if PLASTIC in kinds:   # the base alone (the coating's reflection is Dirac)
        sel = mp.kind == PLASTIC
        f_p, pdf_p = plastic.evaluate(mp, cos_o, jnp.maximum(cos_i, 0.0))
        f = where(sel, f_p, f)
        pdf = jnp.where(sel, pdf_p, pdf)
    f = where(above, f, V3(zero, zero, zero))
    pdf = jnp.where(above, pdf, 0.0)
    if any(k in kinds for k in ROUGH_KINDS):
        s, t, wo_l = _local(n, nf, cos_o, wo)
        wi_l = V3(dot(wi, s), dot(wi, t), cos_i)
        f_r, pdf_r = _rough(kinds, mp, flipped, wo_l, wi_l, mode)
        rough = is_rough(mp)
        f, pdf = where(rough, f_r, f), jnp.where(rough, pdf_r, pdf)
    if mp.one_sided is not None:
        back = back_side(mp, n, wo) | back_side(mp, n, wi)
        f, pdf = where(back, V3(zero, zero, zero), f), jnp.where(back, 0.0, pdf)
    return f, pdf


def back_side(mp: MaterialParams, n: V3, w: V3) -> Array:
    """A one-sided material's lanes where ``w`` is on the back side of the raw (unflipped)
    normal ``n`` (cos theta <= 0, Mitsuba's test): it neither reflects nor is seen there.
    All False in a scene without one-sided materials."""
    if mp.one_sided is None:
        return jnp.zeros(jnp.shape(w.x), bool)
    return mp.one_sided & (dot(w, n) <= 0.0)


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
    if PLASTIC in kinds:
        out = choose(mp.kind == PLASTIC, plastic.sample(mp, nf, wo, cos_o, u_lobe, u1, u2), out)
    if any(k in kinds for k in ROUGH_KINDS):
        out = choose(is_rough(mp), _sample_rough(kinds, mp, n, nf, cos_o, flipped, wo, u_lobe,
                                                 u1, u2, mode), out)
    if mp.one_sided is not None:   # seen from the back, or scattered to it: nothing
        # stored first: the test reads the sampled direction, and without it XLA recomputed
        # every lobe's sampler in each consumer of the final select (SmallVCM's one-sided box:
        # path tracing 0.50 -> 6.5 M paths/s; docs/performance.md#one-sided-materials)
        out = materialize(out)
        out = choose(back_side(mp, n, wo) | back_side(mp, n, out.wi), no_sample(u1), out)
    return out


def _sample_rough(kinds, mp: MaterialParams, n: V3, nf: V3, cos_o: Array, flipped: Array,
                  wo: V3, u_lobe: Array, u1: Array, u2: Array, mode: int) -> BSDFSample:
    """A local direction from the lobe sampler of the lane's rough kind; its weight
    f |cos theta_i| / pdf from ``evaluate``'s (f, pdf) at that direction (taken back to local
    coordinates as ``evaluate`` does, so the two agree)."""
    s, t, wo_l = _local(n, nf, cos_o, wo)
    zero = jnp.zeros_like(cos_o)
    wi_l = V3(zero, zero, zero)
    if ROUGH_CONDUCTOR in kinds:
        wi_l = where(mp.kind == ROUGH_CONDUCTOR,
                     roughconductor.sample_direction(mp, wo_l, u1, u2), wi_l)
    if ROUGH_PLASTIC in kinds:
        wi_l = where(mp.kind == ROUGH_PLASTIC,
                     roughplastic.sample_direction(mp, wo_l, u_lobe, u1, u2), wi_l)
    through = zero > 0   # the rough dielectric of ior 1: a Dirac pass-through
    if ROUGH_DIELECTRIC in kinds:
        sel = mp.kind == ROUGH_DIELECTRIC
        eta = roughdielectric.relative_eta(mp, flipped)
        wi_l = where(sel, roughdielectric.sample_direction(mp, wo_l, eta, u_lobe, u1, u2), wi_l)
        through = sel & roughdielectric.passes_through(mp)
    # stored: the lobe samplers (GGX's visible normals above all) were otherwise recomputed in
    # each kernel reading a component of wi (perf: docs/performance.md#glossy-path-tracer)
    wi = materialize(mf.from_local(wi_l, s, t, nf))
    wi_l = V3(dot(wi, s), dot(wi, t), dot(wi, nf))
    f, pdf = _rough(kinds, mp, flipped, wo_l, wi_l, mode)
    ok = (pdf > 0) & ~through
    w = f * (jnp.abs(wi_l.z) / jnp.where(ok, pdf, 1.0))
    w = where(ok, w, V3(zero, zero, zero))
    pass_ok = through & lit(cos_o)
    w = where(pass_ok, transmission_tint(mp), w)
    wi = where(pass_ok, -wo, where(ok, wi, nf))
    return BSDFSample(wi, w, jnp.where(ok, pdf, 0.0), pass_ok, ok | pass_ok)
