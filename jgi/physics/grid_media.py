"""Heterogeneous participating media on a density grid: null-scattering tracking.

The medium (:class:`jgi.scene.tables.GridMedium`) is a density grid d[nz, ny, nx] over a box
[lo, hi] of the grid's frame (the world's, or an affine image of it: a rotated grid), with
extinction per RGB channel

    sigma_t,c(x) = d(x) sigma_t,c^0,     sigma_s,c(x) = rho_c sigma_t,c(x),

a single-scattering albedo rho (constant, or times an RGB albedo grid over the same box,
interpolated alike) and a Henyey-Greenstein phase function; outside the box the density is 0
(vacuum), and so it is outside the medium's convex null boundary where it has one (a cube or
sphere under an affine map: Mitsuba's shape with a ``null`` bsdf, pbrt-v4's ``interface``; a
homogeneous medium in a null sphere is a constant grid clipped to the sphere). Box and boundary
are convex, so a ray meets the medium in one interval (:func:`extent`) and the trackings below
run over it alone, in the grid's frame with the world's distances. d(x) interpolates the grid
trilinearly with Mitsuba 3's ``gridvolume`` convention: the box's unit coordinates u in [0, 1]^3
map to the continuous index u n - 1/2 (voxel centres at (i + 1/2) / n), clamped to [0, n - 1]
per axis, so the density is constant between the box's faces and the outermost voxel centres
(Dr.Jit's texture lookup with the clamp wrap mode, checked against
``mi.load_dict({'type': 'gridvolume', ...}).eval``).

Null scattering (Woodcock tracking; Miller, Georgiev and Jarosz 2019; Mitsuba 3's volpath,
pbrt-v4): with a majorant mu >= sigma_t,c(x) for every channel and point of the box, the
fictitious "null" extinction sigma_n,c = mu - sigma_t,c >= 0 makes the medium homogeneous with
extinction mu, whose free flights are exponential. jgi's majorant is grey (one for all
channels) and piecewise constant: mu = M_k max_c sigma_t,c^0 in cell k of a coarse grid over
the box, M_k the density's max over the cell (:func:`jgi.scene.builder.majorant_grid`,
precomputed when the scene is built; 8^3 cells by default, 1: the global max). Flights cross
the cells by a DDA and restart their exponential distance at each cell's exit (exact, by
memorylessness; cells of majorant 0 are skipped). It uses the channel-free **spectral
tracking** of Kutz, Habel, Li and Novak 2017 (section 5): a
tentative collision at t ~ mu exp(-mu t) is real with probability P_r and null with 1 - P_r,
and the path's RGB weight is multiplied by

    sigma_s,c(x) / (mu P_r)          at a real collision (the path scatters there),
    sigma_n,c(x) / (mu (1 - P_r))    at a null collision (it flies on),

and by 1 when the flight leaves the box or reaches the surface. Each factor is the ratio of a
channel's integrand (its collision equation's real or null term) to the probability of the
choice made, so the estimator is unbiased in every channel for any P_r in (0, 1) that is
positive wherever the chosen event's coefficient is (Kutz et al. eq. 19). jgi takes the
history-aware choice

    P_r = sum_c b_c sigma_t,c(x) / (mu sum_c b_c),     b = the path throughput times the weight,

so channels that carry the path decide (uniform weights when b is zero); in a grey medium it is
sigma_t / mu and every weight is exactly 1 or the albedo (plain delta tracking, what Mitsuba's
volpath does with a grey sigma_t). Absorption is not an event: as in the homogeneous code the
real collision always scatters, weighted by the albedo.

Transmittance along a shadow ray (next-event estimation) is estimated by **ratio tracking**
(Novak, Selle and Jarosz 2014): tentative collisions at the same majorant, the estimate the
product of sigma_n,c(x_i) / mu over those before the segment's end; unbiased per channel.

Both trackings are one ``jax.lax.while_loop`` over the lanes (:func:`_tracker`), an iteration
a tentative collision or a cell crossing, running until every lane has left the box or
scattered: the number of tentative collisions is Poisson with mean the majorant's integral
along the ray, finite with probability 1 (no cap, so no truncation bias;
:meth:`jgi.scene.builder.SceneBuilder.grid_medium` refuses majorants whose expected collisions
per crossing of the box exceed ``jgi.scene.builder.MAX_OPTICAL_DEPTH``). The random numbers of
a flight are a stream of their own (:func:`jgi.core.rng.substream` of the bounce's two
free-flight numbers), two per tentative collision. Grid media are rendered, not
differentiated: the tracking runs on stop_gradient'ed parameters (its collision decisions have
no pathwise derivative), so a render refuses, by name, to be differentiated with respect to a
grid medium's parameters (:func:`differentiated`, checked by ``jgi.render``) rather than
returning a derivative of zero; derivatives with respect to the rest of the scene, the grid held
constant, are computed as usual.

Cost: a batch's loop runs as long as its longest tracking, so what the majorant grid saves is
the longest lane's tentative collisions, against the crossings it adds. Measured on a 32^3
cloud (haze 0.05, a blob of 12) in the Cornell room, 4096 random rays in the box: 62 loop trips
with the global majorant, 36 with 4^3 or 8^3 cells, 51 with 16^3, 87 with 32^3 (mean tentative
collisions per ray 15.5, 1.8, 0.8, 0.5, 0.3); the path tracer at 32 x 32, 256 spp, max_depth 8
on two loaded CPU cores took 6.7-7.7 s with the global majorant and 3.2-3.5 s with 8^3 cells
(docs/performance.md#grid-media).
"""

