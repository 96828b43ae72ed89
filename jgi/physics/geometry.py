"""Ray-primitive intersection for spheres, parallelograms, disks, cylinders and triangles;
closest-hit queries.

Rays are struct-of-arrays (origin ``o`` and unit direction ``d`` as :class:`V3` of shape [N]).
Small primitive tables are unrolled at trace time (one fused kernel over all primitives, the
scene's values still arrays, not constants); larger tables use a loop, and a triangle table
that carries a BVH (``scene.triangles.bvh``, built by the scene builder for large meshes) is
traversed instead (:mod:`jgi.core.bvh`), after every other table so that their nearest hit culls
it. Every test is written so that parallel rays, zero-area primitives and rays that miss
produce ``t = inf`` and never NaN.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from .. import _xla
from .._xla import materialize
from ..core import bvh, rng
from ..core.vec import EDGE_ON_COS, V3, cross, dot, normalize, where
from ..scene.tables import Boxes, Cylinders, Disks, Quads, Rects, Scene, Spheres, Triangles
from . import textures

INF = jnp.float32(jnp.inf)
T_MIN = 1e-6          # reject hits this close to the origin (origins are also offset, see spawn)
# one fused kernel for small tables, blocks for larger (perf: docs/performance.md#scan-blocks)
UNROLL_LIMIT = 32     # primitive tables up to this size are unrolled into the kernel

SPHERE, QUAD, TRIANGLE, RECT, BOX, DISK, CYLINDER = 0, 1, 2, 3, 4, 5, 6


class Hit(NamedTuple):
    t: Array          # distance along the ray; inf on a miss
    valid: Array      # bool
    p: V3             # hit position
    n: V3             # unit geometric normal, as the primitive defines it (not flipped)
    material: Array   # int32 material row
    emitter: Array    # int32 light element, -1 if the surface does not emit
    uv: tuple | None = None  # surface coordinates (u, v), only in scenes with textures
    ns: V3 | None = None     # unit shading normal, only in scenes with vertex normals
                             # (:func:`shading_normal`; n elsewhere than on smooth triangles)


# --- single-primitive tests (scalar primitive, vector of rays) ---------------------------------

def sphere_roots(center: V3, radius, o: V3, d: V3) -> tuple[Array, Array, Array]:
    """(hit, t0, t1): whether the line meets the sphere and its two crossings t0 <= t1, for a
    unit d; discriminant in the form r^2 - |oc - (oc.d) d|^2 (pbrt-v4) so that it stays
    accurate for small, distant spheres."""
    oc = o - center
    b = dot(oc, d)
    closest = oc - d * b
    disc = radius * radius - dot(closest, closest)
    hit = disc >= 0
    s = _xla.sqrt(jnp.where(hit, disc, 0.0))
    return hit, -b - s, -b + s


def sphere_t(center: V3, radius, o: V3, d: V3) -> Array:
    """Nearest t > T_MIN (:func:`sphere_roots`)."""
    hit, t0, t1 = sphere_roots(center, radius, o, d)
    t = jnp.where(t0 > T_MIN, t0, t1)
    return jnp.where(hit & (t > T_MIN), t, INF)


def _crosses_plane(normal: V3, d: V3) -> tuple[Array, Array]:
    """(n . d, whether the ray crosses the plane of unit normal n): a ray within EDGE_ON_COS of
    the plane (|cos| <= EDGE_ON_COS, d of any length) lies in it to float32 precision and
    misses, on every CPU (see ``vec.EDGE_ON_COS``)."""
    denom = dot(normal, d)
    return denom, denom * denom > (EDGE_ON_COS * EDGE_ON_COS) * dot(d, d)


def quad_t(origin: V3, normal: V3, dual_u: V3, dual_v: V3, o: V3, d: V3) -> Array:
    """Plane hit, then parallelogram coordinates a = (p - origin).dual_u, b = (p - origin).dual_v
    in [0, 1]; the duals are precomputed so the test needs no cross product."""
    denom, ok = _crosses_plane(normal, d)
    t = _xla.div(dot(normal, origin - o), jnp.where(ok, denom, 1.0))
    rel = o + d * t - origin
    a, b = dot(rel, dual_u), dot(rel, dual_v)
    hit = ok & (t > T_MIN) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
    return jnp.where(hit, t, INF)


def triangle_t(v0: V3, e1: V3, e2: V3, normal: V3, o: V3, d: V3) -> tuple[Array, Array, Array]:
    """Moller-Trumbore (:func:`jgi.core.bvh.moller_trumbore`); returns (t, b1, b2). Rays in the
    triangle's plane miss it (as for quads), and the barycentric test is widened by
    ``bvh.BARY_EPS`` as the BVH's is, so a ray through an edge shared by two triangles hits one
    of them whatever the rounding."""
    def solve(det: Array) -> tuple[Array, Array]:
        ok = (jnp.abs(det) > 1e-14) & _crosses_plane(normal, d)[1]
        return _xla.recip(jnp.where(ok, det, 1.0)), ok

    t, b1, b2, inside = bvh.moller_trumbore(v0, e1, e2, o, d, solve)
    return jnp.where(inside & (t > T_MIN), t, INF), b1, b2


SLAB_MIN, SLAB_MAX = 1e-12, 1e12   # |direction component| range for safe_reciprocal


def safe_reciprocal(d: V3) -> V3:
    """1/d per component, for slab and plane tests.

    Components are first clamped to SLAB_MIN <= |x| <= SLAB_MAX: smaller ones become +SLAB_MIN
    (the ray is parallel to that slab at any distance that matters, and no test forms 0 * inf;
    the sign does not matter), larger ones (a shadow ray over 10^12 units) keep their sign. In
    that range the product of the three lies within float32's normal range, so one reciprocal
    serves all three: 1/x = (y z) / (x y z). That is a third of the work of three reciprocals,
    for a relative error of a few float32 roundings (about 3e-7) instead of one."""
    c = d.map(lambda x: jnp.where(jnp.abs(x) < SLAB_MIN, jnp.float32(SLAB_MIN),
                                  jnp.clip(x, -SLAB_MAX, SLAB_MAX)))
    yz, xz, xy = c.y * c.z, c.x * c.z, c.x * c.y
    r = _xla.recip_normal(xy * c.z)
    return V3(yz * r, xz * r, xy * r)


def rect_t(axis: int, plane, lo_a, hi_a, lo_b, hi_b, o: V3, d: V3, inv_d: V3) -> Array:
    """Axis-aligned rectangle: t from the plane equation with the ray's precomputed 1/d, then
    two interval tests."""
    t, hit = _rect_hit(axis, plane, lo_a, hi_a, lo_b, hi_b, o, d, inv_d)
    return jnp.where(hit, t, INF)


def _rect_hit(axis: int, plane, lo_a, hi_a, lo_b, hi_b, o: V3, d: V3, inv_d: V3):
    """(t, hit) of :func:`rect_t` before t is replaced by inf on a miss (the scans fold the
    test into their own comparison, one select less per rectangle)."""
    a, b = [k for k in range(3) if k != axis]
    t = (plane - o[axis]) * inv_d[axis]
    u = o[a] + t * d[a]
    v = o[b] + t * d[b]
    return t, (t > T_MIN) & (u >= lo_a) & (u <= hi_a) & (v >= lo_b) & (v <= hi_b)


def box_t(c: V3, au: V3, av: V3, aw: V3, half: V3, o: V3, d: V3, with_normal: bool = False):
    """Oriented box by the slab method in the box frame (Kay & Kajiya 1986): (t, n).

    t is the entry distance if the origin is outside, else the exit distance (inf on a miss).
    With ``with_normal``, n is the outward normal of the face crossed at t: the slab whose
    entry (exit) distance bounds the interval, signed against (with) the local direction;
    otherwise None."""
    rel = o - c
    lo = V3(dot(rel, au), dot(rel, av), dot(rel, aw))
    ld = V3(dot(d, au), dot(d, av), dot(d, aw))
    inv = safe_reciprocal(ld)
    t1 = (-half - lo) * inv
    t2 = (half - lo) * inv
    near = V3(jnp.minimum(t1.x, t2.x), jnp.minimum(t1.y, t2.y), jnp.minimum(t1.z, t2.z))
    far = V3(jnp.maximum(t1.x, t2.x), jnp.maximum(t1.y, t2.y), jnp.maximum(t1.z, t2.z))
    t_near = jnp.maximum(jnp.maximum(near.x, near.y), near.z)
    t_far = jnp.minimum(jnp.minimum(far.x, far.y), far.z)
    entering = t_near > T_MIN
    t = jnp.where(entering, t_near, t_far)
    t = jnp.where((t_near <= t_far) & (t > T_MIN), t, INF)
    if not with_normal:
        return t, None
    # the bounding slab: argmax of the near distances on entry, argmin of the far ones on exit
    on_x = jnp.where(entering, (near.x >= near.y) & (near.x >= near.z),
                     (far.x <= far.y) & (far.x <= far.z))
    on_y = ~on_x & jnp.where(entering, near.y >= near.z, far.y <= far.z)
    axis = where(on_x, au, where(on_y, av, aw))
    d_axis = jnp.where(on_x, ld.x, jnp.where(on_y, ld.y, ld.z))
    # entering through a face means moving against its outward normal
    sign = jnp.where((d_axis < 0) == entering, 1.0, -1.0)
    return t, axis * sign


def disk_duals(dk: Disks) -> tuple[V3, V3]:
    """Vectors with dual_u.axis_u = 1, dual_u.axis_v = 0 (and vice versa) in the disk's plane:
    (p - center) . dual_u and . dual_v are p's coordinates (a, b) on the unit disk."""
    n = cross(dk.axis_u, dk.axis_v)
    n2 = dot(n, n)
    inv = jnp.where(n2 > 0, 1.0 / jnp.where(n2 > 0, n2, 1.0), 0.0)
    return cross(dk.axis_v, n) * inv, cross(n, dk.axis_u) * inv


