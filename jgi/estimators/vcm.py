"""Vertex connection and merging (Georgiev, Krivanek, Davidovic, Slusallek 2012; SmallVCM), and
its special cases: bidirectional photon mapping, BDPT and progressive photon mapping.

Each *iteration* i traces one light subpath per pixel (N_L = W H of them: y_0 on a light, then
BSDF-sampled bounces, stored where the BSDF is not Dirac) and one camera subpath per pixel
(z_0 the pinhole). Every camera vertex z_{t-1} then estimates the paths through it with

* s = 0: the camera subpath hit an emitter;
* s = 1: next-event estimation (a light sample);
* s >= 2: a *connection* to vertex y_{s-1} of the pixel's own light subpath (BDPT's (s, t));
* *merging*: every stored light vertex y of *any* light subpath within radius r of z_{t-1}
  continues the camera subpath (a photon-density estimate, the photon's incident direction
  standing for the camera subpath's next one), L ~= sum_y f(z, y.wo) beta_y K_r(|z - y|) / N_L;

and every light vertex is connected to the pinhole (t = 1) and splatted. Merging is
consistent, not unbiased: r shrinks as r_i = r_0 i^((alpha - 1) / 2) (Hachisuka & Jensen's
schedule in SmallVCM's form), so its bias falls like r_i^2 (O(i^(alpha - 1))) while the
estimate averages over i.

MIS (:func:`mis_arrive`, :func:`mis_scatter` and the ``weight_*`` functions: every formula in
one place). A merge of light vertex y_{s-1} with camera vertex z is, to first order, the
connection technique with one more vertex sampled from *both* sides: its density is the
connection's times eta_VCM p(z) with eta_VCM = pi r^2 N_L (the merge disc's area times
the number of light subpaths, Georgiev et al. eq. 12). Over all techniques of a path,
w_tech = p_tech^b / sum_j p_j^b (balance b = 1, power b = ``power``). These sums are carried
along each subpath by three quantities (SmallVCM's dVCM, dVC, dVM; Georgiev's technical
report "Implementing vertex connection and merging", 2012), updated at every vertex:

  start (light):     dVCM = 1 / p_dir(y_0),  dVC = |cos y_0| / (p_A(y_0) p_dir(y_0))  (0 for a
                     Dirac light),  dVM = dVC / eta^b
  start (camera):    dVCM = 1 / p_film(z_0 -> z_1),  dVC = dVM = 0
  arrive at x_i:     dVCM *= d^2,  and dVCM, dVC, dVM /= |cos theta_in|
  scatter at x_i:    dVC = (|cos theta_out| / p_fwd) (dVC p_rev + dVCM + eta^b)
                     dVM = (|cos theta_out| / p_fwd) (dVM p_rev + dVCM / eta^b + 1)
                     dVCM = 1 / p_fwd
                     (a Dirac lobe: dVCM = 0; dVC, dVM *= |cos theta_out|)

with every density raised to b (``Mis``), p_fwd / p_rev the solid-angle densities of sampling
the new direction and, reversed, the old one, eta^b dropped (0) where the mode has no merging
(connections: eta^-b dropped where it has none). The weights are then 1 / (1 + w_light +
w_camera), w_light and w_camera each a product of the technique's own densities at the joint
and the other subpath's quantities (``weight_*``). With the same random numbers, ``bpt`` mode is
jgi's BDPT (:mod:`jgi.estimators.bdpt`, pbrt's ratio form of the same weights) path for path.

Modes (SmallVCM's): ``vcm`` (connections and merging), ``bpm`` (merging at every camera vertex,
no connections: bidirectional photon mapping), ``bpt`` (connections only: BDPT), ``ppm``
(merging at the first non-specular camera vertex, no MIS: progressive photon mapping). In the
merging-only modes an emitter hit counts only after a purely specular camera subpath (it cannot
be merged). Subpaths end at ``max_depth`` segments, at absorption, or by Russian roulette
(SmallVCM's: at every vertex the subpath survives with the material's albedo q, and q enters
both directional densities of the MIS; ``roulette=false`` keeps BDPT's random streams).
Directional and environment lights start light subpaths as SmallVCM's background light does:
y_0 is a direction, the subpath leaves a point of the disc covering the scene's bounding
sphere, so dVCM starts as 1 / p_disc, the light has no cosine, and the first segment's
arrival has no 1 / d^2 (solid-angle measure at infinity); next-event estimation compares
solid-angle densities at x (light sampling's with selection, the BSDF's) and weighs the
light subpaths by p_disc |cos x|; a camera subpath that escapes to the environment is the
s = 0 technique with the direction's light-sampling density (SmallVCM's GetLightRadiance).
A directional light is a Dirac direction: dVC = 0 and no s = 0.

Merging reads light vertices from a hash grid rebuilt on the device every iteration
(:func:`jgi.transport.hash_grid.index_cells`, the photon gathers' grid, cells of r). Every
(camera vertex, light vertex) pair of the cells a vertex's ball overlaps is listed and evaluated,
in blocks of fixed size, as many as there are pairs (:func:`merge_at_camera_vertices`): no
vertex has a cap, so no light vertex is ever dropped. The merge filter K_r (``filter``) is any
of photon mapping's density filters (:data:`jgi.transport.density.FILTERS`: box, cone,
Gaussian, Epanechnikov), normalised to integrate to one over the disc; the MIS uses the box's
acceptance area pi r^2 for every filter (as unified path sampling does). The image is
differentiable in r_0 and the filter's parameters (:func:`iteration_image`); with a filter that
vanishes at r (cone with k = 1, Epanechnikov) the image is continuous in r too.

Participating media (a scene filled by a homogeneous medium; UPBP's point-point 3-D estimator,
Krivanek et al. 2014, within VCM). Both walks sample free flights as BDPT's subpaths do
(:func:`jgi.transport.subpath.free_flight`), so medium vertices (phase function, no cosine, no
roulette) join every technique: next-event estimation and connections through the segment's
transmittance (:mod:`jgi.transport.connection`), and *volume merging*: a camera medium vertex
merges the light medium vertices within r_V (never surface ones, nor a surface vertex medium
ones), L ~= sum_y p(-w_y, wo) beta_y / sigma_s K_V(|z - y|) / N_L with the 3-D kernel
normalised over the ball (the light vertex's sigma_s is the camera vertex's to bring). The
MIS densities take the segments' distance densities (p(d) towards a medium vertex, P(d)
towards a surface: at arrival, :func:`mis_arrive`) and the merge vertex's own eta: eta_V =
4/3 pi r_V^3 N_L at a medium vertex (:class:`MisFactors`), r_V,i = r_V,0 i^((alpha - 1) / 3).
With the same random numbers ``bpt`` mode is BDPT path for path in fog too. In a grid medium the
walks track (spectral tracking), every transmittance is ratio tracking's along the shadow ray,
the MIS distance densities are BDPT's proxy (:func:`jgi.transport.subpath.segment_density`),
and a merge divides by sigma_s(y) at the light vertex (the camera vertex brings its own
sigma_s(z): equal as r_V -> 0). Light from directional and environment lights, extinguished by a
medium filling the scene, enters a grid (bounded) as in vacuum: the first segment from the
bounding disc takes no distance density (:func:`_arrive`), as an escaping camera subpath's
last takes none.

Random numbers: iteration i of pixel p draws the camera subpath from the stream (seed, p, i)
and the light subpath from :func:`jgi.transport.subpath.light_key` (seed, p, i), with BDPT's
dimension layout.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._xla import materialize
from ..core import rng
from ..core.compaction import compact_map
from ..core.imageio import write_exr, write_png
from ..core.progress import advance
from ..core.vec import V3, dot, max_component, where
from ..physics import bsdf, camera, geometry, grid_media, medium_interfaces
from ..physics.lights import (
    emitted,
    environment_pdf,
    environment_radiance,
    sample_emission,
    select_light,
)
from ..scene.tables import DIELECTRIC, ROUGH_DIELECTRIC, Scene
from ..transport import density, hash_grid
from ..transport.connection import (
    connect_camera,
    connect_vertices,
    occluded_many,
    transmittance,
)
from ..transport.subpath import (
    CAMERA_DIMS0,
    LIGHT_DIMS0,
    MEDIUM_DIMS,
    Vertices,
    at_medium_vertex,
    camera_dims_per_step,
    camera_ray,
    free_flight,
    has_infinite_lights,
    is_infinite,
    light_dims_per_step,
    light_key,
    light_normal,
    next_event_value,
    no_uv,
    pdf_bounding_disc,
    pdf_emission_dir,
    pdf_light_origin,
    phase_value,
    sample_next_event,
    scatter_in_medium,
    segment_density,
    shading,
)
from .registry import Estimator, Render, param, register

MODES = ("vcm", "bpm", "bpt", "ppm")
MIS_MAX = 1e30                # the recursive quantities are clamped here: no inf * 0 in weights


@dataclass(frozen=True)
class VCMConfig:
    """VCM's parameters. ``spp`` of a render is the number of iterations (one light and one
    camera subpath per pixel each)."""

    mode: str = param("vcm", "techniques: vcm (connect + merge), bpm (merge only), bpt "
                      "(connect only), ppm (merge at the first non-specular camera vertex)",
                      choices=MODES)
    max_depth: int = param(8, "maximum path segments", minimum=1, maximum=16)
    radius: float = param(0.02, "initial merge radius r_0 (scene units)", minimum=1e-6)
    volume_radius: float = param(0.0, "initial volume merge radius r_V,0 at medium vertices "
                                 "(3-D ball; 0: r_0), r_V,i = r_V,0 i^((alpha - 1) / 3)",
                                 minimum=0.0)
    radius_alpha: float = param(0.75, "radius schedule r_i = r_0 i^((alpha - 1) / 2), alpha in "
                                "(0, 1]", minimum=1e-3, maximum=1.0)
    heuristic: str = param("power", "MIS heuristic over all techniques",
                           choices=("balance", "power"))
    power: float = param(2.0, "power-heuristic exponent", minimum=0.1, maximum=16)
    filter: str = param("box", "merge filter (photon mapping's density filters)",
                        choices=density.FILTERS)
    cone_k: float = param(1.1, "cone filter k >= 1", minimum=1.0)
    gauss_alpha: float = param(density.JENSEN_ALPHA, "Gaussian filter alpha (Jensen's)",
                               minimum=1e-3)
    gauss_beta: float = param(density.JENSEN_BETA, "Gaussian filter beta (Jensen's)",
                              minimum=1e-3)
    roulette: bool = param(True, "Russian roulette at every vertex (SmallVCM's): survive with "
                           "the material's albedo q, densities times q (false: BDPT's streams)")
    technique_images: str = param("", "folder: also write each technique's weighted and "
                                  "unweighted image (connections by (s, t), merges by length)")
    chunk: int = 1 << 13      # camera subpaths per jitted call
    compact: bool = True      # techniques on live vertices only (False: dense, differentiable)

    @property
    def exponent(self) -> float:
        return 1.0 if self.heuristic == "balance" else float(self.power)

    @property
    def connects(self) -> bool:
        return self.mode in ("vcm", "bpt")

    @property
    def merges(self) -> bool:
        return self.mode in ("vcm", "bpm", "ppm")

    def filter_params(self) -> dict:
        """The merge filter's parameters (traced: an image is differentiable in them)."""
        if self.filter == "cone":
            return dict(k=jnp.float32(self.cone_k))
        if self.filter == "gaussian":
            return dict(gauss_alpha=jnp.float32(self.gauss_alpha),
                        gauss_beta=jnp.float32(self.gauss_beta))
        return {}

    def compile_key(self) -> "VCMConfig":
        """The settings a compiled function depends on (the rest are traced or host-side;
        without merges, ``bpt`` mode, the filter too: one compile serves every filter)."""
        return replace(self, radius=0.0, volume_radius=0.0, radius_alpha=1.0, cone_k=1.0,
                       gauss_alpha=1.0, gauss_beta=1.0, technique_images="",
                       filter=self.filter if self.merges else "box")

    def techniques(self) -> list[tuple]:
        """Every technique with its own image, in pyramid order: ("connect", s, t) for
        s + t - 1 <= max_depth (not (1, 1)), then ("merge", length) for length 2..max_depth."""
        D = self.max_depth
        out = []
        if self.connects:
            for length in range(1, D + 1):
                for s in range(0, length + 1):
                    t = length + 1 - s
                    if (s, t) != (1, 1):
                        out.append(("connect", s, t))
        else:   # emitters seen after a purely specular camera subpath
            out.extend(("connect", 0, length + 1) for length in range(1, D + 1))
        if self.merges:
            out.extend(("merge", length) for length in range(2, D + 1))
        return out


