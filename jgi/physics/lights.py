"""Light sampling: ``sample_li`` (towards a point), ``pdf_li``, ``emitted`` and ``sample_emission``.

All lights are *elements* of one table (:class:`jgi.scene.Lights`), chosen with probability
proportional to emitted power (``pmf``). Densities returned here include that selection
probability, so MIS code compares like with like.

Per kind (L_e radiance, I intensity, E irradiance, A area, R bounding-sphere radius):

============  ==================================  ============================================
kind          sample_li (towards x)               sample_emission (photons, light paths)
============  ==================================  ============================================
area quad,    uniform point y on the element,     uniform y, cosine-distributed direction:
triangle,     pdf = |x-y|^2 / (A cos theta_y)     pdf = (1/A)(cos/pi), power pi A L_e
disk,         (disk: the concentric map;
cylinder      cylinder: uniform in (phi, z))
area sphere   uniform in the cone subtended       uniform y on the sphere, cosine direction
              at x: pdf = 1/(2 pi (1-cos_max))
point         delta, L_i = I / d^2                uniform direction, power 4 pi I
spot          delta, I * falloff (pbrt's          uniform within the cone
              smoothstep or Mitsuba's linear)
directional   delta, L_i = E along -direction     parallel rays over the scene's bounding
                                                  disc, power E pi R^2
environment   uniform direction, pdf 1/(4 pi);    uniform direction, bounding disc;
              a map: by its piecewise-constant    a map: a direction by its distribution
              distribution (``EnvironmentMap``)
============  ==================================  ============================================
An environment map's radiance is its ``emission`` row (Mitsuba's or pbrt's ``scale``) times the
image's lookup (:func:`environment_radiance`): bilinear on a latitude-longitude map, the nearest
texel on pbrt-v4's equal-area octahedral one (``EnvironmentMap.mapping``, static, so either
compiles to its own code); a constant environment (``lights.envmap`` None, static) compiles to
the code of a scene before environment maps.
Quad, triangle and disk emitters radiate on the side of their normal only; spheres outwards,
cylinders to the side their ``outward`` sign (in ``radius``) names.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array

from .. import _xla
from .._xla import SMALL_TABLE, take
from ..core import warps
from ..core.vec import EDGE_ON_COS, V3, coordinate_system, dot, normalize, to_world, where
from ..scene.tables import (
    AREA_CYLINDER,
    AREA_DISK,
    AREA_QUAD,
    AREA_SPHERE,
    AREA_TRIANGLE,
    DIRECTIONAL,
    ENVIRONMENT,
    POINT,
    SPOT,
    EnvironmentMap,
    Lights,
)

AREA_KINDS = (AREA_QUAD, AREA_TRIANGLE, AREA_SPHERE, AREA_DISK, AREA_CYLINDER)


class LightSample(NamedTuple):
    wi: V3          # unit direction from the reference point towards the light
    dist: Array     # distance to the sampled point (inf for directional and environment)
    Li: V3          # incident radiance (or I/d^2, E for delta lights), not divided by pdf
    pdf: Array      # solid-angle pdf incl. selection; for delta lights the selection pmf
    delta: Array    # True for point, spot and directional lights (no MIS possible)
    valid: Array


class EmissionSample(NamedTuple):
    p: V3            # origin of the light path
    n: V3            # surface normal at p (zero for point/spot, direction for directional)
    d: V3            # direction of travel
    weight: V3       # L_e |cos| / (pmf pdf_pos pdf_dir): the light-path throughput (power)
    pdf_pos: Array   # area density of p incl. selection (the pmf alone for delta positions)
    pdf_dir: Array   # solid-angle density of d (1 for a Dirac direction)
    delta_pos: Array
    delta_dir: Array
    element: Array


def _take(v: V3, i) -> V3:
    """Row i of a V3 table (selects for small tables: a gather would split the caller's kernel
    and keep it from vectorising)."""
    return V3(take(v.x, i), take(v.y, i), take(v.z, i))


def select_light(lights: Lights, u: Array) -> Array:
    """Element index by inverting the power CDF: the number of CDF entries <= u. Small tables
    count with compares (they fuse into the caller's kernel; ``searchsorted`` is a loop of
    kernels of its own)."""
    if lights.count <= SMALL_TABLE:
        i = jnp.zeros(jnp.shape(u), jnp.int32)
        for k in range(lights.count - 1):   # the last entry is 1 > u
            i = i + (lights.cdf[k] <= u).astype(jnp.int32)
        return i
    i = jnp.searchsorted(lights.cdf, u, side="right")
    return jnp.clip(i, 0, lights.count - 1).astype(jnp.int32)


def spot_falloff(cos_theta, cos_total, cos_falloff, linear=None) -> Array:
    """The falloff between the cutoff and the falloff-start (beam) cones: pbrt-v4's smoothstep
    in the cosine, or where ``linear``, Mitsuba 3's ramp linear in the angle,
    (cutoff - theta) / (cutoff - beam) (its spot.cpp ``falloff_curve``)."""
    span = jnp.maximum(cos_falloff - cos_total, 1e-6)
    t = jnp.clip((cos_theta - cos_total) / span, 0.0, 1.0)
    smooth = jnp.where(cos_theta >= cos_falloff, 1.0, t * t * (3.0 - 2.0 * t))
    if linear is None:
        return smooth
    cutoff = jnp.arccos(jnp.clip(cos_total, -1.0, 1.0))
    theta = jnp.arccos(jnp.clip(cos_theta, -1.0, 1.0))
    ramp = jnp.clip((cutoff - theta) / jnp.maximum(cutoff - jnp.arccos(
        jnp.clip(cos_falloff, -1.0, 1.0)), 1e-6), 0.0, 1.0)
    ramp = jnp.where(cos_theta >= cos_falloff, 1.0, jnp.where(cos_theta > cos_total, ramp, 0.0))
    return jnp.where(linear, ramp, smooth)


def _area_to_solid_angle(pdf_area, dist2, cos_light):
    ok = (cos_light > EDGE_ON_COS) & (pdf_area > 0)
    return jnp.where(ok, _xla.div(pdf_area * dist2, jnp.where(ok, cos_light, 1.0)), 0.0)


def disk_point(center: V3, axis_u: V3, axis_v: V3, u1: Array, u2: Array) -> V3:
    """A uniformly distributed point of the disk (ellipse) center + a axis_u + b axis_v,
    a^2 + b^2 <= 1: (a, b) by the concentric map (a linear map keeps it uniform)."""
    a, b = warps.sample_concentric_disc(u1, u2)
    return center + axis_u * a + axis_v * b


def cylinder_point(base: V3, radial_u: V3, radial_v: V3, axis: V3, outward, u1: Array,
                   u2: Array) -> tuple[V3, V3]:
    """(point, normal) uniformly distributed on the tube base + cos(phi) radial_u +
    sin(phi) radial_v + z axis (radial_* = radius * unit axes, axis = height * unit axis),
    phi = 2 pi u1, z = u2: the area element is radius dphi height dz, constant."""
    phi = (2.0 * jnp.pi) * u1
    radial = radial_u * jnp.cos(phi) + radial_v * jnp.sin(phi)
    return base + radial + axis * u2, normalize(radial) * outward


def cylinder_normal(base: V3, axis: V3, outward, y: V3) -> V3:
    """The emitting-side unit normal of a cylinder element at its point y: y's offset from
    the axis, times the element's ``outward`` sign."""
    rel = y - base
    a2 = dot(axis, axis)
    along = dot(rel, axis) * jnp.where(a2 > 0, 1.0 / jnp.where(a2 > 0, a2, 1.0), 0.0)
    return normalize(rel - axis * along) * outward


