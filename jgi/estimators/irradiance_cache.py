"""Irradiance caching (Ward, Rubinstein & Clear 1988) with Ward & Heckbert's (1992) gradients.

Indirect irradiance changes slowly over diffuse surfaces, so it is computed at sparse *records*
and interpolated (the lecture: "store illumination at sparse points, look up cached
illumination"). A record at x_i with normal n_i stores

    E_i  = (pi / (M N)) sum_jk L_jk                      (final gathering: M x N stratified,
                                                          cosine-distributed directions)
    R_i  = harmonic mean distance to the surfaces the gather rays hit
    grad_r E_i = (pi / (M N)) sum_k v_k sum_j tan(theta_j) L_jk       (rotation gradient)
    grad_t E_i = sum_k [ u_k (2 pi / N) sum_{j>=1} sin(theta_j-) cos^2(theta_j-) /
                          min(r_{j-1,k}, r_jk) (L_jk - L_{j-1,k})
                        + v_k- sum_j (sin(theta_j+) - sin(theta_j-)) / min(r_jk, r_{j,k-1})
                          (L_jk - L_{j,k-1}) ]                       (translation gradient)

with theta_j- = asin(sqrt(j / M)), theta_j+ = asin(sqrt((j + 1) / M)), u_k the base-plane
direction at phi_k, v_k at phi_k + pi/2 and v_k- at 2 pi k / N + pi/2. A point x with normal n
uses every record with Ward's weight

    w_i(x, n) = 1 / ( |x - x_i| / R_i + sqrt(1 - n . n_i) )  >  1 / a

that is not behind it ((x - x_i) . (n + n_i) / 2 >= -eps) and faces the same way (n . n_i > 0):

    E(x) = sum_i w_i (E_i + (n_i x n) . grad_r E_i + (x - x_i) . grad_t E_i) / sum_i w_i.

Records are created in passes: first at stratified pixels' first diffuse hits, then wherever
the criterion fails, until every query point is covered; points still uncovered after the last
pass are gathered directly. Gather rays are counted (``CacheStats``), so experiments compare
caches and plain final gathering by work done, not by time.

The incident radiance L_jk of a gather ray is the path tracer's estimate of the light reflected
at the surface it hits (its emission excluded: direct light is computed separately by shadow
rays, as in Jensen's split). Records are looked up by brute force over a padded table; the
tables here hold thousands of records, where that is faster on the CPU than a hash grid.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..core import rng
from ..core.vec import V3, coordinate_system, cross, dot, length, where
from ..physics import geometry
from ..physics.lights import emitted, environment_radiance
from ..scene.tables import Scene
from ..transport import density, hash_grid
from ..transport.photons import trace_photons
from ..transport.visible_points import face_viewer, trace_to_diffuse, visible_points
from .path_tracer import PathTracerConfig, radiance
from .registry import Estimator, Render, param, register

_SALT = rng.SALTS["irradiance_gather"]


class Records(NamedTuple):
    p: V3
    n: V3
    E: V3          # indirect irradiance (rgb)
    R: Array       # harmonic mean distance (clamped)
    gr: tuple      # rotation gradients (V3 per channel r, g, b)
    gt: tuple      # translation gradients (V3 per channel)
    valid: Array


@dataclass(frozen=True)
class CacheConfig:
    """The irradiance cache's parameters. The gather kernels see only the gather settings
    (:meth:`gather_settings`, static): one compilation serves every a, spacing and pass count."""

    a: float = param(0.2, "Ward's error threshold (smaller: more records)", minimum=1e-4,
                     maximum=10.0)
    gather_m: int = param(8, "final-gather strata in theta", minimum=1, maximum=256)
    gather_n: int = param(24, "final-gather strata in phi", minimum=1, maximum=512)
    spacing: int = param(8, "first-pass record spacing in pixels", minimum=1)
    passes: int = param(4, "refinement passes (spacing halves each pass)", minimum=0, maximum=16)
    cached: bool = param(True, "false: plain final gathering at every shading point")
    gradients: bool = param(True, "use rotation and translation gradients")
    photons: int = param(0, "> 0: gather rays read a global photon map of this many photons "
                         "(Jensen); 0: the path tracer", minimum=0)
    photon_k: int = param(50, "photons in each gather estimate", minimum=1, maximum=1024)
    per_pass: int = 4096        # new records per refinement pass (at most)
    r_min: float = 0.01         # clamp of R_i, relative to the scene's bounding radius
    r_max: float = 0.5
    max_depth: int = 8          # specular chains of camera and gather rays
    pt: PathTracerConfig = PathTracerConfig(max_depth=7)   # the gather rays' radiance

    def gather_settings(self) -> "CacheConfig":
        """The compile key of the gather kernels: the fields they do not read at fixed values."""
        return dataclasses.replace(self, a=0.0, spacing=1, passes=0, per_pass=1, cached=True,
                                   photons=0, photon_k=1)


@dataclass
class CacheStats:
    records: int = 0          # records made
    direct_points: int = 0    # points gathered directly (uncached, or not covered by records)
    gather_rays: int = 0      # gather rays traced, records and direct points together
    passes: int = 0           # refinement passes run
    history: list = field(default_factory=list)   # (records, uncovered points) per pass


class CacheResult(NamedTuple):
    E: np.ndarray             # [3, n] indirect irradiance at the shading points
    records: np.ndarray       # indices of the points where records were made
    stats: CacheStats


# --- final gathering ------------------------------------------------------------------------------

def _gather_dirs(cfg: CacheConfig, u1, u2):
    """Stratified cosine-distributed local directions; u1, u2 [..., M, N]."""
    M, N = cfg.gather_m, cfg.gather_n
    j = jnp.arange(M, dtype=jnp.float32)[:, None]
    k = jnp.arange(N, dtype=jnp.float32)[None, :]
    sin2 = (j + u1) / M
    sin_t = jnp.sqrt(sin2)
    cos_t = jnp.sqrt(jnp.maximum(1.0 - sin2, 0.0))
    phi = 2.0 * jnp.pi * (k + u2) / N
    return sin_t, cos_t, phi


def _gather_rays(scene: Scene, cfg: CacheConfig, seed, ids, p: V3, n: V3, ng: V3 | None = None):
    """The M x N stratified gather rays at points p about normals n (the shading normals where
    there are, whose geometric normals ``ng`` offset the rays): (origins, directions, key,
    angles, frame)."""
    M, N = cfg.gather_m, cfg.gather_n
    key = rng.derive(rng.path_key(seed, ids[:, None, None] * (M * N) +
                                  jnp.arange(M * N, dtype=jnp.int32).reshape(1, M, N), 0), _SALT)
    u1, u2 = rng.uniform(key, 0), rng.uniform(key, 1)
    sin_t, cos_t, phi = _gather_dirs(cfg, u1, u2)
    s, t = coordinate_system(n)
    ex = lambda v: V3(*(c[:, None, None] for c in v))
    s3, t3, n3 = ex(s), ex(t), ex(n)
    d = s3 * (sin_t * jnp.cos(phi)) + t3 * (sin_t * jnp.sin(phi)) + n3 * cos_t
    o = geometry.offset_origin(ex(p), n3 if ng is None else ex(ng), d)
    flat = lambda v: V3(*(c.reshape(-1) for c in jnp.broadcast_arrays(*v)))
    return flat(o), flat(d), key.reshape(-1), (sin_t, cos_t, phi), (s, t)


@partial(jax.jit, static_argnames=("cfg",))
def gather(scene: Scene, cfg: CacheConfig, seed, ids, p: V3, n: V3, ng: V3 | None = None):
    """Final gathering at points p (normals n facing the viewer: the shading normals in a
    scene with vertex normals, then ``ng`` the geometric ones): E, R and gradients, with the
    radiance of each gather ray estimated by the path tracer."""
    K = p.x.shape[0]
    of, df, kf, angles, frame = _gather_rays(scene, cfg, seed, ids, p, n, ng)
    hit = geometry.intersect(scene, of, df)
    Le = (emitted(scene.lights, hit.emitter, hit.n, -df) if scene.lights.count
          else V3(*(0 * of.x,) * 3))
    if scene.lights.environment >= 0:   # an escaped gather ray's environment is direct light too
        Le = where(hit.valid, Le, environment_radiance(scene.lights, df))
    L = radiance(scene, cfg.pt, lambda dim: rng.uniform(kf, dim + 2), of, df)
    L = V3(*(jnp.maximum(jnp.where(jnp.isfinite(a), a - b, 0.0), 0.0) for a, b in zip(L, Le)))
    r = jnp.where(hit.valid, hit.t, jnp.inf)
    return _record(scene, cfg, K, L, r, angles, frame)


@partial(jax.jit, static_argnames=("cfg",))
def _gather_hits(scene: Scene, cfg: CacheConfig, seed, ids, p: V3, n: V3, ng: V3 | None = None):
    """Gather rays followed through specular chains to the diffuse surfaces they reach."""
    of, df, kf, angles, frame = _gather_rays(scene, cfg, seed, ids, p, n, ng)
    hit = geometry.intersect(scene, of, df)
    v = trace_to_diffuse(scene, lambda k: rng.uniform(kf, k + 2), of, df, max_depth=cfg.max_depth,
                         light_samples=0, lookup_rough=False)
    return face_viewer(v), jnp.where(hit.valid, hit.t, jnp.inf), angles, frame


_record_jit = jax.jit(
    lambda scene, cfg, K, L, r, angles, frame: _record(scene, cfg, K, L, r, angles, frame),
    static_argnames=("cfg", "K"))


def gather_photons(scene: Scene, cfg: CacheConfig, seed, ids, p: V3, n: V3, grid, *, k: int,
                   radius: float, cap: int | None = None, ng: V3 | None = None):
    """Final gathering against a global photon map (Jensen's split): each gather ray's radiance
    is the photon estimate of the light reflected at the diffuse surface it reaches."""
    K = p.x.shape[0]
    v, r, angles, frame = _gather_hits(scene, cfg, seed, ids, p, n, ng)
    Lp = density.estimate_at_points(scene, grid, v.p, v.n, v.wo, v.material, radius, cap=cap,
                                    k=k, kind="box", thickness=None, filter_params={}, uv=v.uv,
                                    ns=v.ns)
    found = np.asarray(v.found)
    L = V3(*(jnp.asarray(np.where(found, np.asarray(b) * c, 0.0)) for b, c in zip(v.beta, Lp)))
    return _record_jit(scene, cfg, K, L, r, angles, frame)


def _record(scene: Scene, cfg: CacheConfig, K: int, L: V3, r, angles, frame):
    """E, R and Ward-Heckbert gradients from the gather rays' radiance L and hit distances r."""
    M, N = cfg.gather_m, cfg.gather_n
    sin_t, cos_t, phi = angles
    s, t = frame
    cp, sp = jnp.cos(phi), jnp.sin(phi)
    L = V3(*(c.reshape(K, M, N) for c in L))
    r = r.reshape(K, M, N)
    E = V3(*(jnp.pi / (M * N) * jnp.sum(c, axis=(1, 2)) for c in L))
    inv_r = jnp.sum(jnp.where(jnp.isfinite(r), 1.0 / jnp.maximum(r, 1e-9), 0.0), axis=(1, 2))
    scale = scene.lights.bound_radius
    R = jnp.clip(jnp.where(inv_r > 0, (M * N) / jnp.maximum(inv_r, 1e-30), jnp.inf),
                 cfg.r_min * scale, cfg.r_max * scale)
    if not cfg.gradients:
        zero = V3(*(jnp.zeros(K),) * 3)
        return E, R, (zero, zero, zero), (zero, zero, zero)
    # local base-plane directions
    tan_t = sin_t / jnp.maximum(cos_t, 1e-6)
    vkx, vky = -sp, cp                       # v_k = phi_k + pi/2
    jm = jnp.arange(M, dtype=jnp.float32)[:, None]
    kk = jnp.arange(N, dtype=jnp.float32)[None, :]
    sin_minus = jnp.sqrt(jm / M)
    cos2_minus = 1.0 - jm / M
    sin_plus = jnp.sqrt((jm + 1.0) / M)
    phi_minus = 2.0 * jnp.pi * kk / N
    ukx, uky = jnp.cos(phi), jnp.sin(phi)
    vmx, vmy = -jnp.sin(phi_minus), jnp.cos(phi_minus)
    r_up = jnp.minimum(r, jnp.roll(r, 1, axis=1))      # min(r_{j-1,k}, r_jk)
    r_side = jnp.minimum(r, jnp.roll(r, 1, axis=2))    # min(r_jk, r_{j,k-1})
    finite = lambda x: jnp.where(jnp.isfinite(x) & (x > 0), x, jnp.inf)
    gr, gt = [], []
    for c in L:
        # rotation: (pi/(MN)) sum v_k tan(theta) L
        w = jnp.pi / (M * N) * tan_t * c
        grx, gry = jnp.sum(w * vkx, axis=(1, 2)), jnp.sum(w * vky, axis=(1, 2))
        gr.append(s * grx + t * gry)
        # translation
        dL_up = c - jnp.roll(c, 1, axis=1)
        term_u = jnp.where(jm >= 1, sin_minus * cos2_minus / finite(r_up) * dL_up, 0.0)
        term_u = (2.0 * jnp.pi / N) * term_u
        dL_side = c - jnp.roll(c, 1, axis=2)
        term_v = (sin_plus - sin_minus) / finite(r_side) * dL_side
        gtx = jnp.sum(term_u * ukx + term_v * vmx, axis=(1, 2))
        gty = jnp.sum(term_u * uky + term_v * vmy, axis=(1, 2))
        gt.append(s * gtx + t * gty)
    return E, R, tuple(gr), tuple(gt)


# --- interpolation -------------------------------------------------------------------------------

def ward_weight(x: V3, n: V3, rp: V3, rn: V3, R) -> Array:
    """Ward's weight, zero for records behind x or facing away (never across opposed normals)."""
    diff = x - rp
    dist = length(diff)
    nn = dot(n, rn)
    w = 1.0 / jnp.maximum(dist / R + jnp.sqrt(jnp.maximum(1.0 - nn, 0.0)), 1e-6)
    behind = dot(diff, (n + rn) * 0.5) < -0.01 * R
    return jnp.where((nn > 0) & ~behind, w, 0.0)


@jax.jit
def interpolate(rec: Records, x: V3, n: V3, a):
    """(E(x), sum of accepted weights) by Ward's interpolation over all records."""
    def body(i, acc):
        num, wsum = acc
        rp, rn = V3(rec.p.x[i], rec.p.y[i], rec.p.z[i]), V3(rec.n.x[i], rec.n.y[i], rec.n.z[i])
        w = ward_weight(x, n, rp, rn, rec.R[i])
        w = jnp.where(rec.valid[i] & (w > 1.0 / a), w, 0.0)
        rot = cross(rn, n)
        diff = x - rp
        new = []
        for c, (Ec, grc, gtc) in enumerate(zip(rec.E, rec.gr, rec.gt)):
            g_r = V3(grc.x[i], grc.y[i], grc.z[i])
            g_t = V3(gtc.x[i], gtc.y[i], gtc.z[i])
            e = Ec[i] + dot(rot, g_r) + dot(diff, g_t)
            new.append(num[c] + w * jnp.maximum(e, 0.0))
        return tuple(new), wsum + w

    z = jnp.zeros_like(x.x)
    num, wsum = jax.lax.fori_loop(0, rec.R.shape[0], body, ((z, z, z), z))
    E = V3(*(jnp.where(wsum > 0, c / jnp.where(wsum > 0, wsum, 1.0), 0.0) for c in num))
    return E, wsum


# --- the estimator --------------------------------------------------------------------------------

def _pad_records(recs: list[tuple], capacity: int) -> Records:
    """Concatenate record batches (numpy) and pad to ``capacity`` rows."""
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0, np.float32)
    parts = list(zip(*recs)) if recs else [[] for _ in range(7)]
    def v3(items):
        return V3(*(np.pad(cat([np.asarray(it[c]) for it in items]), (0, capacity - n))
                    for c in range(3)))
    n = sum(len(np.asarray(r[3])) for r in recs)
    p, nn, E, R = (v3(parts[0]), v3(parts[1]), v3(parts[2]),
                   np.pad(cat([np.asarray(x) for x in parts[3]]), (0, capacity - n),
                          constant_values=1.0))
    gr = tuple(v3([it[c] for it in parts[4]]) for c in range(3))
    gt = tuple(v3([it[c] for it in parts[5]]) for c in range(3))
    valid = np.arange(capacity) < n
    to = lambda t: jax.tree_util.tree_map(jnp.asarray, t)
    return to(Records(p, nn, E, R, gr, gt, valid))