def disk_t(center: V3, normal: V3, dual_u: V3, dual_v: V3, o: V3, d: V3):
    """(t, a, b): plane hit as for quads, then a^2 + b^2 <= 1 for the unit-disk coordinates
    (a, b) of the hit point (inf on a miss; rays in the plane miss)."""
    denom, ok = _crosses_plane(normal, d)
    t = _xla.div(dot(normal, center - o), jnp.where(ok, denom, 1.0))
    rel = o + d * t - center
    a, b = dot(rel, dual_u), dot(rel, dual_v)
    hit = ok & (t > T_MIN) & (a * a + b * b <= 1.0)
    return jnp.where(hit, t, INF), a, b


CYLINDER_MIN_SIN2 = 1e-10   # rays closer than this (sin^2) to the axis direction miss the tube


def cylinder_t(base: V3, axis_u: V3, axis_v: V3, axis_w: V3, radius, height, o: V3, d: V3):
    """(t, x, y): nearest t > T_MIN where the ray meets the tube x^2 + y^2 = radius^2,
    0 <= z <= height in the cylinder's frame, and the hit's (x, y) there (t = inf on a miss).

    As for spheres, the discriminant is formed from the ray's closest approach to the axis,
    radius^2 - |f|^2 with f = o_xy - d_xy (o_xy . d_xy) / |d_xy|^2 (no cancellation for rays
    far from a thin tube); a ray (nearly) parallel to the axis misses (it could only run
    along the surface). From inside the tube the far root is taken. ``d`` need not be unit."""
    rel = o - base
    ox, oy, oz = dot(rel, axis_u), dot(rel, axis_v), dot(rel, axis_w)
    dx, dy, dz = dot(d, axis_u), dot(d, axis_v), dot(d, axis_w)
    a = dx * dx + dy * dy
    ok = a > CYLINDER_MIN_SIN2 * (a + dz * dz)
    inv_a = _xla.recip(jnp.where(ok, a, 1.0))
    t_mid = -(ox * dx + oy * dy) * inv_a
    fx, fy = ox + dx * t_mid, oy + dy * t_mid
    disc = radius * radius - (fx * fx + fy * fy)
    ok = ok & (disc >= 0)
    half = _xla.sqrt(jnp.where(ok, disc, 0.0) * inv_a)
    t0, t1 = t_mid - half, t_mid + half

    def on_tube(t):
        z = oz + dz * t
        return (t > T_MIN) & (z >= 0) & (z <= height)
    near = on_tube(t0)
    t = jnp.where(near, t0, t1)
    t = jnp.where(ok & (near | on_tube(t1)), t, INF)
    t_at = jnp.where(t < INF, t, 0.0)    # misses: finite (x, y), never inf * 0
    return t, ox + dx * t_at, oy + dy * t_at