def _sphere_cone(center: V3, radius, x: V3):
    """(axis, cos_max, one_minus_cos_max, outside) of the cone the sphere subtends at x."""
    to_c = center - x
    dc2 = dot(to_c, to_c)
    outside = dc2 > radius * radius * 1.0001
    sin2 = jnp.where(outside, radius * radius / jnp.where(dc2 > 0, dc2, 1.0), 1.0)
    cos_max = jnp.sqrt(jnp.maximum(1.0 - sin2, 0.0))
    return normalize(to_c), cos_max, sin2 / (1.0 + cos_max), outside


# --- environment maps (see jgi.scene.tables.EnvironmentMap for the layout) --------------------

def _rotate(m: Array, v: V3, transpose: bool = False) -> V3:
    r = (lambda i, j: m[j, i]) if transpose else (lambda i, j: m[i, j])  # noqa: E731
    return V3(r(0, 0) * v.x + r(0, 1) * v.y + r(0, 2) * v.z,
              r(1, 0) * v.x + r(1, 1) * v.y + r(1, 2) * v.z,
              r(2, 0) * v.x + r(2, 1) * v.y + r(2, 2) * v.z)


def _env_cell(env: EnvironmentMap, d: V3):
    """(row, column, x, y) of world direction d: the cell (r, c) between texel centres and the
    continuous texel coordinates (x in [0, W) from column 0's centre, y in [0, H - 1]); on an
    octahedral map the texel (r, c) holding d (x, y unused)."""
    H, W = env.shape
    v = _rotate(env.to_world, d, transpose=True)
    if env.octahedral:
        return _octahedral_texel(env, v) + (None, None)
    u = jnp.arctan2(v.x, -v.z) * jnp.float32(0.5 / np.pi) - jnp.float32(0.5 / W)
    u = u - jnp.floor(u)
    x = u * W
    y = jnp.arccos(jnp.clip(v.y, -1.0, 1.0)) * jnp.float32((H - 1) / np.pi)
    c = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, W - 1)
    r = jnp.clip(jnp.floor(y).astype(jnp.int32), 0, H - 2)
    return r, c, x, y


