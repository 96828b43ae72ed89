"""Spatial hash grids over points in 3-D, and their queries (SmallVCM's hash grid).

Points are sorted by the hash of their integer cell floor((p - origin) / cell); ``start`` /
``count`` tables give each hashed cell's range in that order. A query at x reads the 3 x 3 x 3
cells around x's cell (:data:`NEIGHBOURS`, the one enumeration of them), so every point within
``cell`` of x is seen. Nothing here knows about surfaces: the caller tests normals, filters and
weights (:mod:`jgi.transport.density` for photons on surfaces; volumes need only the distance).

Two builders, for two uses:

* :func:`build_grid` (host, numpy): a photon map built once and queried by many points, each
  reading at most ``cap`` points per cell (:func:`cells_around`, static shapes for jit; k-nearest
  estimates take their k from these candidates). Its hash is Teschner et al.'s XOR hash.
* :func:`index_cells` (device, inside jit): points that change every iteration (vertex
  merging's light vertices, the photon maps of fixed-radius estimates), queried without a cap
  by listing every (query, point) pair of the cells the query's ball overlaps and walking them
  in fixed-size blocks (:func:`accumulate_near_pairs`). Its cells are a fraction
  1 / ``CELLS_PER_RADIUS`` of the query radius, and its hash is :func:`neighbour_hash`, linear:
  the cells along x of one (y, z) row are consecutive table entries, so a row of cells is one
  contiguous range of the sorted points (:func:`cell_ranges`), and the cells of any block a
  ball can reach are distinct entries, so a query reads each entry once.

They stay two because photon mapping's images follow its grid's order: an estimate sums its
candidates in the order :func:`build_grid` sorts them and :func:`cells_around` lists them, so
sorting photon maps by :func:`neighbour_hash` (or building them on the device) would change
the k-nearest gathers (pm with ``k``, pm_jensen, the irradiance cache) in the last bits. They
share the cell arithmetic (:func:`cell_of`).
"""

from __future__ import annotations

from functools import lru_cache, partial
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..core.vec import V3, dot

_P1, _P2, _P3 = 73856093, 19349663, 83492791  # Teschner et al. 2003

NEIGHBOURS = np.array([(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1)
                       for dz in (-1, 0, 1)], np.int32)                   # [27, 3]


_EARLIER = np.tril(np.ones((NEIGHBOURS.shape[0],) * 2, bool), -1)   # [i, j]: j before i


def cell_of(origin: V3, cell, x: V3) -> list[Array]:
    """The integer cell (int32 per axis) of points x."""
    return [jnp.floor((a - o) / cell).astype(jnp.int32) for a, o in zip(x, origin)]


def neighbour_cells(origin: V3, cell, x: V3) -> list[Array]:
    """[..., 27] per axis: the cell of each point x and its 26 neighbours, in
    :data:`NEIGHBOURS`' order."""
    return [c[..., None] + NEIGHBOURS[:, i] for i, c in enumerate(cell_of(origin, cell, x))]


# --- the host-built grid: a photon map, read with a cap per cell ----------------------------------

class HashGrid(NamedTuple):
    """Points sorted by hashed cell (:func:`build_grid`): ``points`` is the caller's pytree of
    per-point arrays (a :class:`jgi.transport.photons.PhotonMap`: ``points.position`` and every
    other field), sorted and padded together."""
    points: Any        # the sorted points (a NamedTuple with a ``position`` V3)
    start: Array       # [table] first point of each hashed cell
    count: Array       # [table] points in it
    origin: V3         # scalar
    cell: Array        # scalar cell size
    table_size: int


def teschner_hash(ix, iy, iz, table_size):
    """Teschner et al.'s XOR hash of integer cells (numpy or jax arrays)."""
    h = (ix * _P1) ^ (iy * _P2) ^ (iz * _P3)
    return jnp.mod(h, table_size) if isinstance(h, jax.Array) else np.mod(h, table_size)


