"""The scene: an immutable pytree of struct-of-arrays tables with static sizes, and the kind
constants their integer columns hold.

Every float in a scene is a pytree leaf, so one compiled estimator serves every scene with the
same *structure* (primitive counts and which material/light kinds occur), and ``jax.grad`` can
differentiate an image with respect to any of them (albedos, light emission, positions).

Tables:
  * ``Spheres``, ``Rects`` (axis-aligned rectangles), ``Boxes`` (oriented cubes), ``Quads``
    (other parallelograms), ``Triangles``: geometry, a material index and an emitter index (the
    light element that makes the primitive emissive, or -1). The builder files each quad and
    cube under the most specific table that represents it exactly, since the ray test is the
    renderer's inner loop.
  * ``Materials``: one row per material; ``kind`` selects the BSDF (see :mod:`jgi.physics.bsdf`).
    Its ``textures`` (a :class:`Textures` table, or None in scenes without textures) and
    ``texture`` (texture row of each textured parameter, -1 for a constant) make diffuse
    reflectance, specular reflectance and roughness vary over surfaces
    (:mod:`jgi.physics.textures`).
  * ``Lights``: a flat table of *light elements* chosen for next-event estimation with
    probability proportional to power. A diffuse area light on a mesh contributes one element per
    triangle, so light selection and ``pdf_li`` are the same code for every emitter shape.
  * ``Camera``: a pinhole camera (see :mod:`jgi.physics.camera`).

Scenes are made with :class:`jgi.scene.builder.SceneBuilder` (used by :mod:`jgi.scene.builtin`
and the file loaders).
"""

from __future__ import annotations

import equinox as eqx
import numpy as np
from jax import Array

from ..core.bvh import BVH, build_bvh
from ..core.vec import V3
from .metals import METALS

# Triangle tables at least this large get a BVH. Measured (experiments/bench/bvh.py, CPU, one
# closest-hit and one shadow ray per ray, 2^16 rays, interleaved best-of-3 timings) since the
# brute-force scan takes blocks of rows per loop iteration (jgi.physics.geometry._scan): brute force
# falls as 1/T (4.2 Mrays/s at 196 triangles, 2.2 at 400, 0.92 at 1024, 0.22 at 4096) while
# the BVH stays at 0.6-0.9; BVH/brute is 0.22 at 196, 0.40 at 400, 0.79 at 1024, 1.16 at 1600,
# 1.7 at 2304, 2.7 at 4096: the crossover is at about 1400. (With one row per iteration it was
# at 250-280.) The BVH traversal also adds compile time.
BVH_MIN_TRIANGLES = 1400

# Material kinds (jgi.physics.bsdf implements each). Mitsuba's smooth "conductor" is the
# mirror with a complex index of refraction (eta = k = 0, the mirror's, reflects everything).
# Mitsuba's smooth "plastic" is the one kind with both a Dirac lobe and a non-Dirac one.
DIFFUSE, MIRROR, DIELECTRIC, PHONG, ROUGH_CONDUCTOR, ROUGH_DIELECTRIC, ROUGH_PLASTIC = range(7)
PLASTIC = 7
MATERIAL_KINDS = {"diffuse": DIFFUSE, "mirror": MIRROR, "dielectric": DIELECTRIC, "phong": PHONG,
                  "conductor": MIRROR, "roughconductor": ROUGH_CONDUCTOR,
                  "roughdielectric": ROUGH_DIELECTRIC, "roughplastic": ROUGH_PLASTIC,
                  "plastic": PLASTIC}
ROUGH_KINDS = (ROUGH_CONDUCTOR, ROUGH_DIELECTRIC, ROUGH_PLASTIC)
# Microfacet normal distributions of the rough kinds (jgi.physics.bsdf.microfacet).
GGX, BECKMANN = 0, 1
MICROFACET_DISTRIBUTIONS = {"ggx": GGX, "beckmann": BECKMANN}
NAMED_METALS = METALS  # Mitsuba's conductor names -> (eta, k) per RGB channel (jgi.scene.metals)

