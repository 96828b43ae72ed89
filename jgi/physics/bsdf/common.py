"""What every BSDF shares: the material parameters, the sample record, transport modes, and
the side tests (which side of the surface a direction is on, and the edge-on band)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from ...core.vec import EDGE_ON_COS, V3, dot
from ...scene.data import DIELECTRIC, MIRROR, Materials

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
    return MaterialParams(mats.kind[m], V3(mats.diffuse.x[m], mats.diffuse.y[m], mats.diffuse.z[m]),
                          V3(mats.specular.x[m], mats.specular.y[m], mats.specular.z[m]),
                          mats.exponent[m], mats.ior[m])


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
