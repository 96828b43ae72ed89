"""Heterogeneous (grid) media: the density lookup, the trackings and the path tracer (issue 34).

* the trilinear lookup against Mitsuba 3's ``gridvolume`` (voxel centres, clamped at the faces);
* ratio tracking's transmittance against exp(-optical depth) along rays through a grid whose
  density is linear in x and y (trilinear interpolation reproduces a linear function, so the
  density along a ray is piecewise linear and its integral exact), and through a constant grid;
* spectral (delta) tracking: the distances of a grey medium by chi-square against the exact
  distribution 1 - exp(-tau(t)) (negative control: a 10% denser medium is rejected), and the
  RGB weights per distance bin against their exact expectations;
* renders: a zero-density grid renders as vacuum bit for bit, a constant grid filling the fog
  box as the homogeneous medium (Welch per region), and jgi's path tracer as Mitsuba 3's
  volpath on an XML scene with a .vol grid (per 3 x 3 region; negative control: scale 10% off
  is rejected); every other estimator that renders grid media against the path tracer in a
  smoke room (light tracing, BDPT, MMLT, VCM; photon mapping against the homogeneous fog);
* the .vol reader, the Mitsuba importer and the TOML loader refuse what they do not support by
  name.
Tolerances: 4.5 measured standard errors (several rays and channels per test), or Welch's test
with both sides' seed spreads.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jgi
from jgi.analysis.chi2 import pearson
from jgi.analysis.stats import region_agreement
from jgi.core import rng
from jgi.core import transform as xf
from jgi.core.errors import ParameterError
from jgi.core.vec import V3
from jgi.physics import grid_media
from jgi.scene import builtin
from jgi.scene.builder import SceneBuilder, majorant_grid
from jgi.scene.importers.volgrid import VolError, read_vol, write_vol
from jgi.scene.tables import GridMedium
from tests.support.media import MITSUBA_FOG_ROOM
from tests.support.stats import mean_change, tells_apart

N = 40_000
LO, HI = np.array([-1.0, -0.5, -0.8]), np.array([1.5, 0.7, 0.4])
SHAPE = (3, 4, 6)                      # nz, ny, nx
A0, AX, AY = 1.0, 0.6, -0.4            # density = A0 + AX x + AY y at the voxel centres
SIGMA = (0.7, 1.3, 2.0)                # RGB extinction per unit density


def _centres(n, lo, hi):
    return lo + (np.arange(n) + 0.5) / n * (hi - lo)


def _ramp_grid():
    nz, ny, nx = SHAPE
    xc, yc = _centres(nx, LO[0], HI[0]), _centres(ny, LO[1], HI[1])
    return np.broadcast_to(A0 + AX * xc[None, None, :] + AY * yc[None, :, None], SHAPE).copy()


def _medium(grid, sigma=SIGMA, albedo=(1.0, 1.0, 1.0), lo=LO, hi=HI, resolution=16,
            border="clamp"):
    f = lambda v: V3(*(jnp.float32(c) for c in v))  # noqa: E731
    grid = np.asarray(grid, np.float32)
    return GridMedium(f(sigma), f(albedo), jnp.float32(0.0), jnp.asarray(grid), f(lo), f(hi),
                      jnp.float32(grid.max()), jnp.asarray(majorant_grid(grid, resolution)),
                      border=border)


def _pbrt_lookup(grid, p):
    """pbrt-v4's SampledGrid::Lookup of the grid [nz, ny, nx] over the box [LO, HI] at points
    p [..., 3], written from its definition: sample coordinates u n - 1/2, trilinear between
    the 8 integer samples around, a sample outside [0, n) giving 0; 0 outside the box (the
    medium's bounds)."""
    u = (p - LO) / (HI - LO)
    n = np.array(grid.shape[::-1])
    s = u * n - 0.5
    i0 = np.floor(s).astype(int)
    d = s - i0
    out = np.zeros(p.shape[:-1])
    for corner in np.ndindex(2, 2, 2):
        i = i0 + np.array(corner)
        ok = np.all((i >= 0) & (i < n), axis=-1)
        c = np.clip(i, 0, n - 1)
        w = np.prod(np.where(np.array(corner) == 1, d, 1 - d), axis=-1)
        out += np.where(ok, w * grid[c[..., 2], c[..., 1], c[..., 0]], 0.0)
    return np.where(np.all((u >= 0) & (u <= 1), axis=-1), out, 0.0)


def _ramp_density(p):
    """The exact density of the ramp grid at points p [..., 3] inside the box: linear between
    the outermost voxel centres, constant beyond them (clamped)."""
    nz, ny, nx = SHAPE
    xc, yc = _centres(nx, LO[0], HI[0]), _centres(ny, LO[1], HI[1])
    return A0 + AX * np.clip(p[..., 0], xc[0], xc[-1]) + AY * np.clip(p[..., 1], yc[0], yc[-1])


def _ramp_depth(o, d, t_max):
    """int_0^t_max density(o + t d) dt (unit d), exactly: the integrand is piecewise linear
    between the box's entry and exit and the planes of the outermost voxel centres, so the
    trapezoid rule over those breakpoints is exact."""
    o, d = np.asarray(o, float), np.asarray(d, float)
    t0, t1 = _box_interval(o, d, t_max)
    if t0 >= t1:
        return 0.0
    nz, ny, nx = SHAPE
    planes = [(0, _centres(nx, LO[0], HI[0])[[0, -1]]), (1, _centres(ny, LO[1], HI[1])[[0, -1]])]
    ts = [t0, t1] + [(c - o[k]) / d[k] for k, cs in planes if d[k] != 0 for c in cs]
    ts = np.array(sorted(t for t in ts if t0 <= t <= t1))
    return float(np.trapezoid(_ramp_density(o + ts[:, None] * d), ts))


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


# (origin, direction, t_max): through the box from outside, from inside to a point inside, along
# x only (two zero direction components), grazing the face y = LO.y, missing the box, length 0
RAYS = [((-2.0, -1.0, -1.5), _unit((3.0, 1.4, 1.6)), np.inf),
        ((0.2, 0.1, -0.3), _unit((-0.5, 0.3, 0.9)), 0.5),
        ((-3.0, 0.2, -0.1), (1.0, 0.0, 0.0), np.inf),
        ((-2.0, -0.5, 0.0), _unit((1.0, 0.0, 0.2)), 6.0),
        ((-2.0, 2.0, 0.0), _unit((1.0, 0.1, 0.0)), np.inf),
        ((0.0, 0.0, 0.0), _unit((1.0, 1.0, 1.0)), 0.0)]


def _lanes(v, n=N):
    return V3(*(jnp.full((n,), c, jnp.float32) for c in v))


def _keys(seed, n=N):
    return rng.path_key(seed, jnp.arange(n, dtype=jnp.uint32), 0)


def _stack(v3):
    return np.stack([np.asarray(c, np.float64) for c in v3], 1)


def _mean_and_error(x):
    x = np.asarray(x, np.float64)
    return x.mean(0), x.std(0, ddof=1) / np.sqrt(len(x))


_ratio = jax.jit(grid_media.ratio_tracking)
_flight = jax.jit(grid_media.sample_free_flight)


def test_density_lookup_matches_mitsuba_gridvolume(tmp_path):
    """Voxel centres at (i + 1/2) / n of the box, trilinear between them, clamped beyond: the
    ramp's exact density inside the box, 0 outside; and Mitsuba 3's own lookup of the same
    .vol file (unit box: to_world maps it onto ours)."""
    rs = np.random.default_rng(5)
    p = LO + rs.random((2000, 3)) * (HI - LO)
    got = np.asarray(grid_media.density(jnp.asarray(_ramp_grid(), jnp.float32), _v3(LO),
                                        _v3(HI), V3(*(jnp.asarray(c, jnp.float32) for c in p.T))))
    np.testing.assert_allclose(got, _ramp_density(p), rtol=2e-5, atol=2e-6)
    outside = np.asarray(grid_media.density(jnp.asarray(_ramp_grid(), jnp.float32), _v3(LO),
                                            _v3(HI), _v3(HI + 0.01)))
    assert outside == 0.0
    from tests.support.mitsuba import load_mitsuba
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    grid = rs.random(SHAPE).astype(np.float32)
    write_vol(tmp_path / "r.vol", grid)
    vol = mi.load_dict({"type": "gridvolume", "filename": str(tmp_path / "r.vol"),
                        "to_world": mi.ScalarTransform4f().translate(LO.tolist())
                        .scale((HI - LO).tolist())})
    pts = p[:200]
    it = mi.Interaction3f()
    if mi.variant().startswith("scalar"):
        theirs = []
        for q in pts:
            it.p = mi.Point3f(*(float(c) for c in q))
            theirs.append(float(vol.eval_1(it)))
    else:
        it.p = mi.Point3f(*(mi.Float(c.astype(np.float32)) for c in pts.T))
        theirs = np.asarray(vol.eval_1(it)).ravel()
    ours = np.asarray(grid_media.density(jnp.asarray(grid), _v3(LO), _v3(HI),
                                         V3(*(jnp.asarray(c, jnp.float32) for c in pts.T))))
    np.testing.assert_allclose(ours, theirs, rtol=1e-5, atol=1e-6)


def _v3(v):
    return V3(*(jnp.float32(c) for c in v))


def test_zero_border_lookup_is_pbrts_sampled_grid():
    """border="zero" is pbrt-v4's grid lookup (:func:`_pbrt_lookup`), at random points and in
    the half-voxel shells by the faces where it and Mitsuba's clamp differ (which they do
    there, and only there)."""
    rs = np.random.default_rng(6)
    grid = rs.random(SHAPE) + 0.2
    h = 0.5 / np.array(SHAPE[::-1]) * (HI - LO)        # half a voxel per axis
    shell = LO + rs.random((1000, 3)) * h                # near the low faces
    p = np.concatenate([LO + rs.random((2000, 3)) * (HI - LO), shell, HI - (shell - LO)])

    def ours(border):
        return np.asarray(grid_media.density(jnp.asarray(grid, jnp.float32), _v3(LO), _v3(HI),
                                             V3(*(jnp.asarray(c, jnp.float32) for c in p.T)),
                                             border))
    np.testing.assert_allclose(ours("zero"), _pbrt_lookup(grid, p), rtol=2e-5, atol=2e-6)
    interior = np.all((p > LO + 2 * h) & (p < HI - 2 * h), axis=-1)
    np.testing.assert_allclose(ours("clamp")[interior], ours("zero")[interior], rtol=1e-6)
    assert np.all(ours("zero")[2000:] < ours("clamp")[2000:])


def test_majorant_grid_bounds_the_density():
    """Each coarse cell's majorant bounds the interpolated density at every point of the cell
    (random points, and points on the cells' faces); resolution 1 is the global max, and the
    resolution is capped by the grid's."""
    rs = np.random.default_rng(8)
    grid = rs.random(SHAPE) ** 3
    g32 = jnp.asarray(grid, jnp.float32)
    for res in (1, 2, 3, 16):
        maj = majorant_grid(grid, res)
        m = np.array(maj.shape[::-1])             # cells along x, y, z
        u = rs.random((20000, 3))
        u[:5000, 0] = np.round(u[:5000, 0] * m[0]) / m[0]     # on cell faces
        p = LO + u * (HI - LO)
        cell = np.clip(np.floor(u * m), 0, m - 1).astype(int)
        dens = np.asarray(grid_media.density(g32, _v3(LO), _v3(HI),
                                             V3(*(jnp.asarray(c, jnp.float32) for c in p.T))))
        bound = maj[cell[:, 2], cell[:, 1], cell[:, 0]]
        assert np.all(dens <= bound * (1 + 1e-6)), res
    assert majorant_grid(grid, 1).shape == (1, 1, 1) and majorant_grid(grid, 1)[0, 0, 0] == \
        np.float32(grid.max())
    assert majorant_grid(grid, 16).shape == SHAPE
    assert majorant_grid(np.full(SHAPE, 0.5), 16).shape == (1, 1, 1)   # uniform: one cell


@pytest.mark.parametrize("grid,resolution", [("ramp", 1), ("ramp", 2), ("ramp", 16),
                                             ("constant", 8), ("pbrt", 2)])
def test_ratio_tracking_transmittance(grid, resolution):
    """E[ratio tracking] = exp(-sigma_c tau) per channel and ray (tau exact, see the module;
    for pbrt-v4's zero border, the trapezoid rule over 20,001 points of the ray in the box),
    with one global majorant, a coarse majorant grid and one majorant per voxel; rays that miss
    the box or have no length give exactly 1."""
    if grid == "ramp":
        medium, depth = _medium(_ramp_grid(), resolution=resolution), _ramp_depth
    elif grid == "pbrt":
        values = _ramp_grid()
        medium = _medium(values, resolution=resolution, border="zero")

        def depth(o, d, t_max):
            t0, t1 = _box_interval(o, d, t_max)
            if t0 >= t1:
                return 0.0
            ts = np.linspace(t0, t1, 20_001)
            pts = np.asarray(o, float) + ts[:, None] * np.asarray(d, float)
            return float(np.trapezoid(_pbrt_lookup(values, pts), ts))
    else:
        medium = _medium(np.full(SHAPE, 0.8), resolution=resolution)
        depth = lambda o, d, t: 0.8 * _clipped_length(o, d, t)  # noqa: E731
    sigma = np.asarray(SIGMA)
    for i, (o, d, t_max) in enumerate(RAYS):
        T = _stack(_ratio(medium, _lanes(o), _lanes(d), jnp.full((N,), t_max, jnp.float32),
                          jnp.ones((N,), bool), _keys(i)))
        assert np.all(np.isfinite(T)) and np.all(T >= 0)
        exact = np.exp(-sigma * depth(o, d, t_max))
        m, e = _mean_and_error(T)
        if np.all(exact == 1.0):
            np.testing.assert_array_equal(T, 1.0)
            continue
        assert np.all(e > 0)
        np.testing.assert_array_less(np.abs(m - exact), 4.5 * e, err_msg=f"ray {i}")
    # a scaled direction: the same segment, t_max in units of the direction's length
    o, d, _ = RAYS[0]
    T = _stack(_ratio(medium, _lanes(o), _lanes(np.asarray(d) * 2.5),
                      jnp.full((N,), 2.0 / 2.5, jnp.float32), jnp.ones((N,), bool), _keys(9)))
    m, e = _mean_and_error(T)
    np.testing.assert_array_less(np.abs(m - np.exp(-sigma * depth(o, d, 2.0))), 4.5 * e)


def _box_interval(o, d, t_max):
    """[t0, t1]: the part of the ray o + t d, 0 <= t <= t_max, inside the grid's box (t0 >= t1
    where it misses)."""
    o, d = np.asarray(o, float), np.asarray(d, float)
    t0, t1 = 0.0, t_max
    for k in range(3):
        if d[k] == 0:
            if not LO[k] <= o[k] <= HI[k]:
                return 0.0, 0.0
            continue
        a, b = sorted(((LO[k] - o[k]) / d[k], (HI[k] - o[k]) / d[k]))
        t0, t1 = max(t0, a), min(t1, b)
    return t0, t1


def _clipped_length(o, d, t_max):
    t0, t1 = _box_interval(o, d, t_max)
    return max(t1 - t0, 0.0)


def _tracked(medium, o, d, t_max, beta=(1.0, 1.0, 1.0), seed=0, n=N):
    f = _flight(medium, _lanes(o, n), _lanes(d, n), jnp.full((n,), t_max, jnp.float32),
                _lanes(beta, n), jnp.ones((n,), bool), _keys(seed, n))
    return np.asarray(f.t, np.float64), np.asarray(f.scattered), _stack(f.weight)


RAY_O, RAY_D, RAY_T = (-2.0, -1.0, -1.5), _unit((3.0, 1.4, 1.6)), 3.6   # t_max inside the box


@pytest.mark.parametrize("resolution", [1, 2, 16])
def test_delta_tracking_distances_chi_square(resolution):
    """A grey ramp medium (sigma_t = 1.5 density): delta tracking's collision distances follow
    P(t' < t) = 1 - exp(-1.5 tau(t)), with P(no collision before t_max) = exp(-1.5 tau(t_max))
    the last category; weights exactly 1 (albedo 1); for a global majorant, a coarse majorant
    grid and one per voxel. Negative control: the same samples against a medium 10% denser are
    rejected."""
    medium = _medium(_ramp_grid(), sigma=(1.5, 1.5, 1.5), resolution=resolution)
    t, hit, w = _tracked(medium, RAY_O, RAY_D, RAY_T, seed=3, n=100_000)
    np.testing.assert_allclose(w, 1.0, rtol=1e-5)
    assert np.all(t[~hit] == np.float32(RAY_T))

    def expected(sigma, edges):
        cdf = 1.0 - np.exp(-sigma * np.array([_ramp_depth(RAY_O, RAY_D, e) for e in edges]))
        return np.append(np.diff(cdf), 1.0 - cdf[-1]) * len(t)

    edges = np.linspace(0.0, RAY_T, 33)
    observed = np.append(np.histogram(t[hit], edges)[0], (~hit).sum())
    r = pearson(observed, expected(1.5, edges))
    assert r.ok(), r.message
    assert not pearson(observed, expected(1.65, edges)).ok(), "no power: 10% denser passed"


@pytest.mark.parametrize("beta,resolution", [((1.0, 1.0, 1.0), 1), ((0.2, 1.0, 3.0), 1),
                                             ((0.2, 1.0, 3.0), 2)])
def test_spectral_tracking_weights(beta, resolution):
    """RGB extinction, one grey majorant: per channel, E[w 1{collision in bin}] =
    albedo_c (F_c(b) - F_c(a)) with F_c = 1 - exp(-sigma_c tau), and E[w 1{no collision}] =
    exp(-sigma_c tau(t_max)), whatever the path throughput that steers the real/null choice."""
    albedo = np.array([0.9, 0.5, 0.8])
    medium = _medium(_ramp_grid(), albedo=albedo, resolution=resolution)
    t, hit, w = _tracked(medium, RAY_O, RAY_D, RAY_T, beta=beta, seed=4)
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    sigma = np.asarray(SIGMA)
    edges = np.linspace(0.0, RAY_T, 7)
    F = 1.0 - np.exp(-np.outer([_ramp_depth(RAY_O, RAY_D, e) for e in edges], sigma))
    for k in range(len(edges) - 1):
        inside = hit & (t >= edges[k]) & (t < edges[k + 1])
        m, e = _mean_and_error(np.where(inside[:, None], w, 0.0))
        exact = albedo * (F[k + 1] - F[k])   # (0 before the box: then no sample either)
        assert np.all(np.abs(m - exact) <= 4.5 * e), f"bin {k}: {m} vs {exact} +- {e}"
    m, e = _mean_and_error(np.where(~hit[:, None], w, 0.0))
    np.testing.assert_array_less(np.abs(m - (1.0 - F[-1])), 4.5 * e)


# a rotated, non-uniformly scaled and moved grid frame, and an ellipsoid / a rotated cube as the
# convex null boundary clipping a grid (Mitsuba's null sphere or cube, pbrt-v4's interface)
FRAME = xf.translate([0.3, -0.2, 0.1]) @ xf.rotate([1.0, 2.0, 0.5], 35.0) @ xf.scale(
    [1.2, 0.8, 1.1])
ELLIPSOID = xf.translate([0.2, 0.1, -0.2]) @ xf.rotate([0.3, 1.0, -0.4], 50.0) @ xf.scale(
    [1.1, 0.45, 0.7])
TILTED_CUBE = xf.translate([0.1, 0.0, -0.1]) @ xf.rotate([1.0, 0.0, 1.0], 30.0) @ xf.scale(
    [0.9, 0.4, 0.5])


def _in_frame(medium, to_world=None, clip=None):
    """``medium`` with its grid frame mapped by ``to_world`` and clipped to ``clip``, (shape,
    unit shape to world), as the builder stores them (world to frame, [3, 4])."""
    inv = lambda m: jnp.asarray(np.linalg.inv(m)[:3], jnp.float32)   # noqa: E731
    return GridMedium(*[getattr(medium, f) for f in ("sigma_t", "albedo", "g", "density", "lo",
                                                     "hi", "majorant", "majorants")],
                      border=medium.border, to_local=None if to_world is None else inv(to_world),
                      clip=None if clip is None else inv(clip[1]),
                      clip_shape="cube" if clip is None else clip[0])


def _clip_chord(shape, to_world, o, d, t0, t1):
    """The length of [t0, t1] inside the unit cube or ball mapped by to_world (float64)."""
    inv = np.linalg.inv(to_world)
    oc, dc = inv[:3, :3] @ np.asarray(o, float) + inv[:3, 3], inv[:3, :3] @ np.asarray(d, float)
    if shape == "sphere":
        a, b, c = dc @ dc, oc @ dc, oc @ oc - 1.0
        disc = b * b - a * c
        if disc <= 0:
            return 0.0
        s0, s1 = (-b - np.sqrt(disc)) / a, (-b + np.sqrt(disc)) / a
    else:
        s0, s1 = -np.inf, np.inf
        for k in range(3):
            if dc[k] == 0:
                if abs(oc[k]) > 1:
                    return 0.0
                continue
            a, b = sorted(((-1 - oc[k]) / dc[k], (1 - oc[k]) / dc[k]))
            s0, s1 = max(s0, a), min(s1, b)
    return max(min(t1, s1) - max(t0, s0), 0.0)


@pytest.mark.parametrize("case", ["frame", "sphere", "cube"])
def test_tracking_in_a_grid_frame_and_a_null_boundary(case):
    """A grid whose box is rotated, sheared by a non-uniform scale and moved (its frame), and a
    constant grid clipped to an ellipsoid or a tilted box (a convex null boundary): ratio
    tracking's transmittance against exp(-sigma_c tau), tau the ramp's exact optical depth
    along the ray mapped into the grid's frame (world distances) or the density times the
    chord through the boundary and the box (float64); rays from outside, from inside, missing;
    grey delta tracking's distances by chi-square against 1 - exp(-tau(t)) (negative control:
    10% denser rejected). A clip or frame ignored, or distances measured in the grid's frame,
    would miss by many standard errors."""
    sigma = np.asarray(SIGMA)
    if case == "frame":
        medium = _in_frame(_medium(_ramp_grid(), resolution=2), to_world=FRAME)
        inv = np.linalg.inv(FRAME)

        def depth(o, d, t_max):   # the ray in the grid's frame, its parameter t unchanged
            return _ramp_depth(inv[:3, :3] @ o + inv[:3, 3], inv[:3, :3] @ d, t_max)
        rays = [(FRAME[:3, :3] @ o + FRAME[:3, 3], _unit(FRAME[:3, :3] @ d), t)
                for o, d, t in (RAYS[0], RAYS[1], RAYS[2], RAYS[4])]
    else:
        shape, to_world = ("sphere", ELLIPSOID) if case == "sphere" else ("cube", TILTED_CUBE)
        medium = _in_frame(_medium(np.full(SHAPE, 0.8), resolution=2), clip=(shape, to_world))

        def depth(o, d, t_max):
            t0, t1 = _box_interval(o, d, t_max)
            return 0.8 * _clip_chord(shape, to_world, o, d, t0, t1) if t0 < t1 else 0.0
        centre = to_world[:3, 3]
        rays = [((-2.0, -1.0, -1.5), _unit(centre - (-2.0, -1.0, -1.5)), np.inf),
                (centre, _unit((-0.5, 0.3, 0.9)), 0.3),
                ((-2.0, 0.6, -1.5), _unit((3.0, 0.0, 1.6)), np.inf),
                ((-2.0, 2.0, 0.0), _unit((1.0, 0.1, 0.0)), np.inf)]
    for i, (o, d, t_max) in enumerate(rays):
        o, d = np.asarray(o, float), np.asarray(d, float)
        T = _stack(_ratio(medium, _lanes(o), _lanes(d), jnp.full((N,), t_max, jnp.float32),
                          jnp.ones((N,), bool), _keys(i)))
        assert np.all(np.isfinite(T)) and np.all(T >= 0)
        tau = depth(o, d, t_max)
        exact, (m, e) = np.exp(-sigma * tau), _mean_and_error(T)
        if tau == 0:
            np.testing.assert_array_equal(T, 1.0, err_msg=f"ray {i} misses")
            continue
        assert tau > 0.05 and np.all(e > 0), f"ray {i}: tau {tau}"
        np.testing.assert_array_less(np.abs(m - exact), 4.5 * e, err_msg=f"ray {i}")
    grey = _in_frame(_medium(_ramp_grid() if case == "frame" else np.full(SHAPE, 0.8),
                             sigma=(1.5, 1.5, 1.5), resolution=2),
                     to_world=FRAME if case == "frame" else None,
                     clip=None if case == "frame" else (shape, to_world))
    o, d, _ = rays[0]
    t_max = 6.0
    t, hit, w = _tracked(grey, o, d, t_max, seed=3, n=100_000)
    np.testing.assert_allclose(w, 1.0, rtol=1e-5)
    edges = np.linspace(0.0, t_max, 25)

    def expected(scale):
        cdf = 1.0 - np.exp(-1.5 * scale * np.array([depth(np.asarray(o), np.asarray(d), x)
                                                    for x in edges]))
        return np.append(np.diff(cdf), 1.0 - cdf[-1]) * len(t)
    observed = np.append(np.histogram(t[hit], edges)[0], (~hit).sum())
    r = pearson(observed, expected(1.0))
    assert r.ok(), r.message
    assert not pearson(observed, expected(1.1)).ok(), "no power: 10% denser passed"


# a second volume for the scene's own medium made of several: a constant grid cut to a ball, to
# the +x side of the ramp grid's box (x in [-1, 1.5]), with albedos of their own
BALL = xf.translate([3.2, 0.1, 0.0]) @ xf.scale(0.7)
ALBEDO_RAMP, ALBEDO_BALL = np.array([0.9, 0.5, 0.8]), np.array([0.3, 0.95, 0.6])


def test_tracking_through_several_volumes():
    """The scene's own medium as two disjoint volumes (the ramp grid, a constant grid cut to a
    ball; ``medium_interfaces.free_flight`` / ``transmittance``), along rays through both in
    either order, and from inside the ball to a point in the ramp: ratio tracking's
    transmittance against exp(-sigma_c (tau_ramp + tau_ball)), and spectral tracking's RGB
    weights per distance bin against albedo_v (F_c(b) - F_c(a)) of the volume v the bin lies in,
    F_c = 1 - exp(-sigma_c tau(t)) through both, and of escapes against 1 - F_c(t_max); the
    throughput that steers the real/null choices is coloured, so the weights of a volume crossed
    before the collision are not 1. (Hand-run negative controls: the crossed volume's weight
    left out, or the other volume's albedo, miss by many standard errors.)"""
    from types import SimpleNamespace

    from jgi.physics import medium_interfaces
    ramp = _medium(_ramp_grid(), albedo=ALBEDO_RAMP, resolution=2)
    ball = _in_frame(_medium(np.full(SHAPE, 0.8), albedo=ALBEDO_BALL, lo=(2.4, -0.7, -0.8),
                             hi=(4.0, 0.9, 0.8)), clip=("sphere", BALL))
    scene = SimpleNamespace(medium=(ramp, ball), bounded_grids=None)
    sigma = np.asarray(SIGMA)
    flight = jax.jit(lambda *a: medium_interfaces.free_flight(scene, None, *a))
    ratio = jax.jit(lambda *a: medium_interfaces.transmittance(scene, None, *a))

    def intervals(o, d, t_max):   # the ray's spans in the ramp's box and in the ball
        (a0, a1), inv = _box_interval(o, d, t_max), np.linalg.inv(BALL)
        oc, dc = inv[:3, :3] @ o + inv[:3, 3], inv[:3, :3] @ d
        b, c = oc @ dc / (dc @ dc), (oc @ oc - 1.0) / (dc @ dc)
        r = np.sqrt(max(b * b - c, 0.0))
        return (a0, a1), (max(-b - r, 0.0), min(-b + r, t_max))

    def depth(o, d, t):   # through both volumes, up to t
        (a0, a1), (b0, b1) = intervals(o, d, t)
        return _ramp_depth(o, d, t) + 0.8 * max(min(b1, t) - b0, 0.0)
    rays = [((-3.0, 0.2, -0.1), (1.0, 0.0, 0.0), np.inf),
            ((5.0, 0.0, 0.1), _unit((-1.0, 0.05, 0.02)), np.inf),
            ((3.2, 0.1, 0.0), (-1.0, 0.0, 0.0), 3.0)]
    beta = (0.2, 1.0, 3.0)
    for i, (o, d, t_max) in enumerate(rays):
        o, d = np.asarray(o, float), np.asarray(d, float)
        spans = intervals(o, d, t_max)
        assert all(a < b for a, b in spans), f"ray {i} misses a volume"
        args = (_lanes(o), _lanes(d), jnp.full((N,), t_max, jnp.float32))
        T = _stack(ratio(*args, jnp.ones((N,), bool), _keys(20 + i)))
        m, e = _mean_and_error(T)
        np.testing.assert_array_less(np.abs(m - np.exp(-sigma * depth(o, d, t_max))), 4.5 * e,
                                     err_msg=f"ray {i}")
        f = flight(*args, _lanes(beta), jnp.ones((N,), bool), _keys(30 + i))
        t, hit, w = np.asarray(f.t, np.float64), np.asarray(f.scattered), _stack(f.weight)
        assert np.all(np.isfinite(w)) and np.all(w >= 0)
        for (a, b), albedo in zip(spans, (ALBEDO_RAMP, ALBEDO_BALL)):
            edges = np.linspace(a, b, 4)
            F = 1.0 - np.exp(-np.outer([depth(o, d, x) for x in edges], sigma))
            for k in range(3):
                inside = hit & (t >= edges[k]) & (t < edges[k + 1])
                m, e = _mean_and_error(np.where(inside[:, None], w, 0.0))
                np.testing.assert_array_less(np.abs(m - albedo * (F[k + 1] - F[k])), 4.5 * e,
                                             err_msg=f"ray {i}, bin {k} of [{a:.2f}, {b:.2f}]")
        m, e = _mean_and_error(np.where(~hit[:, None], w, 0.0))
        np.testing.assert_array_less(np.abs(m - np.exp(-sigma * depth(o, d, t_max))), 4.5 * e,
                                     err_msg=f"ray {i}: escapes")


def test_tracking_in_smaller_batches_changes_no_bit():
    """The trackings gather their live lanes into batches a quarter the size as lanes end
    (grid_media._tracker; 4096 lanes: batches of 4096 and 512): every lane takes the
    same steps and random numbers as in one loop, so flights (distance, event, RGB weight) and
    ratio-tracking transmittances are bit for bit those of one loop, for rays through the
    turned ramp grid from outside and inside, missing it, inactive, with various t_max and
    throughputs."""
    # (the suite tracks in one loop, JGI_TIERED_FROM in tests/conftest.py: this test asks for
    # the smaller batches itself)
    assert grid_media._tiers(4096, 512) == [4096, 512] and grid_media._tiers(1024) == [1024]
    n = 4096
    r = np.random.default_rng(5)
    medium = _in_frame(_medium(_ramp_grid(), resolution=2), to_world=FRAME)
    o = r.normal(size=(n, 3)) * 1.5
    d = r.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    lanes = lambda a: V3(*(jnp.asarray(a[:, i], jnp.float32) for i in range(3)))  # noqa: E731
    t_max = jnp.asarray(np.where(r.uniform(size=n) < 0.3, np.inf, r.uniform(0, 4, n)),
                        jnp.float32)
    active = jnp.asarray(r.uniform(size=n) < 0.9)
    beta = lanes(r.uniform(0, 2, (n, 3)))
    keys = _keys(7, n)
    out = {}
    for floor in (512, 1 << 30):
        f = jax.jit(lambda *a, fl=floor: (grid_media.sample_free_flight(*a, tier_floor=fl),
                                          grid_media.ratio_tracking(*a[:4], *a[5:],
                                                                    tier_floor=fl)))
        out[floor] = [np.asarray(x) for x in jax.tree_util.tree_leaves(
            f(medium, lanes(o), lanes(d), t_max, beta, active, keys))]
    hit = out[512][1]
    assert 0.05 < hit.mean() < 0.95   # lanes end at different times
    for a, b in zip(out[512], out[1 << 30]):
        np.testing.assert_array_equal(a, b)


def test_tracking_edge_cases():
    """Zero density everywhere, a ray missing the box, inactive lanes: no collision, weight 1,
    transmittance 1, all finite."""
    n = 1000
    zero = _medium(np.zeros(SHAPE))
    for medium, (o, d, _) in ((zero, RAYS[0]), (_medium(_ramp_grid()), RAYS[4])):
        t, hit, w = _tracked(medium, o, d, np.inf, n=n)
        assert not hit.any() and np.all(w == 1.0)
        T = _stack(_ratio(medium, _lanes(o, n), _lanes(d, n), jnp.full((n,), np.inf),
                          jnp.ones((n,), bool), _keys(1, n)))
        assert np.all(T == 1.0)
    f = _flight(_medium(_ramp_grid()), _lanes(RAYS[0][0], n), _lanes(RAYS[0][1], n),
                jnp.full((n,), np.inf), _lanes((1, 1, 1), n), jnp.zeros((n,), bool), _keys(2, n))
    assert not np.asarray(f.scattered).any() and np.all(_stack(f.weight) == 1.0)


# --- renders ----------------------------------------------------------------------------------

def _fog_room(medium: str, res=16, sigma=(0.4, 0.7, 0.25), box=30.0):
    """The Cornell box filled with fog: homogeneous, or a constant grid over a box of half-size
    ``box`` around it and the camera (beyond it, transmittance exp(-0.25 * 26) ~ 1e-3 of paths
    leaving the room's open front; their contribution there is negligible)."""
    b = SceneBuilder(f"fog_{medium}")
    builtin.cornell_room(b, res)
    T, R, S = xf.translate, xf.rotate, xf.scale
    b.cube(T([0.335, -0.7, 0.38]) @ R([0, 1, 0], -17) @ S(0.3), "white")
    b.cube(T([-0.33, -0.4, -0.28]) @ R([0, 1, 0], 18.25) @ S([0.3, 0.61, 0.3]), "white")
    if medium == "homogeneous":
        b.medium(sigma_t=sigma, albedo=0.8, g=0.3)
    elif medium == "grid":
        b.grid_medium(np.ones((2, 3, 4)), (-box,) * 3, (box,) * 3, sigma_t=sigma, albedo=0.8,
                      g=0.3)
    elif medium == "zero_grid":
        b.grid_medium(np.zeros((2, 3, 4)), (-1, -1, -1), (1, 1, 1), sigma_t=sigma, albedo=0.8)
    else:
        b.medium(sigma_t=0.0, albedo=0.8)
    return b.build()


def test_zero_density_grid_renders_as_an_empty_medium():
    """Bit for bit: no collision, transmittance 1, the same random numbers per bounce."""
    a = jgi.render(_fog_room("zero_grid", res=8), "pt", spp=8, seed=3, max_depth=5)
    b = jgi.render(_fog_room("empty", res=8), "pt", spp=8, seed=3, max_depth=5)
    assert np.all(np.isfinite(a))
    np.testing.assert_array_equal(a, b)


def test_constant_grid_renders_like_the_homogeneous_medium():
    """Spectral tracking (RGB extinction, grey majorant) and ratio tracking against the
    homogeneous code's spectral MIS and exact transmittance, per 4 x 4 region."""
    stacks = {m: np.stack([jgi.render(_fog_room(m), "pt", spp=64, seed=10 * k + i, max_depth=6)
                           for k in range(8)]) for i, m in enumerate(("homogeneous", "grid"))}
    assert np.all(np.isfinite(stacks["grid"]))
    r = region_agreement(stacks["grid"], stacks["homogeneous"], 4)
    print(f"constant grid vs homogeneous: worst |t| {abs(r.t[r.worst]):.2f} "
          f"(critical {r.critical[r.worst]:.2f})")
    assert r.agree, f"worst t {r.t[r.worst]:.1f} > {r.critical[r.worst]:.1f}"


SMOKE_XML = """<scene version="3.0.0">
  <integrator type="volpath"><integer name="max_depth" value="6"/></integrator>
  <medium type="heterogeneous" id="smoke">
    <volume name="sigma_t" type="gridvolume">
      <string name="filename" value="density.vol"/>
      <transform name="to_world"><scale value="1.6, 1.4, 1.6"/>
        <translate x="-0.8" y="-1.0" z="-0.8"/></transform>
    </volume>
    <rgb name="albedo" value="0.8, 0.6, 0.9"/>
    <float name="scale" value="{scale}"/>
    <phase type="hg"><float name="g" value="0.5"/></phase>
  </medium>
""" + MITSUBA_FOG_ROOM.format(res=24, medium="smoke")


def _smoke_grid():
    """A 7 x 6 x 5 density: a ramp in x, weaker at the top, and a blob (0.3 to 2.6)."""
    z, y, x = np.meshgrid(*(np.linspace(0, 1, n) for n in (5, 6, 7)), indexing="ij")
    blob = np.exp(-((x - 0.5) ** 2 + (y - 0.4) ** 2 + (z - 0.6) ** 2) / 0.05)
    return (0.3 + 1.5 * x * (1 - 0.5 * y) + 0.8 * blob).astype(np.float32)


def test_grid_medium_renders_like_mitsuba_volpath(tmp_path):
    """A heterogeneous medium from a .vol file (box [-0.8, 0.8] x [-1, 0.4] x [-0.8, 0.8] by a
    to_world of scale and translation; the camera, the light and part of the walls outside it)
    attached to the sensor: jgi's path tracer against Mitsuba 3's volpath per 3 x 3 region and
    over the image (Welch, both sides' seed spreads). Negative control: jgi with the medium's
    scale 10% lower (1.35 for 1.5) must fail the per-region test."""
    from jgi.scene.importers import load_mitsuba_xml
    from tests.support.mitsuba import load_mitsuba
    from tests.support.stats import assert_agree

    write_vol(tmp_path / "density.vol", _smoke_grid())
    (tmp_path / "smoke.xml").write_text(SMOKE_XML.format(scale=1.5))
    (tmp_path / "thin.xml").write_text(SMOKE_XML.format(scale=1.35))
    ours = load_mitsuba_xml(tmp_path / "smoke.xml")
    assert ours.has_grid_medium
    np.testing.assert_allclose([float(c) for c in ours.medium.lo], [-0.8, -1.0, -0.8], atol=1e-6)
    np.testing.assert_allclose([float(c) for c in ours.medium.hi], [0.8, 0.4, 0.8], atol=1e-6)
    np.testing.assert_allclose(float(ours.medium.majorant), 1.5 * _smoke_grid().max(), rtol=1e-6)
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    scene_mi = mi.load_file(str(tmp_path / "smoke.xml"))
    seeds = range(10)
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=128, seed=s))[..., :3] for s in seeds])

    def jgi_stack(scene):
        return np.stack([jgi.render(scene, "pt", spp=128, seed=100 + s, max_depth=6, rr_depth=5)
                         for s in seeds])

    mine = jgi_stack(ours)
    assert np.all(np.isfinite(mine))
    t3 = assert_agree(mine, theirs, regions=3, label="jgi pt vs Mitsuba 3 volpath (3 x 3)")
    assert_agree(mine, theirs, regions=1, label="jgi pt vs Mitsuba 3 volpath (whole image)")
    thin = jgi_stack(load_mitsuba_xml(tmp_path / "thin.xml"))
    r = region_agreement(thin, theirs, 3)
    print(f"vs Mitsuba: max |t| {np.abs(t3).max():.2f}; scale 10% off: max |t| "
          f"{np.abs(r.t).max():.2f} (critical {r.critical[r.worst]:.2f})")
    assert not r.agree, "scale 10% off passed: the comparison has no power"