# Texture kinds (jgi.physics.textures evaluates each), and the material parameters a texture can
# drive: columns of ``Materials.texture``.
CHECKERBOARD, BITMAP = range(2)
TEXTURE_KINDS = {"checkerboard": CHECKERBOARD, "bitmap": BITMAP}
# TEX_ALPHA drives alpha_u (an isotropic alpha: both), TEX_ALPHA_V alpha_v. An isotropic textured
# alpha names its texture in both columns; a scene where every row's two agree drops the
# TEX_ALPHA_V column (alpha_v then follows alpha_u where TEX_ALPHA is textured).
TEX_DIFFUSE, TEX_SPECULAR, TEX_ALPHA, TEX_ALPHA_V = range(4)
TEXTURED_PARAMS = {"diffuse": TEX_DIFFUSE, "specular": TEX_SPECULAR, "alpha": TEX_ALPHA,
                   "alpha_v": TEX_ALPHA_V}

# Light element kinds (jgi.physics.lights implements each).
AREA_QUAD, AREA_TRIANGLE, AREA_SPHERE, POINT, SPOT, DIRECTIONAL, ENVIRONMENT = range(7)
AREA_DISK, AREA_CYLINDER = 7, 8
LIGHT_KIND_NAMES = ("area_quad", "area_triangle", "area_sphere", "point", "spot", "directional",
                    "environment", "area_disk", "area_cylinder")
DELTA_POSITION_KINDS = (POINT, SPOT)
DELTA_DIRECTION_KINDS = (DIRECTIONAL,)


class Spheres(eqx.Module):
    center: V3
    radius: Array
    material: Array
    emitter: Array

    @property
    def count(self) -> int:
        return int(self.radius.shape[0])


class Quads(eqx.Module):
    """Parallelograms origin + a * edge_u + b * edge_v, (a, b) in [0, 1]^2."""

    origin: V3
    edge_u: V3
    edge_v: V3
    normal: V3  # unit cross(edge_u, edge_v); emitters radiate on this side only
    material: Array
    emitter: Array

    @property
    def count(self) -> int:
        return int(self.material.shape[0])


class Rects(eqx.Module):
    """Axis-aligned rectangles, a specialisation of quads chosen automatically by the builder.

    Rectangle i lies in the plane x_axis = ``plane`` (axis static, rows sorted by axis, with
    ``axis_counts`` rows per axis) and spans [lo_a, hi_a] x [lo_b, hi_b] in the other two axes
    in increasing order (for axis y: a = x, b = z). Its ray test is about a fifth of a general
    parallelogram's, which matters for architectural scenes such as the Cornell box."""

    plane: Array
    lo_a: Array
    hi_a: Array
    lo_b: Array
    hi_b: Array
    normal: V3  # unit normal (+-1 along the axis), the side cross(edge_u, edge_v) points to
    material: Array
    emitter: Array
    axis_counts: tuple[int, int, int] = eqx.field(static=True)
    # textured scenes only (else None): the quad's (a, b) parameters of a point p are
    # (p - origin) . dual_u and (p - origin) . dual_v, its surface coordinates uv
    origin: V3 | None = None
    dual_u: V3 | None = None
    dual_v: V3 | None = None

    @property
    def count(self) -> int:
        return int(self.material.shape[0])


class Boxes(eqx.Module):
    """Oriented boxes (Mitsuba's ``cube`` under a rotation/scale transform without shear):
    centre + sum_k s_k half_k axis_k with s_k in [-1, 1]; one slab test replaces six quads."""

    center: V3
    axis_u: V3   # unit box axes (rows of the world-to-box rotation)
    axis_v: V3
    axis_w: V3
    half: V3     # half extents along the axes
    material: Array
    emitter: Array  # always -1: emissive cubes are built from quads so they can be sampled

    @property
    def count(self) -> int:
        return int(self.material.shape[0])