def radius_at(cfg: VCMConfig, iteration: int) -> float:
    """r_i = r_0 i^((alpha - 1) / 2) for iteration i = 1, 2, ... (SmallVCM's schedule)."""
    return cfg.radius * float(iteration) ** ((cfg.radius_alpha - 1.0) / 2.0)


def volume_radius_at(cfg: VCMConfig, iteration: int) -> float:
    """r_V,i = r_V,0 i^((alpha - 1) / 3): the 3-D estimate's variance grows like 1 / r^3, so
    the ball's volume, not its radius, shrinks like i^(alpha - 1) (Knaus and Zwicker 2011 in
    three dimensions); r_V,0 = ``volume_radius``, or r_0 where that is 0."""
    r0 = cfg.volume_radius if cfg.volume_radius > 0 else cfg.radius
    return r0 * float(iteration) ** ((cfg.radius_alpha - 1.0) / 3.0)


# --- MIS: the recursive quantities and the weights of each technique ------------------------------

class MisFactors(NamedTuple):
    """Per-iteration constants at a vertex: eta^b where merging is used (else 0) and eta^-b
    where connections are (else 0), eta = pi r^2 N_L at a surface vertex (eta_A), 4/3 pi r_V^3
    N_L at a medium vertex (eta_V: the merge ball's volume; UPBP's point-point 3-D estimator).

    dVM is kept normalised by the surface's eta_A (SmallVCM's form, exact in vacuum), so a
    medium vertex also needs eta_V / eta_A (``ratio``): there a merge's own term is eta_V /
    eta_A where a surface's is 1."""
    vm: Array        # Mis(eta): SmallVCM's misVmWeightFactor
    vc: Array        # Mis(1 / eta): misVcWeightFactor
    vc_surface: Array | None = None   # Mis(1 / eta_A) (where connections are): dVM's normaliser
    ratio: Array | float = 1.0        # Mis(eta / eta_A): 1 at a surface vertex


class Factors(NamedTuple):
    """An iteration's :class:`MisFactors`: the surface's and, in scenes filled by a medium, the
    volume's; :meth:`at` gives a vertex's."""
    surface: MisFactors
    volume: MisFactors | None = None

    def at(self, in_medium: Array | None) -> MisFactors:
        if in_medium is None or self.volume is None:
            return self.surface
        s, v = self.surface, self.volume
        return MisFactors(jnp.where(in_medium, v.vm, s.vm), jnp.where(in_medium, v.vc, s.vc),
                          s.vc_surface, jnp.where(in_medium, v.ratio, 1.0))


class Mis(NamedTuple):
    """dVCM, dVC, dVM of a subpath at its last vertex (see the module docstring)."""
    dvcm: Array
    dvc: Array
    dvm: Array


def mis_pow(x: Array, b: float) -> Array:
    """Mis(x) = x^b (b = 1: balance heuristic), finite: clamped at ``MIS_MAX``."""
    x = jnp.maximum(x, 0.0)
    y = x if b == 1.0 else (x * x if b == 2.0 else x ** b)
    return jnp.minimum(y, MIS_MAX)


def _inv(x: Array) -> Array:
    return jnp.where(x > 0, 1.0 / jnp.where(x > 0, x, 1.0), MIS_MAX)


def continuation(mp: bsdf.MaterialParams, roulette: bool) -> Array:
    """Russian roulette's survival probability q at a vertex: the material's albedo bound
    max(k_d + k_s) in [0.05, 1] (1 for dielectrics and without roulette). It depends on the
    material alone, so every technique multiplies the same q into a direction density sampled
    there, forwards or backwards (SmallVCM's ContinuationProb), and the weights stay a
    partition of unity."""
    if not roulette:
        return jnp.ones_like(mp.kd.x)
    q = jnp.clip(max_component(mp.kd + mp.ks), 0.05, 1.0)
    glass = (mp.kind == DIELECTRIC) | (mp.kind == ROUGH_DIELECTRIC)
    return jnp.where(glass, 1.0, q)


def mis_factors(radius, n_light: int, cfg: VCMConfig) -> MisFactors:
    """A surface vertex's factors, eta_A = pi r^2 N_L."""
    eta = jnp.pi * radius * radius * n_light
    b = cfg.exponent
    vc = mis_pow(1.0 / eta, b) if cfg.connects else jnp.zeros_like(eta)
    return MisFactors(mis_pow(eta, b) if cfg.merges else jnp.zeros_like(eta), vc, vc)


def volume_mis_factors(volume_radius, surface: MisFactors, radius, n_light: int,
                       cfg: VCMConfig) -> MisFactors:
    """A medium vertex's factors, eta_V = 4/3 pi r_V^3 N_L (and eta_V / eta_A)."""
    eta_v = (4.0 / 3.0) * jnp.pi * volume_radius ** 3 * n_light
    b = cfg.exponent
    return MisFactors(mis_pow(eta_v, b) if cfg.merges else jnp.zeros_like(eta_v),
                      mis_pow(1.0 / eta_v, b) if cfg.connects else jnp.zeros_like(eta_v),
                      surface.vc_surface,
                      mis_pow(eta_v / (jnp.pi * radius * radius * n_light), b))


def factors(scene: Scene, cfg: VCMConfig, radius, volume_radius, n_light: int) -> Factors:
    """The iteration's factors (the volume's in scenes filled by a medium)."""
    f = mis_factors(radius, n_light, cfg)
    if not scene.has_medium:
        return Factors(f)
    return Factors(f, volume_mis_factors(volume_radius, f, radius, n_light, cfg))


def mis_light_start(pdf_dir: Array, pdf_pos: Array, cos_y: Array, delta_light: Array,
                    f: MisFactors, b: float, pdf_disc: Array | None = None) -> Mis:
    """At y_0 (before the first segment): dVCM = 1 / p_dir (SmallVCM's directPdfA /
    emissionPdfW, light sampling and emission choosing y_0 alike), dVC = |cos y_0| / (p_A p_dir),
    0 for a Dirac (point, spot, directional) light, which no other technique can reach.

    ``pdf_disc`` (directional and environment lights; elsewhere None): the area density of the
    origin on the bounding disc. Light sampling then chooses the direction, emission the
    direction and the disc point, so dVCM = directPdfW / emissionPdfW = 1 / p_disc; the light
    has no cosine (|cos y_0| = 1, as SmallVCM's background light)."""
    dvc = jnp.where(delta_light, 0.0, mis_pow(cos_y * _inv(pdf_pos * pdf_dir), b))
    dvcm = _inv(pdf_dir) if pdf_disc is None else _inv(pdf_disc)
    return Mis(mis_pow(dvcm, b), dvc, dvc * f.vc_surface)


def mis_camera_start(pdf_film: Array, b: float) -> Mis:
    """At z_0: dVCM = 1 / p_film (jgi's film density covers the whole image, so N_L is in it)."""
    z = jnp.zeros_like(pdf_film)
    return Mis(mis_pow(_inv(pdf_film), b), z, z)


