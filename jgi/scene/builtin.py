"""Built-in scenes, by name: ``jgi.scenes.get("cornell_box")`` or ``jgi.load_scene(name)``.

* ``cornell_box``: the classic box, with the geometry, albedos and light of Mitsuba 3's
  ``cornell_box()`` (so benchmarks compare like with like).
* ``cornell_box_fog``: the same box filled with a homogeneous fog (participating medium).
* ``cornell_box_caustics``: the same room with a mirror sphere and a glass sphere (caustics).
* ``glass_sphere``: a glass sphere on a diffuse plane under a small area light.
* ``mirror_caustic``: a small lamp facing up at a mirror ceiling, so the floor is lit only by
  paths E D S L (a mirror caustic): the test scene for Veach's caustic perturbation.
* ``metal_ring``: a mirror ring (open cylinder, a trimesh mesh) on a plane: the cardioid caustic.
* ``veach_plates``: Veach's MIS scene, four Phong plates of decreasing roughness lit by four
  spherical lights of decreasing size and increasing radiance (equal power).
* ``veach_plates_ggx``: the same with GGX rough-conductor plates (alpha 0.1 .. 0.005), as in
  Mitsuba's documentation.
* ``cornell_box_rough``: the Cornell room with one object of each microfacet material (rough
  conductor, isotropic and anisotropic; rough dielectric; rough plastic).
* ``furnace``: a closed box whose walls all emit L_e and reflect with albedo rho, the camera
  inside: radiance is L_e (1 + rho + ... + rho^(D-1)) for max depth D.
* ``cornell_box_textured``: the Cornell room with a checkerboard floor, a bitmap-textured
  diffuse sphere, a Phong sphere with a textured specular colour and a rough conductor with a
  textured roughness (every textured parameter and texture kind).
* ``point_light_plane``: a point light of intensity I at height h over a diffuse plane: the
  radiance is (rho / pi) I cos(theta) / d^2 at every point.
* ``smallvcm_box``: SmallVCM's Cornell box (its ``LoadCornellBox`` with the ceiling light box
  and both small spheres: a mirror and an index-1.6 glass ball), its geometry, one-sided
  materials, light and camera, so that benchmarks run jgi and SmallVCM on the same scene.
"""

from __future__ import annotations

import numpy as np

from ..core import transform as xf
from .builder import SceneBuilder
from .tables import Scene

WHITE = (0.885809, 0.698859, 0.666422)
GREEN = (0.105421, 0.37798, 0.076425)
RED = (0.570068, 0.0430135, 0.0443706)
CORNELL_LIGHT = (18.387, 13.9873, 6.75357)


def cornell_room(b: SceneBuilder, resolution: int, floor: str = "white",
                 light: str = "area") -> None:
    """Add the room of Mitsuba 3's ``cornell_box()`` to ``b``: its three materials ("white",
    "green", "red"), five walls, the ceiling light and the camera, without the two blocks.
    ``floor``: the floor's material (defined by the caller unless "white"); ``light``: "area"
    (Mitsuba's) or "point" (a point light 0.24 below it whose intensity is the area light's
    L_e A, its radiant intensity along the normal)."""
    b.material("white", "diffuse", diffuse=WHITE)
    b.material("green", "diffuse", diffuse=GREEN)
    b.material("red", "diffuse", diffuse=RED)
    T, R, S = xf.translate, xf.rotate, xf.scale
    if light == "area":
        b.rectangle(T([0, 0.99, 0.01]) @ R([1, 0, 0], 90) @ S([0.23, 0.19, 0.19]), "white",
                    emission=CORNELL_LIGHT)
    elif light == "point":
        area = (2 * 0.23) * (2 * 0.19)
        b.point_light((0.0, 0.75, 0.01), tuple(c * area for c in CORNELL_LIGHT))
    else:
        raise ValueError(f"cornell_room: light {light!r}; allowed: area, point")
    b.rectangle(T([0, -1, 0]) @ R([1, 0, 0], -90), floor)
    b.rectangle(T([0, 1, 0]) @ R([1, 0, 0], 90), "white")
    b.rectangle(T([0, 0, -1]), "white")
    b.rectangle(T([1, 0, 0]) @ R([0, 1, 0], -90), "green")
    b.rectangle(T([-1, 0, 0]) @ R([0, 1, 0], 90), "red")
    b.camera(position=(0, 0, 3.9), look_at=(0, 0, 0), up=(0, 1, 0), fov=39.3077,
             width=resolution, height=resolution, fov_axis="smaller")