def _capacity(n: int) -> int:
    return max(64, 1 << int(np.ceil(np.log2(max(n, 1)))))


class ShadingPoints(NamedTuple):
    p: np.ndarray        # [3, n] positions
    n: np.ndarray        # [3, n] normals facing the viewer (the shading normals, if any)
    found: np.ndarray    # [n] a non-specular vertex was reached
    ng: np.ndarray | None = None   # [3, n] geometric normals, where n are shading normals


def shading_points(v) -> ShadingPoints:
    """The shading points of visible points (:class:`jgi.transport.visible_points.DiffuseVertex`,
    normals facing the viewer): gathering and records use the shading normal, ray offsets the
    geometric one."""
    stack = lambda a: np.stack([np.asarray(c) for c in a])  # noqa: E731
    if v.ns is None:
        return ShadingPoints(stack(v.p), stack(v.n), np.asarray(v.found))
    return ShadingPoints(stack(v.p), stack(v.ns), np.asarray(v.found), stack(v.n))


class PhotonSource(NamedTuple):
    """Gather rays read radiance from this global photon map instead of the path tracer."""
    grid: object        # jgi.transport.hash_grid.HashGrid
    k: int = 50         # photons in the estimate
    radius: float = 0.08  # maximum search radius


def photon_source(scene: Scene, photons: int, seed: int, *, k: int = 50, radius: float = 0.08,
                  max_depth: int = 8) -> PhotonSource:

    grid = hash_grid.build_grid(trace_photons(scene, photons, seed=seed, max_depth=max_depth),
                                radius, cap=128)
    return PhotonSource(grid, k, float(grid.cell))


