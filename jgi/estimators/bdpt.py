"""Bidirectional path tracing (Veach & Guibas 1994; Veach 1997 ch. 10; pbrt-v4's BDPTIntegrator).

Estimator: for each pixel sample a camera subpath z_0 z_1 ... z_{t-1} (z_0 the pinhole) and a
light subpath y_0 y_1 ... y_{s-1} (y_0 on a light) are traced, each as fixed-size vertex arrays
(:class:`~jgi.transport.subpath.Vertices`, struct of arrays, [max_depth + 1, N]) carrying
their throughput beta and the forward and reverse area densities of every vertex. Every
strategy (s, t) with s + t - 1 <= max_depth path segments then forms a full path and estimates

    C*_{s,t} = beta^L_s  c_{s,t}  beta^E_t,      C_{s,t} = w_{s,t} C*_{s,t}

(Veach eq. 10.8), with the connection term c_{s,t} of each kind:

* s = 0: the camera subpath hit an emitter, c = L_e(z_{t-1} -> z_{t-2});
* s = 1: light sampling at z_{t-1} (:func:`~jgi.transport.subpath.sample_next_event`, the
  path tracer's NEE);
* t = 1: light tracing, y_{s-1} connected to the pinhole and *splatted* into the pixel it
  projects to (W_e of jgi.physics.camera; :func:`~jgi.transport.connection.connect_camera`);
* s, t >= 2: c = f(y_{s-2} -> y_{s-1} -> z_{t-1}) G(y_{s-1} <-> z_{t-1}) f(y_{s-1} -> z_{t-1}
  -> z_{t-2}), G = |cos| |cos| V / d^2 (:func:`~jgi.transport.connection.connect_vertices`).

(s, t) = (1, 1) is not used (a light seen directly is the s = 0 strategy), as in pbrt.

MIS: w_{s,t} = p_s^b / sum_i p_i^b (balance b = 1, power b = ``power``), computed as in
pbrt-v4's MISWeight by ratios r_i = p_i / p_s built stepwise from the vertices' reverse and
forward densities, r_{i-1} = r_i (p_rev / p_fwd)^b, so that no full path density (which
under/overflows float32) is ever formed; here in log space with the ratio clamped, so that
weights and their gradients stay finite. The last two vertices of each subpath get this
strategy's reverse densities first (pbrt's ScopedAssignment; :func:`with_connection`).
:func:`ratio_chain` lists one strategy's steps (its docstring walks Veach's ratios) and
:func:`mis_weights` evaluates the chains of all strategies of a sample at once.

Dirac vertices (mirror, dielectric) are not connectable; their densities are 0 and count as 1
in the ratios (remap0), and strategies that would connect at them are left out of the sum.
A smooth plastic vertex is connectable (its base), but a path that leaves it by the coating's
Dirac reflection is Dirac there: as in pbrt-v4, MIS reads the sampled lobe's flag
(:func:`~jgi.transport.subpath.mis_delta`) and connectability the material's.
Delta lights (point, spot: Dirac position; directional: Dirac direction) cannot be hit (no
s = 0 strategy).

Infinite lights (environment, directional) start light subpaths too (pbrt-v4's
GenerateLightSubpath): y_0 stands for a direction at infinity and the subpath leaves a point
of the disc covering the scene's bounding sphere. Its densities are solid-angle ones: p_fwd(y_0)
the direction's light-sampling density with selection (pbrt's InfiniteLightDensity), p_rev(y_0)
the BSDF's density at y_1 towards it, unconverted; p_fwd(y_1) is the disc's area density
1 / (pi R^2) times |cos| at y_1. A camera subpath that escapes to the environment ends at such
a vertex (s = 0): its p_fwd is the direction's BSDF density, its reverse density the map's
light-sampling density, and z_{t-2}'s the disc's times |cos| (PdfLightOrigin, PdfLight); next
event estimation (s = 1) gives y_0 the same solid-angle densities. So every (s, t) of a path
from the environment is weighted by the full heuristic. Deliberate simplification: no Russian
roulette; subpaths end at ``max_depth`` or at absorption.

Participating media (a scene filled by a homogeneous medium): both subpaths sample free
flights and carry medium vertices (:mod:`jgi.transport.subpath`: phase function as BSDF, never
Dirac, always connectable); every area density along a segment includes its distance density
(p(d) at a medium vertex, P(d) at a surface, the same from either end), so the ratio chains
above hold unchanged; connections and light sampling take the transmittance T(d). Light from
infinite lights is extinguished in such a scene (no light subpaths start there); a grid
medium is bounded, so there they start from the bounding disc as in vacuum, a medium vertex
reached from the disc has no cosine, and the segment from infinity no distance density in any
strategy. In a grid medium the flights are spectral tracking's, each T(d) is ratio tracking's
estimate along the connection's shadow ray
(:func:`jgi.transport.connection.shadow_transmittance`), and the distance densities are a proxy
common to every strategy (:func:`jgi.transport.subpath.segment_density`): the weights still
sum to one per path.

Parameters: ``max_depth`` (segments, the path tracer's convention), ``heuristic``
("balance" | "power"), ``power`` (power exponent), ``path_length`` (> 0: only paths of exactly
that many segments), ``strategy_images`` (a folder: also write every strategy's weighted and
unweighted image there, Veach's pyramid, fig. 10.3). :func:`render_strategies` returns them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._xla import materialize
from ..core import rng
from ..core.configured import Configured
from ..core.imageio import write_exr, write_png
from ..core.vec import V3, dot, max_component, where
from ..drivers.splat import render_splats
from ..physics import bsdf, camera, geometry, medium_interfaces
from ..physics.lights import emitted, environment_pdf, environment_radiance, select_light
from ..scene.tables import Scene
from ..transport.connection import (
    connect_camera,
    connect_vertices,
    occluded_many,
    transmittance,
)
from ..transport.subpath import (
    CAMERA_DIMS0,
    Vertices,
    Visit,
    WalkState,
    area_density,
    at_medium_vertex,
    camera_dims_per_step,
    camera_ray,
    concat_rows,
    convert_density,
    has_infinite_lights,
    is_infinite,
    light_key,
    light_normal,
    light_subpath,
    mis_delta,
    next_event_value,
    no_uv,
    pdf_bounding_disc,
    pdf_emission_dir,
    pdf_light_origin,
    phase_value,
    random_walk,
    rows,
    sample_next_event,
    segment_density,
    vertex_in_medium,
    vertex_lobe_delta,
    vertex_ns,
)
from .registry import Estimator, Render, param, register

LOG_RATIO_MAX = 80.0          # r_i <= e^80: sums of a few stay below float32's maximum

STORE_GROUP = 8   # MIS weight rows per stored kernel (materialize(group=))


@dataclass(frozen=True)
class BDPTConfig:
    """BDPT's parameters; static but for ``strategy_images`` (hashable: one compile serves every
    render with them)."""

    max_depth: int = param(5, "maximum path segments s + t - 1 (1 = emitters only)", minimum=1,
                           maximum=16)
    heuristic: str = param("power", "MIS heuristic over the (s, t) strategies",
                           choices=("balance", "power"))
    power: float = param(2.0, "power-heuristic exponent", minimum=0.1, maximum=16)
    path_length: int = param(0, "keep only paths with exactly this many segments (0 = all)",
                             minimum=0, maximum=16)
    # not seen by the kernels (render drops it from the compile key)
    strategy_images: str = param("", "folder: also write each (s, t) strategy's weighted and "
                                 "unweighted image (EXR, PNG) and pyramid.png there")

    @property
    def exponent(self) -> float:
        return 1.0 if self.heuristic == "balance" else float(self.power)

    def strategies(self) -> list[tuple[int, int]]:
        """Every (s, t) this configuration evaluates, in pyramid order (by length, then s)."""
        out = []
        for length in range(1, self.max_depth + 1):
            if self.path_length and length != self.path_length:
                continue
            for s in range(0, length + 1):
                t = length + 1 - s
                if (s, t) != (1, 1):
                    out.append((s, t))
        return out


# --- MIS: Veach's ratios of strategy densities ----------------------------------------------------

def log_remap0(pdf: Array) -> Array:
    """log of pbrt's remap0 (a zero density, from a Dirac lobe, counts as 1), floored."""
    safe = jnp.maximum(jnp.where(pdf > 0, pdf, 1.0), 1e-30)
    return jnp.log(safe)