class Disks(eqx.Module):
    """Elliptic (usually circular) disks center + a * axis_u + b * axis_v, a^2 + b^2 <= 1:
    Mitsuba 3's ``disk`` and pbrt-v4's full ``disk``, analytic (area pi |axis_u x axis_v|).

    ``normal`` is the unit normal each renderer defines (Mitsuba: its to_world's normal
    transform of +z; pbrt: +z's, reversed by ReverseOrientation or a handedness swap), already
    negated by flip_normals; area emitters radiate on its side. Surface coordinates of the
    point at polar (r, phi) in the (a, b) plane: Mitsuba's (r, phi / 2 pi), pbrt's
    (phi / 2 pi, 1 - r) where ``pbrt_uv``."""

    center: V3
    axis_u: V3
    axis_v: V3
    normal: V3
    material: Array
    emitter: Array
    pbrt_uv: Array | None = None   # bool [D], textured scenes only

    @property
    def count(self) -> int:
        return int(self.material.shape[0])


class Cylinders(eqx.Module):
    """Open circular tubes base + radius (cos phi axis_u + sin phi axis_v) + z axis_w,
    z in [0, height], with a unit frame (axis_u, axis_v, axis_w): Mitsuba 3's ``cylinder`` and
    pbrt-v4's full ``cylinder``, analytic (area 2 pi radius height). ``outward`` is +1 where
    the normal (the side an emitter radiates to) points away from the axis, -1 towards it
    (flip_normals, ReverseOrientation). Surface coordinates (phi / 2 pi, z / height) in both
    renderers."""

    base: V3
    axis_u: V3
    axis_v: V3
    axis_w: V3
    radius: Array
    height: Array
    outward: Array
    material: Array
    emitter: Array

    @property
    def count(self) -> int:
        return int(self.material.shape[0])


class Triangles(eqx.Module):
    """Triangles v0 + b1 * edge1 + b2 * edge2 (Moller-Trumbore layout).

    ``bvh`` is a :class:`jgi.core.bvh.BVH` over the same triangles, built with the scene when
    there are at least ``BVH_MIN_TRIANGLES`` of them (:mod:`jgi.physics.geometry` then traverses
    it instead of testing every triangle), or None. Its arrays are pytree leaves like the rest,
    so the scene's structure, and hence the compiled kernel, depends on their sizes only. It is
    a copy of the geometry: a scene whose triangles are edited afterwards (``eqx.tree_at``)
    must rebuild it (:func:`with_bvh`); gradients with respect to vertices flow through the
    hit triangle's own intersection, not the traversal."""

    v0: V3
    edge1: V3
    edge2: V3
    normal: V3  # unit geometric normal cross(edge1, edge2)
    material: Array
    emitter: Array
    bvh: BVH | None = None
    # textured scenes only (else None): [T, 6] (u0, v0, u1 - u0, v1 - v0, u2 - u0, v2 - v0),
    # the vertices' surface coordinates; a mesh without them has Mitsuba's (0,0), (1,0), (0,1)
    uv: Array | None = None
    # scenes with shading normals only (else None): [T, 9] the unit vertex normals n0, n1, n2
    # of each triangle (a flat triangle's are its geometric normal); the hit's shading normal
    # is their barycentric interpolation, normalised (jgi.physics.geometry)
    normals: Array | None = None

    @property
    def count(self) -> int:
        return int(self.material.shape[0])


class Textures(eqx.Module):
    """One row per texture (Mitsuba's ``checkerboard`` and ``bitmap``, pbrt-v4's
    ``checkerboard`` and ``imagemap``), looked up at surface coordinates (u, v) mapped by the
    affine ``to_uv`` first (Mitsuba's ``to_uv`` transform; pbrt's uscale, vscale, udelta,
    vdelta): (u', v') = (a u + b v + c, d u + e v + f) with ``to_uv`` row (a, b, c, d, e, f).

    Bitmaps are linear RGB, all packed into one flat ``atlas`` [P, 3] (row-major, row 0 the
    image's top row, which v' = 0 addresses, as in Mitsuba); texture i occupies rows
    ``offset[i]`` .. ``offset[i] + width[i] * height[i] - 1``. Every texel is a pytree leaf,
    so ``jax.grad`` of an image with respect to a bitmap works."""

    kind: Array       # int32 [T]: CHECKERBOARD or BITMAP
    color0: V3        # checkerboard: colour where frac(u') and frac(v') lie on the same side of 1/2
    color1: V3        # ... and elsewhere
    to_uv: Array      # [T, 6] affine map of (u, v), see above
    offset: Array     # int32 [T]: first atlas row of a bitmap
    width: Array      # int32 [T]
    height: Array     # int32 [T]
    atlas: Array      # [P, 3] linear RGB texels of every bitmap (one zero row if there are none)
    kinds: tuple[int, ...] = eqx.field(static=True)  # texture kinds present

    @property
    def count(self) -> int:
        return int(self.kind.shape[0])


