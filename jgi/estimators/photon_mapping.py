"""Photon mapping (Jensen 1996, 2001) and its progressive forms (Hachisuka et al. 2008, 2009).

All three start from the photon maps of :mod:`jgi.transport.photons` and the density estimate of
:mod:`jgi.transport.density`, and see the scene from the camera through specular chains
(:func:`jgi.transport.visible_points.visible_points`) to the first non-specular point x:

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
      N_i <- N_i + a M_i,  R_i^2 <- R_i^2 (N_i + a M_i) / (N_i + M_i),
      tau_i <- (tau_i + Phi_i) R_new^2 / R_old^2,
  so the radius shrinks and the estimate L_i = tau_i / (pi R_i^2 T) is consistent as the
  number of passes T grows (a = ``radius_alpha`` in (0, 1), Hachisuka's alpha). ``ppm`` keeps
  one visible point per pixel from the first pass (Hachisuka 2008); ``sppm`` traces a new
  jittered one every pass (2009), so anti-aliasing and glossy/depth effects converge too.
Only the diffuse part (k_d / pi) of a diffuse or Phong surface reflects photons in the
estimates; on microfacet surfaces the whole BSDF does. Glossy microfacet vertices (and rough
dielectrics) are sampled through like specular ones, not looked up
(:func:`jgi.transport.visible_points.samples_through`); ``pm_jensen`` samples through every
microfacet vertex (specular and glossy light by Monte Carlo, Jensen's split).

Participating media (``pm``; a scene filled by a homogeneous medium): photons are stored at
medium interactions too (volume photons, :mod:`jgi.transport.photons`), and a camera chain
that interacts with the medium before reaching a surface ends there, a volume visible point
(:func:`jgi.transport.visible_points.trace_to_diffuse`), where the volume photon map of Jensen
and Christensen (1998) estimates the in-scattered radiance,
L_s(x, wo) ~= sum_p p(-w_p, wo) DeltaPhi_p W(d_p) / K_3 (K_3 = 4/3 pi r^3 for the box
filter; :func:`jgi.transport.density.volume_sum_within`): a point estimate at a sampled
free-flight distance (stochastic ray marching). With ``volume="beam"`` the camera segments
cross the medium to their surfaces (weighed by T) and the beam radiance estimate of Jarosz et
al. (2008) sums every volume photon within r of each segment,
beta sigma_s sum_p T(t_p) p DeltaPhi_p / (pi r^2) (:func:`jgi.transport.density.beam_sum`),
from the same grid. ``ppm`` / ``sppm``
keep a pixel's volume points' statistics apart from its surface points' and shrink their
radius in three dimensions: R^3 <- R^3 (N + a M) / (N + M) (Knaus and Zwicker 2011).
A grid medium (a density grid in a box) takes the point estimate only: photons and camera
chains track it (:mod:`jgi.physics.grid_media`), and the beam estimate, which needs the
transmittance along whole segments in closed form, is refused by name there.

Parameters: :class:`PMConfig`, :class:`JensenConfig`, :class:`ProgressiveConfig`; each
``render_*`` returns a :class:`~jgi.estimators.registry.Render` (image and stats).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..core import rng
from ..core.errors import ParameterError
from ..core.vec import V3, coordinate_system
from ..core.warps import sample_cosine_hemisphere
from ..physics import geometry
from ..scene.tables import Scene
from ..transport import density, hash_grid
from ..transport.photons import trace_photons
from ..transport.subpath import shading
from ..transport.visible_points import face_viewer, trace_to_diffuse, visible_points
from . import irradiance_cache
from .registry import Estimator, Render, param, register

_SALT = rng.SALTS["final_gather"]
# each subpath at most this many segments (pt's max_depth bounds a whole path's segments)
_MAX_BOUNCES_DOC = "maximum surface hits per photon and per camera specular chain"


@dataclass(frozen=True)
class PMConfig:
    """``pm``: direct visualisation of the global photon map (host-side settings; the jitted
    pieces take what they need as static arguments)."""

    photons: int = param(200_000, "photons emitted", minimum=1)
    radius: float = param(0.05, "estimate radius (k > 0: the maximum search radius)", minimum=1e-6)
    k: int = param(0, "k nearest photons (0: fixed radius)", minimum=0, maximum=1024)
    filter: str = param("box", "density filter", choices=density.FILTERS)
    cone_k: float = param(1.1, "cone filter k >= 1", minimum=1.0)
    gauss_alpha: float = param(density.JENSEN_ALPHA, "Gaussian filter alpha (Jensen's)",
                               minimum=1e-3)
    gauss_beta: float = param(density.JENSEN_BETA, "Gaussian filter beta (Jensen's)",
                              minimum=1e-3)
    max_bounces: int = param(8, _MAX_BOUNCES_DOC, minimum=1)
    volume: str = param("point", "in a medium: the volume photons' estimate at a sampled "
                        "point of each camera segment ('point', Jensen and Christensen 1998) "
                        "or along the whole segment ('beam', Jarosz et al. 2008)",
                        choices=("point", "beam"))
    cap: int | None = None          # k > 0: photons read per grid cell (None: the fullest cell)
    thickness: float | None = None  # flattened-disc selection: reject photons this far off
                                    # the plane


@dataclass(frozen=True)
class JensenConfig:
    """``pm_jensen``: Jensen's two-pass method with the four-way split."""

    photons: int = param(200_000, "global photons", minimum=1)
    caustic_photons: int = param(50_000, "photons shot for the caustic map", minimum=1)
    k: int = param(50, "photons in the global estimate", minimum=1, maximum=1024)
    k_caustic: int = param(50, "photons in the caustic estimate", minimum=1, maximum=1024)
    radius: float = param(0.08, "maximum global search radius", minimum=1e-6)
    caustic_radius: float = param(0.05, "maximum caustic search radius", minimum=1e-6)
    final_gather: int = param(32, "final-gather rays per shading point", minimum=1)
    caustics: bool = param(True, "use the caustic map")
    filter: str = param("box", "density filter", choices=density.FILTERS)
    irradiance_cache: bool = param(False, "indirect diffuse term from an irradiance cache of "
                                   "final gathers (Ward), not a gather per shading point")
    cache_a: float = param(0.2, "the cache's error threshold a", minimum=1e-4, maximum=10.0)
    cap: int | None = None          # photons read per grid cell (None: 128)
    max_bounces: int = 8            # surface hits per photon and per camera specular chain