def _sorted_padded(a, order, size: int):
    """Host array a in grid order, float as float32, zero-padded to ``size`` entries."""
    a = np.asarray(a)
    a = (a.astype(np.float32) if a.dtype.kind == "f" else a)[order]
    return jnp.asarray(np.pad(a, (0, size - a.shape[0])))


def build_grid(points, cell: float, table_size: int | None = None, cap: int | None = None
               ) -> HashGrid:
    """Sort ``points`` (a NamedTuple of numpy arrays with a ``position`` V3, e.g. a
    :class:`jgi.transport.photons.PhotonMap`) into a hash grid.

    With ``cap``, the cell is halved until 99% of occupied cells hold at most cap / 2 points,
    so k-nearest queries (whose search radius is the cell) rarely truncate; ``grid.cell`` is
    the size used."""
    n = len(points.position.x)
    table_size = table_size or int(1 << max(10, int(np.ceil(np.log2(max(2 * n, 1))))))
    p = np.stack([np.asarray(c, np.float64) for c in points.position], 1)
    while cap is not None and n:
        ijk = np.floor((p - p.min(0)) / cell).astype(np.int64)
        _, counts = np.unique(ijk, axis=0, return_counts=True)
        if np.quantile(counts, 0.99) <= cap / 2 or cell < 1e-6:
            break
        cell *= 0.5
    origin = p.min(0) - cell if n else np.zeros(3)
    ijk = np.floor((p - origin) / cell).astype(np.int64)
    h = teschner_hash(ijk[:, 0], ijk[:, 1], ijk[:, 2], table_size).astype(np.int64)
    order = np.argsort(h, kind="stable")
    h = h[order]
    count = np.bincount(h, minlength=table_size).astype(np.int32)
    start = (np.cumsum(count) - count).astype(np.int32)
    # pad to a power-of-two length (entries past n are never referenced by the tables), so
    # photon maps of similar size share one compiled query
    size = 1 << max(8, int(np.ceil(np.log2(max(n, 1)))))
    sorted_points = jax.tree_util.tree_map(lambda a: _sorted_padded(a, order, size), points)
    return HashGrid(sorted_points, jnp.asarray(start), jnp.asarray(count),
                    V3(*(jnp.asarray(np.float32(c)) for c in origin)),
                    jnp.asarray(np.float32(cell)), table_size)


def auto_cap(grid: HashGrid, limit: int = 1024) -> int:
    """Per-cell gather cap that sees every point (the fullest cell, rounded up to a power of
    two so that few sizes are compiled), at most ``limit``."""
    most = int(np.asarray(grid.count).max()) if grid.count.size else 1
    return int(min(limit, 1 << max(3, int(np.ceil(np.log2(max(most, 1)))))))


