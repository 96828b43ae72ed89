"""Sampling warps: each ``sample_*`` maps uniforms in [0,1)^2 to a domain, next to its ``pdf_*``.

pbrt-v4 style triples (sample, pdf, and where useful the inverse): the chi-square tests in
``tests/test_warps.py`` check every sampler against its own pdf. Densities are with respect to
solid angle for directions and area for positions. Directions are in a local frame whose +z is
the frame axis (the surface normal or a lobe axis); see :func:`jgi.core.vec.to_world`.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jax import Array

from .. import _xla
from .._xla import pow_positive, sincos, sincos_quarter
from .vec import V3

PI = jnp.float32(jnp.pi)
INV_PI = jnp.float32(1.0 / jnp.pi)
INV_4PI = jnp.float32(0.25 / jnp.pi)


def _safe_sqrt(x: Array) -> Array:
    return _xla.sqrt(jnp.maximum(x, 0.0))


# --- disc -------------------------------------------------------------------------------------

def sample_concentric_disc(u1: Array, u2: Array) -> tuple[Array, Array]:
    """Shirley-Chiu concentric map; see :func:`concentric_disc_polar` (which also returns r)."""
    x, y, _ = concentric_disc_polar(u1, u2)
    return x, y


def concentric_disc_polar(u1: Array, u2: Array, xp=jnp) -> tuple[Array, Array, Array]:
    """Shirley-Chiu concentric map of the square onto the unit disc (area-preserving).

    The square point (a, b) goes to radius r = a at angle phi = (pi/4) b/a where |a| > |b|, else
    to r = b at phi = pi/2 - (pi/4) a/b. Both angles are pi/4 t with |t| <= 1 (in the second
    case cos and sin swap), so one division and the sin/cos polynomials without range reduction
    suffice. At the centre r = 0 and the point is (0, 0) whatever t is. Returns (x, y, r), r = |a|
    or |b| exactly. ``xp=numpy``: the same map in float64 with exact division and trigonometry
    (roughplastic's coating quadrature at scene build)."""
    a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    first = xp.abs(a) > xp.abs(b)
    r = xp.where(first, a, b)
    if xp is jnp:
        # for float32 u in [0, 1), 2u - 1 is 0 or at least 2^-24 in magnitude (recip_normal's
        # range)
        t = jnp.where(first, b, a) * _xla.recip_normal(jnp.where(r == 0, 1.0, r))
        s, c = sincos_quarter((PI / 4) * t)
    else:
        t = xp.where(first, b, a) / xp.where(r == 0, 1.0, r)
        s, c = xp.sin((math.pi / 4) * t), xp.cos((math.pi / 4) * t)
    return r * xp.where(first, c, s), r * xp.where(first, s, c), xp.abs(r)


def pdf_disc() -> Array:
    return INV_PI


# --- hemisphere and sphere ----------------------------------------------------------------------

def sample_cosine_hemisphere(u1: Array, u2: Array) -> V3:
    """Malley's method: disc sample lifted to the hemisphere; pdf = cos(theta) / pi.

    cos(theta) = sqrt((1 - r)(1 + r)) from the disc radius r, which the concentric map gives
    exactly: 1 - x^2 - y^2 carries the rounding of the sin/cos polynomials (and of FMA
    contraction, which differs by CPU), so on the rim, r = 1, it gave 0 on one CPU and 3e-4
    on another. The product form is 0 there on every CPU, and exact to a few roundings
    elsewhere."""
    x, y, r = concentric_disc_polar(u1, u2)
    return V3(x, y, _safe_sqrt((1.0 - r) * (1.0 + r)))


def pdf_cosine_hemisphere(cos_theta: Array) -> Array:
    return jnp.where(cos_theta > 0, cos_theta * INV_PI, 0.0)


def sample_uniform_sphere(u1: Array, u2: Array) -> V3:
    z = 1.0 - 2.0 * u1
    r = _safe_sqrt(1.0 - z * z)
    phi = 2.0 * PI * u2
    sin_phi, cos_phi = sincos(phi)
    return V3(r * cos_phi, r * sin_phi, z)


def pdf_uniform_sphere() -> Array:
    return INV_4PI


# --- Clarberg's equal-area octahedral map (pbrt-v4's image infinite light) --------------------

def equal_area_square_to_sphere(s: Array, t: Array, xp=jnp) -> V3:
    """The unit square onto the sphere, area-preserving (Jacobian 4 pi): Clarberg's concentric
    octahedral map, as pbrt-v4's EqualAreaSquareToSphere. With (u, v) = (2s - 1, 2t - 1), the
    inner diamond |u| + |v| <= 1 is the upper hemisphere (z >= 0) and the four outer corners
    fold onto the lower one; r = 1 - |1 - |u| - |v|| is the concentric radius, z = +-(1 - r^2)
    and the azimuth is pi/4 ((|v| - |u|) / r + 1) in the quadrant of (u, v).
    ``xp=numpy``: the same map in float64 (scene build)."""
    u, v = 2.0 * s - 1.0, 2.0 * t - 1.0
    au, av = xp.abs(u), xp.abs(v)
    signed = 1.0 - (au + av)                 # > 0 inside the diamond (upper hemisphere)
    r = 1.0 - xp.abs(signed)
    phi = xp.where(r > 0, (av - au) / xp.where(r > 0, r, 1.0) + 1.0, 1.0) * (math.pi / 4)
    if xp is jnp:
        # phi in [0, pi/2]: the quarter-range polynomials about pi/4
        sa, ca = sincos_quarter(phi - jnp.float32(math.pi / 4))
        h = jnp.float32(math.sqrt(0.5))
        cos_phi, sin_phi = (ca - sa) * h, (sa + ca) * h
    else:
        cos_phi, sin_phi = xp.cos(phi), xp.sin(phi)
    z = xp.where(signed < 0, -1.0, 1.0) * (1.0 - r * r)
    sin_theta = r * xp.sqrt(xp.maximum(2.0 - r * r, 0.0))
    return V3(xp.where(u < 0, -1.0, 1.0) * xp.abs(cos_phi) * sin_theta,
              xp.where(v < 0, -1.0, 1.0) * xp.abs(sin_phi) * sin_theta, z)


def equal_area_sphere_to_square(d: V3, xp=jnp) -> tuple[Array, Array]:
    """The inverse of :func:`equal_area_square_to_sphere` for unit d: (s, t) in [0, 1]^2
    (pbrt-v4's EqualAreaSphereToSquare, with the library's arctangent where pbrt uses a
    polynomial, and 1 - |z| as (x^2 + y^2) / (1 + |z|), which keeps float32 its precision
    near the poles)."""
    x, y, z = xp.abs(d.x), xp.abs(d.y), xp.abs(d.z)
    r = xp.sqrt(xp.maximum((x * x + y * y) / (1.0 + z), 0.0))
    a, b = xp.maximum(x, y), xp.minimum(x, y)
    # arctan2, not arctan(b / a): jnp.arctan comes out wrong (errors up to pi/2) on arrays
    # of a thousand elements or more under jgi's XLA flags (jgi._xla: vector width 512)
    phi = xp.arctan2(b, xp.where(a > 0, a, 1.0)) * (2.0 / math.pi)
    phi = xp.where(x < y, 1.0 - phi, phi)
    v = phi * r
    u = r - v
    south = d.z < 0                          # mirror into an outer corner
    u, v = xp.where(south, 1.0 - v, u), xp.where(south, 1.0 - u, v)
    u = xp.where(d.x < 0, -u, u)
    v = xp.where(d.y < 0, -v, v)
    return 0.5 * (u + 1.0), 0.5 * (v + 1.0)


def sample_uniform_cone(u1: Array, u2: Array, cos_max: Array,
                        one_minus_cos_max: Array | None = None) -> V3:
    """Uniform direction within angle acos(cos_max) of +z; pdf = 1 / (2 pi (1 - cos_max)).

    Works with 1 - cos(theta) = u1 (1 - cos_max) and sin^2 = (1 - cos)(1 + cos): in float32,
    sqrt(1 - cos^2) of a cosine near 1 keeps only a few distinct values, which clumps the
    samples of narrow cones (small or distant sphere lights). Callers that know
    ``one_minus_cos_max`` more precisely than ``1 - cos_max`` (e.g. sin^2 / (1 + cos)) pass it.
    """
    om_max = (1.0 - cos_max) if one_minus_cos_max is None else one_minus_cos_max
    one_minus = u1 * om_max
    cos_t = 1.0 - one_minus
    sin_t = _safe_sqrt(one_minus * (2.0 - one_minus))
    phi = 2.0 * PI * u2
    sin_phi, cos_phi = sincos(phi)
    return V3(sin_t * cos_phi, sin_t * sin_phi, cos_t)


def pdf_uniform_cone(cos_max: Array) -> Array:
    solid_angle = 2.0 * PI * (1.0 - cos_max)
    return jnp.where(solid_angle > 0, 1.0 / jnp.where(solid_angle > 0, solid_angle, 1.0), 0.0)


# --- Phong lobe ---------------------------------------------------------------------------------

def sample_phong_lobe(u1: Array, u2: Array, exponent: Array) -> V3:
    """Direction about +z with density (n + 1) / (2 pi) cos^n(alpha) (Lafortune & Willems 1994).

    cos(alpha) = u1^(1 / (n + 1)); 1 - cos(alpha) = -expm1(log(u1) / (n + 1)) keeps the angle
    precise in float32 for sharp lobes (see :func:`sample_uniform_cone`).
    """
    one_minus = -jnp.expm1(jnp.log(u1) / (exponent + 1.0))
    cos_a = 1.0 - one_minus
    sin_a = _safe_sqrt(one_minus * (2.0 - one_minus))
    phi = 2.0 * PI * u2
    sin_phi, cos_phi = sincos(phi)
    return V3(sin_a * cos_phi, sin_a * sin_phi, cos_a)


def pdf_phong_lobe(cos_alpha: Array, exponent: Array) -> Array:
    """(n + 1) / (2 pi) cos^n(alpha) on the lobe's hemisphere, 0 outside (also for n = 0)."""
    inside = cos_alpha > 0
    c = jnp.where(inside, cos_alpha, 1.0)  # finite gradients outside the lobe
    return jnp.where(inside, (exponent + 1.0) * (0.5 * INV_PI) * pow_positive(c, exponent), 0.0)


# --- triangle -----------------------------------------------------------------------------------

def sample_uniform_triangle(u1: Array, u2: Array) -> tuple[Array, Array]:
    """Barycentrics (b1, b2) uniform over the triangle (square-root parameterisation)."""
    s = _safe_sqrt(u1)
    return s * (1.0 - u2), s * u2