def _octahedral_texel(env: EnvironmentMap, local: V3):
    """(row, column) of the texel pbrt-v4's nearest lookup reads for a local direction:
    (floor(t N), floor(s N)) of its equal-area square point, a coordinate that reaches N (s or
    t exactly 1) wrapped as pbrt's WrapMode::OctahedralSphere (the square's edges fold at their
    midpoints: column N is column N - 1 of the row mirrored about the middle, then a row out of
    range is mirrored back with the column mirrored)."""
    N = env.shape[0]
    s, t = warps.equal_area_sphere_to_square(local)
    c = jnp.floor(s * N).astype(jnp.int32)
    r = jnp.floor(t * N).astype(jnp.int32)
    over = c >= N
    c, r = jnp.where(over, 2 * N - 1 - c, c), jnp.where(over, N - 1 - r, r)
    under, over = r < 0, r >= N
    c = jnp.where(under | over, N - 1 - c, c)
    r = jnp.where(under, -r, jnp.where(over, 2 * N - 1 - r, r))
    # stored once: each gather by (r, c) is a kernel of its own, and XLA recomputed the whole
    # chain (the samplers' searches too) in every one of them
    return _xla.materialize((jnp.clip(r, 0, N - 1), jnp.clip(c, 0, N - 1)))


def _env_lookup(env: EnvironmentMap, d: V3) -> V3:
    """Texel lookup towards world direction d: bilinear (Mitsuba 3's envmap ``eval``) or, on
    an octahedral map, the nearest texel (pbrt-v4's ImageInfiniteLight::ImageLe)."""
    W = env.shape[1]
    r, c, x, y = _env_cell(env, d)
    t = env.texels
    if env.octahedral:
        rgb = t[r, c]
        return V3(rgb[..., 0], rgb[..., 1], rgb[..., 2])
    wx = jnp.clip(x - c, 0.0, 1.0)
    wy = jnp.clip(y - r, 0.0, 1.0)
    c1 = jnp.where(c + 1 >= W, 0, c + 1)
    rgb = ((t[r, c] * (1 - wx)[..., None] + t[r, c1] * wx[..., None]) * (1 - wy)[..., None]
           + (t[r + 1, c] * (1 - wx)[..., None] + t[r + 1, c1] * wx[..., None]) * wy[..., None])
    return V3(rgb[..., 0], rgb[..., 1], rgb[..., 2])