class MisRows:
    """Named [N] rows (a Python list, indexed by static ints): every density, or every Dirac
    flag, that some strategy's ratio chain reads. Kept as separate arrays, not one stacked
    table, which XLA re-derived inside every consumer (perf: docs/performance.md#bdpt-mis-rows)."""

    def __init__(self):
        self.rows: list = []

    def add(self, x: Array) -> int:
        """Append [N] or [K, N] rows; return the index of the first."""
        first = len(self.rows)
        self.rows.extend([x] if x.ndim == 1 else [x[i] for i in range(x.shape[0])])
        return first


class ChainVertex(NamedTuple):
    """A subpath vertex as one strategy sees it: the rows of its forward and reverse area
    densities (of the density :class:`MisRows`) and of its Dirac flag (of the flag rows)."""
    fwd: int
    rev: int
    delta: int


class SubpathRows(NamedTuple):
    """Where a subpath's vertices sit among the rows: vertex i's p_fwd in row fwd + i, its p_rev
    in row rev + i, its Dirac flag in row delta + i."""
    fwd: int
    rev: int
    delta: int

    def vertices(self, n: int) -> list[ChainVertex]:
        """Vertices 0 .. n - 1, as their own subpath sampled them."""
        return [ChainVertex(self.fwd + i, self.rev + i, self.delta + i) for i in range(n)]


def with_connection(vertices: list[ChainVertex], rev_last: int, rev_before: int,
                    no_delta: int) -> list[ChainVertex]:
    """A subpath's vertices as a strategy that connects at its last vertex sees them (pbrt's
    ScopedAssignment): the last vertex's reverse density is the one of sampling it from the
    other subpath's end (row ``rev_last``), the vertex before gets its reverse density given the
    connection (row ``rev_before``), and the connected vertex counts as non-Dirac (``no_delta``:
    a row of False)."""
    out = list(vertices)
    out[-1] = out[-1]._replace(rev=rev_last, delta=no_delta)
    if len(out) >= 2:
        out[-2] = out[-2]._replace(rev=rev_before)
    return out


class RatioStep(NamedTuple):
    """One step of a ratio chain: the rows of the density ratio p_rev / p_fwd it multiplies in,
    and of the Dirac flags of the two vertices the strategy it reaches would connect."""
    rev: int
    fwd: int
    delta: int
    delta_prev: int