from __future__ import annotations

import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from ..core import rng
from ..core.errors import ParameterError
from ..core.vec import V3, dot
from ..core.vec import length as length_of


def differentiated(medium) -> bool:
    """Whether a derivative is being traced with respect to some float of ``medium``: one of its
    leaves is a forward-mode or linearisation tracer carrying a tangent (``jax.grad``,
    ``jax.jvp`` and their kin over a function that builds the scene from the parameters)."""
    for leaf in jax.tree_util.tree_leaves(medium):
        tangent = getattr(leaf, "tangent", None) if isinstance(leaf, jax.core.Tracer) else None
        if tangent is not None and type(tangent).__name__ != "Zero":
            return True
    return False


def held_constant(medium):
    """The grid medium as the trackings use it: every leaf a constant for derivatives (they
    have no pathwise derivative; see the module and :func:`refuse_derivatives`)."""
    return jax.tree_util.tree_map(jax.lax.stop_gradient, medium)


def refuse_derivatives(medium) -> None:
    """A :class:`jgi.core.errors.ParameterError` if a derivative is being traced with respect to
    some float of ``medium`` (``jax.grad``, ``jax.jvp`` and their kin over a function that puts
    the parameter into the scene: one of its leaves is then a tracer carrying a tangent). Call
    it where the scene enters the estimator, outside loops (whose bodies JAX traces before it
    differentiates them)."""
    for leaf in jax.tree_util.tree_leaves(medium):
        tangent = getattr(leaf, "tangent", None) if isinstance(leaf, jax.core.Tracer) else None
        if tangent is not None and type(tangent).__name__ != "Zero":
            raise ParameterError(
                "derivatives with respect to a grid medium's parameters (density, sigma_t, "
                "albedo, g, box) are not computed: its null-scattering trackings have no "
                "pathwise derivative, so they would come out zero. Hold the grid medium "
                "constant (differentiate a function that puts only the parameters you fit into "
                "the scene, e.g. with equinox.tree_at), or use a homogeneous medium, whose "
                "sigma_t, albedo and g are differentiable")