def disk_uv(a: Array, b: Array, pbrt_uv) -> tuple[Array, Array]:
    """Surface coordinates at unit-disk coordinates (a, b), polar (r, phi): Mitsuba's
    (r, phi / 2 pi), or pbrt-v4's (phi / 2 pi, 1 - r) where ``pbrt_uv``."""
    r = jnp.sqrt(a * a + b * b)
    turn = _turn(b, a)
    return jnp.where(pbrt_uv, turn, r), jnp.where(pbrt_uv, 1.0 - r, turn)


def _turn(y: Array, x: Array) -> Array:
    """atan2(y, x) / 2 pi in [0, 1)."""
    phi = jnp.arctan2(y, x) * (0.5 / jnp.pi)
    return jnp.where(phi < 0, phi + 1.0, phi)


def cylinder_uv(x: Array, y: Array, z: Array, height) -> tuple[Array, Array]:
    """(phi / 2 pi, z / height): Mitsuba's and pbrt-v4's cylinder coordinates."""
    return _turn(y, x), z / height


def _cylinder_row(cy: Cylinders, i):
    return (_take(cy.base, i), _take(cy.axis_u, i), _take(cy.axis_v, i), _take(cy.axis_w, i),
            cy.radius[i], cy.height[i])


def _disk_row(dk: Disks, du: V3, dv: V3, i):
    return _take(dk.center, i), _take(dk.normal, i), _take(du, i), _take(dv, i)


def quad_duals(q: Quads) -> tuple[V3, V3]:
    """Vectors with dual_u.edge_u = 1, dual_u.edge_v = 0 (and vice versa) in the quad's plane."""
    n = cross(q.edge_u, q.edge_v)
    n2 = dot(n, n)
    inv = jnp.where(n2 > 0, 1.0 / jnp.where(n2 > 0, n2, 1.0), 0.0)
    return cross(q.edge_v, n) * inv, cross(n, q.edge_u) * inv


# --- opacity masks --------------------------------------------------------------------------
#
# A masked surface (Mitsuba's ``mask``, pbrt-v4's shape ``alpha``) stops a ray with probability
# opacity and lets it through unchanged otherwise. The test sits inside the traversal (every
# scan below and the BVH's leaf test), so a closest hit is the nearest surface that stops the
# ray and an occlusion test is blocked only by stopping surfaces: every estimator, shadow ray,
# connection and photon sees the same stochastic pass-through with no code of its own.
#
# The random number is a pure hash of the ray (origin, direction) and the primitive
# (rng.ray_uniform, as pbrt-v4's HashFloat(ray.o, ray.d)): the rays are themselves random, so
# for each ray and primitive it is a uniform independent of everything the estimator decides,
# and each crossing counts with probability opacity: the estimators stay unbiased in
# expectation. Two crossings of one sphere hash differently (``crossing``). Visibility is then
# not exactly symmetric (the ray x -> y and the ray y -> x hash differently), which the MIS
# weights do not mind: no pdf depends on visibility. The hash has no derivative: gradients
# with respect to opacity are not available.

_MASK_KEY = {SPHERE: 0 << 28, QUAD: 1 << 28, TRIANGLE: 2 << 28, RECT: 3 << 28}


def opacity(scene: Scene, material, uv_of) -> Array:
    """The opacity of ``material`` rows at a hit; ``uv_of()`` gives the hit's surface
    coordinates, evaluated only when some opacity is a texture (its luminance, as Mitsuba's
    eval_1)."""
    mats = scene.materials
    a = mats.opacity[material]
    if mats.opacity_texture is not None:
        a = textures.textured_scalar(mats.textures, mats.opacity_texture[material], uv_of(), a)
    return a