def ratio_chain(camera: list[ChainVertex], light: list[ChainVertex],
                delta_light: int) -> tuple[list[RatioStep], list[RatioStep]]:
    """The ratio steps of strategy (s, t) = (len(light), len(camera)), as
    :func:`mis_weights` walks them (Veach 1997, sec. 10.2; pbrt-v4's MISWeight).

    ``camera[i]`` is z_i and ``light[i]`` y_i as this strategy sees them (:func:`with_connection`:
    its reverse densities at the last two vertices of each subpath, its connected vertices
    non-Dirac); ``delta_light`` is the row flagging delta lights (a point light cannot be hit).

    Strategy (s, t) samples y_0 .. y_{s-1} from the light and z_0 .. z_{t-1} from the camera,
    each vertex with its own subpath's density p_fwd. Every other strategy that can make the
    same path differs only in where the connection lies, and its density differs only there:

    * moving the connection one vertex towards the camera, to (s + 1, t - 1), turns z_{t-1}
      into a light vertex, sampled from y_{s-1}'s side with its reverse density: the ratio of
      the two strategies' densities is r = p_rev(z_{t-1}) / p_fwd(z_{t-1}). Moving it on, each
      further z_i (i = t - 2 .. 1; the pinhole z_0 is never hit) multiplies in
      p_rev(z_i) / p_fwd(z_i);
    * moving it towards the light, to (s - 1, t + 1), turns y_{s-1} into a camera vertex:
      r = p_rev(y_{s-1}) / p_fwd(y_{s-1}), then y_{s-2} .. y_0 likewise (y_0 last: the s = 0
      strategy, the camera subpath hitting the light).

    The strategy reached by turning vertex i over connects it to its neighbour i - 1 on the same
    side, so it counts only if neither of the two is Dirac (for y_0, the neighbour is the light:
    a delta light). Each step reads (rows of p_rev, p_fwd, flags of vertex i and i - 1); with the
    heuristic's exponent b, w_{s,t} = 1 / (1 + sum of the counted r^b). (s, t) = (0, 2), the
    camera subpath that hits a light at once, has no other strategy ((1, 1) is not used): no
    steps, w = 1."""
    s, t = len(light), len(camera)
    if s + t == 2:
        return [], []
    towards_camera = [RatioStep(camera[i].rev, camera[i].fwd, camera[i].delta,
                                camera[i - 1].delta) for i in range(t - 1, 0, -1)]
    towards_light = [RatioStep(light[i].rev, light[i].fwd, light[i].delta,
                               light[i - 1].delta if i > 0 else delta_light)
                     for i in range(s - 1, -1, -1)]
    return towards_camera, towards_light


def mis_weights(log_pdf: list[Array], delta: list[Array],
                chains: list[tuple[list[RatioStep], list[RatioStep]]], exponent: float) -> Array:
    """w_{s,t} of many strategies at once, [J, N], one per :func:`ratio_chain` in ``chains``.

    ``log_pdf`` (rows of [N]) holds log remap0 of every density the chains read
    (:func:`log_remap0`), ``delta`` every Dirac flag. Along each half of a chain, in walking
    order (outwards from the connection), r_i = exp(b * running sum of (log p_rev - log p_fwd)),
    clamped at e^LOG_RATIO_MAX so that weights and their gradients stay finite; the sum of the
    counted r_i never forms a full path density (which under/overflows float32). Rows are read
    by static index, not by one gather of all steps (perf: docs/performance.md#bdpt-mis-rows)."""
    weights = []
    for chain in chains:
        sum_r = jnp.zeros_like(log_pdf[0])
        for steps in chain:
            log_r = jnp.zeros_like(sum_r)
            for rev, fwd, da, db in steps:
                log_r, sum_r = ratio_step(log_r, sum_r, log_pdf[rev], log_pdf[fwd],
                                          ~delta[da] & ~delta[db], exponent)
        weights.append(weight_of_ratios(sum_r))
    return jnp.stack(weights)


def ratio_step(log_r: Array, sum_r: Array, log_rev: Array, log_fwd: Array, counted: Array,
               exponent: float, active: Array | None = None) -> tuple[Array, Array]:
    """One step of a ratio chain (the formula of every MIS weight here, for all strategies at
    once in :func:`mis_weights` and for one strategy per lane in :func:`strategy_weight`):
    log r_i = log r_{i+1} + b (log p_rev - log p_fwd), and r_i, clamped at e^LOG_RATIO_MAX,
    joins the sum where ``counted`` (neither vertex of the strategy it reaches is Dirac).
    ``active`` (per lane, or None: all) leaves (log_r, sum_r) unchanged where False: the step
    lies beyond the lane's strategy (adding 0 to log_r = 0 keeps the sums exact)."""
    d = exponent * (log_rev - log_fwd)
    if active is not None:
        d = jnp.where(active, d, 0.0)
        counted = counted & active
    log_r = log_r + d
    r_i = jnp.exp(jnp.minimum(log_r, LOG_RATIO_MAX))
    return log_r, sum_r + jnp.where(counted, r_i, 0.0)


def weight_of_ratios(sum_r: Array) -> Array:
    """w_{s,t} = 1 / (1 + sum of the counted r_i^b)."""
    return 1.0 / (1.0 + sum_r)


