"""Media bounded by shapes: which homogeneous medium a ray travels in.

A scene may hold, besides the medium around every shape (``Scene.medium``, or vacuum), media
bounded by shapes (``Scene.bounded_media``): a glass ball full of milk, a lamp in a smoke-filled
dome. Their surfaces' materials carry a medium interface (``Scene.medium_interfaces``: Mitsuba's
``interior`` / ``exterior``, pbrt-v4's ``MediumInterface``), and every ray, path vertex and
connection carries a medium id (0: the scene's own medium; k >= 1: bounded medium k - 1):

* a camera ray, and a light's first segment, start in medium 0;
* a ray leaving a surface whose material bounds media travels in its ``exterior`` if it leaves
  on the side of the geometric normal, else in its ``interior`` (so a refraction or diffuse
  transmission crosses into the other medium and a reflection stays); a surface that bounds no
  medium, and a medium vertex, leave the ray in the medium it arrived in (Mitsuba 3's and
  pbrt-v4's rule for shapes that are no medium transition);
* a connection or shadow ray between two vertices travels in the medium on its side of its
  first vertex (:func:`leaving`). A boundary surface between it and its other end would occlude
  it: a bounded medium's surface scatters (a dielectric, a diffuse shell), it is not a null
  interface, so no unoccluded segment crosses one.

Each homogeneous bounded medium's maths is that of :mod:`jgi.physics.media`, applied segment by
segment with the parameters looked up per lane (:func:`parameters`). Bounded media may also be
density grids (``Scene.bounded_grids``, ids after the homogeneous ones): lanes in one
(:func:`in_grid`) are tracked in their own grid (:func:`free_flight`, :func:`transmittance`:
:mod:`jgi.physics.grid_media` once per grid, on that grid's lanes), and each grid's row of the
table is a vacuum with the grid's phase function, so that the homogeneous code leaves those
lanes alone. Scenes without bounded media carry no ids (None) and compile to the programs they
compiled to before; a scene with one bounded grid to those it compiled to before there could be
several.

The scene's own medium may also be several density grids (``Scene.medium`` a tuple: disjoint
volumes in vacuum, two clouds, Mitsuba's shapes with a ``null`` bsdf). Their extinction is the
sum of theirs, so a flight through them is tracked in each on a stream of its own and the
nearest real collision taken (:func:`free_flight`), and a transmittance is the product of
theirs. They share one phase function (the builder checks it), so a medium vertex needs no
record of the volume it lies in: the albedo entered the flight's weight where it collided.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from ..core import rng
from ..core.vec import V3, dot
from ..scene.tables import GridMedium, Medium, Scene
from .grid_media import GridFlight, extent, held_constant, ratio_tracking, sample_free_flight
from .grid_media import scattering as grid_scattering

AMBIENT = 0   # the id of the scene's own medium (Scene.medium, or vacuum)


def start(scene: Scene, like: Array) -> Array | None:
    """The medium id of a camera ray or a light's first segment (the scene's own medium), shaped
    like ``like``; None in a scene without bounded media."""
    if not scene.has_bounded_media:
        return None
    return jnp.full(like.shape, AMBIENT, jnp.int32)


def grids(scene: Scene) -> tuple[GridMedium, ...]:
    """The scene's density grids: its own medium (one), or those bounded by shapes (the g-th
    has id ``grid_id(scene) + g``); () in a scene without."""
    if isinstance(scene.medium, GridMedium):
        return (scene.medium,)
    if isinstance(scene.medium, tuple):
        return scene.medium
    return scene.bounded_grids or ()


def own_medium(scene: Scene) -> Medium | GridMedium | None:
    """The scene's own medium; its first volume where it is several (they share the phase
    function, the part of it a medium vertex reads)."""
    return scene.medium[0] if isinstance(scene.medium, tuple) else scene.medium


def _volumes(scene: Scene, medium_id: Array | None) -> tuple[GridMedium, ...] | None:
    """The scene's own volumes where it has several and the lanes travel in them (held
    constant), else None."""
    if not isinstance(scene.medium, tuple) or in_grid(scene, medium_id) is not None:
        return None
    return held_constant(scene.medium)


def _volume_key(key: Array, v: int) -> Array:
    """The stream of volume v's tracking in a flight through several (v = 0: the flight's own,
    as where there is one volume)."""
    return key if v == 0 else rng.derive(key, rng.SALTS["grid_volume"] + v)


def held_grid(scene: Scene) -> GridMedium:
    """The scene's first density grid held constant (rendered, not differentiated:
    :func:`jgi.physics.grid_media.held_constant`): where the grid is the scene's own medium,
    the one every lane travels in (its phase function)."""
    return held_constant(grids(scene)[0])


def grid_id(scene: Scene) -> int:
    """The medium id of the first bounded grid: one after the homogeneous bounded media
    (static)."""
    bounded = scene.bounded_media
    return 1 + (0 if bounded is None else int(bounded.g.shape[0]))


def in_grid(scene: Scene, medium_id: Array | None) -> Array | None:
    """Which lanes travel in a density grid: None where the grid is the scene's own medium
    (every lane: it fills its box, vacuum around) or there is none, the lanes whose medium id
    is a bounded grid's otherwise."""
    if scene.bounded_grids is None:
        return None
    return medium_id >= grid_id(scene)