def _env_cell_pdf(env: EnvironmentMap, r, c) -> Array:
    """Solid-angle density on cell (r, c): its probability over its solid angle (on an
    octahedral map every texel's, 4 pi / N^2)."""
    H, W = env.shape
    p = env.row_pmf[r] * env.col_pmf[r, c]
    if env.octahedral:
        return p * jnp.float32(H * W / (4 * np.pi))
    solid = (env.cos_edge[r] - env.cos_edge[r + 1]) * jnp.float32(2 * np.pi / W)
    ok = (solid > 0) & (p > 0)
    return jnp.where(ok, p / jnp.where(ok, solid, 1.0), 0.0)


def _search(cdf: Array, base, n: int, u: Array) -> Array:
    """Per lane, the first j in [0, n) with cdf[base + j] > u, for an inclusive CDF stored flat
    from ``base`` (binary search: one gather per halving, fused into the caller's kernel, where
    ``searchsorted`` would be a loop of kernels of its own)."""
    lo = jnp.zeros(jnp.shape(u), jnp.int32)
    hi = jnp.full(jnp.shape(u), n - 1, jnp.int32)
    for _ in range(int(np.ceil(np.log2(max(n, 2)))) + 1):
        mid = (lo + hi) // 2
        right = cdf[base + mid] <= u
        lo = jnp.where(right & (lo < hi), mid + 1, lo)
        hi = jnp.where(right | (lo >= hi), hi, mid)
    return jnp.minimum(lo, n - 1)


def _env_sample(env: EnvironmentMap, u1: Array, u2: Array) -> tuple[V3, Array]:
    """(world direction, solid-angle density) drawn from the map's distribution: a row of
    cells by the marginal, a cell by the row's conditional, then a point uniform in the cell
    (reusing each uniform's remainder): cos(theta) and phi on a latitude-longitude map, the
    square's (s, t) on an octahedral one."""
    H, W = env.shape
    rows = env.row_pmf.shape[0]
    r = _search(env.row_cdf, 0, rows, u1)
    col_cdf = env.col_cdf.reshape(-1)
    c = _search(col_cdf, r * W, W, u2)
    pr, pc = env.row_pmf[r], env.col_pmf.reshape(-1)[r * W + c]
    fr = jnp.clip((u1 - (env.row_cdf[r] - pr)) / jnp.where(pr > 0, pr, 1.0), 0.0, 1.0)
    fc = jnp.clip((u2 - (col_cdf[r * W + c] - pc)) / jnp.where(pc > 0, pc, 1.0), 0.0, 1.0)
    if env.octahedral:
        local = warps.equal_area_square_to_sphere((c.astype(jnp.float32) + fc) / W,
                                                  (r.astype(jnp.float32) + fr) / H)
        d = _xla.materialize(_rotate(env.to_world, local))   # as in _octahedral_texel
        # the density of the texel d is looked up in ((r, c) but where rounding puts d across
        # a texel edge): pdf_li's, and the radiance's texel
        return d, _env_pdf(env, d)
    c0, c1 = env.cos_edge[r], env.cos_edge[r + 1]
    cos_t = c0 + (c1 - c0) * fr
    sin_t = jnp.sqrt(jnp.maximum(1.0 - cos_t * cos_t, 0.0))
    phi = (c.astype(jnp.float32) + fc + 0.5) * jnp.float32(2 * np.pi / W)
    local = V3(sin_t * jnp.sin(phi), cos_t, -sin_t * jnp.cos(phi))
    return _rotate(env.to_world, local), _env_cell_pdf(env, r, c)