class LaneSubpath(NamedTuple):
    """One subpath's MIS rows as a per-lane strategy sees them (:func:`strategy_weight`): lists
    (one [N] array per vertex) of log remap0 p_fwd, log remap0 p_rev and the Dirac flag, the
    strategy's reverse densities and connected vertex already written in (as
    :func:`with_connection` does by row index for :func:`mis_weights`)."""
    log_fwd: list
    log_rev: list
    delta: list


def strategy_weight(camera: LaneSubpath, light: LaneSubpath, delta_light: Array, s: Array,
                    t: Array, exponent: float) -> Array:
    """w_{s,t} of one strategy per lane, (s, t) traced [N] (MMLT's chosen strategy): the steps
    of :func:`ratio_chain` for (s, t) with :func:`ratio_step`, walked over every vertex row
    (camera rows i = K - 1 .. 1, light rows i = K' - 1 .. 0), each active where it lies inside
    the lane's chain (i < t, i < s). (s, t) = (0, 2) has no steps (w = 1), as in ratio_chain."""
    sum_r = jnp.zeros_like(camera.log_fwd[0])
    more = (s + t) > 2
    log_r = jnp.zeros_like(sum_r)
    for i in range(len(camera.log_fwd) - 1, 0, -1):       # towards the camera
        log_r, sum_r = ratio_step(log_r, sum_r, camera.log_rev[i], camera.log_fwd[i],
                                  ~camera.delta[i] & ~camera.delta[i - 1], exponent,
                                  more & (i < t))
    log_r = jnp.zeros_like(sum_r)
    for i in range(len(light.log_fwd) - 1, -1, -1):        # towards the light
        before = light.delta[i - 1] if i > 0 else delta_light
        log_r, sum_r = ratio_step(log_r, sum_r, light.log_rev[i], light.log_fwd[i],
                                  ~light.delta[i] & ~before, exponent, more & (i < s))
    return weight_of_ratios(sum_r)


# --- the camera subpath, with s = 0 and s = 1 evaluated at each vertex ----------------------------

def emitter_strategy(lights, e: Array, n: V3, wo: V3, beta: V3, d2_prev: Array, cos_prev: Array,
                     prev_surface: Array) -> dict:
    """Strategy s = 0 at camera vertex z = z_{t-1} on light element ``e`` (-1: none), normal n,
    ``wo`` towards z_{t-2}: its value L_e(z -> z_{t-2}) beta and its reverse densities as y_0
    of a light subpath (z) and as y_1 (z_{t-2}: d2_prev, cos_prev = n_{t-2} . (z - z_{t-2})
    direction, prev_surface describe it)."""
    return dict(s0_value=beta * emitted(lights, e, n, wo),
                s0_rev_pt=pdf_light_origin(lights, e),               # as y_0 of a light path
                s0_rev_ptm=convert_density(pdf_emission_dir(lights, e, n, wo), d2_prev, cos_prev,
                                           prev_surface))


def environment_strategy(lights, escaped: Array, beta: V3, d: V3, pdf_dir: Array, prev_n: V3,
                         prev_surface: Array) -> dict:
    """Strategy s = 0 on the environment: the ray from z_{t-2} in direction d (sampled with
    solid-angle density ``pdf_dir``) escaped to z_{t-1} at infinity; as y_0 of a light subpath
    it has the environment's direction density, and z_{t-2} the bounding disc's area density
    times |cos| (pbrt-v4's PdfLightOrigin and PdfLight for infinite lights)."""
    z = jnp.zeros_like(pdf_dir)
    Z = V3(z, z, z)
    return dict(env_value=where(escaped, beta * environment_radiance(lights, d), Z),
                env_fwd=pdf_dir,
                env_rev_pt=environment_pdf(lights, d),
                env_rev_ptm=pdf_bounding_disc(lights) * jnp.where(
                    prev_surface, jnp.abs(dot(prev_n, d)), 1.0))


