"""Subpaths: the path machinery every estimator is assembled from.

Notation (Veach 1997, ch. 8 and 10; pbrt-v4's BDPT): a light subpath y_0 y_1 ... starts on a
light, a camera subpath z_0 z_1 ... at the pinhole. Each vertex x_i of a subpath carries

* beta: the subpath's throughput arriving at x_i, before x_i's BSDF: the start's emission
  (L_e |cos| / p of y_0 and its direction; 1 for the pinhole) times f |cos| / p of every
  direction sampled since; row 0 holds L_e on a light (1 at the camera);
* pdf_fwd: the area density p(x_i) with which its own subpath sampled it (from x_{i-1});
* pdf_rev: the area density with which x_i would be sampled from x_{i+1}, walking the other
  way (what a strategy that builds x_i from the other end needs: MIS by ratios of these).

Directions are sampled with solid-angle densities p_omega; :func:`convert_density` turns one
into the area measure at the vertex it reaches, p_A = p_omega |cos theta| / d^2 (the cosine
at the target, only if that is a surface point).

Contents: the camera ray (:func:`camera_ray`); vertices (:class:`Vertices`, :func:`rows`,
:func:`concat_rows`); BSDF-sampled random walks (:func:`random_walk`); lights as path vertices
(:func:`pdf_light_origin`, :func:`pdf_emission_dir`, :func:`light_normal`,
:func:`is_infinite`) and light subpaths (:func:`light_subpath`); next-event estimation
(:func:`sample_next_event`, :func:`next_event_value`). Connections of one subpath's vertex to
the other's (and to the pinhole) and batched shadow rays: :mod:`jgi.transport.connection`.
Where photon mapping's camera chains end and its photons are stored:
:mod:`jgi.transport.visible_points`.

Shading normals (scenes with vertex normals; :func:`shading`): every BSDF evaluation and sample
is about a vertex's shading normal ``ns`` and the value's cosines are ns's; ray offsets, shadow
rays and :func:`convert_density` use the geometric ``n``; light subpaths (importance mode) and
the connections multiply by Veach's adjoint correction
(:func:`jgi.physics.bsdf.adjoint_correction`), so both directions value a path alike.

Random numbers: a camera path uses dimensions 0 and 1 of its stream for the pixel jitter; a
bidirectional camera subpath (BDPT, VCM) then draws ``CAMERA_DIMS_PER_STEP`` per vertex from
``CAMERA_DIMS0`` on (its BSDF sample, then its light sample). A light subpath draws from the
stream :func:`light_key` (independent of the camera path's), ``LIGHT_DIMS0`` numbers for its
emission sample, then ``LIGHT_DIMS_PER_STEP`` per bounce. In a scene filled by a medium every
step draws two more after its own (free flight: channel, distance), so the per-step counts are
:func:`camera_dims_per_step` and :func:`light_dims_per_step` of the scene.

Participating media (a scene filled by a homogeneous medium, ``scene.has_medium``; Veach 1997
sec. 10.2 extended as in pbrt-v4's BDPT with media): every walk segment first samples a free
flight (:func:`jgi.physics.media.sample_free_flight`, the channel chosen uniformly, not by the
throughput, so the distance density is the same from either end). An interaction before the
surface makes a *medium vertex* (``in_medium`` True, ``on_surface`` False, normal zero, never
Dirac, no emitter) whose "BSDF" is the phase function (value = density, no cosine; sigma_s is
in beta), and beta takes T sigma_s / p(t) or, reaching the surface, T / P(t). Area densities
along a segment of length d multiply by the distance density of the vertex reached,

    p_A(x_i) = p_omega(x_{i-1} -> x_i) (|cos theta_i| if a surface) / d^2 * p_dist,
    p_dist = p(d) = sum_c q_c sigma_t,c T_c(d) (medium vertex),  P(d) = sum_c q_c T_c(d) (surface)

(:func:`area_density`), and connections multiply their values by the transmittance T(d).
Vacuum scenes compile to the programs they compiled to before (``in_medium`` is None there).

Media bounded by shapes (:mod:`jgi.physics.medium_interfaces`): every walk state and vertex
carries the id of the medium it was reached in (``medium``; None in scenes without bounded
media), and each segment's free flight, distance densities and transmittance take that
medium's parameters: the segment from a vertex to the next lies in the medium the walk leaves
the vertex into (:func:`jgi.physics.medium_interfaces.leaving`).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .. import _xla
from .._xla import materialize
from ..core import rng, warps
from ..core.vec import EDGE_ON_COS, V3, dot, max_component, normalize, where
from ..physics import bsdf, camera, geometry, grid_media, media, medium_interfaces, phase
from ..physics.lights import LightSample, cylinder_normal, emitted, sample_emission, sample_li
from ..scene.tables import (
    AREA_CYLINDER,
    AREA_DISK,
    AREA_QUAD,
    AREA_SPHERE,
    AREA_TRIANGLE,
    DIRECTIONAL,
    ENVIRONMENT,
    PLASTIC,
    POINT,
    SPOT,
    Camera,
    Scene,
)

LIGHT_SALT = rng.SALTS["light_subpath"]  # light subpaths: independent of the camera path's
CAMERA_DIMS0 = 2               # dims 0, 1: pixel jitter
CAMERA_DIMS_PER_STEP = 6       # per vertex: BSDF (3), light sample (3)
LIGHT_DIMS0 = 5                # dims 0..4: sample_emission (selection, position, direction)
LIGHT_DIMS_PER_STEP = 3        # per bounce: lobe, u1, u2
MEDIUM_DIMS = 2                # per step in a medium scene, after the step's own: channel, distance


def camera_dims_per_step(scene: Scene) -> int:
    """Random numbers per camera-subpath vertex: BSDF (3) and light sample (3), then free flight
    (channel, distance) in a scene filled by a medium (vacuum scenes keep their streams)."""
    return CAMERA_DIMS_PER_STEP + (MEDIUM_DIMS if scene.has_medium else 0)


def light_dims_per_step(scene: Scene) -> int:
    """Random numbers per light-subpath bounce: lobe, u1, u2, then free flight in a medium."""
    return LIGHT_DIMS_PER_STEP + (MEDIUM_DIMS if scene.has_medium else 0)


# --- streams and the camera ray -------------------------------------------------------------------

def light_key(seed, pixel, sample) -> Array:
    """The stream of the light subpath of path (seed, pixel, sample)."""
    return rng.derive(rng.path_key(seed, pixel, sample), LIGHT_SALT)


def camera_ray(cam: Camera, pixel: Array, uniform: Callable[[int], Array]) -> tuple[V3, V3]:
    """The primary ray (origin, direction) through flat pixel index ``pixel`` (row-major, row 0
    at the top), jittered within the pixel by ``uniform(0)``, ``uniform(1)``: dimensions 0 and
    1 of every camera path's stream."""
    W = cam.width
    return camera.sample_ray(cam, pixel % W, pixel // W, uniform(0), uniform(1))


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
    uv: tuple | None = None  # surface coordinates (u, v), in scenes with textures (else None)
    ns: V3 | None = None     # unit shading normal, in scenes with vertex normals (else None)
    # the direction sampled here left by a Dirac lobe (pbrt-v4's Vertex::delta, what MIS
    # reads), in scenes with smooth plastic, whose vertices are connectable (``delta`` False)
    # and yet may be left by a Dirac lobe; None elsewhere, where ``delta`` says both
    lobe_delta: Array | None = None
    # a medium vertex (a free-flight interaction; phase function, no normal), in scenes filled
    # by a medium; None in vacuum scenes
    in_medium: Array | None = None
    # the id of the medium the vertex was reached in (jgi.physics.medium_interfaces), in scenes
    # with media bounded by shapes; None elsewhere
    medium: Array | None = None


def vertex_in_medium(scene: Scene, like: Array) -> Array | None:
    """The ``in_medium`` of a vertex that is not a free-flight interaction (camera, light,
    surface): False in a medium scene, None in a vacuum one."""
    return (like != like) if scene.has_medium else None


def segment_medium(scene: Scene, v, w: V3) -> Array | None:
    """The medium id of a segment that leaves vertex ``v`` (a :class:`Vertices` or any record
    with n, material, in_medium and medium) in direction w: the side of w at a surface that
    bounds media, else the medium v was reached in. None in scenes without bounded media. (Not
    for a subpath's vertex 0, whose material is no surface's: the pinhole and the lights sit in
    the scene's own medium, its ``medium``.)"""
    if not scene.has_bounded_media:
        return None
    return medium_interfaces.leaving(scene, v.medium, v.material, v.n, w, v.in_medium)


def segment_density(scene: Scene, d2: Array, at_medium: Array, medium: Array | None = None
                    ) -> Array:
    """p_dist of a segment of squared length d2 (medium scenes): p(d) if it ends at a medium
    vertex (``at_medium``), P(d) if at a surface (:func:`jgi.physics.media.segment_pdf`).

    In a grid medium the distance density of a tracked flight has no closed form (it holds the
    transmittance along the segment, which tracking only estimates). There the densities MIS
    reads take a proxy: the homogeneous medium's p(d) or P(d) at the grid's mean extinction
    (:func:`jgi.physics.medium_interfaces.mean_extinction`). It is a function of the segment
    alone, the same in every strategy's density of the path, so the MIS weights of a path still
    sum to one and BDPT, MMLT and VCM stay unbiased (consistent, for VCM's merges); what the
    proxy costs is variance where the medium is far from its mean. (pbrt-v3's BDPT leaves the
    distance densities out altogether; the proxy keeps their units, a medium vertex's 1 /
    length, and is exact in a constant grid. Measured in tests/test_grid_media.py's smoke room,
    16 seeds: BDPT's and VCM's per-pixel variance within 0.5% of leaving them out, so the choice
    is a principle there, not yet a measured gain.)"""
    if not scene.has_grid_medium:
        sigma_t = medium_parameters(scene, medium).sigma_t
    elif not scene.has_bounded_media:
        sigma_t = medium_interfaces.mean_extinction(scene, None)
    else:   # the bounded grids' lanes take their grid's proxy, the others their medium's
        sigma_t = where(medium_interfaces.in_grid(scene, medium),
                        medium_interfaces.mean_extinction(scene, medium),
                        medium_parameters(scene, medium).sigma_t)
    return media.segment_pdf(sigma_t, jnp.sqrt(d2), at_medium)


def medium_parameters(scene: Scene, medium: Array | None):
    """The homogeneous medium of each lane's segment (``medium``: its ids, required in scenes
    with bounded media; :func:`jgi.physics.medium_interfaces.parameters`)."""
    if scene.has_bounded_media and medium is None:
        raise ValueError("a scene with media bounded by shapes needs the segment's medium id")
    return medium_interfaces.parameters(scene, medium)


def area_density(scene: Scene, pdf_solid: Array, d2: Array, cos_at: Array, on_surface: Array,
                 at_medium: Array | None, medium: Array | None = None) -> Array:
    """:func:`convert_density`, times the segment's distance density p_dist of the target's kind
    in a medium scene (p(d) at a medium vertex, ``at_medium``; P(d) elsewhere), in the
    segment's medium ``medium`` (ids; scenes with bounded media). In vacuum scenes exactly
    :func:`convert_density`."""
    pdf = convert_density(pdf_solid, d2, cos_at, on_surface)
    if not scene.has_medium:
        return pdf
    return pdf * segment_density(scene, d2, at_medium, medium)


def phase_value(scene: Scene, d_in: V3, d_out: V3, medium: Array | None = None) -> Array:
    """The phase function of the medium (ids ``medium`` in scenes with bounded media) for
    propagation directions d_in -> d_out (= its sampling density; reciprocal: the reversed
    pair -d_out -> -d_in has the same value)."""
    g = medium_parameters(scene, medium).g
    return phase.evaluate(jax.lax.stop_gradient(g), d_in, d_out)


def mis_delta(v: Vertices) -> Array:
    """The Dirac flags that MIS reads: whether each vertex's sampled direction left it by a
    Dirac lobe (:attr:`Vertices.lobe_delta`, or ``delta`` where the scene has no plastic)."""
    return v.delta if v.lobe_delta is None else v.lobe_delta


def vertex_lobe_delta(scene: Scene, like: Array) -> Array | None:
    """The ``lobe_delta`` of a vertex that sampled no BSDF (camera, light): False in a scene
    with smooth plastic, None in one without."""
    return (like != like) if PLASTIC in scene.materials.kinds else None


def shading(v) -> V3:
    """The normal a vertex's (or hit's) BSDF is evaluated about: its shading normal in a scene
    with vertex normals, else its geometric normal (the same array: such scenes compile as
    before). The geometric normal ``v.n`` stays for ray offsets and area densities."""
    return v.n if v.ns is None else v.ns


def vertex_ns(scene: Scene, n: V3) -> V3 | None:
    """The ``ns`` of a vertex that is not on a mesh (camera, light): n in a scene with vertex
    normals, None in one without."""
    return n if scene.has_shading_normals else None


def no_uv(scene: Scene, like: Array) -> tuple | None:
    """The uv of a vertex that is not on a textured surface (camera, light, no hit yet): zeros
    in a scene with textures, None in one without."""
    return (jnp.zeros_like(like), jnp.zeros_like(like)) if scene.materials.has_textures else None


def concat_rows(a, b):
    """The rows of b after those of a, in every leaf (e.g. vertex 0, then the walk's vertices)."""
    return jax.tree_util.tree_map(lambda x, y: jnp.concatenate([x, y], 0), a, b)


def rows(v, i):
    """Row i (an int or a slice) or rows i (a static index list) of every leaf. Rows are taken
    by static slices, not a gather (which XLA's CPU backend runs as a slow, unfused loop)."""
    if isinstance(i, (int, np.integer, slice)):
        return jax.tree_util.tree_map(lambda x: x[i], v)
    return jax.tree_util.tree_map(lambda x: jnp.stack([x[int(k)] for k in i]), v)


def convert_density(pdf_solid: Array, d2: Array, cos_at: Array, on_surface: Array) -> Array:
    """Solid-angle density at one vertex -> area density at the other (pbrt's ConvertDensity):
    p_A = p_omega |cos theta| / d^2, the cosine only where the target is a surface point."""
    ok = d2 > 0
    c = jnp.where(on_surface, jnp.abs(cos_at), 1.0)
    return jnp.where(ok, pdf_solid * c / jnp.where(ok, d2, 1.0), 0.0)


# --- random walks --------------------------------------------------------------------------------

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
    medium: Array | None = None   # the id of the medium the ray travels in (bounded media)


def free_flight(scene: Scene, o: V3, d: V3, hit: geometry.Hit, alive: Array, u_channel: Array,
                u_distance: Array, throughput: V3 | None = None, medium_id: Array | None = None
                ) -> tuple[geometry.Hit, Array, V3]:
    """The free flight of a subpath segment from o along d in a scene filled by a medium, every
    subpath's (BDPT's, light tracing's, MMLT's, VCM's): a medium vertex before the surface
    ``hit``, or the surface reached. Returns (the hit, a medium vertex there where
    ``in_medium``: its position, a zero normal, no emitter; ``in_medium``; the weight that
    multiplies the throughput).

    A homogeneous medium: detached sampling with the uniform channel choice
    (:func:`jgi.physics.media.sample_free_flight`), weight T sigma_s / p(t) or T / P(t). A grid
    medium: spectral tracking (:func:`jgi.physics.grid_media.sample_free_flight`) on a stream
    hashed from the two numbers, history-aware through ``throughput``, its weight the
    tracking's; not differentiated (the grid is a constant, see that module). ``medium_id``:
    the medium the ray travels in (scenes with bounded media; with a bounded grid, its lanes
    are tracked and the others sampled)."""
    sg = jax.lax.stop_gradient
    t_hit = jnp.where(hit.valid, hit.t, jnp.inf)
    grid = scene.has_grid_medium or None
    in_grid = medium_interfaces.in_grid(scene, medium_id)
    if grid is not None:
        beta = V3.full(1.0, t_hit) if throughput is None else throughput
        gf = medium_interfaces.free_flight(scene, medium_id, o, d, t_hit, sg(beta), alive,
                                           rng.substream(u_channel, u_distance))
        t_ff, scattered, weight = gf.t, gf.scattered, gf.weight
    if grid is None or in_grid is not None:
        medium = medium_parameters(scene, medium_id)   # (a grid lane's row: vacuum)
        ff = media.sample_free_flight(sg(medium.sigma_t), sg(medium.albedo), None, t_hit,
                                      u_channel, u_distance)
        w_ff = media.free_flight_weight(medium.sigma_t, medium.albedo, ff.t, ff.scattered,
                                        ff.pdf)
        if grid is None:
            t_ff, scattered, weight = ff.t, ff.scattered, w_ff
        else:
            t_ff = jnp.where(in_grid, t_ff, ff.t)
            scattered = jnp.where(in_grid, scattered, ff.scattered)
            weight = where(in_grid, weight, w_ff)
    in_med = alive & scattered
    p_m = o + d * jnp.where(in_med, t_ff, 0.0)
    zero = jnp.zeros_like(hit.t)
    Z = V3(zero, zero, zero)
    hit = hit._replace(valid=hit.valid | in_med, p=where(in_med, p_m, hit.p),
                       n=where(in_med, Z, hit.n), emitter=jnp.where(in_med, -1, hit.emitter),
                       ns=None if hit.ns is None else where(in_med, Z, hit.ns))
    return hit, in_med, weight


def scatter_in_medium(scene: Scene, bs, pdf_back: Array, d: V3, in_medium: Array, u1: Array,
                      u2: Array, medium_id: Array | None = None):
    """The BSDF sample ``bs`` (and its reverse density ``pdf_back``) replaced, where
    ``in_medium``, by the phase function's sample for a subpath arriving along d: weight 1
    (p / p; for detached derivatives 1 + (p - sg(p)) / sg(p), the derivative of p alone),
    density the phase value, the same backwards (reciprocity), never Dirac."""
    sg = jax.lax.stop_gradient
    g = medium_parameters(scene, medium_id).g
    ps = phase.sample(sg(g), d, u1, u2)
    p_g = phase.henyey_greenstein(ps.mu, g)
    one = 1.0 + (p_g - sg(p_g)) / jnp.where(sg(p_g) > 0, sg(p_g), 1.0)
    bs = bs._replace(wi=where(in_medium, ps.d_out, bs.wi),
                     weight=where(in_medium, V3(one, one, one), bs.weight),
                     pdf=jnp.where(in_medium, ps.pdf, bs.pdf), delta=bs.delta & ~in_medium,
                     valid=bs.valid | in_medium)
    return bs, jnp.where(in_medium, ps.pdf, pdf_back)


class Visit(NamedTuple):
    """What a walk's per-vertex callback sees (all [N])."""
    step: Array
    hit: geometry.Hit
    mp: bsdf.MaterialParams
    wo: V3
    state: WalkState   # the state that produced this hit (beta, pdf_dir, previous vertex)
    valid: Array
    d2_prev: Array     # squared distance to the previous vertex
    u: Callable[[int], Array]
    # medium scenes: the vertex is a free-flight interaction (``hit`` then holds its position,
    # a zero normal and no emitter; ``state.beta`` already carries the free-flight weight)
    in_medium: Array | None = None


def random_walk(scene: Scene, key: Array, dim0: int, dims_per_step: int, n_steps: int,
                start: WalkState, mode: int, visit: Callable[[Visit], object] | None = None,
                uniform: Callable | None = None, infinite_start: tuple | None = None,
                n_live=None):
    """Extend a subpath by ``n_steps`` BSDF-sampled segments (pbrt-v4's RandomWalk).

    Random numbers come from the hashed stream ``key``, or, if ``uniform`` is given, from
    ``uniform(dim)`` (explicit primary samples, e.g. Metropolis; ``key`` is then unused).

    ``infinite_start = (flags, pdf_disc)`` (light subpaths of scenes with directional or
    environment lights): where a flag is set, vertex 0 lies at infinity and the walk starts on
    its bounding disc, so vertex 1's density is the disc's area density times |cos| at vertex 1
    (no 1 / d^2), and vertex 0's reverse density stays a solid-angle density (pbrt-v4's
    GenerateLightSubpath and ConvertDensity for infinite lights).

    ``n_live`` (traced scalar, or None: all): only the first n_live steps are traced; the others
    are skipped (lax.cond: no intersection) and give invalid, zero vertices, so a batch whose
    paths are all short (MMLT's lanes of short lengths) does not pay for max_depth steps.

    Returns (vertices 1..n_steps as :class:`Vertices` [n_steps, N], pdf_rev of vertex 0 [N],
    the stacked outputs of ``visit``). Each vertex's ``pdf_rev`` is filled in by the next step
    (the density of sampling it backwards from there); the last one's is 0."""
    mats = scene.materials
    kinds = mats.kinds
    if scene.has_grid_medium:   # the trackings' derivatives would come out zero: refused
        grid_media.refuse_derivatives(medium_interfaces.grids(scene))

    def step(s: WalkState, j):
        base = dim0 + j * dims_per_step
        u = ((lambda k: rng.uniform(key, base + k)) if uniform is None  # noqa: E731
             else (lambda k: uniform(base + k)))
        hit = geometry.intersect(scene, s.o, s.d)
        in_med = None
        if scene.has_medium:
            hit, in_med, w_ff = free_flight(scene, s.o, s.d, hit, s.alive,
                                            u(dims_per_step - MEDIUM_DIMS),
                                            u(dims_per_step - MEDIUM_DIMS + 1), s.beta, s.medium)
            s = s._replace(beta=s.beta * w_ff)
        valid = s.alive & hit.valid
        v = hit.p - s.prev_p
        d2 = dot(v, v)
        if in_med is None:
            pdf_fwd = jnp.where(valid, convert_density(s.pdf_dir, d2, dot(hit.n, s.d), True), 0.0)
        else:
            pdf_fwd = jnp.where(valid, area_density(scene, s.pdf_dir, d2, dot(hit.n, s.d),
                                                    ~in_med, in_med, s.medium), 0.0)
        mp = bsdf.lookup_specialised(mats, hit.material, hit.uv)
        wo = -s.d
        delta = bsdf.is_delta(mp)
        if in_med is not None:
            delta = delta & ~in_med
        extra = (visit(Visit(j, hit, mp, wo, s, valid, d2, u, in_med)) if visit is not None
                 else None)
        # ---- BSDF sampling: the next direction, and the reverse density of the previous vertex
        # (both about the shading normal; area conversions use geometric normals)
        ns = shading(hit)
        bs = materialize(bsdf.sample(kinds, mp, ns, wo, u(0), u(1), u(2), mode=mode))
        # left by a Dirac lobe: no density either way through this vertex (pbrt-v4 zeroes
        # pdfFwd and pdfRev); per sample on plastic, else the material's flag
        delta_s = bsdf.sampled_delta(kinds, mp, bs)
        _, pdf_back = bsdf.evaluate(kinds, mp, ns, bs.wi, wo)
        if in_med is not None:
            bs, pdf_back = scatter_in_medium(scene, bs, pdf_back, s.d, in_med, u(0), u(1),
                                             s.medium)
            delta_s = delta_s & ~in_med
            # the previous vertex from here: P(d) if a surface, p(d) if a medium vertex
            pdf_rev_prev = jnp.where(valid & ~delta_s, area_density(
                scene, pdf_back, d2, dot(s.prev_n, s.d), s.prev_surface, ~s.prev_surface,
                s.medium), 0.0)
        else:
            pdf_rev_prev = jnp.where(valid & ~delta_s, convert_density(
                pdf_back, d2, dot(s.prev_n, s.d), s.prev_surface), 0.0)
        if infinite_start is not None:
            # (no distance density for the segment from infinity, in any strategy; a medium
            # vertex there, in a bounded grid, has no cosine)
            at_infinity = infinite_start[0] & (j == 0) & valid
            cos_in = jnp.abs(dot(hit.n, s.d))
            if in_med is not None:
                cos_in = jnp.where(in_med, 1.0, cos_in)
            pdf_fwd = jnp.where(at_infinity, infinite_start[1] * cos_in, pdf_fwd)
            pdf_rev_prev = jnp.where(at_infinity & ~delta_s, pdf_back, pdf_rev_prev)
        surface = valid if in_med is None else valid & ~in_med
        vert = Vertices(hit.p, hit.n, wo, s.beta, pdf_fwd, pdf_rev_prev, delta, surface, valid,
                        hit.material, jnp.where(valid, hit.emitter, -1), hit.uv, hit.ns,
                        delta_s if PLASTIC in kinds else None,
                        None if in_med is None else valid & in_med, s.medium)
        beta = s.beta * bs.weight
        if mode == bsdf.IMPORTANCE and hit.ns is not None:   # Veach's adjoint correction
            corr = bsdf.adjoint_correction(ns, hit.n, wo, bs.wi)
            beta = beta * (corr if in_med is None else jnp.where(in_med, 1.0, corr))
        alive = valid & bs.valid & (max_component(beta) > 0)
        # a medium vertex has a zero normal: the next ray leaves from it, not offset
        nxt = WalkState(geometry.offset_origin(hit.p, hit.n, bs.wi), bs.wi, beta,
                        jnp.where(bs.delta, 0.0, bs.pdf), hit.p, hit.n, surface, delta_s, alive,
                        medium_interfaces.leaving(scene, s.medium, hit.material, hit.n, bs.wi,
                                                  in_med))
        return nxt, (vert, extra)

    body = step
    if n_live is not None:
        def body(s: WalkState, j):
            shapes = jax.eval_shape(step, s, j)

            def skip(s, j):
                return s._replace(alive=s.alive & False), jax.tree_util.tree_map(
                    lambda a: jnp.zeros(a.shape, a.dtype), shapes[1])
            return jax.lax.cond(j < n_live, step, skip, s, j)
    _, (verts, extras) = jax.lax.scan(body, start, jnp.arange(n_steps))
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
    if AREA_DISK in lights.kinds or AREA_CYLINDER in lights.kinds:   # static: else as before
        is_area = is_area | (kind == AREA_DISK) | (kind == AREA_CYLINDER)
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
    if AREA_DISK in lights.kinds:
        on = on | (kind == AREA_DISK)
    if AREA_CYLINDER in lights.kinds:
        c = V3(lights.p0.x[kk], lights.p0.y[kk], lights.p0.z[kk])
        n = where(kind == AREA_CYLINDER, cylinder_normal(c, n, lights.radius[kk], y), n)
        on = on | (kind == AREA_CYLINDER)
    z = jnp.zeros_like(y.x)
    return where(on, n, V3(z, z, z)), on


def pdf_bounding_disc(lights) -> Array:
    """Area density (without selection) of a light path's origin on the bounding disc of a
    directional or environment light, 1 / (pi R^2) (pbrt-v4's PdfLight for infinite lights)."""
    R = lights.bound_radius
    return 1.0 / (jnp.pi * R * R)


def has_infinite_lights(lights) -> bool:
    """Whether the scene has a directional or environment light (static: scenes without one
    compile to the programs they compiled to before infinite lights started subpaths)."""
    return DIRECTIONAL in lights.kinds or ENVIRONMENT in lights.kinds


def is_infinite(lights, k: Array) -> Array:
    """Element k is a directional or environment light (no position: y_0 would be a point of
    the scene's bounding disc)."""
    kind = lights.kind[jnp.maximum(k, 0)]
    return (kind == DIRECTIONAL) | (kind == ENVIRONMENT)


class LightPath(NamedTuple):
    vertices: Vertices   # [max_depth, N]: vertex 0 on the light, then max_depth - 1 bounces
    delta_light: Array   # point, spot (delta position) or directional (delta direction)
    element: Array       # the light element


def light_subpath(scene: Scene, key: Array, max_depth: int, infinite: bool = False,
                  uniform: Callable | None = None, n_live=None) -> LightPath:
    """Light subpath y_0 .. y_{max_depth-1} (enough for every strategy with t >= 1).

    ``uniform(dim)``, if given, replaces the hashed stream ``key`` (explicit primary samples).

    ``infinite=False`` drops subpaths that start on directional or environment lights (their
    y_0 is a point of a bounding disc, not of the scene). ``infinite=True`` (BDPT, light
    tracing) keeps them, as pbrt-v4 does: y_0 then stands for the direction at infinity, its
    p_fwd the direction's solid-angle density with selection (pbrt's InfiniteLightDensity) and
    its p_rev a solid-angle density too; y_1's p_fwd is the disc's area density times |cos| at
    y_1 (:func:`random_walk`'s ``infinite_start``)."""
    lights = scene.lights
    if scene.fills_with_homogeneous_medium:
        # in a medium filling the scene, light from infinity is extinguished (T(inf) = 0, as
        # the path tracer finds: its escaping rays weigh T / P = 0); a grid is bounded
        infinite = False
    u = (lambda k: rng.uniform(key, k)) if uniform is None else uniform  # noqa: E731
    em = sample_emission(lights, u(0), u(1), u(2), u(3), u(4))
    inf = is_infinite(lights, em.element)
    ok = (em.pdf_pos > 0) & (max_component(em.weight) > 0)
    if not infinite:
        ok = ok & ~inf
    on_surface = ~em.delta_pos & ~inf
    z = jnp.zeros_like(em.pdf_pos)
    delta_light = em.delta_pos | em.delta_dir
    le = emitted(lights, jnp.where(on_surface, em.element, -1), em.n, em.d)
    pdf_y0 = em.pdf_pos
    infinite_start = None
    if infinite and has_infinite_lights(lights):
        pdf_y0 = jnp.where(inf, lights.pmf[em.element] * em.pdf_dir, em.pdf_pos)
        infinite_start = (inf, pdf_bounding_disc(lights))
    v0 = Vertices(em.p, em.n, V3(z, z, z), le, pdf_y0, z, z > 0, on_surface, ok,
                  jnp.zeros_like(em.element), em.element, no_uv(scene, z), vertex_ns(scene, em.n),
                  vertex_lobe_delta(scene, z), vertex_in_medium(scene, z),
                  medium_interfaces.start(scene, z))
    v0 = jax.tree_util.tree_map(lambda x: x[None], v0)
    if max_depth <= 1:
        return LightPath(v0, delta_light, em.element)
    start = WalkState(geometry.offset_origin(em.p, em.n, em.d), em.d, em.weight,
                      em.pdf_dir, em.p, em.n, on_surface, z > 0, ok,
                      medium_interfaces.start(scene, z))
    verts, pdf_rev0, _ = random_walk(scene, key, LIGHT_DIMS0, light_dims_per_step(scene),
                                     max_depth - 1,
                                     start, bsdf.IMPORTANCE, uniform=uniform,
                                     infinite_start=infinite_start, n_live=n_live)
    v0 = v0._replace(pdf_rev=pdf_rev0[None])
    return LightPath(concat_rows(v0, verts), delta_light, em.element)


# --- next-event estimation (s = 1): a light sample seen from a surface point ----------------------

class NextEvent(NamedTuple):
    """A light sample y for the surface point x (the light-sampling strategy p_light of Veach
    1997, sec. 9.2; BDPT's s = 1), with what estimators need of the BSDF at x towards it."""
    light: LightSample  # wi (x -> y), dist, L_i, pdf (solid angle, selection included), delta
    f: V3                  # f(wo -> wi) at x
    pdf_bsdf: Array        # solid-angle density of BSDF sampling wi at x (for MIS against it)
    cos: Array             # |cos theta_i| = |ns . wi| at x (ns: the shading normal)
    shadow: tuple          # (origin, direction, t_max) of the shadow ray x -> y
    ok: Array              # a usable sample (before the visibility test)


def sample_next_event(scene: Scene, mp: bsdf.MaterialParams, p: V3, n: V3, wo: V3, u_select: Array,
                      u1: Array, u2: Array, active: Array, ns: V3 | None = None,
                      stored: bool = False) -> NextEvent:
    """Sample a light for the point p (geometric normal n, shading normal ``ns`` if not n,
    ``wo`` towards the previous vertex) with ``lights.sample_li``, and evaluate the BSDF mp
    towards it (about ns, as its cosine). Usable where ``active``, the BSDF has a non-Dirac
    lobe, and the sample has a positive density; the caller tests the shadow ray (now, or
    batched with others) and chooses the MIS weight. ``stored``: the light sample is computed
    once and stored (``jgi._xla.materialize``) for a caller whose BSDF evaluation and shadow
    ray land in different kernels, which would each compute it."""
    nb = n if ns is None else ns
    ls = sample_li(scene.lights, p, u_select, u1, u2)
    if stored:
        ls = materialize(ls)
    f, pdf_bsdf = bsdf.evaluate(scene.materials.kinds, mp, nb, wo, ls.wi)
    ok = active & ~bsdf.is_delta(mp) & ls.valid & (ls.pdf > 0)
    return NextEvent(ls, f, pdf_bsdf, jnp.abs(dot(ls.wi, nb)),
                     geometry.shadow_ray(p, n, ls.wi, ls.dist), ok)


def at_medium_vertex(ne: NextEvent, in_medium: Array, f_phase: Array, active: Array) -> NextEvent:
    """The light sample ``ne`` where ``in_medium``, seen from a medium vertex: the phase
    function's value ``f_phase`` (= its sampling density) in place of the BSDF's f and pdf, no
    cosine, usable wherever the light sample is (no BSDF lobe to be Dirac). The caller's
    estimate also takes the shadow segment's transmittance."""
    f = V3(f_phase, f_phase, f_phase)
    ok = active & ne.light.valid & (ne.light.pdf > 0)
    return ne._replace(f=where(in_medium, f, ne.f),
                       pdf_bsdf=jnp.where(in_medium, f_phase, ne.pdf_bsdf),
                       cos=jnp.where(in_medium, 1.0, ne.cos),
                       ok=jnp.where(in_medium, ok, ne.ok))


def next_event_value(ne: NextEvent, beta: V3, weight: Array | None = None,
                     n_samples: float = 1.0) -> V3:
    """The sample's contribution if y is visible from x: beta f L_i |cos theta_i| w / (n p_light),
    with MIS weight w (None: 1) for one of ``n_samples`` light samples; 0 where not ``ne.ok``."""
    num = ne.cos if weight is None else weight * ne.cos
    scale = _xla.div(num, n_samples * jnp.where(ne.ok, ne.light.pdf, 1.0))
    return where(ne.ok, beta * ne.f * ne.light.Li * scale, V3.full(0.0, scale))
