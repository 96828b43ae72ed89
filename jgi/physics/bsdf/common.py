"""What every BSDF shares: the material parameters, the sample record, transport modes, and
the side tests (which side of the surface a direction is on, and the edge-on band)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array

from ..._xla import materialize
from ..._xla import take as _take
from ...core.vec import EDGE_ON_COS, V3, dot, where
from ...scene.rough_coating import TABLE_SIZE
from ...scene.tables import (
    DIELECTRIC,
    DIFFUSE,
    GGX,
    MIRROR,
    PHONG,
    PLASTIC,
    ROUGH_CONDUCTOR,
    ROUGH_DIELECTRIC,
    ROUGH_KINDS,
    ROUGH_PLASTIC,
    TEX_ALPHA,
    TEX_ALPHA_V,
    TEX_DIFFUSE,
    TEX_SPECULAR,
    Materials,
)
from .. import textures

# Transport modes: camera paths carry radiance, light paths importance (Veach 1997, 5.2).
RADIANCE, IMPORTANCE = 0, 1

# Rough kinds with roughness below this are "glossy" (is_glossy): sharp enough that density
# estimation should sample through them rather than look photons up there.
GLOSSY_ALPHA = 0.1

_ZERO3 = V3(0.0, 0.0, 0.0)
# the roughplastic table of scenes without roughplastic (never read)
_NO_TABLE = np.ones((1, TABLE_SIZE), np.float32)


class MaterialParams(NamedTuple):
    """One material row per lane (see :class:`jgi.scene.Materials`). The fields after ``ior``
    have defaults, so code that builds the first five (the kinds that existed before the
    microfacet ones) keeps working; the defaults make a mirror perfect (eta = k = 0)."""

    kind: Array
    kd: V3
    ks: V3
    exponent: Array
    ior: Array
    alpha_u: Array = 0.1              # roughness along s of the shading frame
    alpha_v: Array = 0.1              # roughness along t
    distribution: Array = GGX        # int array (GGX or BECKMANN), or a Python int when the
                                     # scene uses one distribution (lookup_specialised)
    eta: V3 = _ZERO3                  # conductor index of refraction eta + i k (mirror and
    k: V3 = _ZERO3                    # roughconductor; eta = 0 reflects everything)
    row: Array = 0                    # material row (roughplastic's table lookup)
    transmittance: Array = _NO_TABLE  # [M, 64] roughplastic T(cos): the
                                      # whole table, not per lane (read at row, cos)
    internal_reflectance: Array = 0.0  # roughplastic coating's Ri (per lane)
    nonlinear: Array = False          # roughplastic's nonlinear option (per lane)
    kt: V3 | None = None              # a (rough) dielectric's transmission tint (Mitsuba's
                                      # specular_transmittance); None: ks tints both lobes
    one_sided: Array | None = None    # bool: reflects on n's side only; None: the scene has
                                      # no one-sided material


def transmission_tint(mp: MaterialParams) -> V3:
    """The factor of a dielectric's transmitted (refracted or passed-through) light: ``kt``,
    or the one tint ``ks`` where the params carry none. Reflection is tinted by ``ks``."""
    return mp.ks if mp.kt is None else mp.kt


class BSDFSample(NamedTuple):
    wi: V3
    weight: V3     # f |cos theta_i| / pdf (the Dirac weight for specular lobes)
    pdf: Array     # solid-angle pdf of the sampled direction (0 for Dirac lobes)
    delta: Array   # True if a Dirac lobe was sampled
    valid: Array   # False if the sample was absorbed / fell below the surface


def lookup(mats: Materials, m: Array, uv=None) -> MaterialParams:
    """Rows ``m`` (any index array) of the material table (the roughplastic table whole: the
    BSDF reads two entries of row ``m`` per lane), its textured parameters evaluated at the
    surface coordinates ``uv`` (u, v) of each lane (needed, and only read, when the scene has
    textures: :func:`textured`)."""
    row3 = lambda v: V3(v.x[m], v.y[m], v.z[m])  # noqa: E731
    return textured(mats, m, uv, MaterialParams(mats.kind[m], row3(mats.diffuse), row3(mats.specular),
                          mats.exponent[m], mats.ior[m], mats.alpha_u[m], mats.alpha_v[m],
                          mats.distribution[m], row3(mats.eta), row3(mats.k), m,
                          mats.transmittance, mats.internal_reflectance[m], mats.nonlinear[m],
                          row3(mats.transmission_tint),
                          mats.one_sided[m] if mats.has_one_sided else None))


def textured(mats: Materials, m: Array, uv, mp: MaterialParams) -> MaterialParams:
    """``mp`` (rows ``m``) with its textured parameters (diffuse and specular reflectance,
    roughness alpha_u and alpha_v) evaluated at ``uv`` where the row names a texture. The one place
    textures enter the BSDFs; a scene without textures returns ``mp`` unchanged (its kernels
    are those of jgi before textures)."""
    if not mats.has_textures:
        return mp
    if uv is None:
        raise ValueError("the scene has textures: material lookups need the surface coordinates "
                         "(uv) of each point")
    tex, index, cols = mats.textures, mats.texture, mats.textured
    u, v = (jnp.broadcast_to(c, m.shape) for c in uv)
    kd, ks, au, av = mp.kd, mp.ks, mp.alpha_u, mp.alpha_v
    if TEX_DIFFUSE in cols:
        kd = textures.textured(tex, index[m, TEX_DIFFUSE], (u, v), V3(*(jnp.broadcast_to(c, m.shape)
                                                                        for c in kd)))
    kt = mp.kt
    if TEX_SPECULAR in cols:
        i = index[m, TEX_SPECULAR]
        ks = textures.textured(tex, i, (u, v), V3(*(jnp.broadcast_to(c, m.shape) for c in ks)))
        if kt is not None:   # a textured dielectric tint tints both lobes (the builder's rule)
            kt = where(i >= 0, ks, V3(*(jnp.broadcast_to(c, m.shape) for c in kt)))
    if TEX_ALPHA in cols:
        i = index[m, TEX_ALPHA]
        au = textures.textured_scalar(tex, i, (u, v), jnp.broadcast_to(au, m.shape))
        if TEX_ALPHA_V not in cols:   # isotropic textures only: alpha_v follows alpha_u
            av = jnp.where(i >= 0, au, av)
    if TEX_ALPHA_V in cols:           # anisotropic ones: alpha_v's own texture, or constant
        av = textures.textured_scalar(tex, index[m, TEX_ALPHA_V], (u, v), jnp.broadcast_to(av, m.shape))
    return mp._replace(kd=kd, ks=ks, alpha_u=au, alpha_v=av, kt=kt)


def lookup_specialised(mats: Materials, m: Array, uv=None, stored: bool = False) -> MaterialParams:
    """:func:`lookup` for inner loops, specialised to the kinds the scene uses (``mats.kinds``):
    small material tables are read with selects instead of gathers (see jgi._xla.take), a kind
    that is the only one present is a constant, and the parameters no present kind reads are
    constants too, so the BSDF code of the absent kinds folds away; likewise the microfacet
    distribution is a Python int when the scene's rough materials use one
    (``mats.distributions``), so the other one's code is not traced. Values that a present
    kind's BSDF reads are those of :func:`lookup`. ``stored``: the values read from the table
    are computed once and stored (``jgi._xla.materialize``), for callers whose BSDF code spans
    several kernels, each of which would otherwise repeat the select chains."""
    kinds = mats.kinds
    reads = []

    def take(table, idx):
        v = _take(table, idx)
        reads.append(v)
        return v

    kind = (jnp.full(m.shape, kinds[0], jnp.int32) if len(kinds) == 1 else take(mats.kind, m))
    zero = jnp.zeros(m.shape, jnp.float32)
    zero3 = V3(zero, zero, zero)
    has = lambda *ks: any(k in kinds for k in ks)  # noqa: E731
    col3 = lambda v: V3(*(take(c, m) for c in v))  # noqa: E731
    kd = col3(mats.diffuse) if has(DIFFUSE, PHONG, ROUGH_PLASTIC, PLASTIC) else zero3
    ks = col3(mats.specular) if has(MIRROR, DIELECTRIC, PHONG, PLASTIC, *ROUGH_KINDS) else zero3
    exponent = take(mats.exponent, m) if PHONG in kinds else zero
    ior = (take(mats.ior, m) if has(DIELECTRIC, ROUGH_DIELECTRIC, ROUGH_PLASTIC, PLASTIC)
           else zero + 1.0)
    rough = has(*ROUGH_KINDS)
    alpha_u = take(mats.alpha_u, m) if rough else zero + 0.1
    alpha_v = take(mats.alpha_v, m) if rough else zero + 0.1
    # one distribution in the scene: a Python int, so that microfacet code traces only it
    dists = mats.distributions
    distribution = take(mats.distribution, m) if len(dists) > 1 else (dists or (GGX,))[0]
    # eta = 0 constants where every conductor is a perfect mirror: F = 1 folds at compile time
    # (perf: docs/performance.md#glossy-path-tracer)
    conductor = has(MIRROR, ROUGH_CONDUCTOR) and mats.conductor_fresnel
    eta = col3(mats.eta) if conductor else zero3
    k = col3(mats.k) if conductor else zero3
    plastic = ROUGH_PLASTIC in kinds
    coated = has(ROUGH_PLASTIC, PLASTIC)   # both read Ri and nonlinear
    mp = MaterialParams(
        kind, kd, ks, exponent, ior, alpha_u, alpha_v, distribution, eta, k,
        m if plastic else jnp.zeros(m.shape, jnp.int32),
        mats.transmittance if plastic else _NO_TABLE,
        take(mats.internal_reflectance, m) if coated else zero,
        take(mats.nonlinear, m) if coated else zero > 0,
        col3(mats.transmission_tint) if has(DIELECTRIC, ROUGH_DIELECTRIC) else None,
        take(mats.one_sided, m) if mats.has_one_sided else None)
    if stored and reads:   # the constants stay constants (they fold away)
        swap = {id(a): b for a, b in zip(reads, materialize(tuple(reads)))}
        mp = MaterialParams(*(V3(*(swap.get(id(c), c) for c in x)) if isinstance(x, V3)
                              else swap.get(id(x), x) for x in mp))
    return textured(mats, m, uv, mp)


def is_delta(mp: MaterialParams) -> Array:
    """True for purely specular materials (no lobe that ``evaluate`` or NEE can use): the
    vertex cannot be connected to. The rough kinds are never Dirac, however small their
    roughness; nor is the smooth plastic (its base is not), though its samples may be."""
    return (mp.kind == MIRROR) | (mp.kind == DIELECTRIC)


def sampled_delta(kinds, mp: MaterialParams, bs: BSDFSample) -> Array:
    """Whether the direction ``bs`` sampled at a vertex of material ``mp`` left it by a Dirac
    lobe: what MIS needs of a path's bounce (pbrt-v4's Vertex::delta). Per sample in scenes with
    smooth plastic (``kinds`` static), whose vertices mix Dirac and non-Dirac lobes; elsewhere
    the material's :func:`is_delta`, as before plastic (the same program)."""
    if PLASTIC not in kinds:
        return is_delta(mp)
    return is_delta(mp) | ((mp.kind == PLASTIC) & bs.delta)