def next_event_strategy(scene: Scene, mp, p: V3, n: V3, ns: V3 | None, wo: V3, beta: V3,
                        u_select: Array, u1: Array, u2: Array, valid: Array, d2_prev: Array,
                        cos_prev: Array, prev_surface: Array, in_medium: Array | None = None,
                        medium: Array | None = None, material: Array | None = None):
    """Strategy s = 1 at camera vertex z = z_{t-1} (material ``mp``, point p, normals n and
    ``ns``, ``wo`` towards z_{t-2}, throughput beta): light sampling
    (:func:`~jgi.transport.subpath.sample_next_event`). Returns (value before the visibility
    test, the shadow ray, the densities: y_0's p_fwd and p_rev, z's and z_{t-2}'s reverse
    densities, y_0's Dirac flag), for the caller to test the shadow ray with others or alone.

    ``in_medium`` (medium scenes): z is a medium vertex there (its normal zero): the phase
    function p(-wo -> wi) in place of f, no cosine, its density both ways; the value takes the
    shadow segment's transmittance T(d), and every area density across a segment its distance
    density (:func:`~jgi.transport.subpath.area_density`: p(d) at a medium vertex, P(d) at a
    surface).

    ``medium`` and ``material`` (scenes with media bounded by shapes): the id of the medium z
    was reached in and z's material row, whose interface gives the shadow segment's medium
    (:func:`jgi.physics.medium_interfaces.leaving`)."""
    lights = scene.lights
    kinds = scene.materials.kinds
    out = {}
    ne = sample_next_event(scene, mp, p, n, wo, u_select, u1, u2, valid, ns=ns)
    ls = ne.light
    shadow_medium = medium_interfaces.leaving(scene, medium, material, n, ls.wi, in_medium)
    _, pdf_p_rev = bsdf.evaluate(kinds, mp, n if ns is None else ns, ls.wi, wo)
    if in_medium is not None:
        f_m = phase_value(scene, -wo, ls.wi, medium)
        ne = at_medium_vertex(ne, in_medium, f_m, valid)
        pdf_p_rev = jnp.where(in_medium, f_m, pdf_p_rev)
    pdf_p_fwd = ne.pdf_bsdf
    # the light's density at z_{t-1} converts with the geometric cosine (none at a medium vertex)
    cos_p = ne.cos if ns is None else jnp.abs(dot(ls.wi, n))
    if in_medium is not None and ns is not None:
        cos_p = jnp.where(in_medium, 1.0, cos_p)
    k = select_light(lights, u_select)
    value = next_event_value(ne, beta)
    if in_medium is not None:
        value = value * transmittance(scene, ls.dist, ne.shadow, max_component(value) > 0,
                                      shadow_medium)
    dist = ls.dist
    if has_infinite_lights(lights):
        infinite = is_infinite(lights, k)
        dist = jnp.where(infinite, 0.0, ls.dist)
    d2 = dist * dist
    y = p + ls.wi * dist
    n_y, y_surface = light_normal(lights, k, y)
    out["s1_fwd_y"] = pdf_light_origin(lights, k)                        # p_fwd(y_0)
    if in_medium is None:
        out["s1_rev_y"] = convert_density(pdf_p_fwd, d2, dot(n_y, ls.wi), y_surface)
        out["s1_rev_pt"] = convert_density(pdf_emission_dir(lights, k, n_y, -ls.wi), d2, cos_p,
                                           True)
    else:
        out["s1_rev_y"] = area_density(scene, pdf_p_fwd, d2, dot(n_y, ls.wi), y_surface,
                                       ~y_surface, shadow_medium)
        out["s1_rev_pt"] = area_density(scene, pdf_emission_dir(lights, k, n_y, -ls.wi), d2,
                                        cos_p, ~in_medium, in_medium, shadow_medium)
    if has_infinite_lights(lights):
        # y_0 at infinity: its densities are solid-angle ones (light sampling's, with
        # selection, and BSDF sampling's at z_{t-1}); z_{t-1} from the bounding disc
        out["s1_fwd_y"] = jnp.where(infinite, ls.pdf, out["s1_fwd_y"])
        out["s1_rev_y"] = jnp.where(infinite, pdf_p_fwd, out["s1_rev_y"])
        out["s1_rev_pt"] = jnp.where(infinite, pdf_bounding_disc(lights) * cos_p,
                                     out["s1_rev_pt"])
    if in_medium is None:
        out["s1_rev_ptm"] = convert_density(pdf_p_rev, d2_prev, cos_prev, prev_surface)
    else:
        out["s1_rev_ptm"] = area_density(scene, pdf_p_rev, d2_prev, cos_prev, prev_surface,
                                         ~prev_surface, medium)
    out["s1_delta_light"] = ls.delta
    return value, ne.shadow, out


def _camera_visit(scene: Scene, exponent: float):
    lights = scene.lights

    def visit(v: Visit):
        hit, mp, wo, s, u = v.hit, v.mp, v.wo, v.state, v.u
        z = jnp.zeros_like(hit.t)
        Z = V3(z, z, z)
        cos_prev = dot(s.prev_n, s.d)
        # ---- s = 0: the camera subpath found an emitter: L_e(z_{t-1} -> z_{t-2}) ----
        e = jnp.where(v.valid, hit.emitter, -1)
        out = emitter_strategy(lights, e, hit.n, wo, s.beta, v.d2_prev, cos_prev,
                               s.prev_surface)
        if v.in_medium is not None:   # z_{t-2} reached from the light across a medium segment
            out["s0_rev_ptm"] = out["s0_rev_ptm"] * segment_density(scene, v.d2_prev,
                                                                    ~s.prev_surface, s.medium)
        # ---- s = 0 on the environment, at infinity ----
        if lights.environment >= 0:
            out.update(environment_strategy(lights, s.alive & ~hit.valid, s.beta, s.d,
                                            s.pdf_dir, s.prev_n, s.prev_surface))
        # ---- s = 1: light sampling at z_{t-1} ----
        value, shadow, s1 = next_event_strategy(scene, mp, hit.p, hit.n, hit.ns, wo, s.beta,
                                                u(3), u(4), u(5), v.valid, v.d2_prev, cos_prev,
                                                s.prev_surface, v.in_medium, s.medium,
                                                hit.material)
        visible = ~geometry.occluded(scene, *shadow)
        out["s1_value"] = where(visible, value, Z)
        out.update(s1)
        return out

    return visit


