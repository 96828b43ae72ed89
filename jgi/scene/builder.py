"""Building a scene: :class:`SceneBuilder` accumulates materials, textures, shapes, lights and a
camera from plain numbers, checks them (:class:`SceneError` names the source, the key and what
is allowed) and ``build()`` makes the :class:`jgi.scene.tables.Scene` pytree.

A material's parameters are checked against :data:`MATERIAL_RULES`, one row of rules per
material type (which keys apply, which may name a texture, which need an index of refraction),
read by :meth:`SceneBuilder.material`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from dataclasses import field as dc_field

import jax.numpy as jnp
import numpy as np

from ..core import transform as xf
from ..core import warps
from ..core.bvh import build_bvh, moller_trumbore
from ..core.imageio import read_image
from ..core.vec import V3, cross, dot
from .rough_coating import TABLE_SIZE, fresnel_diffuse_reflectance, plastic_tables
from .tables import (
    AREA_CYLINDER,
    AREA_DISK,
    AREA_QUAD,
    AREA_SPHERE,
    AREA_TRIANGLE,
    BVH_MIN_TRIANGLES,
    DIELECTRIC,
    DIFFUSE,
    DIRECTIONAL,
    ENVIRONMENT,
    GGX,
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
    TEX_ALPHA,
    TEX_ALPHA_V,
    TEXTURE_KINDS,
    TEXTURED_PARAMS,
    Boxes,
    Camera,
    Cylinders,
    Disks,
    EnvironmentMap,
    GridMedium,
    Lights,
    Materials,
    Medium,
    MediumInterfaces,
    Quads,
    Rects,
    Scene,
    Spheres,
    Textures,
    Triangles,
)

# a grid medium's majorant times its box's diagonal, at most: the expected tentative collisions
# of one crossing (jgi.physics.grid_media tracks them all, with no cap)
MAX_OPTICAL_DEPTH = 1e5
# cells per axis of a grid medium's majorant grid (at most the density grid's)
MAJORANT_RESOLUTION = 8


def majorant_grid(grid: np.ndarray, resolution: int) -> np.ndarray:
    """[mz, my, mx] (m = min(resolution, n) per axis): the max of the trilinearly interpolated
    density (voxel centres, clamped: jgi.physics.grid_media) over each cell of an m^3 grid over
    the box: the max of the voxels whose centres lie within a voxel of the cell (the
    interpolation's support), each cell widened by 1e-3 of itself against rounding; one cell
    where all are alike."""
    ranges = []
    for n in grid.shape:
        m = min(resolution, n)
        k = np.arange(m)
        lo = np.clip(((k - 1e-3) / m) * n - 0.5, 0, n - 1)
        hi = np.clip(((k + 1 + 1e-3) / m) * n - 0.5, 0, n - 1)
        ranges.append([(int(np.floor(a)), int(np.ceil(b)) + 1) for a, b in zip(lo, hi)])
    out = np.empty([len(r) for r in ranges], np.float32)
    for iz, (z0, z1) in enumerate(ranges[0]):
        for iy, (y0, y1) in enumerate(ranges[1]):
            for ix, (x0, x1) in enumerate(ranges[2]):
                out[iz, iy, ix] = grid[z0:z1, y0:y1, x0:x1].max()
    # all cells alike (a constant grid): one cell, no crossings (measured: the constant fog of
    # docs/performance.md#grid-media, 0.68-0.72 s with 8^3 cells, 0.40-0.67 s with one)
    return out[:1, :1, :1] if np.all(out == out.flat[0]) else out

# Defaults taken from Mitsuba 3: roughness alpha 0.1; (rough)plastic's int_ior (polypropylene)
# and ext_ior (air); a missing int_ior of a dielectric is bk7's.
DEFAULT_ALPHA = 0.1
IOR_POLYPROPYLENE, IOR_BK7, IOR_AIR = 1.49, 1.5046, 1.000277

# Mitsuba 3's ``cube`` as the mesh it is (Mitsuba 3.9.1's vertex_positions, vertex_texcoords
# and faces, read with mitsuba.traverse): per face (-y, +y, +x, +z, -x, -z) four vertices and
# two triangles wound outwards, the face's uv spanning [0, 1]^2.
CUBE_VERTICES = np.array([
    [1, -1, -1], [1, -1, 1], [-1, -1, 1], [-1, -1, -1],
    [1, 1, -1], [-1, 1, -1], [-1, 1, 1], [1, 1, 1],
    [1, -1, -1], [1, 1, -1], [1, 1, 1], [1, -1, 1],
    [1, -1, 1], [1, 1, 1], [-1, 1, 1], [-1, -1, 1],
    [-1, -1, 1], [-1, 1, 1], [-1, 1, -1], [-1, -1, -1],
    [1, 1, -1], [1, -1, -1], [-1, -1, -1], [-1, 1, -1]], float)
CUBE_UV = np.tile(np.array([[0, 1], [1, 1], [1, 0], [0, 0]], float), (6, 1))
CUBE_FACES = np.array([[4 * k + i for i in tri] for k in range(6)
                       for tri in ((0, 1, 2), (3, 0, 2))], np.int64)


# --- material rules ---------------------------------------------------------------------------

# The optional material parameters that only some types take, in the order they are checked.
OPTIONAL_KEYS = ("alpha", "alpha_u", "alpha_v", "metal", "eta", "k", "int_ior", "ext_ior",
                 "nonlinear", "transmittance")
_ROUGHNESS = ("alpha", "alpha_u", "alpha_v")
_CONDUCTOR = ("metal", "eta", "k")
_IOR = ("int_ior", "ext_ior")


@dataclass(frozen=True)
class MaterialRule:
    """What one material type of :meth:`SceneBuilder.material` takes.

    ``keys``: the :data:`OPTIONAL_KEYS` it accepts (a conductor's index when it has "metal");
    ``colours``: the colours it uses (the others are stored as 0), which may also name a
    texture; ``textured``: every parameter that may name a texture; ``interface``: None, or
    the defaults of its index of refraction: "dielectric" (ior 1.5, int_ior bk7) or "coating"
    (polypropylene, which must differ from ext_ior); ``isotropic``: one alpha only;
    ``untextured_why``: why a parameter cannot be textured, appended to that error;
    ``one_sided``: whether it may be one-sided (reflective types; a dielectric is two-sided by
    nature)."""

    kind: int
    keys: tuple[str, ...] = ()
    colours: tuple[str, ...] = ("specular",)
    textured: tuple[str, ...] = ("specular",)
    interface: str | None = None
    isotropic: bool = False
    untextured_why: dict = dc_field(default_factory=dict)
    one_sided: bool = True


MATERIAL_RULES = {
    "diffuse": MaterialRule(DIFFUSE, colours=("diffuse",), textured=("diffuse",)),
    "mirror": MaterialRule(MIRROR),
    "conductor": MaterialRule(MIRROR, keys=_CONDUCTOR),
    "dielectric": MaterialRule(DIELECTRIC, keys=(*_IOR, "transmittance"),
                               interface="dielectric", one_sided=False),
    "phong": MaterialRule(PHONG, colours=("diffuse", "specular"),
                          textured=("diffuse", "specular")),
    "roughconductor": MaterialRule(ROUGH_CONDUCTOR, keys=(*_ROUGHNESS, *_CONDUCTOR),
                                   textured=("specular", *_ROUGHNESS)),
    "roughdielectric": MaterialRule(ROUGH_DIELECTRIC, keys=(*_ROUGHNESS, *_IOR, "transmittance"),
                                    textured=("specular", *_ROUGHNESS), interface="dielectric",
                                    one_sided=False),
    "roughplastic": MaterialRule(
        ROUGH_PLASTIC, keys=(*_ROUGHNESS, *_IOR, "nonlinear"), colours=("diffuse", "specular"),
        textured=("diffuse", "specular"), interface="coating", isotropic=True,
        untextured_why={"alpha": " (its coating tables are precomputed from one alpha)"}),
    "plastic": MaterialRule(PLASTIC, keys=(*_IOR, "nonlinear"), colours=("diffuse", "specular"),
                            textured=("diffuse", "specular"), interface="coating"),
}
assert {k: r.kind for k, r in MATERIAL_RULES.items()} == MATERIAL_KINDS


def _check_transmittance(transmittance, specular, fail):
    """A dielectric's constant transmitted-light tint, refused beside a textured specular."""
    if isinstance(transmittance, str):
        fail("'transmittance' cannot be textured; a texture given as 'specular' tints "
             "reflection and transmission alike")
    if isinstance(specular, str):
        fail("'specular' is a texture, which tints transmission too: give no "
             "'transmittance'")
    try:
        t = np.broadcast_to(np.asarray(transmittance, float), (3,))
    except (TypeError, ValueError):
        t = np.array([np.nan])
    if not (np.all(np.isfinite(t)) and np.all(t >= 0)):
        fail(f"'transmittance' must be one number or three (RGB), finite and >= 0, got "
             f"{transmittance!r}")


def _roughness(rule: MaterialRule, alpha, alpha_u, alpha_v, fail) -> tuple[float, float]:
    """(alpha_u, alpha_v) from alpha or the pair (default 0.1), each finite and > 0."""
    if alpha is not None and (alpha_u is not None or alpha_v is not None):
        fail("give either alpha or alpha_u and alpha_v, not both")
    if (alpha_u is None) != (alpha_v is None):
        fail("give both alpha_u and alpha_v (or alpha)")
    au = av = DEFAULT_ALPHA if alpha is None else alpha
    if alpha_u is not None:
        au, av = alpha_u, alpha_v
    names = ("alpha", "alpha") if alpha_u is None else ("alpha_u", "alpha_v")
    for key, v in zip(names, (au, av)):
        if not np.isfinite(float(v)) or float(v) <= 0:
            fail(f"{key} must be a finite number > 0, got {v}")
    if rule.isotropic and float(au) != float(av):
        fail("roughplastic is isotropic (as in Mitsuba): give alpha, not alpha_u / alpha_v")
    return float(au), float(av)


def _conductor_index(metal, eta, k, fail) -> tuple[tuple, tuple]:
    """A conductor's (eta, k): a named metal, or eta (default 0) and k (default 1); neither is
    Mitsuba's "none", a perfect mirror."""
    if metal is not None:
        if eta is not None or k is not None:
            fail("give either metal or eta / k, not both")
        if metal not in NAMED_METALS:
            fail(f"unknown metal '{metal}'; allowed: {', '.join(NAMED_METALS)}")
        return NAMED_METALS[metal]
    if eta is None and k is None:
        return NAMED_METALS["none"]
    eta_k = (_rgb(0.0 if eta is None else eta), _rgb(1.0 if k is None else k))
    for key, v in zip(("eta", "k"), eta_k):
        if min(v) < 0:
            fail(f"{key} must be >= 0 in every channel, got {list(v)}")
    return eta_k


def _relative_ior(interface: str, ior, int_ior, ext_ior, fail) -> float:
    """inside / outside, from ior or int_ior / ext_ior (defaults by ``interface``)."""
    coating = interface == "coating"
    if ior is not None and (int_ior is not None or ext_ior is not None):
        fail("give either ior or int_ior / ext_ior, not both")
    if ior is None and int_ior is None and ext_ior is None:
        out = IOR_POLYPROPYLENE / IOR_AIR if coating else 1.5
    elif ior is not None:
        out = float(ior)
    else:
        i = float((IOR_POLYPROPYLENE if coating else IOR_BK7) if int_ior is None else int_ior)
        e = float(IOR_AIR if ext_ior is None else ext_ior)
        if not (np.isfinite(i) and np.isfinite(e) and i > 0 and e > 0):
            fail(f"int_ior and ext_ior must be finite and > 0, got {i}, {e}")
        out = i / e
    if not np.isfinite(out) or out <= 0:
        fail(f"ior must be finite and > 0 (inside / outside), got {out}")
    if coating and out == 1.0:
        fail("the interior and exterior indices of refraction must differ")
    return out


def _v3(a) -> V3:
    a = np.asarray(a, np.float32).reshape(-1, 3)
    return V3(jnp.asarray(a[:, 0]), jnp.asarray(a[:, 1]), jnp.asarray(a[:, 2]))


def _v3_scalar(a) -> V3:
    a = np.asarray(a, np.float32).reshape(3)
    return V3(jnp.asarray(a[0]), jnp.asarray(a[1]), jnp.asarray(a[2]))


class SceneError(ValueError):
    """An invalid scene description; the message names the source, the key and what is allowed."""


@dataclass
class _Material:
    kind: int
    diffuse: tuple = (0.0, 0.0, 0.0)
    specular: tuple = (0.0, 0.0, 0.0)
    exponent: float = 1.0
    ior: float = 1.5
    alpha_u: float = DEFAULT_ALPHA
    alpha_v: float = DEFAULT_ALPHA
    distribution: int = GGX
    eta: tuple = (0.0, 0.0, 0.0)
    k: tuple = (0.0, 0.0, 0.0)
    nonlinear: bool = False
    transmission: tuple | None = None   # dielectrics' k_t (None: specular)
    one_sided: bool = False             # reflects on the normal's side only (Mitsuba's)
    opacity: float = 1.0                # probability that a ray stops at the surface
    opacity_texture: int = -1           # texture row of a textured opacity, -1: constant
    textures: dict = dc_field(default_factory=dict)  # TEX_* column -> texture row
    # the media its surfaces bound (SceneBuilder.medium_interface): (interior, exterior) names
    # of bounded media, None for the scene's own medium; None: no medium transition
    interface: tuple | None = None


@dataclass
class _Texture:
    kind: int
    color0: tuple = (0.4, 0.4, 0.4)
    color1: tuple = (0.2, 0.2, 0.2)
    to_uv: tuple = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)
    image: np.ndarray | None = None   # [H, W, 3] linear RGB


def uv_transform(scale=None, offset=None, matrix=None) -> tuple:
    """The affine (a, b, c, d, e, f) of :class:`Textures` from a scale (one number or (su, sv)),
    an offset (du, dv) applied after it, or a 3x3 / 4x4 matrix acting on (u, v, [0,] 1)."""
    if matrix is not None:
        m = np.asarray(matrix, float)
        if m.shape == (4, 4):
            m = m[np.ix_([0, 1, 3], [0, 1, 3])]
        if m.shape != (3, 3):
            raise SceneError(f"to_uv: expected a 3x3 or 4x4 matrix, got shape {m.shape}")
        return tuple(float(x) for x in (*m[0], *m[1]))
    su, sv = np.broadcast_to(np.asarray(1.0 if scale is None else scale, float), (2,))
    du, dv = np.broadcast_to(np.asarray(0.0 if offset is None else offset, float), (2,))
    return (float(su), 0.0, float(du), 0.0, float(sv), float(dv))


def _homogeneous_medium(sigma_t, albedo, sigma_a, sigma_s, g, scale) -> dict:
    """A homogeneous medium's parameters checked and in Mitsuba's form (sigma_t, albedo, g)."""
    if (sigma_t is None) == (sigma_a is None and sigma_s is None):
        raise SceneError("a medium takes sigma_t (and albedo) or sigma_a and sigma_s; "
                         "allowed: one of the two forms")
    if sigma_t is not None:
        st = np.asarray(_rgb(sigma_t)) * float(scale)
        alb = np.asarray(_rgb(1.0 if albedo is None else albedo))
    else:
        sa = np.asarray(_rgb(0.0 if sigma_a is None else sigma_a)) * float(scale)
        ss = np.asarray(_rgb(0.0 if sigma_s is None else sigma_s)) * float(scale)
        if np.any(sa < 0) or np.any(ss < 0):
            raise SceneError(f"medium sigma_a {sa.tolist()} and sigma_s {ss.tolist()} "
                             "must be >= 0")
        st = sa + ss
        alb = np.where(st > 0, ss / np.where(st > 0, st, 1.0), 0.0)
    if np.any(st < 0):
        raise SceneError(f"medium sigma_t {st.tolist()} must be >= 0")
    if np.any(alb < 0) or np.any(alb > 1):
        raise SceneError(f"medium albedo {alb.tolist()} must lie in [0, 1]")
    if not -1.0 < float(g) < 1.0:
        raise SceneError(f"medium g = {g} must lie in (-1, 1) (Henyey-Greenstein)")
    return dict(sigma_t=tuple(st), albedo=tuple(alb), g=float(g))


def _grid_medium_of(m: dict) -> GridMedium:
    """The GridMedium of checked grid medium arguments (SceneBuilder.grid_medium)."""
    f = lambda v: V3(*(jnp.float32(c) for c in v))  # noqa: E731
    grid = m["grid"]
    return GridMedium(f(m["sigma_t"]), f(m["albedo"]), jnp.float32(m["g"]),
                      jnp.asarray(grid), f(m["lo"]), f(m["hi"]),
                      jnp.float32(grid.max()), jnp.asarray(m["majorants"]),
                      None if m["albedo_grid"] is None else jnp.asarray(m["albedo_grid"]),
                      border=m["border"],
                      to_local=None if m["to_local"] is None else jnp.asarray(m["to_local"]),
                      clip=None if m["clip"] is None else jnp.asarray(m["clip"]),
                      clip_shape=m["clip_shape"])


def _volume_bounds(m: dict) -> np.ndarray:
    """[2, 3]: the world bounding box of checked grid medium arguments ``m``: its box's, cut by
    its null boundary's."""
    def bounds(to_local, lo, hi):
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])], float)
        if to_local is not None:
            frame = np.vstack([np.asarray(to_local, float), [0, 0, 0, 1]])
            corners = xf.apply_point(np.linalg.inv(frame), corners)
        return np.stack([corners.min(0), corners.max(0)])
    box = bounds(m["to_local"], m["lo"], m["hi"])
    if m["clip"] is None:
        return box
    if m["clip_shape"] == "cube":
        cut = bounds(m["clip"], -np.ones(3), np.ones(3))
    else:   # the ellipsoid's extent along each axis: the norm of its map's row
        to_world = np.linalg.inv(np.vstack([np.asarray(m["clip"], float), [0, 0, 0, 1]]))
        reach = np.linalg.norm(to_world[:3, :3], axis=1)
        cut = np.stack([to_world[:3, 3] - reach, to_world[:3, 3] + reach])
    return np.stack([np.maximum(box[0], cut[0]), np.minimum(box[1], cut[1])])