def _env_pdf(env: EnvironmentMap, d: V3) -> Array:
    r, c, _, _ = _env_cell(env, d)
    return _env_cell_pdf(env, r, c)


def sample_li(lights: Lights, x: V3, u_sel: Array, u1: Array, u2: Array) -> LightSample:
    """Sample a direction from x towards a light (next-event estimation)."""
    k = select_light(lights, u_sel)
    kind = take(lights.kind, k)
    pmf = take(lights.pmf, k)
    p0, e1, e2 = _take(lights.p0, k), _take(lights.e1, k), _take(lights.e2, k)
    emission = _take(lights.emission, k)
    zero = jnp.zeros_like(u1)
    out = LightSample(V3(zero, zero, zero + 1), zero, V3(zero, zero, zero), zero, zero > 0,
                      zero > 0)
    kinds = lights.kinds

    def choose(sel, s: LightSample, acc: LightSample) -> LightSample:
        return LightSample(where(sel, s.wi, acc.wi), jnp.where(sel, s.dist, acc.dist),
                           where(sel, s.Li, acc.Li), jnp.where(sel, s.pdf, acc.pdf),
                           jnp.where(sel, s.delta, acc.delta), jnp.where(sel, s.valid, acc.valid))

    def towards(y: V3, n_light: V3, pdf_area, one_sided=True):
        v = y - x
        d2 = dot(v, v)
        inv = jnp.where(d2 > 0, _xla.rsqrt(jnp.where(d2 > 0, d2, 1.0)), 1.0)
        dist = d2 * inv
        wi = v * inv
        cos_l = -dot(wi, n_light)
        pdf = _area_to_solid_angle(pdf_area, d2, cos_l) * pmf
        ok = (pdf > 0) & (dist > 0)
        return LightSample(wi, dist, where(ok, emission, V3(zero, zero, zero)), pdf, zero > 0, ok)

    if AREA_QUAD in kinds or AREA_TRIANGLE in kinds:
        area = take(lights.area, k)
        inv_area = jnp.where(area > 0, _xla.recip(jnp.where(area > 0, area, 1.0)), 0.0)
        n_l = _take(lights.normal, k)
        if AREA_QUAD in kinds:
            s = towards(p0 + e1 * u1 + e2 * u2, n_l, inv_area)
            out = choose(kind == AREA_QUAD, s, out)
        if AREA_TRIANGLE in kinds:
            b1, b2 = warps.sample_uniform_triangle(u1, u2)
            s = towards(p0 + e1 * b1 + e2 * b2, n_l, inv_area)
            out = choose(kind == AREA_TRIANGLE, s, out)
    if AREA_DISK in kinds or AREA_CYLINDER in kinds:
        area = take(lights.area, k)
        inv_area = jnp.where(area > 0, _xla.recip(jnp.where(area > 0, area, 1.0)), 0.0)
        n_l = _take(lights.normal, k)
        if AREA_DISK in kinds:
            s = towards(disk_point(p0, e1, e2, u1, u2), n_l, inv_area)
            out = choose(kind == AREA_DISK, s, out)
        if AREA_CYLINDER in kinds:
            y, n_c = cylinder_point(p0, e1, e2, n_l, take(lights.radius, k), u1, u2)
            s = towards(y, n_c, inv_area)
            out = choose(kind == AREA_CYLINDER, s, out)
    if AREA_SPHERE in kinds:
        r = take(lights.radius, k)
        axis, cos_max, one_minus, outside = _sphere_cone(p0, r, x)
        # one_minus = sin^2 / (1 + cos) keeps small (distant) cones their true width in float32
        d_cone = to_world(warps.sample_uniform_cone(u1, u2, cos_max, one_minus), axis)
        # the sampled ray's nearest intersection with the sphere (tangent point if it grazes)
        oc = x - p0
        b = dot(oc, d_cone)
        closest = oc - d_cone * b
        disc = jnp.maximum(r * r - dot(closest, closest), 0.0)
        t = -b - jnp.sqrt(disc)
        pdf_cone = jnp.where(one_minus > 0,
                             1.0 / (2.0 * jnp.pi * jnp.where(one_minus > 0, one_minus, 1.0)), 0.0)
        ok = outside & (pdf_cone > 0)
        cone = LightSample(d_cone, t, where(ok, emission, V3(zero, zero, zero)), pdf_cone * pmf,
                           zero > 0, ok)
        # inside the sphere nothing is received: spheres emit outwards only (as ``emitted``)
        out = choose((kind == AREA_SPHERE) & outside, cone, out)
        out = choose((kind == AREA_SPHERE) & ~outside, out._replace(valid=zero > 0), out)
    if POINT in kinds or SPOT in kinds:
        v = p0 - x
        d2 = dot(v, v)
        dist = jnp.sqrt(d2)
        ok = d2 > 0
        wi = v / jnp.where(ok, dist, 1.0)
        inv_d2 = jnp.where(ok, 1.0 / jnp.where(ok, d2, 1.0), 0.0)
        if POINT in kinds:
            s = LightSample(wi, dist, emission * inv_d2, pmf, ok, ok)
            out = choose(kind == POINT, s, out)
        if SPOT in kinds:
            fall = spot_falloff(-dot(wi, _take(lights.direction, k)), take(lights.cos_total, k),
                                take(lights.cos_falloff, k), take(lights.spot_linear, k))
            s = LightSample(wi, dist, emission * (inv_d2 * fall), pmf, ok, ok & (fall > 0))
            out = choose(kind == SPOT, s, out)
    if DIRECTIONAL in kinds:
        s = LightSample(-_take(lights.direction, k), zero + jnp.inf, emission, pmf, zero == 0,
                        zero == 0)
        out = choose(kind == DIRECTIONAL, s, out)
    if ENVIRONMENT in kinds and lights.envmap is None:
        s = LightSample(warps.sample_uniform_sphere(u1, u2), zero + jnp.inf, emission,
                        pmf * warps.INV_4PI, zero > 0, zero == 0)
        out = choose(kind == ENVIRONMENT, s, out)
    elif ENVIRONMENT in kinds:
        d, pdf_d = _env_sample(lights.envmap, u1, u2)
        ok = pdf_d > 0
        s = LightSample(d, zero + jnp.inf, where(ok, emission * _env_lookup(lights.envmap, d),
                                                V3(zero, zero, zero)),
                        pmf * pdf_d, zero > 0, ok)
        out = choose(kind == ENVIRONMENT, s, out)
    return out


