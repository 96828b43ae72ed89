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

Fixed-radius estimates (:func:`sum_within`) take every photon of the grid cells x's ball overlaps;
k-nearest ones read at most ``cap`` photons per cell (:func:`jgi.transport.hash_grid.cells_around`),
by default as many as the fullest cell holds, and refuse (:class:`TruncatedGather`) rather
than drop any. Photons are selected in a disc (|x - x_p| < r), or a flattened
disc that also rejects photons further than ``thickness * r`` from the tangent plane (the
lecture's non-symmetric selection, better at edges), and only if their surface normal agrees
with x's. The estimate is a differentiable function of r and the filter parameters. Vertex
merging (:mod:`jgi.estimators.vcm`) weights its merges with the same filters.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..core.calls import ordered_calls
from ..core.compaction import padded_size
from ..core.errors import ParameterError
from ..core.vec import V3, dot, where
from ..physics import bsdf, medium_interfaces, phase
from ..scene.tables import PLASTIC, Scene
from .hash_grid import (
    CellIndex,
    HashGrid,
    accumulate_near_pairs,
    auto_cap,
    cells_around,
    index_cells,
    query_chunk,
)
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


class TruncatedGather(ParameterError):
    """A k-nearest gather would have read fewer photons of a grid cell than it holds."""


def refuse_truncated(grid: HashGrid, cap: int, r) -> None:
    most = int(np.asarray(grid.count).max()) if grid.count.size else 0
    raise TruncatedGather(
        f"photon gather: a grid cell holds {most} photons, more than the {cap} read per cell, "
        f"so the k-nearest estimate would miss photons; use a smaller radius than {r:g}, fewer "
        f"photons, or a cap of at least {most}")


def estimate_at_points(scene, grid, x, n, wo, m, r, *, cap, k, kind, thickness, filter_params,
                       uv=None, ns=None):
    """:func:`radiance_estimate` at any number of points (host arrays in, numpy [3, N] out;
    ``uv`` their surface coordinates in a scene with textures, ``ns`` their shading normals in
    a scene with vertex normals), in padded chunks of one compiled size. Exact: the cap per
    cell defaults to the fullest cell (:func:`~jgi.transport.hash_grid.auto_cap`), and a gather
    that would still drop photons raises :class:`TruncatedGather`."""
    out = []
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
        if np.any(np.asarray(t)[: chunk - pad]):
            refuse_truncated(grid, cap, r)
    return np.concatenate(out, axis=1)


# --- fixed-radius estimates over every photon within r: the device grid, no cap ------------------

PAIR_BLOCK = 1 << 14     # (point, photon) candidate pairs tested per block
NEAR_BLOCK = 1 << 12     # pairs within r evaluated per batch
QUERY_CHUNK = 1 << 16    # points per jitted call (its pair lists are 9 ranges a point)


class PhotonRows(NamedTuple):
    """A photon map on the device grid (:func:`jgi.transport.hash_grid.index_cells`), its
    records in grid order as rows, so a candidate is one contiguous read: ``where`` [M, 6]
    (position, normal: the cheap test's columns) and ``rows`` [M, 12] (position, normal,
    incident direction, power)."""
    cells: CellIndex
    where: Array
    rows: Array


@partial(jax.jit, static_argnames=("table_size",))
def photon_rows(position: V3, normal: V3, wi: V3, power: V3, valid: Array, radius,
                table_size: int) -> PhotonRows:
    # one program (jit: the gathers fuse, where eager ops were a dispatch each: ~15 ms a pass)
    cells = index_cells(position, valid, radius, table_size)
    o = cells.order
    rows = jnp.stack([c[o] for c in (*position, *normal, *wi, *power)], -1)
    return PhotonRows(cells, rows[:, :6], rows)


def _facing_within(q: Array, y: Array, *, x: V3, n: V3, r2: Array, thickness) -> Array:
    """The cheap test's per-point part: the photon within the point's own radius, stored on a
    surface facing the point's normal (and within ``thickness`` of its tangent plane)."""
    diff = V3(y[:, 0], y[:, 1], y[:, 2]) - V3(*(c[q] for c in x))
    nq = V3(*(c[q] for c in n))
    ok = (dot(diff, diff) < r2[q]) & (dot(V3(y[:, 3], y[:, 4], y[:, 5]), nq) > 0.0)
    return ok if thickness is None else ok & (jnp.abs(dot(diff, nq)) <= thickness)


def _add_photons(acc: Array, q: Array, slot: Array, ok: Array, *, scene: Scene, rows: Array,
                 x: V3, n: V3, wo: V3, material: Array, r2: Array, uv, ns, kind: str,
                 filter_params: dict) -> Array:
    """Pair visitor: sum_p f_r W DeltaPhi_p and the photon count, added to acc [N, 4]."""
    y = rows[slot]
    col = lambda k: V3(y[:, k, None], y[:, k + 1, None], y[:, k + 2, None])   # noqa: E731
    at = lambda v: V3(*(c[q] for c in v))                                      # noqa: E731
    diff = V3(y[:, 0], y[:, 1], y[:, 2]) - at(x)
    d2 = dot(diff, diff)
    w, _ = filter_weight(kind, d2, r2[q], **filter_params)
    f = photon_reflectance(scene, material[q], at(n), at(wo), col(6),
                           None if uv is None else tuple(c[q] for c in uv),
                           None if ns is None else at(ns), col(3))
    terms = [jnp.where(ok, f_c[:, 0] * y[:, 9 + c] * w, 0.0) for c, f_c in enumerate(f)]
    return acc.at[q].add(jnp.stack([ok.astype(acc.dtype), *terms], -1))


@partial(jax.jit, static_argnames=("table_size", "kind", "thickness"))
def _sum_within(scene: Scene, photons: PhotonRows, table_size: int, x: V3, n: V3, wo: V3,
                material: Array, r2: Array, live: Array, kind: str, filter_params: dict,
                uv=None, ns=None, thickness=None):
    visit = partial(_add_photons, scene=scene, rows=photons.rows, x=x, n=n, wo=wo,
                    material=material, r2=r2, uv=uv, ns=ns, kind=kind,
                    filter_params=filter_params)
    acc = accumulate_near_pairs(photons.cells, table_size, photons.where, x, live, r2, visit,
                                jnp.zeros((live.shape[0], 4), jnp.float32), block=PAIR_BLOCK,
                                near_block=NEAR_BLOCK,
                                keep=partial(_facing_within, x=x, n=n, r2=r2, thickness=thickness))
    return V3(acc[:, 1], acc[:, 2], acc[:, 3]), acc[:, 0]


# --- volume photons: the 3-D radiance estimate (Jensen and Christensen 1998) -------------------

VOLUME_FILTERS = {"box": 1.0, "epanechnikov": 0.4}   # K / (4/3 pi r^3) in three dimensions


def volume_filter_weight(kind: str, d2, r2):
    """(W(d), K / (4/3 pi r^3)) of a 3-D filter: box (W = 1) or Epanechnikov (W = 1 - d^2/r^2,
    K = 8 pi r^3 / 15); the others' 2-D constants do not carry over, and are refused."""
    if kind == "box":
        return jnp.ones_like(d2), 1.0
    if kind == "epanechnikov":
        return 1.0 - d2 / r2, VOLUME_FILTERS[kind]
    raise ParameterError(f"filter '{kind}' has no volume (3-D) form in jgi; volume photon "
                         f"estimates allow: {', '.join(VOLUME_FILTERS)}")


def _volume_within(q: Array, y: Array, *, x: V3, r2: Array) -> Array:
    """The cheap test's per-point part for volume lookups: a volume photon (zero normal) within
    the point's own radius (the grid's test is the largest radius of all)."""
    diff = V3(y[:, 0], y[:, 1], y[:, 2]) - V3(*(c[q] for c in x))
    return (dot(diff, diff) < r2[q]) & (y[:, 3] == 0) & (y[:, 4] == 0) & (y[:, 5] == 0)


def _add_volume_photons(acc: Array, q: Array, slot: Array, ok: Array, *, rows: Array, x: V3,
                        wo: V3, r2: Array, g, kind: str) -> Array:
    """Pair visitor: sum_p p(-w_p, wo) W DeltaPhi_p and the count, added to acc [N, 4]; the
    photon's propagation direction is -w_p, the light's towards the viewer wo."""
    y = rows[slot]
    at = lambda v: V3(*(c[q] for c in v))                                      # noqa: E731
    diff = V3(y[:, 0], y[:, 1], y[:, 2]) - at(x)
    w, _ = volume_filter_weight(kind, dot(diff, diff), r2[q])
    g = g if jnp.ndim(g) == 0 else g[q]   # per point: its medium's (bounded media)
    p = phase.evaluate(g, -V3(y[:, 6], y[:, 7], y[:, 8]), at(wo))
    terms = [jnp.where(ok, p * y[:, 9 + c] * w, 0.0) for c in range(3)]
    return acc.at[q].add(jnp.stack([ok.astype(acc.dtype), *terms], -1))


@partial(jax.jit, static_argnames=("table_size", "kind"))
def _volume_sum_within(photons: PhotonRows, table_size: int, x: V3, wo: V3, r2: Array,
                       live: Array, g, kind: str):
    visit = partial(_add_volume_photons, rows=photons.rows, x=x, wo=wo, r2=r2, g=g, kind=kind)
    acc = accumulate_near_pairs(photons.cells, table_size, photons.where, x, live, r2, visit,
                                jnp.zeros((live.shape[0], 4), jnp.float32), block=PAIR_BLOCK,
                                near_block=NEAR_BLOCK, keep=partial(_volume_within, x=x, r2=r2))
    return V3(acc[:, 1], acc[:, 2], acc[:, 3]), acc[:, 0]


def volume_sum_within(scene: Scene, pm, x: V3, wo: V3, r2, *, live=None, kind: str = "box",
                      medium=None):
    """(sum_p p(-w_p, wo) W(d_p) DeltaPhi_p, count) over every *volume* photon of ``pm`` within
    each point's radius (r2 per point), numpy [3, N] and [N]: the in-scattered radiance
    int p(w, wo) L_i(x, w) dw is the sum divided by K = (the filter's constant) 4/3 pi r^3
    (:func:`volume_filter_weight`), the volume photons' power being the flux times T / p
    (:mod:`jgi.transport.photons`). x's throughput carries sigma_s already (its free-flight
    weight). Exact as :func:`sum_within`: every pair of the cells a point's ball overlaps is read.

    ``medium`` (scenes with media bounded by shapes): each point's medium id, whose phase
    function weighs the photons. Photons are not told apart by medium: near a boundary the
    estimate mixes the two sides' photons, a bias of the kernel's width like a surface's
    boundary bias, which shrinks with the radius. That is the smaller bias: a volume photon's
    power carries T / p, so the photons of either medium estimate the radiance where they lie,
    whatever its extinction, and the mix is the radiance averaged over the ball; counting only
    the point's own medium would leave the ball's part beyond the boundary empty, a deficit
    even where the radiance is continuous across it. (Measured on ``milk_ball``, pm at radius
    0.2, 8 seeds against the path tracer: the image mean -0.07% mixed, -0.47% with the other
    medium's photons left out, and 15 against 23 of 1,728 pixel channels beyond |t| 4.)"""
    volume_filter_weight(kind, 0.0, 1.0)     # refuses filters without a 3-D form
    vol = pm.select(np.asarray(pm.volume))
    N = x.x.shape[0]
    if vol.count == 0:
        return np.zeros((3, N), np.float32), np.zeros(N, np.float32)
    r2 = np.asarray(r2, np.float32)
    live = np.ones(N, bool) if live is None else np.asarray(live, bool)
    photons, table_size = _device_rows(vol, float(np.sqrt(max(float(r2[live].max(initial=0.0)),
                                                              1e-12))))
    if scene.has_bounded_media:
        g = medium_interfaces.parameters(scene, jnp.asarray(medium, jnp.int32)).g
        return _by_chunks(N, live, lambda take, alive: _volume_sum_within(
            photons, table_size, take(x), take(wo), take(r2), alive, take(g), kind))
    g = jnp.float32(medium_interfaces.own_medium(scene).g)
    return _by_chunks(N, live, lambda take, alive: _volume_sum_within(
        photons, table_size, take(x), take(wo), take(r2), alive, g, kind))


# --- the beam radiance estimate (Jarosz, Zwicker and Jensen 2008) --------------------------------

def _beam_within(q: Array, y: Array, *, o: V3, d: V3, t_lo: Array, t_hi: Array, r2) -> Array:
    """A volume photon within r of the query's piece of ray [t_lo, t_hi) (perpendicular
    distance < r, projection inside the piece: each photon near a segment counts once, in the
    piece its projection falls into)."""
    rel = V3(y[:, 0], y[:, 1], y[:, 2]) - V3(*(c[q] for c in o))
    t = dot(rel, V3(*(c[q] for c in d)))
    perp2 = dot(rel, rel) - t * t
    return ((perp2 < r2) & (t >= t_lo[q]) & (t < t_hi[q])
            & (y[:, 3] == 0) & (y[:, 4] == 0) & (y[:, 5] == 0))


def _add_beam_photons(acc: Array, q: Array, slot: Array, ok: Array, *, rows: Array, o: V3, d: V3,
                      sigma_t: V3, g) -> Array:
    """Pair visitor: sum_p T(t_p) p(-w_p, -d) DeltaPhi_p and the count, added to acc [N, 4]."""
    y = rows[slot]
    dq = V3(*(c[q] for c in d))
    t = dot(V3(y[:, 0], y[:, 1], y[:, 2]) - V3(*(c[q] for c in o)), dq)
    p = phase.evaluate(g, -V3(y[:, 6], y[:, 7], y[:, 8]), -dq)
    tr = [jnp.exp(-s * jnp.maximum(t, 0.0)) for s in sigma_t]
    terms = [jnp.where(ok, tr[c] * p * y[:, 9 + c], 0.0) for c in range(3)]
    return acc.at[q].add(jnp.stack([ok.astype(acc.dtype), *terms], -1))


@partial(jax.jit, static_argnames=("table_size",))
def _beam_sum(photons: PhotonRows, table_size: int, x: V3, o: V3, d: V3, t_lo: Array,
              t_hi: Array, r2, live: Array, sigma_t: V3, g):
    visit = partial(_add_beam_photons, rows=photons.rows, o=o, d=d, sigma_t=sigma_t, g=g)
    acc = accumulate_near_pairs(photons.cells, table_size, photons.where, x, live, 1.25 * r2,
                                visit, jnp.zeros((live.shape[0], 4), jnp.float32),
                                block=PAIR_BLOCK, near_block=NEAR_BLOCK,
                                keep=partial(_beam_within, o=o, d=d, t_lo=t_lo, t_hi=t_hi,
                                             r2=r2))
    return V3(acc[:, 1], acc[:, 2], acc[:, 3]), acc[:, 0]


def beam_sum(scene: Scene, pm, segments, r: float) -> np.ndarray:
    """The beam radiance estimate of the volume photons of ``pm`` along camera segments
    (Jarosz et al. 2008), numpy [3, N]: for each segment (origin o, unit direction d, length
    s, throughput beta; [D, N] as :func:`jgi.transport.visible_points.trace_to_diffuse`
    returns them) and every volume photon within perpendicular distance r of it,

        L_m = beta sigma_s sum_p T(t_p) p(-w_p, -d) DeltaPhi_p / (pi r^2),

    t_p the photon's projection on the segment (0 <= t_p < s): the in-scattered radiance
    integrated along the segment with a 2-D (box) kernel across it, where the point estimate
    samples one distance. Summed over each path's D segments.

    From the same grid as the point estimate: each segment, clipped to the volume photons'
    bounding box grown by r, is cut into pieces of length r whose midpoints are grid queries
    of radius sqrt(5/4) r (holding every photon within r of the piece); a photon counts in the
    piece its projection falls into, so once."""
    so, sd, st, sb = (jax.tree_util.tree_map(np.asarray, a) for a in segments)
    D, N = np.shape(st)
    out = np.zeros((3, N), np.float64)
    vol = pm.select(np.asarray(pm.volume))
    if vol.count == 0:
        return out.astype(np.float32)
    pos = np.stack([np.asarray(c) for c in vol.position], -1)
    lo, hi = pos.min(0) - r, pos.max(0) + r
    o = np.stack([c.reshape(-1) for c in so], -1).astype(np.float64)
    d = np.stack([c.reshape(-1) for c in sd], -1).astype(np.float64)
    s = st.reshape(-1).astype(np.float64)
    # clip each segment to the photons' box (slabs): no photon lies outside it
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(d) > 1e-20, d, 1e-20)
        ta, tb = (lo - o) * inv, (hi - o) * inv
    t0 = np.maximum(np.max(np.minimum(ta, tb), 1), 0.0)
    t1 = np.minimum(np.min(np.maximum(ta, tb), 1), s)
    pieces = np.where((s > 0) & (t1 > t0), np.ceil((t1 - t0) / r), 0).astype(np.int64)
    seg = np.repeat(np.arange(len(s)), pieces)
    if len(seg) == 0:
        return out.astype(np.float32)
    k = np.arange(len(seg)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    t_lo = t0[seg] + k * r
    t_hi = np.minimum(t_lo + r, t1[seg])
    mid = o[seg] + d[seg] * (0.5 * (t_lo + t_hi))[:, None]
    photons, table_size = _device_rows(vol, float(np.sqrt(1.25) * r))
    medium = scene.medium
    sigma_t = V3(*(jnp.float32(c) for c in medium.sigma_t))
    g = jnp.float32(medium.g)
    cols = lambda m: V3(*(m[:, c].astype(np.float32) for c in range(3)))   # noqa: E731
    acc, _ = _by_chunks(len(seg), np.ones(len(seg), bool), lambda take, alive: _beam_sum(
        photons, table_size, take(cols(mid)), take(cols(o[seg])), take(cols(d[seg])),
        take(t_lo.astype(np.float32)), take(t_hi.astype(np.float32)), jnp.float32(r * r), alive,
        sigma_t, g))
    per_segment = np.zeros((3, len(s)), np.float64)
    for c in range(3):
        np.add.at(per_segment[c], seg, acc[c])
    sigma_s = np.array([float(a) * float(b) for a, b in zip(medium.albedo, medium.sigma_t)])
    beta = np.stack([c.reshape(-1) for c in sb]).astype(np.float64)
    per_segment = per_segment * beta * sigma_s[:, None] / (np.pi * r * r)
    return per_segment.reshape(3, D, N).sum(1).astype(np.float32)


def _device_rows(pm, radius: float):
    """The photon map ``pm`` (host arrays) padded to a compiled size and sorted into the device
    grid for queries of radius up to ``radius``: (PhotonRows, table size)."""
    M = pm.count
    size = padded_size(M)
    pad = lambda a: jnp.asarray(np.pad(np.asarray(a, np.float32), (0, size - M)))  # noqa: E731
    padv = lambda v: V3(*(pad(c) for c in v))                                      # noqa: E731
    valid = jnp.asarray(np.arange(size) < M)
    table_size = int(1 << max(10, int(np.ceil(np.log2(2 * size)))))
    return photon_rows(padv(pm.position), padv(pm.normal), padv(pm.wi), padv(pm.power), valid,
                       jnp.float32(radius), table_size), table_size


def sum_within(scene: Scene, pm, x: V3, n: V3, wo: V3, material, r2, *, live=None,
               kind: str = "box", filter_params: dict | None = None, uv=None, ns=None,
               thickness: float | None = None):
    """(sum_p f_r(x, w_p, w) W(d_p) DeltaPhi_p, count) over *every* photon of the map ``pm`` (a
    :class:`~jgi.transport.photons.PhotonMap`, host arrays) within each point's own radius
    (r2 = r^2 per point) on a surface facing its normal (and within ``thickness`` of its
    tangent plane, if given): numpy [3, N] and [N]. The estimate is the sum divided by
    K = (the filter's constant) pi r^2 (:func:`filter_weight`).

    Exact, with no cap: the photons are sorted into cells of the largest radius on the device
    and every (point, photon) pair of the cells a point's ball overlaps is read
    (:func:`jgi.transport.hash_grid.accumulate_near_pairs`, as vertex merging does), so a
    crowded cell costs its own photons and none is dropped."""
    N = x.x.shape[0]
    r2 = np.asarray(r2, np.float32)
    live = np.ones(N, bool) if live is None else np.asarray(live, bool)
    radius = float(np.sqrt(max(float(r2[live].max(initial=0.0)), 1e-12)))
    photons, table_size = _device_rows(pm, radius)
    return _by_chunks(N, live, lambda take, alive: _sum_within(
        scene, photons, table_size, take(x), take(n), take(wo), take(material), take(r2), alive,
        kind, filter_params or {}, take(uv), take(ns),
        None if thickness is None else float(thickness)))


def _by_chunks(n: int, live, query):
    """``query(take, alive)`` over chunks of QUERY_CHUNK points padded to one compiled size:
    ``take(a)`` is the chunk of a (an array, V3 or tuple of [n] arrays; None stays None), padded
    with its last point; ``alive`` marks the chunk's points to estimate (``live``), padding
    excluded. Returns the query's sums [3, n] and counts [n] as numpy. The chunks run as
    concurrent calls (:func:`jgi.core.calls.ordered_calls`): a chunk's block loop is a chain of
    small kernels that leaves the other core idle."""
    chunk = min(QUERY_CHUNK, padded_size(n))
    out, count = np.zeros((3, n), np.float32), np.zeros(n, np.float32)
    live = np.asarray(live, bool)
    starts = list(range(0, n, chunk))

    def call(i):
        s = starts[i]
        k = min(s + chunk, n) - s
        pad = lambda a: jnp.asarray(np.pad(np.asarray(a)[s:s + k], (0, chunk - k),  # noqa: E731
                                           mode="edge"))
        take = lambda v: None if v is None else jax.tree_util.tree_map(pad, v)      # noqa: E731
        L, c = query(take, jnp.asarray(np.pad(live[s:s + k], (0, chunk - k))))
        return np.stack([np.asarray(a)[:k] for a in L]), np.asarray(c)[:k]

    for s, (L, c) in zip(starts, ordered_calls(call, len(starts))):
        out[:, s:s + L.shape[1]] = L
        count[s:s + L.shape[1]] = c
    return out, count
