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

Each medium is homogeneous, so the maths of :mod:`jgi.physics.media` applies segment by segment,
with the parameters looked up per lane (:func:`parameters`). Scenes without bounded media carry
no ids (None) and compile to the programs they compiled to before.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from ..core.vec import V3, dot
from ..scene.tables import Medium, Scene

AMBIENT = 0   # the id of the scene's own medium (Scene.medium, or vacuum)


def start(scene: Scene, like: Array) -> Array | None:
    """The medium id of a camera ray or a light's first segment (the scene's own medium), shaped
    like ``like``; None in a scene without bounded media."""
    if not scene.has_bounded_media:
        return None
    return jnp.full(like.shape, AMBIENT, jnp.int32)


def table(scene: Scene) -> Medium:
    """Every medium of the scene, id by id ([K + 1] per field): the scene's own (vacuum: zero
    extinction, albedo and g), then the bounded ones."""
    own, bounded = scene.medium, scene.bounded_media
    if own is None:
        zero = jnp.zeros((1,), jnp.float32)
        own_rows = (V3(zero, zero, zero), V3(zero, zero, zero), zero)
    else:
        own_rows = tuple(jax_row(x) for x in (own.sigma_t, own.albedo, own.g))
    cat = lambda a, b: jnp.concatenate([a, jnp.asarray(b, jnp.float32)])   # noqa: E731
    return Medium(V3(*(cat(a, b) for a, b in zip(own_rows[0], bounded.sigma_t))),
                  V3(*(cat(a, b) for a, b in zip(own_rows[1], bounded.albedo))),
                  cat(own_rows[2], bounded.g))


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