def test_grid_medium_without_nans_where_rays_graze_or_miss():
    """The camera inside the box, on the plane of one face, looking along it; rays leaving the
    box; a grid that is zero over half its voxels: finite images, and light scattered."""
    b = SceneBuilder("graze")
    b.camera((0.0, 1.0, 2.5), (0.0, 1.0, -1.0), fov=50, width=8, height=8)
    b.point_light((0.3, 0.5, 0.0), (3.0, 3.0, 3.0))
    grid = np.zeros((4, 4, 4))
    grid[:, :2] = 2.0
    b.grid_medium(grid, (-1, -1, -1), (1, 1, 1), sigma_t=(1.0, 0.5, 2.0), albedo=0.9, g=-0.3)
    img = jgi.render(b.build(), "pt", spp=16, seed=0, max_depth=4)
    assert np.all(np.isfinite(img)) and img.mean() > 0


# --- files ------------------------------------------------------------------------------------

def test_vol_files_round_trip_and_refusals(tmp_path):
    g = np.arange(24, dtype=np.float32).reshape(2, 3, 4)
    write_vol(tmp_path / "a.vol", g, (1, 2, 3), (4, 5, 6))
    data, lo, hi = read_vol(tmp_path / "a.vol")
    np.testing.assert_array_equal(data[..., 0], g)
    np.testing.assert_array_equal([lo, hi], [(1, 2, 3), (4, 5, 6)])
    raw = (tmp_path / "a.vol").read_bytes()
    cases = {"magic": (b"XYZ" + raw[3:], r"not a Mitsuba volume grid"),
             "version": (raw[:3] + b"\x02" + raw[4:], r"version 2; supported: 3"),
             "encoding": (raw[:4] + b"\x03\x00\x00\x00" + raw[8:], r"encoding 3; supported: 1"),
             "short": (raw[:-4], r"92 bytes of data, expected 96"),
             "header": (raw[:10], r"shorter than a .vol header")}
    for name, (content, message) in cases.items():
        (tmp_path / f"{name}.vol").write_bytes(content)
        with pytest.raises(VolError, match=rf"{name}\.vol: .*{message}"):
            read_vol(tmp_path / f"{name}.vol")