def mis_arrive(m: Mis, d2: Array, cos_in: Array, b: float, dist_prev: Array | None = None,
               dist_new: Array | None = None) -> Mis:
    """At a new vertex: the last direction's solid-angle density becomes an area density.

    In a medium (``dist_prev``, ``dist_new``: the segment's distance densities p_dist towards
    the previous vertex's kind and the new one's, p(d) at a medium vertex, P(d) at a surface;
    ``cos_in`` 1 at a medium vertex) the new vertex's forward density takes p_dist(new), and
    the previous vertex's reverse density, a factor of dVC's and dVM's every term, takes
    p_dist(previous): the segment is now known."""
    inv_cos = mis_pow(_inv(jnp.abs(cos_in)), b)
    if dist_new is None:
        return Mis(jnp.minimum(m.dvcm * mis_pow(d2, b) * inv_cos, MIS_MAX),
                   jnp.minimum(m.dvc * inv_cos, MIS_MAX), jnp.minimum(m.dvm * inv_cos, MIS_MAX))
    inv_new = inv_cos * mis_pow(_inv(dist_new), b)
    rev = mis_pow(dist_prev, b) * inv_new
    return Mis(jnp.minimum(m.dvcm * mis_pow(d2, b) * inv_new, MIS_MAX),
               jnp.minimum(m.dvc * rev, MIS_MAX), jnp.minimum(m.dvm * rev, MIS_MAX))


def mis_scatter(m: Mis, cos_out: Array, pdf_fwd: Array, pdf_rev: Array, specular: Array,
                f: MisFactors, b: float) -> Mis:
    """After sampling the next direction (densities p_fwd of it, p_rev of the reverse)."""
    c = mis_pow(jnp.abs(cos_out), b)
    g = mis_pow(jnp.abs(cos_out) * _inv(pdf_fwd), b)
    rev = mis_pow(pdf_rev, b)
    dvc = g * (m.dvc * rev + m.dvcm + f.vm)
    dvm = g * (m.dvm * rev + m.dvcm * f.vc_surface + f.ratio)
    dvcm = mis_pow(_inv(pdf_fwd), b)
    out = Mis(jnp.where(specular, 0.0, dvcm), jnp.where(specular, m.dvc * c, dvc),
              jnp.where(specular, m.dvm * c, dvm))
    return Mis(*(jnp.minimum(x, MIS_MAX) for x in out))


def weight_emission(m: Mis, pdf_pos: Array, pdf_emit_dir: Array, b: float) -> Array:
    """s = 0, the camera subpath z hit an emitter at y: against light sampling (p_A(y)) and the
    light subpaths that start at y (p_A(y) p_dir). A camera subpath that escaped to the
    environment (``m`` then as it left its last vertex, with no arrival: SmallVCM's
    GetLightRadiance) passes the direction's light-sampling density for p_A and the bounding
    disc's area density for p_dir."""
    w_camera = mis_pow(pdf_pos, b) * m.dvcm + mis_pow(pdf_pos * pdf_emit_dir, b) * m.dvc
    return 1.0 / (1.0 + w_camera)


def weight_next_event(m: Mis, pdf_light_y: Array, pdf_bsdf_y: Array, pdf_emit_x: Array,
                      pdf_bsdf_rev: Array, delta_light: Array, f: MisFactors, b: float) -> Array:
    """s = 1 at camera vertex x, light point y: area densities of y by light sampling
    (``pdf_light_y``) and by BSDF sampling at x (``pdf_bsdf_y``), of x by emission from y
    (``pdf_emit_x``), and the BSDF's solid-angle density of the reverse direction at x."""
    w_light = jnp.where(delta_light, 0.0, mis_pow(pdf_bsdf_y * _inv(pdf_light_y), b))
    w_camera = mis_pow(pdf_emit_x, b) * (f.vm + m.dvcm + m.dvc * mis_pow(pdf_bsdf_rev, b))
    return 1.0 / (1.0 + w_light + w_camera)


def weight_connection(light: Mis, camera: Mis, pdf_y_from_z: Array, pdf_z_from_y: Array,
                      pdf_y_rev: Array, pdf_z_rev: Array, f: MisFactors, b: float,
                      f_camera: MisFactors | None = None) -> Array:
    """Light vertex y joined to camera vertex z: area densities of y sampled from z and of z
    from y, and at each end the BSDF's solid-angle density of its own subpath's previous
    direction given the connecting one. ``f`` are y's factors, ``f_camera`` z's where they
    differ (a medium vertex at one end)."""
    fz = f if f_camera is None else f_camera
    w_light = mis_pow(pdf_y_from_z, b) * (f.vm + light.dvcm + light.dvc * mis_pow(pdf_y_rev, b))
    w_camera = mis_pow(pdf_z_from_y, b) * (fz.vm + camera.dvcm
                                           + camera.dvc * mis_pow(pdf_z_rev, b))
    return 1.0 / (1.0 + w_light + w_camera)


def weight_camera_connection(light: Mis, pdf_cam: Array, pdf_y_rev: Array, f: MisFactors,
                             b: float) -> Array:
    """t = 1: light vertex y joined to the pinhole (``pdf_cam``: the camera's area density of
    y, film-normalised, so N_L is in it)."""
    w_light = mis_pow(pdf_cam, b) * (f.vm + light.dvcm + light.dvc * mis_pow(pdf_y_rev, b))
    return 1.0 / (1.0 + w_light)


def weight_merge(light: Mis, camera: Mis, pdf_fwd: Array, pdf_rev: Array, f: MisFactors,
                 b: float) -> Array:
    """Light vertex y merged at camera vertex z: the camera BSDF's densities of y's incident
    direction (``pdf_fwd``, continuing the camera subpath) and of the camera's own previous
    direction given it (``pdf_rev``); ``f`` the merge vertex's factors (dVM / ratio: dVM
    normalised by that vertex's eta rather than the surface's)."""
    w_light = light.dvcm * f.vc + light.dvm * mis_pow(pdf_fwd, b) / f.ratio
    w_camera = camera.dvcm * f.vc + camera.dvm * mis_pow(pdf_rev, b) / f.ratio
    return 1.0 / (1.0 + w_light + w_camera)


# --- light subpaths -------------------------------------------------------------------------------

class LightVertices(NamedTuple):
    """Light-subpath vertices y_1 .. y_{D-1}, each field [D - 1, N] (row k - 1: y_k)."""
    p: V3
    n: V3
    wo: V3              # towards y_{k-1}: the incident direction a merge uses
    beta: V3            # throughput arriving at y_k (before its BSDF)
    mis: Mis
    stored: Array       # a valid vertex with a non-Dirac BSDF (connectable, mergeable)
    material: Array
    uv: tuple | None
    ns: V3 | None       # shading normal, in scenes with vertex normals
    in_medium: Array | None = None   # a medium vertex (zero normal), in scenes with a medium
    medium: Array | None = None      # the medium id it was reached in (bounded media)


def light_walk(scene: Scene, cfg: VCMConfig, key: Array, fs: Factors):
    """The light subpath of stream ``key`` (BDPT's dimension layout), with its MIS quantities.
    Returns (:class:`LightVertices` [D - 1, N], valid start).

    In a scene filled by a medium every segment samples a free flight
    (:func:`jgi.transport.subpath.free_flight`, BDPT's), making medium vertices that scatter by
    the phase function (no roulette there: q = 1); light from infinity is extinguished (as in
    BDPT: those subpaths are dropped)."""
    lights, mats = scene.lights, scene.materials
    kinds = mats.kinds
    b = cfg.exponent
    f = fs.surface
    medium = scene.has_medium
    dims = light_dims_per_step(scene)
    if scene.has_grid_medium:   # the trackings' derivatives would come out zero: refused
        grid_media.refuse_derivatives(medium_interfaces.grids(scene))
    u = lambda k: rng.uniform(key, k)  # noqa: E731
    em = sample_emission(lights, u(0), u(1), u(2), u(3), u(4))
    ok = (em.pdf_pos > 0) & (max_component(em.weight) > 0)
    delta_light = em.delta_pos | em.delta_dir
    at_infinity = None
    if scene.fills_with_homogeneous_medium and has_infinite_lights(lights):
        # a medium filling the scene extinguishes light from infinity (T(inf) = 0); a grid is
        # bounded, so there the subpaths start from the bounding disc as in vacuum
        ok = ok & ~is_infinite(lights, em.element)
        mis = mis_light_start(em.pdf_dir, em.pdf_pos, jnp.abs(dot(em.n, em.d)), delta_light, f, b)
    elif has_infinite_lights(lights):   # y_0 a direction, the subpath leaves the bounding disc
        at_infinity = is_infinite(lights, em.element)
        pdf_disc = jnp.where(at_infinity, pdf_bounding_disc(lights), 0.0)
        mis = mis_light_start(em.pdf_dir, em.pdf_pos, jnp.abs(dot(em.n, em.d)), delta_light, f,
                              b, jnp.where(at_infinity, pdf_disc, em.pdf_dir))
    else:
        mis = mis_light_start(em.pdf_dir, em.pdf_pos, jnp.abs(dot(em.n, em.d)), delta_light, f, b)
    start = (geometry.offset_origin(em.p, em.n, em.d), em.d, em.weight, em.p, jnp.zeros_like(ok),
             mis, ok, medium_interfaces.start(scene, em.pdf_pos))
    rr_dim0 = LIGHT_DIMS0 + (cfg.max_depth - 1) * dims   # past BDPT's dimensions

    def step(s, j):
        o, d, beta, prev_p, prev_medium, m, alive, medium_id = s
        base = LIGHT_DIMS0 + j * dims
        hit = geometry.intersect(scene, o, d)
        in_med = None
        if medium:
            hit, in_med, w_ff = free_flight(scene, o, d, hit, alive,
                                            u(base + dims - MEDIUM_DIMS),
                                            u(base + dims - MEDIUM_DIMS + 1),
                                            medium_id=medium_id)
            beta = beta * w_ff
        valid = alive & hit.valid
        v = hit.p - prev_p
        d2 = dot(v, v)
        from_infinity = None
        if at_infinity is not None:   # from infinity: solid angle, no 1 / d^2 (tech. rep. 5.1)
            from_infinity = at_infinity & (j == 0)
            d2 = jnp.where(from_infinity, 1.0, d2)
        m = _arrive(scene, m, d2, dot(hit.n, d), prev_medium, in_med, b, from_infinity,
                    medium_id)
        mp = bsdf.lookup_specialised(mats, hit.material, hit.uv)
        wo = -d
        delta = bsdf.is_delta(mp) if in_med is None else bsdf.is_delta(mp) & ~in_med
        vert = LightVertices(hit.p, hit.n, wo, beta, m, valid & ~delta, hit.material,
                             hit.uv, hit.ns, in_med, medium_id)
        ns = shading(hit)       # BSDFs about the shading normal; densities convert with hit.n
        bs = materialize(bsdf.sample(kinds, mp, ns, wo, u(base), u(base + 1), u(base + 2),
                                     mode=bsdf.IMPORTANCE))
        _, pdf_rev = bsdf.evaluate(kinds, mp, ns, bs.wi, wo)
        q = continuation(mp, cfg.roulette)
        cos_out = dot(hit.n, bs.wi)
        if medium:
            bs, pdf_rev = scatter_in_medium(scene, bs, pdf_rev, d, in_med, u(base), u(base + 1),
                                            medium_id)
            q, cos_out = jnp.where(in_med, 1.0, q), jnp.where(in_med, 1.0, cos_out)
        m = mis_scatter(m, cos_out, bs.pdf * q, pdf_rev * q, bs.delta, fs.at(in_med), b)
        beta = beta * bs.weight / q
        if hit.ns is not None:   # Veach's adjoint correction (a light subpath)
            corr = bsdf.adjoint_correction(hit.ns, hit.n, wo, bs.wi)
            beta = beta * (corr if in_med is None else jnp.where(in_med, 1.0, corr))
        alive = valid & bs.valid & (max_component(beta) > 0)
        if cfg.roulette:
            alive = alive & (rng.uniform(key, rr_dim0 + j) < q)
        nxt = (geometry.offset_origin(hit.p, hit.n, bs.wi), bs.wi, beta, hit.p,
               jnp.zeros_like(valid) if in_med is None else in_med, m, alive,
               medium_interfaces.leaving(scene, medium_id, hit.material, hit.n, bs.wi, in_med))
        return nxt, vert

    _, verts = jax.lax.scan(step, start, jnp.arange(cfg.max_depth - 1))
    return verts, ok