def pdf_li(lights: Lights, k: Array, x: V3, y: V3, n_y: V3) -> Array:
    """Solid-angle density (incl. selection) with which ``sample_li`` from x produces the point
    y on emitter element k (with geometric normal n_y); used by MIS when a BSDF-sampled ray hits
    an emitter. For the environment pass ``k = lights.environment``.

    ``n_y`` is the primitive's geometric normal (unflipped). Like ``sample_li`` and ``emitted``,
    the density is one-sided: zero when x is behind a quad or triangle emitter or inside (or on)
    a sphere emitter, where ``sample_li`` never produces y."""
    kk = jnp.maximum(k, 0)
    kind = take(lights.kind, kk)
    pmf = take(lights.pmf, kk)
    v = y - x
    d2 = dot(v, v)
    cos_l = -dot(v, n_y) * jnp.where(d2 > 0, _xla.rsqrt(jnp.where(d2 > 0, d2, 1.0)), 1.0)
    area = take(lights.area, kk)
    inv_area = jnp.where(area > 0, _xla.recip(jnp.where(area > 0, area, 1.0)), 0.0)
    pdf = _area_to_solid_angle(inv_area, d2, cos_l)
    kinds = lights.kinds
    if AREA_SPHERE in kinds:
        _, _, one_minus, outside = _sphere_cone(_take(lights.p0, kk), take(lights.radius, kk), x)
        pdf_cone = jnp.where(one_minus > 0,
                             1.0 / (2.0 * jnp.pi * jnp.where(one_minus > 0, one_minus, 1.0)), 0.0)
        pdf = jnp.where(kind == AREA_SPHERE, jnp.where(outside, pdf_cone, 0.0), pdf)
    if ENVIRONMENT in kinds:   # y is then a point along the direction to the environment
        env = (warps.INV_4PI if lights.envmap is None
               else _env_pdf(lights.envmap, normalize(y - x)))
        pdf = jnp.where(kind == ENVIRONMENT, env, pdf)
    return jnp.where(k >= 0, pdf * pmf, 0.0)


