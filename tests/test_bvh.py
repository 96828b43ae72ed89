"""BVH: tree invariants, and traversal against a float64 brute-force reference.

The reference (numpy, float64) intersects every ray with every triangle by Moller-Trumbore with
the module's acceptance rule (|det| > DET_EPS |d| |e1| |e2|, barycentrics in [0, 1]) and
classifies each ray-triangle pair as clearly hit, clearly missed, or *ambiguous*: within a
margin of a triangle edge (barycentric 1e-4), of the determinant threshold (factor 2) or of
t_min / t_max (relative 1e-5), where float32 rounding may legitimately decide either way. A ray
whose answer an ambiguous pair could change is left out of the exact comparison (and counted:
at most 2% of rays may be left out, so the comparison cannot pass vacuously); on every other
ray, hit/miss, the triangle, t and the barycentrics must agree. Every ray, ambiguous or not,
must produce finite values (t = inf exactly on misses).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jgi.core import bvh as B
from jgi.core.vec import V3

N_RAYS = 1024          # every traversal call uses this many rays and
T_TEST = 5120          # every traversed mesh this many triangles, built with pad=True, so all
                       # share one compilation of each query
LANES = B.LANES
EDGE_MARGIN = 1e-4     # barycentric distance to an edge below which a pair is ambiguous
T_REL = 1e-5           # relative distance to t_min / t_max below which a pair is ambiguous
MAX_AMBIGUOUS = 0.02   # fraction of rays that may be left out of the exact comparison

closest = jax.jit(B.intersect_closest, static_argnames=("lanes", "refill"))
any_hit = jax.jit(B.intersect_any, static_argnames=("lanes", "refill"))


# --- reference ---------------------------------------------------------------------------------

def reference(v0, v1, v2, o, d, t_min, t_max, chunk=256):
    """float64 brute force. Returns dict of per-ray arrays: t, prim, b1, b2 (closest clear hit
    in (t_min, t_max)), ambiguous_t (nearest ambiguous pair's t, inf if none), and for any-hit
    'any' (a clear hit exists) and 'any_ambiguous' (an ambiguous pair exists in the range)."""
    v0, v1, v2 = (np.asarray(a, np.float32).astype(np.float64) for a in (v0, v1, v2))
    e1, e2 = (v1 - v0).astype(np.float32).astype(np.float64), \
        (v2 - v0).astype(np.float32).astype(np.float64)
    o, d = o.astype(np.float64), d.astype(np.float64)
    n = len(o)
    best = np.full(n, np.inf); prim = np.full(n, -1); bb1 = np.zeros(n); bb2 = np.zeros(n)
    amb = np.full(n, np.inf); any_amb = np.zeros(n, bool)
    tmin, tmax = t_min[:, None].astype(np.float64), t_max[:, None].astype(np.float64)
    dlen = np.linalg.norm(d, axis=1)[:, None]
    for s in range(0, len(v0), chunk):
        a, E1, E2 = v0[None, s:s + chunk], e1[None, s:s + chunk], e2[None, s:s + chunk]
        D, O = d[:, None], o[:, None]
        p = np.cross(D, E2)
        det = (E1 * p).sum(-1)
        scale = dlen * np.linalg.norm(E1, axis=-1) * np.linalg.norm(E2, axis=-1)
        ratio = np.abs(det) / np.where(scale > 0, scale, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(ratio > 0, 1.0 / np.where(det != 0, det, 1.0), 0.0)
        tv = O - a
        b1 = (tv * p).sum(-1) * inv
        q = np.cross(tv, E1)
        b2 = (D * q).sum(-1) * inv
        t = (E2 * q).sum(-1) * inv
        margin = np.minimum(np.minimum(b1, b2), 1.0 - b1 - b2)
        tol_lo = T_REL * np.maximum(np.abs(tmin), 1e-3)
        tol_hi = T_REL * np.where(np.isfinite(tmax), np.abs(tmax), 1.0)
        clear = ((ratio > 2 * B.DET_EPS) & (margin > EDGE_MARGIN) & (t > tmin + tol_lo)
                 & (t < tmax - tol_hi))
        out = ((ratio < 0.5 * B.DET_EPS) | (margin < -EDGE_MARGIN) | (t < tmin - tol_lo)
               | (t > tmax + tol_hi))
        ambiguous = ~clear & ~out
        tc = np.where(clear, t, np.inf)
        j = tc.argmin(1)
        tj = tc[np.arange(n), j]
        better = tj < best
        best = np.where(better, tj, best)
        prim = np.where(better, s + j, prim)
        bb1 = np.where(better, b1[np.arange(n), j], bb1)
        bb2 = np.where(better, b2[np.arange(n), j], bb2)
        amb = np.minimum(amb, np.where(ambiguous, t, np.inf).min(1))
        any_amb |= ambiguous.any(1)
    return dict(t=best, prim=prim, b1=bb1, b2=bb2, ambiguous_t=amb, any=prim >= 0,
                any_ambiguous=any_amb)


def check_finite(res):
    t, prim, b1, b2 = (np.asarray(a) for a in res)
    assert not np.isnan(t).any() and not np.isnan(b1).any() and not np.isnan(b2).any()
    assert np.all(np.isfinite(b1)) and np.all(np.isfinite(b2))
    assert np.array_equal(np.isinf(t), prim < 0), "t must be inf exactly on misses"
    assert np.all(t[prim >= 0] > 0)


def tie(tris, o, d, prim, t_ref, tol):
    """Whether triangle ``prim`` of each ray is also hit (float64, within EDGE_MARGIN) at the
    reference distance: coplanar overlapping triangles tie, and either answer is right."""
    v0, v1, v2 = (np.asarray(a, np.float32).astype(np.float64)[prim] for a in tris)
    e1, e2 = v1 - v0, v2 - v0
    o, d = o.astype(np.float64), d.astype(np.float64)
    p = np.cross(d, e2)
    det = (e1 * p).sum(-1)
    inv = 1.0 / np.where(det != 0, det, np.inf)
    tv = o - v0
    q = np.cross(tv, e1)
    b1, b2, t = (tv * p).sum(-1) * inv, (d * q).sum(-1) * inv, (e2 * q).sum(-1) * inv
    inside = np.minimum(np.minimum(b1, b2), 1 - b1 - b2) > -EDGE_MARGIN
    return (det != 0) & inside & (np.abs(t - t_ref) <= tol)


def compare_closest(ref, o, d, res, label, max_ambiguous=MAX_AMBIGUOUS, tris=None):
    """Exact comparison on unambiguous rays; returns (fraction of ambiguous rays, number of
    unambiguous hits). The distance tolerance is float32 rounding (1e-5 relative) of the
    quantities t is computed from: the origin's coordinates and the distance travelled. With
    ``tris``, a different triangle is accepted where it ties (:func:`tie`)."""
    check_finite(res)
    t, prim, b1, b2 = (np.asarray(a) for a in res)
    t_ref = np.where(np.isfinite(ref["t"]), ref["t"], 0.0)
    tol = 1e-5 * (1.0 + t_ref * np.linalg.norm(d, axis=1) + np.abs(o).max(1))
    # rays an ambiguous pair could change: one at or before the clear closest hit
    ambiguous = np.isfinite(ref["ambiguous_t"]) & (ref["ambiguous_t"] <= ref["t"] + tol)
    ok = ~ambiguous
    frac = ambiguous.mean()
    assert frac <= max_ambiguous, f"{label}: {frac:.1%} ambiguous rays, the test is too weak"
    hit = ref["prim"] >= 0
    bad = ok & ((prim >= 0) != hit)
    assert not bad.any(), (f"{label}: hit/miss differs on {bad.sum()} rays, e.g. ray "
                           f"{np.flatnonzero(bad)[0]}: bvh {prim[bad][0]}, ref "
                           f"{ref['prim'][bad][0]} at t {ref['t'][bad][0]}")
    both = ok & hit
    dt = np.abs(t[both] - ref["t"][both])
    assert np.all(dt <= tol[both]), f"{label}: max |dt| {dt.max():.3g}"
    # the same triangle, unless two hits are at the same t (coplanar overlaps)
    same = prim[both] == ref["prim"][both]
    if tris is not None:
        k = np.flatnonzero(both)[~same]
        ties = tie(tris, o[k], d[k], prim[k], ref["t"][k], tol[k])
        assert ties.all(), f"{label}: {np.sum(~ties)} rays hit another triangle"
    else:
        assert same.all(), f"{label}: {np.sum(~same)} rays hit another triangle"
    assert np.all(np.abs(b1[both][same] - ref["b1"][both][same]) < 1e-4)
    assert np.all(np.abs(b2[both][same] - ref["b2"][both][same]) < 1e-4)
    return frac, int(both.sum())


def compare_any(ref, occluded, label, max_ambiguous=MAX_AMBIGUOUS):
    occluded = np.asarray(occluded)
    ok = ~ref["any_ambiguous"] | ref["any"]   # a clear hit decides it even near ambiguity
    assert (~ok).mean() <= max_ambiguous, f"{label}: too many ambiguous rays"
    bad = ok & (occluded != ref["any"])
    assert not bad.any(), f"{label}: any-hit differs on {bad.sum()} rays"
    return int(ref["any"].sum())


# --- scenes ------------------------------------------------------------------------------------

def soup(rng, n=1500, degenerate=0):
    """Random triangles of mixed sizes and shapes (thin slivers included) in [-1, 1]^3."""
    c = rng.uniform(-1, 1, (n, 1, 3))
    size = 10.0 ** rng.uniform(-2.0, -0.5, (n, 1, 1))
    v = c + size * rng.normal(size=(n, 3, 3))
    v = v.astype(np.float32)
    if degenerate:
        k = degenerate
        v[:k // 3, 1] = v[:k // 3, 0]                                     # coincident vertices
        third = v[k // 3:2 * k // 3]
        third[:, 0] = np.round(third[:, 0] * 16) / 16                     # so that these sums
        third[:, 1] = third[:, 0] + np.float32(0.25)                      # exactly collinear:
        third[:, 2] = third[:, 0] + np.float32(0.5)                       # e2 = 2 e1 exactly
        v[2 * k // 3:k, 2] = v[2 * k // 3:k, 1]
    return v[:, 0], v[:, 1], v[:, 2]


def mesh_tris(m):
    f = np.asarray(m.vertices, np.float32)[np.asarray(m.faces)]
    return f[:, 0], f[:, 1], f[:, 2]


def random_rays(rng, n, lo, hi, spread=1.5):
    """Origins in an enlarged box around [lo, hi] (many inside the BVH's boxes), directions
    uniform on the sphere."""
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * spread
    o = (centre + half * rng.uniform(-1, 1, (n, 3))).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    return o, d


def v3(a):
    return V3.of(jnp.asarray(a, jnp.float32))


def run_closest(bvh, o, d, t_min, t_max, **kw):
    return closest(bvh, v3(o), v3(d), jnp.asarray(t_min), jnp.asarray(t_max),
                   lanes=kw.get("lanes", LANES), refill=kw.get("refill", B.REFILL))


def run_any(bvh, o, d, t_min, t_max):
    return any_hit(bvh, v3(o), v3(d), jnp.asarray(t_min), jnp.asarray(t_max), lanes=LANES)


def ray_ranges(rng, n):
    """t_min mostly the default epsilon, some larger; t_max a mix of inf and finite."""
    t_min = np.where(rng.uniform(size=n) < 0.8, 1e-6, rng.uniform(0, 0.5, n)).astype(np.float32)
    t_max = np.where(rng.uniform(size=n) < 0.5, np.inf, rng.uniform(0.2, 3.0, n))
    return t_min, t_max.astype(np.float32)


@pytest.fixture(scope="module")
def soup_case():
    rng = np.random.default_rng(1)
    tris = soup(rng, n=T_TEST)
    return tris, B.build_bvh(*tris, pad=True)


@pytest.fixture(scope="module")
def torus_case():
    tris = mesh_tris(trimesh.creation.torus(1.0, 0.35, major_sections=128, minor_sections=20))
    assert len(tris[0]) == T_TEST
    return tris, B.build_bvh(*tris, pad=True)


@pytest.fixture(scope="module")
def sphere_case():
    tris = mesh_tris(trimesh.creation.icosphere(subdivisions=4))    # 5120 triangles
    assert len(tris[0]) == T_TEST
    return tris, B.build_bvh(*tris, pad=True)


# --- tree invariants ---------------------------------------------------------------------------

def check_tree(bvh: B.BVH, tris):
    """Every triangle in exactly one leaf; boxes contain their children and triangles;
    depth-first layout; traversal tables equal to the tree."""
    count = np.asarray(bvh.count)
    real = count >= 0
    M = int(real.sum())
    assert np.all(real[:M]) and not np.any(real[M:]), "padding must follow the real nodes"
    count, offset = count[:M], np.asarray(bvh.offset)[:M]
    lo = np.asarray(bvh.lo.stack())[:M].astype(np.float64)
    hi = np.asarray(bvh.hi.stack())[:M].astype(np.float64)
    T = len(tris[0])
    prim = np.asarray(bvh.prim)
    assert np.array_equal(np.sort(prim), np.arange(T)), "prim must be a permutation"
    leaf = count > 0
    assert np.all(count[leaf] <= bvh.max_leaf)
    # leaves' ranges partition [0, T), each triangle in exactly one leaf
    cover = np.zeros(T, int)
    for f, c in zip(offset[leaf], count[leaf]):
        cover[f:f + c] += 1
    assert np.all(cover == 1)
    # stored triangles are the input triangles (float32 v0, e1 = v1 - v0, e2 = v2 - v0)
    v0, v1, v2 = (np.asarray(a, np.float32) for a in tris)
    np.testing.assert_array_equal(np.asarray(bvh.v0.stack()), v0[prim])
    np.testing.assert_allclose(np.asarray(bvh.edge1.stack()), (v1 - v0)[prim], rtol=0, atol=1e-6)
    # depth-first: node i + 1 is the first child, offset the second; subtree sizes consistent
    size = np.ones(M, int)
    depth = np.zeros(M, int)
    for i in range(M - 1, -1, -1):
        if not leaf[i]:
            c1, c2 = i + 1, offset[i]
            assert i + 1 < c2 < M
            assert c2 == c1 + size[c1], "second child must follow the first child's subtree"
            size[i] = 1 + size[c1] + size[c2]
    assert size[0] == M
    for i in range(M):
        if not leaf[i]:
            for c in (i + 1, offset[i]):
                depth[c] = depth[i] + 1
                assert np.all(lo[c] >= lo[i]) and np.all(hi[c] <= hi[i]), "child box escapes"
    assert depth.max() < B.STACK_SIZE
    # leaf boxes contain their triangles' vertices (as the test sees them: v0 + e1, v0 + e2)
    sv0 = np.asarray(bvh.v0.stack()).astype(np.float64)
    p1 = sv0 + np.asarray(bvh.edge1.stack())
    p2 = sv0 + np.asarray(bvh.edge2.stack())
    for i in np.flatnonzero(leaf):
        sl = slice(offset[i], offset[i] + count[i])
        for p in (sv0[sl], p1[sl], p2[sl]):
            assert np.all(p >= lo[i]) and np.all(p <= hi[i]), "triangle escapes its leaf"
    # traversal tables: inner rows = both children's boxes and references
    ref = np.where(leaf, -np.cumsum(leaf), np.cumsum(~leaf) - 1)
    inner = np.asarray(bvh.inner)
    for r, i in enumerate(np.flatnonzero(~leaf)):
        c1, c2 = i + 1, offset[i]
        np.testing.assert_array_equal(inner[r, :12], np.concatenate(
            [lo[c1], hi[c1], lo[c2], hi[c2]]).astype(np.float32))
        assert inner[r, 12] == ref[c1] and inner[r, 13] == ref[c2]
    assert int(bvh.root) == ref[0]
    leaves, leaf_tri = np.asarray(bvh.leaves), np.asarray(bvh.leaf_tri)
    for r, i in enumerate(np.flatnonzero(leaf)):
        rows = leaves[r].reshape(bvh.max_leaf, B._SLOT)
        for k in range(bvh.max_leaf):
            if k < count[i]:
                j = offset[i] + k
                assert leaf_tri[r, k] == prim[j]
                np.testing.assert_array_equal(rows[k, :3], sv0[j].astype(np.float32))
            else:
                assert leaf_tri[r, k] == -1 and np.all(rows[k] == 0)
    return depth.max()


@pytest.mark.parametrize("max_leaf", [1, 4, 8])
def test_tree_invariants_soup(max_leaf):
    tris = soup(np.random.default_rng(2), n=700, degenerate=30)
    check_tree(B.build_bvh(*tris, max_leaf=max_leaf), tris)


def test_tree_invariants_mesh_and_padding(torus_case):
    tris, bvh = torus_case
    check_tree(B.build_bvh(*tris), tris)
    T = len(tris[0])
    assert bvh.count.shape == (2 * T - 1,) and bvh.leaves.shape[0] == T   # padded
    check_tree(bvh, tris)


def test_tree_special_cases():
    # one triangle; fewer than a leaf; identical triangles (no separating plane, median
    # splits); a long chain of nested sizes (deep SAH tree, depth limit)
    one = (np.zeros((1, 3)), np.eye(3)[:1], np.eye(3)[1:2])
    check_tree(B.build_bvh(*one), one)
    rng = np.random.default_rng(3)
    few = soup(rng, n=3)
    check_tree(B.build_bvh(*few), few)
    same = tuple(np.repeat(a[:1], 100, axis=0) for a in soup(rng, n=1))
    assert check_tree(B.build_bvh(*same), same) <= 6      # 100 -> 25 leaves by halving
    k = np.arange(3000, dtype=np.float64)
    s = 0.97 ** k                                          # geometric sizes: unbalanced SAH
    chain = (np.stack([s, 0 * s, 0 * s], 1), np.stack([s, s * 0.01, 0 * s], 1),
             np.stack([s, 0 * s, s * 0.01], 1))
    check_tree(B.build_bvh(*chain, max_leaf=1), chain)


def test_build_rejects_bad_input():
    good = soup(np.random.default_rng(4), n=5)
    with pytest.raises(ValueError, match=r"v1 must have shape \[T, 3\]"):
        B.build_bvh(good[0], good[1][:, :2], good[2])
    with pytest.raises(ValueError, match="same shape"):
        B.build_bvh(good[0], good[1][:4], good[2])
    bad = good[0].copy()
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match="v0 has non-finite coordinates .* triangle 2"):
        B.build_bvh(bad, good[1], good[2])
    with pytest.raises(ValueError, match="no triangles"):
        B.build_bvh(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="max_leaf must be in 1..16"):
        B.build_bvh(*good, max_leaf=0)


# --- traversal against brute force -------------------------------------------------------------

def test_closest_and_any_soup(soup_case):
    tris, bvh = soup_case
    rng = np.random.default_rng(10)
    o, d = random_rays(rng, N_RAYS, -1.0, 1.0)
    t_min, t_max = ray_ranges(rng, N_RAYS)
    ref = reference(*tris, o, d, t_min, t_max)
    frac, hits = compare_closest(ref, o, d, run_closest(bvh, o, d, t_min, t_max), "soup")
    assert hits > N_RAYS // 4
    n_occ = compare_any(ref, run_any(bvh, o, d, t_min, t_max), "soup any")
    assert 0 < n_occ < N_RAYS


@pytest.mark.parametrize("case", ["torus_case", "sphere_case"])
def test_closest_and_any_meshes(case, request):
    tris, bvh = request.getfixturevalue(case)
    rng = np.random.default_rng(11)
    lo = np.min([a.min(0) for a in tris], 0)
    hi = np.max([a.max(0) for a in tris], 0)
    o, d = random_rays(rng, N_RAYS, lo, hi, spread=1.3)
    t_min, t_max = ray_ranges(rng, N_RAYS)
    ref = reference(*tris, o, d, t_min, t_max)
    frac, hits = compare_closest(ref, o, d, run_closest(bvh, o, d, t_min, t_max), case)
    assert hits > N_RAYS // 4
    compare_any(ref, run_any(bvh, o, d, t_min, t_max), case + " any")


def test_hit_point_and_lanes_do_not_matter(torus_case):
    """o + t d equals v0 + b1 e1 + b2 e2 of the reported triangle, and the result does not
    depend on the number of lanes or the refill threshold (bit for bit)."""
    tris, bvh = torus_case
    rng = np.random.default_rng(12)
    o, d = random_rays(rng, N_RAYS, np.array([-1.4, -1.4, -0.4]), np.array([1.4, 1.4, 0.4]))
    t_min = np.full(N_RAYS, 1e-6, np.float32)
    t_max = np.full(N_RAYS, np.inf, np.float32)
    res = run_closest(bvh, o, d, t_min, t_max)
    t, prim, b1, b2 = (np.asarray(a) for a in res)
    h = prim >= 0
    v0, v1, v2 = (np.asarray(a, np.float64)[prim[h]] for a in tris)
    p_tri = v0 + b1[h, None] * (v1 - v0) + b2[h, None] * (v2 - v0)
    p_ray = o[h] + t[h, None] * d[h]
    np.testing.assert_allclose(p_ray, p_tri, atol=2e-5)
    assert np.all(b1[h] >= -1e-5) and np.all(b2[h] >= -1e-5) and np.all(b1[h] + b2[h] <= 1 + 1e-5)
    other = B.intersect_closest(bvh, v3(o), v3(d), t_min, t_max, lanes=97, refill=1.0)
    for a, b in zip(res, other):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


N_DEGENERATE = 600


def test_degenerate_triangles_and_axis_aligned_rays():
    """Zero-area triangles (coincident or exactly collinear vertices), axis-aligned triangles
    on a grid, rays with zero direction components (signed zeros included) that run in the
    planes of triangles and of box faces, rays starting inside boxes, zero directions: no NaN,
    agreement with brute force, and degenerate triangles are never hit."""
    rng = np.random.default_rng(13)
    half = T_TEST // 2
    sv0, sv1, sv2 = soup(rng, n=half, degenerate=N_DEGENERATE)
    # axis-aligned right triangles with vertices on a 1/8 grid, in planes x, y or z = const
    g = rng.integers(-8, 8, (half, 3)).astype(np.float32) / 8
    axis = rng.integers(0, 3, half)
    u, w = (axis + 1) % 3, (axis + 2) % 3
    a0 = g.copy()
    a1 = g.copy(); a1[np.arange(half), u] += 0.25
    a2 = g.copy(); a2[np.arange(half), w] += 0.25
    tris = tuple(np.concatenate([s, a]) for s, a in ((sv0, a0), (sv1, a1), (sv2, a2)))
    bvh = B.build_bvh(*tris, pad=True)
    n = N_RAYS
    # directions: coordinate axes with either sign of zero, plus diagonals in coordinate planes
    dirs = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                     [0.0, -0.0, 1], [-0.0, 1, -0.0], [1, 1, 0], [0, -1, 1], [1, 0, -1]],
                    np.float32)
    d = dirs[rng.integers(0, len(dirs), n)]
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    d[d == 0] *= np.where(rng.uniform(size=(d == 0).sum()) < 0.5, 1.0, -1.0)  # +-0
    o = rng.uniform(-1.2, 1.2, (n, 3)).astype(np.float32)
    # half the rays: one or two origin coordinates on the grid (in triangle and box planes)
    on_grid = rng.uniform(size=(n, 3)) < 0.4
    o = np.where(on_grid, np.round(o * 8) / 8, o).astype(np.float32)
    d[:8] = 0.0                                                   # zero directions: miss
    t_min = np.full(n, 1e-6, np.float32)
    t_max = np.where(rng.uniform(size=n) < 0.5, np.inf, 2.0).astype(np.float32)
    res = run_closest(bvh, o, d, t_min, t_max)
    ref = reference(*tris, o, d, t_min, t_max)
    # rays on the grid often run through edges of grid triangles: ambiguous by design
    frac, hits = compare_closest(ref, o, d, res, "degenerate", max_ambiguous=0.3,
                                 tris=tris)
    assert hits > n // 10
    prim = np.asarray(res[1])
    assert np.all(prim[:8] == -1), "a zero direction must hit nothing"
    degenerate = np.zeros(len(tris[0]), bool)
    degenerate[:N_DEGENERATE] = True
    assert not degenerate[prim[prim >= 0]].any(), "a zero-area triangle was hit"
    occ = run_any(bvh, o, d, t_min, t_max)
    assert not np.asarray(occ)[:8].any()
    compare_any(ref, occ, "degenerate any", max_ambiguous=0.3)


def test_t_range_and_self_intersection(sphere_case):
    """Rays leaving the sphere's surface with t_min = 1e-4 do not hit their own triangle;
    t_max just short of the far side turns hits into misses."""
    tris, bvh = sphere_case
    rng = np.random.default_rng(14)
    v0, v1, v2 = (np.asarray(a, np.float64) for a in tris)
    j = rng.integers(0, len(v0), N_RAYS)
    b = rng.dirichlet([1, 1, 1], N_RAYS)
    p = b[:, :1] * v0[j] + b[:, 1:2] * v1[j] + b[:, 2:] * v2[j]
    d = rng.normal(size=(N_RAYS, 3))
    d -= 2 * np.minimum((d * p).sum(1, keepdims=True), 0) * p    # into the sphere
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o, d = p.astype(np.float32), d.astype(np.float32)
    t, prim, _, _ = (np.asarray(a) for a in run_closest(
        bvh, o, d, np.full(N_RAYS, 1e-4, np.float32), np.full(N_RAYS, np.inf, np.float32)))
    # chord length of the unit sphere (faces are slightly inside it): about -2 p.d
    chord = -2 * (p * d).sum(1)
    long = chord > 0.3       # not grazing: the faces' depth below the sphere shifts t < 1e-3
    assert np.all(prim[long] >= 0) and np.all(prim[long] != j[long])
    np.testing.assert_allclose(t[long], chord[long], rtol=0, atol=2e-3)
    short = np.asarray(run_any(bvh, o, d, np.full(N_RAYS, 1e-4, np.float32),
                               (t * 0.999).astype(np.float32)))
    assert not short[long].any()


# --- integration: scenes, geometry queries, rendering --------------------------------------------

def _mesh_scene(tris, bvh=None, **camera):
    from jgi.scene import SceneBuilder

    b = SceneBuilder("mesh", bvh=bvh)
    b.material("m", "diffuse", diffuse=(0.6, 0.6, 0.6))
    T = len(tris[0])
    b.mesh(np.concatenate(tris), np.arange(3 * T).reshape(3, T).T, "m")
    b.camera((0, 1, 3), (0, 0, 0), **camera)
    return b.build()


def test_scene_builds_bvh_by_size_and_geometry_agrees(torus_case):
    """SceneBuilder adds a BVH from BVH_MIN_TRIANGLES triangles on; geometry.intersect,
    closest_hit and occluded then agree with the brute-force scan (t, triangle, normal, shadow
    rays), and so does the gradient of t with respect to the vertices (through
    ``jgi._xla.materialize``, whose derivative is the identity)."""
    import equinox as eqx

    from jgi.physics import geometry as G
    from jgi.scene import BVH_MIN_TRIANGLES, with_bvh

    tris, _ = torus_case
    small = tuple(a[:BVH_MIN_TRIANGLES - 1] for a in tris)
    assert _mesh_scene(small).triangles.bvh is None
    assert _mesh_scene(tuple(a[:BVH_MIN_TRIANGLES] for a in tris)).triangles.bvh is not None
    fast, slow = _mesh_scene(tris), _mesh_scene(tris, bvh=False)
    assert fast.triangles.bvh is not None and slow.triangles.bvh is None
    assert with_bvh(slow).triangles.bvh.node_count == fast.triangles.bvh.node_count
    assert with_bvh(fast, False).triangles.bvh is None

    rng = np.random.default_rng(20)
    o = rng.normal(size=(N_RAYS, 3))
    o = 3 * o / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform([-1.4, -1.4, -0.4], [1.4, 1.4, 0.4], (N_RAYS, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o, d = v3(o), v3(d)
    t_max = jnp.asarray(rng.uniform(1.0, 5.0, N_RAYS), jnp.float32)

    @jax.jit
    def probe(scene):
        def total_t(v0):
            h = G.intersect(eqx.tree_at(lambda s: s.triangles.v0, scene, v0), o, d)
            return jnp.sum(jnp.where(h.valid, h.t, 0.0)), h
        grad, hit = jax.grad(total_t, has_aux=True)(scene.triangles.v0)
        t, kind, idx = G.closest_hit(scene, o, d)
        return hit.t, hit.n.stack(), t, idx, G.occluded(scene, o, d, t_max), grad.stack()

    a, b = (tuple(np.asarray(x) for x in probe(s)) for s in (fast, slow))
    valid = np.isfinite(b[0])
    assert 0.3 < valid.mean() < 0.9
    # rays through a shared edge may report either triangle: allow a handful
    same = (a[3] == b[3])
    assert same.mean() > 0.995
    assert np.array_equal(np.isfinite(a[0]), valid)
    np.testing.assert_allclose(a[0][valid], b[0][valid], rtol=1e-5)
    np.testing.assert_allclose(a[2], a[0])
    np.testing.assert_allclose(a[1][same], b[1][same], atol=1e-6)
    assert (a[4] == b[4]).mean() > 0.995 and 0.1 < a[4].mean() < 0.9
    np.testing.assert_allclose(a[5], b[5], rtol=1e-4, atol=1e-4 * np.abs(b[5]).max())
    assert np.abs(b[5]).max() > 0


def test_tessellated_sphere_renders_like_the_analytic_sphere():
    """A 81,920-triangle icosphere (through the BVH) and an analytic sphere of the same radius,
    side by side and mirror-symmetric under an area light and an environment: the path
    tracer's mean over the mesh's half of the image equals the mirrored sphere half's within
    statistical error (pixels are independent, so the standard error comes from the pixel
    differences), and no sample is NaN. The icosphere's tessellation bias (its faces lie up to
    3e-4 r inside the sphere) is far below that error."""
    import warnings

    import jgi
    from jgi.scene import SceneBuilder

    mesh = trimesh.creation.icosphere(subdivisions=6, radius=0.5)
    assert len(mesh.faces) == 81920
    b = SceneBuilder("spheres")
    b.material("white", "diffuse", diffuse=(0.7, 0.7, 0.7))
    b.material("grey", "diffuse", diffuse=(0.4, 0.4, 0.4))
    b.mesh(mesh.vertices + np.array([-0.6, 0.0, 0.0]), mesh.faces, "white")
    b.sphere((0.6, 0.0, 0.0), 0.5, "white")
    b.quad((-2, -0.5, 2), (4, 0, 0), (0, 0, -4), "grey")                  # floor, facing up
    b.quad((-0.5, 2.0, -0.5), (1, 0, 0), (0, 0, 1), "white", emission=(6, 6, 6))
    b.environment_light((0.3, 0.3, 0.3))
    W, H = 24, 12
    b.camera((0, 0.4, 3.0), (0, 0, 0), width=W, height=H, fov=30)
    scene = b.build()
    assert scene.triangles.bvh is not None and scene.triangles.count == 81920
    with warnings.catch_warnings():
        warnings.simplefilter("error")           # a dropped non-finite sample would warn
        img = jgi.render(scene, "pt", spp=16, seed=3, max_depth=4)
    assert np.all(np.isfinite(img))
    lum = img.mean(axis=2)
    left, right = lum[:, :W // 2], lum[:, W // 2:][:, ::-1]
    diff = (left - right).ravel()
    se = diff.std(ddof=1) / np.sqrt(diff.size)
    assert left.mean() > 0.05 and right.mean() > 0.05
    assert abs(diff.mean()) < 4 * se, (left.mean(), right.mean(), se)