def _continuation_at(scene: Scene, cfg: VCMConfig, v) -> Array:
    """q at vertices v (records with material, uv and in_medium): 1 at a medium vertex."""
    q = continuation(bsdf.lookup(scene.materials, v.material, v.uv), cfg.roulette)
    return q if v.in_medium is None else jnp.where(v.in_medium, 1.0, q)


def _arrive(scene: Scene, m: Mis, d2: Array, cos_in: Array, prev_medium: Array,
            in_medium: Array | None, b: float, from_infinity: Array | None = None,
            medium_id: Array | None = None) -> Mis:
    """:func:`mis_arrive` at a new vertex (a medium vertex: no cosine, and the segment's
    distance densities towards both ends' kinds; none for a segment ``from_infinity``, a light
    subpath's first from a directional or environment light into a bounded grid medium, as
    the camera subpath that escapes to infinity has none for its last). ``medium_id``: the
    segment's medium (scenes with media bounded by shapes)."""
    if in_medium is None:
        return mis_arrive(m, d2, cos_in, b)
    dist_prev = segment_density(scene, d2, prev_medium, medium_id)
    dist_new = segment_density(scene, d2, in_medium, medium_id)
    if from_infinity is not None:
        dist_prev = jnp.where(from_infinity, 1.0, dist_prev)
        dist_new = jnp.where(from_infinity, 1.0, dist_new)
    return mis_arrive(m, d2, jnp.where(in_medium, 1.0, cos_in), b, dist_prev, dist_new)


def _as_vertices(scene: Scene, y: LightVertices) -> Vertices:
    """Light vertices in :class:`~jgi.transport.subpath.Vertices` form (for connect_camera)."""
    z = jnp.zeros_like(y.p.x)
    on_surface = y.stored if y.in_medium is None else y.stored & ~y.in_medium
    return Vertices(y.p, y.n, y.wo, y.beta, z, z, ~y.stored, on_surface, y.stored, y.material,
                    y.material * 0 - 1, y.uv if y.uv is not None else no_uv(scene, z), y.ns,
                    None, y.in_medium, y.medium)


def light_pass(scene: Scene, cfg: VCMConfig, seed, iteration, fs: Factors, paths: Array):
    """Light subpaths ``paths`` of an iteration: their vertices, and the t = 1 connections
    (pixel [D - 1, N], MIS-weighted and unweighted values)."""
    b = cfg.exponent
    key = light_key(seed, paths, iteration)
    y, _ = light_walk(scene, cfg, key, fs)
    if not cfg.connects or cfg.max_depth < 2:
        return y, None
    K, N = y.material.shape

    def batch(yb: LightVertices, live):
        yb = yb._replace(stored=yb.stored & live)
        conn = materialize(connect_camera(scene, _as_vertices(scene, yb)))
        occ = occluded_many(scene, [conn.shadow])[0]
        q = _continuation_at(scene, cfg, yb)
        w = weight_camera_connection(yb.mis, conn.pdf_cam, conn.pdf_y_rev * q,
                                     fs.at(yb.in_medium), b)
        keep = conn.ok & ~occ
        value = where(keep, conn.value, V3.full(0.0, w))
        # pixel + 1: entries never written stay 0, i.e. pixel -1
        return (jnp.where(keep, conn.pixel, -1) + 1, jnp.stack(list(value * w), -1),
                jnp.stack(list(value), -1))

    flat = _flatten_light(y)
    like = (jnp.zeros((K * N,), jnp.int32), jnp.zeros((K * N, 3)), jnp.zeros((K * N, 3)))
    if cfg.compact:
        pix, wtd, unw = compact_map(batch, flat.stored, flat, like, CONNECT_BATCH)
    else:
        pix, wtd, unw = batch(flat, flat.stored)
    back = lambda a: V3(*(a[:, c].reshape(K, N) for c in range(3)))  # noqa: E731
    return y, ((pix - 1).reshape(K, N), back(wtd), back(unw))


# --- camera subpaths ------------------------------------------------------------------------------

class CameraVertices(NamedTuple):
    """Camera-subpath vertices z_1 .. z_D, each field [D, N], with what each found on the way."""
    p: V3
    n: V3
    wo: V3
    beta: V3
    mis: Mis
    connectable: Array     # valid and non-Dirac
    first_diffuse: Array   # the first non-Dirac vertex after a purely specular subpath
    material: Array
    uv: tuple | None
    ns: V3 | None          # shading normal, in scenes with vertex normals
    emission: V3           # s = 0, unweighted
    w_emission: Array
    next_event: V3         # s = 1, unweighted (visibility tested)
    w_next_event: Array
    in_medium: Array | None = None   # a medium vertex (zero normal), in scenes with a medium
    medium: Array | None = None      # the medium id it was reached in (bounded media)


