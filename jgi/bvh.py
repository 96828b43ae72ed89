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
level, not once per node or triangle (10^6 triangles in a few seconds, see
``experiments/bench_bvh.py``).

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

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .vec import V3, cross, dot

NUM_BINS = 16         # SAH bins per axis and node
MAX_LEAF = 4          # default leaf size: triangles tested per leaf visit
STACK_SIZE = 64       # traversal stack entries; the build keeps the tree depth below this
C_TRAV = 1.0          # SAH cost of a node visit, relative to one triangle test (C_isect = 1)
CHUNK = 1024          # rays per batched traversal loop
BARY_EPS = 2.0**-20   # barycentric tolerance (about 1e-6 of the triangle's size)
DET_EPS = 1e-7        # |det| below DET_EPS |d| |e1| |e2| counts as parallel or degenerate
INV_D_MIN = 1e-20     # direction components smaller than this are treated as zero
_GAMMA3 = 3 * 2.0**-24 / (1 - 3 * 2.0**-24)  # pbrt's gamma_3 for float32
_SLAB_WIDEN = np.float32(1 + 2 * _GAMMA3)


class BVH(eqx.Module):
    """A flattened BVH; every array is a pytree leaf, so one compiled traversal serves every
    mesh with the same node and triangle counts (and the same static ``max_leaf``)."""

    lo: V3          # [M] float32 node box minimum
    hi: V3          # [M] float32 node box maximum
    offset: Array   # [M] int32: second child (internal node) or first triangle (leaf)
    count: Array    # [M] int32: triangles in a leaf; 0 for an internal node
    axis: Array     # [M] int32: split axis of an internal node (0, 1, 2); -1 for a leaf
    v0: V3          # [T] float32 first vertex, in leaf order
    edge1: V3       # [T] v1 - v0
    edge2: V3       # [T] v2 - v0
    prim: Array     # [T] int32 input index of each stored triangle
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


def build_bvh(v0, v1, v2, *, max_leaf: int = MAX_LEAF, node_chunk: int = 1 << 15) -> BVH:
    """Binned-SAH BVH over triangles (v0[i], v1[i], v2[i]); arrays of shape [T, 3].

    Leaves hold at most ``max_leaf`` triangles; the depth stays below ``STACK_SIZE`` (near that
    limit, nodes are split at the object median instead, which halves them). ``node_chunk``
    bounds the build's memory (nodes binned at once). Raises ValueError for wrong shapes,
    non-finite vertices, an empty mesh or a leaf size outside 1..16."""
    v0 = _as_vertices("v0", v0)
    v1 = _as_vertices("v1", v1)
    v2 = _as_vertices("v2", v2)
    if not (v0.shape == v1.shape == v2.shape):
        raise ValueError(f"build_bvh: v0, v1, v2 must have the same shape; got {v0.shape}, "
                         f"{v1.shape}, {v2.shape}")
    T = v0.shape[0]
    if T == 0:
        raise ValueError("build_bvh: the mesh has no triangles; at least one is required")
    if T >= 2**30:
        raise ValueError(f"build_bvh: {T} triangles; at most 2^30 are supported (int32 indices)")
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
    n_axis = np.full(cap, -1, np.int64)
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
        n_axis[ids] = np.where(leaf, -1, axis)
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
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    v3 = lambda a: V3(f32(a[:, 0]), f32(a[:, 1]), f32(a[:, 2]))  # noqa: E731
    return BVH(lo=v3(lo), hi=v3(hi),
               offset=jnp.asarray(offset, jnp.int32),
               count=jnp.asarray(n_count[:M][order], jnp.int32),
               axis=jnp.asarray(n_axis[:M][order], jnp.int32),
               v0=v3(p0[perm]), edge1=v3(e1[perm]), edge2=v3(e2[perm]),
               prim=jnp.asarray(perm, jnp.int32), max_leaf=max_leaf)


# --- ray-primitive tests (JAX) ----------------------------------------------------------------

def inverse_direction(d: V3) -> V3:
    """1/d per component, with |d_i| < INV_D_MIN replaced by INV_D_MIN (sign irrelevant: such a
    ray is parallel to that slab for any finite distance), so slab tests never form 0 * inf."""
    return d.map(lambda x: 1.0 / jnp.where(jnp.abs(x) < INV_D_MIN, jnp.float32(INV_D_MIN), x))