class Materials(eqx.Module):
    """One row per material. Every float is a pytree leaf (differentiable), except the
    roughplastic tables, which are computed from alpha and ior at build time."""

    kind: Array       # int32 [M]
    diffuse: V3       # Lambertian albedo k_d (diffuse, phong, roughplastic, plastic)
    specular: V3      # k_s: mirror/conductor reflectance, dielectric tint, Phong specular albedo,
                      # the specular factor of the rough kinds
    exponent: Array   # Phong exponent n
    ior: Array        # relative index of refraction inside / outside (dielectrics, plastics)
    alpha_u: Array    # microfacet roughness along the tangent s of the shading frame
    alpha_v: Array    # ... along the bitangent t (= alpha_u when isotropic)
    distribution: Array  # int32 [M]: GGX or BECKMANN
    eta: V3           # conductor index of refraction eta + i k per channel (0, 0: a perfect
    k: V3             # mirror, F = 1)
    transmittance: Array  # [M, 64] roughplastic coating's external transmittance T(cos theta)
    internal_reflectance: Array  # [M] the coating's internal reflectance Ri: roughplastic's
                                 # table integral, plastic's fdr_int (Mitsuba's fits)
    nonlinear: Array  # bool [M]: (rough)plastic's ``nonlinear`` (k_d Ri instead of Ri)
    transmission_tint: V3  # k_t: a (rough) dielectric's transmitted-light factor (Mitsuba's
                           # specular_transmittance; = specular unless given)
    kinds: tuple[int, ...] = eqx.field(static=True)  # kinds present, to skip dead code
    # distributions used by rough rows (empty without rough materials), to skip the absent one
    distributions: tuple[int, ...] = eqx.field(static=True, default=())
    # some conductor row (mirror, roughconductor) has eta != 0, so a Fresnel factor other than
    # 1; False: every conductor is a perfect mirror (eta = 0, F = 1) and kernels skip the
    # conductor Fresnel (perf: docs/performance.md#glossy-path-tracer). A scene whose eta is
    # changed after build (eqx.tree_at) from all zeros must set it True.
    conductor_fresnel: bool = eqx.field(static=True, default=True)
    # Textures (None in a scene without any: its kernels are those of a scene before textures)
    textures: Textures | None = None
    texture: Array | None = None   # int32 [M, 3]: texture row per TEX_* column, -1 = constant
    textured: tuple[int, ...] = eqx.field(static=True, default=())  # TEX_* columns in use
    # bool [M]: reflects on its normal's side only (Mitsuba's BSDFs without ``twosided``);
    # None in a scene without one-sided materials (its kernels are those before the flag)
    one_sided: Array | None = None
    # Opacity masks (Mitsuba's ``mask``, pbrt-v4's shape ``alpha``): float32 [M], the
    # probability that a ray meeting the surface stops there (1: opaque); tested inside ray
    # traversal (jgi.physics.geometry). None in a scene without masks (its kernels are those
    # before masks); ``opacity_texture``: int32 [M] texture row of a textured opacity, -1 =
    # constant, None where no opacity is textured.
    opacity: Array | None = None
    opacity_texture: Array | None = None

    @property
    def has_textures(self) -> bool:
        """Static: the scene uses textures (hits then carry surface coordinates uv)."""
        return self.textures is not None

    @property
    def has_one_sided(self) -> bool:
        """Static: some material is one-sided (the BSDFs then test the side of the normal)."""
        return self.one_sided is not None

    @property
    def has_masks(self) -> bool:
        """Static: some material has an opacity mask (traversal then tests it per hit)."""
        return self.opacity is not None