def irradiance(scene: Scene, pts: ShadingPoints, *, cfg: CacheConfig, seed: int = 0,
               raster: tuple | None = None, source: PhotonSource | None = None) -> CacheResult:
    """Indirect irradiance [3, n] at shading points, the indices of the records made, and the
    work done (:class:`CacheStats`); ``cfg.cached=False`` gathers at every point.

    Every gather at point i uses random stream (seed, i), so a record made at point i equals
    the uncached gather there: as a -> 0 the cache reproduces plain final gathering exactly.
    With a photon ``source`` the gather rays' radiance comes from the global photon map
    (Jensen's final gathering) instead of the path tracer.
    ``raster = (px, py)`` (pixel coordinates of the points) makes the passes hierarchical:
    pass k considers uncovered points on a pixel grid of spacing ``cfg.spacing / 2^k``, so
    records appear where the criterion fails, coarse to fine (Ward's lazy creation, in
    passes)."""
    stats = CacheStats()
    n_pts = len(pts.found)
    batch = 64
    # the gather kernel depends only on the gather settings: one compilation for every a
    gather_cfg = cfg.gather_settings()

    def compute(idx: np.ndarray):
        out = []
        for s0 in range(0, len(idx), batch):
            sel = idx[s0:s0 + batch]
            pad = np.pad(sel, (0, batch - len(sel)), mode="edge")
            take = lambda a: V3(*(jnp.asarray(c[pad]) for c in a))
            args = (scene, gather_cfg, jnp.uint32(seed), jnp.asarray(pad, jnp.int32), take(pts.p),
                    take(pts.n))
            ng = None if pts.ng is None else take(pts.ng)
            if source is None:
                E, R, gr, gt = gather(*args, ng)
            else:
                E, R, gr, gt = gather_photons(*args, source.grid, k=source.k,
                                              radius=source.radius, ng=ng)
            k = len(sel)
            cut = lambda t: jax.tree_util.tree_map(lambda a: np.asarray(a)[:k], t)
            out.append((V3(*pts.p[:, sel]), V3(*pts.n[:, sel]), cut(E), cut(R), cut(gr), cut(gt)))
            stats.gather_rays += k * cfg.gather_m * cfg.gather_n
        return out

    def fill(target, idx, outs):
        for o, s0 in zip(outs, range(0, len(idx), batch)):
            target[:, idx[s0:s0 + batch]] = np.stack([np.asarray(c) for c in o[2]])

    E_final = np.zeros((3, n_pts), np.float32)
    found = pts.found
    if not cfg.cached:
        idx = np.nonzero(found)[0]
        fill(E_final, idx, compute(idx))
        stats.direct_points = len(idx)
        return CacheResult(E_final, np.zeros(0, np.int64), stats)
    def on_grid(k):
        if raster is None:
            return np.ones(n_pts, bool)
        sp = max(1, cfg.spacing >> k)
        px, py = raster
        return ((px % sp) == sp // 2) & ((py % sp) == sp // 2)

    cand = np.nonzero(found & on_grid(0))[0]
    rec_idx = [cand]
    recs = compute(cand)
    covered = np.zeros(n_pts, bool)
    qp, qn = V3(*(jnp.asarray(c) for c in pts.p)), V3(*(jnp.asarray(c) for c in pts.n))
    for it in range(cfg.passes + 1):
        table = _pad_records(recs, _capacity(sum(len(r[3]) for r in recs)))
        E, wsum = interpolate(table, qp, qn, jnp.float32(cfg.a))
        covered = (np.asarray(wsum) > 0) & found
        uncovered = np.nonzero(found & ~covered)[0]
        stats.history.append((int(sum(len(r[3]) for r in recs)), len(uncovered)))
        if it == cfg.passes or len(uncovered) == 0:
            break
        stats.passes += 1
        new = np.nonzero(found & ~covered & on_grid(it + 1))[0]
        if len(new) > cfg.per_pass:
            new = new[:: -(-len(new) // cfg.per_pass)]
        rec_idx.append(new)
        recs += compute(new)
    stats.records = sum(len(r[3]) for r in recs)
    E_final[:] = np.stack([np.asarray(c) for c in E])
    rest = np.nonzero(found & ~covered)[0]
    fill(E_final, rest, compute(rest))
    stats.direct_points = len(rest)
    return CacheResult(E_final, np.concatenate(rec_idx), stats)


def shade(scene: Scene, cfg: CacheConfig, seed: int, spp: int):
    """The shading points of ``spp`` camera samples per pixel: their visible points, with the
    direct light found there (one light sample)."""
    W, H = scene.camera.width, scene.camera.height
    P = W * H
    pixel = jnp.tile(jnp.arange(P, dtype=jnp.int32), spp)
    sample = jnp.repeat(jnp.arange(spp, dtype=jnp.int32), P)
    return visible_points(scene, jnp.uint32(seed), pixel, sample, max_depth=cfg.max_depth,
                          light_samples=1, lookup_rough=False)


def render(scene: Scene, cfg: CacheConfig = CacheConfig(), *, spp: int = 1, seed: int = 0,
           progress: bool = False) -> Render:
    """Direct light + specular chains exactly, indirect diffuse light from the irradiance cache
    (``cfg.cached=False``: plain final gathering at every shading point, for comparison); with
    ``cfg.photons > 0`` the gather rays read a global photon map of that many photons.

    Stats: those of :class:`CacheStats` (records, direct_points, gather_rays, passes, history)."""
    W, H = scene.camera.width, scene.camera.height
    v = shade(scene, cfg, seed, spp)
    pts = shading_points(v)
    pix = np.arange(len(pts.found)) % (W * H)
    source = photon_source(scene, cfg.photons, seed, k=cfg.photon_k) if cfg.photons else None
    E, _, stats = irradiance(scene, pts, cfg=cfg, seed=seed, raster=(pix % W, pix // W),
                             source=source)
    if scene.materials.has_textures:
        albedo = np.stack([np.asarray(c) for c in
                           density.diffuse_reflectance(scene, v.material, v.uv)])
    else:
        kd = scene.materials.diffuse
        m = np.asarray(v.material)
        albedo = np.stack([np.asarray(kd.x)[m], np.asarray(kd.y)[m], np.asarray(kd.z)[m]])
    beta = np.stack([np.asarray(c) for c in v.beta])
    L = np.stack([np.asarray(c) for c in v.L]) + np.where(pts.found, beta * albedo / np.pi * E, 0.0)
    image = L.reshape(3, spp, H, W).mean(1).transpose(1, 2, 0).astype(np.float32)
    return Render(image, dataclasses.asdict(stats))


register(Estimator(
    "irradiance_cache",
    "direct light + specular chains, indirect diffuse light by final gathering with an "
    "irradiance cache (Ward 1988)", render, CacheConfig))
