"""What every BSDF shares: the material parameters, the sample record, transport modes, and
the side tests (which side of the surface a direction is on, and the edge-on band)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from ..._xla import take
from ...core.vec import EDGE_ON_COS, V3, dot
from ...scene.data import DIELECTRIC, DIFFUSE, MIRROR, PHONG, Materials

# Transport modes: camera paths carry radiance, light paths importance (Veach 1997, 5.2).
RADIANCE, IMPORTANCE = 0, 1


class MaterialParams(NamedTuple):
    """One material row per lane (see :class:`jgi.scene.Materials`)."""

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
    """Rows ``m`` (any index array) of the material table."""
    return MaterialParams(mats.kind[m], V3(mats.diffuse.x[m], mats.diffuse.y[m], mats.diffuse.z[m]),
                          V3(mats.specular.x[m], mats.specular.y[m], mats.specular.z[m]),
                          mats.exponent[m], mats.ior[m])


def lookup_specialised(mats: Materials, m: Array) -> MaterialParams:
    """:func:`lookup` for inner loops, specialised to the kinds the scene uses (``mats.kinds``):
    small material tables are read with selects instead of gathers (see jgi._xla.take), a kind
    that is the only one present is a constant, and the parameters no present kind reads are
    constants too, so the BSDF code of the absent kinds folds away. Values that a present
    kind's BSDF reads are those of :func:`lookup`."""
    kinds = mats.kinds
    kind = (jnp.full(m.shape, kinds[0], jnp.int32) if len(kinds) == 1 else take(mats.kind, m))
    zero = jnp.zeros(m.shape, jnp.float32)
    uses_ks = any(k in kinds for k in (MIRROR, DIELECTRIC, PHONG))
    kd = V3(*(take(c, m) for c in mats.diffuse)) if (DIFFUSE in kinds or PHONG in kinds) else V3(zero, zero, zero)
    ks = V3(*(take(c, m) for c in mats.specular)) if uses_ks else V3(zero, zero, zero)
    exponent = take(mats.exponent, m) if PHONG in kinds else zero
    ior = take(mats.ior, m) if DIELECTRIC in kinds else zero + 1.0
    return MaterialParams(kind, kd, ks, exponent, ior)


def is_delta(mp: MaterialParams) -> Array:
    """True for purely specular materials (no lobe that ``evaluate`` or NEE can use)."""
    return (mp.kind == MIRROR) | (mp.kind == DIELECTRIC)


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


def no_sample(like: Array) -> BSDFSample:
    """An absorbed sample: what lanes of no listed kind return."""
    zero = jnp.zeros_like(like)
    return BSDFSample(V3(zero, zero, zero + 1.0), V3(zero, zero, zero), zero, zero > 0, zero > 0)