class EnvironmentMap(eqx.Module):
    """An environment image, the radiance of the environment element relative to its
    ``emission`` row (which holds Mitsuba's or pbrt's ``scale``), in one of two static
    parametrisations (``mapping``):

    ``"latlong"`` (Mitsuba 3's ``envmap``): texel (r, c) is the radiance towards the local
    direction with polar angle theta = pi r / (H - 1) from +y and azimuth
    phi = 2 pi (c + 1/2) / W measured by atan2(x, -z) (Mitsuba's convention); between texels
    it is bilinear, wrapping around in phi. Sampling is piecewise constant over the
    W x (H - 1) cells between texel centres: a cell's weight is its four texels' mean
    luminance times its solid angle (the sin(theta) Jacobian), rows by the marginal, columns
    by the row's conditional; within a cell phi and cos(theta) are uniform, so the solid-angle
    density is constant on it.

    ``"octahedral"`` (pbrt-v4's image ``infinite`` light): an N x N image over Clarberg's
    equal-area octahedral square (local +z up; texel (r, c) covers s in [c, c + 1) / N,
    t in [r, r + 1) / N, every texel the solid angle 4 pi / N^2); the radiance is the nearest
    texel's, sampling piecewise constant over the texels (weight: the mean of the three
    channels, as pbrt-v4's Image::GetSamplingDistribution), so the solid-angle density is a
    texel's probability times N^2 / (4 pi).

    ``texels`` are pytree leaves (gradients flow through lookups); the sampling tables are
    computed at build time."""

    texels: Array       # [H, W, 3] linear RGB, row 0 towards +y (latlong) / t = 0 (octahedral)
    row_pmf: Array      # [R] marginal probability of each row of cells (R = H - 1 latlong, N)
    row_cdf: Array      # [R] its inclusive running sum (last entry 1)
    col_pmf: Array      # [R, W] conditional probability of each cell in its row
    col_cdf: Array      # [R, W] inclusive running sums (last entry 1)
    cos_edge: Array     # latlong: [H] cos(pi r / (H - 1)), the cells' polar edges; else [0]
    to_world: Array     # [3, 3] rotation, local -> world (columns: the local axes)
    mapping: str = eqx.field(static=True, default="latlong")   # or "octahedral"

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.texels.shape[0]), int(self.texels.shape[1])

    @property
    def octahedral(self) -> bool:
        """Static: pbrt-v4's equal-area octahedral square rather than latitude-longitude."""
        return self.mapping == "octahedral"


class Lights(eqx.Module):
    kind: Array         # int32 [K]
    p0: V3              # quad/triangle corner, sphere/disk centre, cylinder base, point/spot
                        # position
    e1: V3              # quad/triangle edge 1, disk semi-axis a, cylinder radius * axis_u
    e2: V3              # quad/triangle edge 2, disk semi-axis b, cylinder radius * axis_v
    radius: Array       # sphere radius; a cylinder's Cylinders.outward (+-1)
    normal: V3          # unit normal of quad/triangle/disk emitters (emitting side); a
                        # cylinder's height * axis_w
    direction: V3       # spot axis / directional travel direction (unit)
    emission: V3        # radiance L_e (area, environment), intensity I (point, spot),
                        # irradiance E (directional)
    cos_total: Array    # spot: cosine of the cone half-angle (no light outside)
    cos_falloff: Array  # spot: cosine where the smooth falloff starts
    spot_linear: Array  # spot: True for Mitsuba's falloff (linear in the angle), False for
                        # pbrt's (smoothstep in the cosine)
    area: Array         # area of area-light elements (0 otherwise)
    pmf: Array          # selection probability (proportional to power)
    cdf: Array          # inclusive running sum of pmf, for inversion
    bound_center: V3    # scene bounding sphere (directional and environment emission)
    bound_radius: Array
    kinds: tuple[int, ...] = eqx.field(static=True)
    environment: int = eqx.field(static=True)  # element index of the environment light or -1
    # the environment's image (None: a constant environment, whose kernels are those of a scene
    # before environment maps)
    envmap: EnvironmentMap | None = None

    @property
    def count(self) -> int:
        return int(self.kind.shape[0])


