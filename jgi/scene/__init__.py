"""The scene: immutable pytree tables (:mod:`.tables`), their builder (:mod:`.builder`), loading
from files (:mod:`.files`: jgi TOML, Mitsuba 3 XML, pbrt-v4), the built-in scenes
(:mod:`.builtin`) and the importers.

The scene types are re-exported here: ``from jgi.scene import Scene, SceneBuilder, DIFFUSE``."""

from .builder import SceneBuilder, SceneError, light_power, luminance_np
from .tables import (
                   AREA_CYLINDER,
                   AREA_DISK,
                   AREA_QUAD,
                   AREA_SPHERE,
                   AREA_TRIANGLE,
                   BECKMANN,
                   BVH_MIN_TRIANGLES,
                   DELTA_DIRECTION_KINDS,
                   DELTA_POSITION_KINDS,
                   DIELECTRIC,
                   DIFFUSE,
                   DIRECTIONAL,
                   ENVIRONMENT,
                   GGX,
                   LIGHT_KIND_NAMES,
                   MATERIAL_KINDS,
                   MICROFACET_DISTRIBUTIONS,
                   MIRROR,
                   NAMED_METALS,
                   PHONG,
                   PLASTIC,
                   POINT,
                   ROUGH_CONDUCTOR,
                   ROUGH_DIELECTRIC,
                   ROUGH_KINDS,
                   ROUGH_PLASTIC,
                   SPOT,
                   Boxes,
                   Camera,
                   Cylinders,
                   Disks,
                   Lights,
                   Materials,
                   Quads,
                   Rects,
                   Scene,
                   Spheres,
                   Triangles,
                   with_bvh,
)

__all__ = ["AREA_CYLINDER", "AREA_DISK", "AREA_QUAD", "AREA_SPHERE", "AREA_TRIANGLE", "BECKMANN", "BVH_MIN_TRIANGLES",
           "DELTA_DIRECTION_KINDS", "DELTA_POSITION_KINDS", "DIELECTRIC", "DIFFUSE",
           "DIRECTIONAL", "ENVIRONMENT", "GGX", "LIGHT_KIND_NAMES", "MATERIAL_KINDS",
           "MICROFACET_DISTRIBUTIONS", "MIRROR", "NAMED_METALS", "PHONG", "POINT",
           "ROUGH_CONDUCTOR", "ROUGH_DIELECTRIC", "ROUGH_KINDS", "ROUGH_PLASTIC", "PLASTIC", "SPOT", "Boxes", "Camera", "Cylinders", "Disks", "Lights", "Materials", "Quads", "Rects", "Scene",
           "SceneBuilder", "SceneError", "Spheres", "Triangles", "light_power", "luminance_np",
           "with_bvh"]
