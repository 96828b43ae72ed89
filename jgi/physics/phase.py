"""Phase functions of participating media: how a scattering event in a medium redirects light.

A phase function p(d_in, d_out) is a density over the sphere of outgoing propagation directions
d_out given the incoming propagation direction d_in (both unit, both pointing the way light or
the path travels); it integrates to one, so the single-scattering albedo alone says how much is
scattered. jgi writes it in the propagation directions' cosine mu = d_in . d_out (mu = 1: no
change of direction, forward scattering). pbrt-v4 and Mitsuba 3 write the same function in
cos(wo, wi) with wo pointing back along the path, which is -mu.

* isotropic: p = 1 / (4 pi).
* Henyey-Greenstein (1941), asymmetry g in (-1, 1), the mean cosine E[mu] = g:

      p_HG(mu) = (1 - g^2) / (4 pi (1 + g^2 - 2 g mu)^(3/2)),

  sampled exactly by inverting its cumulative distribution in mu (Pharr, Jakob, Humphreys,
  pbrt-v4 section 11.3.1, in jgi's sign):

      mu = (1 + g^2 - ((1 - g^2) / (1 - g + 2 g xi))^2) / (2 g),   mu = 1 - 2 xi for g ~ 0,

  and phi = 2 pi xi_2 about d_in. The sample's value equals its density, so the weight
  p / pdf of a phase sample is exactly 1.

Isotropic is HG with g = 0; the functions take g per lane, so a scene mixes both in one kernel.
Reciprocity: p(d_in, d_out) = p(-d_out, -d_in) (same mu), which light tracing and BDPT rely on.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from ..core.vec import V3, coordinate_system, dot

INV_4PI = 1.0 / (4.0 * jnp.pi)
G_ISOTROPIC = 1e-3     # below this |g| the HG inversion loses precision: sample uniformly
G_MAX = 0.999          # |g| is clamped here (g = +-1 is a Dirac delta, not a density)


class PhaseSample(NamedTuple):
    d_out: V3        # sampled outgoing propagation direction (unit)
    pdf: Array       # its solid-angle density, equal to the phase function's value
    mu: Array        # d_in . d_out


def henyey_greenstein(mu: Array, g: Array) -> Array:
    """p_HG(mu) for the propagation cosine mu = d_in . d_out (see the module)."""
    g = jnp.clip(g, -G_MAX, G_MAX)
    denom = jnp.maximum(1.0 + g * g - 2.0 * g * mu, 1e-12)
    return INV_4PI * (1.0 - g * g) / (denom * jnp.sqrt(denom))


def evaluate(g: Array, d_in: V3, d_out: V3) -> Array:
    """The phase function (= the density :func:`sample` draws d_out with) for directions d_in,
    d_out."""
    return henyey_greenstein(jnp.clip(dot(d_in, d_out), -1.0, 1.0), g)


def sample_mu(g: Array, u: Array) -> Array:
    """The propagation cosine of an HG sample from one uniform u in [0, 1)."""
    g = jnp.clip(g, -G_MAX, G_MAX)
    iso = jnp.abs(g) < G_ISOTROPIC
    gs = jnp.where(iso, 0.5, g)         # a value that keeps the unused branch finite
    s = (1.0 - gs * gs) / (1.0 - gs + 2.0 * gs * u)
    mu = (1.0 + gs * gs - s * s) / (2.0 * gs)
    return jnp.clip(jnp.where(iso, 1.0 - 2.0 * u, mu), -1.0, 1.0)


def sample(g: Array, d_in: V3, u1: Array, u2: Array) -> PhaseSample:
    """An outgoing direction by the HG phase function about d_in (unit), from uniforms u1, u2."""
    mu = sample_mu(g, u1)
    sin_t = jnp.sqrt(jnp.maximum(0.0, 1.0 - mu * mu))
    phi = 2.0 * jnp.pi * u2
    s, t = coordinate_system(d_in)
    cx, cy = sin_t * jnp.cos(phi), sin_t * jnp.sin(phi)
    d_out = V3(*(cx * a + cy * b + mu * c for a, b, c in zip(s, t, d_in)))
    return PhaseSample(d_out, henyey_greenstein(mu, g), mu)
