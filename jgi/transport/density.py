"""Photon density estimation: filters and radiance estimates from a photon grid
(:mod:`jgi.transport.hash_grid`).

Radiance estimate (the lecture's): L_r(x, w) ~= sum_p f_r(x, w_p, w) DeltaPhi_p W(d_p) / K,
where W is the filter and K = integral of W over the disc of radius r, so that a constant
photon density is estimated without bias by every filter (:data:`FILTERS`):

  box           W = 1                                   K = pi r^2
  cone          W = 1 - d / (k r)                       K = (1 - 2 / (3k)) pi r^2   (lecture)
  gaussian      W = alpha [1 - (1 - e^{-beta d^2/(2r^2)}) / (1 - e^{-beta})]
                K = alpha pi r^2 [1 - (1 - (2/beta)(1 - e^{-beta/2})) / (1 - e^{-beta})]
                (the lecture prints the sum without dividing by K: with Jensen's alpha = 0.918,
                beta = 1.953 that constant makes the estimate unbiased only for r chosen so
                that K = 1; jgi divides by the exact K). Jensen's alpha and beta are the
                keyword arguments ``gauss_alpha``, ``gauss_beta`` (beta is path throughput
                elsewhere in jgi)
  epanechnikov  W = 1 - d^2 / r^2                       K = pi r^2 / 2

Candidates are read from the 27 grid cells around x, at most ``cap`` photons per cell
(:func:`jgi.transport.hash_grid.cells_around`; ``truncated`` reports when a cell held more,
which would bias the estimate). Photons are selected in a disc (|x - x_p| < r), or a flattened
disc that also rejects photons further than ``thickness * r`` from the tangent plane (the
lecture's non-symmetric selection, better at edges), and only if their surface normal agrees
with x's. The estimate is a differentiable function of r and the filter parameters. Vertex
merging (:mod:`jgi.estimators.vcm`) weights its merges with the same filters.
"""

from __future__ import annotations

import warnings
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..core.vec import V3, dot, where
from ..physics import bsdf
from ..scene.tables import PLASTIC, Scene
from .hash_grid import HashGrid, auto_cap, cells_around, query_chunk
from .visible_points import evaluates_whole

FILTERS = ("box", "cone", "gaussian", "epanechnikov")
JENSEN_ALPHA, JENSEN_BETA = 0.918, 1.953       # the Gaussian filter's constants (Jensen 2001)


def gaussian_normaliser(gauss_alpha, gauss_beta):
    """K / (pi r^2) for the Gaussian filter (see the module docstring)."""
    alpha, beta = gauss_alpha, gauss_beta
    return alpha * (1.0 - (1.0 - (2.0 / beta) * (1.0 - jnp.exp(-beta / 2.0)))
                          / (1.0 - jnp.exp(-beta)))


def filter_weight(kind: str, d2, r2, k=1.1, gauss_alpha=JENSEN_ALPHA,
                  gauss_beta=JENSEN_BETA):
    """(W(d), K / (pi r^2)) for a filter; d2, r2 squared distance and radius; ``k`` the cone's,
    ``gauss_alpha``, ``gauss_beta`` the Gaussian's constants."""
    alpha, beta = gauss_alpha, gauss_beta
    if kind == "box":
        return jnp.ones_like(d2), 1.0
    if kind == "cone":
        d = jnp.sqrt(jnp.maximum(d2, 0.0))
        return 1.0 - d / (k * jnp.sqrt(r2)), 1.0 - 2.0 / (3.0 * k)
    if kind == "gaussian":
        w = alpha * (1.0 - (1.0 - jnp.exp(-beta * d2 / (2.0 * r2))) / (1.0 - jnp.exp(-beta)))
        return w, gaussian_normaliser(alpha, beta)
    if kind == "epanechnikov":
        return 1.0 - d2 / r2, 0.5
    raise ValueError(f"unknown filter '{kind}'; allowed: {', '.join(FILTERS)}")


class Gathered(NamedTuple):
    d2: Array        # [N, C] squared distances (inf where no photon)
    power: V3        # [N, C]
    wi: V3
    ok: Array        # [N, C] candidate photon accepted by normal / thickness tests
    truncated: Array  # [N] some cell held more than ``cap`` photons
    normal: V3 | None = None  # [N, C] geometric normals of the surfaces photons were stored on


