"""Ray-primitive intersection for spheres, parallelograms and triangles; closest-hit queries.

Rays are struct-of-arrays (origin ``o`` and unit direction ``d`` as :class:`V3` of shape [N]).
Small primitive tables are unrolled at trace time (one fused kernel over all primitives, the
scene's values still arrays, not constants); larger triangle tables use a loop (or a BVH, see
:mod:`jgi.bvh`). Every test is written so that parallel rays, zero-area primitives and rays that
miss produce ``t = inf`` and never NaN.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from ._xla import materialize
from .scene import Boxes, Quads, Rects, Scene, Spheres, Triangles
from .vec import V3, cross, dot, normalize, where

INF = jnp.float32(jnp.inf)
T_MIN = 1e-6          # reject hits this close to the origin (origins are also offset, see spawn)
UNROLL_LIMIT = 32     # primitive tables up to this size are unrolled into the kernel

SPHERE, QUAD, TRIANGLE, RECT, BOX = 0, 1, 2, 3, 4


class Hit(NamedTuple):
    t: Array          # distance along the ray; inf on a miss
    valid: Array      # bool
    p: V3             # hit position
    n: V3             # unit geometric normal, as the primitive defines it (not flipped)
    material: Array   # int32 material row
    emitter: Array    # int32 light element, -1 if the surface does not emit


# --- single-primitive tests (scalar primitive, vector of rays) ---------------------------------

def sphere_t(center: V3, radius, o: V3, d: V3) -> Array:
    """Nearest t > T_MIN; discriminant in the form r^2 - |oc - (oc.d) d|^2 (pbrt-v4) so that it
    stays accurate for small, distant spheres."""
    oc = o - center
    b = dot(oc, d)
    closest = oc - d * b
    disc = radius * radius - dot(closest, closest)
    hit = disc >= 0
    s = jnp.sqrt(jnp.where(hit, disc, 0.0))
    t0, t1 = -b - s, -b + s
    t = jnp.where(t0 > T_MIN, t0, t1)
    return jnp.where(hit & (t > T_MIN), t, INF)


def quad_t(origin: V3, normal: V3, dual_u: V3, dual_v: V3, o: V3, d: V3) -> Array:
    """Plane hit, then parallelogram coordinates a = (p - origin).dual_u, b = (p - origin).dual_v
    in [0, 1]; the duals are precomputed so the test needs no cross product."""
    denom = dot(normal, d)
    ok = jnp.abs(denom) > 1e-12
    t = dot(normal, origin - o) / jnp.where(ok, denom, 1.0)
    rel = o + d * t - origin
    a, b = dot(rel, dual_u), dot(rel, dual_v)
    hit = ok & (t > T_MIN) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
    return jnp.where(hit, t, INF)


def triangle_t(v0: V3, e1: V3, e2: V3, o: V3, d: V3) -> tuple[Array, Array, Array]:
    """Moller-Trumbore; returns (t, b1, b2)."""
    pvec = cross(d, e2)
    det = dot(e1, pvec)
    ok = jnp.abs(det) > 1e-14
    inv = 1.0 / jnp.where(ok, det, 1.0)
    tvec = o - v0
    b1 = dot(tvec, pvec) * inv
    qvec = cross(tvec, e1)
    b2 = dot(d, qvec) * inv
    t = dot(e2, qvec) * inv
    hit = ok & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > T_MIN)
    return jnp.where(hit, t, INF), b1, b2


def safe_reciprocal(d: V3) -> V3:
    """1/d per component, with zero components mapped to a huge finite value of the same sign
    (so slab tests never form 0 * inf)."""
    def rcp(x):
        small = jnp.abs(x) < 1e-20
        return 1.0 / jnp.where(small, jnp.where(x < 0, -1e-20, 1e-20), x)
    return d.map(rcp)


def rect_t(axis: int, plane, lo_a, hi_a, lo_b, hi_b, o: V3, d: V3, inv_d: V3) -> Array:
    """Axis-aligned rectangle: t from the plane equation with the ray's precomputed 1/d, then
    two interval tests; a non-finite t (ray parallel to the plane) fails every comparison."""
    a, b = [k for k in range(3) if k != axis]
    t = (plane - o[axis]) * inv_d[axis]
    u = o[a] + t * d[a]
    v = o[b] + t * d[b]
    hit = (t > T_MIN) & (u >= lo_a) & (u <= hi_a) & (v >= lo_b) & (v <= hi_b)
    return jnp.where(hit, t, INF)


def _box_local(c: V3, au: V3, av: V3, aw: V3, o: V3, d: V3) -> tuple[V3, V3]:
    rel = o - c
    return V3(dot(rel, au), dot(rel, av), dot(rel, aw)), V3(dot(d, au), dot(d, av), dot(d, aw))


def box_t(c: V3, au: V3, av: V3, aw: V3, half: V3, o: V3, d: V3) -> Array:
    """Oriented box by the slab method in the box frame (Kay & Kajiya 1986); the entry distance
    if the origin is outside, else the exit distance."""
    lo, ld = _box_local(c, au, av, aw, o, d)
    inv = safe_reciprocal(ld)
    t1 = (-half - lo) * inv
    t2 = (half - lo) * inv
    near = V3(jnp.minimum(t1.x, t2.x), jnp.minimum(t1.y, t2.y), jnp.minimum(t1.z, t2.z))
    far = V3(jnp.maximum(t1.x, t2.x), jnp.maximum(t1.y, t2.y), jnp.maximum(t1.z, t2.z))
    t_near = jnp.maximum(jnp.maximum(near.x, near.y), near.z)
    t_far = jnp.minimum(jnp.minimum(far.x, far.y), far.z)
    t = jnp.where(t_near > T_MIN, t_near, t_far)
    return jnp.where((t_near <= t_far) & (t > T_MIN), t, INF)


def box_normal(c: V3, au: V3, av: V3, aw: V3, half: V3, p: V3) -> V3:
    """Outward normal of the face containing p: the axis where |p_local| / half is largest."""
    rel = p - c
    lx, ly, lz = dot(rel, au), dot(rel, av), dot(rel, aw)
    rx = jnp.abs(lx) / jnp.maximum(half.x, 1e-30)
    ry = jnp.abs(ly) / jnp.maximum(half.y, 1e-30)
    rz = jnp.abs(lz) / jnp.maximum(half.z, 1e-30)
    use_x = (rx >= ry) & (rx >= rz)
    use_y = ~use_x & (ry >= rz)
    use_z = ~use_x & ~use_y
    sx = jnp.where(use_x, jnp.sign(lx), 0.0)
    sy = jnp.where(use_y, jnp.sign(ly), 0.0)
    sz = jnp.where(use_z, jnp.sign(lz), 0.0)
    return normalize(au * sx + av * sy + aw * sz)


def quad_duals(q: Quads) -> tuple[V3, V3]:
    """Vectors with dual_u.edge_u = 1, dual_u.edge_v = 0 (and vice versa) in the quad's plane."""
    n = cross(q.edge_u, q.edge_v)
    n2 = dot(n, n)
    inv = jnp.where(n2 > 0, 1.0 / jnp.where(n2 > 0, n2, 1.0), 0.0)
    return cross(q.edge_v, n) * inv, cross(n, q.edge_u) * inv