def cornell_box(resolution: int = 256) -> Scene:
    b = SceneBuilder("cornell_box")
    cornell_room(b, resolution)
    T, R, S = xf.translate, xf.rotate, xf.scale
    b.cube(T([0.335, -0.7, 0.38]) @ R([0, 1, 0], -17) @ S(0.3), "white")
    b.cube(T([-0.33, -0.4, -0.28]) @ R([0, 1, 0], 18.25) @ S([0.3, 0.61, 0.3]), "white")
    return b.build()


def cornell_box_fog(resolution: int = 256, sigma_t=0.6, albedo=0.8, g=0.0) -> Scene:
    """The Cornell box (:func:`cornell_box`) filled with a homogeneous fog: RGB-constant
    extinction ``sigma_t`` (about 1.2 mean free paths across the 2-unit room at 0.6), albedo
    and Henyey-Greenstein g. The camera and every surface sit in the fog."""
    b = SceneBuilder("cornell_box_fog")
    cornell_room(b, resolution)
    T, R, S = xf.translate, xf.rotate, xf.scale
    b.cube(T([0.335, -0.7, 0.38]) @ R([0, 1, 0], -17) @ S(0.3), "white")
    b.cube(T([-0.33, -0.4, -0.28]) @ R([0, 1, 0], 18.25) @ S([0.3, 0.61, 0.3]), "white")
    b.medium(sigma_t=sigma_t, albedo=albedo, g=g)
    return b.build()


def milk_ball(resolution: int = 256, sigma_t=(2.0, 3.0, 5.0), albedo=0.6, g=0.4,
              haze: float = 0.0, smoke: bool = False) -> Scene:
    """A medium bounded by a shape, backlit: a rough glass ball (ior 1.33, GGX alpha 0.2,
    radius 0.8) holding milk-like fog (RGB extinction ``sigma_t``, 3.2-8 mean free paths
    across the ball, albedo, Henyey-Greenstein g), on a grey floor, in front of a large
    emitter (radiance 1) that faces the camera: what reaches the camera through the ball is
    light the milk let through or scattered towards it. ``haze`` > 0 fills the space around
    the ball with a thin grey medium (extinction ``haze``, albedo 0.8), so rays cross between
    two media. The rough interface lets every estimator connect to the ball's surface, and
    through it to the milk. ``smoke``: the ball holds a heterogeneous medium instead, a density
    grid over the ball's box (a ramp along x times a blob, 0.05 to 1.7) times ``sigma_t``."""
    b = SceneBuilder("milk_ball")
    b.material("floor", "diffuse", diffuse=(0.5, 0.5, 0.5))
    b.material("black", "diffuse", diffuse=(0.0, 0.0, 0.0))
    b.material("rough_glass", "roughdielectric", ior=1.33, alpha=0.2)
    if smoke:
        z, y, x = np.meshgrid(*(np.linspace(0, 1, n) for n in (6, 7, 8)), indexing="ij")
        blob = np.exp(-((x - 0.4) ** 2 + (y - 0.5) ** 2 + (z - 0.5) ** 2) / 0.08)
        b.bounded_grid_medium("milk", (0.05 + 1.2 * x * blob + 0.5 * blob).astype(np.float32),
                              (-0.8, -0.8, -0.8), (0.8, 0.8, 0.8), sigma_t=sigma_t,
                              albedo=albedo, g=g)
    else:
        b.bounded_medium("milk", sigma_t=sigma_t, albedo=albedo, g=g)
    b.quad((-4, -0.8, 4), (8, 0, 0), (0, 0, -8), "floor")                         # normal +y
    b.quad((-4, -0.8, -2), (8, 0, 0), (0, 6, 0), "black", (1.0, 1.0, 1.0))        # normal +z
    b.sphere((0.0, 0.0, 0.0), 0.8, b.medium_interface("rough_glass", interior="milk"))
    if haze > 0:
        b.medium(sigma_t=haze, albedo=0.8)
    b.camera(position=(0, 0.6, 4), look_at=(0, 0, 0), fov=40, width=resolution,
             height=resolution)
    return b.build()