@dataclass(frozen=True)
class ProgressiveConfig:
    """``ppm`` / ``sppm``: progressive photon mapping (``stochastic``: SPPM)."""

    passes: int = param(16, "photon passes", minimum=1)
    photons: int = param(50_000, "photons per pass", minimum=1)
    radius: float = param(0.1, "initial radius", minimum=1e-6)
    radius_alpha: float = param(0.7, "radius reduction alpha in (0, 1)", minimum=1e-3,
                                maximum=0.999)
    max_bounces: int = param(8, _MAX_BOUNCES_DOC, minimum=1)
    stochastic: bool = True         # a new visible point per pixel each pass (SPPM), or one (PPM)




def _pixels(scene, spp):
    P = scene.camera.width * scene.camera.height
    return (jnp.tile(jnp.arange(P, dtype=jnp.int32), spp),
            jnp.repeat(jnp.arange(spp, dtype=jnp.int32), P))


def _to_image(scene, L, spp):
    W, H = scene.camera.width, scene.camera.height
    return np.asarray(L, np.float32).reshape(3, spp, H, W).mean(1).transpose(1, 2, 0)


def render_pm(scene: Scene, cfg: PMConfig = PMConfig(), *, spp: int = 4, seed: int = 0) -> Render:
    """Direct visualisation of the global photon map (see the module docstring).

    Stats: ``stored`` (photons in the map)."""
    photons, radius, k, filter, max_depth = (cfg.photons, cfg.radius, cfg.k, cfg.filter,
                                             cfg.max_bounces)
    cap, thickness = cfg.cap, cfg.thickness
    beams = scene.has_medium and cfg.volume == "beam"
    if beams and scene.has_grid_medium:   # (refused before any photon is traced)
        raise ParameterError("pm: the beam estimate (volume='beam') needs closed-form "
                             "transmittance along whole segments, which a grid medium has not; "
                             "allowed there: volume='point'")
    if beams and scene.has_bounded_media:
        raise ParameterError("pm: the beam estimate (volume='beam') is not implemented with "
                             "media bounded by shapes (a beam would cross media); allowed "
                             "there: volume='point'")
    if beams and (k or filter != "box"):
        raise ParameterError("pm: the beam estimate (volume='beam') takes every photon within "
                             "radius with the box filter; allowed: k = 0, filter = 'box'")
    pm = trace_photons(scene, photons, seed=seed, max_depth=max_depth)
    pix, smp = _pixels(scene, spp)
    v = visible_points(scene, jnp.uint32(seed), pix, smp, max_depth=max_depth, light_samples=0,
                       beams=beams)
    fp = (dict(k=cfg.cone_k) if filter == "cone" else
          dict(gauss_alpha=cfg.gauss_alpha, gauss_beta=cfg.gauss_beta) if filter == "gaussian"
          else {})
    if k == 0:   # every photon within r (no cap): sum / K
        r2 = np.full(pix.shape[0], radius * radius, np.float32)
        surface_live, surface_map = np.asarray(v.found), pm
        if beams:
            surface_map = pm.select(~np.asarray(pm.volume))
        elif scene.has_medium:   # volume points: the 3-D estimate from the volume photons
            in_medium = np.asarray(v.in_medium)
            surface_live = surface_live & ~in_medium
            surface_map = pm.select(~np.asarray(pm.volume))
            Lv, _ = density.volume_sum_within(scene, pm, v.p, v.wo, r2, live=in_medium,
                                              kind=filter, medium=v.medium)
            Lv = Lv / (4.0 / 3.0 * np.pi * radius**3
                       * float(density.volume_filter_weight(filter, 0.0, 1.0)[1]))
        L = density.sum_within(scene, surface_map, v.p, v.n, v.wo, v.material, r2,
                               live=surface_live, kind=filter, filter_params=fp,
                               uv=v.uv, ns=v.ns, thickness=thickness)[0]
        L = L / (np.pi * radius * radius * float(density.filter_weight(filter, 0.0, 1.0, **fp)[1]))
        if scene.has_medium and not beams:
            L = np.where(in_medium, Lv, L)
    else:        # the k nearest within r, from the host grid (cells shrunk to hold ~ cap / 2)
        if scene.has_medium:
            raise ParameterError("pm: k-nearest-neighbour estimates (k > 0) are not implemented "
                                 "in participating media; use k = 0 (every photon within "
                                 "radius)")
        grid = hash_grid.build_grid(pm, radius, cap=cap or 128)
        L = density.estimate_at_points(scene, grid, v.p, v.n, v.wo, v.material,
                                       float(grid.cell), cap=cap, k=k, kind=filter,
                                       thickness=thickness, filter_params=fp, uv=v.uv, ns=v.ns)
    found = np.asarray(v.found)
    beta_ = np.stack([np.asarray(c) for c in v.beta])
    total = np.stack([np.asarray(c) for c in v.L]) + np.where(found, beta_ * L, 0.0)
    if beams:   # the in-scattered light along every camera segment (its throughput included)
        total = total + density.beam_sum(scene, pm, v.segments, radius)
    return Render(_to_image(scene, total, spp), dict(stored=pm.count))