def slab(lo: V3, hi: V3, o: V3, inv_d: V3, t_min, t_max) -> tuple[Array, Array]:
    """Ray-box slab test (Kay & Kajiya 1986): (entry distance, hit) for the parameter interval
    (t_min, t_max). The exit distance is widened by 1 + 2 gamma_3 so that float rounding never
    rejects a box the ray touches (pbrt-v4, section 6.8.2)."""
    tx0, tx1 = (lo.x - o.x) * inv_d.x, (hi.x - o.x) * inv_d.x
    ty0, ty1 = (lo.y - o.y) * inv_d.y, (hi.y - o.y) * inv_d.y
    tz0, tz1 = (lo.z - o.z) * inv_d.z, (hi.z - o.z) * inv_d.z
    t_near = jnp.maximum(jnp.maximum(jnp.minimum(tx0, tx1), jnp.minimum(ty0, ty1)),
                         jnp.maximum(jnp.minimum(tz0, tz1), t_min))
    t_far = jnp.minimum(jnp.minimum(jnp.maximum(tx0, tx1), jnp.maximum(ty0, ty1)),
                        jnp.maximum(tz0, tz1)) * _SLAB_WIDEN
    return t_near, t_near <= jnp.minimum(t_far, t_max)


def moller_trumbore(v0: V3, e1: V3, e2: V3, o: V3, d: V3) -> tuple[Array, Array, Array, Array]:
    """Moller & Trumbore 1997: solve o + t d = v0 + b1 e1 + b2 e2 by Cramer's rule,

        det = e1 . (d x e2),  b1 = (o - v0) . (d x e2) / det,
        b2 = d . ((o - v0) x e1) / det,  t = e2 . ((o - v0) x e1) / det.

    Returns (t, b1, b2, inside): ``inside`` is the barycentric test widened by BARY_EPS, and
    false where det^2 <= DET_EPS^2 |d|^2 |e1|^2 |e2|^2 (ray in the triangle's plane, or a
    zero-area triangle); there t, b1, b2 are finite garbage. The t range is the caller's test."""
    pvec = cross(d, e2)
    det = dot(e1, pvec)
    scale = dot(d, d) * dot(e1, e1) * dot(e2, e2)
    ok = det * det > (DET_EPS * DET_EPS) * scale
    inv = 1.0 / jnp.where(ok, det, 1.0)
    tvec = o - v0
    b1 = dot(tvec, pvec) * inv
    qvec = cross(tvec, e1)
    b2 = dot(d, qvec) * inv
    t = dot(e2, qvec) * inv
    inside = ok & (b1 >= -BARY_EPS) & (b2 >= -BARY_EPS) & (b1 + b2 <= 1.0 + BARY_EPS)
    return t, b1, b2, inside


# --- traversal (JAX) -------------------------------------------------------------------------

def _take(v: V3, i) -> V3:
    return V3(v.x[i], v.y[i], v.z[i])


class _Ray(NamedTuple):
    cur: Array       # node to visit next; -1 when done
    cur_t: Array     # its entry distance (skip the visit if beyond the closest hit)
    stack: Array     # [STACK_SIZE] int32 nodes still to visit
    stack_t: Array   # [STACK_SIZE] float32 their entry distances
    sp: Array        # stack size
    t: Array         # closest hit so far (starts at t_max)
    tri: Array       # its stored triangle index, -1 if none
    b1: Array
    b2: Array


def _trace_one(bvh: BVH, o: V3, d: V3, t_min, t_max, any_hit: bool) -> _Ray:
    """One ray's traversal (scalar arrays; vmapped by the callers)."""
    inv_d = inverse_direction(d)
    last_node = bvh.count.shape[0] - 1
    last_tri = bvh.prim.shape[0] - 1
    t0, hit0 = slab(_take(bvh.lo, 0), _take(bvh.hi, 0), o, inv_d, t_min, t_max)
    f32, i32 = jnp.float32, jnp.int32
    init = _Ray(cur=jnp.where(hit0, 0, -1).astype(i32), cur_t=t0,
                stack=jnp.zeros(STACK_SIZE, i32), stack_t=jnp.zeros(STACK_SIZE, f32),
                sp=jnp.zeros((), i32), t=jnp.asarray(t_max, f32), tri=jnp.full((), -1, i32),
                b1=jnp.zeros((), f32), b2=jnp.zeros((), f32))

    def body(r: _Ray) -> _Ray:
        node = r.cur
        visit = r.cur_t <= r.t            # popped nodes beyond the closest hit are skipped
        count, offset = bvh.count[node], bvh.offset[node]
        leaf = visit & (count > 0)
        inner = visit & (count == 0)

        # Leaf: test its triangles (a fixed max_leaf, masked, so lanes stay in step).
        t, tri, b1, b2 = r.t, r.tri, r.b1, r.b2
        for k in range(bvh.max_leaf):
            j = jnp.minimum(offset + k, last_tri)
            tk, b1k, b2k, inside = moller_trumbore(_take(bvh.v0, j), _take(bvh.edge1, j),
                                                   _take(bvh.edge2, j), o, d)
            hit = leaf & (k < count) & inside & (tk > t_min) & (tk < t)
            t = jnp.where(hit, tk, t)
            tri = jnp.where(hit, j, tri)
            b1 = jnp.where(hit, b1k, b1)
            b2 = jnp.where(hit, b2k, b2)

        # Internal node: slab-test both children, go to the nearer, push the farther.
        c1 = jnp.minimum(node + 1, last_node)
        c2 = jnp.minimum(offset, last_node)
        tn1, h1 = slab(_take(bvh.lo, c1), _take(bvh.hi, c1), o, inv_d, t_min, t)
        tn2, h2 = slab(_take(bvh.lo, c2), _take(bvh.hi, c2), o, inv_d, t_min, t)
        h1, h2 = h1 & inner, h2 & inner
        second_first = h2 & (~h1 | (tn2 < tn1))
        near, near_t = jnp.where(second_first, c2, c1), jnp.where(second_first, tn2, tn1)
        far, far_t = jnp.where(second_first, c1, c2), jnp.where(second_first, tn1, tn2)
        both = h1 & h2
        slot = jnp.minimum(r.sp, STACK_SIZE - 1)  # the build bounds the depth; clamp anyway
        stack = r.stack.at[slot].set(far)         # harmless above the top when not pushed
        stack_t = r.stack_t.at[slot].set(far_t)
        sp = r.sp + both.astype(i32)

        # Next node: the nearer child, else the top of the stack, else done.
        go_down = h1 | h2
        top = jnp.maximum(sp - 1, 0)
        cur = jnp.where(go_down, near, jnp.where(sp > 0, stack[top], -1))
        cur_t = jnp.where(go_down, near_t, stack_t[top])
        sp = jnp.where(go_down, sp, jnp.maximum(sp - 1, 0))
        if any_hit:
            cur = jnp.where(tri >= 0, -1, cur)
        return _Ray(cur, cur_t, stack, stack_t, sp, t, tri, b1, b2)

    return jax.lax.while_loop(lambda r: r.cur >= 0, body, init)


