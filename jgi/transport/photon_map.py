"""Photon-map density estimation: a spatial hash grid and radiance estimates with filters.

Grid (SmallVCM's hash grid): photons are sorted by the hash of their integer cell
floor((p - origin) / cell); ``start``/``count`` tables give each hashed cell's range. A query
at x gathers the 3 x 3 x 3 cells around x's cell (so every photon within ``cell`` of x is seen),
at most ``cap`` photons per cell (static, for jit); ``truncated`` reports when a cell held
more, which would bias the estimate.

Radiance estimate (the lecture's): L_r(x, w) ~= sum_p f_r(x, w_p, w) DeltaPhi_p W(d_p) / K,
where W is the filter and K = integral of W over the disc of radius r, so that a constant
photon density is estimated without bias by every filter:

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

Photons are selected in a disc (|x - x_p| < r), or a flattened disc that also rejects photons
further than ``thickness * r`` from the tangent plane (the lecture's non-symmetric selection,
better at edges), and only if their surface normal agrees with x's. The estimate is a
differentiable function of r and the filter parameters.
"""

from __future__ import annotations

import warnings
from functools import lru_cache, partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..core.vec import V3, dot, where
from ..physics import bsdf as B
from ..scene.tables import PLASTIC, Scene
from .subpath import evaluates_whole

_P1, _P2, _P3 = 73856093, 19349663, 83492791  # Teschner et al. 2003
JENSEN_ALPHA, JENSEN_BETA = 0.918, 1.953       # the Gaussian filter's constants (Jensen 2001)


class HashGrid(NamedTuple):
    position: V3       # photons, sorted by hashed cell
    power: V3
    wi: V3
    normal: V3
    start: Array       # [table] first photon of each hashed cell
    count: Array       # [table] photons in it
    origin: V3         # scalar
    cell: Array        # scalar cell size
    table_size: int


def _hash(ix, iy, iz, table_size):
    h = (ix * _P1) ^ (iy * _P2) ^ (iz * _P3)
    return jnp.mod(h, table_size) if isinstance(h, jax.Array) else np.mod(h, table_size)


def build_grid(pm, cell: float, table_size: int | None = None, cap: int | None = None) -> HashGrid:
    """Sort photons (a :class:`jgi.transport.photons.PhotonMap` of numpy arrays) into a hash grid.

    With ``cap``, the cell is halved until 99% of occupied cells hold at most cap / 2 photons,
    so k-nearest queries (whose search radius is the cell) rarely truncate; ``grid.cell`` is
    the size used."""
    n = len(pm.power.x)
    table_size = table_size or int(1 << max(10, int(np.ceil(np.log2(max(2 * n, 1))))))
    p = np.stack([np.asarray(c, np.float64) for c in pm.position], 1)
    while cap is not None and n:
        ijk = np.floor((p - p.min(0)) / cell).astype(np.int64)
        _, counts = np.unique(ijk, axis=0, return_counts=True)
        if np.quantile(counts, 0.99) <= cap / 2 or cell < 1e-6:
            break
        cell *= 0.5
    origin = p.min(0) - cell if n else np.zeros(3)
    ijk = np.floor((p - origin) / cell).astype(np.int64)
    h = _hash(ijk[:, 0], ijk[:, 1], ijk[:, 2], table_size).astype(np.int64)
    order = np.argsort(h, kind="stable")
    h = h[order]
    count = np.bincount(h, minlength=table_size).astype(np.int32)
    start = (np.cumsum(count) - count).astype(np.int32)
    # pad to a power-of-two length (entries past n are never referenced by the tables), so
    # photon maps of similar size share one compiled query
    size = 1 << max(8, int(np.ceil(np.log2(max(n, 1)))))
    take = lambda v: V3(*(jnp.asarray(np.pad(np.asarray(c, np.float32)[order], (0, size - n)))
                          for c in v))
    return HashGrid(take(pm.position), take(pm.power), take(pm.wi), take(pm.normal),
                    jnp.asarray(start), jnp.asarray(count),
                    V3(*(jnp.asarray(np.float32(c)) for c in origin)),
                    jnp.asarray(np.float32(cell)), table_size)


def auto_cap(grid: HashGrid, limit: int = 1024) -> int:
    """Per-cell gather cap that sees every photon (the fullest cell, rounded up to a power of
    two so that few sizes are compiled), at most ``limit``."""
    most = int(np.asarray(grid.count).max()) if grid.count.size else 1
    return int(min(limit, 1 << max(3, int(np.ceil(np.log2(max(most, 1)))))))