@dataclass
class SceneBuilder:
    """Accumulates materials, shapes, lights and a camera; ``build()`` makes the pytree."""

    name: str = "scene"
    materials: list = dc_field(default_factory=list)
    material_names: dict = dc_field(default_factory=dict)
    spheres: list = dc_field(default_factory=list)    # (center, radius, material, emission|None)
    quads: list = dc_field(default_factory=list)      # (origin, u, v, material, emission|None)
    boxes: list = dc_field(default_factory=list)      # (center, axes[3x3 rows], half[3], material)
    triangles: list = dc_field(default_factory=list)  # (v0, v1, v2, material, emission|None)
    lights: list = dc_field(default_factory=list)     # dicts for point/spot/directional/env
    camera_args: dict | None = None
    bvh: bool | None = None   # BVH over the triangles: None = when >= BVH_MIN_TRIANGLES
    textures: list = dc_field(default_factory=list)
    texture_names: dict = dc_field(default_factory=dict)
    triangle_uvs: list = dc_field(default_factory=list)  # per triangle: [3, 2] or None
    triangle_normals: list = dc_field(default_factory=list)  # per triangle: [3, 3] or None
    # (center, axis_u, axis_v, normal, pbrt_uv, material, emission|None)
    disks: list = dc_field(default_factory=list)
    # (base, axis_u, axis_v, axis_w, radius, height, outward, material, emission|None)
    cylinders: list = dc_field(default_factory=list)
    medium_args: dict | None = None   # the homogeneous medium filling the scene, if any
    bounded_media: dict = dc_field(default_factory=dict)   # name -> homogeneous medium args
    bounded_grids: dict = dc_field(default_factory=dict)   # name -> grid medium args (bounded)

    # --- participating medium ----------------------------------------------------------------
    def medium(self, *, sigma_t=None, albedo=None, sigma_a=None, sigma_s=None, g=0.0,
               scale=1.0):
        """Fill the scene's space (the camera's medium, both sides of every surface) with a
        homogeneous medium: Mitsuba's ``sigma_t`` and ``albedo``, or pbrt-v4's ``sigma_a`` and
        ``sigma_s`` (RGB or grey), times ``scale``; Henyey-Greenstein asymmetry ``g``."""
        self.medium_args = _homogeneous_medium(sigma_t, albedo, sigma_a, sigma_s, g, scale)

    def bounded_medium(self, name: str, *, sigma_t=None, albedo=None, sigma_a=None,
                       sigma_s=None, g=0.0, scale=1.0) -> int:
        """Define homogeneous medium ``name`` (parameters as :meth:`medium`'s; zero extinction
        makes a vacuum) to be bounded by shapes: the surfaces of a material made by
        :meth:`medium_interface` hold it inside or outside. Returns its medium id (1, 2, ...;
        0 is the scene's own medium)."""
        if name in self.bounded_media:
            raise SceneError(f"medium '{name}' is defined twice")
        try:
            self.bounded_media[name] = _homogeneous_medium(sigma_t, albedo, sigma_a, sigma_s, g,
                                                           scale)
        except SceneError as e:
            raise SceneError(f"medium '{name}': {e}") from None
        return len(self.bounded_media)

    def bounded_grid_medium(self, name: str, density, bbox_min=(0.0, 0.0, 0.0),
                            bbox_max=(1.0, 1.0, 1.0), **params) -> None:
        """Define heterogeneous medium ``name`` (parameters as :meth:`grid_medium`'s; zero
        outside its box) to be bounded by shapes, as :meth:`bounded_medium` defines a
        homogeneous one: smoke in a glass jar. A scene may hold several (two jars of smoke),
        each tracked on the lanes that travel in it, but not with a grid medium of the
        scene's own."""
        if name in self.bounded_media or name in self.bounded_grids:
            raise SceneError(f"medium '{name}' is defined twice")
        try:
            self.bounded_grids[name] = self._grid_args(density, bbox_min, bbox_max, **params)
        except SceneError as e:
            raise SceneError(f"medium '{name}': {e}") from None

    def medium_interface(self, material, *, interior: str | None = None,
                         exterior: str | None = None) -> int:
        """A material row like ``material`` whose surfaces bound media (Mitsuba's ``interior``
        and ``exterior`` of a shape, pbrt-v4's ``MediumInterface``): a ray leaving such a
        surface on the side of its normal travels in ``exterior``, on the other side in
        ``interior`` (names of :meth:`bounded_medium`; None: the scene's own medium, or
        vacuum). Shapes made with the returned row bound the media; a closed shape with
        outward normals holds ``interior`` inside. One row per (material, interior, exterior)."""
        m = self._mat(material)
        for side, name in (("interior", interior), ("exterior", exterior)):
            if name is not None and name not in self.bounded_media \
                    and name not in self.bounded_grids:
                defined = ", ".join([*self.bounded_media, *self.bounded_grids]) or "(none)"
                raise SceneError(f"medium interface of material '{self._material_name(m)}': "
                                 f"{side} names medium '{name}', which is not defined; defined: "
                                 f"{defined} (bounded_medium, bounded_grid_medium)")
        if interior == exterior:
            return m   # no transition
        base = self.materials[m]
        if _masked(base):
            raise SceneError(f"material '{self._material_name(m)}' has an opacity mask and "
                             "cannot bound a medium (a ray through its holes would change "
                             "media without crossing a surface); allowed: opaque materials")
        key = f"{self._material_name(m)}|{interior or ''}|{exterior or ''}"
        if key not in self.material_names:
            self.materials.append(replace(base, interface=(interior, exterior)))
            self.material_names[key] = len(self.materials) - 1
        return self.material_names[key]

    def grid_medium(self, density, bbox_min=(0.0, 0.0, 0.0), bbox_max=(1.0, 1.0, 1.0), *,
                    sigma_t=1.0, albedo=1.0, g=0.0, scale=1.0,
                    majorant_resolution=MAJORANT_RESOLUTION, border="clamp", to_world=None,
                    clip=None):
        """Fill the box [bbox_min, bbox_max] with a heterogeneous medium (vacuum around it; the
        camera's medium, both sides of every surface): extinction
        sigma_t,c(x) = scale density(x) sigma_t,c, ``density`` a [nz, ny, nx] grid (x fastest,
        Mitsuba's .vol order) interpolated trilinearly between voxel centres
        (:mod:`jgi.physics.grid_media`), ``albedo`` RGB or grey, or a grid over the same box
        ([nz', ny', nx'] or [nz', ny', nx', 3], values in [0, 1]), HG ``g``. The
        trackings' majorant is the density's max over the cells of a coarse grid of
        ``majorant_resolution`` cells per axis (at most the grid's; 1: one global majorant).
        ``border``: the density between a face and the outermost voxel centres, "clamp"
        (Mitsuba's gridvolume: the outermost voxels') or "zero" (pbrt-v4's grids: falling
        towards 0 half a voxel beyond the face); the majorants bound both. ``to_world``: a
        4 x 4 affine map from the grid's frame, where the box lies, to the world (None: the
        identity; a rotated or sheared grid otherwise). ``clip``: a convex null boundary the
        medium is cut to, ("cube" or "sphere", the 4 x 4 map of the unit shape, [-1, 1]^3 or
        the unit ball, to the world): Mitsuba's shape with a ``null`` bsdf, pbrt-v4's
        ``interface`` one; a homogeneous medium in it is a 1 x 1 x 1 grid over a box that holds
        the shape.

        Called again, it adds another volume (clouds in vacuum): volumes must be disjoint (their
        bounding boxes, each the box's cut by its null boundary's, may not overlap) and share
        ``g``; a homogeneous :meth:`medium` before them is replaced."""
        args = self._grid_args(density, bbox_min, bbox_max, sigma_t=sigma_t, albedo=albedo, g=g,
                               scale=scale, majorant_resolution=majorant_resolution,
                               border=border, to_world=to_world, clip=clip)
        volumes = [] if self.medium_args is None else self.medium_args.get("volumes", [])
        for k, other in enumerate(volumes):
            if other["g"] != args["g"]:
                raise SceneError(f"grid medium: volume {len(volumes)} has g = {args['g']}, volume "
                                 f"{k} g = {other['g']}; volumes of the scene's own medium share "
                                 "one phase function (allowed: equal g)")
            a, b = _volume_bounds(other), _volume_bounds(args)
            if np.all(a[0] < b[1]) and np.all(b[0] < a[1]):
                raise SceneError(f"grid medium: volume {len(volumes)}'s bounding box "
                                 f"{np.round(b, 6).tolist()} overlaps volume {k}'s "
                                 f"{np.round(a, 6).tolist()}; allowed: disjoint volumes")
        self.medium_args = dict(volumes=[*volumes, args])

    def _grid_args(self, density, bbox_min, bbox_max, *, sigma_t=1.0, albedo=1.0, g=0.0,
                   scale=1.0, majorant_resolution=MAJORANT_RESOLUTION, border="clamp",
                   to_world=None, clip=None) -> dict:
        """The checked arguments of one grid medium (:meth:`grid_medium`)."""
        if border not in ("clamp", "zero"):
            raise SceneError(f"grid medium: border {border!r} is not one of 'clamp' (Mitsuba), "
                             "'zero' (pbrt-v4)")
        grid = np.asarray(density, np.float64)
        if grid.ndim != 3 or min(grid.shape) < 1:
            raise SceneError(f"grid medium: density must be a [nz, ny, nx] array, got shape "
                             f"{list(grid.shape)}")
        if not np.all(np.isfinite(grid)) or np.any(grid < 0):
            raise SceneError("grid medium: density values must be finite and >= 0")
        lo, hi = np.asarray(_rgb(bbox_min), float), np.asarray(_rgb(bbox_max), float)
        if not np.all(hi > lo):
            raise SceneError(f"grid medium: bbox_max {hi.tolist()} must exceed bbox_min "
                             f"{lo.tolist()} in every axis")
        st = np.asarray(_rgb(sigma_t), float)
        alb_grid = None
        if np.ndim(albedo) >= 3:   # a grid: [nz, ny, nx] (grey) or [nz, ny, nx, 3]
            alb_grid = np.asarray(albedo, np.float64)
            if alb_grid.ndim == 3:
                alb_grid = alb_grid[..., None]
            if alb_grid.ndim != 4 or alb_grid.shape[3] not in (1, 3) or min(alb_grid.shape) < 1:
                raise SceneError(f"grid medium: an albedo grid must be [nz, ny, nx] or "
                                 f"[nz, ny, nx, 3], got shape {list(alb_grid.shape)}")
            if not np.all(np.isfinite(alb_grid)) or np.any(alb_grid < 0) or np.any(alb_grid > 1):
                raise SceneError("grid medium: albedo grid values must lie in [0, 1]")
            alb_grid = np.broadcast_to(alb_grid, alb_grid.shape[:3] + (3,)).astype(np.float32)
            albedo = 1.0
        alb = np.asarray(_rgb(albedo), float)
        if float(scale) < 0 or np.any(st < 0):
            raise SceneError(f"grid medium: scale {scale} and sigma_t {st.tolist()} must be >= 0")
        if np.any(alb < 0) or np.any(alb > 1):
            raise SceneError(f"medium albedo {alb.tolist()} must lie in [0, 1]")
        if not -1.0 < float(g) < 1.0:
            raise SceneError(f"medium g = {g} must lie in (-1, 1) (Henyey-Greenstein)")
        to_local = self._grid_frame("the grid's to_world", to_world)
        clip_shape, clip_to_local = "cube", None
        if clip is not None:
            if not (isinstance(clip, tuple) and len(clip) == 2 and clip[0] in ("cube", "sphere")):
                raise SceneError(f"grid medium: clip must be (\"cube\" or \"sphere\", a 4 x 4 "
                                 f"to_world), got {clip!r}")
            clip_shape, clip_to_local = clip[0], self._grid_frame("the clip's to_world", clip[1])
        grid = (grid * float(scale)).astype(np.float32)
        # the box's diagonal in world space bounds any chord through it
        stretch = 1.0 if to_world is None else float(np.linalg.norm(
            np.asarray(to_world, float)[:3, :3], 2))
        depth = float(grid.max()) * float(st.max()) * float(np.linalg.norm(hi - lo)) * stretch
        if depth > MAX_OPTICAL_DEPTH:
            raise SceneError(f"grid medium: majorant optical depth {depth:.3g} across the box "
                             f"exceeds {MAX_OPTICAL_DEPTH:.0e} tentative collisions per crossing; "
                             "allowed: a smaller scale or density")
        if int(majorant_resolution) < 1:
            raise SceneError(f"grid medium: majorant_resolution {majorant_resolution} must be "
                             ">= 1")
        return dict(sigma_t=tuple(st), albedo=tuple(alb), g=float(g), grid=grid, lo=tuple(lo),
                    hi=tuple(hi), majorants=majorant_grid(grid, int(majorant_resolution)),
                    albedo_grid=alb_grid, border=border, to_local=to_local, clip=clip_to_local,
                    clip_shape=clip_shape)

    @staticmethod
    def _grid_frame(what: str, to_world) -> np.ndarray | None:
        """The [3, 4] world-to-frame map of an invertible affine 4 x 4 ``to_world`` (None:
        None, the identity)."""
        if to_world is None:
            return None
        m = np.asarray(to_world, float)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)) or np.any(m[3] != (0, 0, 0, 1)):
            raise SceneError(f"grid medium: {what} must be a finite affine 4 x 4 matrix (last "
                             "row 0 0 0 1)")
        lin = m[:3, :3]
        if abs(np.linalg.det(lin)) <= 1e-12 * max(np.abs(lin).max(), 1e-30) ** 3:
            raise SceneError(f"grid medium: {what} is singular (it flattens the medium)")
        return np.linalg.inv(m)[:3].astype(np.float32)

    # --- textures ---------------------------------------------------------------------------
    def texture(self, name: str, kind: str, *, color0=(0.4, 0.4, 0.4), color1=(0.2, 0.2, 0.2),
                scale=None, offset=None, to_uv=None, filename=None, data=None,
                raw: bool = False) -> int:
        """Define texture ``name``; returns its row. A material takes it by name wherever a
        textured parameter allows (``diffuse``, ``specular``, ``alpha``). Kinds:

        * ``"checkerboard"`` (Mitsuba's): ``color0`` where frac(u) and frac(v) lie on the same
          side of 1/2, ``color1`` elsewhere (defaults Mitsuba's 0.4 and 0.2).
        * ``"bitmap"``: an image, ``filename`` (PNG, JPEG or EXR; 8-bit images are decoded from
          sRGB unless ``raw``, as Mitsuba does) or ``data`` (an [H, W, 3] or [H, W] array, taken
          as linear), looked up bilinearly with wrap-around (Mitsuba's ``repeat``); row 0 of
          the image is v = 0.

        Coordinates are first mapped by ``to_uv`` (a 3x3 or 4x4 matrix) or by ``scale`` (one
        number or (su, vs)) then ``offset``."""
        if kind not in TEXTURE_KINDS:
            raise SceneError(f"texture '{name}': unknown type '{kind}'; allowed: "
                             f"{', '.join(TEXTURE_KINDS)}")
        if name in self.texture_names:
            raise SceneError(f"texture '{name}' is defined twice")
        if to_uv is not None and (scale is not None or offset is not None):
            raise SceneError(f"texture '{name}': give either to_uv or scale / offset, not both")
        t = _Texture(TEXTURE_KINDS[kind], to_uv=uv_transform(scale, offset, to_uv))
        if kind == "checkerboard":
            if filename is not None or data is not None:
                raise SceneError(f"texture '{name}' (checkerboard): 'filename' and 'data' do "
                                 "not apply")
            t.color0, t.color1 = _rgb(color0), _rgb(color1)
        else:
            if (filename is None) == (data is None):
                raise SceneError(f"texture '{name}' (bitmap): give either filename or data")
            if filename is not None:
                try:
                    img = read_image(filename, raw=raw)
                except (OSError, ValueError) as e:
                    raise SceneError(f"texture '{name}' (bitmap): cannot read '{filename}': "
                                     f"{e}") from None
            else:
                img = np.asarray(data, np.float64)
            if img.ndim == 2:
                img = np.repeat(img[:, :, None], 3, axis=2)
            if img.ndim != 3 or img.shape[2] not in (3, 4) or min(img.shape[:2]) < 1:
                raise SceneError(f"texture '{name}' (bitmap): expected an [H, W, 3] image, got "
                                 f"shape {img.shape}")
            img = img[:, :, :3]
            if not np.all(np.isfinite(img)):
                raise SceneError(f"texture '{name}' (bitmap): the image has non-finite texels")
            t.image = np.asarray(img, np.float32)
        self.texture_names[name] = len(self.textures)
        self.textures.append(t)
        return self.texture_names[name]

    # --- materials --------------------------------------------------------------------------
    def material(self, name: str, kind: str, *, diffuse=(0.0, 0.0, 0.0),
                 specular=(1.0, 1.0, 1.0), exponent: float = 1.0, ior: float | None = None,
                 alpha: float | None = None, alpha_u: float | None = None,
                 alpha_v: float | None = None, distribution: str = "ggx", eta=None, k=None,
                 metal: str | None = None, int_ior: float | None = None,
                 ext_ior: float | None = None, nonlinear: bool = False,
                 transmittance=None, one_sided: bool = False, opacity=1.0) -> int:
        """Define material ``name``; returns its row. Parameters by ``kind``:

        * ``"diffuse"``: ``diffuse`` (k_d).
        * ``"mirror"``: ``specular`` (k_s), a perfect mirror.
        * ``"conductor"``: Mitsuba's smooth conductor: ``specular`` (its specular_reflectance)
          times the Fresnel reflectance of the complex index eta + i k, given as ``metal`` (a
          name of :data:`NAMED_METALS`, Mitsuba's) or as ``eta`` and ``k`` (RGB or scalars,
          >= 0; a missing one is Mitsuba's default, eta 0 or k 1). Neither: Mitsuba's
          "none", a perfect mirror. Stored as the mirror kind.
        * ``"dielectric"``: ``specular`` (the tint of reflected light, and of transmitted light
          unless ``transmittance`` is given: Mitsuba's specular_reflectance and
          specular_transmittance), ``ior`` = inside / outside (default 1.5), or
          ``int_ior`` / ``ext_ior`` (defaults bk7 1.5046 / air 1.000277).
        * ``"phong"``: ``diffuse``, ``specular``, ``exponent``.
        * ``"roughconductor"``: as ``"conductor"``, plus the roughness: ``alpha`` (isotropic)
          or ``alpha_u`` and ``alpha_v`` (along the tangent s and bitangent t of the shading
          frame), all > 0 (default 0.1; values below 1e-4 act as 1e-4, as in Mitsuba), and
          ``distribution`` "ggx" or "beckmann" (alpha is the RMS slope for Beckmann).
        * ``"roughdielectric"``: as ``"dielectric"``, plus the roughness as above.
        * ``"roughplastic"`` (Mitsuba's): ``diffuse`` (diffuse_reflectance), ``specular``
          (specular_reflectance), ``ior`` or ``int_ior`` / ``ext_ior`` (defaults
          polypropylene 1.49 / air 1.000277; must differ), isotropic ``alpha``,
          ``distribution``, ``nonlinear``.
        * ``"plastic"`` (Mitsuba's smooth plastic): as ``"roughplastic"`` without the roughness:
          ``diffuse``, ``specular``, ``ior`` or ``int_ior`` / ``ext_ior``, ``nonlinear``.

        Textured parameters take a texture's name instead of a value: ``diffuse``,
        ``specular`` (a dielectric's one tint, reflection and transmission alike: a textured
        ``specular`` takes no ``transmittance``, which is a constant colour), and the
        roughness ``alpha`` or ``alpha_u`` / ``alpha_v`` (each on its own; its luminance) of
        roughconductor and roughdielectric. A roughplastic's ``alpha`` cannot be textured (its
        coating tables are computed from one value).

        ``one_sided``: the surface reflects on the side its normal points to only, as
        Mitsuba 3's reflective BSDFs without ``twosided``: seen or lit from the back it is
        black (f = 0, no sample). Not for the dielectrics (two-sided by nature). Default
        False: two-sided, as pbrt's materials.

        ``opacity`` (any type): an opacity mask (Mitsuba 3's ``mask`` BSDF around this one,
        pbrt-v4's shape ``alpha``): the probability in [0, 1] that a ray meeting the surface
        stops there and scatters; otherwise it passes straight through. A number, or a
        texture's name (its luminance at the hit). Default 1: opaque, no mask. Tested inside
        ray traversal (:mod:`jgi.physics.geometry`), so every estimator and shadow ray sees
        it. Emitting shapes must be opaque (their light sampling takes the whole surface to
        emit): a masked material on one is refused.

        Raises :class:`SceneError` naming the material and what is allowed; the rules per
        type are :data:`MATERIAL_RULES`."""
        if kind not in MATERIAL_RULES:
            raise SceneError(f"material '{name}': unknown type '{kind}'; allowed: "
                             f"{', '.join(MATERIAL_KINDS)}")
        if name in self.material_names:
            raise SceneError(f"material '{name}' is defined twice")
        rule = MATERIAL_RULES[kind]

        def fail(msg):
            raise SceneError(f"material '{name}' ({kind}): {msg}")

        given = dict(alpha=alpha, alpha_u=alpha_u, alpha_v=alpha_v, metal=metal, eta=eta, k=k,
                     int_ior=int_ior, ext_ior=ext_ior, nonlinear=nonlinear,
                     transmittance=transmittance)
        for key in OPTIONAL_KEYS:
            if given[key] is not None and given[key] is not False and key not in rule.keys:
                fail(f"'{key}' does not apply to this type")
        if transmittance is not None:
            _check_transmittance(transmittance, specular, fail)
        textured = self._texture_columns(rule, fail, diffuse=diffuse, specular=specular,
                                         alpha=alpha, alpha_u=alpha_u, alpha_v=alpha_v)
        if isinstance(diffuse, str):
            diffuse = (0.0, 0.0, 0.0)
        if isinstance(specular, str):
            specular = (1.0, 1.0, 1.0)
        alpha, alpha_u, alpha_v = (DEFAULT_ALPHA if isinstance(a, str) else a
                                   for a in (alpha, alpha_u, alpha_v))
        m = _Material(rule.kind, _rgb(diffuse), _rgb(specular), float(exponent),
                      textures=textured,
                      transmission=None if transmittance is None else _rgb(transmittance))
        if distribution not in MICROFACET_DISTRIBUTIONS:
            fail(f"unknown distribution '{distribution}'; allowed: "
                 f"{', '.join(MICROFACET_DISTRIBUTIONS)}")
        m.distribution = MICROFACET_DISTRIBUTIONS[distribution]
        m.alpha_u, m.alpha_v = _roughness(rule, alpha, alpha_u, alpha_v, fail)
        if "metal" in rule.keys:
            m.eta, m.k = _conductor_index(metal, eta, k, fail)
        if rule.interface is not None:
            m.ior = _relative_ior(rule.interface, ior, int_ior, ext_ior, fail)
        elif ior is not None:   # stored and unused, as before
            m.ior = float(ior)
        m.nonlinear = bool(nonlinear)
        if not isinstance(one_sided, (bool, np.bool_)):
            fail(f"'one_sided' must be true or false, got {one_sided!r}")
        if one_sided and not rule.one_sided:
            fail("cannot be one-sided (a dielectric is two-sided by nature); one-sided types: "
                 + ", ".join(k for k, r in MATERIAL_RULES.items() if r.one_sided))
        m.one_sided = bool(one_sided)
        if isinstance(opacity, str):
            if opacity not in self.texture_names:
                fail(f"'opacity' names texture '{opacity}', which is not defined; defined: "
                     f"{', '.join(self.texture_names) or '(none)'}")
            m.opacity_texture = self.texture_names[opacity]
        elif (isinstance(opacity, (bool, np.bool_))
              or not isinstance(opacity, (int, float, np.integer, np.floating))
              or not 0.0 <= float(opacity) <= 1.0):
            fail(f"'opacity' must be a number in [0, 1] or a texture name, got {opacity!r}")
        else:
            m.opacity = float(opacity)
        if "diffuse" not in rule.colours:
            m.diffuse = (0.0, 0.0, 0.0)
        if "specular" not in rule.colours:
            m.specular = (0.0, 0.0, 0.0)
        self.material_names[name] = len(self.materials)
        self.materials.append(m)
        return self.material_names[name]

    def _texture_columns(self, rule: MaterialRule, fail, **params) -> dict:
        """TEX_* column -> texture row of the parameters that name a texture (by name)."""
        columns = {**TEXTURED_PARAMS, "alpha_u": TEX_ALPHA}
        textured = {}
        for key, v in params.items():
            if not isinstance(v, str):
                continue
            if v not in self.texture_names:
                fail(f"'{key}' names texture '{v}', which is not defined; defined: "
                     f"{', '.join(self.texture_names) or '(none)'}")
            if key not in rule.textured:
                fail(f"'{key}' cannot be textured for this type" + rule.untextured_why.get(key, ""))
            textured[columns[key]] = self.texture_names[v]
        if isinstance(params["alpha"], str):   # isotropic: alpha_v follows alpha_u
            textured[TEX_ALPHA_V] = textured[TEX_ALPHA]
        return textured

    def _mat(self, material) -> int:
        if isinstance(material, (int, np.integer)):
            return int(material)
        if material not in self.material_names:
            raise SceneError(f"unknown material '{material}'; defined: "
                             f"{', '.join(self.material_names) or '(none)'}")
        return self.material_names[material]

    def _unmasked_mat(self, material, shape: str) -> int:
        """The material row of a shape whose ray tests take no opacity mask (yet)."""
        m = self._mat(material)
        if _masked(self.materials[m]):
            raise SceneError(f"material '{self._material_name(m)}' has an opacity mask; jgi's "
                             f"{shape} shapes take none (masks work on spheres, rectangles, "
                             "cubes and meshes)")
        return m

    def _shape_mat(self, material, emission) -> int:
        """The material row of a shape; an emitting shape's must be opaque: light sampling
        takes the whole surface to emit, so a mask that lets rays through an emitter would
        make the strategies disagree."""
        m = self._mat(material)
        if emission is not None and _masked(self.materials[m]):
            raise SceneError(f"material '{self._material_name(m)}' has an opacity mask and is "
                             "used by an emitting shape; emitters must be opaque (opacity 1)")
        return m

    # --- shapes -----------------------------------------------------------------------------
    def sphere(self, center, radius: float, material, emission=None):
        self.spheres.append((np.asarray(center, float), float(radius),
                             self._shape_mat(material, emission),
                             None if emission is None else _rgb(emission)))

    def quad(self, origin, edge_u, edge_v, material, emission=None):
        self.quads.append((np.asarray(origin, float), np.asarray(edge_u, float),
                           np.asarray(edge_v, float), self._shape_mat(material, emission),
                           None if emission is None else _rgb(emission)))

    def disk(self, center, axis_u, axis_v, material, emission=None, normal=None,
             uv: str = "mitsuba"):
        """An analytic disk center + a axis_u + b axis_v, a^2 + b^2 <= 1 (an ellipse if the
        semi-axes differ). ``normal`` (the emitting side) defaults to axis_u x axis_v
        normalised; ``uv`` is "mitsuba" (r, phi / 2 pi) or "pbrt" (phi / 2 pi, 1 - r)."""
        c, au, av = (np.asarray(x, float).reshape(3) for x in (center, axis_u, axis_v))
        cr = np.cross(au, av)
        area = float(np.linalg.norm(cr))
        if not (np.all(np.isfinite(np.concatenate([c, au, av]))) and area > 0):
            raise SceneError(f"disk: the axes {list(au)} and {list(av)} span no area "
                             "(zero radius or a degenerate transform)")
        n = cr / area if normal is None else np.asarray(normal, float).reshape(3)
        if not np.linalg.norm(n) > 0:
            raise SceneError(f"disk: normal {list(n)} is zero")
        if uv not in ("mitsuba", "pbrt"):
            raise SceneError(f"disk: uv must be 'mitsuba' or 'pbrt', got {uv!r}")
        self.disks.append((c, au, av, n / np.linalg.norm(n), uv == "pbrt",
                           self._unmasked_mat(material, "disk"),
                           None if emission is None else _rgb(emission)))

    def cylinder(self, base, axis_u, axis_w, radius: float, height: float, material,
                 emission=None, outward: bool = True, axis_v=None):
        """An analytic open tube of ``radius`` around the segment base .. base + height axis_w
        (unit axis_w; phi = 0 along unit axis_u, which must be perpendicular to it). Its
        normal points away from the axis if ``outward`` (Mitsuba's and pbrt's default),
        towards it otherwise. phi turns from axis_u towards ``axis_v``, by default
        axis_w x axis_u (a mirrored frame gives -that)."""
        b, au, aw = (np.asarray(x, float).reshape(3) for x in (base, axis_u, axis_w))
        radius, height = float(radius), float(height)
        if not (np.isfinite(radius) and np.isfinite(height) and radius > 0 and height > 0):
            raise SceneError(f"cylinder: radius and height must be positive and finite, got "
                             f"{radius} and {height}")
        nu, nw = np.linalg.norm(au), np.linalg.norm(aw)
        if not (nu > 0 and nw > 0) or abs(np.dot(au, aw)) > 1e-6 * nu * nw:
            raise SceneError(f"cylinder: axis_u {list(au)} must be a non-zero vector "
                             f"perpendicular to the non-zero axis {list(aw)}")
        au, aw = au / nu, aw / nw
        av = np.cross(aw, au)
        if axis_v is not None:
            sign = np.sign(np.dot(np.asarray(axis_v, float).reshape(3), av))
            av = av * (sign if sign != 0 else 1.0)
        self.cylinders.append((b, au, av, aw, radius, height,
                               1.0 if outward else -1.0, self._unmasked_mat(material, "cylinder"),
                               None if emission is None else _rgb(emission)))

    def rectangle(self, to_world: np.ndarray, material, emission=None):
        """Mitsuba's ``rectangle``: [-1, 1]^2 in the z = 0 plane, normal +z, then ``to_world``."""
        o = xf.apply_point(to_world, [-1.0, -1.0, 0.0])
        u = xf.apply_point(to_world, [1.0, -1.0, 0.0]) - o
        v = xf.apply_point(to_world, [-1.0, 1.0, 0.0]) - o
        self.quad(o, u, v, material, emission)

    def cube(self, to_world: np.ndarray, material, emission=None):
        """Mitsuba's ``cube``: [-1, 1]^3 under ``to_world``. Without shear and emission it is
        stored as one oriented box; otherwise as six outward-facing quads. A cube whose
        material is textured is Mitsuba's cube mesh itself (:data:`CUBE_VERTICES`: twelve
        triangles, each face's uv spanning [0, 1]^2 as in Mitsuba's), so that its surface
        coordinates are Mitsuba's. So is a cube with an opacity mask (a box is one crossing
        per ray, where a mask needs the entry and the exit face)."""
        row = self.materials[self._mat(material)]
        if row.textures or _masked(row):
            self.mesh(CUBE_VERTICES, CUBE_FACES, material, emission, to_world=to_world,
                      uv=CUBE_UV)
            return
        cols = np.asarray(to_world, float)[:3, :3]
        half = np.linalg.norm(cols, axis=0)
        if emission is None and np.all(half > 0):
            axes = (cols / half).T
            if np.allclose(axes @ axes.T, np.eye(3), atol=1e-9):
                if np.linalg.det(axes) < 0:
                    axes[2] = -axes[2]
                self.boxes.append((xf.apply_point(to_world, [0.0, 0.0, 0.0]), axes, half,
                                   self._mat(material)))
                return
        faces = [  # (corner, edge u, edge v) with cross(u, v) pointing outwards
            ([-1, -1, 1], [2, 0, 0], [0, 2, 0]), ([1, -1, -1], [-2, 0, 0], [0, 2, 0]),
            ([1, -1, 1], [0, 0, -2], [0, 2, 0]), ([-1, -1, -1], [0, 0, 2], [0, 2, 0]),
            ([-1, 1, 1], [2, 0, 0], [0, 0, -2]), ([-1, -1, -1], [2, 0, 0], [0, 0, 2]),
        ]
        for c, u, v in faces:
            o = xf.apply_point(to_world, c)
            self.quad(o, xf.apply_vector(to_world, u), xf.apply_vector(to_world, v), material,
                      emission)

    def mesh(self, vertices, faces, material, emission=None, to_world=None, uv=None,
             normals=None):
        """Triangles ``faces`` of ``vertices``; ``uv`` ([V, 2], optional) are the vertices'
        surface coordinates (without them a triangle's are Mitsuba's (0,0), (1,0), (0,1)).

        ``normals`` makes the mesh smooth-shaded: a [V, 3] array of vertex normals (transformed
        by ``to_world``'s inverse transpose and normalised, as Mitsuba's loaders do), or
        ``"smooth"`` for Mitsuba's computed normals (:func:`smooth_vertex_normals` of the
        transformed vertices); None (default) shades flat with the geometric normal. The BSDF
        is then evaluated about the interpolated normal (:mod:`jgi.physics.geometry`)."""
        v = np.asarray(vertices, float)
        f = np.asarray(faces, np.int64)
        if to_world is not None:
            v = xf.apply_point(to_world, v)
        if uv is not None:
            uv = np.asarray(uv, float)
            if uv.shape != (len(v), 2):
                raise SceneError(f"mesh: expected uv of shape ({len(v)}, 2), got {uv.shape}")
        if isinstance(normals, str):
            if normals != "smooth":
                raise SceneError(f"mesh: normals must be an array, 'smooth' or None, got "
                                 f"'{normals}'")
            normals = smooth_vertex_normals(v, f)
        elif normals is not None:
            normals = np.asarray(normals, float)
            if normals.shape != (len(v), 3):
                raise SceneError(f"mesh: expected normals of shape ({len(v)}, 3), got "
                                 f"{normals.shape}")
            if not np.all(np.isfinite(normals)):
                raise SceneError("mesh: the vertex normals are not finite")
            if to_world is not None:
                normals = normals @ np.linalg.inv(np.asarray(to_world, float)[:3, :3])
            length = np.linalg.norm(normals, axis=1, keepdims=True)
            # a zero normal stays zero: hits there fall back to the geometric normal
            normals = np.where(length > 0, normals / np.where(length > 0, length, 1.0), 0.0)
        m = self._shape_mat(material, emission)
        e = None if emission is None else _rgb(emission)
        for i, (a, b, c) in enumerate(v[f]):
            self.triangles.append((a, b, c, m, e))
            self.triangle_uvs.append(None if uv is None else uv[f[i]])
            self.triangle_normals.append(None if normals is None else normals[f[i]])

    # --- lights -----------------------------------------------------------------------------
    def point_light(self, position, intensity):
        self.lights.append(dict(kind=POINT, p0=position, emission=_rgb(intensity)))

    def spot_light(self, position, target, intensity, cutoff_deg=30.0, falloff_deg=None,
                   profile="smoothstep"):
        """A spot light; between the falloff-start (beam) and cutoff cones its intensity falls
        as pbrt's smoothstep in the cosine (``profile="smoothstep"``) or as Mitsuba 3's ramp
        linear in the angle (``"linear"``)."""
        if profile not in ("smoothstep", "linear"):
            raise SceneError(f"spot light: profile '{profile}' unknown; supported: smoothstep, "
                             "linear")
        d = np.asarray(target, float) - np.asarray(position, float)
        falloff_deg = cutoff_deg * 0.75 if falloff_deg is None else falloff_deg
        if not 0 < cutoff_deg <= 90 or not 0 <= falloff_deg <= cutoff_deg:
            raise SceneError("spot light: need 0 < cutoff <= 90 and 0 <= falloff <= cutoff degrees")
        self.lights.append(dict(kind=SPOT, p0=position, direction=d / np.linalg.norm(d),
                                emission=_rgb(intensity),
                                cos_total=np.cos(np.radians(cutoff_deg)),
                                cos_falloff=np.cos(np.radians(falloff_deg)),
                                spot_linear=profile == "linear"))

    def directional_light(self, direction, irradiance):
        d = np.asarray(direction, float)
        self.lights.append(dict(kind=DIRECTIONAL, direction=d / np.linalg.norm(d),
                                emission=_rgb(irradiance)))

    def environment_light(self, radiance):
        if any(l["kind"] == ENVIRONMENT for l in self.lights):
            raise SceneError("only one environment light is allowed")
        self.lights.append(dict(kind=ENVIRONMENT, emission=_rgb(radiance)))

    def environment_map(self, image, scale=1.0, to_world=None, where="environment map",
                        mapping="latlong"):
        """An environment lit by an image: ``image`` an [H, W, 3] linear RGB array or a file
        name (EXR, or PNG / JPEG decoded from sRGB), radiance ``scale`` times its lookup,
        ``to_world`` a 4x4 (or 3x3) transform whose rotation turns the map's frame into the
        world's. ``mapping``: "latlong" (Mitsuba 3's ``envmap``, +y up, bilinear) or
        "octahedral" (pbrt-v4's image ``infinite`` light: a square equal-area octahedral image,
        +z up, nearest texel); see :class:`EnvironmentMap`. ``where`` names the source in
        errors."""
        if any(l["kind"] == ENVIRONMENT for l in self.lights):
            raise SceneError("only one environment light is allowed")
        if isinstance(image, (str, bytes)) or hasattr(image, "__fspath__"):
            try:
                image = read_image(image)
            except OSError as e:
                raise SceneError(f"{where}: cannot read the image ({e})") from None
        env = environment_map_table(image, to_world, where, mapping)
        self.lights.append(dict(kind=ENVIRONMENT, emission=_rgb(scale), envmap=env,
                                env_mean=float(environment_map_mean(env))))

    # --- camera -----------------------------------------------------------------------------
    def camera(self, position, look_at, up=(0, 1, 0), fov=40.0, width=256, height=256,
               fov_axis="y", mirror=False):
        """Pinhole camera; ``mirror`` flips the image horizontally (left-handed cameras, e.g.
        pbrt's LookAt without a ``Scale -1 1 1``)."""
        self.camera_args = dict(position=position, look_at=look_at, up=up, fov=fov,
                                width=width, height=height, fov_axis=fov_axis, mirror=mirror)

    # --- build ------------------------------------------------------------------------------
    def build(self) -> Scene:
        if self.camera_args is None:
            raise SceneError("the scene has no camera")
        elements = []  # light element rows
        sph_emit, quad_emit, tri_emit = [], [], []
        for c, r, m, e in self.spheres:
            sph_emit.append(-1 if e is None else len(elements))
            if e is not None:
                elements.append(dict(kind=AREA_SPHERE, p0=c, radius=r, emission=e,
                                     area=4 * np.pi * r * r))
        for o, u, v, m, e in self.quads:
            quad_emit.append(-1 if e is None else len(elements))
            if e is not None:
                n = np.cross(u, v)
                a = float(np.linalg.norm(n))
                elements.append(dict(kind=AREA_QUAD, p0=o, e1=u, e2=v, emission=e, area=a,
                                     normal=n / a if a > 0 else np.zeros(3)))
        for a_, b_, c_, m, e in self.triangles:
            tri_emit.append(-1 if e is None else len(elements))
            if e is not None:
                n = np.cross(b_ - a_, c_ - a_)
                a = float(np.linalg.norm(n))
                elements.append(dict(kind=AREA_TRIANGLE, p0=a_, e1=b_ - a_, e2=c_ - a_,
                                     emission=e, area=0.5 * a,
                                     normal=n / a if a > 0 else np.zeros(3)))
        disk_emit, cyl_emit = [], []
        for c, au, av, n, _, m, e in self.disks:
            disk_emit.append(-1 if e is None else len(elements))
            if e is not None:
                elements.append(dict(kind=AREA_DISK, p0=c, e1=au, e2=av, normal=n, emission=e,
                                     area=np.pi * float(np.linalg.norm(np.cross(au, av)))))
        for b, au, av, aw, r, h, out, m, e in self.cylinders:
            cyl_emit.append(-1 if e is None else len(elements))
            if e is not None:   # see Lights: normal holds the axis, radius the side
                elements.append(dict(kind=AREA_CYLINDER, p0=b, e1=au * r, e2=av * r,
                                     normal=aw * h, radius=out, emission=e,
                                     area=2 * np.pi * r * h))
        elements.extend(self.lights)
        center, radius = self._bounds()
        materials = self._build_materials()
        return Scene(
            camera=self._build_camera(),
            spheres=self._build_spheres(sph_emit),
            rects=self._build_rects(quad_emit),
            boxes=self._build_boxes(),
            quads=self._build_quads(quad_emit),
            triangles=self._build_triangles(tri_emit),
            materials=materials,
            lights=_build_lights(elements, center, radius),
            name=self.name,
            disks=self._build_disks(disk_emit) if self.disks else None,
            cylinders=self._build_cylinders(cyl_emit) if self.cylinders else None,
            medium=self._build_medium(),
            **self._build_bounded_media(),
        )

    # directions of the rays cast from a point to find the medium it lies in: three generic
    # ones, so that no ray runs along a face or through an edge of an axis-aligned shape
    PROBE_DIRECTIONS = np.array([[0.5377, 0.8301, -0.1466], [-0.6917, 0.1632, 0.7036],
                                 [0.2893, -0.5601, -0.7763]])

    def _bounded_medium_at(self, q: np.ndarray):
        """(medium name, shape, material) of the bounded medium point q lies in, or None where it
        lies in the scene's own. A ray from q finds the nearest surface that bounds media (a
        sphere, a cube, a quad or a mesh's triangle whose material has an interface): q lies in
        its interior if the ray leaves through it away from its normal, else in its exterior,
        as a path crossing it would (Mitsuba's and pbrt-v4's rule). Open shapes (a plane of
        water) count where a ray meets them; q is in a bounded medium if any of the rays of
        PROBE_DIRECTIONS says so."""
        bounding = lambda m: self.materials[m].interface is not None   # noqa: E731
        for d in self.PROBE_DIRECTIONS / np.linalg.norm(self.PROBE_DIRECTIONS, axis=1)[:, None]:
            hits = []   # (t, the ray leaves q's side through the normal's side, shape, material)
            for c, r, m, _ in self.spheres:
                if bounding(m):
                    oc = q - c
                    b, cc = oc @ d, oc @ oc - r * r
                    disc = b * b - cc
                    if disc > 0:
                        t0, t1 = -b - np.sqrt(disc), -b + np.sqrt(disc)
                        t = t0 if t0 > 0 else t1
                        if t > 0:   # outward normal: q outside when the ray enters (t0)
                            hits.append((t, t0 > 0, f"sphere at {np.round(c, 4).tolist()}", m))
            for c, a, h, m in self.boxes:
                if bounding(m):
                    p_local, d_local = a @ (q - c), a @ d
                    with np.errstate(divide="ignore", invalid="ignore"):
                        t_lo, t_hi = (-h - p_local) / d_local, (h - p_local) / d_local
                    near = np.max(np.minimum(t_lo, t_hi))
                    far = np.min(np.maximum(t_lo, t_hi))
                    if near < far and far > 0:
                        hits.append((near if near > 0 else far, near > 0,
                                     f"cube at {np.round(c, 4).tolist()}", m))
            planar = [(o, u, v, m, "quad") for o, u, v, m, _ in self.quads if bounding(m)]
            planar += [(a, b - a, c - a, m, "triangle") for a, b, c, m, _ in self.triangles
                       if bounding(m)]
            if planar:
                o, u, v = (V3(*np.array([x[k] for x in planar], float).T) for k in range(3))
                ray = lambda a: V3(*(np.full(len(planar), c) for c in a))   # noqa: E731

                def solve(det):   # numpy: the rejected rays' t is discarded by ``ok``
                    solved = np.abs(det) > 1e-12
                    return 1.0 / np.where(solved, det, 1.0), solved

                t, b1, b2, in_triangle = moller_trumbore(o, u, v, ray(q), ray(d), solve)
                triangle = np.array([x[4] == "triangle" for x in planar])
                cos = dot(cross(u, v), ray(d))   # the normal's side the ray meets: its sign
                in_quad = (np.abs(cos) > 1e-12) & (b1 >= 0) & (b1 <= 1) & (b2 >= 0) & (b2 <= 1)
                ok = (t > 0) & np.where(triangle, in_triangle, in_quad)
                for i in np.flatnonzero(ok):
                    o_i, _, _, m, kind = planar[i]
                    hits.append((t[i], cos[i] < 0,
                                 f"{kind} at {np.round(o_i, 4).tolist()}", m))
            if not hits:
                continue
            t, from_outside, what, m = min(hits, key=lambda h: h[0])
            interior, exterior = self.materials[m].interface
            name = exterior if from_outside else interior
            if name is not None:
                return name, what, m
        return None

    def _build_bounded_media(self) -> dict:
        """Scene.bounded_media and Scene.medium_interfaces (none: a scene before them)."""
        bounding = [m for m in self.materials if m.interface is not None]
        if not bounding:
            return {}
        if self.medium_args is not None and "volumes" in self.medium_args:
            raise SceneError("media bounded by shapes (medium_interface) with a grid medium "
                             "around them: allowed: a homogeneous medium or vacuum around "
                             "bounded media (a grid among them: bounded_grid_medium)")
        emitting = {m for *_, m, e in (*self.spheres, *self.quads, *self.triangles, *self.disks,
                                       *self.cylinders) if e is not None}
        for i in sorted(emitting):
            face = self.materials[i].interface
            if face is not None and face[1] is not None:
                raise SceneError(f"material '{self._material_name(i)}' is used by an emitting "
                                 f"shape and has exterior medium '{face[1]}': lights shine into "
                                 "the scene's own medium; allowed: exterior None")
        # point and spot lights, and the camera, in a bounded medium would sit in it, where
        # their paths start in the scene's own: refused
        points = [(f"a point or spot light at {np.asarray(light['p0'], float).tolist()}",
                   "lights shine into the scene's own medium", light["p0"])
                  for light in self.lights if light["kind"] in (POINT, SPOT)]
        points.append((f"the camera at {np.asarray(self.camera_args['position'], float).tolist()}",
                       "camera rays start in the scene's own medium",
                       self.camera_args["position"]))
        for who, why, q in points:
            found = self._bounded_medium_at(np.asarray(q, float))
            if found is not None:
                name, what, m = found
                raise SceneError(f"{who} lies in medium '{name}', inside the {what} of material "
                                 f"'{self._material_name(m)}': {why}; allowed: outside bounded "
                                 "media (or the medium as the scene's own)")
        ids = {name: k + 1 for k, name in enumerate(self.bounded_media)}
        # the grids' ids: after the homogeneous ones, in the order they were defined
        for g, name in enumerate(self.bounded_grids):
            ids[name] = len(self.bounded_media) + 1 + g
        grids = tuple(_grid_medium_of(a) for a in self.bounded_grids.values()) or None
        rows = [m.interface for m in (self.materials or [_Material(DIFFUSE)])]
        f = lambda key: V3(*(jnp.asarray([a[key][c] for a in self.bounded_media.values()],  # noqa: E731
                                         jnp.float32) for c in range(3)))
        media = None
        if self.bounded_media:
            media = Medium(f("sigma_t"), f("albedo"),
                           jnp.asarray([a["g"] for a in self.bounded_media.values()],
                                       jnp.float32))
        side = lambda r, k: -1 if r is None else (0 if r[k] is None else ids[r[k]])  # noqa: E731
        faces = MediumInterfaces(jnp.asarray([side(r, 0) for r in rows], jnp.int32),
                                 jnp.asarray([side(r, 1) for r in rows], jnp.int32))
        return dict(bounded_media=media, medium_interfaces=faces, bounded_grids=grids)

    def _build_medium(self) -> Medium | None:
        m = self.medium_args
        if m is None:
            return None
        f = lambda v: V3(*(jnp.float32(c) for c in v))  # noqa: E731
        if "volumes" in m:
            grids = tuple(_grid_medium_of(v) for v in m["volumes"])
            return grids[0] if len(grids) == 1 else grids
        return Medium(f(m["sigma_t"]), f(m["albedo"]), jnp.float32(m["g"]))

    def _material_name(self, m: int) -> str:
        return next((k for k, v in self.material_names.items() if v == m), str(m))

    def _textured(self) -> bool:
        """Whether hits need surface coordinates: a texture in some material's BSDF or
        opacity."""
        return any(m.textures or m.opacity_texture >= 0 for m in self.materials)

    def _bounds(self):
        pts = []
        for c, r, *_ in self.spheres:
            pts += [c - r, c + r]
        for o, u, v, *_ in self.quads:
            pts += [o, o + u, o + v, o + u + v]
        for a, b, c, *_ in self.triangles:
            pts += [a, b, c]
        for c, axes, half, _ in self.boxes:
            pts += [c - np.abs(axes.T) @ half, c + np.abs(axes.T) @ half]
        for c, au, av, *_ in self.disks:
            ext = np.sqrt(au * au + av * av)   # the ellipse's half extents along the axes
            pts += [c - ext, c + ext]
        for b, au, av, aw, r, h, *_ in self.cylinders:
            ext = r * np.sqrt(np.maximum(1.0 - aw * aw, 0.0))
            pts += [b - ext, b + ext, b + aw * h - ext, b + aw * h + ext]
        for l in self.lights:
            if "p0" in l:
                pts.append(np.asarray(l["p0"], float))
        if not pts:
            return np.zeros(3), 1.0
        pts = np.array(pts)
        lo, hi = pts.min(0), pts.max(0)
        center = 0.5 * (lo + hi)
        return center, max(float(np.linalg.norm(hi - lo)) * 0.5, 1e-3)

    def _build_camera(self) -> Camera:
        a = self.camera_args
        w, h = int(a["width"]), int(a["height"])
        if w <= 0 or h <= 0:
            raise SceneError(f"camera: width and height must be positive, got {w}x{h}")
        if not 0 < a["fov"] < 180:
            raise SceneError(f"camera: fov must be in (0, 180) degrees, got {a['fov']}")
        pos = np.asarray(a["position"], float)
        fwd = np.asarray(a["look_at"], float) - pos
        if np.linalg.norm(fwd) == 0:
            raise SceneError("camera: look_at equals position")
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, np.asarray(a["up"], float))
        if np.linalg.norm(right) < 1e-9:
            raise SceneError("camera: up is parallel to the viewing direction")
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        t = np.tan(np.radians(a["fov"]) / 2)
        axis = a.get("fov_axis", "y")
        if axis == "smaller":
            axis = "x" if w < h else "y"
        if axis == "x":
            tx, ty = t, t * h / w
        elif axis == "y":
            tx, ty = t * w / h, t
        else:
            raise SceneError(f"camera: fov_axis must be 'x', 'y' or 'smaller', got {axis!r}")
        if a.get("mirror"):
            right = -right
        return Camera(_v3_scalar(pos), _v3_scalar(fwd), _v3_scalar(right * tx), _v3_scalar(up * ty),
                      w, h)

    def _build_spheres(self, emit) -> Spheres:
        n = len(self.spheres)
        c = np.array([s[0] for s in self.spheres]).reshape(n, 3)
        r = np.array([s[1] for s in self.spheres], np.float32)
        if np.any(r < 0):
            raise SceneError("sphere radius must be non-negative")
        return Spheres(_v3(c), jnp.asarray(r, jnp.float32),
                       jnp.asarray([s[2] for s in self.spheres], jnp.int32),
                       jnp.asarray(emit, jnp.int32))

    def _rect_axis(self, q) -> int:
        """The axis a quad is an axis-aligned rectangle across, or -1."""
        u, v = q[1], q[2]
        scale = max(np.abs(u).max(), np.abs(v).max(), 1e-30)
        nz_u = np.abs(u) > 1e-12 * scale
        nz_v = np.abs(v) > 1e-12 * scale
        if nz_u.sum() != 1 or nz_v.sum() != 1 or np.argmax(nz_u) == np.argmax(nz_v):
            return -1
        return int(3 - np.argmax(nz_u) - np.argmax(nz_v))

    def _build_rects(self, emit) -> Rects:
        rows = [(self._rect_axis(q), i) for i, q in enumerate(self.quads)]
        rows = sorted((a, i) for a, i in rows if a >= 0)
        plane, lo_a, hi_a, lo_b, hi_b, nrm, mat, em = [], [], [], [], [], [], [], []
        for axis, i in rows:
            o, u, v, m, _ = self.quads[i]
            a, b = [k for k in range(3) if k != axis]
            corners = np.array([o, o + u, o + v, o + u + v])
            plane.append(o[axis])
            lo_a.append(corners[:, a].min()); hi_a.append(corners[:, a].max())
            lo_b.append(corners[:, b].min()); hi_b.append(corners[:, b].max())
            n = np.zeros(3)
            n[axis] = np.sign(np.cross(u, v)[axis])
            nrm.append(n)
            mat.append(m)
            em.append(emit[i])
        counts = tuple(sum(1 for a, _ in rows if a == k) for k in range(3))
        f32 = lambda x: jnp.asarray(np.asarray(x, np.float32).reshape(-1))
        uv = {}
        if self._textured():
            qs = [self.quads[i] for _, i in rows]
            o = np.array([q[0] for q in qs]).reshape(-1, 3)
            du, dv = _duals(np.array([q[1] for q in qs]).reshape(-1, 3),
                            np.array([q[2] for q in qs]).reshape(-1, 3))
            uv = dict(origin=_v3(o), dual_u=_v3(du), dual_v=_v3(dv))
        return Rects(f32(plane), f32(lo_a), f32(hi_a), f32(lo_b), f32(hi_b),
                     _v3(np.asarray(nrm).reshape(-1, 3)), jnp.asarray(mat, jnp.int32).reshape(-1),
                     jnp.asarray(em, jnp.int32).reshape(-1), counts, **uv)

    def _build_boxes(self) -> Boxes:
        n = len(self.boxes)
        c = np.array([b[0] for b in self.boxes]).reshape(n, 3)
        ax = np.array([b[1] for b in self.boxes]).reshape(n, 3, 3)
        h = np.array([b[2] for b in self.boxes]).reshape(n, 3)
        return Boxes(_v3(c), _v3(ax[:, 0]), _v3(ax[:, 1]), _v3(ax[:, 2]), _v3(h),
                     jnp.asarray([b[3] for b in self.boxes], jnp.int32).reshape(-1),
                     jnp.full((n,), -1, jnp.int32))

    def _build_quads(self, emit) -> Quads:
        keep = [i for i, q in enumerate(self.quads) if self._rect_axis(q) < 0]
        n = len(keep)
        qs = [self.quads[i] for i in keep]
        o = np.array([q[0] for q in qs]).reshape(n, 3)
        u = np.array([q[1] for q in qs]).reshape(n, 3)
        v = np.array([q[2] for q in qs]).reshape(n, 3)
        nrm = np.cross(u, v)
        ln = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.where(ln > 0, nrm / np.where(ln > 0, ln, 1), 0.0)
        return Quads(_v3(o), _v3(u), _v3(v), _v3(nrm),
                     jnp.asarray([q[3] for q in qs], jnp.int32).reshape(-1),
                     jnp.asarray([emit[i] for i in keep], jnp.int32).reshape(-1))

    def _build_disks(self, emit) -> Disks:
        rows = self.disks
        col = lambda k: np.array([r[k] for r in rows]).reshape(len(rows), 3)  # noqa: E731
        return Disks(_v3(col(0)), _v3(col(1)), _v3(col(2)), _v3(col(3)),
                     jnp.asarray([r[5] for r in rows], jnp.int32),
                     jnp.asarray(emit, jnp.int32),
                     jnp.asarray([r[4] for r in rows], bool) if self._textured() else None)

    def _build_cylinders(self, emit) -> Cylinders:
        rows = self.cylinders
        col = lambda k: np.array([r[k] for r in rows]).reshape(len(rows), 3)  # noqa: E731
        f32 = lambda k: jnp.asarray([r[k] for r in rows], jnp.float32)  # noqa: E731
        return Cylinders(_v3(col(0)), _v3(col(1)), _v3(col(2)), _v3(col(3)), f32(4), f32(5),
                         f32(6), jnp.asarray([r[7] for r in rows], jnp.int32),
                         jnp.asarray(emit, jnp.int32))

    def _build_triangles(self, emit) -> Triangles:
        n = len(self.triangles)
        a = np.array([t[0] for t in self.triangles]).reshape(n, 3)
        b = np.array([t[1] for t in self.triangles]).reshape(n, 3)
        c = np.array([t[2] for t in self.triangles]).reshape(n, 3)
        e1, e2 = b - a, c - a
        nrm = np.cross(e1, e2)
        ln = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.where(ln > 0, nrm / np.where(ln > 0, ln, 1), 0.0)
        use_bvh = n >= BVH_MIN_TRIANGLES if self.bvh is None else bool(self.bvh) and n > 0
        uv = None
        if self._textured():
            default = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
            t_uv = np.array([default if x is None else x for x in self.triangle_uvs]
                            + [default] * (n - len(self.triangle_uvs))).reshape(n, 3, 2)
            uv = jnp.asarray(np.concatenate([t_uv[:, 0], t_uv[:, 1] - t_uv[:, 0],
                                             t_uv[:, 2] - t_uv[:, 0]], 1), jnp.float32)
        normals = None
        if any(x is not None for x in self.triangle_normals):
            ns = [np.repeat(nrm[i][None], 3, 0) if i >= len(self.triangle_normals)
                  or self.triangle_normals[i] is None else self.triangle_normals[i]
                  for i in range(n)]
            normals = jnp.asarray(np.asarray(ns, np.float32).reshape(n, 9))
        return Triangles(_v3(a), _v3(e1), _v3(e2), _v3(nrm),
                         jnp.asarray([t[3] for t in self.triangles], jnp.int32),
                         jnp.asarray(emit, jnp.int32),
                         build_bvh(a, b, c) if use_bvh else None, uv, normals)

    def _build_materials(self) -> Materials:
        ms = self.materials or [_Material(DIFFUSE, (0.5, 0.5, 0.5))]
        for m in ms:
            if m.kind == PHONG and m.exponent < 0:
                raise SceneError("phong exponent must be >= 0")
            if m.kind == DIELECTRIC and m.ior <= 0:
                raise SceneError("dielectric ior must be > 0")
        # roughplastic coatings: T(cos theta) and Ri, once per (distribution, alpha, eta);
        # plastic's smooth coating: Ri = fdr_int, the diffuse Fresnel reflectance seen from inside
        table = np.ones((len(ms), TABLE_SIZE), np.float64)
        internal = np.zeros(len(ms), np.float64)
        cache: dict = {}
        for i, m in enumerate(ms):
            if m.kind == PLASTIC:
                internal[i] = fresnel_diffuse_reflectance(1.0 / np.float32(m.ior))
            if m.kind == ROUGH_PLASTIC:
                key = (m.distribution, np.float32(m.alpha_u), np.float32(m.ior))
                if key not in cache:
                    cache[key] = plastic_tables(*key)
                table[i], internal[i] = cache[key]
        f32 = lambda x: jnp.asarray(np.asarray(x, np.float32))  # noqa: E731
        tex = {}
        if any(m.textures or m.opacity_texture >= 0 for m in ms):
            index = np.full((len(ms), len(TEXTURED_PARAMS)), -1, np.int32)
            for i, m in enumerate(ms):
                for col, t in m.textures.items():
                    index[i, col] = t
            cols = {c for m in ms for c in m.textures}
            if np.array_equal(index[:, TEX_ALPHA], index[:, TEX_ALPHA_V]):
                cols.discard(TEX_ALPHA_V)   # isotropic only: alpha_v follows alpha_u
            else:
                cols.add(TEX_ALPHA_V)       # a constant alpha_v (-1) must not follow
            tex = dict(textures=self._build_textures(), texture=jnp.asarray(index),
                       textured=tuple(sorted(cols)))
        return Materials(
            kind=jnp.asarray([m.kind for m in ms], jnp.int32),
            diffuse=_v3([m.diffuse for m in ms]),
            specular=_v3([m.specular for m in ms]),
            exponent=f32([m.exponent for m in ms]),
            ior=f32([m.ior for m in ms]),
            alpha_u=f32([m.alpha_u for m in ms]),
            alpha_v=f32([m.alpha_v for m in ms]),
            distribution=jnp.asarray([m.distribution for m in ms], jnp.int32),
            eta=_v3([m.eta for m in ms]),
            k=_v3([m.k for m in ms]),
            transmittance=f32(table),
            internal_reflectance=f32(internal),
            nonlinear=jnp.asarray([m.nonlinear for m in ms], bool),
            transmission_tint=_v3([m.specular if m.transmission is None else m.transmission
                                   for m in ms]),
            kinds=tuple(sorted({m.kind for m in ms})),
            distributions=tuple(sorted({m.distribution for m in ms if m.kind in ROUGH_KINDS})),
            conductor_fresnel=any(m.kind in (MIRROR, ROUGH_CONDUCTOR)
                                  and bool(np.any(np.asarray(m.eta) != 0)) for m in ms),
            one_sided=(jnp.asarray([m.one_sided for m in ms], bool)
                       if any(m.one_sided for m in ms) else None),
            # None without masks: such scenes compile to the programs from before masks
            opacity=f32([m.opacity for m in ms]) if any(map(_masked, ms)) else None,
            opacity_texture=(jnp.asarray([m.opacity_texture for m in ms], jnp.int32)
                             if any(m.opacity_texture >= 0 for m in ms) else None),
            **tex,
        )

    def _build_textures(self) -> Textures:
        ts = self.textures
        offsets, texels, at = [], [], 0
        for t in ts:
            offsets.append(at)
            if t.image is not None:
                texels.append(t.image.reshape(-1, 3))
                at += t.image.shape[0] * t.image.shape[1]
        atlas = np.concatenate(texels) if texels else np.zeros((1, 3), np.float32)
        size = lambda t, k: 1 if t.image is None else t.image.shape[k]  # noqa: E731
        return Textures(
            kind=jnp.asarray([t.kind for t in ts], jnp.int32),
            color0=_v3([t.color0 for t in ts]), color1=_v3([t.color1 for t in ts]),
            to_uv=jnp.asarray(np.asarray([t.to_uv for t in ts], np.float32).reshape(-1, 6)),
            offset=jnp.asarray(offsets, jnp.int32),
            width=jnp.asarray([size(t, 1) for t in ts], jnp.int32),
            height=jnp.asarray([size(t, 0) for t in ts], jnp.int32),
            atlas=jnp.asarray(atlas, jnp.float32),
            kinds=tuple(sorted({t.kind for t in ts})))