def glass_sphere_fog(resolution: int = 256, sigma_t=0.25, albedo=0.9, g=0.3) -> Scene:
    """A volumetric caustic (the case mitsuba3#181 asks for): a glass sphere (ior 1.5, radius
    0.6) in fog under a spot light whose cone (15 degrees) lies within the sphere's silhouette
    (16.7 degrees), over a floor, in front of a back wall. All light below the sphere has
    passed through the glass: the bright cone it focuses into the fog is an L S S M E path
    (M: a medium vertex), which a path tracer cannot sample (its shadow rays stop at the glass
    and a phase-sampled ray never hits the point light): light tracing, BDPT, photon maps
    and beams can. The fog above the sphere is lit directly (single scattering: every
    estimator)."""
    b = SceneBuilder("glass_sphere_fog")
    b.material("floor", "diffuse", diffuse=(0.6, 0.6, 0.6))
    b.material("glass", "dielectric", ior=1.5)
    b.quad((-3, 0, -3), (0, 0, 6), (6, 0, 0), "floor")              # normal +y
    b.quad((-3, 0, -1.5), (6, 0, 0), (0, 4, 0), "floor")            # back wall, normal +z
    b.sphere((0, 1.2, 0), 0.6, "glass")
    b.spot_light((0, 3.2, 0), (0, 0, 0), intensity=(120, 120, 120), cutoff_deg=15.0,
                 falloff_deg=12.0)
    b.medium(sigma_t=sigma_t, albedo=albedo, g=g)
    b.camera(position=(0, 1.4, 5.5), look_at=(0, 1.0, 0), fov=40, width=resolution,
             height=resolution)
    return b.build()


def cornell_box_caustics(resolution: int = 256, light: str = "area") -> Scene:
    """The Cornell room with a mirror and a glass sphere; ``light="point"``: lit by a point
    light (:func:`cornell_room`), so that caustics seen in the spheres (L S D S E) can be
    sampled by no unbiased technique, only by density estimation."""
    b = SceneBuilder("cornell_box_caustics" if light == "area" else "cornell_box_caustics_point")
    cornell_room(b, resolution, light=light)
    b.material("mirror", "mirror", specular=(0.95, 0.95, 0.95))
    b.material("glass", "dielectric", ior=1.5)
    b.sphere((-0.45, -0.65, -0.3), 0.35, "mirror")
    b.sphere((0.45, -0.65, 0.3), 0.35, "glass")
    return b.build()


def cornell_box_caustics_point(resolution: int = 256) -> Scene:
    """:func:`cornell_box_caustics` lit by a point light."""
    return cornell_box_caustics(resolution, light="point")


def stripes_image(size: int = 8) -> np.ndarray:
    """A small linear-RGB test image: horizontal colour bands times a vertical ramp, so that a
    bitmap lookup's orientation, filtering and wrap all show."""
    y, x = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    band = (y * 3) // size
    img = np.zeros((size, size, 3))
    img[..., 0] = np.where(band == 0, 0.8, 0.1)
    img[..., 1] = np.where(band == 1, 0.8, 0.1)
    img[..., 2] = np.where(band == 2, 0.8, 0.1)
    return img * (0.4 + 0.6 * x / (size - 1))[..., None]


def cornell_box_textured(resolution: int = 256) -> Scene:
    """The Cornell room with a checkerboard floor (Mitsuba's checkerboard, 4 x 4 periods) and
    a diffuse sphere carrying a bitmap (:func:`stripes_image`), behind it a Phong sphere with
    a checkerboard specular colour and a GGX rough-conductor sphere with a textured roughness:
    every textured parameter, and both texture kinds, in one scene."""
    b = SceneBuilder("cornell_box_textured")
    b.texture("checks", "checkerboard", color0=(0.8, 0.8, 0.8), color1=(0.15, 0.3, 0.6),
              scale=4)
    b.texture("stripes", "bitmap", data=stripes_image(), scale=(2, 1))
    b.texture("spec", "checkerboard", color0=(0.5, 0.5, 0.5), color1=(0.1, 0.1, 0.1), scale=6)
    b.texture("rough", "checkerboard", color0=(0.05, 0.05, 0.05), color1=(0.4, 0.4, 0.4),
              scale=4)
    b.material("floor", "diffuse", diffuse="checks")
    b.material("striped", "diffuse", diffuse="stripes")
    b.material("plastic", "phong", diffuse=(0.3, 0.3, 0.3), specular="spec", exponent=20.0)
    b.material("metal", "roughconductor", specular=(0.9, 0.9, 0.9), alpha="rough")
    cornell_room(b, resolution, floor="floor")
    b.sphere((0.4, -0.6, 0.2), 0.4, "striped")
    b.sphere((-0.45, -0.7, -0.3), 0.3, "plastic")
    b.sphere((-0.3, 0.2, -0.5), 0.25, "metal")
    return b.build()


