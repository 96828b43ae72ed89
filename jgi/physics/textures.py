"""Textures evaluated at surface coordinates (u, v): Mitsuba's ``checkerboard`` and ``bitmap``
(bilinear filter, ``repeat`` wrap), pbrt-v4's ``checkerboard`` and ``imagemap``.

A texture row i of :class:`jgi.scene.tables.Textures` first maps (u, v) by its affine ``to_uv``;
then

* checkerboard: ``color0`` where frac(u') > 1/2 and frac(v') > 1/2 agree, else ``color1``
  (Mitsuba's checkerboard.cpp);
* bitmap (w x h texels, row 0 at v' = 0): the texel grid is sampled at
  (x, y) = (u' w - 1/2, v' h - 1/2), bilinearly between the four texels around it, their indices
  wrapped modulo w and h (Mitsuba's bilinear filter with wrap mode ``repeat``).

Scalar parameters (roughness) take the luminance of the RGB value, as Mitsuba's ``eval_1`` of an
RGB texture does."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ..core.vec import V3, where
from ..scene.tables import BITMAP, CHECKERBOARD, Textures


def _row(a: Array, i: Array) -> Array:
    return a[i]


def map_uv(tex: Textures, i: Array, u: Array, v: Array) -> tuple[Array, Array]:
    """(u', v') of texture rows ``i`` at (u, v): the affine ``to_uv``."""
    a = tex.to_uv[i]
    return (a[..., 0] * u + a[..., 1] * v + a[..., 2], a[..., 3] * u + a[..., 4] * v + a[..., 5])


def checkerboard(color0: V3, color1: V3, u: Array, v: Array) -> V3:
    """Mitsuba's checkerboard at mapped coordinates (u, v)."""
    same = ((u - jnp.floor(u)) > 0.5) == ((v - jnp.floor(v)) > 0.5)
    return where(same, color0, color1)


def bilinear(tex: Textures, i: Array, u: Array, v: Array) -> V3:
    """Bitmap rows ``i`` at mapped coordinates (u, v): bilinear, wrapped (``repeat``)."""
    w, h, off = tex.width[i], tex.height[i], tex.offset[i]
    x = u * w.astype(u.dtype) - 0.5
    y = v * h.astype(v.dtype) - 0.5
    x0, y0 = jnp.floor(x), jnp.floor(y)
    fx, fy = x - x0, y - y0
    x0, y0 = x0.astype(jnp.int32), y0.astype(jnp.int32)
    xs = (jnp.mod(x0, w), jnp.mod(x0 + 1, w))
    ys = (jnp.mod(y0, h), jnp.mod(y0 + 1, h))
    out = [jnp.zeros_like(u)] * 3
    for ky, wy in ((0, 1.0 - fy), (1, fy)):
        for kx, wx in ((0, 1.0 - fx), (1, fx)):
            texel = tex.atlas[off + ys[ky] * w + xs[kx]]
            out = [o + (wx * wy) * texel[..., c] for c, o in enumerate(out)]
    return V3(*out)


def evaluate(tex: Textures, i: Array, uv: tuple[Array, Array]) -> V3:
    """RGB value of texture rows ``i`` (any index array, >= 0) at surface coordinates uv."""
    u, v = map_uv(tex, i, *uv)
    kinds = tex.kinds
    out = None
    if CHECKERBOARD in kinds:
        c0 = V3(*(_row(c, i) for c in tex.color0))
        c1 = V3(*(_row(c, i) for c in tex.color1))
        out = checkerboard(c0, c1, u, v)
    if BITMAP in kinds:
        b = bilinear(tex, i, u, v)
        out = b if out is None else where(tex.kind[i] == BITMAP, b, out)
    return out


def luminance(c: V3) -> Array:
    """Rec. 709 luminance (Mitsuba's ``luminance``), what scalar parameters take of a colour."""
    return 0.212671 * c.x + 0.715160 * c.y + 0.072169 * c.z


def textured(tex: Textures, index: Array, uv: tuple[Array, Array], constant: V3) -> V3:
    """The texture of rows ``index`` at uv where index >= 0, ``constant`` where it is -1."""
    value = evaluate(tex, jnp.maximum(index, 0), uv)
    return where(index >= 0, value, constant)


def textured_scalar(tex: Textures, index: Array, uv: tuple[Array, Array],
                    constant: Array) -> Array:
    """:func:`textured` for a scalar parameter: the texture's luminance."""
    return jnp.where(index >= 0, luminance(evaluate(tex, jnp.maximum(index, 0), uv)), constant)