def is_rough(mp: MaterialParams) -> Array:
    """True for the microfacet kinds (roughconductor, roughdielectric, roughplastic)."""
    return (mp.kind == ROUGH_CONDUCTOR) | (mp.kind == ROUGH_DIELECTRIC) | (mp.kind == ROUGH_PLASTIC)


def is_glossy(mp: MaterialParams) -> Array:
    """True for microfacet materials whose larger roughness is below ``GLOSSY_ALPHA``: lobes so
    sharp that density estimation (photon lookups) there is hopeless and sampling through them
    is better. roughplastic counts too (its diffuse base would allow lookups; callers that want
    them can test the kind)."""
    return is_rough(mp) & (jnp.maximum(mp.alpha_u, mp.alpha_v) < GLOSSY_ALPHA)


def facing(n: V3, w: V3) -> V3:
    """The normal flipped onto ``w``'s side."""
    return side(n, w)[0]


def side(n: V3, wo: V3) -> tuple[V3, Array, Array]:
    """(n flipped onto wo's side, |cos theta_o|, whether it was flipped). Every side test of a
    BSDF derives from this one dot product: recomputing dot(wo, n_flipped) instead can round
    (XLA contracts it into FMAs differently per fusion) to the other sign when wo grazes the
    surface, making ``valid`` and ``weight`` disagree."""
    cos_o = dot(n, wo)
    flip = cos_o < 0
    return n * jnp.where(flip, -1.0, 1.0), jnp.abs(cos_o), flip