def glass_sphere(resolution: int = 256) -> Scene:
    b = SceneBuilder("glass_sphere")
    b.material("floor", "diffuse", diffuse=(0.8, 0.8, 0.8))
    b.material("glass", "dielectric", ior=1.5)
    b.material("lamp", "diffuse", diffuse=(0.0, 0.0, 0.0))
    b.quad((-4, 0, -4), (0, 0, 8), (8, 0, 0), "floor")
    b.sphere((0, 1, 0), 1.0, "glass")
    s = 0.25  # a small square light, facing down
    b.quad((-s + 1.0, 4.0, -s), (2 * s, 0, 0), (0, 0, 2 * s), "lamp",
           emission=(200.0, 200.0, 200.0))
    b.camera(position=(0, 4.5, 7.5), look_at=(0, 0.6, 0), fov=35, width=resolution,
             height=resolution)
    return b.build()


def mirror_caustic(resolution: int = 256) -> Scene:
    b = SceneBuilder("mirror_caustic")
    b.material("floor", "diffuse", diffuse=(0.8, 0.8, 0.8))
    b.material("mirror", "mirror", specular=(0.9, 0.9, 0.9))
    b.material("lamp", "diffuse", diffuse=(0.0, 0.0, 0.0))
    b.quad((-2, 0, -2), (0, 0, 4), (4, 0, 0), "floor")              # normal +y
    b.quad((-2, 2, -2), (4, 0, 0), (0, 0, 4), "mirror")             # normal -y, facing the floor
    s = 0.5  # a square lamp facing up: its light reaches the floor only by the mirror
    b.quad((-s, 0.6, -s), (0, 0, 2 * s), (2 * s, 0, 0), "lamp", emission=(8.0, 8.0, 8.0))
    b.camera(position=(0, 1.2, 4.5), look_at=(0, 0, 0), fov=40, width=resolution,
             height=resolution)
    return b.build()


def metal_ring(resolution: int = 256, segments: int = 96) -> Scene:
    """A thin mirror ring (open cylinder) on a diffuse plane, lit from a low angle."""
    b = SceneBuilder("metal_ring")
    b.material("floor", "diffuse", diffuse=(0.8, 0.8, 0.8))
    b.material("metal", "mirror", specular=(0.95, 0.85, 0.55))
    b.material("lamp", "diffuse", diffuse=(0.0, 0.0, 0.0))
    b.quad((-3, 0, -3), (0, 0, 6), (6, 0, 0), "floor")
    v, f = ring_mesh(radius=1.0, height=0.35, segments=segments)
    b.mesh(v, f, "metal")
    s = 0.15
    b.quad((-s, 2.0, 3.0 - s), (2 * s, 0, 0), (0, 0, 2 * s), "lamp", emission=(300.0, 300.0, 300.0))
    b.camera(position=(0, 3.2, -2.6), look_at=(0, 0, 0.2), fov=40, width=resolution,
             height=resolution)
    return b.build()


def ring_mesh(radius: float, height: float, segments: int):
    """Open cylinder (both faces reflect: the mirror material is two-sided) built with trimesh."""
    import trimesh  # on use: its import costs every start-up 0.4 s

    ann = trimesh.creation.cylinder(radius=radius, height=height, sections=segments)
    # keep only the side wall: drop the caps (faces whose normal is along the axis)
    keep = np.abs(ann.face_normals[:, 2]) < 0.5
    v = np.asarray(ann.vertices)
    f = np.asarray(ann.faces)[keep]
    v = v[:, [0, 2, 1]] + np.array([0.0, height / 2, 0.0])  # axis z -> y, standing on the floor
    return v, f