def test_mitsuba_heterogeneous_refusals(tmp_path):
    from jgi.scene.importers import load_mitsuba_xml
    from jgi.scene.importers._common import ImportError_

    write_vol(tmp_path / "density.vol", _smoke_grid())
    write_vol(tmp_path / "rgb.vol", np.ones((2, 2, 2, 3)))
    base = SMOKE_XML.format(scale=1.5)
    vol = '<string name="filename" value="density.vol"/>'
    cases = [
        (base.replace("density.vol", "rgb.vol"), r"3 channels; allowed for sigma_t: 1"),
        (base.replace('<rgb name="albedo" value="0.8, 0.6, 0.9"/>',
                      '<volume name="albedo" type="gridvolume"><string name="filename" '
                      'value="rgb.vol"/></volume>'),
         r"albedo gridvolume: its box .* differs from sigma_t's"),
        (base.replace("density.vol", "missing.vol"), r"volume grid 'missing.vol' does not exist"),
        (base.replace('<scale value="1.6, 1.4, 1.6"/>', '<rotate y="1" angle="30"/>'),
         r"a rotated or sheared gridvolume is taken where a null cube is its very box, or "
         r"where its outermost voxels are 0"),
        (base.replace(vol, vol + '<string name="filter_type" value="nearest"/>'),
         r"filter_type 'nearest' is not supported; allowed: trilinear"),
        (base.replace('type="gridvolume"', 'type="constvolume"'),
         r"volume 'constvolume' is not supported for sigma_t; allowed: gridvolume"),
        (base.replace('<rgb name="albedo" value="0.8, 0.6, 0.9"/>',
                      '<volume name="albedo" type="checkervolume">' + vol + "</volume>"),
         r"albedo volume 'checkervolume' is not supported"),
        (base.replace('<float name="scale"', '<float name="density"'),
         r"unknown parameter 'density'; allowed: sigma_t, albedo, scale"),
    ]
    for i, (xml, message) in enumerate(cases):
        (tmp_path / f"s{i}.xml").write_text(xml)
        with pytest.raises(ImportError_, match=rf"s{i}\.xml.*{message}"):
            load_mitsuba_xml(tmp_path / f"s{i}.xml")
    # a sigma_t given as a constant: that is a homogeneous medium
    const = base.replace(base[base.index("<volume"):base.index("</volume>") + 9],
                         '<float name="sigma_t" value="1"/>')
    (tmp_path / "c.xml").write_text(const)
    with pytest.raises(ImportError_, match=r"c\.xml.*sigma_t must be a <volume"):
        load_mitsuba_xml(tmp_path / "c.xml")
    # use_grid_bbox: the file's box, through to_world
    write_vol(tmp_path / "boxed.vol", _smoke_grid(), (1, 1, 1), (3, 2, 2))
    boxed = base.replace(vol, '<string name="filename" value="boxed.vol"/>'
                              '<boolean name="use_grid_bbox" value="true"/>')
    (tmp_path / "b.xml").write_text(boxed)
    m = load_mitsuba_xml(tmp_path / "b.xml").medium
    np.testing.assert_allclose([float(c) for c in m.lo], [0.8, 0.4, 0.8], atol=1e-6)
    np.testing.assert_allclose([float(c) for c in m.hi], [4.0, 1.8, 2.4], atol=1e-6)