def hit_opacity(scene: Scene, hit: Hit) -> Array:
    """The opacity at a hit that stopped a ray (1 in a scene without masks). A hit stops only a
    fraction ``opacity`` of the rays that reach the surface: a density estimate of the flux
    arriving there divides what is stored there by it (photon maps)."""
    if not scene.materials.has_masks:
        return jnp.ones_like(hit.t)
    a = opacity(scene, hit.material, lambda: hit.uv)
    return jnp.where(hit.valid & (a > 0), a, 1.0)


def mask_stops(scene: Scene, o: V3, d: V3, kind: int, i, material, uv_of,
               crossing: int = 0) -> Array:
    """Whether the crossing of primitive ``i`` of table ``kind`` by the ray (o, d) stops it:
    hash(o, d, primitive) < opacity (so opacity 1 always, 0 never)."""
    key = jnp.asarray(i).astype(jnp.uint32) + jnp.uint32(_MASK_KEY[kind] | (crossing << 27))
    return rng.ray_uniform(o, d, key) < opacity(scene, material, uv_of)


def _masked(scene: Scene, t: Array, o: V3, d: V3, kind: int, i, material, uv_of) -> Array:
    """t where the crossing stops the ray, inf where it passes (t itself without masks)."""
    if not scene.materials.has_masks:
        return t
    return jnp.where(mask_stops(scene, o, d, kind, i, material, uv_of), t, INF)


def _sphere_t_masked(scene: Scene, sp: Spheres, i, o: V3, d: V3, hash_d: V3) -> Array:
    """:func:`sphere_t` with the mask tested at both crossings (the far one counts where the
    near one lets the ray through); ``hash_d`` is the direction the mask hashes (the caller's,
    before normalisation)."""
    center = _take(sp.center, i)
    if not scene.materials.has_masks:
        return sphere_t(center, sp.radius[i], o, d)
    hit, t0, t1 = sphere_roots(center, sp.radius[i], o, d)
    t = INF
    for crossing, tc in ((1, t1), (0, t0)):   # the near crossing last: it wins where it stops
        def uv_of(tc=tc):
            return sphere_uv(normalize(o + d * tc - center))
        stops = mask_stops(scene, o, hash_d, SPHERE, i, sp.material[i], uv_of, crossing)
        t = jnp.where(hit & (tc > T_MIN) & stops, tc, t)
    return t


def _bvh_mask(scene: Scene):
    """The BVH's leaf-test callback ``(triangle, b1, b2, o, d) -> stops`` (None without
    masks)."""
    if not scene.materials.has_masks:
        return None
    tr = scene.triangles

    def stops(tri, b1, b2, o, d):
        i = jnp.maximum(tri, 0)
        return mask_stops(scene, o, d, TRIANGLE, i, tr.material[i],
                          lambda: triangle_uv(tr.uv, i, b1, b2))
    return stops


def _rect_uv(r: Rects, i, p: V3):
    return parallelogram_uv(_take(r.origin, i), _take(r.dual_u, i), _take(r.dual_v, i), p)


# --- closest hit over the scene --------------------------------------------------------------

def _take(v: V3, i) -> V3:
    return V3(v.x[i], v.y[i], v.z[i])


SCAN_BLOCK = 8        # rows per iteration of the loop over a larger table


def _scan(count: int, body, carry):
    """Unrolled for small tables (fuses into one kernel); for larger ones a loop over blocks of
    SCAN_BLOCK rows, each block unrolled and stored by one kernel, then the remaining rows
    (one row per iteration made every row a kernel launch over all rays;
    perf: docs/performance.md#scan-blocks)."""
    if count <= UNROLL_LIMIT:
        for i in range(count):
            carry = body(i, carry)
        return carry

    def block(b, c):
        for j in range(SCAN_BLOCK):
            c = body(b * SCAN_BLOCK + j, c)
        # one kernel per block, not one per carried value (perf: docs/performance.md#scan-blocks)
        return materialize(c)

    n_blocks = count // SCAN_BLOCK
    carry = jax.lax.fori_loop(0, n_blocks, block, carry)
    for i in range(n_blocks * SCAN_BLOCK, count):
        carry = body(i, carry)
    return carry


def traversal_loops(scene: Scene) -> bool:
    """Whether a closest-hit query on ``scene`` runs loops (a BVH, or a table of more than
    UNROLL_LIMIT rows) rather than one unrolled kernel: a value the rays are computed from is
    then best stored before the query, or each loop iteration's kernel recomputes it."""
    tables = (scene.spheres.count, *scene.rects.axis_counts, scene.boxes.count,
              scene.quads.count, scene.triangles.count,
              *(t.count for t in (scene.disks, scene.cylinders) if t is not None))
    return scene.triangles.bvh is not None or max(tables) > UNROLL_LIMIT


def _rect_axes(r: Rects):
    """(axis, first row, row count) for each axis that has rectangles."""
    out, start = [], 0
    for axis, n_axis in enumerate(r.axis_counts):
        if n_axis:
            out.append((axis, start, n_axis))
        start += n_axis
    return out


def _scan_rects(r: Rects, o: V3, d: V3, inv_d: V3, body, carry):
    """``body(i, carry, t, hit, axis)`` over the rectangles, axis by axis (:func:`_scan`)."""
    for axis, start, n_axis in _rect_axes(r):
        def one(i, c, axis=axis):
            return body(i, c, *_rect_hit(axis, r.plane[i], r.lo_a[i], r.hi_a[i], r.lo_b[i],
                                         r.hi_b[i], o, d, inv_d), axis)
        carry = _scan(n_axis, lambda k, c, one=one, start=start: one(start + k, c), carry)
    return carry