def gather(grid: HashGrid, x: V3, n: V3, cap: int, thickness: float | None = None) -> Gathered:
    """Candidate photons of a grid of a :class:`jgi.transport.photons.PhotonMap` for surface
    points x (normal n): those of the 27 cells around x stored on a surface facing n's way."""
    idx, valid, trunc = cells_around(grid, x, cap)
    ph = grid.points
    g = lambda v: V3(v.x[idx], v.y[idx], v.z[idx])
    pp, pw, pwi, pn = g(ph.position), g(ph.power), g(ph.wi), g(ph.normal)
    ex = lambda v: V3(v.x[:, None], v.y[:, None], v.z[:, None])
    diff = pp - ex(x)
    d2 = dot(diff, diff)
    ok = valid & (dot(pn, ex(n)) > 0.0)
    # a photon in a neighbouring hashed cell can belong to a far-away colliding cell: the
    # distance test below removes it
    if thickness is not None:
        ok = ok & (jnp.abs(dot(diff, ex(n))) <= thickness)
    d2 = jnp.where(ok, d2, jnp.inf)
    return Gathered(d2, pw, pwi, ok, trunc, pn)


def estimate(gathered: Gathered, r2, brdf_weight, kind: str = "box", **filter_params):
    """sum_p f_r W(d_p) DeltaPhi_p / K over photons within r (r2 = r^2, [N] or scalar);
    ``brdf_weight`` is f_r per candidate ([N, C] array or a V3 of them), 1/pi for diffuse."""
    inside = gathered.d2 < r2[..., None] if jnp.ndim(r2) else gathered.d2 < r2
    r2b = r2[..., None] if jnp.ndim(r2) else r2
    w, norm = filter_weight(kind, jnp.where(inside, gathered.d2, 0.0), r2b, **filter_params)
    w = jnp.where(inside, w, 0.0)
    K = norm * jnp.pi * r2
    fw = brdf_weight if isinstance(brdf_weight, V3) else V3(brdf_weight, brdf_weight, brdf_weight)
    s = V3(*(jnp.sum(f * p * w, axis=-1) for f, p in zip(fw, gathered.power)))
    return V3(*(c / K for c in s)), jnp.sum(inside, axis=-1)


def knn_radius2(gathered: Gathered, k: int, r_max):
    """Squared distance to the k-th nearest accepted candidate (r = distance to the k-th photon,
    as in the lecture), capped at r_max^2 when fewer than k photons lie within the search."""
    neg, _ = jax.lax.top_k(-gathered.d2, k)
    dk = -neg[..., k - 1]
    return jnp.minimum(dk, r_max * r_max) * (1.0 + 1e-6)


# --- radiance estimates at surface points --------------------------------------------------------

def diffuse_reflectance(scene: Scene, m, uv=None) -> V3:
    """k_d of material rows m (at surface coordinates uv, in a scene with textures): the
    diffuse part of the BSDF that photon estimates use."""
    if scene.materials.has_textures:
        return bsdf.lookup(scene.materials, m, uv).kd
    kd = scene.materials.diffuse
    return V3(kd.x[m], kd.y[m], kd.z[m])


