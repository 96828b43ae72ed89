"""Photon mapping (Jensen 1996, 2001) and its progressive forms (Hachisuka et al. 2008, 2009).

All three start from the photon maps of :mod:`jgi.transport.photons` and the density estimate of
:mod:`jgi.transport.photon_map`, and see the scene from the camera through specular chains
(:func:`jgi.transport.subpath.visible_points`) to the first non-specular point x:

* ``pm`` - direct visualisation: L(x) = L_r estimated from the global map at x (every
  bounce of light, direct included, from photons). Fixed radius, or k nearest photons.
* ``pm_jensen`` - Jensen's split of the reflected radiance at x (the lecture's four
  integrals): direct light by shadow rays, specular/glossy by Monte Carlo (the chain),
  caustics (L S+ D) from the caustic map at x, and indirect diffuse by final gathering:
  ``final_gather`` cosine-distributed rays from x, each followed through specular surfaces to
  a diffuse point y where the global map gives the radiance (emitters and caustics seen by
  gather rays are skipped: they are counted by the other terms).
* ``ppm`` / ``sppm`` - progressive photon mapping: each pass shoots ``photons`` photons; every
  pixel keeps (N_i, R_i, tau_i) and, with M_i new photons within R_i,
      N_i <- N_i + alpha M_i,  R_i^2 <- R_i^2 (N_i + alpha M_i) / (N_i + M_i),
      tau_i <- (tau_i + Phi_i) R_new^2 / R_old^2,
  so the radius shrinks and the estimate L_i = tau_i / (pi R_i^2 T) is consistent as the
  number of passes T grows (alpha in (0, 1)). ``ppm`` keeps one visible point per pixel from
  the first pass (Hachisuka 2008); ``sppm`` traces a new jittered one every pass (2009), so
  anti-aliasing and glossy/depth effects converge too.
Only the diffuse part (k_d / pi) of a surface reflects photons in the estimates.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..core import rng
from ..core.vec import V3, coordinate_system
from ..core.warps import sample_cosine_hemisphere
from ..physics import bsdf as B
from ..physics import geometry as G
from ..scene.data import Scene
from ..transport import photon_map as PMap
from ..transport.photons import trace_photons
from ..transport.subpath import trace_to_diffuse, visible_points
from . import irradiance_cache as IC
from .registry import Estimator, Param, register

_SALT = 0x1B873593


def _pixels(scene, spp):
    P = scene.camera.width * scene.camera.height
    return (jnp.tile(jnp.arange(P, dtype=jnp.int32), spp),
            jnp.repeat(jnp.arange(spp, dtype=jnp.int32), P))


def _to_image(scene, L, spp):
    W, H = scene.camera.width, scene.camera.height
    return np.asarray(L, np.float32).reshape(3, spp, H, W).mean(1).transpose(1, 2, 0)


def render_pm(scene: Scene, *, spp: int = 4, seed: int = 0, photons: int = 200_000, radius: float = 0.05,
              k: int = 0, filter: str = "box", cone_k: float = 1.1,
              alpha: float = PMap.JENSEN_ALPHA, beta: float = PMap.JENSEN_BETA,
              cap: int | None = None, max_depth: int = 8, thickness: float | None = None,
              stats: dict | None = None):
    """Direct visualisation of the global photon map (see the module docstring)."""
    pm = trace_photons(scene, photons, seed=seed, max_depth=max_depth)
    grid = PMap.build_grid(pm, radius, cap=(cap or 128) if k > 0 else None)
    radius = float(grid.cell)
    pix, smp = _pixels(scene, spp)
    v = visible_points(scene, jnp.uint32(seed), pix, smp, max_depth=max_depth, light_samples=0)
    fp = dict(k=cone_k) if filter == "cone" else dict(alpha=alpha, beta=beta) if filter == "gaussian" else {}
    L, trunc = PMap.estimate_at_points(scene, grid, v.p, v.n, v.material, radius, cap=cap, k=k, kind=filter,
                                 thickness=thickness, filter_params=fp)
    found = np.asarray(v.found)
    beta_ = np.stack([np.asarray(c) for c in v.beta])
    total = np.stack([np.asarray(c) for c in v.L]) + np.where(found, beta_ * L, 0.0)
    if stats is not None:
        stats.update(stored=pm.count, truncated=trunc)
    return _to_image(scene, total, spp)


@partial(jax.jit, static_argnames=("n_gather", "max_depth"))
def _gather_points(scene: Scene, seed, ids, x: V3, n: V3, n_gather: int, max_depth: int):
    """Final-gather rays from x: the diffuse points they reach and the chain throughput."""
    key = rng.derive(rng.path_key(seed, ids[:, None] * n_gather + jnp.arange(n_gather)[None, :], 0), _SALT)
    u1, u2 = rng.uniform(key, 0), rng.uniform(key, 1)
    local = sample_cosine_hemisphere(u1, u2)
    s, t = coordinate_system(n)
    ex = lambda v: V3(*(c[:, None] for c in v))
    d = ex(s) * local.x + ex(t) * local.y + ex(n) * local.z
    o = G.offset_origin(ex(x), ex(n), d)
    flat = lambda v: V3(*(c.reshape(-1) for c in v))
    kf = key.reshape(-1)
    v = trace_to_diffuse(scene, lambda k: rng.uniform(kf, k + 2), flat(o), flat(d),
                         max_depth=max_depth, light_samples=0)
    return v._replace(n=B.facing(v.n, v.wo))


def render_jensen(scene: Scene, *, spp: int = 1, seed: int = 0, photons: int = 200_000,
                  caustic_photons: int = 50_000, k: int = 50, k_caustic: int = 50,
                  radius: float = 0.08, caustic_radius: float = 0.05, final_gather: int = 32,
                  caustics: bool = True, cap: int | None = None, max_depth: int = 8, filter: str = "box",
                  irradiance_cache: bool = False, cache_a: float = 0.2, stats: dict | None = None):
    """Jensen's two-pass method with the four-way split (see the module docstring)."""
    pm = trace_photons(scene, photons, seed=seed, max_depth=max_depth)
    grid = PMap.build_grid(pm, radius, cap=cap or 128)
    radius = float(grid.cell)
    pix, smp = _pixels(scene, spp)
    v = visible_points(scene, jnp.uint32(seed), pix, smp, max_depth=max_depth, light_samples=1)
    found = np.asarray(v.found)
    beta_ = np.stack([np.asarray(c) for c in v.beta])
    total = np.stack([np.asarray(c) for c in v.L])  # emission along the chain + direct light
    kdx = np.stack([np.asarray(c) for c in PMap.diffuse_reflectance(scene, v.material)])
    if caustics:
        cpm = trace_photons(scene, caustic_photons, seed=seed + 7919, max_depth=max_depth)
        cpm = cpm.select(cpm.caustic)
        if cpm.count:
            cgrid = PMap.build_grid(cpm, caustic_radius, cap=cap or 128)
            Lc, _ = PMap.estimate_at_points(scene, cgrid, v.p, v.n, v.material, float(cgrid.cell), cap=cap,
                                      k=k_caustic, kind=filter, thickness=None, filter_params={})
            total = total + np.where(found, beta_ * Lc, 0.0)
    # indirect diffuse by final gathering on the global map (at every point, or cached)
    if irradiance_cache:
        m = max(1, int(round(np.sqrt(final_gather / 3))))  # Ward's strata: N ~ 3 M (phi vs theta)
        cfg = IC.CacheConfig(a=cache_a, gather_m=m, gather_n=max(1, final_gather // m), max_depth=max_depth)
        pts = IC.ShadingPoints(np.stack([np.asarray(c) for c in v.p]), np.stack([np.asarray(c) for c in v.n]),
                               found)
        W = scene.camera.width
        pix = np.arange(len(found)) % (W * scene.camera.height)
        E, _ = IC.irradiance(scene, pts, cfg=cfg, cached=True, seed=seed, raster=(pix % W, pix // W),
                             source=IC.PhotonSource(grid, k, radius))
        ind = E / np.pi  # cosine-weighted gathering: the mean gathered radiance is E / pi
    else:
        idx = np.nonzero(found)[0]
        ind = np.zeros((3, len(found)), np.float32)
        batch = max(1, 1024 // final_gather)
        for s0 in range(0, len(idx), batch):
            sel = idx[s0:s0 + batch]
            pad = np.pad(sel, (0, batch - len(sel)), mode="edge")
            take = lambda vv: V3(*(jnp.asarray(np.asarray(c)[pad]) for c in vv))
            g = _gather_points(scene, jnp.uint32(seed), jnp.asarray(pad, jnp.int32), take(v.p), take(v.n),
                               final_gather, max_depth)
            Lg, _ = PMap.estimate_at_points(scene, grid, g.p, g.n, g.material, radius, cap=cap, k=k,
                                      kind=filter, thickness=None, filter_params={})
            gb = np.stack([np.asarray(c) for c in g.beta])
            Lg = np.where(np.asarray(g.found), gb * Lg, 0.0).reshape(3, batch, final_gather).mean(-1)
            ind[:, sel] = Lg[:, : len(sel)]
    total = total + np.where(found, beta_ * kdx * ind, 0.0)
    if stats is not None:
        stats.update(stored=pm.count)
    return _to_image(scene, total, spp)


@partial(jax.jit, static_argnames=("cap",))
def _ppm_gather(scene: Scene, grid, x: V3, n: V3, material, r2, cap: int):
    g = PMap.gather(grid, x, n, cap, None)
    inside = g.d2 < r2[:, None]
    kd = PMap.diffuse_reflectance(scene, material)
    M = jnp.sum(inside, axis=-1).astype(jnp.float32)
    phi = V3(*(jnp.sum(jnp.where(inside, p, 0.0), axis=-1) * c / jnp.pi for p, c in zip(g.power, kd)))
    return M, phi, g.truncated


def render_progressive(scene: Scene, *, spp: int = 1, seed: int = 0, passes: int = 16,
                       photons: int = 50_000, radius: float = 0.1, alpha: float = 0.7,
                       stochastic: bool = True, cap: int | None = None, max_depth: int = 8,
                       stats: dict | None = None):
    """PPM (``stochastic=False``) or SPPM; ``spp`` visible points per pixel per pass."""
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    pix, smp = _pixels(scene, spp)
    n_pts = pix.shape[0]
    N = np.zeros(n_pts, np.float64)
    R2 = np.full(n_pts, radius * radius, np.float64)
    tau = np.zeros((3, n_pts), np.float64)
    direct = np.zeros((3, n_pts), np.float64)
    v = None
    truncated = False
    for t in range(passes):
        if stochastic or v is None:
            v = visible_points(scene, jnp.uint32(rng.lowbias32(jnp.uint32(seed * 65599 + t)).item()),
                               pix, smp, max_depth=max_depth, light_samples=0)
            found = np.asarray(v.found)
            beta_ = np.stack([np.asarray(c) for c in v.beta])
            Lv = np.stack([np.asarray(c) for c in v.L])
        direct += Lv
        pm = trace_photons(scene, photons, seed=int(rng.lowbias32(jnp.uint32(seed * 7919 + t + 1))),
                           max_depth=max_depth)
        grid = PMap.build_grid(pm, float(np.sqrt(R2.max())))
        cap_t = cap or PMap.auto_cap(grid)
        chunk = PMap.query_chunk(cap_t)
        M = np.zeros(n_pts)
        phi = np.zeros((3, n_pts))
        for s0 in range(0, n_pts, chunk):
            sl = slice(s0, s0 + chunk)
            sub = lambda vv: V3(*(c[sl] for c in vv))
            m, ph, tr = _ppm_gather(scene, grid, sub(v.p), sub(v.n), v.material[sl],
                                    jnp.asarray(R2[sl], jnp.float32), cap_t)
            M[sl] = np.asarray(m)
            phi[:, sl] = np.stack([np.asarray(c) for c in ph])
            truncated |= bool(np.any(np.asarray(tr)))
        M = np.where(found, M, 0.0)
        phi = np.where(found, beta_ * phi, 0.0)
        grow = N + alpha * M
        ratio = np.where(N + M > 0, grow / np.maximum(N + M, 1e-30), 1.0)
        tau = (tau + phi) * ratio
        R2 = R2 * ratio
        N = grow
    L = direct / passes + tau / (np.pi * R2 * passes)
    PMap.warn_truncated(truncated, cap_t, radius)
    if stats is not None:
        stats.update(radius_final=float(np.sqrt(R2.mean())), truncated=truncated)
    return _to_image(scene, L, spp)


FILTERS = ("box", "cone", "gaussian", "epanechnikov")

register(Estimator("pm", "photon mapping, direct visualisation of the global map",
                   lambda scene, *, spp, seed, progress=False, **p: render_pm(scene, spp=spp, seed=seed, **p),
                   (Param("photons", 200_000, "photons emitted", int, minimum=1),
                    Param("radius", 0.05, "estimate radius (k > 0: the maximum search radius)", float, minimum=1e-6),
                    Param("k", 0, "k nearest photons (0: fixed radius)", int, minimum=0, maximum=1024),
                    Param("filter", "box", "density filter", str, FILTERS),
                    Param("cone_k", 1.1, "cone filter k >= 1", float, minimum=1.0),
                    Param("alpha", PMap.JENSEN_ALPHA, "Gaussian filter alpha", float, minimum=1e-3),
                    Param("beta", PMap.JENSEN_BETA, "Gaussian filter beta", float, minimum=1e-3),
                    Param("max_depth", 8, "maximum bounces of photons and of specular chains", int, minimum=1))))
register(Estimator("pm_jensen", "photon mapping with Jensen's split (direct, specular, caustic map, final gathering)",
                   lambda scene, *, spp, seed, progress=False, **p: render_jensen(scene, spp=spp, seed=seed, **p),
                   (Param("photons", 200_000, "global photons", int, minimum=1),
                    Param("caustic_photons", 50_000, "photons shot for the caustic map", int, minimum=1),
                    Param("k", 50, "photons in the global estimate", int, minimum=1, maximum=1024),
                    Param("k_caustic", 50, "photons in the caustic estimate", int, minimum=1, maximum=1024),
                    Param("radius", 0.08, "maximum global search radius", float, minimum=1e-6),
                    Param("caustic_radius", 0.05, "maximum caustic search radius", float, minimum=1e-6),
                    Param("final_gather", 32, "final-gather rays per shading point", int, minimum=1),
                    Param("caustics", True, "use the caustic map", bool),
                    Param("filter", "box", "density filter", str, FILTERS),
                    Param("irradiance_cache", False, "indirect diffuse term from an irradiance cache "
                          "of final gathers (Ward), not a gather per shading point", bool),
                    Param("cache_a", 0.2, "the cache's error threshold a", float, minimum=1e-4, maximum=10.0))))
for _name, _stoch in (("ppm", False), ("sppm", True)):
    register(Estimator(_name, ("progressive photon mapping (Hachisuka 2008)" if not _stoch else
                               "stochastic progressive photon mapping (Hachisuka & Jensen 2009)"),
                       (lambda st: lambda scene, *, spp, seed, progress=False, **p:
                        render_progressive(scene, spp=spp, seed=seed, stochastic=st, **p))(_stoch),
                       (Param("passes", 16, "photon passes", int, minimum=1),
                        Param("photons", 50_000, "photons per pass", int, minimum=1),
                        Param("radius", 0.1, "initial radius", float, minimum=1e-6),
                        Param("alpha", 0.7, "radius reduction alpha in (0, 1)", float, minimum=1e-3, maximum=0.999),
                        Param("max_depth", 8, "maximum bounces of photons and of specular chains", int, minimum=1))))