def veach_plates(resolution: int = 256) -> Scene:
    """Veach's MIS scene (1997, fig. 9.8): four plates from rough (Phong n = 30) to nearly
    mirror-like (n = 10^4), each tilted to reflect a row of four spherical lights of radius
    0.9 .. 0.03 and equal power (radiance ~ 1 / r^2) into the camera. BSDF sampling wins on
    smooth plates with large lights, light sampling on rough plates with small lights."""
    return veach_plates_builder(resolution).build()


def veach_plates_ggx(resolution: int = 256) -> Scene:
    """Veach's MIS scene as Mitsuba's documentation renders it: the plates of
    :func:`veach_plates` made GGX rough conductors (perfect-mirror Fresnel, reflectance 0.4)
    of roughness alpha = 0.1, 0.05, 0.02, 0.005 from the front plate to the back."""
    return veach_plates_builder(resolution, alphas=VEACH_GGX_ALPHAS).build()


VEACH_GGX_ALPHAS = (0.1, 0.05, 0.02, 0.005)


def veach_plates_builder(resolution: int, alphas: tuple | None = None) -> SceneBuilder:
    """The builder of :func:`veach_plates` (``alphas``: GGX rough-conductor plates of these
    roughnesses instead of Phong ones), before ``build()``: benchmarks translate it for
    Mitsuba 3."""
    b = SceneBuilder("veach_plates" if alphas is None else "veach_plates_ggx")
    b.material("floor", "diffuse", diffuse=(0.3, 0.3, 0.3))
    b.material("lamp", "diffuse", diffuse=(0.0, 0.0, 0.0))
    b.quad((-12, -4.5, -12), (0, 0, 30), (24, 0, 0), "floor")
    b.quad((-12, -4.5, -4), (24, 0, 0), (0, 16, 0), "floor")
    eye = np.array([0.0, 2.0, 15.0])
    light_row = np.array([0.0, 0.2, -2.0])
    centers = [(0.0, -3.6, 4.4), (0.0, -2.75, 3.0), (0.0, -1.8, 1.7), (0.0, -0.75, 0.5)]
    for i, (e, c) in enumerate(zip((30.0, 150.0, 1000.0, 10000.0), centers)):
        c = np.array(c)
        n = (eye - c) / np.linalg.norm(eye - c) + (light_row - c) / np.linalg.norm(light_row - c)
        n /= np.linalg.norm(n)
        along = np.cross(np.array([1.0, 0.0, 0.0]), n)  # in the plate, perpendicular to x
        u, v = np.array([8.0, 0.0, 0.0]), along * 1.25
        if alphas is None:
            b.material(f"plate{i}", "phong", diffuse=(0.0, 0.0, 0.0), specular=(0.4, 0.4, 0.4),
                       exponent=e)
        else:
            b.material(f"plate{i}", "roughconductor", specular=(0.4, 0.4, 0.4),
                       alpha=alphas[i], distribution="ggx")
        b.quad(c - u / 2 - v / 2, u, v, f"plate{i}")
    for i, r in enumerate((0.9, 0.3, 0.1, 0.03)):
        radiance = 4.0 * (0.3 / r) ** 2  # equal power
        b.sphere(light_row + np.array([-3.75 + 2.5 * i, 0.0, 0.0]), r, "lamp",
                 emission=(radiance, radiance * 0.95, radiance * 0.85))
    b.sphere((8.0, 12.0, 10.0), 1.0, "lamp", emission=(6.0, 6.0, 6.0))  # dim fill light
    b.camera(position=tuple(eye), look_at=(0, -1.6, 2.0), fov=34, width=resolution,
             height=resolution)
    return b


def cornell_box_rough(resolution: int = 256) -> Scene:
    """The Cornell room with microfacet objects, one of each kind (GGX unless noted): a glossy
    copper sphere (alpha 0.05: photon mapping samples through it), a rough glass sphere
    (alpha 0.2, ior 1.5; amber in transmission, clear in reflection), a Beckmann rough-plastic
    block (alpha 0.3, a photon lookup surface) and an anisotropic gold block (alpha_u 0.3,
    alpha_v 0.08)."""
    b = SceneBuilder("cornell_box_rough")
    cornell_room(b, resolution)
    T, R, S = xf.translate, xf.rotate, xf.scale
    b.material("copper", "roughconductor", metal="Cu", alpha=0.05)
    b.material("frosted", "roughdielectric", alpha=0.2, ior=1.5, transmittance=(0.9, 0.65, 0.4))
    b.material("plastic", "roughplastic", diffuse=(0.2, 0.3, 0.6), alpha=0.3,
               distribution="beckmann")
    b.material("gold", "roughconductor", metal="Au", alpha_u=0.3, alpha_v=0.08)
    b.sphere((-0.5, -0.65, 0.35), 0.35, "copper")
    b.sphere((0.45, -0.7, 0.45), 0.3, "frosted")
    b.cube(T([-0.33, -0.45, -0.4]) @ R([0, 1, 0], 18.25) @ S([0.28, 0.55, 0.28]), "plastic")
    b.cube(T([0.4, -0.8, -0.35]) @ R([0, 1, 0], -17) @ S(0.2), "gold")
    return b.build()