TOML = """name = "grid"
[camera]
position = [0, 0, 4]
look_at = [0, 0, 0]
width = 4
height = 4
medium = "smoke"
[[light]]
type = "point"
position = [0, 3, 0]
intensity = [1, 1, 1]
[[medium]]
name = "smoke"
type = "grid"
"""


def test_toml_grid_medium(tmp_path):
    def load(extra):
        f = tmp_path / "s.toml"
        f.write_text(TOML + extra)
        return jgi.load_scene(f)

    write_vol(tmp_path / "d.vol", _smoke_grid(), (-1, -1, -1), (1, 1, 1))
    m = load('file = "d.vol"\nsigma_t = [1, 2, 3]\nscale = 2\nalbedo = 0.5\ng = 0.2\n').medium
    np.testing.assert_allclose(np.asarray(m.density), 2 * _smoke_grid(), rtol=1e-6)
    np.testing.assert_allclose([float(c) for c in m.lo], -1)
    np.testing.assert_allclose([float(c) for c in m.sigma_t], [1, 2, 3])
    m = load('file = "d.vol"\nbbox_min = [0, 0, 0]\nbbox_max = [2, 1, 1]\n').medium
    np.testing.assert_allclose([float(c) for c in m.hi], [2, 1, 1])
    m = load("density = [[[0, 1], [2, 3]]]\nbbox_min = [-1, -1, -1]\nbbox_max = [1, 1, 1]\n").medium
    assert m.density.shape == (1, 2, 2) and float(m.majorant) == 3.0
    write_vol(tmp_path / "a.vol", np.full((2, 2, 2, 3), 0.25))
    m = load('file = "d.vol"\nalbedo_file = "a.vol"\n').medium
    np.testing.assert_array_equal(np.asarray(m.albedo_grid), 0.25)
    assert m.border == "clamp" and load('file = "d.vol"\nborder = "zero"\n').medium.border == "zero"
    # a turned grid cut to a ball: the frame and the clip as the builder keeps them
    m = load('file = "d.vol"\ntransform = { rotate = { axis = [0, 1, 0], angle = 90 } }\n'
             'clip = "sphere"\nclip_transform = { translate = [0, 0.5, 0], scale = 0.8 }\n').medium
    np.testing.assert_allclose(np.asarray(m.to_local) @ [0, 0, -1, 1], [1, 0, 0], atol=1e-6)
    np.testing.assert_allclose(np.asarray(m.clip) @ [0, 1.3, 0, 1], [0, 1, 0], atol=1e-6)
    assert m.clip_shape == "sphere"
    cases = [
        ('file = "d.vol"\nclip = "sphere"\n', r"medium\[0\].*clip and clip_transform go "
         r"together"),
        ('file = "d.vol"\nclip = "cone"\nclip_transform = { scale = 1 }\n',
         r"medium\[0\]\.clip.*unknown shape 'cone'; allowed: cube, sphere"),
        ('file = "d.vol"\ntransform = { scale = [1, 0, 1] }\n',
         r"medium\[0\]\.transform: the transform is singular"),
        ('file = "d.vol"\nborder = "wrap"\n', r"medium\[0\].*border 'wrap'.*'clamp'.*'zero'"),
        ("", r"medium\[0\].*file .* or density"),
        ('file = "d.vol"\ndensity = [[[1]]]\n', r"medium\[0\].*one of the two"),
        ('file = "nope.vol"\n', r"medium\[0\]\.file.*nope\.vol.*cannot read"),
        ("density = [[[1]]]\n", r"medium\[0\]\.bbox_min.*required with an inline density"),
        ("density = [1, 2]\nbbox_min = [0, 0, 0]\nbbox_max = [1, 1, 1]\n",
         r"medium\[0\]\.density.*\[nz\]\[ny\]\[nx\]"),
        ("density = [[[-1]]]\nbbox_min = [0, 0, 0]\nbbox_max = [1, 1, 1]\n",
         r"medium\[0\].*finite and >= 0"),
        ("density = [[[1]]]\nbbox_min = [0, 0, 0]\nbbox_max = [1, 0, 1]\n",
         r"medium\[0\].*must exceed bbox_min"),
        ('file = "d.vol"\nsigma_a = 1\n', r"medium\[0\]\.sigma_a.*unknown key"),
        ('file = "d.vol"\nalbedo_file = "a.vol"\nalbedo = 1\n', r"medium\[0\].*albedo or "
         r"albedo_file"),
        ('file = "a.vol"\n', r"medium\[0\]\.file.*3 channels; allowed: 1"),
    ]
    for extra, message in cases:
        with pytest.raises(jgi.SceneError, match=r"s\.toml.*" + message):
            load(extra)