def camera_subpath(scene: Scene, cfg: BDPTConfig, key: Array, pixel: Array, uniform=None,
                   visit=None, n_live=None):
    """z_0 (the pinhole) .. z_max_depth, and the per-vertex s = 0 / s = 1 records.
    ``uniform(dim)``, if given, replaces the hashed stream ``key`` (dims 0, 1: pixel jitter).
    ``visit``, if given, replaces BDPT's per-vertex records (:func:`_camera_visit`) by its own
    (MMLT's, which evaluates one strategy per lane after the walk); ``n_live``: see
    :func:`~jgi.transport.subpath.random_walk`."""
    cam = scene.camera
    u = (lambda k: rng.uniform(key, k)) if uniform is None else uniform  # noqa: E731
    o, d = camera_ray(cam, pixel, u)
    z = jnp.zeros_like(o.x)
    Z = V3(z, z, z)
    one = V3(z + 1, z + 1, z + 1)
    pdf_dir = camera.project(cam, o + d).pdf_dir            # 1 / (A cos^3): the film's density
    z0 = Vertices(o, Z, Z, one, z + 1, z, z > 0, z > 0, z == 0, z.astype(jnp.int32),
                  z.astype(jnp.int32) - 1, no_uv(scene, z), vertex_ns(scene, Z),
                  vertex_lobe_delta(scene, z), vertex_in_medium(scene, z),
                  medium_interfaces.start(scene, z))
    start = WalkState(o, d, one, pdf_dir, o, Z, z > 0, z > 0, z == 0,
                      medium_interfaces.start(scene, z))
    verts, pdf_rev0, rec = random_walk(scene, key, CAMERA_DIMS0, camera_dims_per_step(scene),
                                       cfg.max_depth, start, bsdf.RADIANCE,
                                       _camera_visit(scene, cfg.exponent) if visit is None
                                       else visit, uniform=uniform, n_live=n_live)
    z0 = jax.tree_util.tree_map(lambda x: x[None], z0._replace(pdf_rev=pdf_rev0))
    return concat_rows(z0, verts), rec


# --- all strategies of one sample -----------------------------------------------------------------

def interior_connection(scene: Scene, y: Vertices, ym: Vertices, z: Vertices, zm: Vertices):
    """Connection y = y_{s-1} <-> z = z_{t-1} (s, t >= 2) for stacked rows of pairs (ym, zm: the
    vertices before them): the value, the shadow ray, and this strategy's reverse area densities
    at the last two vertices of each subpath (pt, ptm: z_{t-1}, z_{t-2}; qs, qsm: y_{s-1},
    y_{s-2})."""
    ok = y.valid & z.valid & ~y.delta & ~z.delta
    conn = connect_vertices(scene, y, z, ok)
    vm_z = zm.p - z.p
    vm_y = ym.p - y.p
    rev = dict(
        pt=conn.pdf_z_from_y,
        ptm=area_density(scene, conn.pdf_z_rev, dot(vm_z, vm_z), dot(zm.n, z.wo), zm.on_surface,
                         zm.in_medium, z.medium),
        qs=conn.pdf_y_from_z,
        qsm=area_density(scene, conn.pdf_y_rev, dot(vm_y, vm_y), dot(ym.n, y.wo), ym.on_surface,
                         ym.in_medium, y.medium),
    )
    if has_infinite_lights(scene.lights):   # y_{s-2} may be y_0 at infinity
        rev["qsm_solid"] = conn.pdf_y_rev
    return conn.value, conn.shadow, rev


def reverse_at_predecessor(lights, lp, light_rows, pdf_solid: Array, pdf_area: Array) -> Array:
    """y_{s-2}'s reverse density under a connection at y_{s-1} (light rows ``light_rows`` =
    s - 1: a static list, one per stacked strategy, or a traced [N] array, one strategy per
    lane): the area density ``pdf_area``, but where y_{s-2} = y_0 is a directional or
    environment light the solid-angle density ``pdf_solid`` (pbrt-v4's ConvertDensity leaves
    a density towards an infinite light unconverted)."""
    if not has_infinite_lights(lights):
        return pdf_area
    if isinstance(light_rows, np.ndarray):
        second = jnp.asarray(light_rows == 1)[:, None]
    else:
        second = light_rows == 1
    at_y0 = second & is_infinite(lights, lp.element)
    return jnp.where(at_y0, pdf_solid, pdf_area)