def _each_grid(scene: Scene, medium_id: Array | None, track):
    """``track(grid, mine)`` for every grid of the scene (held constant), ``mine`` its lanes
    (None: the scene's own grid, every lane), merged lane by lane: the lanes of grid g take its
    result, lanes in no grid the first grid's."""
    every = held_constant(grids(scene))
    if in_grid(scene, medium_id) is None:
        return track(every[0], None)
    first, out = grid_id(scene), None
    for g, grid in enumerate(every):
        mine = medium_id == first + g
        result = track(grid, mine)
        out = result if out is None else jax.tree_util.tree_map(
            lambda a, b, m=mine: jnp.where(m, a, b), result, out)
    return out


def _only(active: Array, mine: Array | None) -> Array:
    return active if mine is None else active & mine


def free_flight(scene: Scene, medium_id: Array | None, o: V3, d: V3, t_max: Array,
                throughput: V3, active: Array, key: Array) -> GridFlight:
    """Spectral tracking (:func:`jgi.physics.grid_media.sample_free_flight`) of the lanes
    ``active`` that travel in a density grid, each in its own; the other lanes collide
    nowhere (t = t_max, weight 1)."""
    volumes = _volumes(scene, medium_id)
    if volumes is not None:
        return _first_collision(volumes, o, d, t_max, throughput, active, key)
    return _each_grid(scene, medium_id, lambda grid, mine: sample_free_flight(
        grid, o, d, t_max, throughput, _only(active, mine), key))


def _first_collision(volumes: tuple[GridMedium, ...], o: V3, d: V3, t_max: Array,
                     throughput: V3, active: Array, key: Array) -> GridFlight:
    """A flight through several disjoint volumes: each tracked on a stream of its own, the
    nearest real collision taken (the first event of independent processes whose rates add, as
    the volumes' extinctions do). Its weight is the collider's times those of the volumes the ray
    crossed before reaching it without a collision: the volumes are disjoint and convex, so each
    other volume's interval lies wholly before the collision (entered before it, crossed) or
    wholly after (never reached; its tracking is discarded). Each tracking's spectral
    probabilities read the flight's throughput, not the one after the volumes before it: any
    positive choice keeps the weights unbiased."""
    flights = [sample_free_flight(v, o, d, t_max, throughput, active, _volume_key(key, i))
               for i, v in enumerate(volumes)]
    t_first, scattered = flights[0].t, flights[0].scattered
    for f in flights[1:]:
        t_first, scattered = jnp.minimum(t_first, f.t), scattered | f.scattered
    weight, taken = V3(*(jnp.ones_like(t_first) for _ in range(3))), jnp.zeros_like(scattered)
    for v, f in zip(volumes, flights):
        collider = f.scattered & (f.t <= t_first) & ~taken
        crossed = ~f.scattered & (extent(v, o, d)[0] < t_first)
        taken = taken | collider
        weight = V3(*(jnp.where(collider | crossed, w * fw, w) for w, fw in zip(weight, f.weight)))
    return GridFlight(t_first, scattered, weight)


def transmittance(scene: Scene, medium_id: Array | None, o: V3, d: V3, t_max: Array,
                  active: Array, key: Array) -> V3:
    """Ratio tracking's transmittance estimate (:func:`jgi.physics.grid_media.ratio_tracking`)
    along o + t d, t in [0, t_max], for the lanes ``active`` that travel in a density grid,
    each in its own; 1 on the other lanes."""
    volumes = _volumes(scene, medium_id)
    if volumes is not None:   # the product of the volumes' own
        out = None
        for i, v in enumerate(volumes):
            T = ratio_tracking(v, o, d, t_max, active, _volume_key(key, i))
            out = T if out is None else V3(*(a * b for a, b in zip(out, T)))
        return out
    return _each_grid(scene, medium_id, lambda grid, mine: ratio_tracking(
        grid, o, d, t_max, _only(active, mine), key))


def scattering(scene: Scene, medium_id: Array | None, p: V3) -> V3:
    """sigma_s,c of each lane's density grid at points p (lanes in no grid: the first
    grid's)."""
    volumes = _volumes(scene, medium_id)
    if volumes is not None:   # the sum of the volumes' own (each 0 outside itself)
        out = None
        for v in volumes:
            s = grid_scattering(v, p)
            out = s if out is None else V3(*(a + b for a, b in zip(out, s)))
        return out
    return _each_grid(scene, medium_id, lambda grid, _: grid_scattering(grid, p))