def query_chunk(cap: int, budget: int = 1 << 21) -> int:
    """Queries per jitted call so that the 27 * cap candidates per query fit in ``budget``."""
    return int(max(64, 1 << int(np.floor(np.log2(max(budget // (27 * cap), 1))))))


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
    raise ValueError(f"unknown filter '{kind}'; allowed: box, cone, gaussian, epanechnikov")


class Gathered(NamedTuple):
    d2: Array        # [N, C] squared distances (inf where no photon)
    power: V3        # [N, C]
    wi: V3
    ok: Array        # [N, C] candidate photon accepted by normal / thickness tests
    truncated: Array  # [N] some cell held more than ``cap`` photons
    normal: V3 | None = None  # [N, C] geometric normals of the surfaces photons were stored on


def cells_around(origin: V3, cell, start: Array, count: Array, table_size, x: V3, cap: int):
    """(slot [N, 27 cap], valid [N, 27 cap], truncated [N]): the sorted-order slots of at most
    ``cap`` entries from each of the 27 hashed cells around each query point x, so every entry
    within ``cell`` of x is among them unless a cell held more than cap (``truncated``)."""
    fx, fy, fz = ((x.x - origin.x) / cell, (x.y - origin.y) / cell, (x.z - origin.z) / cell)
    ix, iy, iz = (jnp.floor(f).astype(jnp.int32) for f in (fx, fy, fz))
    offs = jnp.arange(cap, dtype=jnp.int32)
    cols = []
    trunc = jnp.zeros(ix.shape, bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                h = _hash(ix + dx, iy + dy, iz + dz, table_size)
                st, ct = start[h], count[h]
                trunc = trunc | (ct > cap)
                idx = st[..., None] + offs
                valid = offs < ct[..., None]
                cols.append((jnp.where(valid, idx, 0), valid))
    slot = jnp.concatenate([i for i, _ in cols], axis=-1)
    valid = jnp.concatenate([v for _, v in cols], axis=-1)
    return slot, valid, trunc


class CellIndex(NamedTuple):
    """A hash grid built on the device (inside jit), for points that change every iteration
    (vertex merging's light vertices): ``order`` lists the point indices sorted by hashed cell,
    ``start`` / ``count`` give each hashed cell's range in it (invalid points are hashed past
    the table and never referenced). The hash is :func:`neighbour_hash`, not
    :class:`HashGrid`'s: the 27 cells around any cell occupy 27 distinct table entries, so a
    query reads each entry once without comparing its cells' hashes."""
    order: Array      # [M] point indices by hashed cell (the first ``count.sum()`` are valid)
    start: Array      # [table]
    count: Array      # [table]
    origin: V3        # scalar
    cell: Array       # scalar cell size


@lru_cache(maxsize=None)
def _neighbour_strides(table_size: int) -> tuple[int, int]:
    """Strides (a, b) of h = (i + a j + b k) mod T (T a power of two) such that no two cells of
    any 3 x 3 x 3 block share an entry (no nonzero offset in {-2..2}^3 maps to 0 mod T) and,
    among such pairs of Teschner et al.'s and Knuth's odd multipliers, the nearest two cells
    that do share one (a lattice of offsets: the hash is linear) are as far apart as can be."""
    assert table_size & (table_size - 1) == 0 and table_size >= 128, table_size
    r = np.arange(-12, 13)
    d = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3).astype(np.int64)
    d = d[np.any(d != 0, 1)]
    reach = np.abs(d).max(1)
    best, best_reach = None, -1
    for a in (19349663, 83492791, 73856093, 2654435761, 40503, 1640531527):
        for b in (83492791, 73856093, 19349663, 2246822519, 3266489917, 668265263):
            a_, b_ = a % table_size, b % table_size
            hit = (d[:, 0] + a_ * d[:, 1] + b_ * d[:, 2]) % table_size == 0
            nearest = reach[hit].min() if hit.any() else 13
            if nearest > 2 and nearest > best_reach:
                best, best_reach = (a_, b_), nearest
    assert best is not None, f"no neighbour-distinct strides for table size {table_size}"
    return best


def neighbour_hash(ix, iy, iz, table_size: int):
    """(i + a j + b k) mod T with :func:`_neighbour_strides` (int32 arithmetic wraps modulo
    2^32, which T divides, so the result is exact)."""
    a, b = _neighbour_strides(table_size)
    return (ix + iy * np.int32(a) + iz * np.int32(b)) & np.int32(table_size - 1)


def index_cells(p: V3, valid: Array, cell, table_size: int, capacity: int | None = None
                ) -> CellIndex:
    """Sort the points p ([M], where ``valid``) into hashed cells of size ``cell`` (traced).
    ``capacity``: when at most that many points are valid, only they are sorted (a sort of
    ``capacity`` keys, not M; the full sort otherwise, under ``lax.cond``)."""
    M = valid.shape[0]
    big = jnp.float32(3e38)
    lo = V3(*(jnp.min(jnp.where(valid, c, big)) for c in p))
    lo = V3(*(jnp.where(jnp.any(valid), c, 0.0) for c in lo))
    origin = lo - V3.full(cell, cell)
    ijk = [jnp.floor((c - o) / cell).astype(jnp.int32) for c, o in zip(p, origin)]
    h = jnp.where(valid, neighbour_hash(*ijk, table_size), table_size)

    def sort_all():
        return jnp.argsort(h, stable=True).astype(jnp.int32)

    def sort_valid():
        (idx,) = jnp.nonzero(valid, size=capacity, fill_value=M - 1)
        hv = jnp.where(jnp.arange(capacity) < n_valid, h[idx], table_size)
        order = idx[jnp.argsort(hv, stable=True)].astype(jnp.int32)
        return jnp.concatenate([order, jnp.full((M - capacity,), M - 1, jnp.int32)])

    n_valid = jnp.sum(valid)
    if capacity is None or capacity >= M:
        order = sort_all()
    else:
        order = jax.lax.cond(n_valid <= capacity, sort_valid, sort_all)
    count = jax.ops.segment_sum(jnp.ones_like(h), h, num_segments=table_size + 1)[:table_size]
    start = (jnp.cumsum(count) - count).astype(jnp.int32)
    return CellIndex(order, start, count.astype(jnp.int32), origin, jnp.asarray(cell))


_NEIGHBOURS = np.array([(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1)
                        for dz in (-1, 0, 1)], np.int32)                  # [27, 3]


def cell_ranges(cells: CellIndex, table_size: int, x: V3):
    """(start, count) [N, 27]: the ranges (in grid order, ``cells.order``) of the 27 hashed
    cells around each query x, so every point within ``cells.cell`` of x lies in one of them;
    the 27 are distinct table entries (:func:`neighbour_hash`), so no point is read twice."""
    c = cells.cell
    ijk = [jnp.floor((a - o) / c).astype(jnp.int32)[..., None] + _NEIGHBOURS[:, i]
           for i, (a, o) in enumerate(zip(x, cells.origin))]
    h = neighbour_hash(*ijk, table_size)                                 # [N, 27]
    return cells.start[h], cells.count[h]


class Pairs(NamedTuple):
    """The (query, point) candidate pairs of :func:`cell_ranges`: every entry of every query's
    27 cells, queries in order, as flat ranges; :func:`pair_block` reads them in blocks."""
    start: Array      # [N * 27] first slot (grid order) of each (query, cell)
    count: Array      # [N * 27] entries in it
    end: Array        # [N * 27] inclusive prefix sum of count
    total: Array      # scalar: number of pairs


def candidate_pairs(start: Array, count: Array) -> Pairs:
    count = count.reshape(-1)
    end = jnp.cumsum(count)
    return Pairs(start.reshape(-1), count, end, end[-1])


def pair_block(pairs: Pairs, block: int, b) -> tuple[Array, Array, Array]:
    """Pairs b * block .. (b + 1) * block - 1: (query [block], slot [block], valid [block]).
    No query has a cap: a loop over ceil(total / block) blocks reads each pair once, so a dense
    cell costs its own entries and nothing more."""
    k = b * block + jnp.arange(block, dtype=jnp.int32)
    seg = jnp.minimum(jnp.searchsorted(pairs.end, k, side="right", method="scan_unrolled"),
                      pairs.count.shape[0] - 1)
    slot = pairs.start[seg] + (k - (pairs.end[seg] - pairs.count[seg]))
    valid = k < pairs.total
    return seg // _NEIGHBOURS.shape[0], jnp.where(valid, slot, 0), valid


def gather(grid: HashGrid, x: V3, n: V3, cap: int, thickness: float | None = None) -> Gathered:
    """Candidates from the 27 cells around each query point x (normal n)."""
    idx, valid, trunc = cells_around(grid.origin, grid.cell, grid.start, grid.count,
                                     grid.table_size, x, cap)
    g = lambda v: V3(v.x[idx], v.y[idx], v.z[idx])
    pp, pw, pwi, pn = g(grid.position), g(grid.power), g(grid.wi), g(grid.normal)
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
        return B.lookup(scene.materials, m, uv).kd
    kd = scene.materials.diffuse
    return V3(kd.x[m], kd.y[m], kd.z[m])


def photon_reflectance(scene: Scene, material, n: V3, wo: V3, wi: V3, uv=None,
                       ns: V3 | None = None, n_photon: V3 | None = None) -> V3:
    """f_r(x, w_p, w) of the estimate for candidate photons arriving from ``wi`` ([N, C]) at
    points with material rows ``material``, normal n and outgoing direction wo ([N]): k_d / pi
    on diffuse and Phong surfaces (the diffuse part alone), the whole BSDF on microfacet
    surfaces, the base (``evaluate``'s non-Dirac part) on smooth plastic
    (:func:`jgi.transport.subpath.is_lookup_surface`). [N, 1] columns when the scene has no
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
        above = B.lit(dot(wi, col(ns))) & B.lit(dot(wo, ns))[:, None]
        n_p = col(n) if n_photon is None else n_photon
        ratio = jnp.where(above, B.shading_ratio(col(ns), n_p, wi), 0.0)
        f = V3(*(c * ratio for c in f))
    if not evaluates_whole(mats.kinds):
        return f
    mp = B.lookup(mats, jnp.broadcast_to(material[:, None], wi.x.shape),
                  None if uv is None else tuple(c[:, None] for c in uv))
    nb = n if ns is None else ns
    f_rough, _ = B.evaluate(mats.kinds, mp, col(nb), col(wo), wi)
    if ns is not None:
        f_rough = f_rough * B.shading_ratio(col(ns), col(n) if n_photon is None else n_photon, wi)
    whole = B.is_rough(mp)
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