def contributions(scene: Scene, cfg: BDPTConfig, seed, pixel: Array, sample: Array,
                  uniforms=None) -> dict:
    """For every strategy (s, t): (splat pixel or None for the sample's own pixel, MIS-weighted
    value, unweighted value), each [N]. ``uniforms = (camera, light)``, two ``uniform(dim)``
    callables, replaces the hashed streams of (seed, pixel, sample) (Metropolis: MMLT)."""
    D = cfg.max_depth
    lights = scene.lights
    u_cam, u_light = uniforms if uniforms is not None else (None, None)
    key = rng.path_key(seed, pixel, sample) if u_cam is None else None
    cam, rec = camera_subpath(scene, cfg, key, pixel, u_cam)      # z_0 .. z_D
    lkey = light_key(seed, pixel, sample) if u_light is None else None
    lp = light_subpath(scene, lkey, D, infinite=True, uniform=u_light)  # y_0 .. y_{D-1}
    light = lp.vertices
    strategies = cfg.strategies()
    z = jnp.zeros_like(cam.pdf_fwd[0])

    # ---- t = 1 (light tracing) and s, t >= 2 (interior connections): one shadow-ray batch ----
    t1 = [(s, t) for (s, t) in strategies if t == 1]
    inner = [(s, t) for (s, t) in strategies if s >= 2 and t >= 2]
    rays = []
    if t1:
        y_rows = np.array([s - 1 for s, _ in t1])
        y, ym = rows(light, y_rows), rows(light, y_rows - 1)
        conn = materialize(connect_camera(scene, y))
        vm = ym.p - y.p
        rev_qsm = reverse_at_predecessor(lights, lp, y_rows, conn.pdf_y_rev, area_density(
            scene, conn.pdf_y_rev, dot(vm, vm), dot(ym.n, y.wo), ym.on_surface, ym.in_medium,
            y.medium))
        rays.append(conn.shadow)
    if inner:
        ls = np.array([s - 1 for s, _ in inner])
        ts = np.array([t - 1 for _, t in inner])
        value_in, shadow_in, rev_in = materialize(interior_connection(
            scene, rows(light, ls), rows(light, ls - 1), rows(cam, ts), rows(cam, ts - 1)))
        rev_in["qsm"] = reverse_at_predecessor(lights, lp, ls, rev_in.get("qsm_solid"),
                                                rev_in["qsm"])
        rays.append(shadow_in)
    occ = occluded_many(scene, rays) if rays else []
    occ_t1 = occ.pop(0) if t1 else None
    occ_in = occ.pop(0) if inner else None

    # ---- the densities every strategy's ratio chain reads, as numbered rows ----
    P, F = MisRows(), MisRows()                 # densities, Dirac flags
    cam_fwd, cam_rev = P.add(cam.pdf_fwd), P.add(cam.pdf_rev)
    light_fwd, light_rev = P.add(light.pdf_fwd), P.add(light.pdf_rev)
    s0_pt, s0_ptm = P.add(rec["s0_rev_pt"]), P.add(rec["s0_rev_ptm"])
    s1_pt, s1_ptm = P.add(rec["s1_rev_pt"]), P.add(rec["s1_rev_ptm"])
    s1_fwd_y, s1_rev_y = P.add(rec["s1_fwd_y"]), P.add(rec["s1_rev_y"])
    if t1:
        t1_qs, t1_qsm = P.add(conn.pdf_cam), P.add(rev_qsm)
    if inner:
        in_rows = {k: P.add(rev_in[k]) for k in ("pt", "ptm", "qs", "qsm")}
    env_strategies = [(s, t) for (s, t) in strategies if s == 0] if "env_value" in rec else []
    if env_strategies:
        env_fwd, env_pt = P.add(rec["env_fwd"]), P.add(rec["env_rev_pt"])
        env_ptm = P.add(rec["env_rev_ptm"])
    P.add(z)                                    # last row: density 0 (log remap0 = 0)
    # Dirac flags of the sampled bounces (a plastic vertex left by its coating's reflection is
    # one, though connectable); the connection's own vertices count as non-Dirac (no_delta)
    cam_delta, light_delta = F.add(mis_delta(cam)), F.add(mis_delta(light))
    s1_delta_light = F.add(rec["s1_delta_light"])
    delta_light = F.add(lp.delta_light)
    no_delta = F.add(z > 0)
    F.add(z == 0)                               # last row: True (padding)
    camera_rows = SubpathRows(cam_fwd, cam_rev, cam_delta)
    light_rows = SubpathRows(light_fwd, light_rev, light_delta)

    # ---- each strategy's view of the subpaths (rows t - 2, j: its own records), its chain ----
    chains = []
    for (s, t) in strategies:
        camera_v, light_v, at_light = camera_rows.vertices(t), light_rows.vertices(s), delta_light
        if s == 0:        # z_{t-1} on a light, as y_0 of a light subpath would be
            camera_v = with_connection(camera_v, s0_pt + t - 2, s0_ptm + t - 2, no_delta)
        elif s == 1:      # y_0: the light sample of next-event estimation at z_{t-1}
            camera_v = with_connection(camera_v, s1_pt + t - 2, s1_ptm + t - 2, no_delta)
            light_v = [ChainVertex(s1_fwd_y + t - 2, s1_rev_y + t - 2, no_delta)]
            at_light = s1_delta_light + t - 2
        elif t == 1:      # y_{s-1} seen from the pinhole
            j = t1.index((s, t))
            light_v = with_connection(light_v, t1_qs + j, t1_qsm + j, no_delta)
        else:
            j = inner.index((s, t))
            camera_v = with_connection(camera_v, in_rows["pt"] + j, in_rows["ptm"] + j, no_delta)
            light_v = with_connection(light_v, in_rows["qs"] + j, in_rows["qsm"] + j, no_delta)
        chains.append(ratio_chain(camera_v, light_v, at_light))
    for (_, t) in env_strategies:   # s = 0 with z_{t-1} on the environment, at infinity
        camera_v = with_connection(camera_rows.vertices(t), env_pt + t - 2, env_ptm + t - 2,
                                   no_delta)
        camera_v[-1] = camera_v[-1]._replace(fwd=env_fwd + t - 2)
        chains.append(ratio_chain(camera_v, [], no_delta))
    weights = mis_weights([log_remap0(r) for r in P.rows], F.rows, chains, cfg.exponent)
    # stored a few rows at a time: one kernel for all of them ran unvectorised
    # (perf: docs/performance.md#bdpt-stored-in-groups)
    weights = materialize([weights[j] for j in range(weights.shape[0])], group=STORE_GROUP)

    # ---- contributions C* and C = w C* per strategy ----
    out = {}
    for j, (s, t) in enumerate(strategies):
        w = weights[j]
        pix = None
        if s == 0:
            c = rows(rec["s0_value"], t - 2)
            weighted = c * w
            if env_strategies:            # camera rays that escaped to the environment
                ce = rows(rec["env_value"], t - 2)
                weighted = weighted + ce * weights[len(strategies) + env_strategies.index((s, t))]
                c = c + ce
            out[(s, t)] = (None, weighted, c)
            continue
        if s == 1:
            c = rows(rec["s1_value"], t - 2)
        elif t == 1:
            k = t1.index((s, t))
            c = where(occ_t1[k], V3.full(0.0, w), rows(conn.value, k))
            pix = jnp.where(occ_t1[k], -1, conn.pixel[k])
        else:
            k = inner.index((s, t))
            c = where(occ_in[k], V3.full(0.0, w), rows(value_in, k))
        out[(s, t)] = (pix, c * w, c)
    return out