class Medium(eqx.Module):
    """A homogeneous participating medium (:mod:`jgi.physics.media`, :mod:`jgi.physics.phase`):
    extinction sigma_t and single-scattering albedo per RGB channel, Henyey-Greenstein asymmetry
    g (0: isotropic). Every float is a leaf (differentiable)."""

    sigma_t: V3     # 1 / scene length unit
    albedo: V3      # sigma_s / sigma_t, in [0, 1]
    g: Array        # in (-1, 1)


class MediumInterfaces(eqx.Module):
    """Which media a material's surfaces bound (Mitsuba's shape ``interior`` / ``exterior``,
    pbrt-v4's ``MediumInterface``), one row per material: medium ids, 0 the scene's own medium
    (``Scene.medium``, or vacuum) and k >= 1 row k - 1 of ``Scene.bounded_media``. A ray leaving
    such a surface on the side of its normal travels in ``exterior``, on the other side in
    ``interior``; ``interior`` -1 marks a material whose surfaces are no medium transition
    (the ray keeps the medium it arrived in, as in both renderers)."""

    interior: Array   # int32 [M]
    exterior: Array   # int32 [M]


class GridMedium(eqx.Module):
    """A heterogeneous medium (:mod:`jgi.physics.grid_media`): extinction
    sigma_t,c(x) = density(x) sigma_t,c inside the box [lo, hi] of the grid's frame (0 outside;
    optionally clipped to a convex null boundary, ``clip``), the density interpolated
    trilinearly from the grid (voxel centres, Mitsuba 3's gridvolume convention), constant
    albedo, Henyey-Greenstein g. The grid's shape is static (one compile
    per shape); ``majorant`` is max(density) and ``majorants`` the max per coarse cell, computed
    when the scene is built (the trackings' bounds: a density above them would bias them, so
    edit the grid through the builder, or :func:`jgi.scene.builder.majorant_grid`)."""

    sigma_t: V3        # extinction per unit density, RGB
    albedo: V3         # sigma_s / sigma_t, in [0, 1]
    g: Array           # in (-1, 1)
    density: Array     # [nz, ny, nx] float32, >= 0 (the medium's scale folded in)
    lo: V3             # the box's corners in world space
    hi: V3
    majorant: Array    # max(density)
    # [mz, my, mx]: the max of the density over each cell of a coarse grid over the box (the
    # trackings' piecewise-constant majorant; shape (1, 1, 1): the global max)
    majorants: Array
    # [nz', ny', nx', 3] RGB in [0, 1] over the same box, multiplying ``albedo`` (None: a constant
    # albedo, whose kernels are those of a medium before albedo grids)
    albedo_grid: Array | None = None
    # between a face and the outermost voxel centres: "clamp" (Mitsuba's gridvolume) or "zero"
    # (pbrt-v4's grids: towards 0 half a voxel beyond the face); see grid_media.density
    border: str = eqx.field(static=True, default="clamp")
    # world -> the grid's frame, [3, 4] affine (the box [lo, hi] lies in that frame: a rotated
    # or sheared grid); None: the grid's frame is the world's (an axis-aligned box)
    to_local: Array | None = None
    # a convex null boundary the medium is clipped to (Mitsuba's shape with a "null" bsdf,
    # pbrt-v4's with the "interface" material): world -> the frame of its unit shape, [3, 4]
    # affine; None: the box alone bounds the medium
    clip: Array | None = None
    # the unit shape of ``clip``: "cube" ([-1, 1]^3, Mitsuba's cube) or "sphere" (radius 1)
    clip_shape: str = eqx.field(static=True, default="cube")


class Camera(eqx.Module):
    """Pinhole camera. ``forward`` is unit; ``right``/``up`` are scaled to the image-plane
    half-extents at distance 1, so a film point (sx, sy) in [-1, 1]^2 maps to the direction
    forward + sx * right + sy * up."""

    position: V3
    forward: V3
    right: V3
    up: V3
    width: int = eqx.field(static=True)
    height: int = eqx.field(static=True)