def furnace(resolution: int = 32, albedo: float = 0.5, emission: float = 1.0) -> Scene:
    """Closed box (inward normals); every wall emits ``emission`` and reflects ``albedo``."""
    b = SceneBuilder("furnace")
    b.material("wall", "diffuse", diffuse=(albedo, albedo, albedo))
    e = (emission, emission, emission)
    for c, u, v in _inward_box_faces():
        b.quad(c, u, v, "wall", emission=e)
    b.camera(position=(0.1, -0.2, 0.3), look_at=(0.5, 0.2, -1), fov=60, width=resolution,
             height=resolution)
    return b.build()


def _inward_box_faces():
    """Faces of [-1, 1]^3 with cross(u, v) pointing into the box."""
    return [
        ((-1, -1, 1), (0, 2, 0), (2, 0, 0)), ((1, -1, -1), (0, 2, 0), (-2, 0, 0)),
        ((1, -1, 1), (0, 2, 0), (0, 0, -2)), ((-1, -1, -1), (0, 2, 0), (0, 0, 2)),
        ((-1, 1, 1), (0, 0, -2), (2, 0, 0)), ((-1, -1, -1), (0, 0, 2), (2, 0, 0)),
    ]


def point_light_plane(resolution: int = 32, intensity: float = 10.0, height: float = 1.0,
                      albedo: float = 0.5) -> Scene:
    b = SceneBuilder("point_light_plane")
    b.material("plane", "diffuse", diffuse=(albedo, albedo, albedo))
    b.quad((-50, 0, -50), (0, 0, 100), (100, 0, 0), "plane")
    b.point_light((0, height, 0), (intensity, intensity, intensity))
    b.camera(position=(0, 3, 3), look_at=(0, 0, 0), fov=50, width=resolution, height=resolution)
    return b.build()


MIRROR_SDS = dict(floor_height=0.0, light=(0.0, 1.0, 0.0), mirror_height=2.0,
                  camera=(0.0, 1.0, 2.0), look_at=(0.0, 2.0, 1.0), fov=40.0)


def mirror_sds(resolution: int = 64, intensity: float = 10.0, albedo: float = 0.5,
               mirror: float = 0.9) -> Scene:
    """Specular-diffuse-specular light with a closed form: a point light between a diffuse floor
    (y = 0) and a mirror ceiling (y = 2) facing it; the camera looks up, so it sees the floor
    only in the mirror. Paths of at most 4 segments are L D S E (direct light on the floor) and
    L S D S E (the light's mirror image), which no unbiased estimator with a point light can
    sample (BDPT, path tracing) and photon density estimation can; their radiance is
    :func:`jgi.analysis.closed_form.mirror_sds_image`."""
    g = MIRROR_SDS
    b = SceneBuilder("mirror_sds")
    b.material("floor", "diffuse", diffuse=(albedo, albedo, albedo))
    b.material("mirror", "mirror", specular=(mirror, mirror, mirror))
    h = g["mirror_height"]
    b.quad((-30, 0, -30), (0, 0, 60), (60, 0, 0), "floor")              # normal +y
    b.quad((-30, h, -30), (60, 0, 0), (0, 0, 60), "mirror")             # normal -y
    b.point_light(g["light"], (intensity, intensity, intensity))
    b.camera(position=g["camera"], look_at=g["look_at"], fov=g["fov"], width=resolution,
             height=resolution)
    return b.build()


# SmallVCM's box corners (its scene.hxx, z up): 0-3 at y = +1.30455 (the back), 4-7 at the front
SMALLVCM_BOX = np.array([
    (-1.27029, 1.30455, -1.28002), (1.28975, 1.30455, -1.28002), (1.28975, 1.30455, 1.28002),
    (-1.27029, 1.30455, 1.28002), (-1.27029, -1.25549, -1.28002), (1.28975, -1.25549, -1.28002),
    (1.28975, -1.25549, 1.28002), (-1.27029, -1.25549, 1.28002)])