def _masked(m: _Material) -> bool:
    """Whether a material row has an opacity mask (a constant below 1, or a texture)."""
    return m.opacity < 1.0 or m.opacity_texture >= 0


def smooth_vertex_normals(vertices, faces) -> np.ndarray:
    """Mitsuba 3's ``Mesh::recompute_vertex_normals``: each vertex's normal is the sum of its
    triangles' unit normals weighted by the triangle's angle at that vertex (Thuermer and
    Wuethrich 1998), normalised; degenerate triangles add nothing, and a vertex with no
    usable triangle gets Mitsuba's placeholder (1, 0, 0)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    p = v[f]                                          # [F, 3, 3]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1)
    good = length > 0
    n = n[good] / length[good, None]
    p, f = p[good], f[good]
    out = np.zeros_like(v)
    for j in range(3):
        d0 = p[:, (j + 1) % 3] - p[:, j]
        d1 = p[:, (j + 2) % 3] - p[:, j]
        d0 = d0 / np.maximum(np.linalg.norm(d0, axis=1, keepdims=True), 1e-300)
        d1 = d1 / np.maximum(np.linalg.norm(d1, axis=1, keepdims=True), 1e-300)
        # the angle between unit vectors, accurate near 0 and pi (Mitsuba's unit_angle)
        dot_ = np.sum(d0 * d1, axis=1)
        angle = np.where(dot_ >= 0, 2 * np.arcsin(np.clip(0.5 * np.linalg.norm(d1 - d0, axis=1),
                                                          0, 1)),
                         np.pi - 2 * np.arcsin(np.clip(0.5 * np.linalg.norm(d1 + d0, axis=1),
                                                       0, 1)))
        np.add.at(out, f[:, j], n * angle[:, None])
    length = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(length > 0, out / np.where(length > 0, length, 1.0), [1.0, 0.0, 0.0])


def _duals(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows with dual_u . u = 1, dual_u . v = 0 (and vice versa) in each parallelogram's plane."""
    n = np.cross(u, v)
    n2 = np.sum(n * n, 1, keepdims=True)
    inv = np.where(n2 > 0, 1.0 / np.where(n2 > 0, n2, 1.0), 0.0)
    return np.cross(v, n) * inv, np.cross(n, u) * inv