@partial(jax.jit, static_argnames=("n_gather", "max_depth"))
def _gather_points(scene: Scene, seed, ids, x: V3, n: V3, n_gather: int, max_depth: int,
                   ng: V3 | None = None):
    """Final-gather rays from x, cosine-distributed about n (the shading normal where there is
    one, whose geometric normal ``ng`` then offsets the rays): the diffuse points they reach
    and the chain throughput."""
    key = rng.derive(
        rng.path_key(seed, ids[:, None] * n_gather + jnp.arange(n_gather)[None, :], 0), _SALT)
    u1, u2 = rng.uniform(key, 0), rng.uniform(key, 1)
    local = sample_cosine_hemisphere(u1, u2)
    s, t = coordinate_system(n)
    ex = lambda v: V3(*(c[:, None] for c in v))
    d = ex(s) * local.x + ex(t) * local.y + ex(n) * local.z
    o = geometry.offset_origin(ex(x), ex(n if ng is None else ng), d)
    flat = lambda v: V3(*(c.reshape(-1) for c in v))
    kf = key.reshape(-1)
    v = trace_to_diffuse(scene, lambda k: rng.uniform(kf, k + 2), flat(o), flat(d),
                         max_depth=max_depth, light_samples=0, lookup_rough=False)
    return face_viewer(v)