def lit(cos: Array) -> Array:
    """A cosine (>= 0 by construction, or signed) counts as above the surface: outside the
    edge-on band, so that an edge-on direction is decided alike on every CPU."""
    return cos > EDGE_ON_COS


def adjoint_correction(ns: V3, ng: V3, wo: V3, wi: V3) -> Array:
    """Veach's (1997, sec. 5.3) correction of the adjoint BSDF for shading normals, by which
    a throughput sampled or evaluated in importance mode (light subpaths, photons, t = 1
    camera connections) is multiplied: |wo . ns| |wi . ng| / (|wo . ng| |wi . ns|) (pbrt-v4's
    CorrectShadingNormal, Mitsuba 3's particle tracer), wo towards the light, wi the direction
    importance arrives from. With it, f |wi . ns| (the path tracer's cosine) times the factor
    is f |wo . ns| |wi . ng| / |wo . ng|, so light paths value every path as camera paths do.
    0 where a denominator vanishes (no NaN or Inf)."""
    num = jnp.abs(dot(wo, ns)) * jnp.abs(dot(wi, ng))
    den = jnp.abs(dot(wo, ng)) * jnp.abs(dot(wi, ns))
    ok = den > 0
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def shading_ratio(ns: V3, ng: V3, wi: V3) -> Array:
    """|wi . ns| / |wi . ng|: what turns a flux density on the geometric surface (photons
    arriving from wi) into the path tracer's shading-normal cosine (photon density estimates
    on smooth meshes). 0 where wi grazes the geometric surface."""
    den = jnp.abs(dot(wi, ng))
    ok = den > 0
    return jnp.where(ok, jnp.abs(dot(wi, ns)) / jnp.where(ok, den, 1.0), 0.0)


def no_sample(like: Array) -> BSDFSample:
    """An absorbed sample: what lanes of no listed kind return."""
    zero = jnp.zeros_like(like)
    return BSDFSample(V3(zero, zero, zero + 1.0), V3(zero, zero, zero), zero, zero > 0, zero > 0)