def test_estimators_without_media_refuse_grid_media_by_name():
    from jgi.estimators import registry

    scene = _fog_room("zero_grid", res=4)
    for name, est in registry.REGISTRY.items():
        if not est.media:
            with pytest.raises(ParameterError, match=f"'{name}' does not render participating"):
                jgi.render(scene, name, spp=1)
        elif not est.grid_media:   # homogeneous media only (photon maps, ...)
            with pytest.raises(ParameterError, match=f"'{name}' does not render heterogeneous"):
                jgi.render(scene, name, spp=1)


def _sky_grid(scale=1.0):
    """A floor and a red ball under tests.support.environment's sky map (its sun texel a tenth
    as bright: the full one's fireflies take the estimators' seed spreads far from normal), in
    a random 4 x 5 x 6 density grid (0.3 to 1.5) around them, vacuum beyond: light from
    infinity crosses vacuum, then the grid."""
    from tests.support.environment import rotation, sky

    b = SceneBuilder("sky_grid")
    b.material("white", "diffuse", diffuse=0.7)
    b.material("red", "diffuse", diffuse=(0.7, 0.2, 0.2))
    b.sphere((0.0, 0.0, 0.0), 0.8, "red")
    b.quad((-3.0, -0.8, 3.0), (6.0, 0.0, 0.0), (0.0, 0.0, -6.0), "white")
    b.environment_map(sky(sun_rgb=(6.0, 5.0, 4.0)), scale=1.0, to_world=rotation(40.0, 0.0))
    b.camera(position=(0, 3, 1.5), look_at=(0, -0.8, 0), fov=40, width=16, height=16)
    density = (0.3 + 1.2 * np.random.default_rng(1).random((4, 5, 6))) * scale
    b.grid_medium(density, (-2.0, -0.8, -2.0), (1.0, 1.0, 1.5), sigma_t=(0.5, 0.7, 0.9),
                  albedo=0.8, g=0.3)
    return b.build()