# --- closest hit over the scene --------------------------------------------------------------

def _take(v: V3, i) -> V3:
    return V3(v.x[i], v.y[i], v.z[i])


def _scan(count: int, body, carry):
    """Unrolled for small tables (fuses into one kernel), a rolled loop for large ones."""
    if count <= UNROLL_LIMIT:
        for i in range(count):
            carry = body(i, carry)
        return carry
    return jax.lax.fori_loop(0, count, body, carry)


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
            return update(c, sphere_t(_take(sp.center, i), sp.radius[i], o, d), SPHERE, i)
        carry = _scan(sp.count, body, carry)

    r: Rects = scene.rects
    if r.count:
        inv_d = safe_reciprocal(d)
        start = 0
        for axis, n_axis in enumerate(r.axis_counts):
            def body(i, c, axis=axis):
                t = rect_t(axis, r.plane[i], r.lo_a[i], r.hi_a[i], r.lo_b[i], r.hi_b[i], o, d, inv_d)
                return update(c, t, RECT, i)
            if n_axis <= UNROLL_LIMIT:
                for i in range(start, start + n_axis):
                    carry = body(i, carry)
            else:
                carry = jax.lax.fori_loop(start, start + n_axis, body, carry)
            start += n_axis

    bx: Boxes = scene.boxes
    if bx.count:
        def body(i, c):
            t = box_t(_take(bx.center, i), _take(bx.axis_u, i), _take(bx.axis_v, i),
                      _take(bx.axis_w, i), _take(bx.half, i), o, d)
            return update(c, t, BOX, i)
        carry = _scan(bx.count, body, carry)

    q: Quads = scene.quads
    if q.count:
        du, dv = quad_duals(q)

        def body(i, c):
            t = quad_t(_take(q.origin, i), _take(q.normal, i), _take(du, i), _take(dv, i), o, d)
            return update(c, t, QUAD, i)
        carry = _scan(q.count, body, carry)

    tr: Triangles = scene.triangles
    if tr.count:
        def body(i, c):
            t, _, _ = triangle_t(_take(tr.v0, i), _take(tr.edge1, i), _take(tr.edge2, i), o, d)
            return update(c, t, TRIANGLE, i)
        carry = _scan(tr.count, body, carry)
    return materialize(carry)


