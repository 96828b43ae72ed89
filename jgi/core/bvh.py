"""Bounding volume hierarchy (BVH) over triangle meshes: a numpy build, a JAX traversal.

Build (:func:`build_bvh`, numpy, once per mesh). A binary tree of axis-aligned boxes split by
the *surface area heuristic* with binned centroids (Goldsmith & Salmon 1987; MacDonald & Booth
1990; the binned evaluation of Wald 2007, "On fast construction of SAH-based bounding volume
hierarchies"). Splitting a node of area A into children (A_L, N_L), (A_R, N_R) costs

    C = C_trav + C_isect (A_L N_L + A_R N_R) / A,

the expected work for a ray that hits the node, since a random line that meets a convex box also
meets a convex box inside it with probability A_child / A. Centroids are sorted into
``NUM_BINS`` equal bins per axis and the ``NUM_BINS - 1`` planes between bins are evaluated with
prefix and suffix sweeps. The build goes level by level: every node of a level is binned,
costed and partitioned by whole-array numpy operations, so the Python loop runs once per tree
level, not once per node or triangle (measured on 2 shared CPU cores: 10^5 triangles in 1.4 s,
10^6 in 13 s; see ``experiments/bench/bvh.py``).

Layout (as pbrt-v4's ``LinearBVHNode``): nodes in depth-first order, so the first child of an
internal node is the next node; ``offset`` holds the second child of an internal node, or the
first triangle of a leaf, whose ``count`` is positive (0 marks an internal node). Triangles are
reordered so each leaf owns a contiguous range, and stored as ``v0``, ``edge1``, ``edge2`` (the
Moller-Trumbore layout of :class:`jgi.scene.Triangles`); ``prim`` maps back to input indices.

Traversal (:func:`intersect_closest`, :func:`intersect_any`, JAX). One ray runs a
``lax.while_loop`` with a fixed-size stack of node indices and entry distances; ``vmap`` turns
it into a batched loop over a chunk of rays, and chunks run one after another so a chunk's
loop ends as soon as its slowest ray does. Each iteration visits one node: a leaf tests its
(at most ``max_leaf``) triangles, an internal node slab-tests both children and continues with
the nearer one, pushing the other. Nodes are culled by the current closest distance, and
popped nodes whose recorded entry distance is beyond it are skipped.

Because a batched loop executes every branch for every lane, an iteration costs the same
whether it visits a leaf of one triangle or of ``max_leaf``; the build therefore makes a leaf
of every node with at most ``max_leaf`` triangles, and uses the SAH only to place splits.

Robustness: direction components below 1e-20 in magnitude get a large finite reciprocal (no
0 * inf), node bounds are rounded outwards to float32 and the slab test widens its exit
distance by 1 + 2 gamma_3 (pbrt-v4, section 6.8.2), so rounding never culls a box that the ray
touches. Moller-Trumbore accepts barycentrics within ``BARY_EPS`` of the triangle, so a ray
through a shared edge cannot slip between two triangles of a mesh, and rejects triangles whose
determinant is tiny relative to |d| |e1| |e2| (zero-area triangles, rays in the triangle's plane).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._xla import materialize
from .vec import V3, cross, dot

NUM_BINS = 16         # SAH bins per axis and node
MAX_LEAF = 4          # default leaf size: triangles tested per leaf visit
STACK_SIZE = 64       # traversal stack entries; the build keeps the tree depth below this
C_TRAV = 1.0          # SAH cost of a node visit, relative to one triangle test (C_isect = 1)
LANES = 4096          # traversal lanes (rays in flight) of the batched loop
# smaller loops are unrolled and compile slower (perf: docs/performance.md#bvh-lanes)
MIN_LANES = 2048      # fewer rays still get this many lanes (the extra ones idle)
REFILL = 0.25         # refill lanes once this fraction of them is free
BARY_EPS = 2.0**-20   # barycentric tolerance (about 1e-6 of the triangle's size)
DET_EPS = 1e-6        # |det| below DET_EPS |d| |e1| |e2| counts as parallel or degenerate
INV_D_MIN = 1e-20     # direction components smaller than this are treated as zero
_GAMMA3 = 3 * 2.0**-24 / (1 - 3 * 2.0**-24)  # pbrt's gamma_3 for float32
_SLAB_WIDEN = np.float32(1 + 2 * _GAMMA3)
_SLOT = 10            # floats per triangle slot of a leaf row


class BVH(eqx.Module):
    """A flattened BVH. Every array is a pytree leaf, so one compiled traversal serves every
    mesh with the same node, leaf and triangle counts (and the same static ``max_leaf``).

    The depth-first node arrays and the leaf-ordered triangles are the tree itself; ``inner``
    and ``leaves`` repack the same numbers for the traversal, so that one visit reads one row
    (a gather per visit rather than one per coordinate: XLA's CPU backend runs every gather
    as a separate loop)."""

    # The tree, depth-first (first child of an internal node = next node).
    lo: V3          # [M] float32 node box minimum
    hi: V3          # [M] float32 node box maximum
    offset: Array   # [M] int32: second child (internal node) or first triangle (leaf)
    count: Array    # [M] int32: triangles in a leaf; 0 internal node; -1 padding (pad=True)
    v0: V3          # [T] float32 first vertex, in leaf order
    edge1: V3       # [T] v1 - v0
    edge2: V3       # [T] v2 - v0
    prim: Array     # [T] int32 input index of each stored triangle
    # Traversal tables. A reference r >= 0 names row r of ``inner``, r < 0 row -r-1 of
    # ``leaves``; references are stored in float32 rows as exact integers (|r| < 2^24).
    inner: Array     # [max(I, 1), 16] float32 per internal node: the boxes of its two
                     # children (lo1, hi1, lo2, hi2, 12 floats), then their references
    leaves: Array    # [L, 10 max_leaf] float32 per leaf: (v0, edge1, edge2, det_threshold)
                     # of each slot; slots beyond the leaf's count are zero (never hit)
    leaf_tri: Array  # [L, max_leaf] int32 input triangle index of each slot, -1 if empty
    root: Array      # int32 scalar: reference of the root node
    max_leaf: int = eqx.field(static=True, default=MAX_LEAF)

    @property
    def node_count(self) -> int:
        return int(self.count.shape[0])

    @property
    def triangle_count(self) -> int:
        return int(self.prim.shape[0])


class Closest(NamedTuple):
    t: Array      # [N] float32 distance; inf on a miss
    prim: Array   # [N] int32 input triangle index; -1 on a miss
    b1: Array     # [N] barycentric weight of v1 (hit point = v0 + b1 e1 + b2 e2); 0 on a miss
    b2: Array     # [N] barycentric weight of v2


# --- build (numpy) ---------------------------------------------------------------------------

def _as_vertices(name: str, a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"build_bvh: {name} must have shape [T, 3]; got {a.shape}")
    if not np.all(np.isfinite(a)):
        bad = int(np.argmax(~np.all(np.isfinite(a), axis=1)))
        raise ValueError(f"build_bvh: {name} has non-finite coordinates (first at triangle {bad});"
                         " only finite vertices are allowed")
    return a


def _round_out(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float64 box -> float32 box containing it, one ulp wider on each side (so a ray travelling
    exactly in a face plane of the box still enters it)."""
    lo32, hi32 = lo.astype(np.float32), hi.astype(np.float32)
    lo32 = np.nextafter(np.where(lo32 > lo, np.nextafter(lo32, np.float32(-np.inf)), lo32),
                        np.float32(-np.inf))
    hi32 = np.nextafter(np.where(hi32 < hi, np.nextafter(hi32, np.float32(np.inf)), hi32),
                        np.float32(np.inf))
    return lo32, hi32