def _rgb(v) -> tuple:
    a = np.broadcast_to(np.asarray(v, float), (3,))
    if not np.all(np.isfinite(a)):
        raise SceneError(f"colour {list(a)} is not finite")
    return tuple(float(x) for x in a)


def luminance_np(rgb) -> float:
    r, g, b = rgb
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


def light_power(el: dict, radius: float) -> float:
    """Emitted power (luminance), used for power-proportional light selection."""
    lum = luminance_np(el["emission"])
    k = el["kind"]
    if k in (AREA_QUAD, AREA_TRIANGLE, AREA_SPHERE, AREA_DISK, AREA_CYLINDER):
        return np.pi * el["area"] * lum
    if k == POINT:
        return 4 * np.pi * lum
    if k == SPOT and el.get("spot_linear", False):
        # 2 pi int_0^cutoff falloff(theta) sin(theta) d theta, the falloff linear in theta
        c, b = np.arccos(el["cos_total"]), np.arccos(el["cos_falloff"])
        ramp = (np.sin(b) - np.sin(c)) / (c - b) if c - b > 1e-6 else -np.cos(c)
        return 2 * np.pi * (1 + ramp) * lum
    if k == SPOT:
        return 2 * np.pi * (1 - 0.5 * (el["cos_total"] + el["cos_falloff"])) * lum
    if k == DIRECTIONAL:
        return np.pi * radius * radius * lum
    if k == ENVIRONMENT:   # a map's mean luminance over the sphere scales its emission's
        return 4 * np.pi * np.pi * radius * radius * lum * el.get("env_mean", 1.0)
    raise AssertionError(k)