def density(grid: Array, lo: V3, hi: V3, p: V3, border: str = "clamp") -> Array:
    """The trilinearly interpolated density at points p, voxel centres at (i + 1/2) / n of the
    box; 0 outside the box [lo, hi]. Between a face and the outermost voxel centres the density
    is that of the outermost voxels (``border="clamp"``: Mitsuba 3's gridvolume) or falls
    linearly towards 0 at a sample half a voxel beyond the face (``"zero"``: pbrt-v4's
    SampledGrid, whose lookups outside the samples give 0)."""
    nz, ny, nx = grid.shape
    zero = border == "zero"
    inside = None
    idx, frac, valid = [], [], []
    for pc, lc, hc, n in zip(p, lo, hi, (nx, ny, nz)):
        ext = hc - lc
        u = (pc - lc) / jnp.where(ext > 0, ext, 1.0)
        ok = (u >= 0.0) & (u <= 1.0)
        inside = ok if inside is None else inside & ok
        if zero:   # corners i0 and i0 + 1 in [-1, n]; those outside [0, n - 1] weigh 0
            f = jnp.clip(u * n - 0.5, -0.5, n - 0.5)
            i0 = jnp.floor(f).astype(jnp.int32)
            frac.append(f - i0.astype(f.dtype))
            valid.append(((i0 >= 0), (i0 + 1 <= n - 1)))
            idx.append(i0)
            continue
        f = jnp.clip(u * n - 0.5, 0.0, n - 1.0)
        i0 = jnp.clip(jnp.floor(f), 0.0, max(n - 2, 0)).astype(jnp.int32)
        idx.append(i0)
        frac.append(jnp.where(n > 1, f - i0.astype(f.dtype), 0.0))
    (ix, iy, iz), (fx, fy, fz) = idx, frac
    flat = grid.reshape(-1)
    value = 0.0
    if zero:
        (vx, vy, vz) = valid
        for dz, wz, okz in ((0, 1.0 - fz, vz[0]), (1, fz, vz[1])):
            for dy, wy, oky in ((0, 1.0 - fy, vy[0]), (1, fy, vy[1])):
                for dx, wx, okx in ((0, 1.0 - fx, vx[0]), (1, fx, vx[1])):
                    at = ((jnp.clip(iz + dz, 0, nz - 1) * ny + jnp.clip(iy + dy, 0, ny - 1)) * nx
                          + jnp.clip(ix + dx, 0, nx - 1))
                    value = value + jnp.where(okz & oky & okx, wz * wy * wx * flat[at], 0.0)
        return jnp.where(inside, value, 0.0)
    sx, sy = (1 if nx > 1 else 0), (nx if ny > 1 else 0)
    sz = nx * ny if nz > 1 else 0
    base = (iz * ny + iy) * nx + ix
    for dz, wz in ((0, 1.0 - fz), (sz, fz)):
        for dy, wy in ((0, 1.0 - fy), (sy, fy)):
            for dx, wx in ((0, 1.0 - fx), (sx, fx)):
                value = value + wz * wy * wx * flat[base + dz + dy + dx]
    return jnp.where(inside, value, 0.0)


def clip_to_box(lo: V3, hi: V3, o: V3, d: V3) -> tuple[Array, Array]:
    """(t_enter, t_exit) of the ray o + t d in the box (slabs); t_enter >= t_exit: a miss."""
    t0, t1 = -jnp.inf, jnp.inf
    for oc, dc, lc, hc in zip(o, d, lo, hi):
        par = dc == 0.0
        inv = 1.0 / jnp.where(par, 1.0, dc)
        a, b = (lc - oc) * inv, (hc - oc) * inv
        near, far = jnp.minimum(a, b), jnp.maximum(a, b)
        inside = (oc >= lc) & (oc <= hc)
        near = jnp.where(par, jnp.where(inside, -jnp.inf, jnp.inf), near)
        far = jnp.where(par, jnp.where(inside, jnp.inf, -jnp.inf), far)
        t0, t1 = jnp.maximum(t0, near), jnp.minimum(t1, far)
    return t0, t1


def _affine(m: Array, p: V3) -> V3:
    """The affine map m ([3, 4]) applied to points p."""
    return V3(*(m[i, 0] * p.x + m[i, 1] * p.y + m[i, 2] * p.z + m[i, 3] for i in range(3)))


