"""Metropolis light transport in path space (Veach & Guibas 1997; Veach 1997, ch. 11).

The chain's state is a *path* x = (x_0, x_1, ..., x_k): x_0 the pinhole, x_k a point on an area
emitter, k <= ``max_depth`` segments. The target is f*(x) = luminance of the measurement
contribution f(x), and three mutations move the chain:

* **large step** (independence sampler, keeps the chain ergodic): a fresh path from the
  unidirectional sampler p: length k uniform in 1..K, a film point, k - 1 BSDF samples, and the
  last direction from the mixture q = (1 - c) p_bsdf + c p_light (c = 1/2 after a non-specular
  vertex), so every path with f > 0 has p > 0. Acceptance min(1, C*(y) / C*(x)) with
  C* = f* / p (the Kelemen large step, written in path space);
* **lens perturbation** (paths E S* D (D|L) ...): move the film point by a radius
  r2 exp(-log(r2/r1) xi) in a uniform direction, retrace the specular chain from the pinhole
  with the same reflect/refract choices to a new first non-specular vertex x'_m, and reconnect it
  to the unchanged x_{m+1};
* **caustic perturbation** (paths E D S+ (D|L) ...): turn the direction leaving x_j (the first
  non-specular vertex after the chain) towards the specular chain by an angle
  theta2 exp(-log(theta2/theta1) xi) about its old direction, retrace the chain towards the eye
  to a new x'_1, and connect x'_1 to the pinhole (a new film point).

Both perturbations are symmetric in their natural coordinates (film area for the lens
perturbation, solid angle at x_j for the caustic one), so T(x->y) = T(y->x) there, and the
acceptance is the ratio of the target written in those coordinates:

    lens:     f*(y) / f*(x) = [lum P(y) G(y_m, x_{m+1})] / [lum P(x) G(x_m, x_{m+1})]
    caustic:  f*(y) / f*(x) = [lum P(y) W(y_1) |cos theta_j(y)|] / [same for x]

where P(x) = L_e(x_k -> x_{k-1}) prod_i rho(x_i) is the path's colour (BSDF values at
non-specular vertices, the Dirac coefficient - k_s, F k_s or (1 - F) k_s / eta^2 - at specular
ones), G the geometry term, and W(x_1) = W_e G(x_0, x_1) = |cos theta_1| / (A cos^3 theta_c
d^2) the pinhole's importance in area measure. Factors of the unchanged part of the path are
common to both and cancel except through the colour, which is why P is carried whole. A mutation
that finds a different kind of vertex (a diffuse surface where the chain had a specular one, a
different reflect/refract choice), leaves the film, or is occluded proposes f = 0 and is
rejected; those rules are the same from x and from y, so detailed balance holds.

The image follows Kelemen's expected-value splatting: each step records the current path with
weight 1 - a and the proposal with a, each as b P / lum P at its film point, with
b = integral of f* = the image's mean luminance, estimated by default with the path tracer (MIS,
same maximum length, ``b_paths`` paths; on the Cornell box at 16^2 and 64 spp the image
mean's standard error over seeds fell from 1.9e-3 to 2.9e-4 with it, in less time), or with
``b_paths=0``
from the mean of C* over ``bootstrap_samples`` independent large-step paths, from which the
chains also start (resampled in proportion to C*, so there is no start-up bias). Each step
applies one mutation kind to all chains, chosen at random with probabilities
(p_large, p_lens, p_caustic): a random mixture of mutations that each preserve f*, so the mixture
does too, and only the chosen kind's code runs. That step (kind choice, acceptance, splatting,
acceptance counts per kind) is the Metropolis transition :func:`jgi.transport.mcmc.metropolis`; this
module supplies the path state, the mutations and the targets in their coordinates.

On meshes with vertex normals the BSDF values, Dirac coefficients and specular chains are about
the shading normal, and a non-specular vertex's value carries |wi . ns| / |wi . ng| (the path
tracer's shading cosine over the geometric one of the area measure), so the path space is the
path tracer's; geometry terms, densities and the targets' cosines stay geometric.

Smooth plastic (a Dirac coating over a diffuse base) is the one material whose vertices are
specular or not according to the path: each path records per vertex (``Path.coat``) whether it
left a plastic vertex by the coating's reflection. Such a vertex is specular everywhere a
mirror's is - in P(x) (Dirac coefficient k_s F(cos_o), the large step's 1 / p for the lobe
choice p, halved at the last bounce, where the large step light-samples half the time since a
plastic vertex is connectable), in the perturbations' chains (retraced as a reflection; a
retraced chain may swap a mirror for a coating-reflected plastic and back) - and one left by its
base is diffuse. Scenes without plastic carry no flags and compile to the program of before.

Only area emitters (quads, triangles, spheres) are supported: a point or directional light has no
area measure for x_k. Where two emitters lie along one ray the large step's light-sampling
density counts only the nearer one (harmless in the bundled scenes, which have one emitter).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..core import rng
from ..core.errors import ParameterError
from ..core.vec import EDGE_ON_COS, V3, coordinate_system, dot, luminance, normalize, reflect, where
from ..physics import bsdf, camera, geometry
from ..physics.lights import AREA_KINDS, emitted, pdf_li, sample_li
from ..scene.tables import DIELECTRIC, MIRROR, PLASTIC, Scene
from ..transport import mcmc, subpath
from . import path_tracer
from .registry import Estimator, Render, param, register

_SALT = rng.SALTS["mlt"]
LARGE, LENS, CAUSTIC = 0, 1, 2
MUTATION_KINDS = ("large", "lens", "caustic")


@dataclass(frozen=True)
class MLTConfig:
    """Veach's MLT's parameters. Only ``max_depth`` is static (one compilation each): the
    compiled kernels see :meth:`compile_key`; the mutation mixture and sizes are traced
    (:meth:`mutations`)."""

    max_depth: int = param(5, "maximum path segments", minimum=1, maximum=32)   # K
    chains: int = param(4096, "Markov chains run in parallel", minimum=1)
    bootstrap_samples: int = param(65536, "independent large-step paths to start the chains",
                                   minimum=16)
    b_paths: int = param(1 << 20, "path-traced paths to estimate b (0: the bootstrap's mean)",
                         minimum=0)
    p_large: float = param(0.1, "probability of a large step (fresh path)", minimum=0.0,
                           maximum=1.0)
    p_lens: float = param(0.45, "probability of a lens perturbation", minimum=0.0, maximum=1.0)
    p_caustic: float = param(0.45, "probability of a caustic perturbation", minimum=0.0,
                             maximum=1.0)
    lens_r1: float = 0.1          # smallest film displacement, pixels
    lens_r2: float = param(0.1, "largest lens perturbation, fraction of the image size",
                           minimum=1e-3, maximum=1.0)
    caustic_theta1: float = 1e-4  # smallest turn of the caustic direction, radians
    # largest, radians (measured on mirror_caustic: relMSE at 2M mutations 0.0090 / 0.0041 /
    # 0.0033 / 0.0028 for 0.1 / 0.3 / 0.5 / 1)
    caustic_theta2: float = param(0.5, "largest caustic perturbation angle, radians", minimum=1e-3,
                                  maximum=1.0)
    steps_per_call: int = 16      # mutations per chain and kernel call

    def compile_key(self) -> "MLTConfig":
        """The static part, the compile key of the compiled kernels: the path length alone."""
        return MLTConfig(max_depth=self.max_depth)

    def mutations(self) -> "Mutations":
        """The mutation mixture and sizes, as the compiled kernels take them (traced)."""
        return Mutations(self.p_large, self.p_lens, self.p_caustic, self.lens_r1, self.lens_r2,
                         self.caustic_theta1, self.caustic_theta2)


class Mutations(NamedTuple):
    """The mutation mixture and perturbation sizes: traced values, so changing them does not
    recompile (fields and defaults: :class:`MLTConfig`'s)."""

    p_large: float = MLTConfig.p_large
    p_lens: float = MLTConfig.p_lens
    p_caustic: float = MLTConfig.p_caustic
    lens_r1: float = MLTConfig.lens_r1
    lens_r2: float = MLTConfig.lens_r2
    caustic_theta1: float = MLTConfig.caustic_theta1
    caustic_theta2: float = MLTConfig.caustic_theta2

    def arrays(self) -> "Mutations":
        return Mutations(*(jnp.float32(v) for v in self))


class Path(NamedTuple):
    """Vertex rows 0..K (row 0 the pinhole) for every chain: arrays [K + 1, chains]."""

    p: V3
    n: V3             # geometric normal (row 0 unused)
    material: Array   # int32
    emitter: Array    # int32 light element, -1 if none
    length: Array     # [chains] segments k; vertex k is on an emitter; 0: no path (f = 0)
    fx: Array         # [chains] raster position of x_1 (column, float)
    fy: Array         # [chains] (row, float; 0 at the top)
    uv: tuple | None = None  # surface coordinates (u, v) [K + 1, chains], in textured scenes
    ns: V3 | None = None     # shading normals [K + 1, chains], in scenes with vertex normals
    coat: Array | None = None  # [K + 1, chains] bool, in scenes with smooth plastic: the path
                               # leaves a plastic vertex i by its coating's Dirac reflection
                               # (else by the base); read only at plastic vertices


class PathValue(NamedTuple):
    color: V3         # P(x): L_e times the BSDF values / Dirac coefficients (no geometry)
    lum: Array        # luminance of P(x)
    inv_pdf: Array    # the large step's |cos| / pdf product: C(x) = P(x) * inv_pdf = f(x) / p(x)


# --- per-chain rows ----------------------------------------------------------------------------
# Path arrays are [R, C]: row r of chain c. Rows the same for every chain are
# ``subpath.rows(v, slice(lo, hi))``; these take or replace a different row per chain.

def _chain_row(v, i: Array):
    """Row i[c] of chain c of every leaf of v (an [R, C] array, a V3 or a tuple of them)."""
    i = i[None, :].astype(jnp.int32)
    return jax.tree_util.tree_map(lambda a: jnp.take_along_axis(a, i, axis=0)[0], v)


def _set_chain_row(v, i, value, where_: Array):
    """v with row i[c] of chain c replaced by value[c] where where_[c], in every leaf; None (a
    scene without uv, shading normals or coatings) stays None."""
    if v is None:
        return None

    def put(a, x):
        rows = jnp.arange(a.shape[0])[:, None]
        at = jnp.broadcast_to(i, a.shape[1:])
        return jnp.where((rows == at[None, :]) & where_[None, :], x[None, :].astype(a.dtype), a)

    return jax.tree_util.tree_map(put, v, value)


def _store_hit(path, i, hit, where_: Array):
    """``path`` (a :class:`Path`) with vertex i[c] of chain c set to the ray hit ``hit`` where
    where_[c]."""
    return path._replace(p=_set_chain_row(path.p, i, hit.p, where_),
                         n=_set_chain_row(path.n, i, hit.n, where_),
                         material=_set_chain_row(path.material, i, hit.material, where_),
                         emitter=_set_chain_row(path.emitter, i, hit.emitter, where_),
                         uv=_set_chain_row(path.uv, i, hit.uv, where_),
                         ns=_set_chain_row(path.ns, i, hit.ns, where_))


def _first(mask: Array, fallback: Array) -> Array:
    """Index of the first True row of ``mask`` [R, C] per chain, or ``fallback``."""
    rows = jnp.arange(mask.shape[0])[:, None]
    idx = jnp.min(jnp.where(mask, rows, mask.shape[0]), axis=0)
    return jnp.where(idx < mask.shape[0], idx, fallback)


def specular_coefficient(mp: bsdf.MaterialParams, n: V3, wo: V3, wi: V3, plastic: bool = False):
    """The Dirac coefficient of a specular vertex (f |cos| without the delta) for the pair
    (wo, wi), and the probability with which ``bsdf.sample`` picks that lobe. Mirror (smooth
    conductor): k_s F_conductor(cos_o) (k_s for the perfect mirror), 1. Dielectric: F k_s with
    probability F (reflection), (1 - F) k_t / eta^2 with 1 - F (transmission, radiance scaling
    as in jgi.physics.bsdf; k_t the transmission tint). Smooth plastic's coating
    (``plastic``, static: the scene has it): k_s F(cos_o) with probability p
    (:func:`jgi.physics.bsdf.plastic.coating_probability`), so coefficient / probability is
    the weight ``bsdf.sample`` returns for that lobe."""
    cos_o = dot(wo, n)
    transmit = cos_o * dot(wi, n) < 0
    eta = jnp.where(cos_o > 0, mp.ior, 1.0 / mp.ior)
    F = bsdf.fresnel_dielectric(jnp.abs(cos_o), eta)
    diel = jnp.where(transmit, (1.0 - F) / (eta * eta), F)
    prob = jnp.where(mp.kind == DIELECTRIC, jnp.where(transmit, 1.0 - F, F), 1.0)
    mirror = bsdf.mirror_reflectance(mp, jnp.abs(cos_o))
    zero = jnp.zeros_like(cos_o)
    coeff = where(mp.kind == DIELECTRIC, where(transmit, bsdf.transmission_tint(mp), mp.ks) * diel,
                  where(transmit, V3(zero, zero, zero), mirror))
    if plastic:
        sel = mp.kind == PLASTIC
        cos_c = jnp.abs(cos_o)
        coat = mp.ks * bsdf.plastic.reflectance(mp, cos_c)
        coeff = where(sel, where(transmit, V3(zero, zero, zero), coat), coeff)
        prob = jnp.where(sel, bsdf.plastic.coating_probability(mp, cos_c), prob)
    return coeff, prob


def specular_continue(mp: bsdf.MaterialParams, n: V3, w_from: V3, transmit: Array,
                      plastic: bool = False):
    """The direction leaving a specular vertex when the path arrives from ``w_from`` (pointing
    back along the path), reflecting or refracting as ``transmit`` says; (direction, valid).
    Specular scattering is reversible, so the same rule serves chains traced from the eye and
    from the light. With ``plastic`` (static) a smooth plastic vertex reflects too (its
    coating)."""
    cos_f = dot(w_from, n)
    nside = n * jnp.where(cos_f > 0, 1.0, -1.0)
    eta = jnp.where(cos_f > 0, mp.ior, 1.0 / mp.ior)
    wt, can_refract = bsdf.refract(w_from, nside, eta)
    d = where(transmit, wt, reflect(w_from, nside))
    refracts = (mp.kind == DIELECTRIC) & can_refract
    reflects = (mp.kind == MIRROR) | (mp.kind == DIELECTRIC)
    if plastic:
        reflects = reflects | (mp.kind == PLASTIC)
    ok = jnp.where(transmit, refracts, reflects)
    # edge-on: nothing scattered, as in jgi.physics.bsdf
    return d, ok & (jnp.abs(cos_f) > EDGE_ON_COS)


def transmits(path: Path) -> Array:
    """[K + 1, C]: the path refracts through vertex i (its neighbours on opposite sides)."""
    prev, cur, nxt = (subpath.rows(path.p, slice(0, -2)), subpath.rows(path.p, slice(1, -1)),
                      subpath.rows(path.p, slice(2, None)))
    # sides of the shading normal, as the BSDF decides
    n = subpath.rows(subpath.shading(path), slice(1, -1))
    t = dot(prev - cur, n) * dot(nxt - cur, n) < 0
    f = jnp.zeros_like(t[:1])
    return jnp.concatenate([f, t, f], 0)


def dirac(mp: bsdf.MaterialParams, coat: Array | None) -> Array:
    """Whether the path leaves vertices of material ``mp`` by a Dirac lobe: a mirror or
    dielectric always, a smooth plastic where its ``coat`` flag says the coating reflected it
    (``coat`` None in scenes without plastic: the material's flag alone, as before plastic)."""
    if coat is None:
        return bsdf.is_delta(mp)
    return bsdf.is_delta(mp) | ((mp.kind == PLASTIC) & coat)


def can_take(delta: Array, mp: bsdf.MaterialParams, specular, plastic: bool) -> Array:
    """Whether a vertex of material ``mp`` (``delta`` its :func:`jgi.physics.bsdf.is_delta`)
    that a retraced chain finds can take the place of a specular vertex (``specular``) or of a
    non-specular one: a plastic vertex can be either, by its coating or its base; mirrors and
    dielectrics only specular ones, the rest only non-specular ones (``plastic`` static: the
    scene has smooth plastic)."""
    if not plastic:
        return delta == specular
    return jnp.where(specular, delta | (mp.kind == PLASTIC), ~delta)


def is_specular(scene: Scene, path: Path) -> Array:
    """[K + 1, C]: the path leaves vertex i by a Dirac lobe (a mirror or dielectric vertex,
    a plastic one reflected by its coating); rows 0 and k are never."""
    mp = bsdf.lookup(scene.materials, path.material, path.uv)
    rows = jnp.arange(path.material.shape[0])[:, None]
    return dirac(mp, path.coat) & (rows >= 1) & (rows < path.length[None, :])


# --- the path's value: P(x) and the large step's density ----------------------------------------

def evaluate(scene: Scene, cfg: MLTConfig, path: Path) -> PathValue:
    """P(x) = L_e prod rho(x_i) and 1 / p(x) relative to the area measure (|cos| / pdf per
    sampled direction, times K for the uniform choice of length), from the vertices alone, so
    perturbed paths are valued exactly like sampled ones."""
    K = cfg.max_depth
    k = path.length
    mats, lights = scene.materials, scene.lights
    kk = jnp.maximum(k, 1)
    x_k, n_k, e_k = _chain_row(path.p, kk), _chain_row(path.n, kk), _chain_row(path.emitter, kk)
    x_km1 = _chain_row(path.p, kk - 1)
    Le = emitted(lights, e_k, n_k, normalize(x_km1 - x_k))
    one = jnp.ones_like(path.fx)
    color, inv_pdf = V3(Le.x, Le.y, Le.z), one * K
    if K > 1:
        prev, cur, nxt = (subpath.rows(path.p, slice(0, K - 1)),
                          subpath.rows(path.p, slice(1, K)), subpath.rows(path.p, slice(2, K + 1)))
        n = subpath.rows(path.n, slice(1, K))
        ns = subpath.rows(subpath.shading(path), slice(1, K))
        wo, wi = normalize(prev - cur), normalize(nxt - cur)
        mp = bsdf.lookup(mats, path.material[1:K], subpath.rows(path.uv, slice(1, K)))
        coat = None if path.coat is None else path.coat[1:K]
        delta = dirac(mp, coat)
        f, pdf_bsdf = bsdf.evaluate(mats.kinds, mp, ns, wo, wi)
        if path.ns is not None:
            # in the area measure (geometric G) the path tracer's shading cosine |wi . ns|
            # is the factor |wi . ns| / |wi . ng| of the BSDF
            f = f * bsdf.shading_ratio(ns, n, wi)
        coeff, prob = specular_coefficient(mp, ns, wo, wi, plastic=coat is not None)
        rows = jnp.arange(1, K)[:, None]
        last = rows == (k - 1)[None, :]
        if coat is not None:
            # a coating-reflected last bounce was the BSDF's half of the mixture (a plastic
            # vertex is not Dirac, so the large step light-samples there half the time)
            prob = jnp.where(last & ~bsdf.is_delta(mp), 0.5 * prob, prob)
        # the last direction came from the mixture (1/2) p_bsdf + (1/2) p_light
        pdf_light = pdf_li(lights, e_k[None, :], cur, V3(*(c[None, :] for c in x_k)),
                           V3(*(c[None, :] for c in n_k)))
        pdf = jnp.where(last, 0.5 * pdf_bsdf + 0.5 * pdf_light, pdf_bsdf)
        cos_i = jnp.abs(dot(wi, n))
        s = jnp.where(delta, 1.0 / jnp.maximum(prob, 1e-30),
                      jnp.where(pdf > 0, cos_i / jnp.where(pdf > 0, pdf, 1.0), 0.0))
        rho = where(delta, coeff, f)
        inside = rows < k[None, :]
        rho = V3(*(jnp.where(inside, c, 1.0) for c in rho))
        s = jnp.where(inside, s, 1.0)
        color = V3(*(c * jnp.prod(r, axis=0) for c, r in zip(color, rho)))
        inv_pdf = inv_pdf * jnp.prod(s, axis=0)
    ok = (k >= 1) & (e_k >= 0)
    color = V3(*(jnp.where(ok & jnp.isfinite(c), c, 0.0) for c in color))
    lum = jnp.maximum(luminance(color), 0.0)
    inv_pdf = jnp.where(ok & jnp.isfinite(inv_pdf), inv_pdf, 0.0)
    return PathValue(color, lum, inv_pdf)


# --- large step: a fresh path from the unidirectional sampler ------------------------------------

def _empty(scene: Scene, cfg: MLTConfig, n_chains: int) -> Path:
    K = cfg.max_depth
    z = jnp.zeros((K + 1, n_chains), jnp.float32)
    cam = scene.camera.position
    p = V3(z + cam.x, z + cam.y, z + cam.z)
    zi = jnp.zeros((K + 1, n_chains), jnp.int32)
    return Path(p, V3(z, z, z + 1.0), zi, zi - 1, jnp.zeros(n_chains, jnp.int32), z[0], z[0],
                (z, z) if scene.materials.has_textures else None,
                V3(z, z, z + 1.0) if scene.has_shading_normals else None,
                zi > 0 if PLASTIC in scene.materials.kinds else None)


def sample_path(scene: Scene, cfg: MLTConfig, key: Array) -> Path:
    """One path per lane of ``key`` from the large step's density p (see module docstring)."""
    K = cfg.max_depth
    cam, lights, kinds = scene.camera, scene.lights, scene.materials.kinds
    n_chains = key.shape[0]
    u = lambda d: rng.uniform(key, d)  # noqa: E731
    k = jnp.minimum(1 + jnp.floor(u(0) * K).astype(jnp.int32), K)
    fx, fy = u(1) * cam.width, u(2) * cam.height
    px = jnp.clip(jnp.floor(fx), 0, cam.width - 1).astype(jnp.int32)
    py = jnp.clip(jnp.floor(fy), 0, cam.height - 1).astype(jnp.int32)
    o, d = camera.sample_ray(cam, px, py, fx - px, fy - py)
    path = _empty(scene, cfg, n_chains)._replace(length=k, fx=fx, fy=fy)

    def body(i, carry):
        path, o, d, alive = carry
        hit = geometry.intersect(scene, o, d)
        here = alive & (i <= k)
        alive = alive & (~here | hit.valid)
        path = _store_hit(path, i, hit, here)
        mp = bsdf.lookup(scene.materials, hit.material, hit.uv)
        base = 3 + 7 * i
        bs = bsdf.sample(kinds, mp, subpath.shading(hit), -d, u(base), u(base + 1), u(base + 2))
        ls = sample_li(lights, hit.p, u(base + 3), u(base + 4), u(base + 5))
        nee = (i == k - 1) & ~bsdf.is_delta(mp) & (u(base + 6) < 0.5)
        wi = where(nee, ls.wi, bs.wi)
        if path.coat is not None:   # the lobe the path leaves a plastic vertex by
            path = path._replace(coat=_set_chain_row(path.coat, i, bs.delta & ~nee & (i < k),
                                                     here))
        alive = alive & (~(i < k) | jnp.where(nee, ls.valid, bs.valid))
        return path, geometry.offset_origin(hit.p, hit.n, wi), wi, alive

    path, _, _, alive = jax.lax.fori_loop(1, K + 1, body, (path, o, d, jnp.ones(n_chains, bool)))
    ok = alive & (_chain_row(path.emitter, k) >= 0)
    return path._replace(length=jnp.where(ok, k, 0))


# --- lens perturbation --------------------------------------------------------------------------

def lens_radius_range(scene: Scene, mu: Mutations):
    r2 = mu.lens_r2 * max(scene.camera.width, scene.camera.height)
    return mu.lens_r1, jnp.maximum(r2, 2.0 * mu.lens_r1)


def log_uniform(xi: Array, lo, hi) -> Array:
    """hi exp(-log(hi/lo) xi): the perturbation size, density 1 / (s log(hi/lo)) on [lo, hi]."""
    return hi * jnp.exp(-jnp.log(hi / lo) * xi)


def lens_log_density(scene: Scene, mu: Mutations, x: Path, y: Path) -> Array:
    """log T(x -> y) of the lens perturbation in film-area measure (pixels^2): the displacement's
    radius density over the circumference, 1 / (2 pi r^2 log(r2/r1)). Depends on |y - x| only."""
    r1, r2 = lens_radius_range(scene, mu)
    r = jnp.hypot(y.fx - x.fx, y.fy - x.fy)
    ok = (r >= r1 * (1 - 1e-4)) & (r <= r2 * (1 + 1e-4))
    return jnp.where(ok, -jnp.log(2 * np.pi * r * r * jnp.log(r2 / r1)), -jnp.inf)


def _geometry(a: V3, na: V3, b: V3, nb: V3) -> Array:
    v = b - a
    d2 = dot(v, v)
    w = v * jax.lax.rsqrt(jnp.maximum(d2, 1e-30))
    return jnp.abs(dot(w, na)) * jnp.abs(dot(w, nb)) / jnp.maximum(d2, 1e-30)


def lens_vertex(scene: Scene, x: Path) -> tuple[Array, Array]:
    """(m, applicable): x_m is the first non-specular vertex from the eye, for paths
    E S* D (D|L) ...: the lens perturbation needs x_{m+1} non-specular (or m = k)."""
    K = x.material.shape[0] - 1
    k = x.length
    spec = is_specular(scene, x)
    rows = jnp.arange(K + 1)[:, None]
    m = jnp.minimum(_first(~spec & (rows >= 1), k), jnp.maximum(k, 1))
    after = jnp.minimum(m + 1, K)
    return m, (k >= 1) & ((m == k) | ~_chain_row(spec, after))


def retrace_lens(scene: Scene, cfg: MLTConfig, x: Path, fx: Array, fy: Array):
    """The path through film point (fx, fy) with x's specular chain (same reflect/refract
    choices) up to a new x'_m, reconnected to x_{m+1}; (y, valid). The map is its own inverse:
    retracing y through x's film point gives x back."""
    K = cfg.max_depth
    cam = scene.camera
    n_chains = x.length.shape[0]
    k = x.length
    m, applicable = lens_vertex(scene, x)
    modes = transmits(x)
    plastic = x.coat is not None
    inside = (fx >= 0) & (fx < cam.width) & (fy >= 0) & (fy < cam.height)
    px = jnp.clip(jnp.floor(fx), 0, cam.width - 1).astype(jnp.int32)
    py = jnp.clip(jnp.floor(fy), 0, cam.height - 1).astype(jnp.int32)
    o, d = camera.sample_ray(cam, px, py, fx - px, fy - py)

    def body(i, carry):
        y, o, d, ok = carry
        hit = geometry.intersect(scene, o, d)
        here = i <= m
        mp = bsdf.lookup(scene.materials, hit.material, hit.uv)
        good = hit.valid & can_take(bsdf.is_delta(mp), mp, i < m, plastic)
        good = good & ((i < k) | (hit.emitter >= 0))  # a light vertex must stay on a light
        ok = ok & (~here | good)
        y = _store_hit(y, i, hit, here)
        y = y._replace(coat=_set_chain_row(y.coat, i, i < m, here))
        w, valid = specular_continue(mp, subpath.shading(hit), -d,
                                     _chain_row(modes, jnp.full((n_chains,), i)), plastic)
        ok = ok & (~(i < m) | valid)
        return y, geometry.offset_origin(hit.p, hit.n, w), w, ok

    y, _, _, ok = jax.lax.fori_loop(1, K + 1, body, (x._replace(fx=fx, fy=fy), o, d,
                                                      applicable & inside))
    # reconnect x'_m to the unchanged x_{m+1}
    ym, nm = _chain_row(y.p, m), _chain_row(y.n, m)
    nxt = _chain_row(x.p, jnp.minimum(m + 1, K))
    o_s, d_s, t_s = geometry.shadow_ray(ym, nm, normalize(nxt - ym),
                                        jnp.sqrt(dot(nxt - ym, nxt - ym)))
    ok = ok & ~((m < k) & geometry.occluded(scene, o_s, d_s, t_s))
    return y._replace(length=jnp.where(ok, k, 0)), ok


def lens_target(scene: Scene, x: Path, xv: PathValue) -> Array:
    """f* in the lens perturbation's coordinates (film area, x_{m+1}, ... in area measure), up
    to factors shared by x and y: lum P(x) G(x_m, x_{m+1})."""
    K = x.material.shape[0] - 1
    m, _ = lens_vertex(scene, x)
    nxt = jnp.minimum(m + 1, K)
    g = _geometry(_chain_row(x.p, m), _chain_row(x.n, m), _chain_row(x.p, nxt),
                  _chain_row(x.n, nxt))
    return xv.lum * jnp.where(m < x.length, g, 1.0)


def lens_perturbation(scene: Scene, cfg: MLTConfig, mu: Mutations, x: Path, xv: PathValue,
                      key: Array):
    """(y, its value, target ratio numerator, denominator, applicable): move the film point by
    r2 exp(-log(r2/r1) xi) pixels in a uniform direction and retrace (symmetric in film area)."""
    _, applicable = lens_vertex(scene, x)
    r1, r2 = lens_radius_range(scene, mu)
    r = log_uniform(rng.uniform(key, 0), r1, r2)
    phi = 2 * np.pi * rng.uniform(key, 1)
    y, _ = retrace_lens(scene, cfg, x, x.fx + r * jnp.cos(phi), x.fy + r * jnp.sin(phi))
    yv = evaluate(scene, cfg, y)
    return y, yv, lens_target(scene, y, yv), lens_target(scene, x, xv), applicable


# --- caustic perturbation -----------------------------------------------------------------------

def rotate_about(w: V3, theta: Array, phi: Array) -> V3:
    """The unit direction at angle theta from w, azimuth phi about it."""
    s, t = coordinate_system(w)
    st = jnp.sin(theta)
    return normalize(w * jnp.cos(theta) + s * (st * jnp.cos(phi)) + t * (st * jnp.sin(phi)))


def caustic_vertex(scene: Scene, x: Path) -> tuple[Array, Array]:
    """(j, applicable): x_j is the first non-specular vertex after x_1, for paths E D S+ (D|L)."""
    K = x.material.shape[0] - 1
    k = x.length
    spec = is_specular(scene, x)
    rows = jnp.arange(K + 1)[:, None]
    j = _first(~spec & (rows >= 2), k)
    j = jnp.minimum(j, jnp.maximum(k, 1))
    applicable = (k >= 3) & ~spec[1] & spec[min(2, K)] & (j >= 3)
    return j, applicable


def caustic_log_density(scene: Scene, mu: Mutations, x: Path, y: Path) -> Array:
    """log T(x -> y) of the caustic perturbation in solid angle at x_j: the angle's density over
    the circle of directions at that angle, 1 / (2 pi theta sin(theta) log(theta2/theta1))."""
    j, _ = caustic_vertex(scene, x)
    xj = _chain_row(x.p, j)
    a = normalize(_chain_row(x.p, j - 1) - xj)
    b = normalize(_chain_row(y.p, j - 1) - xj)
    c = jnp.clip(dot(a, b), -1.0, 1.0)
    theta = jnp.arctan2(jnp.sqrt(jnp.maximum(dot(a - b * c, a - b * c), 0.0)), c)
    t1, t2 = mu.caustic_theta1, mu.caustic_theta2
    ok = (theta >= t1 * (1 - 1e-3)) & (theta <= t2 * (1 + 1e-3))
    return jnp.where(ok, -jnp.log(2 * np.pi * theta * jnp.sin(theta) * jnp.log(t2 / t1)), -jnp.inf)


def _camera_weight(cam, p: V3, n: V3):
    """W(x_1) = W_e G(x_0, x_1) up to the film-area constant, the film position, visibility."""
    pr = camera.project(cam, p)
    cos_c = -dot(pr.wi, cam.forward)
    w = pr.importance * cos_c * jnp.abs(dot(pr.wi, n)) / jnp.maximum(pr.dist * pr.dist, 1e-30)
    return jnp.where(pr.visible, w, 0.0), pr


def retrace_caustic(scene: Scene, cfg: MLTConfig, x: Path, w_new: V3):
    """The path leaving x_j in direction ``w_new`` through x's specular chain (same choices)
    to a new x'_1, connected to the pinhole (a new film point); (y, valid). Retracing y with
    x's old direction gives x back."""
    K = cfg.max_depth
    cam = scene.camera
    k = x.length
    j, applicable = caustic_vertex(scene, x)
    modes = transmits(x)
    plastic = x.coat is not None
    xj, nj = _chain_row(x.p, j), _chain_row(x.n, j)

    def body(s, carry):
        y, o, d, ok = carry
        i = j - 1 - s  # the vertex this step finds, walking from x_j towards the eye
        here = i >= 1
        hit = geometry.intersect(scene, o, d)
        mp = bsdf.lookup(scene.materials, hit.material, hit.uv)
        good = hit.valid & can_take(bsdf.is_delta(mp), mp, i >= 2, plastic)
        ok = ok & (~here | good)
        y = _store_hit(y, i, hit, here)
        y = y._replace(coat=_set_chain_row(y.coat, i, i >= 2, here))
        dn, valid = specular_continue(mp, subpath.shading(hit), -d,
                                      _chain_row(modes, jnp.maximum(i, 0)), plastic)
        ok = ok & (~(i >= 2) | valid)
        return y, geometry.offset_origin(hit.p, hit.n, dn), dn, ok

    o = geometry.offset_origin(xj, nj, w_new)
    y, _, _, ok = jax.lax.fori_loop(0, K - 1, body, (x, o, w_new, applicable))
    one = jnp.ones_like(k)
    y1, n1 = _chain_row(y.p, one), _chain_row(y.n, one)
    pr = camera.project(cam, y1)
    o_s, d_s, t_s = geometry.shadow_ray(y1, n1, pr.wi, pr.dist)
    ok = ok & pr.visible & ~geometry.occluded(scene, o_s, d_s, t_s)
    return y._replace(length=jnp.where(ok, k, 0), fx=jnp.where(ok, pr.px, x.fx),
                      fy=jnp.where(ok, pr.py, x.fy)), ok


def caustic_target(scene: Scene, x: Path, xv: PathValue) -> Array:
    """f* in the caustic perturbation's coordinates (solid angle at x_j, x_j, x_{j+1}, ... in
    area measure), up to shared factors: lum P(x) W(x_1) |cos theta_j|."""
    j, _ = caustic_vertex(scene, x)
    one = jnp.ones_like(x.length)
    w1, _ = _camera_weight(scene.camera, _chain_row(x.p, one), _chain_row(x.n, one))
    xj = _chain_row(x.p, j)
    cos_j = jnp.abs(dot(_chain_row(x.n, j), normalize(_chain_row(x.p, j - 1) - xj)))
    return xv.lum * w1 * cos_j


def caustic_perturbation(scene: Scene, cfg: MLTConfig, mu: Mutations, x: Path, xv: PathValue,
                         key: Array):
    """(y, its value, target ratio numerator, denominator, applicable): turn the direction
    leaving x_j by theta2 exp(-log(theta2/theta1) xi) about the old one (symmetric in solid
    angle) and retrace towards the eye."""
    j, applicable = caustic_vertex(scene, x)
    w = normalize(_chain_row(x.p, j - 1) - _chain_row(x.p, j))
    theta = log_uniform(rng.uniform(key, 0), mu.caustic_theta1, mu.caustic_theta2)
    y, _ = retrace_caustic(scene, cfg, x, rotate_about(w, theta, 2 * np.pi * rng.uniform(key, 1)))
    yv = evaluate(scene, cfg, y)
    return y, yv, caustic_target(scene, y, yv), caustic_target(scene, x, xv), applicable


# --- the chains ---------------------------------------------------------------------------------

def _large_step(scene, cfg, mu, x, xv, key):
    y = sample_path(scene, cfg, key)
    yv = evaluate(scene, cfg, y)
    return y, yv, yv.lum * yv.inv_pdf, xv.lum * xv.inv_pdf, jnp.ones_like(x.length) > 0


def _pixel(scene: Scene, path: Path) -> Array:
    W, H = scene.camera.width, scene.camera.height
    px = jnp.clip(jnp.floor(path.fx), 0, W - 1).astype(jnp.int32)
    py = jnp.clip(jnp.floor(path.fy), 0, H - 1).astype(jnp.int32)
    return py * W + px


@partial(jax.jit, static_argnames=("cfg", "n"))
def bootstrap(scene: Scene, cfg: MLTConfig, seed, n: int):
    key = rng.derive(rng.path_key(seed, jnp.arange(n, dtype=jnp.int32), 0), _SALT)
    path = sample_path(scene, cfg, key)
    v = evaluate(scene, cfg, path)
    return path, v.lum * v.inv_pdf, v


@partial(jax.jit, static_argnames=("cfg", "n_steps"))
def run_chains(scene: Scene, cfg: MLTConfig, mu: Mutations, seed, x: Path, step0, n_steps: int,
               scale, n_live):
    """Advance the chains by n_steps mutations, of which the first ``n_live`` (traced) count:
    a render's last block runs masked instead of compiling a shorter one. Returns (state, image
    sums times ``scale``, per-kind counts [3, 3]: proposed, applicable, accepted)."""
    W, H = scene.camera.width, scene.camera.height

    def kind(mutate):
        """A kind for :func:`jgi.transport.mcmc.metropolis`: each is symmetric in its own
        coordinates, so log T cancels and the acceptance is the ratio of the target written in
        them."""
        def mutation(state, key) -> mcmc.Move:
            x, xv = state
            y, yv, num, den, applicable = mutate(scene, cfg, mu, x, xv, rng.derive(key, 3))
            return mcmc.Move((y, yv), den, num, applicable=applicable, valid=y.length > 0)
        return mutation

    def splat_at(state):
        # each path splats b P / lum P at its film point
        path, value = state
        return _pixel(scene, path), value.color, value.lum

    mutations = [kind(_large_step), kind(lens_perturbation), kind(caustic_perturbation)]
    (x, _), img, tally, _ = mcmc.metropolis(
        mutations, (x, evaluate(scene, cfg, x)), n_steps, seed=seed, salt=_SALT + 1, step0=step0,
        n_live=n_live, kind_probs=jnp.stack([mu.p_large, mu.p_lens, mu.p_caustic]),
        record=mcmc.splatting(splat_at, scale), acc0=jnp.zeros((W * H, 3), jnp.float32))
    # per kind: (proposed, applicable, accepted), summed over the chains
    return x, img, jnp.stack([jnp.sum(n, axis=1) for n in tally], axis=1)


def check_scene(scene: Scene) -> None:
    if scene.lights.count == 0 or any(k not in AREA_KINDS for k in scene.lights.kinds):
        raise ParameterError("estimator 'mlt': path-space MLT needs area emitters only (quads, "
                             "triangles, spheres, disks, cylinders); this scene has point, "
                             "spot, directional or environment lights, or none")


def normalisation_from_path_tracer(scene: Scene, cfg: MLTConfig, seed: int, paths: int) -> float:
    """b = the mean luminance of a path-traced image (MIS, same maximum length): an unbiased
    estimate of the integral of f* over the film."""
    W, H = scene.camera.width, scene.camera.height
    img = path_tracer.render(scene, path_tracer.PathTracerConfig(max_depth=cfg.max_depth),
                             spp=max(1, -(-paths // (W * H))), seed=seed + 0x2F6B1D).image
    return float(np.mean(np.asarray(img, np.float64) @ np.array([0.2126, 0.7152, 0.0722])))


def render(scene: Scene, cfg: MLTConfig = MLTConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """Path-space MLT image with spp * W * H mutations in total (the path tracer's path count).

    Stats: ``b`` (the normalisation used), ``b_bootstrap`` and its standard error
    ``b_bootstrap_se``, ``mutations``, ``acceptance`` (accepted / proposed, all kinds), and per
    mutation kind K in ``MUTATION_KINDS``: ``K_proposed``, ``K_applicable`` (proposals the kind
    could make from the current path) and ``K_acceptance`` (accepted / applicable)."""
    check_scene(scene)
    W, H = scene.camera.width, scene.camera.height
    chains, bootstrap_samples, steps_per_call = (cfg.chains, cfg.bootstrap_samples,
                                                 cfg.steps_per_call)
    mu = cfg.mutations().arrays()
    b_paths = cfg.b_paths
    cfg = cfg.compile_key()
    paths, c_star, _ = bootstrap(scene, cfg, jnp.uint32(seed), bootstrap_samples)
    c_np = np.asarray(c_star, np.float64)
    b_bootstrap = c_np.mean()
    b = normalisation_from_path_tracer(scene, cfg, seed, b_paths) if b_paths > 0 else b_bootstrap
    if not (b > 0 and b_bootstrap > 0):
        return Render(np.zeros((H, W, 3), np.float32), {})
    cdf = np.cumsum(c_np) / c_np.sum()
    r = (np.arange(chains) + 0.5) / chains
    pick = jnp.asarray(np.minimum(np.searchsorted(cdf, r), bootstrap_samples - 1))
    x = jax.tree_util.tree_map(lambda a: jnp.take(a, pick, axis=a.ndim - 1), paths)
    n_steps_total = max(1, -(-spp * W * H // chains))
    scale = jnp.float32(b * W * H / (n_steps_total * chains))
    img = np.zeros((W * H, 3), np.float64)
    counts = np.zeros((3, 3), np.int64)
    for done in range(0, n_steps_total, steps_per_call):
        n = min(steps_per_call, n_steps_total - done)  # the last block runs masked
        x, part, c = run_chains(scene, cfg, mu, jnp.uint32(seed), x, jnp.int32(done),
                                steps_per_call, scale, jnp.int32(n))
        img += np.asarray(part, np.float64)
        counts += np.asarray(c, np.int64)
    stats = dict(b=b, b_bootstrap=b_bootstrap, mutations=n_steps_total * chains,
                 b_bootstrap_se=c_np.std() / np.sqrt(c_np.size),
                 acceptance=counts[:, 2].sum() / max(counts[:, 0].sum(), 1))
    for i, name in enumerate(MUTATION_KINDS):
        stats[f"{name}_proposed"] = int(counts[i, 0])
        stats[f"{name}_applicable"] = int(counts[i, 1])
        stats[f"{name}_acceptance"] = counts[i, 2] / max(counts[i, 1], 1)
    return Render(img.reshape(H, W, 3).astype(np.float32), stats)


def _check(cfg: MLTConfig) -> None:
    if cfg.p_large + cfg.p_lens + cfg.p_caustic <= 0:
        raise ParameterError("estimator 'mlt': p_large + p_lens + p_caustic must be positive")
    if cfg.p_large <= 0:
        raise ParameterError("estimator 'mlt', parameter 'p_large': must be > 0 (the large step "
                             "keeps the chain ergodic)")


register(Estimator(
    "mlt", "Veach's path-space MLT: lens and caustic perturbations mixed with large steps", render,
    MLTConfig, check=_check))