def photon_reflectance(scene: Scene, material, n: V3, wo: V3, wi: V3, uv=None,
                       ns: V3 | None = None, n_photon: V3 | None = None) -> V3:
    """f_r(x, w_p, w) of the estimate for candidate photons arriving from ``wi`` ([N, C]) at
    points with material rows ``material``, normal n and outgoing direction wo ([N]): k_d / pi
    on diffuse and Phong surfaces (the diffuse part alone), the whole BSDF on microfacet
    surfaces, the base (``evaluate``'s non-Dirac part) on smooth plastic
    (:func:`jgi.transport.visible_points.is_lookup_surface`). [N, 1] columns when the scene has no
    microfacet or plastic material and no shading normals.

    With shading normals ``ns`` (facing wo, as n does) the BSDF is evaluated about ns and
    multiplied by |wi . ns| / |wi . n_p| (:func:`jgi.physics.bsdf.shading_ratio`), n_p the
    geometric normal each photon was stored on (``n_photon``, [N, C]; the point's n if not
    given): a photon's power is flux through that surface, L |wi . n_p| dw per area, and the
    path tracer integrates radiance against the shading cosine. (With the point's own n the
    photons of a neighbouring facet that arrive grazing this one would be divided by a
    vanishing cosine: on a 6 x 4 sphere the estimate was up to twice the path tracer's.)"""
    kd = diffuse_reflectance(scene, material, uv)
    f = V3(*(c[:, None] / jnp.pi for c in kd))
    mats = scene.materials
    col = lambda v: V3(*(c[:, None] for c in v))  # noqa: E731
    if ns is not None:
        # the diffuse part about ns: both directions on its side (ns faces wo)
        above = bsdf.lit(dot(wi, col(ns))) & bsdf.lit(dot(wo, ns))[:, None]
        n_p = col(n) if n_photon is None else n_photon
        ratio = jnp.where(above, bsdf.shading_ratio(col(ns), n_p, wi), 0.0)
        f = V3(*(c * ratio for c in f))
    if not evaluates_whole(mats.kinds):
        return f
    mp = bsdf.lookup(mats, jnp.broadcast_to(material[:, None], wi.x.shape),
                     None if uv is None else tuple(c[:, None] for c in uv))
    nb = n if ns is None else ns
    f_rough, _ = bsdf.evaluate(mats.kinds, mp, col(nb), col(wo), wi)
    if ns is not None:
        n_p = col(n) if n_photon is None else n_photon
        f_rough = f_rough * bsdf.shading_ratio(col(ns), n_p, wi)
    whole = bsdf.is_rough(mp)
    if mp.layer is not None:
        whole = whole | bsdf.is_layered(mp)
    if PLASTIC in mats.kinds:
        whole = whole | (mp.kind == PLASTIC)
    return where(whole, f_rough, V3(*(jnp.broadcast_to(c, wi.x.shape) for c in f)))


@partial(jax.jit, static_argnames=("cap", "k", "kind", "thickness"))
def radiance_estimate(scene: Scene, grid: HashGrid, x: V3, n: V3, wo: V3, material, r, cap: int,
                      k: int, kind: str, thickness, filter_params, uv=None, ns=None):
    """L_r at points x (outgoing direction wo) from a photon grid: radius r, or (k > 0) the k
    nearest within r."""
    g = gather(grid, x, n, cap, thickness)
    r2 = knn_radius2(g, k, r) if k > 0 else jnp.broadcast_to(r * r, x.x.shape)
    f = photon_reflectance(scene, material, n, wo, g.wi, uv, ns, g.normal)
    L, count = estimate(g, r2, f, kind, **filter_params)
    return L, count, g.truncated


def warn_truncated(trunc, cap, r):
    if trunc:
        warnings.warn(f"photon grid cells held more than cap={cap} photons: the estimate is biased "
                      f"low; use a smaller radius than {r} or a larger cap", RuntimeWarning,
                      stacklevel=3)


def estimate_at_points(scene, grid, x, n, wo, m, r, *, cap, k, kind, thickness, filter_params,
                       uv=None, ns=None):
    """:func:`radiance_estimate` at any number of points (host arrays in, numpy [3, N] out;
    ``uv`` their surface coordinates in a scene with textures, ``ns`` their shading normals in
    a scene with vertex normals), in padded chunks of one compiled size; warns if grid cells
    were truncated."""
    out, trunc = [], False
    N = x.x.shape[0]
    cap = cap or auto_cap(grid)
    chunk = query_chunk(cap)
    for s in range(0, N, chunk):
        sl = slice(s, s + chunk)
        xs, nxs, wos = (V3(*(c[sl] for c in v)) for v in (x, n, wo))
        pad = chunk - xs.x.shape[0]
        padv = lambda v: V3(*(jnp.pad(c, (0, pad), mode="edge") for c in v))
        L, _, t = radiance_estimate(scene, grid, padv(xs), padv(nxs), padv(wos),
                                    jnp.pad(m[sl], (0, pad), mode="edge"),
                                    jnp.float32(r), cap, k, kind, thickness, filter_params,
                                    None if uv is None else
                                    tuple(jnp.pad(c[sl], (0, pad), mode="edge") for c in uv),
                                    None if ns is None else padv(V3(*(c[sl] for c in ns))))
        out.append(np.stack([np.asarray(c)[: chunk - pad] for c in L]))
        trunc |= bool(np.any(np.asarray(t)[: chunk - pad]))
    warn_truncated(trunc, cap, r)
    return np.concatenate(out, axis=1), trunc