def query_chunk(cap: int, budget: int = 1 << 21) -> int:
    """Queries per jitted call so that the 27 * cap candidates per query fit in ``budget``."""
    return int(max(64, 1 << int(np.floor(np.log2(max(budget // (27 * cap), 1))))))


def cells_around(grid: HashGrid, x: V3, cap: int):
    """(slot [N, 27 cap], valid [N, 27 cap], truncated [N]): the sorted-order slots of at most
    ``cap`` points from each of the 27 hashed cells around each query point x ([N]), so every
    point within ``grid.cell`` of x is among them unless a cell held more than cap
    (``truncated``). Two of the 27 cells may share a table entry (the XOR hash): the entry is
    read once, at its first cell (its points would otherwise be counted twice). A far-away cell
    hashed to the same entry lists its points too: callers test the distance."""
    h = teschner_hash(*neighbour_cells(grid.origin, grid.cell, x), grid.table_size)  # [N, 27]
    st, ct = grid.start[h], grid.count[h]
    trunc = jnp.any(ct > cap, axis=-1)
    repeated = jnp.any((h[..., :, None] == h[..., None, :]) & _EARLIER, axis=-1)
    ct = jnp.where(repeated, 0, ct)
    offs = jnp.arange(cap, dtype=jnp.int32)
    valid = offs < ct[..., None]                                                # [N, 27, cap]
    slot = jnp.where(valid, st[..., None] + offs, 0)
    shape = x.x.shape + (NEIGHBOURS.shape[0] * cap,)
    return slot.reshape(shape), valid.reshape(shape), trunc


# --- the device-built grid: points of an iteration, every pair of a ball's cells read in blocks ---

# Cells per query radius of the device grid, and its rows: the (y, z) offsets within a query's
# reach, each read as one range of cells along x (cells of r: a query reads 9 ranges, not 27
# cells; cells of r / 2 measured slower, perf: docs/performance.md#photon-passes).
CELLS_PER_RADIUS = 1
ROWS = np.array([(dj, dk) for dj in range(-CELLS_PER_RADIUS, CELLS_PER_RADIUS + 1)
                 for dk in range(-CELLS_PER_RADIUS, CELLS_PER_RADIUS + 1)], np.int32)  # [R, 2]


class CellIndex(NamedTuple):
    """A hash grid built on the device (inside jit), for points that change every iteration
    (vertex merging's light vertices): ``order`` lists the point indices sorted by hashed cell,
    ``start`` / ``count`` give each hashed cell's range in it (invalid points are hashed past
    the table and never referenced). The hash is :func:`neighbour_hash`, not
    :func:`teschner_hash`: consecutive cells along x are consecutive entries, and the cells of
    any block of (2 CELLS_PER_RADIUS + 1)^3 occupy distinct entries, so a query reads each
    entry once without comparing its cells' hashes."""
    order: Array      # [M] point indices by hashed cell (the first ``n_valid`` are valid)
    # [table + 1]: entry c's points are order[bounds[c]:bounds[c + 1]] (one array, not a start
    # and a count: a row's two ends are then mostly one cache line of it)
    bounds: Array
    origin: V3        # scalar
    cell: Array       # scalar cell size: the query radius / CELLS_PER_RADIUS
    n_valid: Array    # scalar: valid points

    @property
    def count(self) -> Array:   # [table] points an entry holds
        return self.bounds[1:] - self.bounds[:-1]


BLOCK = 2 * CELLS_PER_RADIUS + 1    # cells per axis a query can reach


@lru_cache(maxsize=None)
def _neighbour_strides(table_size: int) -> tuple[int, int]:
    """Strides (a, b) of h = (i + a j + b k) mod T (T a power of two) such that no two cells of
    any BLOCK^3 block share an entry (no nonzero offset in {-(BLOCK-1)..BLOCK-1}^3 maps to 0
    mod T) and, among such pairs of Teschner et al.'s and Knuth's odd multipliers (and the
    dense strides BLOCK, BLOCK^2, which always qualify), the nearest two cells that do share
    one (a lattice of offsets: the hash is linear) are as far apart as can be."""
    assert table_size & (table_size - 1) == 0 and table_size >= BLOCK ** 3, table_size
    r = np.arange(-12, 13)
    d = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3).astype(np.int64)
    d = d[np.any(d != 0, 1)]
    reach = np.abs(d).max(1)
    best, best_reach = None, -1
    for a in (19349663, 83492791, 73856093, 2654435761, 40503, 1640531527, BLOCK):
        for b in (83492791, 73856093, 19349663, 2246822519, 3266489917, 668265263, BLOCK ** 2):
            a_, b_ = a % table_size, b % table_size
            hit = (d[:, 0] + a_ * d[:, 1] + b_ * d[:, 2]) % table_size == 0
            nearest = reach[hit].min() if hit.any() else 13
            if nearest > BLOCK - 1 and nearest > best_reach:
                best, best_reach = (a_, b_), nearest
    assert best is not None, f"no neighbour-distinct strides for table size {table_size}"
    return best


def neighbour_hash(ix, iy, iz, table_size: int):
    """(i + a j + b k) mod T with :func:`_neighbour_strides` (int32 arithmetic wraps modulo
    2^32, which T divides, so the result is exact)."""
    a, b = _neighbour_strides(table_size)
    return (ix + iy * np.int32(a) + iz * np.int32(b)) & np.int32(table_size - 1)


def index_cells(p: V3, valid: Array, radius, table_size: int, capacity: int | None = None
                ) -> CellIndex:
    """Sort the points p ([M], where ``valid``) into hashed cells for queries of radius up to
    ``radius`` (traced; cells of radius / CELLS_PER_RADIUS).
    ``capacity``: when at most that many points are valid, only they are sorted (a sort of
    ``capacity`` keys, not M); else at most twice as many, and so on; the full sort when more
    than M / 2 are valid."""
    cell = jnp.asarray(radius, jnp.float32) / CELLS_PER_RADIUS
    big = jnp.float32(3e38)
    lo = V3(*(jnp.min(jnp.where(valid, c, big)) for c in p))
    lo = V3(*(jnp.where(jnp.any(valid), c, 0.0) for c in lo))
    origin = lo - V3.full(radius, radius)
    h = jnp.where(valid, neighbour_hash(*cell_of(origin, cell, p), table_size), table_size)
    n_valid = jnp.sum(valid)
    order = _sort_tiers(h, valid, n_valid, capacity, table_size)
    count = jax.ops.segment_sum(jnp.ones_like(h), h, num_segments=table_size + 1)[:table_size]
    bounds = jnp.concatenate([jnp.zeros((1,), jnp.int32), jnp.cumsum(count).astype(jnp.int32)])
    return CellIndex(order, bounds, origin, cell, n_valid.astype(jnp.int32))


def stable_order(keys: Array) -> Array:
    """``jnp.argsort(keys, stable=True)`` for non-negative int32 keys, as int32: each key and
    its index packed into one uint64 (key high, index low) and the packed values sorted alone."""
    # perf: docs/performance.md#cell-sort
    with jax.enable_x64(True):
        idx = jnp.arange(keys.shape[0], dtype=jnp.uint64)
        packed = (keys.astype(jnp.uint64) << jnp.uint64(32)) | idx
        return (jnp.sort(packed) & jnp.uint64(0xFFFFFFFF)).astype(jnp.int32)


def _sort_all(h: Array) -> Array:
    return stable_order(h)


def _sort_tiers(h: Array, valid: Array, n_valid, capacity: int | None, table_size: int):
    """:func:`_sort_all`, sorting only the valid points where they fit ``capacity``, or twice
    that, and so on below M (one ``lax.cond`` a tier)."""
    M = valid.shape[0]
    if capacity is None or capacity >= M:
        return _sort_all(h)
    return jax.lax.cond(n_valid <= capacity,
                        partial(_sort_valid, h, valid, n_valid, capacity, table_size),
                        partial(_sort_tiers, h, valid, n_valid, 2 * capacity, table_size))


def _sort_valid(h: Array, valid: Array, n_valid, capacity: int, table_size: int) -> Array:
    """:func:`_sort_all`'s order when at most ``capacity`` points are valid, sorting only them."""
    M = valid.shape[0]
    (idx,) = jnp.nonzero(valid, size=capacity, fill_value=M - 1)
    hv = jnp.where(jnp.arange(capacity) < n_valid, h[idx], table_size)
    order = idx[stable_order(hv)].astype(jnp.int32)
    return jnp.concatenate([order, jnp.full((M - capacity,), M - 1, jnp.int32)])


def cell_ranges(cells: CellIndex, table_size: int, x: V3, r2):
    """(start, count) [N, R]: for each query x ([N]) with radius^2 r2 (scalar or [N], at most
    the grid's radius^2) and each row of :data:`ROWS`, the range of the cells along x that its
    ball overlaps in that row, in grid order (``cells.order``), so every point within r of x
    lies in one of the ranges, and no entry is in two (the rows' cells are distinct entries
    of :func:`neighbour_hash`). A row the ball misses has count 0.

    A row's cells i_lo .. i_hi have the consecutive entries h(i_lo) .. h(i_lo) + i_hi - i_lo,
    so their points are one range of the sorted order, or, where the entries wrap past the
    table's end, the range from h(i_lo) to the last valid point followed by the range from the
    first: ``start`` and ``count`` then run past ``cells.n_valid``, and :func:`pair_block`
    reads slot s as s - n_valid. The culling is widened by a margin of rounding, so no point
    within r is lost to it; the distance test decides."""
    o, cell = cells.origin, cells.cell
    ci, cj, ck = cell_of(o, cell, x)
    r2 = jnp.asarray(r2, jnp.float32)
    r2 = (r2[..., None] if r2.ndim else r2) * (1.0 + 1e-4) + (1e-5 * cell) ** 2
    j = cj[..., None] + ROWS[:, 0]                                                   # [N, R]
    k = ck[..., None] + ROWS[:, 1]

    def gap(a, c, oc):   # distance along one axis from a to the cells c
        lo = oc + c.astype(jnp.float32) * cell
        return jnp.maximum(jnp.maximum(lo - a[..., None], a[..., None] - (lo + cell)), 0.0)

    chord2 = r2 - gap(x.y, j, o.y) ** 2 - gap(x.z, k, o.z) ** 2
    chord = jnp.sqrt(jnp.maximum(chord2, 0.0)) + 1e-5 * cell
    reach = CELLS_PER_RADIUS
    i_lo = jnp.maximum(jnp.floor((x.x[..., None] - chord - o.x) / cell).astype(jnp.int32),
                       ci[..., None] - reach)
    i_hi = jnp.minimum(jnp.floor((x.x[..., None] + chord - o.x) / cell).astype(jnp.int32),
                       ci[..., None] + reach)
    h_lo = neighbour_hash(i_lo, j, k, table_size)
    last = h_lo + (i_hi - i_lo)
    h_hi = last & jnp.int32(table_size - 1)
    end = cells.bounds[h_hi + 1] + jnp.where(last >= table_size, cells.n_valid, 0)
    start = cells.bounds[h_lo]
    return start, jnp.where(chord2 > 0, end - start, 0)


class Pairs(NamedTuple):
    """The (query, point) candidate pairs of :func:`cell_ranges`: every entry of every query's
    rows, queries in order, as flat ranges; :func:`pair_block` reads them in blocks."""
    start: Array      # [N * R] first slot (grid order, may run past n_valid) of each range
    count: Array      # [N * R] entries in it
    end: Array        # [N * R] inclusive prefix sum of count
    total: Array      # scalar: number of pairs
    n_valid: Array    # scalar: the grid's valid points (slots past it wrap to its start)


def candidate_pairs(start: Array, count: Array, n_valid) -> Pairs:
    count = count.reshape(-1)
    end = jnp.cumsum(count)
    return Pairs(start.reshape(-1), count, end, end[-1], jnp.asarray(n_valid, jnp.int32))


def pair_block(pairs: Pairs, block: int, b) -> tuple[Array, Array, Array]:
    """Pairs b * block .. (b + 1) * block - 1: (query [block], slot [block], valid [block]).
    No query has a cap: a loop over ceil(total / block) blocks reads each pair once, so a dense
    cell costs its own entries and nothing more."""
    k = b * block + jnp.arange(block, dtype=jnp.int32)
    seg = jnp.minimum(jnp.searchsorted(pairs.end, k, side="right", method="scan_unrolled"),
                      pairs.count.shape[0] - 1)
    slot = pairs.start[seg] + (k - (pairs.end[seg] - pairs.count[seg]))
    slot = jnp.where(slot >= pairs.n_valid, slot - pairs.n_valid, slot)   # a wrapped row
    valid = k < pairs.total
    return seg // ROWS.shape[0], jnp.where(valid, slot, 0), valid


# A pair visitor: visit(acc, query [B], slot [B], ok [B]) -> acc, the caller's evaluation of the
# pairs (query index, grid slot) where ok; it must add nothing where ok is false.
PairVisitor = Callable[[Array, Array, Array, Array], Array]


def accumulate_near_pairs(cells: CellIndex, table_size: int, points: Array, x: V3, live: Array,
                          r2, visit: PairVisitor, acc: Array, *, block: int, near_block: int,
                          keep: Callable[[Array, Array], Array] | None = None,
                          dense: int | None = None) -> Array:
    """The fixed-radius query of the device grid: ``visit`` folded over every (query, point)
    pair with the point within r of the query (r2 = r^2), for the queries x ([N]) where
    ``live``. ``points``: [M, >= 3] rows in grid order (``cells.order``) whose first three
    columns are the position (the rest is the caller's, for ``keep``).

    Every pair of the cells a query's ball overlaps is listed (:func:`cell_ranges`,
    :func:`candidate_pairs`; r2 scalar or per query) and read ``block`` at a time, as many
    blocks as there are pairs; the cheap test (distance, and ``keep(query [block],
    rows [block, ...])`` if given) selects the near pairs, packed ``near_block`` at a time into
    ``visit``: no query has a cap, so no point is dropped, and a dense cell costs its own pairs
    only.

    ``dense`` (a differentiable form: a loop of traced length has no reverse-mode derivative):
    one block of that many pairs for all queries, ``visit`` given every candidate (no cheap
    test); if the queries have more pairs the result is NaN, never a silently truncated sum."""
    start, count = cell_ranges(cells, table_size, x, r2)
    pairs = candidate_pairs(start, jnp.where(live[:, None], count, 0), cells.n_valid)
    if dense is not None:
        q, slot, ok = pair_block(pairs, dense, 0)
        return visit(acc, q, slot, ok) + jnp.where(pairs.total > dense, jnp.nan, 0.0)
    n_blocks = (pairs.total + block - 1) // block
    body = partial(_near_pairs_of_block, pairs=pairs, points=points, x=x, r2=r2, visit=visit,
                   keep=keep, block=block, near_block=near_block)
    return jax.lax.fori_loop(0, n_blocks, body, acc)


def _near_pairs_of_block(i, acc, *, pairs: Pairs, points: Array, x: V3, r2, visit: PairVisitor,
                         keep, block: int, near_block: int):
    """Block i of :func:`accumulate_near_pairs`: the cheap test, then ``visit`` on the packed
    near pairs."""
    q, slot, ok = pair_block(pairs, block, i)
    y = points[slot]
    diff = V3(y[:, 0], y[:, 1], y[:, 2]) - V3(*(c[q] for c in x))
    near = ok & (dot(diff, diff) < (r2[q] if jnp.ndim(r2) else r2))
    if keep is not None:
        near = near & keep(q, y)
    (sel,) = jnp.nonzero(near, size=block, fill_value=block)
    sel = jnp.concatenate([sel, jnp.full((near_block,), block, sel.dtype)])
    n_near = (jnp.sum(near) + near_block - 1) // near_block
    body = partial(_visit_packed, sel=sel, q=q, slot=slot, visit=visit, block=block,
                   near_block=near_block)
    return jax.lax.fori_loop(0, n_near, body, acc)


def _visit_packed(k, acc, *, sel: Array, q: Array, slot: Array, visit: PairVisitor, block: int,
                  near_block: int):
    """Near pairs k * near_block .. of a block (``sel``: their places in it, padded with
    ``block``)."""
    e = jax.lax.dynamic_slice(sel, (k * near_block,), (near_block,))
    live = e < block
    e = jnp.minimum(e, block - 1)
    return visit(acc, q[e], slot[e], live)