def _linear(m: Array, d: V3) -> V3:
    """The linear part of m ([3, 4]) applied to directions d."""
    return V3(*(m[i, 0] * d.x + m[i, 1] * d.y + m[i, 2] * d.z for i in range(3)))


def to_grid_frame(medium, o: V3, d: V3) -> tuple[V3, V3]:
    """The ray o + t d in the grid's frame (``GridMedium.to_local``), its parameter t unchanged:
    d is mapped, not normalised, so distances along it stay the world's and so do the
    extinction's units."""
    if medium.to_local is None:
        return o, d
    return _affine(medium.to_local, o), _linear(medium.to_local, d)


def _clip_interval(medium, o: V3, d: V3) -> tuple[Array, Array]:
    """(t_enter, t_exit) of the world ray o + t d in the medium's convex null boundary (its
    unit cube or sphere, in the frame ``clip`` maps to); (-inf, inf) without one."""
    if medium.clip is None:
        return -jnp.inf, jnp.inf
    oc, dc = _affine(medium.clip, o), _linear(medium.clip, d)
    if medium.clip_shape == "cube":
        one = jnp.float32(1.0)
        return clip_to_box(V3(-one, -one, -one), V3(one, one, one), oc, dc)
    # |oc + t dc|^2 = 1, with the cancellation-free roots (q = -(b + sign(b) sqrt(disc)))
    a, b, c = dot(dc, dc), dot(oc, dc), dot(oc, oc) - 1.0
    disc = b * b - a * c
    hit = (disc > 0) & (a > 0)
    q = -(b + jnp.where(b >= 0, 1.0, -1.0) * jnp.sqrt(jnp.where(hit, disc, 0.0)))
    r0 = q / jnp.where(hit, a, 1.0)
    r1 = c / jnp.where(hit & (q != 0), q, 1.0)
    r1 = jnp.where(q != 0, r1, r0)
    return (jnp.where(hit, jnp.minimum(r0, r1), jnp.inf),
            jnp.where(hit, jnp.maximum(r0, r1), -jnp.inf))


def inside_clip(medium, p: V3) -> Array | bool:
    """Whether world points p lie inside the medium's null boundary (True without one)."""
    if medium.clip is None:
        return True
    q = _affine(medium.clip, p)
    if medium.clip_shape == "cube":
        return (jnp.abs(q.x) <= 1.0) & (jnp.abs(q.y) <= 1.0) & (jnp.abs(q.z) <= 1.0)
    return dot(q, q) <= 1.0


def extent(medium, o: V3, d: V3) -> tuple[Array, Array]:
    """(t_enter, t_exit) of the world ray o + t d in the medium: its box (in the grid's frame)
    cut by its null boundary; t_enter >= t_exit: a miss. Both are convex, so the ray meets the
    medium in one interval and the trackings run over it alone."""
    o_l, d_l = to_grid_frame(medium, o, d)
    t0, t1 = clip_to_box(medium.lo, medium.hi, o_l, d_l)
    c0, c1 = _clip_interval(medium, o, d)
    return jnp.maximum(t0, c0), jnp.minimum(t1, c1)


class GridFlight(NamedTuple):
    t: Array          # distance of the real collision (= t_max where none)
    scattered: Array  # bool: a real collision before t_max
    weight: V3        # the product of the tracking's weights (see the module)


def albedo(medium, p: V3) -> V3:
    """The single-scattering albedo at points p of the grid's frame inside the box: the
    constant, times the albedo grid's interpolated RGB where the medium has one."""
    a = medium.albedo
    if medium.albedo_grid is None:
        return a
    g = medium.albedo_grid
    return V3(*(ac * density(g[..., c], medium.lo, medium.hi, p, medium.border)
                 for c, ac in enumerate(a)))