class Scene(eqx.Module):
    camera: Camera
    spheres: Spheres
    rects: Rects
    boxes: Boxes
    quads: Quads
    triangles: Triangles
    materials: Materials
    lights: Lights
    name: str = eqx.field(static=True, default="scene")
    # analytic disks and cylinders (None in a scene without any: its kernels are those of a
    # scene before them)
    disks: Disks | None = None
    cylinders: Cylinders | None = None
    # the medium filling the scene's space: the camera's, and both sides of every surface
    # (pbrt-v4 with one MediumInterface for all shapes). None: vacuum (kernels as before media)
    # (a GridMedium: a heterogeneous medium in a box, vacuum around it; a tuple of them:
    # several disjoint volumes with one phase function, clouds in vacuum)
    medium: Medium | GridMedium | tuple[GridMedium, ...] | None = None
    # homogeneous media bounded by shapes (medium ids 1..K, each field [K]), and the interfaces
    # of the materials whose surfaces bound them; None in a scene without (its kernels are those
    # of a scene before bounded media)
    bounded_media: Medium | None = None
    medium_interfaces: MediumInterfaces | None = None
    # heterogeneous media bounded by shapes (ids K + 1, K + 2, ... after the homogeneous ones;
    # each zero outside its box as well), or None
    bounded_grids: tuple[GridMedium, ...] | None = None

    @property
    def has_medium(self) -> bool:
        """Static: some of the scene's space holds a participating medium (paths then sample
        free flights)."""
        return (self.medium is not None or self.bounded_media is not None
                or self.bounded_grids is not None)

    @property
    def has_bounded_media(self) -> bool:
        """Static: media bounded by shapes; rays and path vertices carry the id of the medium
        they travel in (:mod:`jgi.physics.medium_interfaces`)."""
        return self.bounded_media is not None or self.bounded_grids is not None

    @property
    def fills_with_homogeneous_medium(self) -> bool:
        """Static: a homogeneous medium fills the space around every shape (light from infinity
        never reaches into the scene)."""
        return isinstance(self.medium, Medium)

    @property
    def has_grid_medium(self) -> bool:
        """Static: a medium is a density grid (null-scattering tracking): the scene's own, or
        some bounded by shapes (``bounded_grids``)."""
        return (isinstance(self.medium, GridMedium | tuple)
                or self.bounded_grids is not None)

    @property
    def resolution(self) -> tuple[int, int]:
        return self.camera.width, self.camera.height

    @property
    def has_shading_normals(self) -> bool:
        """Static: some mesh has vertex normals (hits and path vertices then carry a shading
        normal ``ns`` besides the geometric ``n``; scenes without compile as before)."""
        return self.triangles.normals is not None

    def with_resolution(self, width: int, height: int) -> "Scene":
        """Same scene and field of view, another film size."""
        cam = self.camera
        aspect_old = cam.width / cam.height
        aspect_new = width / height
        right = cam.right * (aspect_new / aspect_old)
        new = Camera(cam.position, cam.forward, right, cam.up, int(width), int(height))
        return eqx.tree_at(lambda s: s.camera, self, new)


def with_bvh(scene: "Scene", bvh: bool | None = None) -> "Scene":
    """The scene with its triangles' BVH rebuilt from the current triangles (``bvh`` None: if
    there are at least BVH_MIN_TRIANGLES of them), or removed (``bvh=False``)."""
    tr = scene.triangles
    n = tr.count
    use = n >= BVH_MIN_TRIANGLES if bvh is None else bool(bvh) and n > 0
    new = None
    if use:
        v0 = np.asarray(tr.v0.stack(), np.float64)
        new = build_bvh(v0, v0 + np.asarray(tr.edge1.stack()), v0 + np.asarray(tr.edge2.stack()))
    return eqx.tree_at(lambda s: s.triangles.bvh, scene, new, is_leaf=lambda x: x is None)