def render_jensen(scene: Scene, cfg: JensenConfig = JensenConfig(), *, spp: int = 1,
                  seed: int = 0) -> Render:
    """Jensen's two-pass method with the four-way split (see the module docstring).

    Stats: ``stored`` (photons in the global map)."""
    photons, k, radius, final_gather = cfg.photons, cfg.k, cfg.radius, cfg.final_gather
    cap, max_depth, filter = cfg.cap, cfg.max_bounces, cfg.filter
    pm = trace_photons(scene, photons, seed=seed, max_depth=max_depth)
    grid = hash_grid.build_grid(pm, radius, cap=cap or 128)
    radius = float(grid.cell)
    pix, smp = _pixels(scene, spp)
    v = visible_points(scene, jnp.uint32(seed), pix, smp, max_depth=max_depth, light_samples=1,
                       lookup_rough=False)
    found = np.asarray(v.found)
    beta_ = np.stack([np.asarray(c) for c in v.beta])
    total = np.stack([np.asarray(c) for c in v.L])  # emission along the chain + direct light
    kdx = np.stack([np.asarray(c) for c in density.diffuse_reflectance(scene, v.material, v.uv)])
    if cfg.caustics:
        cpm = trace_photons(scene, cfg.caustic_photons, seed=seed + 7919, max_depth=max_depth)
        cpm = cpm.select(cpm.caustic)
        if cpm.count:
            cgrid = hash_grid.build_grid(cpm, cfg.caustic_radius, cap=cap or 128)
            Lc = density.estimate_at_points(scene, cgrid, v.p, v.n, v.wo, v.material,
                                            float(cgrid.cell),
                                            cap=cap, k=cfg.k_caustic, kind=filter, thickness=None,
                                            filter_params={}, uv=v.uv, ns=v.ns)
            total = total + np.where(found, beta_ * Lc, 0.0)
    # indirect diffuse by final gathering on the global map (at every point, or cached)
    if cfg.irradiance_cache:
        m = max(1, int(round(np.sqrt(final_gather / 3))))  # Ward's strata: N ~ 3 M (phi vs theta)
        cache = irradiance_cache.CacheConfig(a=cfg.cache_a, gather_m=m,
                                             gather_n=max(1, final_gather // m),
                                             max_depth=max_depth)
        pts = irradiance_cache.shading_points(v)
        W = scene.camera.width
        pix = np.arange(len(found)) % (W * scene.camera.height)
        E = irradiance_cache.irradiance(scene, pts, cfg=cache, seed=seed,
                                        raster=(pix % W, pix // W),
                                        source=irradiance_cache.PhotonSource(grid, k, radius)).E
        ind = E / np.pi  # cosine-weighted gathering: the mean gathered radiance is E / pi
    else:
        idx = np.nonzero(found)[0]
        ind = np.zeros((3, len(found)), np.float32)
        batch = max(1, 1024 // final_gather)
        for s0 in range(0, len(idx), batch):
            sel = idx[s0:s0 + batch]
            pad = np.pad(sel, (0, batch - len(sel)), mode="edge")
            take = lambda vv: V3(*(jnp.asarray(np.asarray(c)[pad]) for c in vv))
            g = _gather_points(scene, jnp.uint32(seed), jnp.asarray(pad, jnp.int32), take(v.p),
                               take(shading(v)), final_gather, max_depth,
                               None if v.ns is None else take(v.n))
            Lg = density.estimate_at_points(scene, grid, g.p, g.n, g.wo, g.material, radius,
                                            cap=cap, k=k, kind=filter, thickness=None,
                                            filter_params={}, uv=g.uv, ns=g.ns)
            gb = np.stack([np.asarray(c) for c in g.beta])
            Lg = (np.where(np.asarray(g.found), gb * Lg, 0.0)
                  .reshape(3, batch, final_gather).mean(-1))
            ind[:, sel] = Lg[:, : len(sel)]
    total = total + np.where(found, beta_ * kdx * ind, 0.0)
    return Render(_to_image(scene, total, spp), dict(stored=pm.count))


def _u32(n: int):
    """n modulo 2^32 as a uint32 (a pass's seed from any 32-bit seed: a study's seeds times a
    multiplier exceed 32 bits)."""
    return jnp.uint32(int(n) % (1 << 32))


def render_progressive(scene: Scene, cfg: ProgressiveConfig = ProgressiveConfig(), *, spp: int = 1,
                       seed: int = 0) -> Render:
    """PPM (``cfg.stochastic=False``) or SPPM; ``spp`` visible points per pixel per pass. Each
    pass gathers every photon within each point's radius (:func:`density.sum_within`: no cap).

    Stats: ``radius_final`` (root mean square of the final radii)."""
    passes, photons, radius, radius_alpha = cfg.passes, cfg.photons, cfg.radius, cfg.radius_alpha
    stochastic, max_depth = cfg.stochastic, cfg.max_bounces
    if not 0.0 < radius_alpha < 1.0:
        raise ValueError(f"radius_alpha must be in (0, 1), got {radius_alpha}")
    pix, smp = _pixels(scene, spp)
    n_pts = pix.shape[0]
    N = np.zeros(n_pts, np.float64)
    R2 = np.full(n_pts, radius * radius, np.float64)
    tau = np.zeros((3, n_pts), np.float64)
    direct = np.zeros((3, n_pts), np.float64)
    # in a medium, a pixel's volume visible points keep statistics of their own (3-D
    # kernels): SPPM's point of a pixel may be on a surface in one pass and in the medium in
    # the next, and each kind's estimate tau / (K R^d passes) is its share of the average
    medium = scene.has_medium
    N_v, R2_v, tau_v = N.copy(), R2.copy(), tau.copy()
    v = None
    for t in range(passes):
        if stochastic or v is None:
            v = visible_points(scene,
                               jnp.uint32(rng.lowbias32(_u32(seed * 65599 + t)).item()),
                               pix, smp, max_depth=max_depth, light_samples=0)
            found = np.asarray(v.found)
            beta_ = np.stack([np.asarray(c) for c in v.beta])
            Lv = np.stack([np.asarray(c) for c in v.L])
        direct += Lv
        pm = trace_photons(scene, photons, seed=int(rng.lowbias32(_u32(seed * 7919 + t + 1))),
                           max_depth=max_depth)
        surface = found
        if medium:
            in_medium = np.asarray(v.in_medium)
            surface = found & ~in_medium
            phi_v, M_v = density.volume_sum_within(scene, pm, v.p, v.wo, R2_v,
                                                   live=found & in_medium, medium=v.medium)
            phi_v = np.where(found & in_medium, beta_ * phi_v, 0.0)
            tau_v, R2_v, N_v = _progressive_update(tau_v, R2_v, N_v, phi_v, M_v, radius_alpha, 3)
            pm = pm.select(~np.asarray(pm.volume))
        # M_i (photons within R_i) and Phi_i = sum f_r DeltaPhi_p, over every photon (no cap)
        phi, M = density.sum_within(scene, pm, v.p, v.n, v.wo, v.material, R2, live=surface,
                                    uv=v.uv, ns=v.ns)
        phi = np.where(surface, beta_ * phi, 0.0)
        tau, R2, N = _progressive_update(tau, R2, N, phi, M, radius_alpha, 2)
    L = direct / passes + tau / (np.pi * R2 * passes)
    if medium:
        L = L + tau_v / (4.0 / 3.0 * np.pi * R2_v**1.5 * passes)
    return Render(_to_image(scene, L, spp), dict(radius_final=float(np.sqrt(R2.mean()))))


def _progressive_update(tau, R2, N, phi, M, radius_alpha: float, dim: int):
    """One pass of Hachisuka's statistics in ``dim`` dimensions: N <- N + a M, the kernel's
    measure (pi R^2, or 4/3 pi R^3 in a medium: Knaus and Zwicker 2011) scaled by
    (N + a M) / (N + M), tau <- (tau + Phi) times the same ratio."""
    grow = N + radius_alpha * M
    ratio = np.where(N + M > 0, grow / np.maximum(N + M, 1e-30), 1.0)
    return (tau + phi) * ratio, R2 * ratio ** (2.0 / dim), grow


def _pm(scene: Scene, cfg: PMConfig, *, spp: int, seed: int, progress: bool = False) -> Render:
    return render_pm(scene, cfg, spp=spp, seed=seed)


def _jensen(scene: Scene, cfg: JensenConfig, *, spp: int, seed: int,
            progress: bool = False) -> Render:
    return render_jensen(scene, cfg, spp=spp, seed=seed)


def _ppm(scene: Scene, cfg: ProgressiveConfig, *, spp: int, seed: int,
         progress: bool = False) -> Render:
    return render_progressive(scene, replace(cfg, stochastic=False), spp=spp, seed=seed)


def _sppm(scene: Scene, cfg: ProgressiveConfig, *, spp: int, seed: int,
          progress: bool = False) -> Render:
    return render_progressive(scene, replace(cfg, stochastic=True), spp=spp, seed=seed)


register(Estimator("pm", "photon mapping, direct visualisation of the global map", _pm, PMConfig,
                   renamed={"alpha": "gauss_alpha", "beta": "gauss_beta",
                            "max_depth": "max_bounces"}, media=True, grid_media=True))
register(Estimator("pm_jensen", "photon mapping with Jensen's split (direct, specular, "
                   "caustic map, final gathering)", _jensen, JensenConfig))
register(Estimator("ppm", "progressive photon mapping (Hachisuka 2008)", _ppm, ProgressiveConfig,
                   renamed={"alpha": "radius_alpha", "max_depth": "max_bounces"}, media=True,
                   grid_media=True))
register(Estimator("sppm", "stochastic progressive photon mapping (Hachisuka & Jensen 2009)", _sppm,
                   ProgressiveConfig, renamed={"alpha": "radius_alpha",
                                               "max_depth": "max_bounces"}, media=True,
                   grid_media=True))