def closest_hit(scene: Scene, o: V3, d: V3, t_max: Array | None = None):
    """(t, kind, index) of the nearest primitive with T_MIN < t < t_max (inf and -1 on a miss)."""
    shape = o.x.shape
    best_t = jnp.full(shape, INF) if t_max is None else jnp.broadcast_to(t_max, shape)
    best_kind = jnp.full(shape, -1, jnp.int32)
    best_idx = jnp.full(shape, -1, jnp.int32)
    carry = (best_t, best_kind, best_idx)

    def update(carry, t, kind, i):
        bt, bk, bi = carry
        closer = t < bt
        return (jnp.where(closer, t, bt), jnp.where(closer, kind, bk), jnp.where(closer, i, bi))

    sp: Spheres = scene.spheres
    if sp.count:
        def body(i, c):
            return update(c, _sphere_t_masked(scene, sp, i, o, d, d), SPHERE, i)
        carry = _scan(sp.count, body, carry)
    r: Rects = scene.rects
    if r.count:
        def rect_body(i, c, t, hit, _):
            t = _masked(scene, jnp.where(hit, t, INF), o, d, RECT, i, r.material[i],
                        lambda: _rect_uv(r, i, o + d * t))
            return update(c, t, RECT, i)
        carry = _scan_rects(r, o, d, safe_reciprocal(d), rect_body, carry)
    bx: Boxes = scene.boxes
    if bx.count:
        def body(i, c):
            return update(c, box_t(*_box_row(bx, i), o, d)[0], BOX, i)
        carry = _scan(bx.count, body, carry)
    q: Quads = scene.quads
    if q.count:
        du, dv = quad_duals(q)

        def body(i, c):
            origin = _take(q.origin, i)
            t = quad_t(origin, _take(q.normal, i), _take(du, i), _take(dv, i), o, d)
            t = _masked(scene, t, o, d, QUAD, i, q.material[i],
                        lambda: parallelogram_uv(origin, _take(du, i), _take(dv, i), o + d * t))
            return update(c, t, QUAD, i)
        carry = _scan(q.count, body, carry)
    dk: Disks | None = scene.disks
    if dk is not None:
        ddu, ddv = disk_duals(dk)
        carry = _scan(dk.count, lambda i, c: update(c, disk_t(*_disk_row(dk, ddu, ddv, i), o,
                                                                 d)[0], DISK, i), carry)
    cy: Cylinders | None = scene.cylinders
    if cy is not None:
        carry = _scan(cy.count, lambda i, c: update(c, cylinder_t(*_cylinder_row(cy, i), o,
                                                                     d)[0], CYLINDER, i), carry)
    tr: Triangles = scene.triangles
    if tr.count and tr.bvh is not None:
        t, prim = _bvh_closest(tr, o, d, carry[0], _bvh_mask(scene))
        carry = update(carry, jnp.where(prim >= 0, t, INF), TRIANGLE, prim)
    elif tr.count:
        def body(i, c):
            t, b1, b2 = triangle_t(_take(tr.v0, i), _take(tr.edge1, i), _take(tr.edge2, i),
                                   _take(tr.normal, i), o, d)
            t = _masked(scene, t, o, d, TRIANGLE, i, tr.material[i],
                        lambda: triangle_uv(tr.uv, i, b1, b2))
            return update(c, t, TRIANGLE, i)
        carry = _scan(tr.count, body, carry)
    return materialize(carry)


def _flat(a: Array) -> Array:
    return jnp.reshape(a, (-1,))


def _bvh_closest(tr: Triangles, o: V3, d: V3, t_max: Array, mask=None
                 ) -> tuple[Array, Array]:
    """(t, triangle) of the nearest BVH triangle with T_MIN < t < t_max (t_max, -1 on a miss).

    The traversal is a while loop, which reverse-mode differentiation cannot enter, so it runs
    on stopped gradients; t's gradient is that of the hit triangle's own Moller-Trumbore
    solution (its value is the traversal's, exactly). ``mask``: :func:`_bvh_mask`'s callback."""
    shape = o.x.shape
    sg = jax.lax.stop_gradient
    of, df = V3(*(_flat(sg(a)) for a in o)), V3(*(_flat(sg(a)) for a in d))
    tm = _flat(jnp.broadcast_to(sg(t_max), shape))
    h = bvh.intersect_closest(tr.bvh, of, df, T_MIN, tm, mask=mask)
    prim = jnp.reshape(h.prim, shape)
    t = jnp.reshape(h.t, shape)
    # t = e2 . ((o - v0) x e1) / (e1 . (d x e2)) of the hit triangle, for its gradient only
    i = jnp.maximum(prim, 0)
    v0, e1, e2 = _take(tr.v0, i), _take(tr.edge1, i), _take(tr.edge2, i)
    det = dot(e1, cross(d, e2))
    hit = prim >= 0           # misses divide by 1: no inf or NaN, not even in the gradient
    t_mt = dot(e2, cross(o - v0, e1)) / jnp.where(hit & (det != 0), det, 1.0)
    t = t + (t_mt - sg(t_mt))
    return jnp.where(hit, t, t_max), prim


def _box_row(bx: Boxes, i):
    return (_take(bx.center, i), _take(bx.axis_u, i), _take(bx.axis_v, i), _take(bx.axis_w, i),
            _take(bx.half, i))