def emitted(lights: Lights, k: Array, n_y: V3, wo: V3) -> V3:
    """Radiance leaving emitter element k towards wo (zero behind one-sided emitters)."""
    kk = jnp.maximum(k, 0)
    e = _take(lights.emission, kk)
    front = (k >= 0) & (dot(n_y, wo) > EDGE_ON_COS)
    z = jnp.zeros_like(e.x)
    return where(front, e, V3(z, z, z))


def environment_radiance(lights: Lights, d: V3) -> V3:
    """Radiance arriving from the environment along -d (d: a ray's direction that escaped)."""
    if lights.environment < 0:
        z = jnp.zeros_like(d.x)
        return V3(z, z, z)
    e = _take(lights.emission, lights.environment)
    if lights.envmap is not None:
        return e * _env_lookup(lights.envmap, d)
    like = jnp.zeros_like(d.x)
    return V3(e.x + 0 * like, e.y + 0 * like, e.z + 0 * like)


def environment_pdf(lights: Lights, d: V3) -> Array:
    """Solid-angle density (incl. selection) with which ``sample_li`` draws direction d on the
    environment (0 without one)."""
    like = jnp.zeros_like(d.x)
    if lights.environment < 0:
        return like
    pmf = lights.pmf[lights.environment]
    if lights.envmap is None:
        return pmf * jnp.float32(0.25 / np.pi) + like
    return pmf * _env_pdf(lights.envmap, d)


