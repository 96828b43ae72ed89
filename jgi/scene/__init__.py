"""The scene: immutable pytree tables (:mod:`.data`), loading from files (:mod:`.files`:
jgi TOML, Mitsuba 3 XML, pbrt-v4), the built-in scenes (:mod:`.builtin`) and the importers.

The scene types are re-exported here: ``from jgi.scene import Scene, SceneBuilder, DIFFUSE``."""

from .data import (
                   AREA_QUAD,
                   AREA_SPHERE,
                   AREA_TRIANGLE,
                   BVH_MIN_TRIANGLES,
                   DELTA_DIRECTION_KINDS,
                   DELTA_POSITION_KINDS,
                   DIELECTRIC,
                   DIFFUSE,
                   DIRECTIONAL,
                   ENVIRONMENT,
                   LIGHT_KIND_NAMES,
                   MATERIAL_KINDS,
                   MIRROR,
                   PHONG,
                   POINT,
                   SPOT,
                   Boxes,
                   Camera,
                   Lights,
                   Materials,
                   Quads,
                   Rects,
                   Scene,
                   SceneBuilder,
                   SceneError,
                   Spheres,
                   Triangles,
                   light_power,
                   luminance_np,
                   with_bvh,
)

__all__ = ["AREA_QUAD", "AREA_SPHERE", "AREA_TRIANGLE", "BVH_MIN_TRIANGLES",
           "DELTA_DIRECTION_KINDS", "DELTA_POSITION_KINDS", "DIELECTRIC", "DIFFUSE",
           "DIRECTIONAL", "ENVIRONMENT", "LIGHT_KIND_NAMES", "MATERIAL_KINDS", "MIRROR", "PHONG",
           "POINT", "SPOT", "Boxes", "Camera", "Lights", "Materials", "Quads", "Rects", "Scene",
           "SceneBuilder", "SceneError", "Spheres", "Triangles", "light_power", "luminance_np",
           "with_bvh"]