def camera_walk(scene: Scene, cfg: VCMConfig, key: Array, pixel: Array,
                fs: Factors) -> CameraVertices:
    """The camera subpath of stream ``key`` through ``pixel``, with s = 0 and s = 1 at each
    vertex (in a medium as :func:`light_walk`; next-event estimation from a medium vertex by
    the phase function, through the shadow segment's transmittance)."""
    cam, lights, mats = scene.camera, scene.lights, scene.materials
    kinds = mats.kinds
    b, D = cfg.exponent, cfg.max_depth
    medium = scene.has_medium
    dims = camera_dims_per_step(scene)
    if scene.has_grid_medium:   # the trackings' derivatives would come out zero: refused
        grid_media.refuse_derivatives(medium_interfaces.grids(scene))
    u0 = lambda k: rng.uniform(key, k)  # noqa: E731
    o, d = camera_ray(cam, pixel, u0)
    z = jnp.zeros_like(o.x)
    one = V3(z + 1, z + 1, z + 1)
    mis = mis_camera_start(camera.project(cam, o + d).pdf_dir, b)
    start = (o, d, one, o, z != 0, mis, z == 0, z == 0, medium_interfaces.start(scene, z))
    rr_dim0 = CAMERA_DIMS0 + D * dims   # past BDPT's dimensions

    def step(s, j):
        o, d, beta, prev_p, prev_medium, m, alive, specular_path, medium_id = s
        base = CAMERA_DIMS0 + j * dims
        u = lambda k: rng.uniform(key, base + k)  # noqa: E731
        hit = geometry.intersect(scene, o, d)
        in_med = None
        if medium:
            hit, in_med, w_ff = free_flight(scene, o, d, hit, alive, u(dims - MEDIUM_DIMS),
                                            u(dims - MEDIUM_DIMS + 1), medium_id=medium_id)
            beta = beta * w_ff
        valid = alive & hit.valid
        v = hit.p - prev_p
        d2 = dot(v, v)
        m_left = m            # as the subpath left its last vertex (an escaped ray's)
        m = _arrive(scene, m, d2, dot(hit.n, d), prev_medium, in_med, b, None, medium_id)
        mp = bsdf.lookup_specialised(mats, hit.material, hit.uv)
        wo = -d
        delta = bsdf.is_delta(mp) if in_med is None else bsdf.is_delta(mp) & ~in_med
        connectable = valid & ~delta
        q = continuation(mp, cfg.roulette)
        if medium:
            q = jnp.where(in_med, 1.0, q)
        f = fs.at(in_med)
        # ---- s = 0: an emitter ----
        e = jnp.where(valid, hit.emitter, -1)
        pdf_pos = pdf_light_origin(lights, e)
        emission = beta * emitted(lights, e, hit.n, wo)
        if cfg.connects:
            w_e = weight_emission(m, pdf_pos, pdf_emission_dir(lights, e, hit.n, wo), b)
            if lights.environment >= 0:   # ... or the environment, the ray having escaped
                escaped = alive & ~hit.valid
                p_env = environment_pdf(lights, d)
                w_env = weight_emission(m_left, p_env, pdf_bounding_disc(lights), b)
                w_e = jnp.where(escaped, w_env, w_e)
            w_e = jnp.where(j == 0, 1.0, w_e)
        else:   # merging only: emitters count after purely specular subpaths alone
            w_e = jnp.where(specular_path, 1.0, 0.0)
        if lights.environment >= 0:
            emission = where(alive & ~hit.valid, beta * environment_radiance(lights, d), emission)
        # ---- s = 1: next-event estimation ----
        ns = shading(hit)       # BSDFs about the shading normal; densities convert with hit.n
        if cfg.connects and D >= 2:
            ne_active = valid & (j + 2 <= D)
            ne = sample_next_event(scene, mp, hit.p, hit.n, wo, u(3), u(4), u(5), ne_active,
                                   ns=hit.ns)
            ls = ne.light
            k = select_light(lights, u(3))
            # the shadow segment's medium (bounded media): the light's side of the surface
            shadow_medium = medium_interfaces.leaving(scene, medium_id, hit.material, hit.n,
                                                      ls.wi, in_med)
            _, pdf_bsdf_rev = bsdf.evaluate(kinds, mp, ns, ls.wi, wo)
            cos_x = jnp.abs(dot(ls.wi, hit.n))
            if medium:   # the phase function at a medium vertex, no cosine
                f_m = phase_value(scene, d, ls.wi, medium_id)
                ne = at_medium_vertex(ne, in_med, f_m, ne_active)
                pdf_bsdf_rev = jnp.where(in_med, f_m, pdf_bsdf_rev)
                cos_x = jnp.where(in_med, 1.0, cos_x)
            y = hit.p + ls.wi * ls.dist
            n_y, y_surface = light_normal(lights, k, y)
            d2_y = ls.dist * ls.dist
            inv_d2 = _inv(d2_y)
            cos_y = jnp.where(y_surface, jnp.abs(dot(n_y, ls.wi)), 1.0)
            pdf_emit_x = pdf_emission_dir(lights, k, n_y, -ls.wi) * cos_x * inv_d2
            pdf_light_y, pdf_bsdf_y = pdf_light_origin(lights, k), ne.pdf_bsdf * q * cos_y * inv_d2
            if medium:   # each end's distance density (the light's: a surface's, P(d))
                pdf_emit_x = pdf_emit_x * segment_density(scene, d2_y, in_med, shadow_medium)
                pdf_bsdf_y = pdf_bsdf_y * segment_density(scene, d2_y, jnp.zeros_like(in_med),
                                                          shadow_medium)
            if has_infinite_lights(lights):
                # a light at infinity: y_0 is a direction (solid-angle densities, selection
                # included), x is reached from the bounding disc (SmallVCM's background light)
                inf = is_infinite(lights, k)
                pdf_light_y = jnp.where(inf, ls.pdf, pdf_light_y)
                pdf_bsdf_y = jnp.where(inf, ne.pdf_bsdf * q, pdf_bsdf_y)
                pdf_emit_x = jnp.where(inf, pdf_bounding_disc(lights) * cos_x, pdf_emit_x)
            w_ne = weight_next_event(m, pdf_light_y, pdf_bsdf_y, pdf_emit_x, pdf_bsdf_rev * q,
                                     ls.delta, f, b)
            Z = V3.full(0.0, z)
            ne_value = where(~geometry.occluded(scene, *ne.shadow), next_event_value(ne, beta), Z)
            if medium:
                ne_value = ne_value * transmittance(scene, ls.dist, ne.shadow,
                                                    max_component(ne_value) > 0, shadow_medium)
        else:
            ne_value, w_ne = V3.full(0.0, z), z
        rec = CameraVertices(hit.p, hit.n, wo, beta, m, connectable,
                             connectable & specular_path, hit.material, hit.uv, hit.ns, emission,
                             w_e, ne_value, w_ne, in_med, medium_id)
        # ---- the next direction ----
        bs = materialize(bsdf.sample(kinds, mp, ns, wo, u(0), u(1), u(2)))
        _, pdf_rev = bsdf.evaluate(kinds, mp, ns, bs.wi, wo)
        cos_out = dot(hit.n, bs.wi)
        if medium:
            bs, pdf_rev = scatter_in_medium(scene, bs, pdf_rev, d, in_med, u(0), u(1),
                                            medium_id)
            cos_out = jnp.where(in_med, 1.0, cos_out)
        m = mis_scatter(m, cos_out, bs.pdf * q, pdf_rev * q, bs.delta, f, b)
        beta = beta * bs.weight / q
        alive = valid & bs.valid & (max_component(beta) > 0)
        if cfg.roulette:
            alive = alive & (rng.uniform(key, rr_dim0 + j) < q)
        # left by a Dirac lobe (per sample on plastic: a merge there estimates its base alone,
        # and the coating's reflection goes on)
        delta_s = bsdf.sampled_delta(kinds, mp, bs)
        if medium:
            delta_s = delta_s & ~in_med
        if cfg.mode == "ppm":   # the subpath ends at its first merge
            alive = alive & delta_s
        nxt = (geometry.offset_origin(hit.p, hit.n, bs.wi), bs.wi, beta, hit.p,
               prev_medium if in_med is None else in_med, m, alive, specular_path & delta_s,
               medium_interfaces.leaving(scene, medium_id, hit.material, hit.n, bs.wi, in_med))
        return nxt, rec

    _, verts = jax.lax.scan(step, start, jnp.arange(D))
    return verts


def connection_pairs(cfg: VCMConfig) -> list[tuple[int, int]]:
    """(k, j): light vertex y_k joined to camera vertex z_{j+1}, i.e. strategy (s, t) =
    (k + 1, j + 2), for every pair with s + t - 1 <= max_depth."""
    D = cfg.max_depth
    return [(k, j) for j in range(D) for k in range(1, D) if k + j + 2 <= D]


def _connect(scene: Scene, cfg: VCMConfig, y: LightVertices, z: CameraVertices, fs: Factors):
    """Light vertices y joined to camera vertices z (rows of pairs): (weighted, unweighted) V3.
    The direction densities at both ends carry Russian roulette's continuation q."""
    conn = connect_vertices(scene, y, z, y.stored & z.connectable,
                            continuation=partial(continuation, roulette=cfg.roulette),
                            reciprocal=True)
    occ = occluded_many(scene, [conn.shadow])[0]
    value = where(occ, V3.full(0.0, conn.pdf_y_rev), conn.value)
    wt = weight_connection(y.mis, z.mis, conn.pdf_y_from_z, conn.pdf_z_from_y, conn.pdf_y_rev,
                           conn.pdf_z_rev, fs.at(y.in_medium), cfg.exponent,
                           fs.at(z.in_medium))
    return value * wt, value


def connections(scene: Scene, cfg: VCMConfig, y: LightVertices, z: CameraVertices,
                fs: Factors, summed: bool = False):
    """s, t >= 2: y_{s-1} of the pixel's own light subpath joined to z_{t-1}, for every
    :func:`connection_pairs` pair whose two vertices are connectable (gathered into batches:
    :func:`jgi.core.compaction.compact_map`; ``cfg.compact``). Returns (weighted, unweighted)
    [J, N] V3; ``summed``: (the weighted sum over the pairs [1, N], None)."""
    pairs = connection_pairs(cfg)
    if not pairs:
        return None, None
    J, N = len(pairs), z.material.shape[1]
    k = jnp.repeat(jnp.array([k for k, _ in pairs], jnp.int32), N)
    j = jnp.repeat(jnp.array([j for _, j in pairs], jnp.int32), N)
    n = jnp.tile(jnp.arange(N, dtype=jnp.int32), J)
    active = y.stored[k - 1, n] & z.connectable[j, n]

    def batch(idx, live):
        kb, jb, nb = idx
        yb = jax.tree_util.tree_map(lambda a: a[kb - 1, nb], y)
        zb = jax.tree_util.tree_map(lambda a: a[jb, nb], z)
        wtd, unw = _connect(scene, cfg, yb._replace(stored=yb.stored & live), zb, fs)
        return jnp.stack(list(wtd), -1), jnp.stack(list(unw), -1)

    if cfg.compact and summed:   # a pixel's sum: no [J N] rows to store and read back
        wtd = compact_map(lambda idx, live: batch(idx, live)[0], active, (k, j, n),
                          jnp.zeros((N, 3)), CONNECT_BATCH, dest=n)
        return V3(*(wtd[None, :, c] for c in range(3))), None
    like = (jnp.zeros((J * N, 3)), jnp.zeros((J * N, 3)))
    if cfg.compact:
        wtd, unw = compact_map(batch, active, (k, j, n), like, CONNECT_BATCH)
    else:
        wtd, unw = batch((k, j, n), active)
    back = lambda a: V3(*(a[:, c].reshape(J, N) for c in range(3)))  # noqa: E731
    return back(wtd), back(unw)


class MergeGrid(NamedTuple):
    """An iteration's stored light vertices for merging: the hash grid over them, and their
    records in grid order packed as rows [M, 16] (position, normal, incident direction, beta,
    dVCM, dVC, dVM, row k - 1 of y_k), so a query reads each candidate in one contiguous
    gather, not sixteen scattered ones (measured: docs/performance.md#vcm-merging); the
    positions and rows again as [M, 4] for the distance test, which every candidate takes."""
    cells: hash_grid.CellIndex
    rows: Array           # [M, 16] float32
    where: Array          # [M, 4] float32: position, row