def _build_lights(elements: list, center, radius) -> Lights:
    k = len(elements)
    power = np.array([light_power(e, radius) for e in elements], float)
    if k and power.sum() > 0:
        pmf = power / power.sum()
    else:
        pmf = np.full(k, 1.0 / max(k, 1))
    cdf = np.cumsum(pmf)
    if k:
        cdf[-1] = 1.0

    def col(key, default):
        return [e.get(key, default) for e in elements]

    z3 = (0.0, 0.0, 0.0)
    env = [i for i, e in enumerate(elements) if e["kind"] == ENVIRONMENT]
    return Lights(
        kind=jnp.asarray(col("kind", 0), jnp.int32),
        p0=_v3(col("p0", z3)), e1=_v3(col("e1", z3)), e2=_v3(col("e2", z3)),
        radius=jnp.asarray(col("radius", 0.0), jnp.float32),
        normal=_v3(col("normal", z3)), direction=_v3(col("direction", (0.0, 0.0, 1.0))),
        emission=_v3(col("emission", z3)),
        cos_total=jnp.asarray(col("cos_total", 1.0), jnp.float32),
        cos_falloff=jnp.asarray(col("cos_falloff", 1.0), jnp.float32),
        spot_linear=jnp.asarray(col("spot_linear", False), bool),
        area=jnp.asarray(col("area", 0.0), jnp.float32),
        pmf=jnp.asarray(pmf, jnp.float32), cdf=jnp.asarray(cdf, jnp.float32),
        bound_center=_v3_scalar(center), bound_radius=jnp.asarray(radius, jnp.float32),
        kinds=tuple(sorted({e["kind"] for e in elements})),
        environment=env[0] if env else -1,
        envmap=elements[env[0]].get("envmap") if env else None,
    )