def pixel_contributions(scene, cfg, seed, pixel, sample):
    """The render's splat list: the sum of all t >= 2 strategies at the sample's own pixel,
    then one splat per t = 1 strategy."""
    out = contributions(scene, cfg, seed, pixel, sample)
    own = None
    splats = []
    for (s, t), (pix, weighted, _) in out.items():
        if pix is None:
            own = weighted if own is None else own + weighted
        else:
            splats.append((0, pix, weighted))
    items = [(0, pixel, own)] if own is not None else []
    return items + splats


def strategy_contributions(scene, cfg, seed, pixel, sample):
    """The splat list of :func:`render_strategies`: every strategy's unweighted value (image
    2k) and weighted value (image 2k + 1)."""
    # stored once, not re-derived per consumer (perf: docs/performance.md#bdpt-strategy-images)
    out = materialize(contributions(scene, cfg, seed, pixel, sample))
    items = []
    for k, st in enumerate(cfg.strategies()):
        pix, weighted, unweighted = out[st]
        p = pixel if pix is None else pix
        items.append((2 * k, p, unweighted))
        items.append((2 * k + 1, p, weighted))
    return items


def _blank(scene, n=None):
    H, W = scene.camera.height, scene.camera.width
    return np.zeros((H, W, 3) if n is None else (n, H, W, 3), np.float32)


def render_strategies(scene: Scene, cfg: BDPTConfig = BDPTConfig(), *, spp: int = 16, seed: int = 0,
                      progress: bool = False) -> dict:
    """Veach's pyramid: ``{(s, t): (unweighted, weighted)}`` images (H, W, 3) per strategy.

    The weighted images of one render sum to the BDPT image; each unweighted image is an
    unbiased estimate of the paths of length s + t - 1 that its strategy can sample."""
    cfg = replace(cfg, strategy_images="")
    strategies = cfg.strategies()
    if scene.lights.count == 0 or not strategies:
        return {st: (_blank(scene), _blank(scene)) for st in strategies}
    imgs = render_splats(scene, Configured(strategy_contributions, cfg), spp=spp, seed=seed,
                         n_images=2 * len(strategies), progress=progress)
    return {st: (imgs[2 * k], imgs[2 * k + 1]) for k, st in enumerate(strategies)}


def write_strategy_images(folder, images: dict, exposure: float = 0.0) -> list[Path]:
    """EXR + PNG per strategy (``s{s}_t{t}_weighted`` / ``_unweighted``) and a PNG pyramid:
    row L = path length, column s, weighted above unweighted."""

    folder = Path(folder)
    written = []
    for (s, t), (unw, wtd) in images.items():
        for tag, img in (("unweighted", unw), ("weighted", wtd)):
            path = folder / f"s{s}_t{t}_{tag}.exr"
            write_exr(path, img)
            write_png(path.with_suffix(".png"), img, exposure)
            written.append(path)
    if images:
        H, W, _ = next(iter(images.values()))[0].shape
        lengths = sorted({s + t - 1 for s, t in images})
        cols = max(lengths) + 1
        canvas = np.zeros((len(lengths) * (2 * H + 2), cols * (W + 2), 3), np.float32)
        for (s, t), (unw, wtd) in images.items():
            r = lengths.index(s + t - 1) * (2 * H + 2)
            c = s * (W + 2)
            canvas[r:r + H, c:c + W] = wtd
            canvas[r + H + 1:r + 2 * H + 1, c:c + W] = unw
        write_png(folder / "pyramid.png", canvas, exposure)
        written.append(folder / "pyramid.png")
    return written


def render(scene: Scene, cfg: BDPTConfig = BDPTConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """The BDPT image, (H, W, 3) float32 (no stats); with ``cfg.strategy_images`` every
    strategy's images are written there too (:func:`write_strategy_images`)."""
    if cfg.strategy_images:
        imgs = render_strategies(scene, cfg, spp=spp, seed=seed, progress=progress)
        write_strategy_images(cfg.strategy_images, imgs)
        return Render(sum((w for _, w in imgs.values()), _blank(scene)), {})
    if scene.lights.count == 0 or not cfg.strategies():
        return Render(_blank(scene), {})
    return Render(render_splats(scene, Configured(pixel_contributions, cfg), spp=spp, seed=seed,
                                progress=progress)[0], {})


register(Estimator("bdpt", "bidirectional path tracing, all (s, t) strategies with MIS", render,
                   BDPTConfig, renamed={"beta": "power"}, media=True, grid_media=True))