class _Nearest(NamedTuple):
    """Closest-hit scan state: the nearest t so far and the attributes of that primitive, so no
    table has to be gathered again afterwards."""
    t: Array
    n: V3              # geometric normal (sphere: its centre, resolved after the scan)
    material: Array
    emitter: Array
    sphere: Array      # bool, only carried when the scene has spheres
    uv: tuple | None   # (u, v), only carried when the scene has textures (spheres: after the scan)
    ns: V3 | None      # interpolated vertex normal (not normalised), only in scenes with them


def sphere_uv(n: V3) -> tuple[Array, Array]:
    """Mitsuba's sphere parametrisation at the unit outward normal n (the sphere's frame is
    the world's): u = phi / 2 pi with phi = atan2(n_y, n_x) in [0, 2 pi), v = theta / pi with
    theta = acos(n_z)."""
    phi = jnp.arctan2(n.y, n.x)
    phi = jnp.where(phi < 0, phi + 2 * jnp.pi, phi)
    return phi * (0.5 / jnp.pi), jnp.arccos(jnp.clip(n.z, -1.0, 1.0)) * (1 / jnp.pi)


def parallelogram_uv(origin: V3, dual_u: V3, dual_v: V3, p: V3) -> tuple[Array, Array]:
    """The parameters (a, b) of p = origin + a edge_u + b edge_v: a rectangle's or quad's uv
    (Mitsuba's rectangle uv for quads built from ``rectangle``)."""
    rel = p - origin
    return dot(rel, dual_u), dot(rel, dual_v)


def triangle_uv(uv: Array, i, b1: Array, b2: Array) -> tuple[Array, Array]:
    """Barycentric interpolation of triangle rows i's vertex uvs (``Triangles.uv``)."""
    r = uv[i]
    return r[..., 0] + b1 * r[..., 2] + b2 * r[..., 4], r[..., 1] + b1 * r[..., 3] + b2 * r[..., 5]


def triangle_normal(normals: Array, i, b1: Array, b2: Array) -> V3:
    """Barycentric interpolation of triangle rows i's vertex normals (``Triangles.normals``),
    not normalised: n0 (1 - b1 - b2) + n1 b1 + n2 b2 (Mitsuba's and pbrt's)."""
    r = normals[i]
    b0 = 1.0 - b1 - b2
    return V3(*(r[..., k] * b0 + r[..., 3 + k] * b1 + r[..., 6 + k] * b2 for k in range(3)))


NS_MIN_LENGTH2 = 1e-12   # squared length below which an interpolated normal counts as zero


def shading_normal(ns: V3, n: V3) -> V3:
    """The unit shading normal from an interpolated vertex normal ``ns``; the geometric normal
    n where ns is (nearly) zero or not finite (opposed vertex normals), so that no NaN
    appears."""
    n2 = dot(ns, ns)
    ok = (n2 > NS_MIN_LENGTH2) & jnp.isfinite(n2)
    inv = _xla.rsqrt(jnp.where(ok, n2, 1.0))
    return where(ok, ns * inv, n)