def _sky_pt(scene, seed):
    return jgi.render(scene, "pt", spp=64, seed=seed, max_depth=5)


@pytest.fixture(scope="module")
def sky_reference():
    """The path tracer under the sky (16 seeds) and a 60% denser grid's change to its image."""
    ref = np.stack([_sky_pt(_sky_grid(), s) for s in range(16)])
    return ref, mean_change(_sky_pt, _sky_grid(), _sky_grid(1.6))


@pytest.mark.slow
@pytest.mark.parametrize("name, kw", [("bdpt", dict(spp=16))])
def test_bidirectional_estimators_under_an_environment_map_in_a_grid(sky_reference, name, kw):
    """Light from infinity into a bounded grid medium: light subpaths start from the scene's
    bounding disc and track through the grid, a medium vertex reached from the disc has no
    cosine, and the segment from infinity has no distance density in any strategy (as the
    camera subpath that escapes has none for its last). Against the path tracer per 4 x 4
    region (16 seeds a side), with a 60% denser grid's power check. Measured (2026-12-06):
    bdpt worst |t| 2.6, vcm 2.0 (critical 6.5-6.7), offset by the denser grid's change 11.0
    and 10.2 (vcm, 16 spp, not run here for the suite's time: its light subpaths from the disc
    and their connections are BDPT's code, its merges in a grid are checked in the smoke room
    below); with a grid 30% denser, bdpt's offset reached 6.9 against 6.7 and vcm's 6.4
    against 6.5 (no power for vcm in this thin medium at these sample counts, hence 60%). With
    the full sun texel (ten times brighter) mmlt read 2.9 against 6.6 (not run here for the
    suite's time: its evaluation is BDPT's, lane for lane, tests/test_mmlt.py) and light
    tracing 1.9. Before: a medium
    vertex reached from the disc had density 0, the segment a proxy distance density on the
    light side only, and VCM dropped the sky's light subpaths: BDPT read 0.499 and VCM 0.327
    where the path tracer reads 0.381 (|t| 9.5 and 12)."""
    ref, change = sky_reference
    stack = np.stack([jgi.render(_sky_grid(), name, seed=100 + s, max_depth=5, **kw)
                      for s in range(16)])
    assert np.all(np.isfinite(stack))
    r = region_agreement(stack, ref, 4)
    denser = tells_apart(stack, ref, change, 4)
    print(f"{name} vs pt under the sky: worst |t| {np.abs(r.t).max():.2f}; offset by the 60% "
          f"denser grid's change {np.abs(denser.t).max():.2f} (critical "
          f"{r.critical[r.worst]:.2f})")
    assert r.agree, f"{name} vs pt: worst t {r.t[r.worst]:.1f} > {r.critical[r.worst]:.1f}"
    assert not denser.agree, f"{name}: a 60% denser grid's bias passed: no power"