def mean_extinction(scene: Scene, medium_id: Array | None) -> V3:
    """Each lane's density grid's extinction averaged over its voxels, RGB (sigma_t times the
    mean density; lanes in no grid: the first grid's): a homogeneous stand-in. Scalars where
    the grid is the scene's own (``medium_id`` None), shaped like ``medium_id`` otherwise."""
    def mean(grid, mine):
        d = jnp.mean(grid.density)
        return V3(*(d * c if mine is None else jnp.broadcast_to(d * c, mine.shape)
                    for c in grid.sigma_t))
    volumes = _volumes(scene, medium_id)
    if volumes is not None:   # several volumes: their means weighted by their boxes' volumes
        means, sizes = [mean(v, None) for v in volumes], [_box_volume(v) for v in volumes]
        return V3(*(sum(m[c] * s for m, s in zip(means, sizes)) / sum(sizes) for c in range(3)))
    return _each_grid(scene, medium_id, mean)


def _box_volume(grid: GridMedium) -> Array:
    """The world volume of a grid's box (its frame's box over |det| of the world-to-frame
    map)."""
    size = (grid.hi.x - grid.lo.x) * (grid.hi.y - grid.lo.y) * (grid.hi.z - grid.lo.z)
    if grid.to_local is None:
        return size
    return size / jnp.abs(jnp.linalg.det(grid.to_local[:, :3]))


def table(scene: Scene) -> Medium:
    """Every medium of the scene, id by id ([K + 1 + G] per field, G bounded grids): the
    scene's own (vacuum: zero extinction, albedo and g), the bounded homogeneous ones, then a
    row per bounded grid: a vacuum with the grid's g (its lanes are tracked, not sampled here;
    their phase function is the grid's)."""
    own = scene.medium
    zero = jnp.zeros((1,), jnp.float32)
    vacuum = (V3(zero, zero, zero), V3(zero, zero, zero), zero)
    rows = [vacuum if own is None else tuple(jax_row(x) for x in (own.sigma_t, own.albedo,
                                                                  own.g))]
    if scene.bounded_media is not None:
        b = scene.bounded_media
        f = lambda v: V3(*(jnp.asarray(c, jnp.float32) for c in v))   # noqa: E731
        rows.append((f(b.sigma_t), f(b.albedo), jnp.asarray(b.g, jnp.float32)))
    for grid in scene.bounded_grids or ():
        rows.append(vacuum[:2] + (jax_row(grid.g),))
    cat = lambda parts: jnp.concatenate(parts)   # noqa: E731
    return Medium(V3(*(cat([r[0][c] for r in rows]) for c in range(3))),
                  V3(*(cat([r[1][c] for r in rows]) for c in range(3))),
                  cat([r[2] for r in rows]))


def jax_row(x):
    """A scalar medium parameter (or V3 of them) as one-row arrays."""
    if isinstance(x, V3):
        return V3(*(jnp.reshape(jnp.asarray(c, jnp.float32), (1,)) for c in x))
    return jnp.reshape(jnp.asarray(x, jnp.float32), (1,))


def parameters(scene: Scene, medium_id: Array | None) -> Medium:
    """The homogeneous medium each lane travels in (fields shaped like ``medium_id``); the
    scene's own medium, unchanged, in a scene without bounded media (``medium_id`` None)."""
    if medium_id is None or not scene.has_bounded_media:
        return own_medium(scene)
    t = table(scene)
    pick = lambda a: a[medium_id]   # noqa: E731
    return Medium(V3(*(pick(c) for c in t.sigma_t)), V3(*(pick(c) for c in t.albedo)),
                  pick(t.g))


def leaving(scene: Scene, medium_id: Array | None, material: Array, n: V3, w: V3,
            in_medium: Array | None = None) -> Array | None:
    """The medium id of a ray leaving a vertex in direction w: at a surface whose material bounds
    media, its exterior on the side of the geometric normal n and its interior on the other;
    elsewhere (a surface that bounds none, a medium vertex where ``in_medium``) the id the
    vertex was reached in, ``medium_id``. None in a scene without bounded media."""
    if not scene.has_bounded_media:
        return None
    faces = scene.medium_interfaces
    m = jnp.maximum(material, 0)
    interior, exterior = faces.interior[m], faces.exterior[m]
    crossed = jnp.where(dot(n, w) > 0, exterior, interior)
    out = jnp.where(interior >= 0, crossed, medium_id)
    if in_medium is not None:
        out = jnp.where(in_medium, medium_id, out)
    return out.astype(jnp.int32)
