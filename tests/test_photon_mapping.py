"""Photon density estimation and the photon-mapping estimators."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import cKDTree

import jgi
from jgi.core import transform as xf
from jgi.core.vec import V3
from jgi.scene import SceneBuilder
from jgi.transport import density, hash_grid
from jgi.transport.photons import PhotonMap
from tests.support.stats import critical_t


def plane_photons(rng, n, size=1.0, power=1.0, clustered=False):
    if clustered:
        centers = rng.random((8, 2)) * size
        xy = centers[rng.integers(0, 8, n)] + rng.normal(0, 0.03 * size, (n, 2))
    else:
        xy = rng.random((n, 2)) * size
    z = np.zeros(n)
    f = lambda a: V3(*(np.asarray(c, np.float32) for c in a))
    one = np.ones(n)
    return PhotonMap(f((xy[:, 0], xy[:, 1], z)), f((one * power,) * 3), f((z, z, one)),
                     f((z, z, one)), np.zeros(n, bool), np.zeros(n, np.int32)), xy


def queries(xy):
    n = len(xy)
    return (V3(jnp.asarray(xy[:, 0], jnp.float32), jnp.asarray(xy[:, 1], jnp.float32),
               jnp.zeros(n)),
            V3(jnp.zeros(n), jnp.zeros(n), jnp.ones(n)))


@pytest.mark.parametrize("clustered", [False, True])
def test_knn_and_ball_queries_agree_with_ckdtree(rng_np, clustered):
    pm, xy = plane_photons(rng_np, 20000, clustered=clustered)
    q = rng_np.random((500, 2))
    grid = hash_grid.build_grid(pm, 0.05, cap=128)
    x, n = queries(q)
    g = density.gather(grid, x, n, cap=128)
    assert not np.any(np.asarray(g.truncated))
    tree = cKDTree(xy)
    k = 20
    d_ref, _ = tree.query(q, k=k)
    r2 = np.asarray(density.knn_radius2(g, k, float(grid.cell)))
    have = d_ref[:, -1] < float(grid.cell)  # the k-th neighbour lies within the search radius
    np.testing.assert_allclose(np.sqrt(r2[have] / (1 + 1e-6)), d_ref[have, -1], rtol=1e-4,
                               atol=1e-6)
    rb = 0.9 * float(grid.cell)  # fixed-radius queries see every photon within one cell
    counts = np.asarray(jnp.sum(g.d2 < rb**2, axis=-1))
    ref_counts = np.array([len(c) for c in tree.query_ball_point(q, rb - 1e-6)])
    ref_counts_hi = np.array([len(c) for c in tree.query_ball_point(q, rb + 1e-6)])
    assert np.all((counts >= ref_counts) & (counts <= ref_counts_hi))


def test_a_table_entry_shared_by_neighbour_cells_is_read_once(rng_np):
    """With a table of 16 entries the 27 cells around a query must share entries: each photon
    within the cell size is still gathered exactly once (it was listed once per cell sharing
    its entry, so counted two or three times)."""
    pm, xy = plane_photons(rng_np, 4000)
    q = rng_np.random((300, 2))
    grid = hash_grid.build_grid(pm, 0.05, table_size=16)
    x, n = queries(q)
    g = density.gather(grid, x, n, cap=1024)
    assert not np.any(np.asarray(g.truncated))
    rb = 0.9 * float(grid.cell)
    counts = np.asarray(jnp.sum(g.d2 < rb**2, axis=-1))
    ref_lo = np.array([len(c) for c in cKDTree(xy).query_ball_point(q, rb - 1e-6)])
    ref_hi = np.array([len(c) for c in cKDTree(xy).query_ball_point(q, rb + 1e-6)])
    assert np.all((counts >= ref_lo) & (counts <= ref_hi)), np.max(counts - ref_hi)


def test_neighbour_hash_gives_a_query_block_distinct_entries_and_rows_consecutive_ones():
    """The device grid's linear hash (:func:`hash_grid.neighbour_hash`): for every table size
    VCM uses, the BLOCK^3 cells a query can reach land on distinct entries (so a query reads no
    entry twice), and the cells along x are consecutive entries modulo the table (a row of
    cells is one range), checked on random cells including negative and large coordinates."""
    rng = np.random.default_rng(5)
    ijk = rng.integers(-2**20, 2**20, (2000, 3)).astype(np.int32)
    B = hash_grid.BLOCK
    r = np.arange(B) - B // 2
    off = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    for T in (128, 1024, 1 << 16, 1 << 23):
        h = np.asarray(hash_grid.neighbour_hash(*(jnp.asarray(ijk[:, None, i] + off[:, i])
                                              for i in range(3)), T))
        assert h.min() >= 0 and h.max() < T
        assert all(len(set(row)) == B ** 3 for row in h), T
        step = np.asarray(hash_grid.neighbour_hash(*(jnp.asarray(ijk[:, i] + (i == 0))
                                                     for i in range(3)), T))
        assert np.array_equal(step, (h[:, off.shape[0] // 2] + 1) % T)


@pytest.mark.parametrize("capacity, T", [(None, 1 << 13), (4000, 1 << 13), (1200, 1 << 13),
                                         (1000, 1 << 13), (None, 128)])
def test_device_grid_pairs_list_every_point_within_the_radius_once(rng_np, capacity, T):
    """index_cells + cell_ranges + candidate_pairs / pair_block (VCM's merges, the photon
    gathers): every valid point within the radius of a query is listed exactly once for it, in
    blocks of any size, whether only the valid points are sorted (capacity; about 2,100 valid:
    1200 sorts in the second tier, 2400 keys; 1000 < 2000 < valid: the full sort) or all slots
    are, and in the same order (the valid points' stable order by cell). A table of 128
    entries makes many rows wrap past its end (a row read as two ranges of the sorted
    points)."""
    pm, xy = plane_photons(rng_np, 3000, clustered=True)
    valid = rng_np.random(3000) < 0.7
    radius = 0.03
    cells = hash_grid.index_cells(pm.position, jnp.asarray(valid), jnp.float32(radius), T,
                                  capacity)
    h = np.asarray(hash_grid.neighbour_hash(*hash_grid.cell_of(cells.origin, cells.cell,
                                                              pm.position), T))
    n = int(valid.sum())
    assert n in {1200: range(1201, 2401), 1000: range(2001, 3001)}.get(capacity, [n]), n
    assert np.array_equal(np.asarray(cells.order)[:n],
                          np.flatnonzero(valid)[np.argsort(h[valid], kind="stable")])
    q = rng_np.random((300, 2))
    x, _ = queries(q)
    start, count = hash_grid.cell_ranges(cells, T, x, radius ** 2)
    pairs = hash_grid.candidate_pairs(start, count, cells.n_valid)
    got = []
    for b in range(-(-int(pairs.total) // 1024)):
        qi, slot, ok = (np.asarray(a) for a in hash_grid.pair_block(pairs, 1024, b))
        got += list(zip(qi[ok], np.asarray(cells.order)[slot[ok]]))
    assert len(got) == len(set(got)) == int(pairs.total)       # no pair twice
    assert all(valid[i] for _, i in got)
    tree = cKDTree(xy[valid])
    index = np.flatnonzero(valid)
    near = {(k, int(index[i])) for k, ids in enumerate(tree.query_ball_point(q, radius * 0.999))
            for i in ids}
    assert near and near <= set(got)
    # fewer candidates than the 27 cells around the query's cell hold (the same table): the
    # rows' ranges skip the cells the ball misses
    around = hash_grid.neighbour_hash(*(c[:, None] + hash_grid.NEIGHBOURS[:, i] for i, c in
                                        enumerate(hash_grid.cell_of(cells.origin, cells.cell, x))),
                                      T)
    in_27 = int(np.asarray(cells.count)[np.asarray(around)].sum())
    print(f"candidates {len(got)}, within r {len(near)}, in the 27 cells {in_27}")
    assert len(got) < 0.8 * in_27


@pytest.mark.parametrize("kind, thickness", [("box", None), ("epanechnikov", None),
                                             ("box", 0.004)])
def test_sum_within_takes_every_photon_within_each_radius(rng_np, kind, thickness):
    """density.sum_within (pm's, PPM's and SPPM's gather) against a brute-force sum over all
    photons: clustered photons (cells far fuller than the old per-cell cap of 128), a radius per
    point, photons on the back side (normal away from the point's) left out, points not live
    get 0; with ``thickness``, photons off the plane by more than it too."""
    pm, xy = plane_photons(rng_np, 20000, clustered=True)
    flip = rng_np.random(20000) < 0.2
    z = rng_np.uniform(-0.01, 0.01, 20000) if thickness else np.zeros(20000)
    pm = pm._replace(normal=V3(*(np.where(flip, -c, c).astype(np.float32) for c in pm.normal)),
                     power=V3(*(rng_np.random(20000).astype(np.float32) for _ in range(3))),
                     position=V3(pm.position.x, pm.position.y, z.astype(np.float32)))
    scene = jgi.load_scene("cornell_box", resolution=4)       # diffuse rows for f_r = k_d / pi
    q = np.concatenate([rng_np.random((250, 2)), xy[rng_np.integers(0, 20000, 250)]])
    x, n = queries(q)
    wo = V3(jnp.zeros(500), jnp.zeros(500), jnp.ones(500))
    material = jnp.asarray(rng_np.integers(0, scene.materials.kind.shape[0], 500), jnp.int32)
    r2 = (rng_np.uniform(0.01, 0.05, 500) ** 2).astype(np.float32)
    live = rng_np.random(500) < 0.9
    got, count = density.sum_within(scene, pm, x, n, wo, material, r2, live=live, kind=kind,
                                    thickness=thickness)
    d2 = ((q[:, None, :] - xy[None, :, :]) ** 2).sum(-1) + z[None, :] ** 2
    flat = np.ones(20000, bool) if thickness is None else np.abs(z) <= thickness
    kd = np.stack([np.asarray(c)[np.asarray(material)] for c in scene.materials.diffuse]) / np.pi
    power = np.stack([np.asarray(c) for c in pm.power])

    def reference(scale):     # photons within r^2 scale (float32 decides the ones at the rim)
        inside = (d2 < scale * r2[:, None]) & ~flip[None, :] & flat[None, :] & live[:, None]
        w = np.ones_like(d2) if kind == "box" else np.maximum(1.0 - d2 / r2[:, None], 0.0)
        return kd * np.einsum("qp,cp->cq", inside * w, power), inside.sum(1)

    (lo, n_lo), (hi, n_hi) = reference(1 - 1e-5), reference(1 + 1e-5)
    assert np.all((count >= n_lo) & (count <= n_hi)) and n_lo.max() > 128
    assert np.all((got >= lo * (1 - 2e-5) - 1e-7) & (got <= hi * (1 + 2e-5) + 1e-7))
    assert np.sum(n_hi - n_lo) < 1e-3 * np.sum(n_lo)      # the rim decides a few photons only


@pytest.mark.parametrize("kind, params", [("box", {}), ("cone", dict(k=1.1)), ("cone", dict(k=3.0)),
                                          ("gaussian", dict(gauss_alpha=0.918, gauss_beta=1.953)),
                                          ("epanechnikov", {})])
def test_constant_density_is_estimated_without_bias(rng_np, kind, params):
    n, size, r = 40000, 1.0, 0.04
    pm, _ = plane_photons(rng_np, n, size)
    grid = hash_grid.build_grid(pm, r)
    # independent estimates: query points on a grid spaced > 2r apart, away from the border
    g1 = np.arange(0.1, 0.9, 0.09)
    q = np.stack(np.meshgrid(g1, g1), -1).reshape(-1, 2)
    x, nrm = queries(q)
    est, _ = density.estimate(density.gather(grid, x, nrm, cap=256), jnp.float32(r * r),
                              jnp.float32(1.0), kind, **params)
    e = np.asarray(est.x)
    per_area = n / size**2
    se = e.std(ddof=1) / np.sqrt(len(e))
    assert abs(e.mean() - per_area) < critical_t(len(e) - 1, 1) * se, (kind, e.mean(), per_area, se)


@pytest.mark.parametrize("kind, name", [("gaussian", "gauss_alpha"), ("gaussian", "gauss_beta"),
                                        ("cone", "k"), ("epanechnikov", "r"), ("gaussian", "r")])
def test_gradients_match_central_differences(rng_np, kind, name):
    pm, _ = plane_photons(rng_np, 5000)
    grid = hash_grid.build_grid(pm, 0.1)
    x, n = queries(np.array([[0.5, 0.5], [0.3, 0.6]]))
    g = density.gather(grid, x, n, cap=256)
    base = dict(r=0.08, gauss_alpha=0.918, gauss_beta=1.953, k=1.5)

    def f(v):
        p = dict(base, **{name: v})
        fp = {kk: p[kk] for kk in (("gauss_alpha", "gauss_beta") if kind == "gaussian"
                                   else ("k",) if kind == "cone" else ())}
        L, _ = density.estimate(g, p["r"] ** 2, jnp.float32(1.0), kind, **fp)
        return jnp.sum(L.x)

    # evaluate in float64 so that the finite difference measures the derivative, not rounding
    from jax import enable_x64

    with enable_x64():
        g64 = jax.tree_util.tree_map(
            lambda a: jnp.asarray(a, jnp.float64) if a.dtype == jnp.float32 else a, g)

        def f64(v):
            p = dict(base, **{name: v})
            fp = {kk: p[kk] for kk in (("gauss_alpha", "gauss_beta") if kind == "gaussian"
                                       else ("k",) if kind == "cone" else ())}
            L, _ = density.estimate(g64, p["r"] ** 2, jnp.float64(1.0), kind, **fp)
            return jnp.sum(L.x)

        v0 = jnp.float64(base[name])
        grad = float(jax.grad(f64)(v0))
        h = 1e-5 * float(v0)
        fd = float((f64(v0 + h) - f64(v0 - h)) / (2 * h))
        # radius: the derivative for a fixed photon set; a photon crossing the circle is a jump
        # only if W(r) != 0 (the Gaussian's W(r) > 0): skip FD intervals that contain a crossing
        if name == "r":
            d = np.sqrt(np.asarray(g64.d2))
            crossing = np.any((d > float(v0) - h) & (d < float(v0) + h))
            assert not crossing, "choose another radius: a photon lies within the FD step"
    assert abs(grad - fd) <= 1e-6 * abs(fd) + 1e-6, (grad, fd)


def test_truncation_is_refused_not_estimated(rng_np):
    """A k-nearest gather that would read fewer photons of a cell than it holds raises a named
    error (it would be biased); the default cap reads the fullest cell whole."""
    pm, _ = plane_photons(rng_np, 20000)
    grid = hash_grid.build_grid(pm, 0.2)
    x, n = queries(np.array([[0.5, 0.5]]))
    assert bool(density.gather(grid, x, n, cap=8).truncated[0])
    scene = jgi.load_scene("cornell_box", resolution=4)
    wo, m = V3(*(jnp.ones(1) * c for c in (0.0, 0.0, 1.0))), jnp.zeros(1, jnp.int32)
    args = (scene, grid, x, n, wo, m, 0.2)
    with pytest.raises(density.TruncatedGather, match=r"a grid cell holds \d+ photons, more "
                                                      r"than the 8 read per cell"):
        density.estimate_at_points(*args, cap=8, k=10, kind="box", thickness=None,
                                   filter_params={})
    L = density.estimate_at_points(*args, cap=None, k=10, kind="box", thickness=None,
                                   filter_params={})
    assert np.all(np.isfinite(L)) and L.shape == (3, 1)


def test_photon_mapping_point_light_converges_to_closed_form():
    """Irradiance bias shrinks with r and variance with N r^2: error falls along the sweep."""
    from tests.support.scenes import point_light_reference

    scene = jgi.scenes.point_light_plane(resolution=8, intensity=10.0, height=1.0, albedo=0.5)
    ref = point_light_reference(scene, 0.5, 10.0, 1.0)
    errs = []
    for photons, r in ((20_000, 0.3), (80_000, 0.2), (320_000, 0.12)):
        img = jgi.render(scene, "pm", spp=32, seed=1, photons=photons, radius=r)[..., 0]
        errs.append(float(np.sqrt(np.mean((img - ref) ** 2)) / ref.mean()))
    assert errs[0] > errs[1] > errs[2], errs


def test_photon_mapped_cornell_box_converges_to_path_tracing():
    scene = jgi.scenes.cornell_box(resolution=16)
    ref = np.mean([jgi.render(scene, "pt", spp=128, seed=s) for s in range(4)], 0)
    rel = []
    for photons in (10_000, 40_000, 160_000):
        r = 0.15 * (photons / 10_000) ** (-1 / 6)  # the MSE-optimal rate in 2D
        img = jgi.render(scene, "pm", spp=4, seed=2, photons=photons, radius=r)
        rel.append(float(np.mean((img - ref) ** 2 / (ref**2 + 1e-2))))
    assert rel[0] > rel[1] > rel[2], rel


def test_caustic_appears_only_with_the_caustic_map():
    scene = jgi.scenes.glass_sphere(resolution=24)
    kw = dict(spp=1, seed=0, photons=30_000, caustic_photons=60_000, final_gather=4)
    with_c = jgi.render(scene, "pm_jensen", caustics=True, **kw)
    without = jgi.render(scene, "pm_jensen", caustics=False, **kw)
    diff = (with_c - without).mean(-1)
    assert diff.min() >= -1e-6                      # the caustic map only adds light
    assert diff.max() > 0.5 * without.mean()        # a bright caustic appears
    assert (diff > 0.01 * without.mean()).mean() < 0.25  # and only in a small region


def test_sppm_is_consistent():
    scene = jgi.scenes.cornell_box(resolution=16)
    ref = np.mean([jgi.render(scene, "pt", spp=128, seed=s) for s in range(4)], 0)
    rel = []
    for passes in (1, 6, 36):
        img = jgi.render(scene, "sppm", spp=1, seed=3, passes=passes, photons=10_000,
                         radius=0.15, radius_alpha=0.7)
        rel.append(float(np.mean((img - ref) ** 2 / (ref**2 + 1e-2))))
    assert rel[0] > rel[1] > rel[2], rel
    # any 32-bit seed (a study's derived seeds are large; a pass's seed is taken modulo 2^32)
    big = jgi.render(scene, "sppm", spp=1, seed=2**32 - 1, passes=1, photons=10_000,
                     radius=0.15, radius_alpha=0.7)
    assert np.isfinite(big).all() and big.mean() > 0


def test_photons_on_a_thin_surfaces_far_side_are_not_seen_from_the_near_side():
    """A one-sheet floor lit from below, seen from above: its top receives no light, so every
    estimator renders it black. Photons landing on the underside were once stored with the
    sheet's normal as given (+y), which the top's queries accepted: the top glowed."""
    b = SceneBuilder("lit_from_below")
    b.material("white", "diffuse", diffuse=0.8)
    b.rectangle(xf.rotate([1, 0, 0], -90), "white")           # y = 0, normal +y
    b.point_light((0.0, -0.5, 0.0), (5.0, 5.0, 5.0))
    b.camera((0.0, 2.0, 0.01), (0.0, 0.0, 0.0), fov=30.0, width=8, height=8)
    scene = b.build()
    assert float(jgi.render(scene, "pt", spp=4, seed=0).max()) == 0.0
    for est, kw in (("pm", dict(photons=20_000, radius=0.2)),
                    ("sppm", dict(passes=2, photons=10_000, radius=0.2))):
        img = jgi.render(scene, est, spp=1, seed=0, **kw)
        assert float(img.max()) == 0.0, (est, float(img.max()))


@pytest.mark.parametrize("estimator", ["pm", "ppm", "sppm"])
def test_max_depth_was_renamed_max_bounces(estimator):
    """The photon estimators bound each subpath's surface hits (``max_bounces``); pt's
    ``max_depth`` bounds a whole path's segments, so the old name is refused with the new one."""
    with pytest.raises(jgi.ParameterError,
                       match=f"estimator '{estimator}': parameter 'max_depth' was renamed "
                             "'max_bounces'"):
        jgi.render(jgi.scenes.furnace(resolution=4), estimator, max_depth=4)