def _half_area(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Half the surface area of boxes [..., 3]; 0 for empty boxes (lo > hi)."""
    e = np.maximum(hi - lo, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def _segment_rank(seg: np.ndarray, flag: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """For elements grouped in contiguous segments: how many earlier elements of the same
    segment have ``flag`` set (a segmented exclusive prefix count)."""
    c = np.cumsum(flag, dtype=np.int64)
    before = np.concatenate([[0], c])[starts]  # flagged elements before each segment
    return c - flag - before[seg]


def _best_splits(seg, n_nodes, cen, tlo, thi, clo, chi, node_area):
    """Binned SAH over the nodes of one chunk.

    seg [n]: node (0..n_nodes-1) of each triangle; cen, tlo, thi [n, 3]: centroid and bounds of
    each triangle; clo, chi [n_nodes, 3]: centroid bounds; node_area [n_nodes] (half areas).
    Returns (cost, axis, split bin) per node; a triangle goes left when its bin <= split bin.
    Cost is inf where no plane separates the centroids."""
    B = NUM_BINS
    best_cost = np.full(n_nodes, np.inf)
    best_axis = np.zeros(n_nodes, np.int64)
    best_bin = np.zeros(n_nodes, np.int64)
    for a in range(3):
        ext = chi[:, a] - clo[:, a]
        scale = np.where(ext > 0, B / np.where(ext > 0, ext, 1.0), 0.0)
        b = np.minimum(((cen[:, a] - clo[seg, a]) * scale[seg]).astype(np.int64), B - 1)
        key = seg * B + b
        cnt = np.bincount(key, minlength=n_nodes * B).reshape(n_nodes, B)
        blo = np.empty((n_nodes * B, 3), np.float32)
        bhi = np.empty((n_nodes * B, 3), np.float32)
        for k in range(3):
            col = np.full(n_nodes * B, np.inf, np.float32)
            np.minimum.at(col, key, tlo[:, k])
            blo[:, k] = col
            col = np.full(n_nodes * B, -np.inf, np.float32)
            np.maximum.at(col, key, thi[:, k])
            bhi[:, k] = col
        blo, bhi = blo.reshape(n_nodes, B, 3), bhi.reshape(n_nodes, B, 3)
        # left = bins 0..i, right = bins i+1..B-1, for i = 0..B-2
        n_l = np.cumsum(cnt, axis=1)[:, :-1]
        n_r = np.cumsum(cnt[:, ::-1], axis=1)[:, ::-1][:, 1:]
        a_l = _half_area(np.minimum.accumulate(blo, axis=1), np.maximum.accumulate(bhi, axis=1))
        a_r = _half_area(np.minimum.accumulate(blo[:, ::-1], axis=1)[:, ::-1],
                         np.maximum.accumulate(bhi[:, ::-1], axis=1)[:, ::-1])
        with np.errstate(invalid="ignore", divide="ignore"):
            cost = C_TRAV + (a_l[:, :-1] * n_l + a_r[:, 1:] * n_r) / node_area[:, None]
        cost = np.where((n_l > 0) & (n_r > 0) & np.isfinite(cost), cost, np.inf)
        i = np.argmin(cost, axis=1)
        c = cost[np.arange(n_nodes), i]
        better = c < best_cost
        best_cost = np.where(better, c, best_cost)
        best_axis = np.where(better, a, best_axis)
        best_bin = np.where(better, i, best_bin)
    return best_cost, best_axis, best_bin


def build_bvh(v0, v1, v2, *, max_leaf: int = MAX_LEAF, pad: bool = False,
              node_chunk: int = 1 << 15) -> BVH:
    """Binned-SAH BVH over triangles (v0[i], v1[i], v2[i]); arrays of shape [T, 3].

    Leaves hold at most ``max_leaf`` triangles; the depth stays within ``STACK_SIZE`` (near
    that limit, nodes are split at the object median instead, which halves them). With
    ``pad``, the arrays are padded to sizes that depend on T only (2T - 1 nodes), so that one
    compiled traversal serves every mesh of T triangles, e.g. a deforming mesh rebuilt per
    frame. ``node_chunk`` bounds the build's memory (nodes binned at once). Raises ValueError
    for wrong shapes, non-finite vertices, an empty mesh or a leaf size outside 1..16."""
    v0 = _as_vertices("v0", v0)
    v1 = _as_vertices("v1", v1)
    v2 = _as_vertices("v2", v2)
    if not (v0.shape == v1.shape == v2.shape):
        raise ValueError(f"build_bvh: v0, v1, v2 must have the same shape; got {v0.shape}, "
                         f"{v1.shape}, {v2.shape}")
    T = v0.shape[0]
    if T == 0:
        raise ValueError("build_bvh: the mesh has no triangles; at least one is required")
    if T >= 2**24:
        raise ValueError(f"build_bvh: {T} triangles; fewer than 2^24 are supported (node "
                         "references are stored as exact float32 integers)")
    if not (1 <= int(max_leaf) <= 16):
        raise ValueError(f"build_bvh: max_leaf must be in 1..16; got {max_leaf}")
    max_leaf = int(max_leaf)

    # The triangle exactly as the intersection test sees it: float32 v0, e1, e2.
    p0 = v0.astype(np.float32)
    e1 = (v1 - v0).astype(np.float32)
    e2 = (v2 - v0).astype(np.float32)
    q0 = p0.astype(np.float64)
    q1, q2 = q0 + e1, q0 + e2          # exact in float64
    tlo64 = np.minimum(np.minimum(q0, q1), q2)
    thi64 = np.maximum(np.maximum(q0, q1), q2)
    tlo, thi = _round_out(tlo64, thi64)
    cen = 0.5 * (tlo64 + thi64)

    cap = 2 * T - 1                    # nodes of a binary tree with at most T leaves
    n_lo = np.empty((cap, 3), np.float32)
    n_hi = np.empty((cap, 3), np.float32)
    n_left = np.full(cap, -1, np.int64)    # breadth-first ids of the children
    n_right = np.full(cap, -1, np.int64)
    n_first = np.zeros(cap, np.int64)
    n_count = np.zeros(cap, np.int64)
    levels = []                        # (first id, end id) of each level

    perm = np.arange(T)
    # The active level: node ids and their contiguous ranges [start, start + size) in perm.
    ids = np.array([0]); starts = np.array([0]); sizes = np.array([T])
    n_nodes = 1
    depth = 0
    while ids.size:
        levels.append((int(ids[0]), int(ids[-1]) + 1))
        K = ids.size
        seg_start = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        seg = np.repeat(np.arange(K), sizes)
        pos = np.arange(seg.size) - seg_start[seg] + starts[seg]   # positions in perm
        tri = perm[pos]
        lo = np.minimum.reduceat(tlo[tri], seg_start, axis=0)
        hi = np.maximum.reduceat(thi[tri], seg_start, axis=0)
        n_lo[ids], n_hi[ids] = lo, hi
        c = cen[tri]
        clo = np.minimum.reduceat(c, seg_start, axis=0)
        chi = np.maximum.reduceat(c, seg_start, axis=0)

        leaf = sizes <= max_leaf
        # Near the stack limit, median splits guarantee the remaining depth.
        median_needed = np.ceil(np.log2(np.maximum(sizes / max_leaf, 1.0)))
        force_median = ~leaf & (depth + median_needed + 2 >= STACK_SIZE)

        cost = np.full(K, np.inf); axis = np.zeros(K, np.int64); sbin = np.zeros(K, np.int64)
        sah_nodes = np.flatnonzero(~leaf & ~force_median)
        for k0 in range(0, sah_nodes.size, node_chunk):
            nodes = sah_nodes[k0:k0 + node_chunk]
            in_chunk = np.zeros(K, bool)
            in_chunk[nodes] = True
            sel = np.flatnonzero(in_chunk[seg])
            local = np.searchsorted(nodes, seg[sel])
            area = _half_area(lo[nodes].astype(np.float64), hi[nodes].astype(np.float64))
            cc, aa, bb = _best_splits(local, nodes.size, c[sel], tlo[tri[sel]], thi[tri[sel]],
                                      clo[nodes], chi[nodes], area)
            cost[nodes], axis[nodes], sbin[nodes] = cc, aa, bb

        # Nodes without a separating plane (coincident centroids) or near the depth limit:
        # object median along the widest centroid axis.
        median = ~leaf & ~np.isfinite(cost)
        axis = np.where(median, np.argmax(chi - clo, axis=1), axis)
        go_left = np.ones(seg.size, bool)
        split = ~leaf
        ext = chi[np.arange(K), axis] - clo[np.arange(K), axis]
        scale = np.where(ext > 0, NUM_BINS / np.where(ext > 0, ext, 1.0), 0.0)
        b = np.minimum(((c[np.arange(seg.size), axis[seg]] - clo[seg, axis[seg]])
                        * scale[seg]).astype(np.int64), NUM_BINS - 1)
        go_left = np.where(split[seg] & ~median[seg], b <= sbin[seg], go_left)
        if median.any():
            m = np.flatnonzero(median[seg])
            order = np.lexsort((c[m, axis[seg[m]]], seg[m]))     # by node, then centroid
            rank = np.empty(m.size, np.int64)
            ms = seg[m][order]
            first = np.searchsorted(ms, ms)                     # first slot of each node
            rank[order] = np.arange(m.size) - first
            go_left[m] = rank < sizes[seg[m]] // 2

        # Stable partition of every node's range: left triangles first.
        r_left = _segment_rank(seg, go_left, seg_start)
        r_right = _segment_rank(seg, ~go_left, seg_start)
        n_left_tris = np.bincount(seg, weights=go_left, minlength=K).astype(np.int64)
        new_pos = starts[seg] + np.where(go_left, r_left, n_left_tris[seg] + r_right)
        perm[new_pos] = tri

        # Records: leaves keep their range, split nodes get two children on the next level.
        n_first[ids] = starts
        n_count[ids] = np.where(leaf, sizes, 0)
        s = np.flatnonzero(split)
        child = n_nodes + 2 * np.arange(s.size)
        n_left[ids[s]], n_right[ids[s]] = child, child + 1
        n_nodes += 2 * s.size
        ids = np.stack([child, child + 1], axis=1).ravel()
        starts = np.stack([starts[s], starts[s] + n_left_tris[s]], axis=1).ravel()
        sizes = np.stack([n_left_tris[s], sizes[s] - n_left_tris[s]], axis=1).ravel()
        depth += 1
    assert depth <= STACK_SIZE, depth

    # Breadth-first ids -> depth-first order: subtree sizes bottom-up, then
    # dfs(left) = dfs(parent) + 1, dfs(right) = dfs(parent) + 1 + size(left), top-down.
    M = n_nodes
    size = np.ones(M, np.int64)
    for a, e in reversed(levels):
        r = np.arange(a, e)
        inner = r[n_left[r] >= 0]
        size[inner] = 1 + size[n_left[inner]] + size[n_right[inner]]
    dfs = np.zeros(M, np.int64)
    for a, e in levels:
        r = np.arange(a, e)
        inner = r[n_left[r] >= 0]
        dfs[n_left[inner]] = dfs[inner] + 1
        dfs[n_right[inner]] = dfs[inner] + 1 + size[n_left[inner]]
    order = np.empty(M, np.int64)
    order[dfs] = np.arange(M)          # order[k] = breadth-first id of depth-first node k
    is_leaf = n_left[:M] < 0
    offset = np.where(is_leaf, n_first[:M], dfs[np.maximum(n_right[:M], 0)])[order]

    lo, hi = n_lo[:M][order], n_hi[:M][order]
    count = n_count[:M][order]
    inner, leaves, leaf_tri, root = _traversal_tables(lo, hi, offset, count, p0[perm], e1[perm],
                                                      e2[perm], perm, max_leaf)
    if pad:
        # Shapes that depend on T only: at most 2T - 1 nodes, T - 1 internal, T leaves.
        # Padding nodes are marked by count -1 and an empty box; no reference reaches them.
        extra = 2 * T - 1 - M
        lo = np.concatenate([lo, np.full((extra, 3), np.inf, np.float32)])
        hi = np.concatenate([hi, np.full((extra, 3), -np.inf, np.float32)])
        offset = np.concatenate([offset, np.zeros(extra, np.int64)])
        count = np.concatenate([count, np.full(extra, -1, np.int64)])
        inner = _pad_rows(inner, max(T - 1, 1))
        leaves = _pad_rows(leaves, T)
        leaf_tri = np.concatenate([leaf_tri, np.full((T - leaf_tri.shape[0], max_leaf), -1)])
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    v3 = lambda a: V3(f32(a[:, 0]), f32(a[:, 1]), f32(a[:, 2]))  # noqa: E731
    return BVH(lo=v3(lo), hi=v3(hi),
               offset=jnp.asarray(offset, jnp.int32),
               count=jnp.asarray(count, jnp.int32),
               v0=v3(p0[perm]), edge1=v3(e1[perm]), edge2=v3(e2[perm]),
               prim=jnp.asarray(perm, jnp.int32),
               inner=f32(inner), leaves=f32(leaves), leaf_tri=jnp.asarray(leaf_tri, jnp.int32),
               root=jnp.asarray(root, jnp.int32), max_leaf=max_leaf)


def _pad_rows(a: np.ndarray, rows: int) -> np.ndarray:
    return np.concatenate([a, np.zeros((rows - a.shape[0],) + a.shape[1:], a.dtype)])


def _traversal_tables(lo, hi, offset, count, v0, e1, e2, prim, max_leaf):
    """Repack the depth-first tree into per-visit rows (see :class:`BVH`)."""
    is_leaf = count > 0
    ref = np.where(is_leaf, -np.cumsum(is_leaf), np.cumsum(~is_leaf) - 1)
    nodes = np.flatnonzero(~is_leaf)
    c1, c2 = nodes + 1, offset[nodes]
    inner = np.zeros((max(nodes.size, 1), 16), np.float32)
    inner[:nodes.size] = np.concatenate(
        [lo[c1], hi[c1], lo[c2], hi[c2], ref[c1][:, None], ref[c2][:, None],
         np.zeros((nodes.size, 2))], axis=1)
    leaf_nodes = np.flatnonzero(is_leaf)
    k = np.arange(max_leaf)
    slot = offset[leaf_nodes][:, None] + k
    used = k < count[leaf_nodes][:, None]
    slot = np.where(used, slot, 0)
    e1_64, e2_64 = e1.astype(np.float64), e2.astype(np.float64)
    det_min = DET_EPS * np.sqrt((e1_64 * e1_64).sum(1) * (e2_64 * e2_64).sum(1))
    rows = np.concatenate([v0, e1, e2, det_min[:, None]], axis=1)[slot]   # [L, max_leaf, 10]
    leaves = np.where(used[..., None], rows, 0.0).reshape(leaf_nodes.size, _SLOT * max_leaf)
    leaf_tri = np.where(used, prim[slot], -1)
    return inner, leaves, leaf_tri, ref[0]


# --- ray-primitive tests (JAX) ----------------------------------------------------------------

def inverse_direction(d: V3) -> V3:
    """1/d per component, with |d_i| < INV_D_MIN replaced by INV_D_MIN (sign irrelevant: such a
    ray is parallel to that slab for any finite distance), so slab tests never form 0 * inf."""
    return d.map(lambda x: 1.0 / jnp.where(jnp.abs(x) < INV_D_MIN, jnp.float32(INV_D_MIN), x))


def slab(lo: V3, hi: V3, o: V3, inv_d: V3, t_min, t_max) -> Array:
    """Ray-box slab test (Kay & Kajiya 1986): the entry distance max(t_near, t_min) where the
    box overlaps the ray's interval (t_min, t_max), inf where it does not. The exit distance
    is widened by 1 + 2 gamma_3 so that float rounding never rejects a box the ray touches
    (pbrt-v4, section 6.8.2). A miss is inf rather than a flag because XLA's CPU backend
    vectorises float results far better than boolean ones."""
    tx0, tx1 = (lo.x - o.x) * inv_d.x, (hi.x - o.x) * inv_d.x
    ty0, ty1 = (lo.y - o.y) * inv_d.y, (hi.y - o.y) * inv_d.y
    tz0, tz1 = (lo.z - o.z) * inv_d.z, (hi.z - o.z) * inv_d.z
    t_near = jnp.maximum(jnp.maximum(jnp.minimum(tx0, tx1), jnp.minimum(ty0, ty1)),
                         jnp.maximum(jnp.minimum(tz0, tz1), t_min))
    t_far = jnp.minimum(jnp.minimum(jnp.maximum(tx0, tx1), jnp.maximum(ty0, ty1)),
                        jnp.maximum(tz0, tz1)) * _SLAB_WIDEN
    return jnp.where(t_near <= jnp.minimum(t_far, t_max), t_near, jnp.inf)


def det_threshold(e1: V3, e2: V3) -> Array:
    """Per-triangle factor of the BVH's parallel/degenerate test: DET_EPS |e1| |e2|
    (multiplied by |d| per ray, see :func:`solve_above`)."""
    return DET_EPS * jnp.sqrt(dot(e1, e1) * dot(e2, e2))


def moller_trumbore(v0: V3, e1: V3, e2: V3, o: V3, d: V3,
                    solve: Callable[[Array], tuple[Array, Array]]
                    ) -> tuple[Array, Array, Array, Array]:
    """Moller & Trumbore 1997, the one ray-triangle test: solve o + t d = v0 + b1 e1 + b2 e2 by
    Cramer's rule,

        det = e1 . (d x e2),  b1 = (o - v0) . (d x e2) / det,
        b2 = d . ((o - v0) x e1) / det,  t = e2 . ((o - v0) x e1) / det.

    ``solve(det) -> (1 / det, solved)`` is the caller's degeneracy test and reciprocal, the
    one thing the two callers do differently (each keeps its own, so that its hits stay what
    they were bit for bit):

    * the BVH traversal, :func:`solve_above` ``(det_threshold(e1, e2) * |d|)``: a threshold
      scaled by the triangle and the ray, an exact reciprocal, and b1 = b2 = 0 where rejected;
    * the brute-force scans of :mod:`jgi.physics.geometry` (and the barycentrics of the hit a
      BVH found): a fixed |det| > 1e-14 plus the plane test that quads use (a ray within
      ``EDGE_ON_COS`` of the plane misses), with the fast reciprocal ``jgi._xla.recip``.

    Returns (t, b1, b2, inside): ``inside`` where the system is solved and the point lies in
    the triangle (barycentric test widened by BARY_EPS, so a ray through an edge shared by two
    triangles hits one of them whatever the rounding). The caller masks t with it and its own
    t range, in one select (a second one changed XLA's fusion, and the brute-force scan's
    images by float rounding)."""
    pvec = cross(d, e2)
    det = dot(e1, pvec)
    inv, solved = solve(det)
    tvec = o - v0
    b1 = dot(tvec, pvec) * inv
    qvec = cross(tvec, e1)
    b2 = dot(d, qvec) * inv
    t = dot(e2, qvec) * inv
    inside = solved & (b1 >= -BARY_EPS) & (b2 >= -BARY_EPS) & (b1 + b2 <= 1.0 + BARY_EPS)
    return t, b1, b2, inside


def solve_above(det_min) -> Callable[[Array], tuple[Array, Array]]:
    """The BVH's ``solve`` for :func:`moller_trumbore`: rejects |det| <= det_min. Since
    |det| = |d| |e1| |e2| sin(e1, e2) |cos(d, normal)|, ``det_min = det_threshold(e1, e2) * |d|``
    rejects zero-area triangles and rays within about DET_EPS radians of the triangle's plane,
    where t and the barycentrics are rounding noise. There 1 / det is 0 (no division by a tiny
    det), so b1 = b2 = 0."""
    def solve(det: Array) -> tuple[Array, Array]:
        inv = 1.0 / jnp.where(jnp.abs(det) > det_min, det, jnp.inf)   # 0 when rejected
        return inv, inv != 0
    return solve


# --- traversal (JAX) -------------------------------------------------------------------------

_NONE = -(2**30)      # "no reference": a finished lane, an empty leaf slot

# An opacity mask tested in the leaves: ``mask(triangle, b1, b2, o, d) -> stops`` (bool [L]) for
# the input triangle index and barycentrics of a crossing of the ray (o, d); a crossing that
# does not stop the ray is skipped (jgi.physics.geometry's masks). None: every crossing stops.
Mask = Callable[[Array, Array, Array, V3, V3], Array]


class _Ray(NamedTuple):
    """The rays held by the lanes ([L] arrays)."""
    o: V3
    d: V3
    inv_d: V3
    d_len: Array     # |d|, for the determinant threshold
    t_min: Array


class _Lane(NamedTuple):
    """Traversal state of each lane ([L] arrays, the stack [STACK_SIZE, L])."""
    item: Array      # reference of the node to visit next, or _NONE
    item_t: Array    # its entry distance: the visit is skipped if beyond the closest hit
    leaf: Array      # reference of a leaf whose triangles the next step tests, or _NONE
    leaf_t: Array    # its entry distance
    stack: Array     # [STACK_SIZE, L] int32 references still to visit
    stack_t: Array   # [STACK_SIZE, L] float32 their entry distances
    sp: Array        # stack size
    t: Array         # closest hit so far (t_max until something is hit)
    tri: Array       # input index of its triangle, -1 if none
    b1: Array        # its barycentrics
    b2: Array

    @property
    def done(self) -> Array:
        return (self.item == _NONE) & (self.leaf == _NONE)


def _start(bvh: BVH, ray: _Ray, t_max: Array, live: Array) -> _Lane:
    """Lanes at the root (finished at once if the ray misses the root box or ``live`` is
    false)."""
    t0 = slab(_take(bvh.lo, 0), _take(bvh.hi, 0), ray.o, ray.inv_d, ray.t_min, t_max)
    hit = t0 < jnp.inf
    shape = t_max.shape
    f32, i32 = jnp.float32, jnp.int32
    none = jnp.full(shape, _NONE, i32)
    return _Lane(item=jnp.where(hit & live, bvh.root, _NONE).astype(i32), item_t=t0,
                 leaf=none, leaf_t=jnp.zeros(shape, f32),
                 stack=jnp.zeros((STACK_SIZE,) + shape, i32),
                 stack_t=jnp.zeros((STACK_SIZE,) + shape, f32),
                 sp=jnp.zeros(shape, i32), t=t_max.astype(f32), tri=jnp.full(shape, -1, i32),
                 b1=jnp.zeros(shape, f32), b2=jnp.zeros(shape, f32))


def _take(v: V3, i) -> V3:
    return V3(v.x[i], v.y[i], v.z[i])


def _step(bvh: BVH, ray: _Ray, s: _Lane, any_hit: bool, mask: Mask | None = None) -> _Lane:
    """One step of every lane: test the pending leaf's triangles, and visit one node.

    A visited internal node slab-tests its two children. Of the children hit, the nearest leaf
    becomes the next pending leaf and the nearest internal node the next node; a child left
    over is pushed. A visited leaf (popped from the stack) becomes the pending leaf. So, unlike
    a loop that visits one node or one leaf per step, a step usually does both kinds of work;
    in a batched loop every lane pays for both in every step anyway.

    ``mask`` (see :data:`Mask`), if given, decides whether a triangle the ray crosses stops it;
    one that does not is no hit, and the search goes on beyond it.

    Written for XLA's CPU backend: misses are carried as t = inf rather than as boolean
    arrays (boolean fusion outputs are not vectorised), and results used by many selects are
    materialised once (:func:`jgi._xla.materialize`)."""
    o, d, inv_d, d_len, t_min = ray
    n = s.item.shape[0]
    i32 = jnp.int32

    # Pending leaf: Moller-Trumbore on each slot; lanes without a leaf search an empty
    # interval (t_min, -inf), so they keep their state.
    t_hi = jnp.where((s.leaf != _NONE) & (s.leaf_t <= s.t), s.t, -jnp.inf)
    li = jnp.clip(-s.leaf - 1, 0, bvh.leaves.shape[0] - 1)
    rows = bvh.leaves[li]                                           # [L, 10 max_leaf]
    slots = bvh.leaf_tri[li]                                        # [L, max_leaf]
    tri, b1, b2 = s.tri, s.b1, s.b2
    for k in range(bvh.max_leaf):
        c = lambda j, k=k: rows[:, _SLOT * k + j]  # noqa: E731
        tk, b1k, b2k, inside = moller_trumbore(V3(c(0), c(1), c(2)), V3(c(3), c(4), c(5)),
                                               V3(c(6), c(7), c(8)), o, d,
                                               solve_above(c(9) * d_len))
        if mask is not None:
            inside = inside & mask(jnp.maximum(slots[:, k], 0), b1k, b2k, o, d)
        tk = jnp.where(inside, tk, jnp.inf)
        tk, b1k, b2k = materialize((jnp.where((tk > t_min) & (tk < t_hi), tk, jnp.inf),
                                    b1k, b2k))
        tri = jnp.where(tk < jnp.inf, slots[:, k], tri)
        b1 = jnp.where(tk < jnp.inf, b1k, b1)
        b2 = jnp.where(tk < jnp.inf, b2k, b2)
        t_hi = jnp.minimum(tk, t_hi)
    t = jnp.where(t_hi > -jnp.inf, t_hi, s.t)        # s.t where no leaf was tested

    # Node: an internal node's row holds both children's boxes; a popped leaf is passed on.
    visiting = (s.item != _NONE) & (s.item_t <= t)
    node = bvh.inner[jnp.clip(s.item, 0, bvh.inner.shape[0] - 1)]   # [L, 16]
    col = lambda j: node[:, j]  # noqa: E731
    t_node = jnp.where(visiting & (s.item >= 0), t, -jnp.inf)
    tn1 = slab(V3(col(0), col(1), col(2)), V3(col(3), col(4), col(5)), o, inv_d, t_min, t_node)
    tn2 = slab(V3(col(6), col(7), col(8)), V3(col(9), col(10), col(11)), o, inv_d, t_min,
               t_node)
    tn1, tn2 = materialize((tn1, tn2))
    r1, r2 = col(12).astype(i32), col(13).astype(i32)
    # candidates a (the nearer child hit, or a popped leaf) and b (the farther child hit)
    popped_leaf = visiting & (s.item < 0)
    b_first = tn2 < tn1
    a = jnp.where(popped_leaf, s.item, jnp.where(b_first, r2, r1))
    a_t = jnp.where(popped_leaf, s.item_t, jnp.minimum(tn1, tn2))
    b = jnp.where(b_first, r1, r2)
    b_t = jnp.maximum(tn1, tn2)
    a = jnp.where(a_t < jnp.inf, a, _NONE)
    b = jnp.where(b_t < jnp.inf, b, _NONE)
    a_leaf, b_leaf = (a < 0) & (a != _NONE), (b < 0) & (b != _NONE)
    a_node, b_node = a >= 0, b >= 0

    # Distribute: the nearest leaf -> pending, the nearest internal node -> next node, and a
    # child of the same kind as a left over: pushed, or next if there is no next node.
    leaf = jnp.where(a_leaf, a, jnp.where(b_leaf, b, _NONE))
    leaf_t = jnp.where(a_leaf, a_t, b_t)
    nxt = jnp.where(a_node, a, jnp.where(b_node, b, _NONE))
    nxt_t = jnp.where(a_node, a_t, b_t)
    rest = (a_leaf & b_leaf) | (a_node & b_node)      # b is left over
    push = rest & a_node
    nxt = jnp.where(rest & a_leaf, b, nxt)
    nxt_t = jnp.where(rest & a_leaf, b_t, nxt_t)

    # Stack [STACK_SIZE, L]: push b where needed, pop where there is no next node.
    lane = jnp.arange(n)
    slot = jnp.minimum(s.sp, STACK_SIZE - 1)   # the build bounds the depth; clamp anyway
    stack = s.stack.at[slot, lane].set(jnp.where(push, b, s.stack[slot, lane]))
    stack_t = s.stack_t.at[slot, lane].set(b_t)   # above the top unless pushed: harmless
    sp = s.sp + push.astype(i32)
    pop = (nxt == _NONE) & (sp > 0)
    top = jnp.maximum(sp - 1, 0)
    item = jnp.where(pop, stack[top, lane], nxt)
    item_t = jnp.where(pop, stack_t[top, lane], nxt_t)
    sp = sp - pop.astype(i32)
    if any_hit:
        item = jnp.where(tri >= 0, _NONE, item)
        leaf = jnp.where(tri >= 0, _NONE, leaf)
    return _Lane(item, item_t, leaf, leaf_t, stack, stack_t, sp, t, tri, b1, b2)


def _check_rays(o: V3, d: V3, t_min, t_max):
    shape = jnp.shape(o.x)
    if len(shape) != 1:
        raise ValueError(f"rays must be V3 of shape [N]; got origin component shape {shape}")
    for name, v in (("o", o), ("d", d)):
        for c in v:
            if jnp.shape(c) != shape:
                raise ValueError(f"ray {name} components must all have shape {shape}; got "
                                 f"{jnp.shape(c)}")
    for name, v in (("t_min", t_min), ("t_max", t_max)):
        if jnp.ndim(v) not in (0, 1) or (jnp.ndim(v) == 1 and jnp.shape(v) != shape):
            raise ValueError(f"{name} must be a scalar or of shape {shape}; got {jnp.shape(v)}")
    f = lambda a: jnp.broadcast_to(jnp.asarray(a, jnp.float32), shape)  # noqa: E731
    return V3(*map(f, o)), V3(*map(f, d)), f(t_min), f(t_max)


def _trace(bvh: BVH, o: V3, d: V3, t_min: Array, t_max: Array, any_hit: bool, lanes: int,
           refill: float, mask: Mask | None = None):
    """All rays through a pool of ``lanes`` traversal lanes; a finished lane takes the next
    waiting ray ("persistent threads", Aila & Laine 2009), so the loop's length follows the
    rays' mean step count rather than the slowest ray of a fixed batch. Lanes are refilled
    (results written out, new rays loaded) when at least a fraction ``refill`` of them is
    free. Returns ((t, tri, b1, b2) per ray, with t = t_max where nothing was hit; the number
    of loop steps)."""
    n = o.x.shape[0]
    if n == 0:
        return (t_max, jnp.zeros(0, jnp.int32), t_max, t_max), jnp.int32(0)
    if int(lanes) < 1 or not 0.0 < float(refill) <= 1.0:
        raise ValueError(f"lanes must be >= 1 and refill in (0, 1]; got {lanes}, {refill}")
    L = max(min(int(lanes), n), min(int(lanes), MIN_LANES))
    threshold = max(1, int(refill * L))
    inv_d = inverse_direction(d)
    d_len = jnp.sqrt(dot(d, d))

    def load(ids):
        j = jnp.minimum(ids, n - 1)
        take = lambda v: V3(v.x[j], v.y[j], v.z[j])  # noqa: E731
        ray = _Ray(take(o), take(d), take(inv_d), d_len[j], t_min[j])
        return ray, _start(bvh, ray, t_max[j], ids < n)

    def write(out, ids, lane, mask):
        idx = jnp.where(mask, ids, n)             # index n is out of range: dropped
        return tuple(a.at[idx].set(v, mode="drop")
                     for a, v in zip(out, (lane.t, lane.tri, lane.b1, lane.b2)))

    ids = jnp.arange(L, dtype=jnp.int32)
    ray, lane = load(ids)
    out = (t_max, jnp.full(n, -1, jnp.int32), jnp.zeros(n, jnp.float32),
           jnp.zeros(n, jnp.float32))
    carry = (ids, ray, lane, out, jnp.int32(L), jnp.int32(0))

    def refill_lanes(c):
        ids, ray, lane, out, nxt = c
        free = lane.done
        out = write(out, ids, lane, free & (ids < n))
        new_ids = jnp.where(free, jnp.minimum(nxt + jnp.cumsum(free) - 1, n), ids)
        new_ray, new_lane = load(new_ids)
        sel = lambda a, b: jax.tree_util.tree_map(  # noqa: E731
            lambda x, y: jnp.where(free, x, y), a, b)
        return (new_ids.astype(jnp.int32), sel(new_ray, ray), sel(new_lane, lane), out,
                jnp.minimum(nxt + free.sum(dtype=jnp.int32), n))

    def body(c):
        ids, ray, lane, out, nxt, steps = c
        lane = _step(bvh, ray, lane, any_hit, mask)
        c = (ids, ray, lane, out, nxt)
        n_free = lane.done.sum()
        c = jax.lax.cond((n_free >= threshold) & (nxt < n), refill_lanes, lambda c: c, c)
        return c + (steps + 1,)

    def cond(c):
        return ~jnp.all(c[2].done)

    ids, ray, lane, out, nxt, steps = jax.lax.while_loop(cond, body, carry)
    return write(out, ids, lane, ids < n), steps


def intersect_closest(bvh: BVH, o: V3, d: V3, t_min=1e-6, t_max=jnp.inf, *,
                      lanes: int = LANES, refill: float = REFILL,
                      mask: Mask | None = None) -> Closest:
    """Nearest triangle hit with t_min < t < t_max for each ray o + t d (V3 of shape [N];
    t_min, t_max scalars or [N]). Returns :class:`Closest` (t, prim, b1, b2) with the input
    triangle index, and t = inf, prim = -1, b1 = b2 = 0 where nothing is hit. ``d`` need not
    be unit length (t is in units of |d|); a zero ``d`` hits nothing. ``lanes`` and ``refill``
    tune the batched loop (see :func:`_trace`) and do not change results; ``mask``: see
    :data:`Mask`. Not differentiable
    (a while loop); differentiate through the hit triangle's own intersection instead."""
    o, d, t_min, t_max = _check_rays(o, d, t_min, t_max)
    (t, tri, b1, b2), _ = _trace(bvh, o, d, t_min, t_max, False, lanes, refill, mask)
    hit = tri >= 0
    return Closest(jnp.where(hit, t, jnp.inf), tri, b1, b2)


def intersect_any(bvh: BVH, o: V3, d: V3, t_min=1e-6, t_max=jnp.inf, *,
                  lanes: int = LANES, refill: float = REFILL, mask: Mask | None = None) -> Array:
    """True where some triangle is hit with t_min < t < t_max (shadow rays). A ray stops at the
    first hit found, which need not be the nearest; ``mask``: see :data:`Mask`."""
    o, d, t_min, t_max = _check_rays(o, d, t_min, t_max)
    return _trace(bvh, o, d, t_min, t_max, True, lanes, refill, mask)[0][1] >= 0