ENVIRONMENT_MAPPINGS = ("latlong", "octahedral")


def environment_map_table(image, to_world=None, where="environment map",
                          mapping="latlong") -> EnvironmentMap:
    """The :class:`EnvironmentMap` of an [H, W, 3] linear RGB image: its sampling tables
    (latlong: cells between texel centres weighted by mean luminance times solid angle;
    octahedral: texels weighted by their channels' mean, pbrt-v4's choice, all of one solid
    angle) and the rotation of ``to_world`` (4x4 or 3x3; its scale and shear are removed, as
    directions have none)."""
    if mapping not in ENVIRONMENT_MAPPINGS:
        raise SceneError(f"{where}: unknown mapping {mapping!r}; allowed: "
                         f"{', '.join(ENVIRONMENT_MAPPINGS)}")
    img = np.asarray(image, np.float64)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 2 or img.shape[1] < 1:
        raise SceneError(f"{where}: expected an [H, W, 3] image with H >= 2, got shape "
                         f"{img.shape}")
    if mapping == "octahedral" and img.shape[0] != img.shape[1]:
        raise SceneError(f"{where}: an equal-area octahedral map must be square (N x N "
                         f"texels, as pbrt-v4 requires), got {img.shape[1]} x {img.shape[0]}")
    if not np.all(np.isfinite(img)) or np.any(img < 0):
        raise SceneError(f"{where}: texels must be finite and non-negative")
    H, W = img.shape[:2]
    if mapping == "octahedral":
        weight = img.mean(2)             # equal solid angles: no Jacobian
        solid = np.ones_like(weight)
        cos_edge = np.zeros(0)
    else:
        lum = np.maximum(img @ np.array([0.2126, 0.7152, 0.0722]), 0.0)
        cell = 0.25 * (lum[:-1] + lum[1:] + np.roll(lum[:-1], -1, 1) + np.roll(lum[1:], -1, 1))
        cos_edge = np.cos(np.pi * np.arange(H) / (H - 1))
        cos_edge[-1] = -1.0
        solid = np.broadcast_to((cos_edge[:-1] - cos_edge[1:])[:, None] * (2 * np.pi / W),
                                cell.shape)
        weight = cell * solid
    if weight.sum() <= 0:               # a black map: sample uniformly (its power is 0 anyway)
        weight = np.array(solid, np.float64)
    row = weight.sum(1)
    row_pmf = row / row.sum()
    col_pmf = np.where(row[:, None] > 0, weight / np.where(row > 0, row, 1.0)[:, None], 1.0 / W)
    row_cdf = np.cumsum(row_pmf)
    row_cdf[-1] = 1.0
    col_cdf = np.cumsum(col_pmf, 1)
    col_cdf[:, -1] = 1.0
    m = np.eye(3) if to_world is None else np.asarray(to_world, np.float64)[:3, :3]
    if not np.all(np.isfinite(m)) or abs(np.linalg.det(m)) < 1e-12:
        raise SceneError(f"{where}: to_world is singular or not finite")
    u_, _, vt = np.linalg.svd(m)       # the nearest rotation (polar decomposition)
    rot = u_ @ vt
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return EnvironmentMap(texels=f32(img), row_pmf=f32(row_pmf), row_cdf=f32(row_cdf),
                          col_pmf=f32(col_pmf), col_cdf=f32(col_cdf), cos_edge=f32(cos_edge),
                          to_world=f32(rot), mapping=mapping)