def sample_emission(lights: Lights, u_sel, u1, u2, u3, u4) -> EmissionSample:
    """Sample a light path's first vertex and direction (photon emission, lecture rules)."""
    k = select_light(lights, u_sel)
    kind = take(lights.kind, k)
    pmf = take(lights.pmf, k)
    p0, e1, e2 = _take(lights.p0, k), _take(lights.e1, k), _take(lights.e2, k)
    emission = _take(lights.emission, k)
    kinds = lights.kinds
    zero = jnp.zeros_like(u1)
    Z = V3(zero, zero, zero)
    inv_pmf = jnp.where(pmf > 0, 1.0 / jnp.where(pmf > 0, pmf, 1.0), 0.0)
    out = EmissionSample(Z, Z, V3(zero, zero, zero + 1), Z, zero, zero, zero > 0, zero > 0, k)

    def choose(sel, s: EmissionSample, acc: EmissionSample) -> EmissionSample:
        return EmissionSample(*(where(sel, a, b) if isinstance(a, V3) else jnp.where(sel, a, b)
                                for a, b in zip(s, acc)))

    if any(kd in kinds for kd in AREA_KINDS):
        area = take(lights.area, k)
        inv_area = jnp.where(area > 0, 1.0 / jnp.where(area > 0, area, 1.0), 0.0)
        local = warps.sample_cosine_hemisphere(u3, u4)
        pdf_dir = warps.pdf_cosine_hemisphere(local.z)
        # L_e cos / (pmf (1/A) (cos/pi)) = L_e pi A / pmf
        w = emission * (jnp.pi * area * inv_pmf)

        def area_sample(y, n):
            ok = (area > 0) & (local.z > EDGE_ON_COS)   # as emitted() and pdf_emission_dir
            return EmissionSample(y, n, to_world(local, n), where(ok, w, Z), inv_area * pmf,
                                  pdf_dir, zero > 0, zero > 0, k)
        if AREA_QUAD in kinds:
            s = area_sample(p0 + e1 * u1 + e2 * u2, _take(lights.normal, k))
            out = choose(kind == AREA_QUAD, s, out)
        if AREA_TRIANGLE in kinds:
            b1, b2 = warps.sample_uniform_triangle(u1, u2)
            s = area_sample(p0 + e1 * b1 + e2 * b2, _take(lights.normal, k))
            out = choose(kind == AREA_TRIANGLE, s, out)
        if AREA_SPHERE in kinds:
            n = warps.sample_uniform_sphere(u1, u2)
            s = area_sample(p0 + n * take(lights.radius, k), n)
            out = choose(kind == AREA_SPHERE, s, out)
        if AREA_DISK in kinds:
            s = area_sample(disk_point(p0, e1, e2, u1, u2), _take(lights.normal, k))
            out = choose(kind == AREA_DISK, s, out)
        if AREA_CYLINDER in kinds:
            s = area_sample(*cylinder_point(p0, e1, e2, _take(lights.normal, k),
                                            take(lights.radius, k), u1, u2))
            out = choose(kind == AREA_CYLINDER, s, out)
    if POINT in kinds:
        d = warps.sample_uniform_sphere(u3, u4)
        s = EmissionSample(p0, Z, d, emission * (4.0 * jnp.pi * inv_pmf), pmf, zero + warps.INV_4PI,
                           zero == 0, zero > 0, k)
        out = choose(kind == POINT, s, out)
    if SPOT in kinds:
        axis = _take(lights.direction, k)
        ct, cf = take(lights.cos_total, k), take(lights.cos_falloff, k)
        d = to_world(warps.sample_uniform_cone(u3, u4, ct), axis)
        pdf_dir = warps.pdf_uniform_cone(ct)
        fall = spot_falloff(dot(d, axis), ct, cf, take(lights.spot_linear, k))
        w = emission * (fall * jnp.where(pdf_dir > 0, 1.0 / jnp.where(pdf_dir > 0, pdf_dir, 1.0),
                                         0.0) * inv_pmf)
        s = EmissionSample(p0, Z, d, w, pmf, pdf_dir, zero == 0, zero > 0, k)
        out = choose(kind == SPOT, s, out)
    if DIRECTIONAL in kinds or ENVIRONMENT in kinds:
        R = lights.bound_radius
        disc_x, disc_y = warps.sample_concentric_disc(u1, u2)
        disc_area = jnp.pi * R * R

        def parallel(d):
            s_, t_ = coordinate_system(d)
            p = lights.bound_center - d * R + (s_ * disc_x + t_ * disc_y) * R
            return p
        if DIRECTIONAL in kinds:
            d = _take(lights.direction, k)
            s = EmissionSample(parallel(d), d, d, emission * (disc_area * inv_pmf),
                               pmf / disc_area, zero + 1.0, zero > 0, zero == 0, k)
            out = choose(kind == DIRECTIONAL, s, out)
        if ENVIRONMENT in kinds and lights.envmap is None:
            d = -warps.sample_uniform_sphere(u3, u4)
            s = EmissionSample(parallel(d), d, d,
                               emission * (disc_area * 4.0 * jnp.pi * inv_pmf),
                               pmf / disc_area, zero + warps.INV_4PI, zero > 0, zero > 0, k)
            out = choose(kind == ENVIRONMENT, s, out)
        elif ENVIRONMENT in kinds:   # travelling along d: radiance arriving from -d
            w_env, pdf_w = _env_sample(lights.envmap, u3, u4)
            d = -w_env
            inv_pdf = jnp.where(pdf_w > 0, 1.0 / jnp.where(pdf_w > 0, pdf_w, 1.0), 0.0)
            s = EmissionSample(parallel(d), d, d,
                               emission * _env_lookup(lights.envmap, w_env)
                               * (disc_area * inv_pdf * inv_pmf),
                               pmf / disc_area, pdf_w, zero > 0, zero > 0, k)
            out = choose(kind == ENVIRONMENT, s, out)
    return out
