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

Each bounded medium is homogeneous, so the maths of :mod:`jgi.physics.media` applies segment
by segment with the parameters looked up per lane (:func:`parameters`), but for one that may be
a density grid (``Scene.bounded_grid``): lanes in it (:func:`in_grid`) are tracked
(:mod:`jgi.physics.grid_media`), and its row of the table is a vacuum with the grid's phase
function, so that the homogeneous code leaves those lanes alone. Scenes without bounded media
carry no ids (None) and compile to the programs they compiled to before.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ..core.vec import V3, dot
from ..scene.tables import GridMedium, Medium, Scene
from .grid_media import held_constant

AMBIENT = 0   # the id of the scene's own medium (Scene.medium, or vacuum)


def start(scene: Scene, like: Array) -> Array | None:
    """The medium id of a camera ray or a light's first segment (the scene's own medium), shaped
    like ``like``; None in a scene without bounded media."""
    if not scene.has_bounded_media:
        return None
    return jnp.full(like.shape, AMBIENT, jnp.int32)


def grid(scene: Scene) -> GridMedium | None:
    """The scene's density grid: its own medium, or the one bounded by shapes; None."""
    return scene.medium if isinstance(scene.medium, GridMedium) else scene.bounded_grid


def held_grid(scene: Scene):
    """The scene's density grid held constant (rendered, not differentiated:
    :func:`jgi.physics.grid_media.held_constant`)."""
    return held_constant(grid(scene))


def grid_id(scene: Scene) -> int:
    """The medium id of the bounded grid: one after the homogeneous bounded media (static)."""
    bounded = scene.bounded_media
    return 1 + (0 if bounded is None else int(bounded.g.shape[0]))


def in_grid(scene: Scene, medium_id: Array | None) -> Array | None:
    """Which lanes travel in the density grid: None where the grid is the scene's own medium
    (every lane: it fills its box, vacuum around), the lanes whose medium id is the bounded
    grid's otherwise."""
    if scene.bounded_grid is None:
        return None
    return medium_id == grid_id(scene)


def table(scene: Scene) -> Medium:
    """Every medium of the scene, id by id ([K + 1] per field, or K + 2 with a bounded grid):
    the scene's own (vacuum: zero extinction, albedo and g), the bounded homogeneous ones, then
    the bounded grid's row: a vacuum with the grid's g (its lanes are tracked, not sampled
    here; their phase function is the grid's)."""
    own = scene.medium
    zero = jnp.zeros((1,), jnp.float32)
    vacuum = (V3(zero, zero, zero), V3(zero, zero, zero), zero)
    rows = [vacuum if own is None else tuple(jax_row(x) for x in (own.sigma_t, own.albedo,
                                                                  own.g))]
    if scene.bounded_media is not None:
        b = scene.bounded_media
        f = lambda v: V3(*(jnp.asarray(c, jnp.float32) for c in v))   # noqa: E731
        rows.append((f(b.sigma_t), f(b.albedo), jnp.asarray(b.g, jnp.float32)))
    if scene.bounded_grid is not None:
        rows.append(vacuum[:2] + (jax_row(scene.bounded_grid.g),))
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
        return scene.medium
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