def environment_map_mean(env: EnvironmentMap) -> float:
    """The map's luminance averaged over the sphere of directions (latlong: cells' mean
    texels; octahedral: the texels', each of one solid angle)."""
    img = np.asarray(env.texels, np.float64)
    lum = np.maximum(img @ np.array([0.2126, 0.7152, 0.0722]), 0.0)
    if env.octahedral:
        return float(lum.mean())
    cell = 0.25 * (lum[:-1] + lum[1:] + np.roll(lum[:-1], -1, 1) + np.roll(lum[1:], -1, 1))
    ce = np.asarray(env.cos_edge, np.float64)
    solid = (ce[:-1] - ce[1:])[:, None] * (2 * np.pi / img.shape[1])
    return float((cell * solid).sum() / (4 * np.pi))


def pbrt_map_illuminance(image) -> float:
    """The illuminance (luminance units) pbrt-v4 ascribes to an equal-area octahedral map of
    radiance ``image`` ([N, N, 3]) when it scales the map to a requested "illuminance": the sum
    over texels whose centre lies above the light's xy plane of luminance x cos(theta) at the
    centre, times 2 pi / N^2 (lights.cpp, ImageInfiniteLight). A texel's solid angle is
    4 pi / N^2, so this is about half the map's illuminance (a constant map of luminance L:
    about pi L / 2, not pi L), and pbrt renders a map scaled by E over it with illuminance
    about 2 E. jgi scales as pbrt does, so a file renders as in pbrt."""
    img = np.asarray(image, np.float64)
    N = img.shape[0]
    g = (np.arange(N) + 0.5) / N
    S, T = np.meshgrid(g, g, indexing="xy")           # S varies along columns (s), T rows (t)
    z = warps.equal_area_square_to_sphere(S, T, xp=np).z
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    return float(np.sum(np.where(z > 0, lum * z, 0.0)) * 2 * np.pi / (N * N))