def scattering(medium, p: V3) -> V3:
    """sigma_s,c(x) = albedo_c(x) sigma_t,c(x) at world points p (0 outside the box and the
    null boundary)."""
    q = p if medium.to_local is None else _affine(medium.to_local, p)
    inside = inside_clip(medium, p)
    return V3(*(jnp.where(inside, a * st, 0.0)
                for a, st in zip(albedo(medium, q), _sigma_t(medium, q))))


def _sigma_t(medium, p: V3) -> V3:
    d = density(medium.density, medium.lo, medium.hi, p, medium.border)
    return V3(*(d * s for s in medium.sigma_t))


# A tracking of at least TIERED_FROM lanes compacts its live lanes into batches SHRINK times
# smaller, down to MIN_TIER lanes (see _tracker). Smaller batches (the test suite's images, up
# to 32^2 pixels) run one loop. Each batch size is a copy of the loop for XLA to compile.
# Measured on the cloud bench (`python -m experiments.bench.pt --objects cloud`, 128^2 x 64 spp;
# the path tracer tracks 4096 lanes at a time), render time and first call from an empty
# compilation cache: one loop 2.07-2.26 s, 8.9 s; 4096 then 512 lanes 1.03-1.07 s, 12.2-13.2 s;
# 4096, 1024, 256: 0.81-0.97 s, 16.8 s; 4096, 256: 1.25 s, 13.2 s (docs/performance.md#grid-media).
# JGI_TIERED_FROM sets TIERED_FROM: the test suite, which is compile-bound, tracks in one loop
# (tests/conftest.py), except where a test asks for the smaller batches (tier_floor), which
# change no result (test_grid_media checks them bit for bit).
MIN_TIER = 256
TIERED_FROM = int(os.environ.get("JGI_TIERED_FROM", 4096))
SHRINK = 8


