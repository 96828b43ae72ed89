"""Light tracing (particle tracing, t = 1): light subpaths connected to the pinhole camera.

Estimator (Veach 1997, sec. 10.2 with t = 1; the lecture's "visualize particles from light"):
a light subpath y_0 y_1 ... is started with ``lights.sample_emission`` (y_0 on a light, beta_1 =
L_e |cos| / (pmf p_pos p_dir)) and extended by BSDF sampling in importance mode. Every
non-specular vertex y_i is connected to the pinhole z_0 by a shadow ray; the contribution

    C = beta_i f(y_{i-1} -> y_i -> z_0) |cos theta_i| W_e(z_0 -> y_i) cos theta_cam / |y_i - z_0|^2

is splatted (scatter-add, ``.at[].add``: deterministic) into the pixel that y_i projects to.
W_e = 1 / (A cos^4) (jgi.physics.camera) integrates to one over the film, so with one light subpath
per pixel sample (P spp paths) the image is the sum of splats divided by spp. Light vertex y_0
of an area light is splatted too (s = 1: emitters seen directly, L_e |cos| / (pmf / area)).

What each direction cannot do (the lecture's "all one-bounce cases"):

* Forward path tracing with pure BSDF sampling **fails for point light sources**: a sampled
  direction never hits a point (or spot, or directional) light, so the image is black; light
  sampling saves the direct part, but L-D-S-E paths (a point light seen in a mirror) remain
  impossible for it.
* Light tracing **fails for a pinhole camera** wherever the camera sees a specular surface:
  the pinhole is a point, so a light path can only reach it by a deterministic connection,
  which a Dirac BSDF (mirror, glass) cannot make: L-...-S-E paths (mirror reflections,
  caustics *seen through* glass) are missing, and so is anything a light subpath would have to
  *hit the lens* to contribute. Directly visible point lights (a finite power on a point of the
  film) are left out as well, matching the path tracer; environment light seen directly is not
  rendered (its y_0 is on a bounding disc, not a surface).
* Light tracing is at its best where path tracing is at its worst: L-S-D-E caustics seen on
  diffuse surfaces (cornell_box_caustics), small or point lights.

Parameters: ``max_depth`` (path segments, as the path tracer's: 1 = emitters seen directly,
2 = direct lighting). No Russian roulette: light subpaths end at ``max_depth`` or absorption.
The subpath machinery (:class:`Vertices`, :func:`random_walk`, :func:`light_subpath`,
:func:`connect_camera`) and the splatting driver :func:`render_splats` are shared with BDPT.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import partial
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._xla import materialize
from ..core import rng, warps
from ..core.vec import EDGE_ON_COS, V3, dot, max_component, normalize, where
from ..drivers.chunked import sum_path_chunks
from ..physics import bsdf as B
from ..physics import camera as C
from ..physics import geometry as G
from ..physics import lights as LT
from ..scene.data import (
    AREA_QUAD,
    AREA_SPHERE,
    AREA_TRIANGLE,
    DIRECTIONAL,
    ENVIRONMENT,
    POINT,
    SPOT,
    Scene,
)
from .path_tracer import _material
from .registry import Estimator, Render, param, register

LIGHT_SALT = rng.SALTS["light_subpath"]  # light subpaths: a stream independent of the camera path's
LIGHT_DIMS0 = 5                # dims 0..4: sample_emission (selection, position, direction)
LIGHT_DIMS_PER_STEP = 3        # per bounce: lobe, u1, u2


# --- subpath vertices (struct of arrays, [K, N]) --------------------------------------------------

class Vertices(NamedTuple):
    """Vertices of a subpath, each field [K, N] (vertex index, path). Vertex 0 is the camera or
    the light; the densities are area-measure (pbrt-v4's Vertex::pdfFwd / pdfRev)."""
    p: V3             # position
    n: V3             # unit geometric normal (unflipped; zero for the camera and point lights)
    wo: V3            # unit direction towards the previous vertex of this subpath
    beta: V3          # throughput of the subpath up to this vertex (before its BSDF)
    pdf_fwd: Array    # area density of this vertex as its own subpath sampled it
    pdf_rev: Array    # area density of this vertex sampled from the next vertex (reverse walk)
    delta: Array      # Dirac BSDF at this vertex (mirror, glass): not connectable
    on_surface: Array  # a surface point (densities convert with |cos|); False: camera, point light
    valid: Array
    material: Array
    emitter: Array    # light element at this surface, -1 if none


def _cat(a: Vertices, b: Vertices) -> Vertices:
    return jax.tree_util.tree_map(lambda x, y: jnp.concatenate([x, y], 0), a, b)


def _row(v, i):
    """Row i (an int) or rows i (a static index list) of every leaf. Rows are taken by static
    slices, not a gather (which XLA's CPU backend runs as a slow, unfused loop)."""
    if isinstance(i, (int, np.integer, slice)):
        return jax.tree_util.tree_map(lambda x: x[i], v)
    return jax.tree_util.tree_map(lambda x: jnp.stack([x[int(k)] for k in i]), v)


def convert_density(pdf_solid: Array, d2: Array, cos_at: Array, on_surface: Array) -> Array:
    """Solid-angle density at one vertex -> area density at the other (pbrt's ConvertDensity):
    p_A = p_omega |cos theta| / d^2, the cosine only where the target is a surface point."""
    ok = d2 > 0
    c = jnp.where(on_surface, jnp.abs(cos_at), 1.0)
    return jnp.where(ok, pdf_solid * c / jnp.where(ok, d2, 1.0), 0.0)


class WalkState(NamedTuple):
    o: V3
    d: V3
    beta: V3
    pdf_dir: Array     # solid-angle pdf of d at the previous vertex (0 after a Dirac lobe)
    prev_p: V3
    prev_n: V3
    prev_surface: Array
    prev_delta: Array
    alive: Array


class Visit(NamedTuple):
    """What a walk's per-vertex callback sees (all [N])."""
    step: Array
    hit: G.Hit
    mp: B.MaterialParams
    wo: V3
    state: WalkState   # the state that produced this hit (beta, pdf_dir, previous vertex)
    valid: Array
    d2_prev: Array     # squared distance to the previous vertex
    u: Callable[[int], Array]


def random_walk(scene: Scene, key: Array, dim0: int, dims_per_step: int, n_steps: int,
                start: WalkState, mode: int, visit: Callable[[Visit], object] | None = None,
                uniform: Callable | None = None):
    """Extend a subpath by ``n_steps`` BSDF-sampled segments (pbrt-v4's RandomWalk).

    Random numbers come from the hashed stream ``key``, or, if ``uniform`` is given, from
    ``uniform(dim)`` (explicit primary samples, e.g. Metropolis; ``key`` is then unused).

    Returns (vertices 1..n_steps as :class:`Vertices` [n_steps, N], pdf_rev of vertex 0 [N],
    the stacked outputs of ``visit``). Each vertex's ``pdf_rev`` is filled in by the next step
    (the density of sampling it backwards from there); the last one's is 0."""
    mats = scene.materials
    kinds = mats.kinds

    def step(s: WalkState, j):
        base = dim0 + j * dims_per_step
        u = ((lambda k: rng.uniform(key, base + k)) if uniform is None  # noqa: E731
             else (lambda k: uniform(base + k)))
        hit = G.intersect(scene, s.o, s.d)
        valid = s.alive & hit.valid
        v = hit.p - s.prev_p
        d2 = dot(v, v)
        pdf_fwd = jnp.where(valid, convert_density(s.pdf_dir, d2, dot(hit.n, s.d), True), 0.0)
        mp = _material(mats, hit.material)
        wo = -s.d
        delta = B.is_delta(mp)
        extra = visit(Visit(j, hit, mp, wo, s, valid, d2, u)) if visit is not None else None
        # ---- BSDF sampling: the next direction, and the reverse density of the previous vertex
        bs = materialize(B.sample(kinds, mp, hit.n, wo, u(0), u(1), u(2), mode=mode))
        _, pdf_back = B.evaluate(kinds, mp, hit.n, bs.wi, wo)
        pdf_rev_prev = jnp.where(valid & ~delta,
                                 convert_density(pdf_back, d2, dot(s.prev_n, s.d), s.prev_surface),
                                 0.0)
        vert = Vertices(hit.p, hit.n, wo, s.beta, pdf_fwd, pdf_rev_prev, delta, valid, valid,
                        hit.material, jnp.where(valid, hit.emitter, -1))
        beta = s.beta * bs.weight
        alive = valid & bs.valid & (max_component(beta) > 0)
        nxt = WalkState(G.offset_origin(hit.p, hit.n, bs.wi), bs.wi, beta,
                        jnp.where(bs.delta, 0.0, bs.pdf), hit.p, hit.n, valid, delta, alive)
        return nxt, (vert, extra)

    _, (verts, extras) = jax.lax.scan(step, start, jnp.arange(n_steps))
    # shift: the value computed at step j belongs to vertex j (the one before the hit)
    pdf_rev0 = verts.pdf_rev[0]
    pdf_rev = jnp.concatenate([verts.pdf_rev[1:], jnp.zeros_like(verts.pdf_rev[:1])], 0)
    return verts._replace(pdf_rev=pdf_rev), pdf_rev0, extras


# --- lights as path vertices ---------------------------------------------------------------------

def pdf_light_origin(lights, k: Array) -> Array:
    """Area density (incl. selection) with which a light subpath starts at a point of element k
    (pbrt's PdfLightOrigin): pmf / area for area lights; the pmf for point and spot lights."""
    kk = jnp.maximum(k, 0)
    area = lights.area[kk]
    kind = lights.kind[kk]
    is_area = (kind == AREA_QUAD) | (kind == AREA_TRIANGLE) | (kind == AREA_SPHERE)
    inv_area = jnp.where(area > 0, 1.0 / jnp.where(area > 0, area, 1.0), 0.0)
    return jnp.where(k >= 0, lights.pmf[kk] * jnp.where(is_area, inv_area, 1.0), 0.0)


def pdf_emission_dir(lights, k: Array, n_y: V3, w: V3) -> Array:
    """Solid-angle density with which ``sample_emission`` leaves element k in direction w from
    a point with normal n_y (pbrt's PdfLight before conversion): cos / pi for area lights (one
    side), 1 / 4 pi for point lights, uniform in the cone for spots."""
    kk = jnp.maximum(k, 0)
    kind = lights.kind[kk]
    cos_y = dot(n_y, w)
    pdf = jnp.where(cos_y > EDGE_ON_COS, cos_y * jnp.float32(1.0 / np.pi), 0.0)
    kinds = lights.kinds
    if POINT in kinds:
        pdf = jnp.where(kind == POINT, warps.INV_4PI, pdf)
    if SPOT in kinds:
        axis = V3(lights.direction.x[kk], lights.direction.y[kk], lights.direction.z[kk])
        ct = lights.cos_total[kk]
        inside = dot(w, axis) >= ct
        pdf = jnp.where(kind == SPOT, jnp.where(inside, warps.pdf_uniform_cone(ct), 0.0), pdf)
    return jnp.where(k >= 0, pdf, 0.0)


def light_normal(lights, k: Array, y: V3) -> tuple[V3, Array]:
    """(normal, on_surface) at point y of light element k (zero normal for point/spot)."""
    kk = jnp.maximum(k, 0)
    kind = lights.kind[kk]
    n = V3(lights.normal.x[kk], lights.normal.y[kk], lights.normal.z[kk])
    if AREA_SPHERE in lights.kinds:
        c = V3(lights.p0.x[kk], lights.p0.y[kk], lights.p0.z[kk])
        n = where(kind == AREA_SPHERE, normalize(y - c), n)
    on = (kind == AREA_QUAD) | (kind == AREA_TRIANGLE) | (kind == AREA_SPHERE)
    z = jnp.zeros_like(y.x)
    return where(on, n, V3(z, z, z)), on


def is_infinite(lights, k: Array) -> Array:
    kind = lights.kind[jnp.maximum(k, 0)]
    return (kind == DIRECTIONAL) | (kind == ENVIRONMENT)


class LightPath(NamedTuple):
    vertices: Vertices   # [max_depth, N]: vertex 0 on the light, then max_depth - 1 bounces
    delta_light: Array   # point, spot (delta position) or directional (delta direction)
    element: Array       # the light element


def light_subpath(scene: Scene, key: Array, max_depth: int, infinite: bool = False,
                  uniform: Callable | None = None) -> LightPath:
    """Light subpath y_0 .. y_{max_depth-1} (enough for every strategy with t >= 1).

    ``uniform(dim)``, if given, replaces the hashed stream ``key`` (explicit primary samples).

    ``infinite=False`` drops subpaths that start on directional or environment lights (their
    y_0 is a point of a bounding disc, not of the scene); BDPT reaches those lights through the
    camera subpath only. Light tracing keeps them (``infinite=True``)."""
    lights = scene.lights
    u = (lambda k: rng.uniform(key, k)) if uniform is None else uniform  # noqa: E731
    em = LT.sample_emission(lights, u(0), u(1), u(2), u(3), u(4))
    inf = is_infinite(lights, em.element)
    ok = (em.pdf_pos > 0) & (max_component(em.weight) > 0)
    if not infinite:
        ok = ok & ~inf
    on_surface = ~em.delta_pos & ~inf
    z = jnp.zeros_like(em.pdf_pos)
    delta_light = em.delta_pos | em.delta_dir
    le = LT.emitted(lights, jnp.where(on_surface, em.element, -1), em.n, em.d)
    v0 = Vertices(em.p, em.n, V3(z, z, z), le, em.pdf_pos, z, z > 0, on_surface, ok,
                  jnp.zeros_like(em.element), em.element)
    v0 = jax.tree_util.tree_map(lambda x: x[None], v0)
    if max_depth <= 1:
        return LightPath(v0, delta_light, em.element)
    start = WalkState(G.offset_origin(em.p, em.n, em.d), em.d, em.weight,
                      em.pdf_dir, em.p, em.n, on_surface, z > 0, ok)
    verts, pdf_rev0, _ = random_walk(scene, key, LIGHT_DIMS0, LIGHT_DIMS_PER_STEP, max_depth - 1,
                                     start, B.IMPORTANCE, uniform=uniform)
    v0 = v0._replace(pdf_rev=pdf_rev0[None])
    return LightPath(_cat(v0, verts), delta_light, em.element)


# --- t = 1: connecting a light vertex to the pinhole ------------------------------------------------

class CameraConnection(NamedTuple):
    pixel: Array       # flat pixel index (-1 outside the frame)
    value: V3          # unweighted contribution if unoccluded
    shadow: tuple      # (origin, direction, t_max) of the shadow ray towards the pinhole
    pdf_cam: Array     # camera's area density for q_{s-1} (its pdf_rev under this strategy)
    pdf_q_rev: Array   # BSDF solid-angle density at q_{s-1} from the camera towards q_{s-2}
    ok: Array


def connect_camera(scene: Scene, q: Vertices) -> CameraConnection:
    """Connect surface vertices q (any array shape) to the pinhole (strategy t = 1)."""
    cam = scene.camera
    kinds = scene.materials.kinds
    proj = C.project(cam, q.p)
    w = proj.wi                                  # from q towards the pinhole
    mp = _material(scene.materials, q.material)
    f, _ = B.evaluate(kinds, mp, q.n, q.wo, w)
    _, pdf_q_rev = B.evaluate(kinds, mp, q.n, w, q.wo)
    cos_q = jnp.abs(dot(q.n, w))
    d2 = proj.dist * proj.dist
    inv_d2 = jnp.where(d2 > 0, 1.0 / jnp.where(d2 > 0, d2, 1.0), 0.0)
    cos_cam = -dot(w, cam.forward)
    # W_e / p(pinhole as seen from q) with p = d^2 / cos_cam (pbrt's Camera::SampleWi)
    we_term = proj.importance * cos_cam * inv_d2
    ok = q.valid & ~q.delta & proj.visible
    value = where(ok, q.beta * f * (cos_q * we_term), V3.full(0.0, cos_q))
    W, H = cam.width, cam.height
    ix = jnp.clip(jnp.floor(proj.px).astype(jnp.int32), 0, W - 1)
    iy = jnp.clip(jnp.floor(proj.py).astype(jnp.int32), 0, H - 1)
    pixel = jnp.where(ok, iy * W + ix, -1)
    shadow = G.shadow_ray(q.p, q.n, w, proj.dist)
    pdf_cam = jnp.where(ok, proj.pdf_dir * cos_q * inv_d2, 0.0)
    return CameraConnection(pixel, value, shadow, pdf_cam, pdf_q_rev, ok)


def occluded_many(scene: Scene, rays: list[tuple]) -> list[Array]:
    """One any-hit query for several batches of shadow rays (one kernel, not one per batch)."""
    shapes = [o.x.shape for o, _, _ in rays]
    flat = lambda a: a.reshape(-1)  # noqa: E731
    o = V3(*(jnp.concatenate([flat(r[0][c]) for r in rays]) for c in range(3)))
    d = V3(*(jnp.concatenate([flat(r[1][c]) for r in rays]) for c in range(3)))
    t = jnp.concatenate([flat(jnp.broadcast_to(r[2], s)) for r, s in zip(rays, shapes)])
    o, d, t = materialize((o, d, t))   # one buffer, read by every primitive test
    occ = G.occluded(scene, o, d, t)
    out, i = [], 0
    for s in shapes:
        n = int(np.prod(s))
        out.append(occ[i:i + n].reshape(s))
        i += n
    return out


# --- the splatting driver -------------------------------------------------------------------------

_COMPILED: dict = {}
DEFAULT_CHUNK = 1 << 13


def _accumulate(scene: Scene, seed, sample0, pixel0, total_left, *, path_fn, chunk, n_images):
    W, H = scene.camera.width, scene.camera.height
    P = W * H
    lane = jnp.arange(chunk, dtype=jnp.int32)

    def body(c, acc):
        img, bad = acc
        local = c * chunk + lane
        flat = pixel0 + local
        pixel = flat % P
        sample = sample0 + flat // P
        valid = local < total_left
        contribs = path_fn(scene, seed, pixel, sample)   # [(image, pixel [N] or -1, V3 [N])]
        # stacked to [M, N] first: one finiteness test and one scatter for all of them
        image = jnp.asarray(np.repeat([c[0] for c in contribs], chunk).reshape(-1, chunk))
        px = jnp.stack([jnp.broadcast_to(c[1], (chunk,)) for c in contribs])
        L = V3(*(jnp.stack([c[2][k] for c in contribs]) for k in range(3)))
        finite = jnp.isfinite(L.x) & jnp.isfinite(L.y) & jnp.isfinite(L.z)
        bad = bad + jnp.sum(valid & (px >= 0) & ~finite)
        keep = valid & (px >= 0) & finite
        vals = jnp.stack([jnp.where(keep, c_, 0.0) for c_ in L], -1)
        img = img.at[image.reshape(-1), jnp.where(keep, px, 0).reshape(-1)].add(vals.reshape(-1, 3))
        return img, bad

    init = (jnp.zeros((n_images, P, 3), jnp.float32), jnp.int32(0))
    n_chunks = (total_left + chunk - 1) // chunk
    return jax.lax.fori_loop(0, n_chunks, body, init)


def render_splats(scene: Scene, path_fn: Callable, *, spp: int, seed: int, cache_key,
                  n_images: int = 1, progress: bool = False, chunk: int | None = None) -> np.ndarray:
    """Sum over spp samples per pixel of ``path_fn(scene, seed, pixel, sample)``'s contributions,
    each (image index, flat pixel (-1: none), V3 value) and splatted anywhere in the film, divided
    by spp: shape (n_images, H, W, 3). Path (pixel, sample) draws from the stream (seed, pixel,
    sample) whatever the chunking; the scatter-add is sequential, so results are reproducible."""


    W, H = scene.camera.width, scene.camera.height
    P = W * H
    total = P * spp
    chunk = chunk or min(DEFAULT_CHUNK, 1 << max(int(np.ceil(np.log2(P))), 8))
    key = (cache_key, chunk, n_images)
    fn = _COMPILED.get(key)
    if fn is None:
        fn = jax.jit(partial(_accumulate, path_fn=path_fn, chunk=chunk, n_images=n_images))
        _COMPILED[key] = fn
    img, bad = sum_path_chunks(fn, scene, seed, total, chunk * 4, progress)
    if bad:
        warnings.warn(f"{bad} path contributions were not finite and were dropped", RuntimeWarning)
    return img.reshape(n_images, H, W, 3) / np.float32(spp)


# --- the light tracer ----------------------------------------------------------------------------

@dataclass(frozen=True)
class LightTracerConfig:
    """The light tracer's parameters (static)."""

    max_depth: int = param(8, "maximum path segments (1 = emitters only, 2 = direct light)",
                           minimum=1, maximum=64)


def light_key(seed, pixel, sample) -> Array:
    return rng.derive(rng.path_key(seed, pixel, sample), LIGHT_SALT)


def trace_light_paths(scene: Scene, cfg: LightTracerConfig, seed, pixel: Array, sample: Array):
    """One light subpath per (pixel, sample), connected to the camera at every vertex."""
    lights = scene.lights
    path = light_subpath(scene, light_key(seed, pixel, sample), cfg.max_depth, infinite=True)
    v = path.vertices
    out = []
    # ---- s = 1: an area light seen directly (y_0 splatted with L_e / p(y_0)) ----
    y0 = _row(v, 0)
    proj = C.project(scene.camera, y0.p)
    le = LT.emitted(lights, jnp.where(y0.on_surface, path.element, -1), y0.n, proj.wi)
    d2 = proj.dist * proj.dist
    cos_cam = -dot(proj.wi, scene.camera.forward)
    g = jnp.abs(dot(y0.n, proj.wi)) * cos_cam / jnp.where(d2 > 0, d2, 1.0)
    pdf0 = y0.pdf_fwd
    ok0 = y0.valid & y0.on_surface & proj.visible & (pdf0 > 0)
    val0 = where(ok0, le * (proj.importance * g / jnp.where(ok0, pdf0, 1.0)), V3.full(0.0, g))
    W = scene.camera.width
    pix0 = jnp.where(ok0, jnp.clip(jnp.floor(proj.py).astype(jnp.int32), 0, scene.camera.height - 1) * W
                     + jnp.clip(jnp.floor(proj.px).astype(jnp.int32), 0, W - 1), -1)
    rays = [G.shadow_ray(y0.p, y0.n, proj.wi, proj.dist)]
    # ---- s >= 2: every surface vertex of the light subpath, all at once ([max_depth - 1, N]) ----
    if cfg.max_depth > 1:
        conn = connect_camera(scene, _row(v, slice(1, None)))
        rays.append(conn.shadow)
    occ = occluded_many(scene, rays)
    out.append((0, jnp.where(occ[0], -1, pix0), val0))
    if cfg.max_depth > 1:
        for i in range(cfg.max_depth - 1):
            out.append((0, jnp.where(occ[1][i], -1, conn.pixel[i]), _row(conn.value, i)))
    return out


def render(scene: Scene, cfg: LightTracerConfig = LightTracerConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """The light-traced image, (H, W, 3) float32 (no stats)."""
    if scene.lights.count == 0:
        H, W = scene.camera.height, scene.camera.width
        return Render(np.zeros((H, W, 3), np.float32), {})
    fn = lambda sc, sd, px, sm: trace_light_paths(sc, cfg, sd, px, sm)  # noqa: E731
    image = render_splats(scene, fn, spp=spp, seed=seed, cache_key=("lt", cfg), progress=progress)[0]
    return Render(image, {})


register(Estimator("lt", "light tracing: light subpaths splatted onto the pinhole film (t = 1)",
                   render, LightTracerConfig))