def test_albedo_grid_renders_like_mitsuba_volpath(tmp_path):
    """An RGB albedo gridvolume (3 channels, 5 x 4 x 3 voxels, values in [0.3, 0.95]) over the
    sigma_t grid's box: jgi against Mitsuba 3's volpath per 3 x 3 region. Negative control: the
    albedo grid with its channels reversed must fail."""
    from jgi.scene.importers import load_mitsuba_xml
    from tests.support.mitsuba import load_mitsuba

    albedo = 0.3 + 0.65 * np.random.default_rng(2).random((3, 4, 5, 3))
    write_vol(tmp_path / "density.vol", _smoke_grid())
    write_vol(tmp_path / "albedo.vol", albedo)
    write_vol(tmp_path / "reversed.vol", albedo[..., ::-1])
    box = ('<transform name="to_world"><scale value="1.6, 1.4, 1.6"/>'
           '<translate x="-0.8" y="-1.0" z="-0.8"/></transform>')
    for name in ("albedo", "reversed"):
        (tmp_path / f"{name}.xml").write_text(SMOKE_XML.format(scale=2.0).replace(
            '<rgb name="albedo" value="0.8, 0.6, 0.9"/>',
            f'<volume name="albedo" type="gridvolume"><string name="filename" value="{name}.vol"'
            f'/>{box}</volume>'))
    ours = load_mitsuba_xml(tmp_path / "albedo.xml")
    assert ours.medium.albedo_grid.shape == (3, 4, 5, 3)
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    scene_mi = mi.load_file(str(tmp_path / "albedo.xml"))
    seeds = range(8)
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=96, seed=s))[..., :3] for s in seeds])

    def jgi_stack(scene):
        return np.stack([jgi.render(scene, "pt", spp=96, seed=200 + s, max_depth=6)
                         for s in seeds])

    r = region_agreement(jgi_stack(ours), theirs, 3)
    bad = region_agreement(jgi_stack(load_mitsuba_xml(tmp_path / "reversed.xml")), theirs, 3)
    print(f"albedo grid vs Mitsuba: max |t| {np.abs(r.t).max():.2f}; channels reversed: max |t| "
          f"{np.abs(bad.t).max():.2f} (critical {r.critical[r.worst]:.2f})")
    assert r.agree, f"worst t {r.t[r.worst]:.1f} > {r.critical[r.worst]:.1f}"
    assert not bad.agree, "reversed albedo channels passed: the comparison has no power"


def test_builder_albedo_grid():
    b = SceneBuilder("a")
    b.camera((0, 0, 3), (0, 0, 0), width=4, height=4)
    b.grid_medium(np.ones((2, 2, 2)), albedo=np.full((3, 2, 2), 0.5))
    m = b.build().medium
    assert m.albedo_grid.shape == (3, 2, 2, 3)
    np.testing.assert_array_equal([float(c) for c in m.albedo], 1.0)
    for bad, message in ((np.full((2, 2, 2), 1.5), r"\[0, 1\]"),
                         (np.ones((2, 2, 2, 2)), r"\[nz, ny, nx, 3\]")):
        with pytest.raises(jgi.SceneError, match=message):
            b.grid_medium(np.ones((2, 2, 2)), albedo=bad)


@pytest.mark.slow
def test_pssmlt_renders_a_grid_medium_like_the_path_tracer():
    """PSSMLT over the path tracer's primary samples, the trackings' streams derived from two of
    them (rng.substream): a constant grid filling the fog box, per 3 x 3 region (measured worst
    |t| 1.7)."""
    from jgi.analysis.stats import region_agreement

    scene = _fog_room("grid", res=16)
    mlt = np.stack([jgi.render(scene, "pssmlt", spp=32, seed=k, chains=256,
                               bootstrap_samples=8192, max_depth=6) for k in range(16)])
    pt = np.stack([jgi.render(scene, "pt", spp=32, seed=100 + k, max_depth=6) for k in range(16)])
    r = region_agreement(mlt, pt, 3)
    assert r.agree, f"pssmlt vs pt, grid medium: worst t {r.t[r.worst]:.1f}"


