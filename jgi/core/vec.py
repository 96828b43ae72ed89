"""Three-component vectors stored as separate x, y, z arrays (struct of arrays).

On XLA's CPU backend, arithmetic on three separate [N] arrays fuses and vectorises far better
than on one [N, 3] array (measured: about 70x on the path tracer's bounce kernel), so every hot
path in jgi works with :class:`V3`. A ``V3`` is a NamedTuple, hence a pytree: it passes through
``jit``, ``vmap``, ``lax`` loops and ``grad`` unchanged.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from .._xla import rsqrt as _rsqrt  # fusion-friendly 1/sqrt (jgi._xla, item 5)

# A cosine within EDGE_ON_COS of zero counts as zero: the direction is edge-on to the surface,
# or the ray lies in the primitive's plane. A float32 dot product of unit vectors is off by up
# to 3 roundings (3 * 2^-24 = 1.8e-7), and by how much depends on the processor: XLA contracts
# a * b + c into one fused multiply-add wherever the CPU has FMA, so an exactly perpendicular
# pair gives 0 on a CPU without FMA and +-7e-9 on one with it (measured; tests/test_cpu.py).
# Every sidedness decision that can meet an exactly edge-on input (a BSDF's, an emitter's, a
# ray against a plane) compares against this band, 5x wider than that error, so it is decided
# alike on every x86-64 CPU. What the band drops is a set of directions of projected solid
# angle about EDGE_ON_COS^2 = 1e-12 of the hemisphere's.
EDGE_ON_COS = 1e-6


class V3(NamedTuple):
    x: Array
    y: Array
    z: Array

    # Arithmetic overrides tuple concatenation/repetition on purpose: V3 is a vector.
    def __add__(self, o):  # type: ignore[override]
        if isinstance(o, V3):
            return V3(self.x + o.x, self.y + o.y, self.z + o.z)
        return V3(self.x + o, self.y + o, self.z + o)

    __radd__ = __add__

    def __sub__(self, o):
        if isinstance(o, V3):
            return V3(self.x - o.x, self.y - o.y, self.z - o.z)
        return V3(self.x - o, self.y - o, self.z - o)

    def __neg__(self):
        return V3(-self.x, -self.y, -self.z)

    def __mul__(self, s):  # type: ignore[override]
        if isinstance(s, V3):
            return V3(self.x * s.x, self.y * s.y, self.z * s.z)
        return V3(self.x * s, self.y * s, self.z * s)

    __rmul__ = __mul__

    def __truediv__(self, s):
        if isinstance(s, V3):
            return V3(self.x / s.x, self.y / s.y, self.z / s.z)
        return V3(self.x / s, self.y / s, self.z / s)

    def map(self, fn) -> "V3":
        return V3(fn(self.x), fn(self.y), fn(self.z))

    def stack(self) -> Array:
        """[..., 3] array (for output and tests, not for hot paths)."""
        return jnp.stack([self.x, self.y, self.z], axis=-1)

    @staticmethod
    def of(a) -> "V3":
        """From an array-like with a trailing axis of 3."""
        a = jnp.asarray(a)
        return V3(a[..., 0], a[..., 1], a[..., 2])

    @staticmethod
    def full(v, like: Array | None = None) -> "V3":
        v = jnp.asarray(v, jnp.float32)
        if like is not None:
            v = jnp.broadcast_to(v, jnp.shape(like))
        return V3(v, v, v)


def dot(a: V3, b: V3) -> Array:
    return a.x * b.x + a.y * b.y + a.z * b.z


def cross(a: V3, b: V3) -> V3:
    return V3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x)


def length(a: V3) -> Array:
    return jnp.sqrt(dot(a, a))


def normalize(a: V3) -> V3:
    """Unit vector; the zero vector maps to zero rather than NaN."""
    n2 = dot(a, a)
    inv = jnp.where(n2 > 0, _rsqrt(jnp.where(n2 > 0, n2, 1.0)), 0.0)
    return a * inv


def where(c: Array, a: V3, b: V3) -> V3:
    return V3(jnp.where(c, a.x, b.x), jnp.where(c, a.y, b.y), jnp.where(c, a.z, b.z))


def reflect(wi: V3, n: V3) -> V3:
    """Mirror direction of ``wi`` (pointing away from the surface) about ``n``."""
    return n * (2.0 * dot(wi, n)) - wi


def luminance(rgb: V3) -> Array:
    """Rec. 709 luminance, used for power-proportional choices and Russian roulette."""
    return 0.2126 * rgb.x + 0.7152 * rgb.y + 0.0722 * rgb.z


def max_component(a: V3) -> Array:
    return jnp.maximum(jnp.maximum(a.x, a.y), a.z)


def coordinate_system(n: V3) -> tuple[V3, V3]:
    """Orthonormal tangent frame (s, t) for unit ``n`` without branches.

    Duff et al. 2017, "Building an Orthonormal Basis, Revisited"; continuous except at the
    south pole seam, where it stays orthonormal.
    """
    sign = jnp.where(n.z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n.z)
    b = n.x * n.y * a
    s = V3(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x)
    t = V3(b, sign + n.y * n.y * a, -n.y)
    return s, t


def to_world(local: V3, n: V3) -> V3:
    """Local (s, t, n) coordinates to world space."""
    s, t = coordinate_system(n)
    return s * local.x + t * local.y + n * local.z


def to_local(w: V3, n: V3) -> V3:
    s, t = coordinate_system(n)
    return V3(dot(w, s), dot(w, t), dot(w, n))