def _tiers(n: int, smallest: int | None = None) -> list[int]:
    """The batch sizes a tracking of n lanes runs at: n, then the last over SHRINK while that
    is at least ``smallest`` (MIN_TIER); n alone below TIERED_FROM."""
    sizes = [n]
    if n < TIERED_FROM and smallest is None:
        return sizes
    while sizes[-1] // SHRINK >= (smallest or MIN_TIER):
        sizes.append(sizes[-1] // SHRINK)
    return sizes


def _tracker(medium, o: V3, d: V3, t_start: Array, t_end: Array, live: Array, key: Array,
             carry, collide, smallest: int | None = None):
    """Tentative collisions along o + t d (in the grid's frame, t the world distance: d the
    image of a unit direction), t in [t_start, t_end], against the majorant
    grid (one cell: the global majorant), for lanes ``live``. Cells are crossed by a DDA
    (Amanatides and Woo 1987; pbrt-v4's DDAMajorantIterator): in a cell of majorant mu the next
    distance is exponential at rate mu, and one that passes the cell's exit restarts there at
    the next cell's rate (exact, by memorylessness; a cell of mu = 0 is skipped). At each
    collision ``collide(carry, at, p, sigma_t, mu, u)`` returns (carry, stop): ``at`` the lanes
    colliding, p where, sigma_t the RGB extinction there, u a uniform for the choice; lanes
    ``stop`` end (``carry``: per-lane leaves; ``collide`` may close over no per-lane array).
    Iteration i uses dimensions 2i, 2i + 1 of stream ``key``. Returns (carry, t of the last
    collision, the loop's iterations: the batch's longest tracking).

    The loop steps every lane of its batch until the last one ends, and the longest tracking
    is several times the mean (measured on a 32^3 cloud: 41 trips, 3.4 collisions a ray on
    average, 21 at most), so once few enough lanes are live it gathers them into a smaller
    batch and goes on there, down to ``smallest`` lanes
    (:func:`_tiers`: from TIERED_FROM lanes, down to MIN_TIER by default; 1-D batches).
    Every lane takes the same steps and random numbers as in one loop: the results are the
    same bit for bit."""
    maj = medium.majorants
    res = (maj.shape[2], maj.shape[1], maj.shape[0])   # cells along x, y, z
    s = medium.sigma_t
    s_max = jnp.maximum(jnp.maximum(s.x, s.y), s.z)
    flat = maj.reshape(-1)
    cell, t_next, dt, step = [], [], [], []
    for oc, dc, lc, hc, m in zip(o, d, medium.lo, medium.hi, res):
        ext = hc - lc
        pc = oc + dc * t_start
        k = jnp.clip(jnp.floor((pc - lc) / ext * m), 0, m - 1).astype(jnp.int32)
        pos, par = dc > 0, dc == 0
        inv = 1.0 / jnp.where(par, 1.0, dc)
        bound = lc + (k + pos.astype(jnp.int32)).astype(oc.dtype) * (ext / m)
        cell.append(k)
        t_next.append(jnp.where(par, jnp.inf, (bound - oc) * inv))
        dt.append(jnp.where(par, jnp.inf, jnp.abs(ext / m * inv)))
        step.append(jnp.where(pos, 1, -1).astype(jnp.int32))

    def body(consts):
        o, d, t_end, dt, step, key = consts

        def run(c):
            i, t, live, (kx, ky, kz), (nx, ny, nz), carry = c
            ctr = rng.counter(key, 2 * i)
            mu = flat[(kz * res[1] + ky) * res[0] + kx] * s_max
            t_seg = jnp.minimum(jnp.minimum(nx, ny), jnp.minimum(nz, t_end))
            t_c = t - jnp.log1p(-rng.uniform_at(ctr, 0)) / jnp.where(mu > 0, mu, 1.0)
            at = live & (mu > 0) & (t_c < t_seg)
            cross = live & ~at
            t = jnp.where(at, t_c, jnp.where(cross, jnp.maximum(t_seg, t), t))
            p = o + d * jnp.where(at, t, 0.0)
            carry, stop = collide(carry, at, p, _sigma_t(medium, p),
                                  jnp.where(mu > 0, mu, 1.0), rng.uniform_at(ctr, 1))
            # a crossing: on to the next cell along the axis whose boundary comes first, or out
            ax = jnp.where(nx <= jnp.minimum(ny, nz), 0, jnp.where(ny <= nz, 1, 2))
            move = cross & (t_seg < t_end)
            k, n = [kx, ky, kz], [nx, ny, nz]
            for a in range(3):
                go = move & (ax == a)
                k[a] = jnp.where(go, k[a] + step[a], k[a])
                n[a] = jnp.where(go, n[a] + dt[a], n[a])
            inside = ((k[0] >= 0) & (k[0] < res[0]) & (k[1] >= 0) & (k[1] < res[1])
                      & (k[2] >= 0) & (k[2] < res[2]))
            live = live & ~stop & ~(cross & ~move) & inside
            return i + 1, t, live, tuple(k), tuple(n), carry
        return run

    def loop(consts, state, sizes):
        limit = sizes[1] if len(sizes) > 1 else 0
        state = jax.lax.while_loop(
            lambda c: jnp.sum(c[2].astype(jnp.int32)) > limit if limit else jnp.any(c[2]),
            body(consts), state)
        if len(sizes) == 1:
            return state
        # at most ``limit`` lanes live: on in a batch of that size, then back in place
        n = state[2].shape[0]
        idx = jnp.nonzero(state[2], size=limit, fill_value=n)[0]
        safe = jnp.minimum(idx, n - 1)
        lanes = lambda tree: jax.tree_util.tree_map(lambda a: a[safe], tree)   # noqa: E731
        sub = lanes(state[1:])
        sub = loop(lanes(consts), (state[0], sub[0], sub[1] & (idx < n)) + sub[2:], sizes[1:])
        back = jax.tree_util.tree_map(lambda a, b: a.at[idx].set(b, mode="drop"),
                                      state[1:], sub[1:])
        return (sub[0],) + back

    key = jnp.broadcast_to(key, live.shape)
    wide = lambda a: jnp.broadcast_to(a, live.shape)   # noqa: E731
    consts = (V3(*map(wide, o)), V3(*map(wide, d)), wide(t_end), tuple(map(wide, dt)),
              tuple(map(wide, step)), key)
    init = (jnp.uint32(0), wide(t_start), live, tuple(map(wide, cell)), tuple(map(wide, t_next)),
            carry)
    sizes = _tiers(live.shape[0], smallest) if live.ndim == 1 else [0]
    out = loop(consts, init, sizes)
    return out[5], out[1], out[0]


def sample_free_flight(medium, o: V3, d: V3, t_max: Array, throughput: V3, active: Array,
                       key: Array, tier_floor: int | None = None) -> GridFlight:
    """Spectral (weighted delta) tracking along the unit-direction ray o + t d, t in
    [0, t_max] (inf: unbounded), for lanes ``active``; ``key``: the flight's random stream;
    ``tier_floor``: the smallest batch the tracking compacts into (:func:`_tracker`; None: by
    the batch's size; the result is the same bit for bit)."""
    t0, t1 = extent(medium, o, d)
    o, d = to_grid_frame(medium, o, d)
    t_start, t_end = jnp.maximum(t0, 0.0), jnp.minimum(t1, t_max)
    go = active & (t_start < t_end)
    one = jnp.ones_like(t_start)
    beta = V3(*(jnp.broadcast_to(jnp.abs(b), go.shape) for b in throughput))

    def collide(carry, at, p, st, mu, u):
        alb = albedo(medium, p)
        hit, w, beta = carry
        b = V3(beta.x * w.x, beta.y * w.y, beta.z * w.z)
        bsum = b.x + b.y + b.z
        pr_w = (b.x * st.x + b.y * st.y + b.z * st.z) / (mu * jnp.where(bsum > 0, bsum, 1.0))
        pr_u = (st.x + st.y + st.z) / (3.0 * mu)
        pr = jnp.clip(jnp.where(bsum > 0, pr_w, pr_u), 0.0, 1.0)
        real = at & (u < pr)
        null = at & ~real
        f_real = [a * sc / (mu * jnp.where(pr > 0, pr, 1.0)) for a, sc in zip(alb, st)]
        f_null = [jnp.maximum(mu - sc, 0.0) / (mu * jnp.where(pr < 1, 1.0 - pr, 1.0))
                  for sc in st]
        w = V3(*(wc * jnp.where(real, fr, jnp.where(null, fn, 1.0))
                 for fr, fn, wc in zip(f_real, f_null, w)))
        return (hit | real, w, beta), real

    (scattered, w, _), t, _ = _tracker(medium, o, d, t_start, t_end, go, key,
                                    (go & False, V3(one, one, one), beta), collide, tier_floor)
    return GridFlight(jnp.where(scattered, t, t_max), scattered, w)


def ratio_tracking(medium, o: V3, d: V3, t_max: Array, active: Array, key: Array,
                   tier_floor: int | None = None) -> V3:
    """Transmittance estimate along o + t d, t in [0, t_max] (any direction length; t_max may be
    inf), for lanes ``active`` (1 elsewhere): the product of sigma_n,c / mu over the tentative
    collisions (see the module); ``tier_floor`` as :func:`sample_free_flight`'s."""
    n = length_of(d)
    dn = d * (1.0 / jnp.where(n > 0, n, 1.0))
    t0, t1 = extent(medium, o, dn)
    o, dn = to_grid_frame(medium, o, dn)
    t_start, t_end = jnp.maximum(t0, 0.0), jnp.minimum(t1, t_max * n)
    go = active & (t_start < t_end) & (n > 0)
    one = jnp.ones_like(t_start)

    def collide(T, at, p, st, mu, u):
        T = V3(*(jnp.where(at, tc * jnp.maximum(mu - sc, 0.0) / mu, tc) for tc, sc in zip(T, st)))
        return T, (T.x <= 0) & (T.y <= 0) & (T.z <= 0)   # 0 in every channel stays 0: stop

    T, _, _ = _tracker(medium, o, dn, t_start, t_end, go, key, V3(one, one, one), collide,
                       tier_floor)
    return T