def _broadcast(o: V3, d: V3, t_min, t_max):
    shape = jnp.shape(o.x)
    if len(shape) != 1:
        raise ValueError(f"rays must be V3 of shape [N]; got origin shape {shape}")
    for name, v in (("d", d),):
        for c in v:
            if jnp.shape(c) != shape:
                raise ValueError(f"{name} components must have shape {shape}; got {jnp.shape(c)}")
    f = lambda a: jnp.broadcast_to(jnp.asarray(a, jnp.float32), shape)  # noqa: E731
    return (V3(*map(f, o)), V3(*map(f, d)), f(t_min), f(t_max))


def _chunked(fn, args, chunk: int):
    """Apply a vmapped ``fn`` to rays in chunks of ``chunk`` (padded), one chunk at a time."""
    n = jnp.shape(args[0].x)[0]
    chunk = max(1, min(int(chunk), n))
    pad = (-n) % chunk
    flat, treedef = jax.tree_util.tree_flatten(args)
    # padding rays repeat ray 0 (valid input; results dropped)
    flat = [jnp.concatenate([a, jnp.broadcast_to(a[:1], (pad,))]) if pad else a for a in flat]
    flat = [a.reshape(-1, chunk) for a in flat]
    out = jax.lax.map(lambda xs: jax.vmap(fn)(*jax.tree_util.tree_unflatten(treedef, xs)), flat)
    return jax.tree_util.tree_map(lambda a: a.reshape(-1)[:n], out)


def intersect_closest(bvh: BVH, o: V3, d: V3, t_min=1e-6, t_max=jnp.inf, *,
                      chunk: int = CHUNK) -> Closest:
    """Nearest triangle hit with t_min < t < t_max for each ray o + t d (V3 of shape [N];
    t_min, t_max scalars or [N]). Returns :class:`Closest` (t, prim, b1, b2) with the input
    triangle index, and t = inf, prim = -1 where nothing is hit. ``d`` need not be unit length
    (t is in units of |d|) but must not be zero."""
    o, d, t_min, t_max = _broadcast(o, d, t_min, t_max)

    def one(o, d, t_min, t_max):
        r = _trace_one(bvh, o, d, t_min, t_max, any_hit=False)
        hit = r.tri >= 0
        return Closest(jnp.where(hit, r.t, jnp.inf), jnp.where(hit, bvh.prim[r.tri], -1),
                       jnp.where(hit, r.b1, 0.0), jnp.where(hit, r.b2, 0.0))

    return _chunked(one, (o, d, t_min, t_max), chunk)


def intersect_any(bvh: BVH, o: V3, d: V3, t_min=1e-6, t_max=jnp.inf, *,
                  chunk: int = CHUNK) -> Array:
    """True where some triangle is hit with t_min < t < t_max (shadow rays). Stops at the first
    hit found, which need not be the nearest."""
    o, d, t_min, t_max = _broadcast(o, d, t_min, t_max)

    def one(o, d, t_min, t_max):
        return _trace_one(bvh, o, d, t_min, t_max, any_hit=True).tri >= 0

    return _chunked(one, (o, d, t_min, t_max), chunk)
