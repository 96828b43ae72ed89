"""Connections: a light-subpath vertex joined to a camera-subpath vertex by a shadow ray.

Two kinds (Veach 1997, sec. 10.2; pbrt-v4's BDPT ``ConnectBDPT``), each returning what every
estimator that makes it needs, the value before visibility, the shadow ray and the densities its
MIS reads:

* :func:`connect_vertices`, s, t >= 2: light vertex y = y_{s-1} and camera vertex z = z_{t-1},
  c = f(y_{s-2} -> y -> z) G(y <-> z) f(y -> z -> z_{t-2}), G = |cos| |cos| / d^2 (BDPT's
  interior strategies, VCM's connections, and so MMLT's);
* :func:`connect_camera`, t = 1: light vertex y joined to the pinhole and splatted into the
  pixel it projects to (light tracing, BDPT, VCM).

Both evaluate BSDFs about the vertices' shading normals (:func:`~jgi.transport.subpath.shading`)
with the shading normals' cosines in the value, and the geometric normals' in the area densities
and the shadow ray; the light vertex y, whose BSDF is evaluated in importance mode, takes Veach's
adjoint correction (:func:`jgi.physics.bsdf.adjoint_correction`), so that a path is valued alike
from both ends. :func:`occluded_many` tests several batches of shadow rays in one query.

In a scene filled by a medium (:mod:`jgi.transport.subpath`'s medium vertices) a connection's
value takes the transmittance T_c(d) = exp(-sigma_t,c d) of the segment (the shadow ray stays a
binary visibility test), a medium vertex contributes the phase function in place of f and no
cosine, and every area density across the connection multiplies by the distance density p_dist
of the vertex it reaches (p(d) at a medium vertex, P(d) at a surface): the density with which a
subpath's free flight would have made that segment. In a grid medium T is ratio tracking's
unbiased estimate along the shadow ray (:func:`shadow_transmittance`), and p_dist the proxy of
:func:`jgi.transport.subpath.segment_density`.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array

from .._xla import materialize
from ..core import rng
from ..core.vec import V3, dot, max_component, where
from ..physics import bsdf, camera, geometry, media, medium_interfaces
from ..scene.tables import Scene
from .subpath import (
    Vertices,
    convert_density,
    medium_parameters,
    phase_value,
    segment_density,
    segment_medium,
    shading,
)

# --- s, t >= 2: a light vertex joined to a camera vertex -----------------------------------------


class VertexConnection(NamedTuple):
    """Light vertex y joined to camera vertex z (any array shape, all alike)."""
    value: V3          # beta_y f_y G f_z beta_z, unweighted, before the visibility test
    shadow: tuple      # (origin, direction, t_max) of the shadow ray y -> z
    pdf_z_from_y: Array  # area density of z sampled by y's BSDF (z's reverse density)
    pdf_y_from_z: Array  # area density of y sampled by z's BSDF (y's reverse density)
    pdf_y_rev: Array   # solid-angle density at y of the direction back to y's predecessor,
                       # given the direction to z (y_{s-2}'s reverse density, before conversion)
    pdf_z_rev: Array   # the same at z, of the direction back to z_{t-2}


def connect_vertices(scene: Scene, y, z, ok: Array,
                     continuation: Callable[[bsdf.MaterialParams], Array] | None = None,
                     reciprocal: bool = False) -> VertexConnection:
    """Light vertices y joined to camera vertices z (strategy (s, t), s, t >= 2).

    ``y`` and ``z`` are any records with fields p, n, wo (towards the previous vertex of the
    vertex's own subpath), beta, material, uv and ns (:class:`~jgi.transport.subpath.Vertices`,
    or VCM's). ``ok``: the caller's test that both may be connected (valid, not Dirac; BDPT and
    VCM keep different flags); pairs at distance 0 are refused here. The value is zero where not
    ok.

    ``continuation(material)``, if given, multiplies every direction density at a vertex (VCM's
    Russian roulette: the probability q that a subpath continues there). ``reciprocal``: divide
    by d^2 through one reciprocal multiplied in (VCM's form, SmallVCM's) rather than by
    division (BDPT's, pbrt's ConvertDensity): the same quantities, rounded differently, each
    estimator keeping its own so that its images stay bit for bit."""
    kinds = scene.materials.kinds
    v = z.p - y.p
    d2 = dot(v, v)
    dist = jnp.sqrt(d2)
    w = v / jnp.where(dist > 0, dist, 1.0)             # from y towards z
    my = bsdf.lookup_specialised(scene.materials, y.material, y.uv)
    mz = bsdf.lookup_specialised(scene.materials, z.material, z.uv)
    ny, nz = shading(y), shading(z)                     # BSDFs about the shading normals
    f_y, pdf_y_fwd = bsdf.evaluate(kinds, my, ny, y.wo, w,  # y_{s-2} -> y -> z
                                   mode=bsdf.IMPORTANCE)
    _, pdf_y_rev = bsdf.evaluate(kinds, my, ny, w, y.wo)
    f_z, pdf_z_fwd = bsdf.evaluate(kinds, mz, nz, z.wo, -w)  # z_{t-2} -> z -> y
    _, pdf_z_rev = bsdf.evaluate(kinds, mz, nz, -w, z.wo)
    medium = scene.has_medium
    if medium:
        # medium vertices: the phase function for the propagation directions (in: -wo, out:
        # towards the other end), its value its density both ways (reciprocity)
        y_m, z_m = y.in_medium, z.in_medium
        p_y = phase_value(scene, -y.wo, w, y.medium)
        p_z = phase_value(scene, -z.wo, -w, z.medium)
        # the segment's medium (bounded media): on its side of y; z's side agrees unless a
        # boundary occludes the segment
        segment = segment_medium(scene, y, w)
        f_y = where(y_m, V3(p_y, p_y, p_y), f_y)
        f_z = where(z_m, V3(p_z, p_z, p_z), f_z)
        pdf_y_fwd, pdf_y_rev = jnp.where(y_m, p_y, pdf_y_fwd), jnp.where(y_m, p_y, pdf_y_rev)
        pdf_z_fwd, pdf_z_rev = jnp.where(z_m, p_z, pdf_z_fwd), jnp.where(z_m, p_z, pdf_z_rev)
    if continuation is not None:
        q_y, q_z = continuation(my), continuation(mz)
        if medium:   # no roulette at a medium vertex (VCM's q is a material's)
            q_y, q_z = jnp.where(y_m, 1.0, q_y), jnp.where(z_m, 1.0, q_z)
        pdf_y_fwd, pdf_y_rev, pdf_z_fwd, pdf_z_rev = (pdf_y_fwd * q_y, pdf_y_rev * q_y,
                                                      pdf_z_fwd * q_z, pdf_z_rev * q_z)
    cos_y, cos_z = jnp.abs(dot(y.n, w)), jnp.abs(dot(z.n, w))   # geometric: G, area densities
    if medium:      # no cosine at a medium vertex
        cos_y, cos_z = jnp.where(y_m, 1.0, cos_y), jnp.where(z_m, 1.0, cos_z)
    ok = ok & (d2 > 0)
    if reciprocal:
        inv_d2 = 1.0 / jnp.where(ok, d2, 1.0)
        over_d2 = lambda x: x * inv_d2                              # noqa: E731
        to_area = lambda pdf, cos: pdf * cos * inv_d2               # noqa: E731
    else:
        over_d2 = lambda x: x / jnp.where(ok, d2, 1.0)              # noqa: E731
        to_area = lambda pdf, cos: convert_density(pdf, d2, cos, True)  # noqa: E731
    g_value = over_d2(cos_y * cos_z)                   # G without visibility
    if y.ns is not None:
        # the value's cosines are the shading normals' (pbrt-v4's G), and y, a light vertex,
        # takes Veach's adjoint correction
        corr = bsdf.adjoint_correction(y.ns, y.n, y.wo, w)
        cs_y, cs_z = jnp.abs(dot(y.ns, w)), jnp.abs(dot(z.ns, w))
        if medium:
            corr = jnp.where(y_m, 1.0, corr)
            cs_y, cs_z = jnp.where(y_m, 1.0, cs_y), jnp.where(z_m, 1.0, cs_z)
        f_y = f_y * corr
        g_value = over_d2(cs_y * cs_z)
    value = where(ok, y.beta * f_y * f_z * z.beta * g_value, V3.full(0.0, d2))
    pdf_z_from_y, pdf_y_from_z = to_area(pdf_y_fwd, cos_z), to_area(pdf_z_fwd, cos_y)
    shadow = geometry.shadow_ray(y.p, y.n, w, dist)
    if medium:      # T(d) in the value; p_dist of the reached vertex's kind in the densities
        value = value * transmittance(scene, dist, shadow, ok & (max_component(value) > 0),
                                      segment)
        pdf_z_from_y = pdf_z_from_y * segment_density(scene, d2, z_m, segment)
        pdf_y_from_z = pdf_y_from_z * segment_density(scene, d2, y_m, segment)
    return VertexConnection(value, shadow, pdf_z_from_y, pdf_y_from_z, pdf_y_rev, pdf_z_rev)


# --- t = 1: a light vertex joined to the pinhole -------------------------------------------------

class CameraConnection(NamedTuple):
    pixel: Array       # flat pixel index (-1 outside the frame)
    value: V3          # unweighted contribution if unoccluded
    shadow: tuple      # (origin, direction, t_max) of the shadow ray towards the pinhole
    pdf_cam: Array     # camera's area density for y_{s-1} (its pdf_rev under this strategy)
    pdf_y_rev: Array   # BSDF solid-angle density at y_{s-1} from the camera towards y_{s-2}
    ok: Array


def connect_camera(scene: Scene, y: Vertices) -> CameraConnection:
    """Connect vertices y (any array shape; surface, or medium vertices in a medium scene) to
    the pinhole (strategy t = 1). In a medium the camera sits in it: the value takes T(d)
    (:func:`transmittance`), a medium vertex the phase function and no cosine, and the camera's
    area density of y the p_dist of y's kind (p(d) or P(d))."""
    cam = scene.camera
    kinds = scene.materials.kinds
    proj = camera.project(cam, y.p)
    w = proj.wi                                  # from y towards the pinhole
    mp = bsdf.lookup_specialised(scene.materials, y.material, y.uv)
    ny = shading(y)
    f, _ = bsdf.evaluate(kinds, mp, ny, y.wo, w, mode=bsdf.IMPORTANCE)   # a light vertex
    _, pdf_y_rev = bsdf.evaluate(kinds, mp, ny, w, y.wo)
    cos_y = jnp.abs(dot(y.n, w))     # geometric: the camera's area density of y
    cos_f = cos_y                    # the cosine of the value: the shading normal's
    if y.ns is not None:             # (pbrt-v4's BDPT), with Veach's adjoint correction
        corr = bsdf.adjoint_correction(y.ns, y.n, y.wo, w)
        cos_f = jnp.abs(dot(y.ns, w))
        if scene.has_medium:
            corr, cos_f = jnp.where(y.in_medium, 1.0, corr), jnp.where(y.in_medium, 1.0, cos_f)
        f = f * corr
    if scene.has_medium:             # a medium vertex: the phase function, no cosine
        p_y = phase_value(scene, -y.wo, w, y.medium)
        f = where(y.in_medium, V3(p_y, p_y, p_y), f)
        pdf_y_rev = jnp.where(y.in_medium, p_y, pdf_y_rev)
        cos_y = jnp.where(y.in_medium, 1.0, cos_y)
        if y.ns is None:
            cos_f = cos_y
    d2 = proj.dist * proj.dist
    inv_d2 = jnp.where(d2 > 0, 1.0 / jnp.where(d2 > 0, d2, 1.0), 0.0)
    cos_cam = -dot(w, cam.forward)
    # W_e / p(pinhole as seen from y) with p = d^2 / cos_cam (pbrt's Camera::SampleWi)
    we_term = proj.importance * cos_cam * inv_d2
    ok = y.valid & ~y.delta & proj.visible
    value = where(ok, y.beta * f * (cos_f * we_term), V3.full(0.0, cos_y))
    W, H = cam.width, cam.height
    ix = jnp.clip(jnp.floor(proj.px).astype(jnp.int32), 0, W - 1)
    iy = jnp.clip(jnp.floor(proj.py).astype(jnp.int32), 0, H - 1)
    pixel = jnp.where(ok, iy * W + ix, -1)
    shadow = geometry.shadow_ray(y.p, y.n, w, proj.dist)
    pdf_cam = jnp.where(ok, proj.pdf_dir * cos_y * inv_d2, 0.0)
    if scene.has_medium:
        segment = segment_medium(scene, y, w)
        value = value * transmittance(scene, proj.dist, shadow, ok & (max_component(value) > 0),
                                      segment)
        pdf_cam = pdf_cam * segment_density(scene, d2, y.in_medium, segment)
    return CameraConnection(pixel, value, shadow, pdf_cam, pdf_y_rev, ok)


# --- transmittance along a connection ------------------------------------------------------------

def transmittance(scene: Scene, dist: Array, shadow: tuple, active: Array,
                  medium: Array | None = None) -> V3:
    """T(d) of a connection or light sample of length ``dist`` (inf towards an infinite light)
    in a scene with a medium: exp(-sigma_t d) per channel in a homogeneous medium (that of ids
    ``medium`` in scenes with bounded media), ratio tracking's unbiased estimate along the
    ``shadow`` ray in a grid medium (:func:`shadow_transmittance`; 1 where not ``active``; a
    bounded grid's lanes only, where ``medium`` is its id)."""
    if not scene.has_grid_medium:
        return media.transmittance(medium_parameters(scene, medium).sigma_t, dist)
    in_grid = medium_interfaces.in_grid(scene, medium)
    tracked = shadow_transmittance(scene, shadow, active, medium)
    if in_grid is None:
        return tracked
    return where(in_grid, tracked,
                 media.transmittance(medium_parameters(scene, medium).sigma_t, dist))


def shadow_transmittance(scene: Scene, shadow: tuple, active: Array,
                         medium: Array | None = None) -> V3:
    """Ratio tracking's estimate of the grid medium's transmittance along a shadow ray (origin,
    direction of any length, t_max; :func:`jgi.physics.geometry.shadow_ray`) for lanes
    ``active`` (1 elsewhere; with bounded grids, the lanes whose ids ``medium`` are a grid's,
    each tracked in its own), on a stream hashed from the ray itself
    (:func:`jgi.core.rng.ray_key`): the ray is random, so the stream is fresh for every
    connection and the same for a connection however it is reached (BDPT's strategies and
    MMLT's single one), with no key to carry from the subpaths. Not differentiated (the grid
    is held constant: :mod:`jgi.physics.grid_media`)."""
    o, d, t_max = shadow
    key = rng.ray_key(o, d, rng.SALTS["ratio_tracking"])
    return medium_interfaces.transmittance(scene, medium, o, d, t_max, active, key)


# --- shadow rays ----------------------------------------------------------------------------------

def occluded_many(scene: Scene, rays: list[tuple]) -> list[Array]:
    """One any-hit query for several batches of shadow rays (one kernel, not one per batch)."""
    shapes = [o.x.shape for o, _, _ in rays]
    flat = lambda a: a.reshape(-1)  # noqa: E731
    o = V3(*(jnp.concatenate([flat(r[0][c]) for r in rays]) for c in range(3)))
    d = V3(*(jnp.concatenate([flat(r[1][c]) for r in rays]) for c in range(3)))
    t = jnp.concatenate([flat(jnp.broadcast_to(r[2], s)) for r, s in zip(rays, shapes)])
    o, d, t = materialize((o, d, t))   # one buffer, read by every primitive test
    occ = geometry.occluded(scene, o, d, t)
    out, i = [], 0
    for s in shapes:
        n = int(np.prod(s))
        out.append(occ[i:i + n].reshape(s))
        i += n
    return out