def intersect(scene: Scene, o: V3, d: V3, stored: bool = True) -> Hit:
    """Closest hit with its position, geometric normal, material and emitter.

    The hit is computed once and stored (jgi._xla.materialize); with ``stored=False`` the caller
    stores it, together with values of its own, in the same kernel.

    One pass over the primitives keeps the nearest hit's attributes (normal, material, emitter)
    as it goes: cheaper than recording (kind, index) and gathering from every table afterwards."""
    shape = o.x.shape
    zf = jnp.zeros(shape, jnp.float32)
    has_spheres = scene.spheres.count > 0
    # surface coordinates, only in scenes with textures (static: other scenes' kernels are
    # unchanged)
    with_uv = scene.materials.has_textures
    # shading normals, only in scenes with vertex normals (static, as uv)
    with_ns = scene.has_shading_normals
    carry = _Nearest(jnp.full(shape, INF), V3(zf, zf, zf + 1.0), jnp.zeros(shape, jnp.int32),
                     jnp.full(shape, -1, jnp.int32), zf > 0 if has_spheres else None,
                     (zf, zf) if with_uv else None, V3(zf, zf, zf + 1.0) if with_ns else None)
    no_uv = (jnp.float32(0.0), jnp.float32(0.0)) if with_uv else None

    def update(c: _Nearest, closer, t, n: V3, material, emitter, sphere=False,
               uv=no_uv, ns=None) -> _Nearest:
        sel = lambda a, b: jnp.where(closer, a, b)  # noqa: E731
        ns = n if ns is None else ns
        return _Nearest(sel(t, c.t), V3(sel(n.x, c.n.x), sel(n.y, c.n.y), sel(n.z, c.n.z)),
                        sel(material, c.material), sel(emitter, c.emitter),
                        sel(sphere, c.sphere) if has_spheres else None,
                        (sel(uv[0], c.uv[0]), sel(uv[1], c.uv[1])) if with_uv else None,
                        V3(sel(ns.x, c.ns.x), sel(ns.y, c.ns.y), sel(ns.z, c.ns.z))
                        if with_ns else None)

    sp: Spheres = scene.spheres
    if sp.count:
        def body(i, c):
            center = _take(sp.center, i)
            t = _sphere_t_masked(scene, sp, i, o, d, d)
            return update(c, t < c.t, t, center, sp.material[i], sp.emitter[i], True)
        carry = _scan(sp.count, body, carry)
    r: Rects = scene.rects
    if r.count:
        inv_d = safe_reciprocal(d)

        def rect_body(i, c, t, hit, axis):
            # the normal is +-1 along the axis: one table value per row, not three (the scene's
            # values are kept in registers or reloaded in the kernel's loop, and there are many)
            n = [jnp.float32(0.0)] * 3
            n[axis] = r.normal[axis][i]
            uv = _rect_uv(r, i, o + d * t) if with_uv else None
            if scene.materials.has_masks:
                hit = hit & mask_stops(scene, o, d, RECT, i, r.material[i],
                                       lambda: _rect_uv(r, i, o + d * t))
            return update(c, hit & (t < c.t), t, V3(*n), r.material[i], r.emitter[i], uv=uv)
        carry = _scan_rects(r, o, d, inv_d, rect_body, carry)
    bx: Boxes = scene.boxes
    if bx.count:
        def body(i, c):
            t, n = box_t(*_box_row(bx, i), o, d, with_normal=True)
            return update(c, t < c.t, t, n, bx.material[i], bx.emitter[i])
        carry = _scan(bx.count, body, carry)
    q: Quads = scene.quads
    if q.count:
        du, dv = quad_duals(q)

        def body(i, c):
            origin = _take(q.origin, i)
            t = quad_t(origin, _take(q.normal, i), _take(du, i), _take(dv, i), o, d)
            uv = (parallelogram_uv(origin, _take(du, i), _take(dv, i), o + d * t)
                  if with_uv else None)
            t = _masked(scene, t, o, d, QUAD, i, q.material[i],
                        lambda: parallelogram_uv(origin, _take(du, i), _take(dv, i), o + d * t))
            return update(c, t < c.t, t, _take(q.normal, i), q.material[i], q.emitter[i], uv=uv)
        carry = _scan(q.count, body, carry)
    dk: Disks | None = scene.disks
    if dk is not None:
        ddu, ddv = disk_duals(dk)

        def body(i, c):
            t, a, b = disk_t(*_disk_row(dk, ddu, ddv, i), o, d)
            uv = disk_uv(a, b, dk.pbrt_uv[i]) if with_uv else None
            return update(c, t < c.t, t, _take(dk.normal, i), dk.material[i], dk.emitter[i],
                          uv=uv)
        carry = _scan(dk.count, body, carry)
    cy: Cylinders | None = scene.cylinders
    if cy is not None:
        def body(i, c):
            row = _cylinder_row(cy, i)
            base, au, av, aw, radius, height = row
            t, x, y = cylinder_t(*row, o, d)
            n = normalize(au * x + av * y) * cy.outward[i]
            uv = (cylinder_uv(x, y, dot(o + d * t - base, aw), height) if with_uv else None)
            return update(c, t < c.t, t, n, cy.material[i], cy.emitter[i], uv=uv)
        carry = _scan(cy.count, body, carry)
    tr: Triangles = scene.triangles
    if tr.count and tr.bvh is not None:
        t, prim = _bvh_closest(tr, o, d, carry.t, _bvh_mask(scene))
        i = jnp.maximum(prim, 0)
        uv = ns = None
        if with_uv or with_ns:   # the hit triangle's barycentrics, from its own test
            _, b1, b2 = triangle_t(_take(tr.v0, i), _take(tr.edge1, i), _take(tr.edge2, i),
                                   _take(tr.normal, i), o, d)
            uv = triangle_uv(tr.uv, i, b1, b2) if with_uv else None
            ns = triangle_normal(tr.normals, i, b1, b2) if with_ns else None
        carry = update(carry, prim >= 0, t, _take(tr.normal, i), tr.material[i], tr.emitter[i],
                       uv=uv if with_uv else no_uv, ns=ns)
    elif tr.count:
        def body(i, c):
            t, b1, b2 = triangle_t(_take(tr.v0, i), _take(tr.edge1, i), _take(tr.edge2, i),
                                   _take(tr.normal, i), o, d)
            uv = triangle_uv(tr.uv, i, b1, b2) if with_uv else None
            ns = triangle_normal(tr.normals, i, b1, b2) if with_ns else None
            t = _masked(scene, t, o, d, TRIANGLE, i, tr.material[i],
                        lambda: triangle_uv(tr.uv, i, b1, b2))
            return update(c, t < c.t, t, _take(tr.normal, i), tr.material[i], tr.emitter[i],
                          uv=uv, ns=ns)
        carry = _scan(tr.count, body, carry)

    valid = carry.t < INF
    tt = jnp.where(valid, carry.t, 0.0)
    p = o + d * tt
    n = carry.n
    uv = carry.uv
    if has_spheres:
        n_sphere = normalize(p - n)
        n = V3(*(jnp.where(carry.sphere, a, b) for a, b in zip(n_sphere, n)))
        if with_uv:
            su, sv = sphere_uv(n_sphere)
            uv = (jnp.where(carry.sphere, su, uv[0]), jnp.where(carry.sphere, sv, uv[1]))
    ns = None
    if with_ns:
        ns = shading_normal(carry.ns, n)
        if has_spheres:   # a sphere's shading normal is its geometric one
            ns = where(carry.sphere, n, ns)
    hit = Hit(carry.t, valid, p, n, carry.material, carry.emitter, uv, ns)
    return materialize(hit) if stored else hit