def merge_grid(y_all: LightVertices, radius, table_size: int, n_light: int,
               scene: Scene | None = None) -> MergeGrid:
    """The grid of cell ``radius`` (the largest merge radius) over the stored light vertices.
    A medium vertex's row has a zero normal and the throughput without the medium's sigma_s
    (a volume density estimate of the arriving light: the camera vertex brings its own
    sigma_s; the photon maps' T / p)."""
    # most slots are empty (absorbed, Dirac, ended by roulette): sort only the stored ones
    cells = hash_grid.index_cells(y_all.p, y_all.stored, radius, table_size,
                                  capacity=2 * n_light)
    o = cells.order
    row = (o // n_light).astype(jnp.float32)
    beta = y_all.beta
    if y_all.in_medium is not None:   # (a grid medium's sigma_s at the vertex)
        in_grid = medium_interfaces.in_grid(scene, y_all.medium)
        if scene.has_grid_medium:
            sigma_s = medium_interfaces.scattering(scene, y_all.medium, y_all.p)
        if not scene.has_grid_medium or in_grid is not None:
            at = medium_interfaces.parameters(scene, y_all.medium)   # the vertex's medium's
            sigma_h = at.sigma_t * at.albedo
            sigma_s = sigma_h if not scene.has_grid_medium else where(in_grid, sigma_s, sigma_h)
        inv_s = V3(*(jnp.where(c > 0, 1.0 / jnp.where(c > 0, c, 1.0), 0.0) for c in sigma_s))
        beta = where(y_all.in_medium, beta * inv_s, beta)
    if scene is not None and scene.materials.has_masks:
        # a masked surface stops a fraction opacity of the light arriving there: a merge
        # (a density estimate of that arriving light) divides the vertex's throughput by it,
        # as the photon maps do (connections need no factor: they start at the vertex)
        a = geometry.opacity(scene, y_all.material, lambda: y_all.uv)
        if y_all.in_medium is not None:
            a = jnp.where(y_all.in_medium, 1.0, a)
        beta = beta * (1.0 / jnp.where(a > 0, a, 1.0))
    cols = [*y_all.p, *y_all.n, *y_all.wo, *beta, *y_all.mis]
    rows = jnp.stack([c[o] for c in cols] + [row], -1)
    return MergeGrid(cells, rows, rows[:, jnp.array([0, 1, 2, 15])])


MERGE_BATCH = 4096      # camera vertices merged per batch (compact_map)
MERGE_PAIRS = 1 << 14   # (camera vertex, light vertex) candidate pairs tested per block
MERGE_NEAR = 1 << 12    # pairs within r evaluated per batch
CONNECT_BATCH = 4096    # light-camera vertex pairs connected per batch


class MergeKernel(NamedTuple):
    """An iteration's merge kernels: r^2 and the surface's normalisation 1 / (norm pi r^2 N_L),
    and in a medium the volume's, r_V^2 and K / (4/3 pi r_V^3 N_L)."""
    r2: Array
    scale: Array
    r2_volume: Array | None = None
    scale_volume: Array | None = None

    @property
    def query_r2(self):
        return self.r2 if self.r2_volume is None else jnp.maximum(self.r2, self.r2_volume)


def merge_kernel(cfg: VCMConfig, radius, volume_radius, n_light: int, filter_params: dict,
                 media: bool) -> MergeKernel:
    r2 = radius * radius
    norm = density.filter_weight(cfg.filter, jnp.float32(0.0), r2, **filter_params)[1]
    scale = 1.0 / (norm * jnp.pi * r2 * n_light)
    if not media:
        return MergeKernel(r2, scale)
    r2_v = volume_radius * volume_radius
    k_v = density.volume_filter_weight(cfg.filter, jnp.float32(0.0), r2_v)[1]
    return MergeKernel(r2, scale, r2_v, k_v / ((4.0 / 3.0) * jnp.pi * volume_radius ** 3
                                                * n_light))


def _merge_pairs(scene: Scene, cfg: VCMConfig, z: "CameraVertexRows", y: Array, ok: Array,
                 fs: Factors, kernel: MergeKernel, filter_params: dict):
    """Merges of camera vertices z (one per pair, [P]) with the light vertices of grid rows y
    ([P, 16]; :class:`MergeGrid`): (weighted, unweighted) [P] V3, zero where ``ok`` is false or
    y lies beyond r, and the light vertex's row (it is y_{row + 1}).

    In a medium a medium vertex merges with medium vertices only, within r_V, by the 3-D
    kernel and the phase function (volume merging, the point-point 3-D estimator of Krivanek et
    al. 2014), a surface vertex with surface vertices as in vacuum."""
    D = cfg.max_depth
    b = cfg.exponent
    kinds = scene.materials.kinds
    r2 = kernel.r2
    v3 = lambda i: V3(y[:, i], y[:, i + 1], y[:, i + 2])  # noqa: E731
    diff = v3(0) - z.p
    d2 = dot(diff, diff)
    row = y[:, 15].astype(jnp.int32)
    facing = dot(v3(3), z.n) > 0
    if z.in_medium is not None:   # medium vertex with medium vertex (zero normals), within r_V
        y_medium = dot(v3(3), v3(3)) == 0
        facing = jnp.where(z.in_medium, y_medium, facing)
        r2 = jnp.where(z.in_medium, kernel.r2_volume, r2)
    ok = ok & (d2 < r2) & facing & (row + z.j + 2 <= D)
    # ---- the camera BSDF at the light vertex's incident direction; MIS ----
    wi = v3(6)
    mp = bsdf.lookup(scene.materials, z.material, z.uv)
    nz = shading(z)
    f_z, pdf_fwd = bsdf.evaluate(kinds, mp, nz, z.wo, wi)
    _, pdf_rev = bsdf.evaluate(kinds, mp, nz, wi, z.wo)
    if z.ns is not None:   # photon flux through the stored surface -> the shading cosine
        f_z = f_z * bsdf.shading_ratio(nz, v3(3), wi)
    q = continuation(mp, cfg.roulette)
    d2_ok = jnp.where(ok, d2, 0.0)
    c = density.filter_weight(cfg.filter, d2_ok, kernel.r2, **filter_params)[0] * kernel.scale
    if z.in_medium is not None:
        # the phase function for the photon's propagation -wi scattered towards the camera (its
        # value its density both ways), the 3-D kernel, no roulette at a medium vertex
        p_z = phase_value(scene, -wi, z.wo, z.medium)
        f_z = where(z.in_medium, V3(p_z, p_z, p_z), f_z)
        pdf_fwd, pdf_rev = jnp.where(z.in_medium, p_z, pdf_fwd), jnp.where(z.in_medium, p_z,
                                                                            pdf_rev)
        q = jnp.where(z.in_medium, 1.0, q)
        c_v = density.volume_filter_weight(cfg.filter, d2_ok, kernel.r2_volume)[0]
        c = jnp.where(z.in_medium, c_v * kernel.scale_volume, c)
    c = jnp.where(ok, c, 0.0)
    value = where(ok, z.beta * f_z * v3(9) * c, V3.full(0.0, c))
    if cfg.mode == "ppm":
        return value, value, row
    wt = weight_merge(Mis(y[:, 12], y[:, 13], y[:, 14]), z.mis, pdf_fwd * q, pdf_rev * q,
                      fs.at(z.in_medium), b)
    return where(ok, value * wt, V3.full(0.0, c)), value, row


class CameraVertexRows(NamedTuple):
    """What a technique needs of a camera vertex: rows of :class:`CameraVertices`, flattened,
    with the vertex's index j (z_{j+1})."""
    p: V3
    n: V3
    wo: V3
    beta: V3
    mis: Mis
    material: Array
    uv: tuple | None
    ns: V3 | None
    j: Array
    in_medium: Array | None = None
    medium: Array | None = None


def _camera_vertex_rows(z: CameraVertices) -> CameraVertexRows:
    D, N = z.material.shape
    flat = lambda t: jax.tree_util.tree_map(lambda a: a.reshape(-1), t)  # noqa: E731
    return CameraVertexRows(flat(z.p), flat(z.n), flat(z.wo), flat(z.beta), flat(z.mis),
                            z.material.reshape(-1), flat(z.uv) if z.uv is not None else None,
                            flat(z.ns) if z.ns is not None else None,
                            jnp.repeat(jnp.arange(D, dtype=jnp.int32), N),
                            None if z.in_medium is None else z.in_medium.reshape(-1),
                            None if z.medium is None else z.medium.reshape(-1))


def _within_max_depth(q: Array, y: Array, *, j: Array, max_depth: int) -> Array:
    """The merge of grid row y (light vertex y_{row+1}, row in column 3 of
    :attr:`MergeGrid.where`) at camera vertex z_{j+1} of query q makes a path of row + j + 2
    segments: the cheap test's bound, before the BSDF is evaluated."""
    return y[:, 3] + j[q] + 2 <= max_depth


def _add_merges(acc: Array, q: Array, slot: Array, ok: Array, *, scene: Scene, cfg: VCMConfig,
                zs: CameraVertexRows, rows: Array, fs: Factors, kernel: MergeKernel,
                filter_params: dict,
                by_length: bool) -> Array:
    """The pair visitor of :func:`jgi.transport.hash_grid.accumulate_near_pairs`: the merges of
    camera vertices zs[q] with grid rows ``slot`` added to acc [Q, (D - 1,) 6] (weighted and
    unweighted, by the light vertex's row if ``by_length``), in one scatter."""
    wtd, unw, row = _merge_pairs(scene, cfg, jax.tree_util.tree_map(lambda a: a[q], zs),
                                 rows[slot], ok, fs, kernel, filter_params)
    at = (q, row) if by_length else q
    return acc.at[at].add(jnp.stack([*wtd, *unw], -1))


def _merge_batch(zs: CameraVertexRows, live: Array, *, scene: Scene, cfg: VCMConfig,
                 grid: MergeGrid, fs: Factors, kernel: MergeKernel, filter_params: dict,
                 table_size: int,
                 by_length: bool, dense_pairs: int | None):
    """The merges at a batch of camera vertices (where ``live``): (weighted, unweighted)
    [Q, (D - 1,) 3]. The grid query is :func:`jgi.transport.hash_grid.accumulate_near_pairs`;
    its cheap test also drops the pairs whose path would exceed ``max_depth``."""
    D = cfg.max_depth
    visit = partial(_add_merges, scene=scene, cfg=cfg, zs=zs, rows=grid.rows, fs=fs,
                    kernel=kernel, filter_params=filter_params, by_length=by_length)
    zero = jnp.zeros((live.shape[0],) + ((D - 1,) if by_length else ()) + (6,))
    acc = hash_grid.accumulate_near_pairs(
        grid.cells, table_size, grid.where, zs.p, live, kernel.query_r2, visit, zero,
        block=MERGE_PAIRS,
        near_block=MERGE_NEAR, keep=partial(_within_max_depth, j=zs.j, max_depth=D),
        dense=dense_pairs)
    return acc[..., :3], acc[..., 3:]


def _per_camera_vertex(a: Array, D: int, N: int, by_length: bool) -> V3:
    """[D N, (D - 1,) 3] -> V3 of [D, (D - 1,) N]."""
    a = a.reshape((D, N) + a.shape[1:])
    if by_length:
        a = jnp.moveaxis(a, 2, 1)
    return V3(*(a[..., c] for c in range(3)))


def merge_at_camera_vertices(scene: Scene, cfg: VCMConfig, grid: MergeGrid, z: CameraVertices,
                             fs: Factors, radius, filter_params: dict, n_light: int,
                             table_size: int, by_length: bool, dense_pairs: int | None = None,
                             volume_radius=None, summed: bool = False):
    """Vertex merging at every camera vertex (``ppm``: the first non-specular one), the live
    ones gathered into batches (:func:`jgi.core.compaction.compact_map`; ``cfg.compact``).
    A batch reads every (camera vertex, light vertex) pair of the grid cells its vertices' balls
    overlap
    (:func:`jgi.transport.hash_grid.accumulate_near_pairs`), ``MERGE_PAIRS`` at a time, and
    evaluates the pairs within r ``MERGE_NEAR`` at a time: no vertex has a cap, so no light
    vertex is ever dropped, and a dense caustic costs its own pairs only. Returns (weighted,
    unweighted) [D, N] V3 per camera vertex (``by_length``: [D, D - 1, N], by the light
    vertex's row).

    ``dense_pairs`` (the differentiable form, ``cfg.compact`` false): one block of that many
    pairs for all vertices (a loop of traced length has no reverse-mode derivative); if the
    vertices have more pairs the result is NaN, never a silently truncated sum.

    ``summed`` (with ``cfg.compact``, not ``by_length``): (the weighted sum over a pixel's
    vertices [1, N] V3, None)."""
    D, N = z.material.shape
    kernel = merge_kernel(cfg, radius, radius if volume_radius is None else volume_radius,
                          n_light, filter_params, scene.has_medium)
    active = (z.first_diffuse if cfg.mode == "ppm" else z.connectable).reshape(-1)
    batch = partial(_merge_batch, scene=scene, cfg=cfg, grid=grid, fs=fs, kernel=kernel,
                    filter_params=filter_params, table_size=table_size, by_length=by_length,
                    dense_pairs=dense_pairs)
    inputs = _camera_vertex_rows(z)
    if cfg.compact and summed and not by_length:   # no [D N] rows to store and read back
        wtd = compact_map(lambda zs, live: batch(zs, live)[0], active, inputs,
                          jnp.zeros((N, 3)), MERGE_BATCH,
                          dest=jnp.tile(jnp.arange(N, dtype=jnp.int32), D))
        return V3(*(wtd[None, :, c] for c in range(3))), None
    tail = (D - 1, 3) if by_length else (3,)
    like = (jnp.zeros((D * N,) + tail), jnp.zeros((D * N,) + tail))
    if cfg.compact:
        wtd, unw = compact_map(batch, active, inputs, like, MERGE_BATCH)
    else:
        wtd, unw = batch(inputs, active)
    return (_per_camera_vertex(wtd, D, N, by_length), _per_camera_vertex(unw, D, N, by_length))


# --- one iteration --------------------------------------------------------------------------------

class Techniques(NamedTuple):
    """Contributions of one iteration's camera subpaths, per technique (own pixel)."""
    emission: tuple        # (weighted, unweighted) [D, N] V3: s = 0, t = j + 2
    next_event: tuple      # [D, N]: s = 1, t = j + 2
    connect: tuple         # (weighted, unweighted) [J, N], J over connection_pairs(cfg)
    merge: tuple           # weighted, unweighted: [D, N] (or [D, D - 1, N] by light row)


def camera_pass(scene: Scene, cfg: VCMConfig, seed, iteration, fs: Factors, radius,
                filter_params: dict, y_all: LightVertices, cells, pixels: Array,
                table_size: int, by_technique: bool, dense_pairs: int | None = None,
                volume_radius=None) -> Techniques:
    """Camera subpaths of ``pixels`` in one iteration, with every technique at their vertices."""
    D = cfg.max_depth
    n_light = scene.camera.width * scene.camera.height
    key = rng.path_key(seed, pixels, iteration)
    z = camera_walk(scene, cfg, key, pixels, fs)
    em = (z.emission * z.w_emission, z.emission)
    ne = (z.next_event * z.w_next_event, z.next_event)
    conn = (None, None)
    if cfg.connects and D >= 3:
        y_own = jax.tree_util.tree_map(lambda a: a.reshape(D - 1, -1)[:, pixels], y_all)
        conn = connections(scene, cfg, y_own, z, fs, summed=not by_technique)
    mrg = (None, None)
    if cfg.merges and D >= 2:
        mrg = merge_at_camera_vertices(scene, cfg, cells, z, fs, radius, filter_params, n_light,
                                       table_size, by_technique, dense_pairs, volume_radius,
                                       summed=not by_technique)
    return Techniques(em, ne, conn, mrg)


def _flatten_light(y: LightVertices) -> LightVertices:
    return jax.tree_util.tree_map(lambda a: a.reshape(-1), y)


def table_size_for(scene: Scene, cfg: VCMConfig) -> int:
    m = scene.camera.width * scene.camera.height * max(cfg.max_depth - 1, 1)
    return int(1 << max(10, int(np.ceil(np.log2(2 * m)))))


def _cell_size(scene: Scene, radius, volume_radius):
    return jnp.maximum(radius, volume_radius) if scene.has_medium else radius


@partial(jax.jit, static_argnames=("cfg", "table_size"))
def _light_stage(scene: Scene, cfg: VCMConfig, seed, iteration, radius, volume_radius,
                 table_size: int):
    """All light subpaths of an iteration, their grid, and the t = 1 splat image."""
    W, H = scene.camera.width, scene.camera.height
    n_light = W * H
    fs = factors(scene, cfg, radius, volume_radius, n_light)
    y, t1 = light_pass(scene, cfg, seed, iteration, fs, jnp.arange(n_light, dtype=jnp.int32))
    y_all = _flatten_light(y)
    grid = (merge_grid(y_all, _cell_size(scene, radius, volume_radius), table_size, n_light,
                       scene) if cfg.merges else None)
    img = jnp.zeros((n_light, 3), jnp.float32)
    if t1 is not None:
        pix, wtd, _ = t1
        img = _splat(img, pix, wtd)
    return y_all, grid, img


def _splat(img, pix, value: V3):
    pix = pix.reshape(-1)
    vals = jnp.stack([c.reshape(-1) for c in value], -1)
    finite = jnp.all(jnp.isfinite(vals), -1)
    keep = (pix >= 0) & finite
    return img.at[jnp.where(keep, pix, 0)].add(jnp.where(keep[:, None], vals, 0.0))


def _own_sum(t: Techniques) -> V3:
    """The weighted contributions of every technique at the sample's own pixel."""
    out = V3(*(jnp.sum(c, 0) for c in t.emission[0]))
    out = out + V3(*(jnp.sum(c, 0) for c in t.next_event[0]))
    if t.connect[0] is not None:
        out = out + V3(*(jnp.sum(c, 0) for c in t.connect[0]))
    if t.merge[0] is not None:
        out = out + V3(*(jnp.sum(c, 0) for c in t.merge[0]))
    return out


@partial(jax.jit, static_argnames=("cfg", "table_size", "by_technique"))
def _camera_stage(scene: Scene, cfg: VCMConfig, seed, iteration, radius, volume_radius,
                  filter_params, y_all, cells, pixel0, table_size: int, by_technique: bool):
    """Camera subpaths of pixels pixel0 .. pixel0 + chunk - 1 (clamped to the image) with every
    technique; ``by_technique``: the :class:`Techniques`, else their weighted sum ([chunk] V3)."""
    P = scene.camera.width * scene.camera.height
    fs = factors(scene, cfg, radius, volume_radius, P)
    pixels = jnp.minimum(pixel0 + jnp.arange(cfg.chunk, dtype=jnp.int32), P - 1)
    t = camera_pass(scene, cfg, seed, iteration, fs, radius, filter_params, y_all, cells, pixels,
                    table_size, by_technique, volume_radius=volume_radius)
    return t if by_technique else _own_sum(t)


class _Iterations:
    """The host loop shared by :func:`render` and :func:`render_techniques`: per iteration, the
    light stage, then the camera stage per chunk. Calls ``on_chunk(i, p0, result)`` and
    ``on_light(i, light stage outputs)``."""

    def __init__(self, scene: Scene, cfg: VCMConfig, chunk_limit: int):
        P = scene.camera.width * scene.camera.height
        if scene.has_medium and cfg.merges:   # volume merges: the filter needs a 3-D form
            density.volume_filter_weight(cfg.filter, 0.0, 1.0)
        self.scene, self.cfg, self.P = scene, cfg, P
        self.chunk = min(cfg.chunk, chunk_limit, 1 << max(8, int(np.ceil(np.log2(P)))))
        self.key_cfg = replace(cfg.compile_key(), chunk=self.chunk)
        self.table_size = table_size_for(scene, cfg)
        self.filter_params = cfg.filter_params() if cfg.merges else {}

    def run(self, spp: int, seed: int, on_light, on_chunk, by_technique: bool, progress=False):
        scene, cfg, kc, ts = self.scene, self.cfg, self.key_cfg, self.table_size
        for i in range(1, spp + 1):
            r = jnp.float32(radius_at(cfg, i))
            r_v = jnp.float32(volume_radius_at(cfg, i))
            s_, it = jnp.uint32(seed), jnp.uint32(i - 1)
            y_all, cells, img = _light_stage(scene, kc, s_, it, r, r_v, ts)
            on_light(i, img)
            for p0 in range(0, self.P, self.chunk):
                out = _camera_stage(scene, kc, s_, it, r, r_v, self.filter_params, y_all, cells,
                                    jnp.int32(p0), ts, by_technique)
                on_chunk(i, p0, out)
            if progress:
                advance(i, spp, "iterations")


def render(scene: Scene, cfg: VCMConfig = VCMConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """``spp`` iterations of VCM (see the module docstring); the mean of their images.

    Stats: ``radius_final`` (r of the last iteration)."""
    W, H = scene.camera.width, scene.camera.height
    if cfg.technique_images:
        imgs = render_techniques(scene, cfg, spp=spp, seed=seed)
        write_technique_images(cfg.technique_images, imgs)
        return Render(sum((w for _, w in imgs.values()), np.zeros((H, W, 3), np.float32)), {})
    if scene.lights.count == 0:
        return Render(np.zeros((H, W, 3), np.float32), {})
    loop = _Iterations(scene, cfg, cfg.chunk)
    P, chunk = loop.P, loop.chunk
    n_chunks = -(-P // chunk)
    acc = {"splat": jnp.zeros((P, 3), jnp.float32),
           "own": jnp.zeros((n_chunks * chunk, 3), jnp.float32)}

    def on_light(i, img):
        acc["splat"] = acc["splat"] + img

    def on_chunk(i, p0, L):
        acc["own"] = _add_rows(acc["own"], jnp.int32(p0), jnp.stack(list(L), -1))

    loop.run(spp, seed, on_light, on_chunk, False, progress)
    image = (acc["splat"] + acc["own"][:P]) / spp
    return Render(np.asarray(image, np.float32).reshape(H, W, 3),
                  dict(radius_final=radius_at(cfg, spp)))


@jax.jit
def _add_rows(acc, p0, rows):
    return jax.lax.dynamic_update_slice(
        acc, jax.lax.dynamic_slice(acc, (p0, 0), rows.shape) + rows, (p0, 0))


# --- per-technique images -------------------------------------------------------------------------

@partial(jax.jit, static_argnames=("cfg",))
def _add_techniques(imgs, cfg: VCMConfig, p0, t: Techniques):
    """Add one chunk's :class:`Techniques` into the per-technique images ([2 T, P, 3]:
    unweighted 2k, weighted 2k + 1, k in ``cfg.techniques()`` order)."""
    D = cfg.max_depth
    P = imgs.shape[1]
    index = {tech: k for k, tech in enumerate(cfg.techniques())}
    lane = p0 + jnp.arange(cfg.chunk, dtype=jnp.int32)
    pixels = jnp.where(lane < P, lane, -1)

    def add(imgs, tech, wtd: V3, unw: V3):
        k = index.get(tech)
        if k is None:
            return imgs
        imgs = imgs.at[2 * k].set(_splat(imgs[2 * k], pixels, unw))
        return imgs.at[2 * k + 1].set(_splat(imgs[2 * k + 1], pixels, wtd))

    row = lambda v, i: V3(*(c[i] for c in v))  # noqa: E731
    for j in range(D):
        imgs = add(imgs, ("connect", 0, j + 2), row(t.emission[0], j), row(t.emission[1], j))
        imgs = add(imgs, ("connect", 1, j + 2), row(t.next_event[0], j), row(t.next_event[1], j))
    wtd, unw = t.connect
    for i, (k, j) in enumerate(connection_pairs(cfg) if wtd is not None else []):
        imgs = add(imgs, ("connect", k + 1, j + 2), row(wtd, i), row(unw, i))
    if t.merge[0] is not None:
        for j in range(D):
            for r in range(D - 1):
                if r + j + 2 <= D:
                    imgs = add(imgs, ("merge", r + j + 2), row(row(t.merge[0], j), r),
                               row(row(t.merge[1], j), r))
    return imgs


@partial(jax.jit, static_argnames=("cfg",))
def _add_light_splats(imgs, scene: Scene, cfg: VCMConfig, seed, iteration, radius,
                      volume_radius):
    """Add the t = 1 connections of an iteration's light vertex rows to their images."""
    P = scene.camera.width * scene.camera.height
    index = {tech: k for k, tech in enumerate(cfg.techniques())}
    fs = factors(scene, cfg, radius, volume_radius, P)
    _, t1 = light_pass(scene, cfg, seed, iteration, fs, jnp.arange(P, dtype=jnp.int32))
    if t1 is None:
        return imgs
    pix, wtd, unw = t1
    for r in range(cfg.max_depth - 1):
        k = index[("connect", r + 2, 1)]
        imgs = imgs.at[2 * k].set(_splat(imgs[2 * k], pix[r], V3(*(c[r] for c in unw))))
        imgs = imgs.at[2 * k + 1].set(_splat(imgs[2 * k + 1], pix[r], V3(*(c[r] for c in wtd))))
    return imgs


def render_techniques(scene: Scene, cfg: VCMConfig = VCMConfig(), *, spp: int = 4,
                      seed: int = 0) -> dict:
    """``{technique: (unweighted, weighted)}`` images (H, W, 3), techniques as
    ``cfg.techniques()`` names them: ("connect", s, t) (light tracing's t = 1 included) and
    ("merge", path length). The weighted images sum to the VCM image; an unweighted connection
    image is an unbiased estimate of the paths its technique samples, an unweighted merge image
    a consistent one."""
    W, H = scene.camera.width, scene.camera.height
    techs = cfg.techniques()
    loop = _Iterations(scene, cfg, 1 << 11)
    acc = {"imgs": jnp.zeros((2 * len(techs), loop.P, 3), jnp.float32)}

    def on_light(i, img):
        acc["imgs"] = _add_light_splats(acc["imgs"], scene, loop.key_cfg, jnp.uint32(seed),
                                        jnp.uint32(i - 1), jnp.float32(radius_at(cfg, i)),
                                        jnp.float32(volume_radius_at(cfg, i)))

    def on_chunk(i, p0, t):
        acc["imgs"] = _add_techniques(acc["imgs"], loop.key_cfg, jnp.int32(p0), t)

    if scene.lights.count:
        loop.run(spp, seed, on_light, on_chunk, True)
    out = np.asarray(acc["imgs"] / spp, np.float32).reshape(2 * len(techs), H, W, 3)
    return {tech: (out[2 * k], out[2 * k + 1]) for k, tech in enumerate(techs)}


def _technique_name(tech: tuple) -> str:
    return f"s{tech[1]}_t{tech[2]}" if tech[0] == "connect" else f"merge_length{tech[1]}"


def write_technique_images(folder, images: dict, exposure: float = 0.0) -> list[Path]:
    """EXR + PNG per technique (``s{s}_t{t}_weighted`` / ``merge_length{L}_unweighted``, ...)."""
    folder = Path(folder)
    written = []
    for tech, (unw, wtd) in images.items():
        for tag, img in (("unweighted", unw), ("weighted", wtd)):
            path = folder / f"{_technique_name(tech)}_{tag}.exr"
            write_exr(path, img)
            write_png(path.with_suffix(".png"), img, exposure)
            written.append(path)
    return written


# --- a differentiable iteration -------------------------------------------------------------------

def iteration_image(scene: Scene, cfg: VCMConfig, seed, iteration, radius, filter_params: dict,
                    pairs_per_vertex: int = 64, volume_radius=None) -> Array:
    """One iteration's image [H, W, 3] as a traced function of the merge ``radius`` and the
    merge filter's parameters (``cfg.filter_params()``; jit it, or differentiate it:
    ``jax.grad`` of a loss of it with respect to r fits r_0, as :mod:`jgi.analysis.density_fit`
    fits photon radii). The merges read
    ``pairs_per_vertex`` times (max_depth x pixels) grid candidates in all (static; the image
    is NaN if the iteration's camera vertices have more: choose it large enough)."""
    W, H = scene.camera.width, scene.camera.height
    P = W * H
    ts = table_size_for(scene, cfg)
    cfg = replace(cfg, chunk=P, compact=False)
    r_v = radius if volume_radius is None else volume_radius
    fs = factors(scene, cfg, radius, r_v, P)
    y, t1 = light_pass(scene, cfg, seed, iteration, fs, jnp.arange(P, dtype=jnp.int32))
    y_all = _flatten_light(y)
    cells = (merge_grid(y_all, jax.lax.stop_gradient(_cell_size(scene, radius, r_v)), ts, P,
                        scene) if cfg.merges else None)
    img = jnp.zeros((P, 3), jnp.float32)
    if t1 is not None:
        img = _splat(img, t1[0], t1[1])
    pixels = jnp.arange(P, dtype=jnp.int32)
    t = camera_pass(scene, cfg, seed, iteration, fs, radius, filter_params, y_all, cells, pixels,
                    ts, False, pairs_per_vertex * cfg.max_depth * P, r_v)
    return _splat(img, pixels, _own_sum(t)).reshape(H, W, 3)


register(Estimator("vcm", "vertex connection and merging (modes vcm, bpm, bpt, ppm), progressive",
                   render, VCMConfig, renamed={"kernel": "filter"}, media=True,
                   grid_media=True))