SMALLVCM_LIGHT_BOX = np.array([
    (-0.25, 0.25, 1.26002), (0.25, 0.25, 1.26002), (0.25, 0.25, 1.28002), (-0.25, 0.25, 1.28002),
    (-0.25, -0.25, 1.26002), (0.25, -0.25, 1.26002), (0.25, -0.25, 1.28002),
    (-0.25, -0.25, 1.28002)])


def smallvcm_box(resolution: int = 512) -> Scene:
    """SmallVCM's ``LoadCornellBox(kLightCeiling | kBothSmallSpheres)``: triangles in its vertex
    order (so its normals), its albedos, a light box under the ceiling whose downward face
    emits 25.0333 (its radiance), a mirror ball (reflectance 1) and a glass ball (index 1.6),
    and its camera (45 degrees horizontal field of view). Its diffuse surfaces are one-sided
    (SmallVCM's BSDF is black from behind), and so are they here."""
    b = SceneBuilder("smallvcm_box")
    for name, rgb in (("white", (0.803922,) * 3), ("green", (0.156863, 0.803922, 0.172549)),
                      ("red", (0.803922, 0.152941, 0.152941))):
        b.material(name, "diffuse", diffuse=rgb, one_sided=True)
    b.material("emitter", "diffuse", one_sided=True)
    b.material("mirror", "mirror", specular=(1.0, 1.0, 1.0))
    b.material("glass", "dielectric", ior=1.6)
    cb, lb = SMALLVCM_BOX, SMALLVCM_LIGHT_BOX
    walls = {"white": [(0, 4, 5), (5, 1, 0), (0, 1, 2), (2, 3, 0), (2, 6, 7), (7, 3, 2)],
             "green": [(3, 7, 4), (4, 0, 3)], "red": [(1, 5, 6), (6, 2, 1)]}
    for material, faces in walls.items():
        b.mesh(cb, faces, material)
    b.mesh(lb, [(0, 2, 1), (2, 0, 3), (3, 4, 7), (4, 3, 0), (1, 6, 5), (6, 1, 2), (4, 5, 6),
                (6, 7, 4)], "white")
    b.mesh(lb, [(0, 5, 4), (5, 0, 1)], "emitter", emission=(25.03329895614464,) * 3)
    floor_left, floor_right = (cb[0] + cb[4]) / 2, (cb[1] + cb[5]) / 2
    shift = np.array([2 * (floor_right[0] - floor_left[0]) / 7, 0, 0.5])
    b.sphere(floor_left + shift * (1, 0, 1), 0.5, "mirror")
    b.sphere(floor_right + shift * (-1, 0, 1), 0.5, "glass")
    position = np.array((-0.0439815, -4.12529, 0.222539))
    b.camera(position=position, look_at=position + (0.00688625, 0.998505, -0.0542161),
             up=(3.73896e-4, 0.0542148, 0.998529), fov=45.0, width=resolution,
             height=resolution, fov_axis="x")
    return b.build()


BUILTINS = {
    "cornell_box": cornell_box,
    "cornell_box_caustics": cornell_box_caustics,
    "cornell_box_caustics_point": cornell_box_caustics_point,
    "glass_sphere": glass_sphere,
    "metal_ring": metal_ring,
    "veach_plates": veach_plates,
    "veach_plates_ggx": veach_plates_ggx,
    "cornell_box_rough": cornell_box_rough,
    "cornell_box_textured": cornell_box_textured,
    "furnace": furnace,
    "point_light_plane": point_light_plane,
    "mirror_caustic": mirror_caustic,
    "mirror_sds": mirror_sds,
    "smallvcm_box": smallvcm_box,
    "cornell_box_fog": cornell_box_fog,
    "glass_sphere_fog": glass_sphere_fog,
    "milk_ball": milk_ball,
}


def get(name: str, **kwargs) -> Scene:
    try:
        fn = BUILTINS[name]
    except KeyError:
        raise KeyError(f"unknown built-in scene '{name}'; available: "
                       f"{', '.join(BUILTINS)}") from None
    return fn(**kwargs)