def occluded(scene: Scene, o: V3, d: V3, t_max: Array) -> Array:
    """True where something lies strictly between o and o + t_max d (shadow rays).

    An any-hit query: the OR over primitives of T_MIN < t_i < t_max, with no nearest-hit
    bookkeeping. ``d`` need not be a unit vector (t is then in units of its length; see
    :func:`shadow_ray`)."""
    shape = o.x.shape
    t_max = jnp.broadcast_to(t_max, shape)
    occ = jnp.zeros(shape, bool)

    sp: Spheres = scene.spheres
    if sp.count:
        # the sphere test needs a unit direction: t scales by the length
        n2 = dot(d, d)
        inv_length = _xla.rsqrt(jnp.where(n2 > 0, n2, 1.0))
        du, t_max_u = d * inv_length, _xla.div(t_max, inv_length)
        occ = _scan(sp.count, lambda i, a: a | (_sphere_t_masked(scene, sp, i, o, du, d)
                                                < t_max_u), occ)
    r: Rects = scene.rects
    if r.count:
        def rect_body(i, a, t, hit, _):
            if scene.materials.has_masks:
                hit = hit & mask_stops(scene, o, d, RECT, i, r.material[i],
                                       lambda: _rect_uv(r, i, o + d * t))
            return a | (hit & (t < t_max))
        occ = _scan_rects(r, o, d, safe_reciprocal(d), rect_body, occ)
    bx: Boxes = scene.boxes
    if bx.count:
        occ = _scan(bx.count, lambda i, a: a | (box_t(*_box_row(bx, i), o, d)[0] < t_max), occ)
    q: Quads = scene.quads
    if q.count:
        du, dv = quad_duals(q)
        def quad_body(i, a):
            origin = _take(q.origin, i)
            t = quad_t(origin, _take(q.normal, i), _take(du, i), _take(dv, i), o, d)
            t = _masked(scene, t, o, d, QUAD, i, q.material[i],
                        lambda: parallelogram_uv(origin, _take(du, i), _take(dv, i), o + d * t))
            return a | (t < t_max)
        occ = _scan(q.count, quad_body, occ)
    dk: Disks | None = scene.disks
    if dk is not None:
        ddu, ddv = disk_duals(dk)
        occ = _scan(dk.count, lambda i, a: a | (disk_t(*_disk_row(dk, ddu, ddv, i), o, d)[0]
                                                < t_max), occ)
    cy: Cylinders | None = scene.cylinders
    if cy is not None:
        occ = _scan(cy.count, lambda i, a: a | (cylinder_t(*_cylinder_row(cy, i), o, d)[0]
                                                < t_max), occ)
    tr: Triangles = scene.triangles
    if tr.count and tr.bvh is not None:
        # rays already occluded get an empty interval: they leave the traversal at once
        sg = jax.lax.stop_gradient
        tm = _flat(jnp.where(occ, 0.0, sg(t_max)))
        hit = bvh.intersect_any(tr.bvh, V3(*(_flat(sg(a)) for a in o)),
                                V3(*(_flat(sg(a)) for a in d)), T_MIN, tm,
                                mask=_bvh_mask(scene))
        occ = occ | jnp.reshape(hit, shape)
    elif tr.count:
        def triangle_body(i, a):
            t, b1, b2 = triangle_t(_take(tr.v0, i), _take(tr.edge1, i), _take(tr.edge2, i),
                                   _take(tr.normal, i), o, d)
            t = _masked(scene, t, o, d, TRIANGLE, i, tr.material[i],
                        lambda: triangle_uv(tr.uv, i, b1, b2))
            return a | (t < t_max)
        occ = _scan(tr.count, triangle_body, occ)
    # stored: XLA would repeat the whole unrolled test in every consumer fusion (a pixel index,
    # each channel of a value; perf: docs/performance.md#occlusion-stored)
    return materialize(occ)


def offset_origin(p: V3, n: V3, w: V3) -> V3:
    """Move a spawned ray's origin off the surface, to the side ``w`` leaves on, by an amount
    relative to the position's magnitude, so that the surface is not hit again."""
    eps = 1e-4 * (1.0 + jnp.maximum(jnp.maximum(jnp.abs(p.x), jnp.abs(p.y)), jnp.abs(p.z)))
    side = jnp.where(dot(n, w) >= 0, eps, -eps)
    return p + n * side


SHADOW_EPSILON = 1e-4  # relative shortening of shadow rays, so the light's own surface is excluded


def shadow_ray(p: V3, n: V3, wi: V3, dist: Array) -> tuple[V3, V3, Array]:
    """(origin, direction, t_max) of the shadow ray from surface point p (normal n) to the light
    sample at p + dist * wi (``dist = inf`` for directional and environment lights).

    The origin is offset as for any spawned ray, and the ray is re-aimed from there at the
    sampled point (pbrt-v4's ``SpawnRayTo``): keeping ``wi`` and ``dist`` from the unshifted
    point would make the ray meet the light's own surface before t_max whenever the surface and
    the light are close to parallel (measured: 18% of light samples lost on the top of the
    Cornell box's tall block).

    For a finite sample the direction is the segment itself, not normalised, and t_max is
    1 - SHADOW_EPSILON (no square root or division: cheaper, and :func:`occluded` accepts
    any direction length); towards infinity it is ``wi`` with t_max = inf."""
    o = offset_origin(p, n, wi)
    finite = jnp.isfinite(dist)
    v = p + wi * jnp.where(finite, dist, 0.0) - o
    d = where(finite, v, wi)
    t_max = jnp.where(finite, jnp.where(dot(v, v) > 0, 1.0 - SHADOW_EPSILON, 0.0), INF)
    return o, d, t_max