def intersect(scene: Scene, o: V3, d: V3) -> Hit:
    """Closest hit with its position, geometric normal, material and emitter."""
    t, kind, idx = closest_hit(scene, o, d)
    valid = kind >= 0
    tt = jnp.where(valid, t, 0.0)
    p = o + d * tt
    zero_i = jnp.zeros_like(kind)
    n = V3(jnp.zeros_like(tt), jnp.zeros_like(tt), jnp.ones_like(tt))
    material, emitter = zero_i, jnp.full_like(kind, -1)

    sp = scene.spheres
    if sp.count:
        sel = kind == SPHERE
        i = jnp.where(sel, idx, 0)
        c = _take(sp.center, i)
        ns = normalize(p - c)
        n = V3(*(jnp.where(sel, a, b) for a, b in zip(ns, n)))
        material = jnp.where(sel, sp.material[i], material)
        emitter = jnp.where(sel, sp.emitter[i], emitter)
    bx = scene.boxes
    if bx.count:
        sel = kind == BOX
        i = jnp.where(sel, idx, 0)
        nb = box_normal(_take(bx.center, i), _take(bx.axis_u, i), _take(bx.axis_v, i),
                        _take(bx.axis_w, i), _take(bx.half, i), p)
        n = V3(*(jnp.where(sel, a, b) for a, b in zip(nb, n)))
        material = jnp.where(sel, bx.material[i], material)
    for k, table in ((QUAD, scene.quads), (TRIANGLE, scene.triangles), (RECT, scene.rects)):
        if table.count:
            sel = kind == k
            i = jnp.where(sel, idx, 0)
            nt = _take(table.normal, i)
            n = V3(*(jnp.where(sel, a, b) for a, b in zip(nt, n)))
            material = jnp.where(sel, table.material[i], material)
            emitter = jnp.where(sel, table.emitter[i], emitter)
    return materialize(Hit(jnp.where(valid, t, INF), valid, p, n, material, emitter))


def occluded(scene: Scene, o: V3, d: V3, t_max: Array) -> Array:
    """True where something lies strictly between o and o + t_max d (shadow rays)."""
    _, kind, _ = closest_hit(scene, o, d, t_max)
    return kind >= 0


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
    Cornell box's tall block)."""
    o = offset_origin(p, n, wi)
    finite = jnp.isfinite(dist)
    v = p + wi * jnp.where(finite, dist, 0.0) - o
    d2 = dot(v, v)
    ok = finite & (d2 > 0)
    dist_o = jnp.sqrt(jnp.where(ok, d2, 1.0))
    d = where(ok, v * (1.0 / dist_o), wi)
    t_max = jnp.where(ok, dist_o * (1.0 - SHADOW_EPSILON), jnp.where(finite, 0.0, INF))
    return o, d, t_max