def test_derivatives_with_respect_to_a_grid_medium_are_refused_by_name():
    """A derivative of the path tracer's estimate with respect to a grid medium's parameters
    raises a ParameterError naming them (the trackings have no pathwise derivative; it was
    silently zero), while one with respect to a wall's reflectance, the grid held constant, is
    computed: finite, and positive for the light the walls reflect."""
    import equinox as eqx

    from jgi.estimators.path_tracer import PathTracerConfig, trace_pixels

    scene = _fog_room("grid", res=4)
    cfg = PathTracerConfig(max_depth=3, rr_depth=-1)
    pixel = jnp.tile(jnp.arange(16, dtype=jnp.int32), 4)
    sample = jnp.repeat(jnp.arange(4, dtype=jnp.int32), 16)

    def estimate(sc):
        return trace_pixels(sc, cfg, jnp.uint32(0), pixel, sample).x.mean()

    for where in (lambda s: s.medium.density, lambda s: s.medium.g):
        with pytest.raises(ParameterError, match="grid medium's parameters"):
            jax.grad(lambda k, w=where: estimate(eqx.tree_at(w, scene, w(scene) * k)))(1.0)
    # the subpaths of BDPT, MMLT and light tracing, and VCM's walks, refuse alike (while
    # tracing, before any compile)
    from jgi.estimators import bdpt, vcm

    def bdpt_estimate(sc):
        out = bdpt.contributions(sc, bdpt.BDPTConfig(max_depth=2), 0, pixel, sample)
        return sum(weighted.x.mean() for _, weighted, _ in out.values())

    def vcm_estimate(sc):
        return vcm.iteration_image(sc, vcm.VCMConfig(max_depth=2), jnp.uint32(0), jnp.uint32(0),
                                   jnp.float32(0.1), {}).mean()

    density = lambda s: s.medium.density  # noqa: E731
    for f in (bdpt_estimate, vcm_estimate):
        with pytest.raises(ParameterError, match="grid medium's parameters"):
            jax.grad(lambda k, f=f: f(eqx.tree_at(density, scene, density(scene) * k)))(1.0)
    d = float(jax.jit(jax.grad(lambda k: estimate(eqx.tree_at(   # (one program, not eager ops)
        lambda s: s.materials.diffuse, scene, scene.materials.diffuse * k))))(1.0))
    assert np.isfinite(d) and d > 0


def _smoke_room(scale=1.0, res=16):
    """The Cornell room with one cube, a 7 x 6 x 5 smoke grid in a box around the cube and the
    room's lower middle (vacuum above and around it), RGB extinction, HG g 0.3."""
    b = SceneBuilder("smoke_room")
    builtin.cornell_room(b, res)
    T, R, S = xf.translate, xf.rotate, xf.scale
    b.cube(T([0.335, -0.7, 0.38]) @ R([0, 1, 0], -17) @ S(0.3), "white")
    b.grid_medium(_smoke_grid() * scale, (-0.9, -1.0, -0.9), (0.9, 0.6, 0.9),
                  sigma_t=(0.8, 1.0, 1.3), albedo=0.8, g=0.3)
    return b.build()


def _smoke_pt(scene, seed):
    return jgi.render(scene, "pt", spp=64, seed=seed, max_depth=5)


@pytest.fixture(scope="module")
def smoke_reference():
    """The path tracer in the smoke room (16 seeds), and what a grid 30% denser changes in its
    image (tests.support.stats.mean_change): the reference and the power check of every
    estimator below."""
    ref = np.stack([_smoke_pt(_smoke_room(), s) for s in range(16)])
    return ref, mean_change(_smoke_pt, _smoke_room(), _smoke_room(1.3))


def _agrees_in_the_smoke(name, stack, smoke_reference):
    """``stack`` (16 seeds) against the path tracer per 4 x 4 region and channel (Welch), and
    the power check: offset by the 30% denser grid's change it must fail the same test."""
    ref, change = smoke_reference
    assert np.all(np.isfinite(stack))
    r = region_agreement(stack, ref, 4)
    denser = tells_apart(stack, ref, change, 4)
    print(f"{name} vs pt: worst |t| {np.abs(r.t).max():.2f}; offset by the 30% denser grid's "
          f"change {np.abs(denser.t).max():.2f} (critical {r.critical[r.worst]:.2f})")
    assert r.agree, f"{name} vs pt: worst t {r.t[r.worst]:.1f} > {r.critical[r.worst]:.1f}"
    assert not denser.agree, f"{name}: a 30% denser grid's bias passed: no power"


def test_light_tracing_renders_a_grid_medium_like_the_path_tracer(smoke_reference):
    """Light subpaths tracked through the grid (spectral tracking, phase scattering) and
    splatted through ratio tracking's transmittance agree with the path tracer per 4 x 4 region
    and channel (Welch, 16 seeds a side; measured worst |t| 2.1 against a critical 5.9); the
    power check, a bias as large as a grid 30% denser makes, fails it (the light-traced stack
    offset by the path tracer's change, tests.support.stats.tells_apart: measured 12.1; light
    tracing the denser grid gave 16.6 with the former per-vertex streams)."""
    lt = np.stack([jgi.render(_smoke_room(), "lt", spp=32, seed=100 + s, max_depth=5)
                   for s in range(16)])
    _agrees_in_the_smoke("lt", lt, smoke_reference)


@pytest.mark.slow
@pytest.mark.parametrize("name, kw", [
    ("bdpt", dict(spp=16)),
    ("vcm", dict(spp=8)),
])
def test_bidirectional_estimators_render_a_grid_medium_like_the_path_tracer(
        smoke_reference, name, kw):
    """BDPT, MMLT and VCM in the smoke room (density jumping to 0 at the box's faces, vacuum
    above): subpaths by spectral tracking, every connection and light sample through ratio
    tracking along its shadow ray (jgi.transport.connection.shadow_transmittance), MIS over the
    proxy distance densities of jgi.transport.subpath.segment_density, and VCM's volume merges
    dividing by sigma_s at the light vertex. Against the path tracer per 4 x 4 region and
    channel (Welch, 16 seeds a side), with the 30% denser grid's power check. Measured
    (2026-12-06), worst |t| and the offset stack's against the critical value: bdpt 2.9 and 9.7
    (6.1), mmlt 2.5 and 6.7 (6.2), vcm 2.0 and 7.6 (6.5). MMLT needs 64 spp and 1,024
    chains for that power: with 32 spp and 256 chains its offset reached 7.0 against 7.2 (its
    chains' correlation widens the seeds' spread); it is not run here for the suite's time
    (its strategies are BDPT's lane for lane in a grid medium, tests/test_mmlt.py, and its chains
    are checked in fog, tests/test_media_bidirectional.py). A proxy used inconsistently between
    strategies would bias these images; MMLT's lane-by-lane equality with BDPT in a grid
    (tests/test_mmlt.py) checks the connections' shared streams too."""
    stack = np.stack([jgi.render(_smoke_room(), name, seed=200 + s, max_depth=5, **kw)
                      for s in range(16)])
    _agrees_in_the_smoke(name, stack, smoke_reference)


@pytest.mark.parametrize("name, kw", [
    ("pm", dict(spp=4, photons=50_000, radius=0.1, max_bounces=4))])
def test_photon_estimators_track_a_grid_like_the_homogeneous_medium(name, kw):
    """Photons stored at spectral tracking's collisions (its weight divided by sigma_s(x)) and
    camera chains ending at its collisions give, in a constant grid filling the room, the
    expectation of the same estimator in the equal homogeneous fog, kernel bias included, per
    4 x 4 region (16 seeds a side; measured worst |t| 3.6 against 5.9); a bias as large as a
    grid 15% denser makes (the path tracer's change, tests.support.stats.tells_apart) fails
    it (measured 8.9). ppm and sppm run the same photon and visible-point code (sppm measured
    2.8 against 5.9 at 4 passes of 25,000 photons; not run here for the suite's time).
    (Against the path tracer in the smoke room, whose density jumps to 0 at the box's faces, pm
    at r = 0.1 shows its kernel bias: worst |t| 5.8.)"""
    grid = np.stack([jgi.render(_fog_room("grid"), name, seed=100 + s, **kw) for s in range(16)])
    fog = np.stack([jgi.render(_fog_room("homogeneous"), name, seed=300 + s, **kw)
                    for s in range(16)])
    assert np.all(np.isfinite(grid))
    r = region_agreement(grid, fog, 4)
    assert r.agree, f"{name}: worst t {r.t[r.worst]:.1f} > {r.critical[r.worst]:.1f}"
    # the change as the path tracer sees it in the equal homogeneous fog (the constant-grid
    # test's renders, so its compiled kernel)
    denser = _fog_room("homogeneous", sigma=tuple(1.15 * c for c in (0.4, 0.7, 0.25)))
    change = mean_change(lambda scene, seed: jgi.render(scene, "pt", spp=64, seed=seed,
                                                        max_depth=6),
                         _fog_room("homogeneous"), denser)
    control = tells_apart(grid, fog, change, 4)
    print(f"{name}: worst |t| {np.abs(r.t).max():.2f}; offset by the 15% denser grid's change "
          f"{np.abs(control.t).max():.2f} (critical {r.critical[r.worst]:.2f})")
    assert not control.agree


def test_beam_estimates_refuse_grid_media_by_name():
    with pytest.raises(ParameterError, match="volume='beam'.*grid medium"):
        jgi.render(_smoke_room(res=4), "pm", spp=1, photons=100, volume="beam")
