"""Mitsuba 3 XML scenes -> jgi scenes, for the subset jgi represents exactly.

Supported (anything else is refused with the file, the line, the plugin and what is
supported):

  sensor     perspective: fov, fov_axis (x | y | smaller | larger | diagonal), to_world;
             film hdrfilm: width, height (pixel filter, sampler and integrator are ignored:
             jgi uses box pixel filtering and its own estimators; read_mitsuba_integrator
             gives the integrator's max_depth, rr_depth and hide_emitters, through the moment
             and aov wrappers, to pass to them)
  bsdf       diffuse (reflectance); conductor and roughconductor (material: a name from jgi's
             table of metals, or eta / k as rgb, float or constant spectrum;
             specular_reflectance; material "none" without eta and k is a 100 % reflector);
             dielectric and roughdielectric (int_ior / ext_ior as numbers or Mitsuba's names,
             ior = int / ext; specular_reflectance tints reflection and
             specular_transmittance transmission, constants; a texture tints both, as both
             <ref>s to one texture; other textured tints are refused);
             roughplastic and plastic (smooth: a Dirac coating reflection over a diffuse
             base) (diffuse_reflectance, specular_reflectance, int_ior, ext_ior,
             nonlinear). The reflective ones (every BSDF but the dielectrics, and a shape's
             default diffuse) are one-sided, as in Mitsuba: black seen or lit from the back
             of the surface (jgi's ``one_sided`` material flag); twosided around any of them
             (nested or a <ref>; one BSDF, or the same one twice, for front and back;
             Mitsuba refuses transmissive ones, and jgi two different ones) is that BSDF on
             both sides. mask (opacity: float, rgb, spectrum or texture, default 0.5) around
             any of them, twosided included: jgi's ``opacity`` on a copy of the nested row,
             tested in ray traversal (a mask in a mask multiplies constant opacities; a mask
             in twosided is refused, as by Mitsuba; so is a mask on an area emitter's shape).
             rough plugins: distribution beckmann | ggx, alpha or alpha_u / alpha_v (not for
             roughplastic; anisotropic only where Mitsuba's shading frame is jgi's, see
             check_anisotropy_frame: rectangles whose to_world x axis, and meshes whose
             triangles' first edges, are jgi's tangent); sample_visible is accepted and ignored (it
             changes Mitsuba's sampling, not the BSDF). Omitted parameters take Mitsuba's
             defaults: distribution beckmann, alpha 0.1 (values below 1e-4 are raised to 1e-4,
             as Mitsuba does), specular_reflectance 1, conductor material "none", dielectric
             int_ior bk7 (1.5046), (rough)plastic diffuse_reflectance 0.5, int_ior
             polypropylene (1.49), nonlinear false, ext_ior air (1.000277). Unknown parameters
             are refused (Mitsuba refuses unreferenced properties too). null: no surface; a
             shape with it is left out, or, a cube (any affine to_world) or sphere holding a
             medium in vacuum (Mitsuba's usual volume; the sensor outside, or inside with the
             medium as its own), becomes jgi's grid medium cut to the shape (see
             _Importer.null_shape). A shape without a bsdf is diffuse 0.5, or black if it
             emits (as in Mitsuba 3). Refused: the other plugins.
  texture    bitmap (filename: PNG, JPEG or EXR; filter_type bilinear; wrap_mode repeat; raw;
             to_uv: the 4 x 4 transform's rows / columns 0, 1, 3, as Mitsuba takes them) and
             checkerboard (color0, color1, to_uv), nested or at the top level with an
             id and a <ref name=...>, for diffuse's reflectance, (rough)plastic's
             diffuse_reflectance, the specular_reflectance of conductors and (rough)plastic, and
             the alpha or alpha_u / alpha_v of roughconductor and roughdielectric (not
             roughplastic's alpha, a <float> in Mitsuba).
             Other filters and wrap modes are refused. Textured spheres must not be rotated.
             A checkerboard that drives a roughness is read as Mitsuba 3.9.1's eval_1 reads
             it: color0 and color1 exchanged (see _Importer.scalar_texture).
             Textured OBJ meshes take the file's texture coordinates (v flipped, as Mitsuba's
             OBJ loader does), textured PLY meshes the vertex properties u, v (or s, t, or
             texture_u, texture_v: Mitsuba's names; v as written), both Mitsuba's (0,0), (1,0),
             (0,1) per triangle without them. Textured cubes take Mitsuba's per-face uv
             (SceneBuilder.cube).
  shape      rectangle, cube, sphere (center/radius or a uniform-scale to_world), disk
             (to_world without shear), cylinder (p0, p1, radius; to_world keeping it
             circular and upright), obj, ply,
             serialized (Mitsuba's compressed format, versions 3 and 4, one of several meshes
             by shape_index; its normals and uv as stored, vertex colours skipped and the
             face-normal flag ignored, as Mitsuba 3.9.1 does):
             with face_normals="true" shaded flat; otherwise, as Mitsuba, with vertex normals
             (the file's, transformed and normalised, or, when it has none, Mitsuba's smooth
             angle-weighted ones: jgi.scene.builder.smooth_vertex_normals) interpolated into a
             shading normal. OBJ files are then read as Mitsuba reads them (a vertex per
             position / texture / normal index triple). Refused on smooth meshes: area
             emission (jgi's emitters radiate about the geometric normal) and anisotropic
             roughness
  emitter    area (radiance), point (intensity, position or to_world), spot (intensity,
             cutoff_angle, beam_width: Mitsuba's falloff, linear in the angle between the two
             cones; to_world), directional (direction, irradiance), constant (radiance),
             envmap (filename: EXR, Radiance HDR, PNG or JPEG latitude-longitude image;
             scale; to_world)
  media      homogeneous (sigma_t, albedo, scale; phase isotropic or hg), nested in or
             referenced by the <sensor>: the camera's medium, jgi's scene medium. Shapes may
             name media (<ref name="interior"/"exterior"> or nested): a ray takes the medium
             on the side it leaves such a shape to, as in Mitsuba 3's volpath; homogeneous
             media other than the sensor's (and vacuum, where the sensor has a medium) become
             media bounded by shapes (glass holding milk, a fog inside a dielectric shell), and
             so do heterogeneous media, the sensor's being homogeneous or none (smoke in
             glass jars; each zero outside its grid's box). Refused: a heterogeneous medium
             with another as the sensor's or a null shape's, an area emitter whose exterior is
             not the sensor's medium, a shape medium on a masked bsdf, and other medium
             plugins
  values     rgb, float, spectrum (a constant, wavelength:value pairs, a filename= .spd
             file, blackbody in emitters: converted to RGB as Mitsuba 3's RGB variants
             do, jgi.scene.spectra; a blackbody as its spectral variants' RGB film sees
             it, since its RGB variants cannot render one); <default> and $name
             substitution; <ref>; <include>; <path> (relative file names are looked up as
             Mitsuba's file resolver does: in the <path> folders, the latest first, then in
             the main scene file's folder, for included files too); transforms translate,
             rotate (about the axis as given: Mitsuba does not normalise it), scale, matrix
             (16 values, or 9: a 3 x 3 in the upper left of a 4 x 4), lookat (each applied
             after the previous one, as Mitsuba does)

Units need no conversion: Mitsuba's radiance (W m^-2 sr^-1), intensity (W sr^-1) and
irradiance (W m^-2) are jgi's.
"""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
import xml.parsers.expat as expat
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ...core import transform as xf
from .. import spectra
from ..builder import SceneBuilder, SceneError, luminance_np, smooth_vertex_normals
from ..tables import DIELECTRIC, ROUGH_DIELECTRIC, Scene
from ._common import (
    NAMED_IOR,
    ImportError_,
    axis_aligned,
    has_texture_coordinates,
    load_mesh,
    load_mesh_with_normals,
    named_metals,
    normals_are_flat,
    read_serialized,
    same_region,
    tangent_frame,
    zero_faces,
)
from .volgrid import VolError, read_vol

SUPPORTED = {
    "sensor": ("perspective",),
    "bsdf": ("diffuse", "conductor", "roughconductor", "dielectric", "roughdielectric",
             "roughplastic", "plastic", "twosided", "mask", "null"),
    "shape": ("rectangle", "cube", "sphere", "disk", "cylinder", "obj", "ply", "serialized"),
    "emitter": ("area", "point", "spot", "directional", "constant", "envmap"),
    "medium": ("homogeneous", "heterogeneous"),
    "phase": ("isotropic", "hg"),
}
IGNORED_TAGS = ("sampler", "rfilter")
# Mitsuba 3's integrators that wrap others (their nested <integrator>s): read through to the
# inner one's settings
WRAPPER_INTEGRATORS = ("moment", "aov")

_ROUGH = ("distribution", "alpha", "alpha_u", "alpha_v", "sample_visible")
# The parameters each BSDF plugin takes (Mitsuba refuses unreferenced properties too).
# sample_visible only changes how Mitsuba samples, not the BSDF: it is accepted and ignored.
BSDF_PARAMETERS = {
    "diffuse": ("reflectance",),
    "conductor": ("material", "eta", "k", "specular_reflectance"),
    "roughconductor": ("material", "eta", "k", "specular_reflectance") + _ROUGH,
    "dielectric": ("int_ior", "ext_ior", "specular_reflectance", "specular_transmittance"),
    "roughdielectric": ("int_ior", "ext_ior", "specular_reflectance",
                        "specular_transmittance") + _ROUGH,
    "roughplastic": ("diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior",
                     "nonlinear") + _ROUGH,   # alpha_u / alpha_v: refused as Mitsuba does
    "plastic": ("diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior", "nonlinear"),
    "twosided": (),
    "mask": ("opacity",),
    "null": (),
}
DISTRIBUTIONS = ("beckmann", "ggx")
# Texture plugins and their parameters (Mitsuba's names).
TEXTURE_PARAMETERS = {
    "bitmap": ("filename", "filter_type", "wrap_mode", "raw", "to_uv"),
    "checkerboard": ("color0", "color1", "to_uv"),
}


def mitsuba_frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba 3's tangents (s, t) of unit n (``coordinate_system``, Duff et al. 2017)."""
    sign = 1.0 if n[2] >= 0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return (np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]]),
            np.array([b, sign + n[1] * n[1] * a, -n[1]]))


class IntegratorSettings(NamedTuple):
    """The light-transport settings of a Mitsuba scene's integrator (the innermost one, through
    ``moment`` and ``aov`` wrappers), Mitsuba's defaults filled in: what to pass to jgi's
    estimators to render what Mitsuba renders (``max_depth`` counts as Mitsuba's and jgi's do:
    1 = emitters seen directly; None = unbounded, Mitsuba's -1)."""

    type: str | None            # "path", "volpath", ...; None: an aov integrator without one
    max_depth: int | None = None
    rr_depth: int = 5
    hide_emitters: bool = False
    wrappers: tuple = ()        # the wrappers read through, outermost first


class TextureRef(str):
    """A parameter given as a <texture> or a <ref> to one: the texture's name in the builder."""
MIN_ALPHA = 1e-4   # Mitsuba's MicrofacetDistribution clamps alpha_u, alpha_v to at least this
# Plugins refused with a pointer to what jgi has instead.
ALTERNATIVES: dict = {}


def _parse(path: Path, source: dict) -> ET.Element:
    """Parse ``path`` with expat, recording each element's line: ``source`` maps
    id(element) -> (file, line, element) for error messages."""

    builder = ET.TreeBuilder()
    p = expat.ParserCreate()

    def start(tag, attrs):
        el = builder.start(tag, attrs)
        source[id(el)] = (path, p.CurrentLineNumber, el)

    p.StartElementHandler = start
    p.EndElementHandler = builder.end
    try:
        p.Parse(path.read_bytes(), True)
        return builder.close()
    except expat.ExpatError as e:
        raise ImportError_(f"{path}:{e.lineno}: XML syntax error: "
                           f"{expat.errors.messages[e.code]}") from None
    except OSError as e:
        raise ImportError_(f"{path}: cannot read: {e}") from None


class _Importer:
    def __init__(self, path: Path):
        self.path = path
        self.defaults: dict[str, str] = {}
        self.b = SceneBuilder(path.stem)
        self.bsdfs: dict[str, tuple] = {}   # id -> (kind, kwargs)
        self.null_bsdfs: set = set()        # names of null bsdfs (no material: see null_shape)
        self.null_volumes = []               # the media null shapes bound (null_shape)
        self.anisotropic: set[str] = set()  # BSDFs with alpha_u != alpha_v
        self.two_sided_rows: dict[int, int] = {}  # one-sided row -> its twosided copy
        self.n_anon = 0
        self.checkerboards: dict[str, dict] = {}   # name -> the builder's checkerboard kwargs
        self.sensor_done = False
        self.sensor_medium_of_file = None   # the sensor's medium id, or nested <medium>
        self.nested_media: dict = {}         # id() of a shape's nested <medium> -> its name
        self.source: dict = {}
        self.integrator: IntegratorSettings | None = None
        # ids of the transforms with a non-unit rotation axis: Mitsuba moves normals by such
        # a rotation as if it were one (its inverse transpose taken as itself)
        self.nonunit_rotations: set[int] = set()
        self.area_emitters: dict[str, ET.Element] = {}   # top-level area emitters by id
        self.media: dict[str, ET.Element] = {}            # top-level media by id
        # Mitsuba's file resolver: the scene file's folder, then each <path> prepended
        self.search_paths: list[Path] = [path.parent]

    # --- helpers --------------------------------------------------------------------------
    def where(self, el) -> str:
        file, line, _ = self.source.get(id(el), (self.path, "?", None))
        return f"{file}:{line}"

    def fail(self, el, msg):
        raise ImportError_(f"{self.where(el)}: {msg}")

    def resolve(self, el, name: str, what: str | None = None) -> Path:
        """A file name as Mitsuba 3's file resolver finds it: an absolute name as it is; a
        relative one in the folders of the <path> elements, the latest first, then in the main
        scene file's folder (also for names in <include>d files: checked with Mitsuba 3.9.1,
        an included file's own folder is not searched). A name found nowhere is refused when
        ``what`` names it, otherwise returned in the scene's folder for the reader to report."""
        p = Path(name)
        if p.is_absolute():
            return p
        for base in self.search_paths:
            if (base / p).exists():
                return base / p
        if what is None:
            return self.path.parent / p
        self.fail(el, f"{what} '{name}' does not exist in the folders Mitsuba's file resolver "
                      "searches (the <path> folders, latest first, then the scene's folder): "
                      f"{', '.join(str(b) for b in self.search_paths)}")

    def attr(self, el, name, default=None):
        v = el.get(name, default)
        if isinstance(v, str) and "$" in v:
            for k, val in self.defaults.items():
                v = v.replace("$" + k, val)
            if "$" in v:
                self.fail(el, f"undefined parameter in '{el.get(name)}'")
        return v

    def number(self, el, name="value"):
        v = self.attr(el, name)
        try:
            return float(v)
        except (TypeError, ValueError):
            self.fail(el, f"<{el.tag} name='{el.get('name')}'>: '{v}' is not a number")

    def vec3(self, el, prefix=""):
        if el.get("value") is not None:
            parts = [p for p in self.attr(el, "value").replace(",", " ").split()]
            if len(parts) == 1:
                parts = parts * 3
            if len(parts) != 3:
                self.fail(el, f"<{el.tag}>: expected 3 numbers, got '{el.get('value')}'")
            try:
                return np.array([float(p) for p in parts])
            except ValueError:
                self.fail(el, f"<{el.tag}>: '{el.get('value')}' is not numeric")
        return np.array([float(self.attr(el, k, "0")) for k in "xyz"])

    def props(self, el) -> dict:
        """Named child values: rgb / float / spectrum / boolean / integer / string / point /
        vector / transform / nested objects."""
        out = {}
        for c in el:
            name = c.get("name")
            if c.tag in ("rgb", "color"):
                out[name] = self.vec3(c)
            elif c.tag == "spectrum":
                out[name] = self.spectrum(c, el)
            elif c.tag in ("float", "integer"):
                out[name] = self.number(c)
            elif c.tag == "boolean":
                out[name] = self.attr(c, "value", "false").lower() == "true"
            elif c.tag == "string":
                out[name] = self.attr(c, "value")
            elif c.tag in ("point", "vector"):
                out[name] = self.vec3(c)
            elif c.tag == "transform":
                out[name] = self.transform(c)
            elif c.tag == "texture":
                out[name] = TextureRef(self.texture(c))
            elif c.tag == "ref" and name and c.get("id") in self.b.texture_names:
                out[name] = TextureRef(c.get("id"))
        return out

    def spectrum(self, c, parent) -> np.ndarray:
        """A <spectrum> (a constant, wavelength:value pairs, a filename= .spd file, or
        type="blackbody" in an emitter) as the RGB Mitsuba 3's RGB variants use
        (jgi.scene.spectra): emitters' values unbounded and without the D65 weighting, a
        conductor's eta and k unbounded, other values reflectances clamped to [0, 1]."""
        name = c.get("name")
        emitter = parent.tag == "emitter"
        unbounded = parent.tag == "bsdf" and name in ("eta", "k")
        try:
            if c.get("type") is not None:
                if c.get("type") != "blackbody":
                    self.fail(c, f"spectrum '{name}': type '{c.get('type')}' is not "
                                 "supported (Mitsuba's RGB variants cannot evaluate it "
                                 "either); supported: blackbody (in emitters), value=, "
                                 "filename=")
                if not emitter:
                    self.fail(c, f"spectrum '{name}': a blackbody is supported as an "
                                 "emitter's radiance / intensity / irradiance only")
                q = {k.get("name"): self.number(k) for k in c if k.tag == "float"}
                extra = set(q) - {"temperature", "wavelength_min", "wavelength_max"}
                if "temperature" not in q or extra:
                    self.fail(c, "blackbody: needs <float name=\"temperature\"> (kelvin); "
                                 "also accepted: wavelength_min, wavelength_max")
                return spectra.mitsuba_blackbody_rgb(
                    q["temperature"], q.get("wavelength_min", spectra.CIE_MIN),
                    q.get("wavelength_max", spectra.CIE_MAX))
            if c.get("filename") is not None:
                value = spectra.read_spd(self.resolve(c, self.attr(c, "filename"),
                                                      "spectrum file"))
            else:
                value = spectra.parse_mitsuba_value(self.attr(c, "value", ""))
        except spectra.SpectrumError as e:
            self.fail(c, f"spectrum '{name}': {e}")
        return spectra.mitsuba_rgb(value, emitter=emitter, unbounded=unbounded)

    def texture(self, el) -> str:
        """Register a <texture> (bitmap or checkerboard), return its name in the builder.
        Supported as Mitsuba defines them: bitmap (filename, filter_type bilinear, wrap_mode
        repeat, raw, to_uv), checkerboard (color0, color1, to_uv)."""
        kind = el.get("type")
        if kind not in TEXTURE_PARAMETERS:
            self.fail(el, f"texture plugin '{kind}' is not supported by jgi; supported texture "
                          f"plugins: {', '.join(TEXTURE_PARAMETERS)}")
        p = self.props(el)
        for key, v in p.items():
            if key not in TEXTURE_PARAMETERS[kind]:
                self.fail(el, f"texture '{kind}': unknown parameter '{key}'; {kind} takes: "
                              f"{', '.join(TEXTURE_PARAMETERS[kind])}")
            if isinstance(v, TextureRef):
                self.fail(el, f"texture '{kind}': parameter '{key}' cannot be a texture")
        name = el.get("id") or f"_texture{self.n_anon}"
        self.n_anon += 1
        to_uv = p.get("to_uv")
        try:
            if kind == "checkerboard":
                self.checkerboards[name] = dict(to_uv=to_uv,
                                                color0=self.rgb(el, p, "color0", 0.4),
                                                color1=self.rgb(el, p, "color1", 0.2))
                self.b.texture(name, "checkerboard", **self.checkerboards[name])
            else:
                for key, allowed in (("filter_type", ("bilinear",)), ("wrap_mode", ("repeat",))):
                    v = p.get(key, allowed[0])
                    if v not in allowed:
                        self.fail(el, f"bitmap: {key} '{v}' is not supported; jgi supports "
                                      f"{', '.join(allowed)} (Mitsuba's default)")
                fname = p.get("filename")
                if not isinstance(fname, str):
                    self.fail(el, "bitmap: needs a <string name=\"filename\">")
                raw = p.get("raw", False)
                if not isinstance(raw, bool):
                    self.fail(el, "bitmap: 'raw' must be a <boolean>")
                self.b.texture(name, "bitmap", to_uv=to_uv, raw=raw,
                               filename=self.resolve(el, fname))
        except SceneError as e:
            self.fail(el, str(e))
        return name

    def transform(self, el) -> np.ndarray:
        m = np.eye(4)
        unit_axes = True
        for op in el:
            if op.tag == "translate":
                t = xf.translate(self.vec3(op))
            elif op.tag == "rotate":
                axis = self.vec3(op) if op.get("value") else np.array(
                    [float(self.attr(op, k, "0")) for k in "xyz"])
                angle = float(self.attr(op, "angle", "0"))
                if not np.any(axis):
                    self.fail(op, "rotate: the axis must be non-zero")
                # Mitsuba 3 does not normalise the axis (checked with 3.9.1's parser): a
                # non-unit one also scales and shears, as the same formula does here
                unit = np.isclose(np.linalg.norm(axis), 1.0, rtol=0, atol=1e-12)
                t = xf.rotate(axis, angle) if unit else _unnormalised_rotation(axis, angle)
                unit_axes &= bool(unit)
            elif op.tag == "scale":
                s = self.vec3(op) if op.get("value") else np.array(
                    [float(self.attr(op, k, "1")) for k in "xyz"])
                t = xf.scale(s)
            elif op.tag == "matrix":
                vals = [float(x) for x in self.attr(op, "value").replace(",", " ").split()]
                if len(vals) not in (9, 16):
                    self.fail(op, f"matrix needs 16 values (4 x 4) or 9 (3 x 3), got "
                                  f"{len(vals)}")
                # Mitsuba puts a 3 x 3 matrix in the upper left of a 4 x 4 one (so as a to_uv,
                # whose 3 x 3 is rows / columns 0, 1, 3, its third column is dropped)
                if len(vals) == 16:
                    t = np.array(vals).reshape(4, 4)
                else:
                    t = np.eye(4)
                    t[:3, :3] = np.reshape(vals, (3, 3))
            elif op.tag == "lookat":
                def pt(k):
                    return np.array([float(x) for x in self.attr(op, k).replace(",", " ").split()])
                t = xf.look_at(pt("origin"), pt("target"), pt("up") if op.get("up") else [0, 1, 0])
            else:
                self.fail(op, f"unknown transform operation <{op.tag}>; supported: translate, "
                              "rotate, scale, matrix, lookat")
            m = t @ m
        if not unit_axes:
            self.nonunit_rotations.add(id(m))
        return m

    def check_type(self, el):
        kind = el.get("type")
        allowed = SUPPORTED[el.tag]
        if kind not in allowed:
            hint = f" ({ALTERNATIVES[kind]})" if el.tag == "bsdf" and kind in ALTERNATIVES else ""
            self.fail(el, f"{el.tag} plugin '{kind}' is not supported by jgi{hint}; supported "
                          f"{el.tag} plugins: {', '.join(allowed)}")
        return kind

    # --- objects --------------------------------------------------------------------------
    def bsdf(self, el) -> str:
        """Register a BSDF, return its material name in the builder."""
        kind = self.check_type(el)
        p = self.props(el)
        for c in el:
            if kind in ("twosided", "mask") and c.tag == "ref" and not c.get("name"):
                continue   # a nested BSDF by reference
            if c.tag == "ref" and c.get("name") and c.get("id") not in self.b.texture_names:
                self.fail(c, f"bsdf '{kind}': parameter '{c.get('name')}' refers to "
                             f"'{c.get('id')}', which is not a texture defined before it")
        for key in p:
            if key not in BSDF_PARAMETERS[kind]:
                self.fail(el, f"bsdf '{kind}': unknown parameter '{key}'; {kind} takes: "
                              f"{', '.join(BSDF_PARAMETERS[kind]) or '(none)'}")
        name = el.get("id") or f"_bsdf{self.n_anon}"
        self.n_anon += 1
        if kind == "null":   # no surface at all (null_shape)
            self.null_bsdfs.add(name)
            self.bsdfs[name] = ("null", p)
            return name
        if kind == "mask":
            self.mask(el, name, p)
            return name
        if kind == "twosided":
            inner_name = self.twosided(el)
            nested = [c for c in el if c.tag == "bsdf"]
            if nested and not nested[0].get("id"):   # used here alone: made two-sided in place
                self.b.materials[self.b.material_names[inner_name]].one_sided = False
            if inner_name in self.anisotropic:
                self.anisotropic.add(name)
            self.bsdfs[name] = self.bsdfs[inner_name]
            self.b.material_names[name] = self.two_sided_row(inner_name)
            return name
        if kind == "diffuse":
            self.b.material(name, "diffuse", one_sided=True,
                            diffuse=self.rgb(el, p, "reflectance", 0.5, texture=True))
        elif kind in ("conductor", "roughconductor"):
            self.conductor(el, name, kind, p)
        elif kind in ("dielectric", "roughdielectric"):
            refl = self.rgb(el, p, "specular_reflectance", 1.0, texture=True)
            trans = self.rgb(el, p, "specular_transmittance", 1.0, texture=True)
            textures = isinstance(refl, str), isinstance(trans, str)
            if any(textures) and (not all(textures) or refl != trans):
                self.fail(el, f"{kind}: a textured specular_reflectance or "
                              "specular_transmittance must be one texture for both (a <texture> "
                              "with an id and two <ref>s); jgi's transmission tint is otherwise "
                              "a constant <rgb> / <float> / <spectrum>")
            tint = {} if any(textures) or np.array_equal(refl, trans) else \
                {"transmittance": trans}
            int_ior, ext_ior = self.ior(el, p, "int_ior", "bk7"), self.ior(el, p, "ext_ior", "air")
            if kind == "dielectric":
                self.b.material(name, "dielectric", specular=refl, ior=int_ior / ext_ior, **tint)
            else:
                if int_ior == ext_ior:
                    self.fail(el, f"{kind}: int_ior and ext_ior must differ (Mitsuba refuses "
                                  "equal indices)")
                self.b.material(name, "roughdielectric", specular=refl, ior=int_ior / ext_ior,
                                **tint, **self.roughness(el, kind, p))
        elif kind in ("roughplastic", "plastic"):
            int_ior = self.ior(el, p, "int_ior", "polypropylene")
            ext_ior = self.ior(el, p, "ext_ior", "air")
            if int_ior == ext_ior:
                self.fail(el, f"{kind}: int_ior and ext_ior must differ (Mitsuba refuses equal "
                              "indices)")
            nonlinear = p.get("nonlinear", False)
            if not isinstance(nonlinear, bool):
                self.fail(el, f"{kind}: 'nonlinear' must be a <boolean>")
            rough = (self.roughness(el, kind, p, anisotropic=False) if kind == "roughplastic"
                     else {})
            self.b.material(name, kind, one_sided=True,
                            diffuse=self.rgb(el, p, "diffuse_reflectance", 0.5, texture=True),
                            specular=self.rgb(el, p, "specular_reflectance", 1.0, texture=True),
                            int_ior=int_ior, ext_ior=ext_ior, nonlinear=nonlinear, **rough)
        if "alpha_u" in p and p["alpha_u"] != p["alpha_v"]:
            self.anisotropic.add(name)
        self.bsdfs[name] = (kind, p)
        return name

    def twosided(self, el) -> str:
        """The BSDF a ``twosided`` wraps (nested or a <ref>), as Mitsuba 3 defines it: one
        BSDF used on both sides, or two (front, back). jgi's opaque BSDFs are two-sided, so one
        BSDF (or the same one twice) is that BSDF; two different ones are refused (a jgi
        surface has one material on both sides), and so are transmissive ones, which Mitsuba
        refuses too."""
        names = self.nested_bsdfs(el, "twosided")
        if len(names) not in (1, 2):
            self.fail(el, f"twosided needs one or two nested BSDFs (or <ref>s), got {len(names)}")
        for n in names:
            if self.bsdfs[n][0] == "mask":
                self.fail(el, "twosided: the nested bsdf is a 'mask', which lets light through "
                              "(Mitsuba refuses it too); put the twosided inside the mask")
            if self.bsdfs[n][0] in ("dielectric", "roughdielectric"):
                self.fail(el, f"twosided: the nested bsdf '{self.bsdfs[n][0]}' transmits light; "
                              "Mitsuba nests only materials without transmission")
        if len(names) == 2 and self.b.material_names[names[0]] != \
                self.b.material_names[names[1]]:
            self.fail(el, "twosided with two different BSDFs (front, back) is not supported: "
                          "a jgi surface has one material on both sides; give one nested bsdf")
        return names[0]

    def nested_bsdfs(self, el, plugin: str) -> list[str]:
        """The material names of a wrapper BSDF's nested <bsdf>s and unnamed <ref>s, in order."""
        names = []
        for c in el:
            if c.tag == "bsdf":
                names.append(self.bsdf(c))
            elif c.tag == "ref" and not c.get("name"):
                if c.get("id") not in self.b.material_names:
                    self.fail(c, f"{plugin}: reference to unknown bsdf '{c.get('id')}'")
                names.append(c.get("id"))
        return names

    def mask(self, el, name: str, p: dict):
        """Mitsuba's ``mask``: its nested BSDF (nested or a <ref>) with an opacity (a <float>,
        <rgb> or <spectrum>, whose luminance is taken, or a texture, read as Mitsuba's eval_1;
        default 0.5, clamped to [0, 1] as Mitsuba does): a copy of the nested BSDF's row with
        jgi's ``opacity``. A mask inside a mask multiplies constant opacities."""
        names = self.nested_bsdfs(el, "mask")
        if len(names) != 1:
            self.fail(el, f"mask needs exactly one nested BSDF (or <ref>), got {len(names)}")
        inner = names[0]
        row = self.b.material_names[inner]
        m = self.b.materials[row]
        v = p.get("opacity", 0.5)
        if isinstance(v, TextureRef):
            if m.opacity < 1.0 or m.opacity_texture >= 0:
                self.fail(el, "mask: a textured opacity around another mask is not supported "
                              "(jgi's opacity is one texture or a constant); nest constants only")
            opacity, texture = 1.0, self.b.texture_names[self.scalar_texture(str(v))]
        elif isinstance(v, (str, bool)):
            self.fail(el, "mask: 'opacity' must be a <float>, <rgb>, <spectrum> or <texture>")
        else:
            a = float(np.clip(luminance_np(np.broadcast_to(np.asarray(v, float), (3,))), 0, 1))
            if m.opacity_texture >= 0 and a < 1.0:
                self.fail(el, "mask: a mask around a mask with a textured opacity is not "
                              "supported (jgi's opacity is one texture or a constant)")
            opacity, texture = a * m.opacity, m.opacity_texture
        self.b.material_names[name] = len(self.b.materials)
        self.b.materials.append(dataclasses.replace(m, opacity=opacity,
                                                    opacity_texture=texture))
        if inner in self.anisotropic:
            self.anisotropic.add(name)
        self.bsdfs[name] = ("mask", p)

    def two_sided_row(self, inner_name: str) -> int:
        """The material row of ``inner_name`` made two-sided: the row itself if it is (an
        anonymous nested BSDF, made two-sided in place), else a two-sided copy of it (the
        one-sided row stays for the shapes that use the BSDF unwrapped, by reference)."""
        row = self.b.material_names[inner_name]
        m = self.b.materials[row]
        if not m.one_sided:
            return row
        if row not in self.two_sided_rows:
            self.two_sided_rows[row] = len(self.b.materials)
            self.b.materials.append(dataclasses.replace(m, one_sided=False))
        return self.two_sided_rows[row]

    def conductor(self, el, name: str, kind: str, p: dict):
        """conductor / roughconductor: Mitsuba's rules for ``material`` versus ``eta`` / ``k``
        (``material`` "none" without eta and k is a 100 % reflector)."""
        material = p.get("material", "none")
        if not isinstance(material, str):
            self.fail(el, f"{kind}: 'material' must be a <string>")
        spec = self.rgb(el, p, "specular_reflectance", 1.0, texture=True)
        rough = self.roughness(el, kind, p) if kind == "roughconductor" else {}
        jgi_kind = "conductor" if kind == "conductor" else "roughconductor"
        if material != "none":
            if "eta" in p or "k" in p:
                self.fail(el, f"{kind}: give either material='{material}' or eta/k, not both")
            metals = named_metals()
            if material not in metals:
                self.fail(el, f"{kind}: material '{material}' is not in jgi's table of metals; "
                              f"supported: {', '.join(metals)} (or give eta and k)")
            self.b.material(name, jgi_kind, specular=spec, metal=material, **rough, one_sided=True)
        elif "eta" not in p and "k" not in p:   # Mitsuba's "none": eta 0, k 1, F = 1
            self.b.material(name, jgi_kind, specular=spec, metal="none", **rough, one_sided=True)
        else:  # Mitsuba's defaults for a missing one of the two: eta 0, k 1
            eta, k = self.rgb(el, p, "eta", 0.0), self.rgb(el, p, "k", 1.0)
            if np.any(eta < 0) or np.any(k < 0):
                self.fail(el, f"{kind}: eta and k must be >= 0, got eta {eta.tolist()}, "
                              f"k {k.tolist()}")
            self.b.material(name, jgi_kind, specular=spec, eta=eta, k=k, **rough, one_sided=True)

    def roughness(self, el, kind: str, p: dict, anisotropic: bool = True) -> dict:
        """distribution (beckmann | ggx, default beckmann) and alpha or alpha_u / alpha_v
        (default 0.1), checked as Mitsuba does; Mitsuba clamps alpha below 1e-4 to 1e-4."""
        dist = p.get("distribution", "beckmann")
        if not isinstance(dist, str) or dist.lower() not in DISTRIBUTIONS:
            self.fail(el, f"{kind}: unknown distribution '{dist}'; supported: "
                          f"{', '.join(DISTRIBUTIONS)}")
        out = {"distribution": dist.lower()}
        has_uv = "alpha_u" in p or "alpha_v" in p
        if has_uv and not anisotropic:
            self.fail(el, f"{kind}: alpha_u / alpha_v are not supported (Mitsuba's {kind} is "
                          "isotropic); give alpha")
        if has_uv and "alpha" in p:
            self.fail(el, f"{kind}: give either alpha or alpha_u / alpha_v, not both")
        if has_uv and not ("alpha_u" in p and "alpha_v" in p):
            self.fail(el, f"{kind}: alpha_u and alpha_v must be given together")
        keys = ("alpha_u", "alpha_v") if has_uv else ("alpha",)
        for key in keys:
            a = p.get(key, 0.1)
            if isinstance(a, TextureRef) and kind != "roughplastic":
                out[key] = self.scalar_texture(str(a))   # (Mitsuba clamps it to 1e-4 too)
                continue
            if isinstance(a, TextureRef):
                self.fail(el, f"{kind}: '{key}' cannot be a texture (Mitsuba's roughplastic "
                              "takes a <float> alpha: its coating tables are computed from one "
                              "value); give a <float>")
            if isinstance(a, (str, bool, np.ndarray)):
                self.fail(el, f"{kind}: '{key}' must be a <float>")
            if not a >= 0:
                self.fail(el, f"{kind}: {key} must be >= 0, got {a}")
            out[key] = max(float(a), MIN_ALPHA)
        return out

    def scalar_texture(self, name: str) -> str:
        """The texture Mitsuba's ``eval_1`` (a scalar parameter: roughness) reads from texture
        ``name``. Mitsuba 3.9.1's checkerboard ``eval_1`` returns color1 where its ``eval``
        returns color0 and vice versa (checked with ``mitsuba.load_dict``), so a checkerboard
        that drives a scalar becomes a twin with the two colours exchanged; other textures
        are themselves."""
        if name not in self.checkerboards:
            return name
        twin = f"_eval_1_{name}"
        if twin not in self.b.texture_names:
            c = self.checkerboards[name]
            self.b.texture(twin, "checkerboard", to_uv=c["to_uv"], color0=c["color1"],
                           color1=c["color0"])
        return twin

    def ior(self, el, p: dict, key: str, default: str) -> float:
        """An index of refraction given as a number or by one of Mitsuba's names."""
        v = p.get(key, default)
        if isinstance(v, str):
            if v.lower() not in NAMED_IOR:
                self.fail(el, f"{el.get('type')}: {key} '{v}' is unknown; names: "
                              f"{', '.join(NAMED_IOR)}")
            return NAMED_IOR[v.lower()]
        if isinstance(v, (bool, np.ndarray)):
            self.fail(el, f"{el.get('type')}: {key} must be a <float> or a <string> name")
        if not v > 0:
            self.fail(el, f"{el.get('type')}: {key} must be > 0, got {v}")
        return float(v)

    def rgb(self, el, p: dict, key: str, default: float, texture: bool = False):
        """A colour parameter given as <rgb>, <float> or a constant <spectrum>; with
        ``texture``, a <texture> (or a <ref> to one) too, returned as its name."""
        v = p.get(key, default)
        if isinstance(v, TextureRef):
            if not texture:
                self.fail(el, f"{el.get('type')}: '{key}' cannot be textured in jgi; give an "
                              "<rgb>, <float> or <spectrum>")
            return str(v)
        if isinstance(v, (str, bool)):
            self.fail(el, f"{el.get('type')}: '{key}' must be an <rgb>, <float> or <spectrum>")
        return np.broadcast_to(np.asarray(v, float), (3,)).copy()

    def shape(self, el):
        kind = self.check_type(el)
        p = self.props(el)
        m = p.get("to_world", np.eye(4))
        material = None
        emission = None
        shape_media: dict = {}     # "interior" / "exterior" -> medium id (or nested element)
        for c in el:
            if c.tag == "bsdf":
                material = self.bsdf(c)
            elif c.tag == "medium" or (c.tag == "ref" and c.get("name") in ("interior",
                                                                          "exterior")):
                side = c.get("name")
                if side not in ("interior", "exterior"):
                    self.fail(c, "a shape's medium needs name=\"interior\" or "
                                 "name=\"exterior\"")
                if c.tag == "ref" and c.get("id") not in self.media:
                    self.fail(c, f"reference to unknown medium '{c.get('id')}'; defined: "
                                 f"{', '.join(self.media) or '(none)'}")
                shape_media[side] = c.get("id") if c.tag == "ref" else c
            elif c.tag == "ref" and c.get("id") in self.area_emitters:
                # a top-level area emitter with an id, referenced (before or after it)
                emission = self.emitted(self.area_emitters[c.get("id")], "radiance")
            elif c.tag == "ref" and c.get("id") in self.null_bsdfs:
                material = c.get("id")
            elif c.tag == "ref":
                rid = c.get("id")
                if rid not in self.b.material_names:
                    defined = ", ".join(k for k in self.b.material_names
                                        if not k.startswith("_")) or "(none)"
                    self.fail(c, f"reference to unknown bsdf '{rid}'; defined: {defined}")
                material = rid
            elif c.tag == "emitter":
                if c.get("type") != "area":
                    self.fail(c, f"a shape's emitter must be 'area', got '{c.get('type')}'")
                emission = self.emitted(c, "radiance")
        if material in self.null_bsdfs:
            return self.null_shape(el, kind, m, shape_media, emission)
        if material in self.anisotropic and kind not in ("obj", "ply", "serialized"):
            self.check_anisotropy_frame(el, kind, p, m, material)
        if material is None:
            # Mitsuba 3's default: diffuse, reflectance 0.5; 0 on a shape that emits (measured:
            # an emitter without a bsdf reflects nothing in Mitsuba 3.5)
            material = f"_default{self.n_anon}"
            self.n_anon += 1
            grey = 0.0 if emission is not None else 0.5
            self.b.material(material, "diffuse", diffuse=(grey, grey, grey), one_sided=True)
        row = self.b.materials[self.b.material_names[material]]
        if shape_media:
            transmits = (row.kind in (DIELECTRIC, ROUGH_DIELECTRIC) or row.opacity < 1.0
                         or row.opacity_texture >= 0)
            material = self.medium_interface(el, kind, material, shape_media.get("interior"),
                                             shape_media.get("exterior"), transmits,
                                             emission is not None)
        if emission is not None and (row.opacity < 1.0 or row.opacity_texture >= 0):
            self.fail(el, f"{kind}: an area emitter on a shape whose bsdf is a 'mask' is not "
                          "supported (jgi's emitters are opaque: they are sampled over their "
                          "whole surface); remove the mask or the emitter")
        if p.get("flip_normals", False) and kind in ("cube", "sphere"):
            # the side matters to one-sided BSDFs, area emitters and dielectrics
            self.fail(el, f"{kind}: flip_normals is not supported on a {kind} (it turns "
                          "Mitsuba's one-sided surfaces, emitters and interfaces inside out); "
                          "supported on rectangle, obj, ply and serialized shapes")
        if kind == "rectangle":
            if p.get("flip_normals", False):   # the same rectangle, its normal negated
                m = m @ np.diag([1.0, -1.0, 1.0, 1.0])
            self.b.rectangle(m, material, emission)
        elif kind == "cube":
            self.b.cube(m, material, emission)
        elif kind == "sphere":
            cols = m[:3, :3]
            scales = np.linalg.norm(cols, axis=0)
            if not np.allclose(scales, scales[0], rtol=1e-6) or not np.allclose(
                    cols.T @ cols, np.diag(scales**2), atol=1e-9 * scales[0] ** 2 + 1e-12):
                self.fail(el, "sphere: to_world must be a uniform scale, rotation and translation")
            if (row.textures or row.opacity_texture >= 0) and not np.allclose(
                    cols / scales[0], np.eye(3), atol=1e-9):
                self.fail(el, "sphere: a textured sphere's to_world must not rotate (jgi's "
                              "sphere uv is in the world frame)")
            center = xf.apply_point(m, p.get("center", np.zeros(3)))
            self.b.sphere(center, float(p.get("radius", 1.0)) * scales[0], material, emission)
        elif kind == "disk":
            self.disk(el, p, m, material, emission)
        elif kind == "cylinder":
            self.cylinder(el, p, m, material, emission)
        else:  # obj, ply, serialized
            fname = p.get("filename")
            if not fname:
                self.fail(el, f"{kind} shape needs a 'filename'")
            mesh_file = self.resolve(el, fname, f"{kind} mesh file")
            smooth = not p.get("face_normals", False)
            if kind == "serialized":
                index = p.get("shape_index", 0)
                if index != int(index) or index < 0:
                    self.fail(el, f"serialized: shape_index must be an integer >= 0, got {index}")
                # (the file's face-normal flag is ignored: Mitsuba 3.9.1 ignores it too)
                v, f, uv, normals, _ = read_serialized(mesh_file, self.where(el), int(index))
                file_has_uv = uv is not None
                if smooth:   # Mitsuba's smooth normals when the file has none
                    normals = "smooth" if normals is None else normals
                else:
                    normals = None
            elif smooth:
                # Mitsuba 3 shades with the file's vertex normals, or with smooth ones it
                # computes when there are none (OBJMesh / PLYMesh: recompute_vertex_normals)
                v, f, uv, normals = load_mesh_with_normals(mesh_file, self.where(el))
                normals = "smooth" if normals is None else normals
            else:
                v, f, uv = load_mesh(mesh_file, self.where(el), allow_vertex_normals=True,
                                     with_uv=True)
                normals = None
            if kind != "serialized":
                file_has_uv = has_texture_coordinates(mesh_file)
            textured = bool(self.b.materials[self.b.material_names[material]].textures)
            if textured and file_has_uv:
                if uv is None:
                    self.fail(el, f"{kind} mesh '{fname}' with a textured material: its texture "
                                  "coordinates cannot be read (an OBJ file must give vt on "
                                  "every face vertex; a PLY file's are the vertex properties "
                                  "u, v or s, t or texture_u, texture_v)")
                if kind == "obj":   # Mitsuba's OBJ loader flips v; its PLY loader does not
                    uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], 1)
            else:
                uv = None   # Mitsuba's (0,0), (1,0), (0,1) per triangle
            if material in self.anisotropic:
                if smooth:
                    self.fail(el, f"bsdf '{material}' is anisotropic (alpha_u != alpha_v) on "
                                  f"the smooth-shaded mesh '{fname}': Mitsuba orients its frame "
                                  "by the interpolated normal and dp/du, jgi by a frame built "
                                  "from the normal, so the highlight would turn; give alpha, or "
                                  "face_normals=true")
                self.check_anisotropy_frame(el, kind, p, m, material,
                                            xf.apply_point(m, v), f, file_has_uv)
            if p.get("flip_normals", False):
                # Mitsuba negates both the geometric and the shading normal
                f = f[:, ::-1]
                if smooth and not isinstance(normals, str):
                    normals = -normals
            if emission is not None and smooth:
                # Mitsuba's area emitter on a smooth mesh emits about the interpolated normal,
                # jgi's about the geometric one: the same only where the mesh is flat
                if not _flat_normals(xf.apply_point(m, v), f, normals, m):
                    self.fail(el, f"{kind} mesh '{fname}' is an area emitter shaded with "
                                  "vertex normals that differ from its face normals: jgi's "
                                  "emitters radiate about their geometric normal; add "
                                  "<boolean name=\"face_normals\" value=\"true\"/>")
                normals = None
            if id(m) in self.nonunit_rotations and not isinstance(normals, (str, type(None))):
                self.fail(el, f"{kind} mesh '{fname}': its to_world rotates about a non-unit "
                              "axis, which Mitsuba applies as given (scaling and shearing) to "
                              "positions but to the file's vertex normals as if it were a "
                              "rotation; give a unit axis, or face_normals=true")
            # (computed normals follow the flipped winding: negated as Mitsuba's are)
            self.b.mesh(v, f, material, emission, to_world=m, uv=uv, normals=normals)

    def disk(self, el, p: dict, m: np.ndarray, material, emission):
        """Mitsuba's ``disk``: the unit disk in z = 0 under to_world, its normal to_world's
        normal transform of +z (negated by flip_normals), uv (r, phi / 2 pi)."""
        lin = m[:3, :3]
        du, dv = lin[:, 0], lin[:, 1]
        if not abs(np.dot(du, dv)) <= 1e-6 * np.linalg.norm(du) * np.linalg.norm(dv):
            self.fail(el, "disk: to_world shears the disk's plane (its x and y axes are not "
                          "perpendicular); allowed: rotation, translation and scaling along x, y")
        if abs(np.linalg.det(lin)) <= 0:
            self.fail(el, "disk: to_world is singular")
        n = np.linalg.inv(lin).T @ np.array([0.0, 0.0, 1.0])
        if p.get("flip_normals", False):
            n = -n
        self.b.disk(xf.apply_point(m, [0.0, 0.0, 0.0]), du, dv, material, emission, normal=n)

    def cylinder(self, el, p: dict, m: np.ndarray, material, emission):
        """Mitsuba's ``cylinder``: the open tube of ``radius`` from p0 to p1 under to_world,
        normal outwards (inwards with flip_normals), uv (phi / 2 pi, z) with phi measured in
        Mitsuba's frame of p1 - p0 (Frame3f: Duff et al.'s basis)."""
        p0 = np.broadcast_to(np.asarray(p.get("p0", np.zeros(3)), float), (3,))
        p1 = np.broadcast_to(np.asarray(p.get("p1", [0.0, 0.0, 1.0]), float), (3,))
        radius = p.get("radius", 1.0)
        if isinstance(radius, (bool, str, np.ndarray)) or not radius > 0:
            self.fail(el, f"cylinder: radius must be a <float> > 0, got {radius}")
        axis = p1 - p0
        length = float(np.linalg.norm(axis))
        if not length > 0:
            self.fail(el, "cylinder: p0 and p1 coincide")
        w = axis / length
        s_, t_ = mitsuba_frame(w)
        local = np.eye(4)
        local[:3, :3] = np.stack([s_ * radius, t_ * radius, w * length], 1)
        local[:3, 3] = p0
        full = m @ local
        eu, ev, ew = full[:3, 0], full[:3, 1], full[:3, 2]
        r_u, r_v, h = (float(np.linalg.norm(x)) for x in (eu, ev, ew))
        gram = np.array([[np.dot(a, b) for b in (eu, ev, ew)] for a in (eu, ev, ew)])
        if not (abs(r_u - r_v) <= 1e-6 * r_u and np.allclose(gram, np.diag(np.diag(gram)),
                                                             atol=1e-6 * max(r_u, h) ** 2)):
            self.fail(el, "cylinder: to_world must keep the tube circular and upright: "
                          "rotation, translation, uniform scaling, and scaling along the axis "
                          "only (no shear, no other non-uniform scale)")
        self.b.cylinder(full[:3, 3], eu, ew, r_u, h, material, emission,
                        outward=not p.get("flip_normals", False), axis_v=ev)

    def check_anisotropy_frame(self, el, kind, p, m, material, vertices=None, faces=None,
                               file_has_uv=None):
        """Anisotropic roughness is oriented by the shading frame. Mitsuba's tangent is dp/du of
        the shape's (u, v) parametrisation: to_world's x axis on a rectangle, the
        texture-coordinate gradient on a mesh with texture coordinates, and on a mesh without
        them the first edge p1 - p0 of each triangle (Mitsuba 3.9.1 parametrises the triangle
        by its barycentrics; checked with ``ray_intersect``: ``si.sh_frame.s``). jgi's tangent
        is built from the normal alone (:func:`._common.tangent_frame`). Where the two differ
        the highlight would turn: refused. Accepted: rectangles whose to_world x axis is jgi's
        tangent, and meshes without texture coordinates whose every triangle's first edge is
        (called once the mesh is loaded, with its world-space ``vertices`` and ``faces``)."""
        why = None
        if kind == "rectangle" and p.get("flip_normals", False):
            why = "flip_normals changes Mitsuba's frame"
        elif kind == "rectangle":
            du, dv = m[:3, 0], m[:3, 1]
            n = np.cross(du, dv)
            s, _ = tangent_frame(n)
            du = du - n * np.dot(n, du) / np.dot(n, n)
            if abs(np.dot(s, du)) < (1 - 1e-6) * np.linalg.norm(du):
                why = (f"this rectangle's dp/du {np.round(du / np.linalg.norm(du), 4).tolist()} "
                       f"is not jgi's tangent {np.round(s, 4).tolist()}")
        elif kind in ("obj", "ply", "serialized"):
            fname = p.get("filename")
            if p.get("flip_normals", False):
                why = "flip_normals changes Mitsuba's frame"
            elif file_has_uv:
                why = f"'{fname}' has texture coordinates, which orient Mitsuba's frame"
            else:
                tri = vertices[faces]
                e1 = tri[:, 1] - tri[:, 0]
                n = np.cross(e1, tri[:, 2] - tri[:, 0])
                bad = [i for i in range(len(faces))
                       if abs(np.dot(tangent_frame(n[i])[0], e1[i]))
                       < (1 - 1e-6) * np.linalg.norm(e1[i])]
                if bad:
                    why = (f"Mitsuba's tangent on '{fname}' is each triangle's first edge p1 - p0 "
                           f"(there are no texture coordinates), and on {len(bad)} of "
                           f"{len(faces)} triangles it is not jgi's tangent")
        else:
            why = f"a {kind}'s frame follows its (u, v) parametrisation"
        if why:
            self.fail(el, f"bsdf '{material}' is anisotropic (alpha_u != alpha_v), and {why}: "
                          "jgi orients anisotropy by a frame built from the normal, so the "
                          "highlight would turn. Supported: rectangles whose to_world x axis, "
                          "and meshes whose triangles' first edges, are that frame's tangent; "
                          "or give alpha")

    def emitted(self, el, name: str):
        """An emitter's constant radiance / intensity / irradiance (Mitsuba's default 1)."""
        value = self.props(el).get(name, np.ones(3))
        if isinstance(value, TextureRef):
            self.fail(el, f"emitter '{el.get('type')}': a textured {name} is not supported "
                          "(jgi's emitters are constant: give an rgb, spectrum or float)")
        return value

    def emitter(self, el):
        kind = self.check_type(el)
        if kind == "area":
            if el.get("id") in self.area_emitters:
                return   # referenced by shapes (read there)
            self.fail(el, "an area emitter must be nested in a shape, or have an id that shapes "
                          "<ref>")
        p = self.props(el)
        m = p.get("to_world", np.eye(4))
        if kind == "point":
            pos = p.get("position", xf.apply_point(m, np.zeros(3)))
            self.b.point_light(pos, self.emitted(el, "intensity"))
        elif kind == "spot":
            # Mitsuba 3's falloff: linear in the angle from 1 at beam_width (default 3/4 of
            # cutoff_angle) to 0 at cutoff_angle; with beam_width = cutoff_angle a hard cone
            cutoff = float(p.get("cutoff_angle", 20.0))
            beam = float(p.get("beam_width", cutoff * 0.75))
            if not 0 < cutoff <= 90 or not 0 <= beam <= cutoff:
                self.fail(el, f"spot: need 0 < cutoff_angle <= 90 and 0 <= beam_width <= "
                              f"cutoff_angle (degrees), got {cutoff} and {beam}")
            hard = math.isclose(beam, cutoff, rel_tol=1e-6)
            pos = xf.apply_point(m, np.zeros(3))
            target = xf.apply_point(m, np.array([0.0, 0.0, 1.0]))
            self.b.spot_light(pos, target, self.emitted(el, "intensity"), cutoff_deg=cutoff,
                              falloff_deg=cutoff if hard else beam,
                              profile="smoothstep" if hard else "linear")
        elif kind == "directional":
            d = p.get("direction", xf.apply_vector(m, np.array([0.0, 0.0, 1.0])))
            self.b.directional_light(d, self.emitted(el, "irradiance"))
        elif kind == "constant":
            self.b.environment_light(self.emitted(el, "radiance"))
        elif kind == "envmap":
            # Mitsuba 3's envmap: radiance scale x the latitude-longitude image's bilinear
            # lookup (EXR linear, PNG / JPEG sRGB-decoded), oriented by to_world
            fname = p.get("filename")
            if not isinstance(fname, str):
                self.fail(el, "envmap: needs a <string name=\"filename\"> (EXR, HDR, PNG or "
                              "JPEG)")
            path = self.resolve(el, fname, "envmap image")
            if path.suffix.lower() not in (".exr", ".hdr", ".rgbe", ".png", ".jpg", ".jpeg"):
                self.fail(el, f"envmap: '{fname}' is not an EXR, Radiance HDR, PNG or JPEG "
                              "image (the formats jgi reads)")
            try:
                self.b.environment_map(path, scale=float(p.get("scale", 1.0)), to_world=m,
                                       where=f"envmap '{fname}'")
            except SceneError as e:
                self.fail(el, str(e))

    def sensor(self, el):
        self.check_type(el)
        if self.sensor_done:
            self.fail(el, "only one sensor is supported")
        self.sensor_done = True
        p = self.props(el)
        m = p.get("to_world", np.eye(4))
        film = [c for c in el if c.tag == "film"]
        fp = self.props(film[0]) if film else {}
        w, h = int(fp.get("width", 768)), int(fp.get("height", 576))
        fov = float(p.get("fov", 39.3077))
        axis = p.get("fov_axis", "x")
        if axis == "larger":
            axis = "x" if w >= h else "y"
        elif axis == "diagonal":  # convert to the vertical field of view
            t = math.tan(math.radians(fov) / 2) * h / math.hypot(w, h)
            fov, axis = math.degrees(2 * math.atan(t)), "y"
        elif axis not in ("x", "y", "smaller"):
            self.fail(el, f"fov_axis '{axis}' unknown; supported: x, y, smaller, larger, diagonal")
        pos = m[:3, 3]
        self.b.camera(pos, pos + m[:3, 2], up=m[:3, 1], fov=fov, width=w, height=h, fov_axis=axis)
        media = [c for c in el if c.tag == "medium"]
        for c in el:
            if c.tag == "ref" and (c.get("name") == "medium" or c.get("id") in self.media):
                if c.get("id") not in self.media:
                    self.fail(c, f"reference to unknown medium '{c.get('id')}'; defined: "
                                 f"{', '.join(self.media) or '(none)'}")
                media.append(self.media[c.get("id")])
        if len(media) > 1:
            self.fail(el, "a sensor takes one medium")
        # the medium of a null shape read before: that shape's volume, cut to it (null_shape)
        bounded = [self.media.get(v[3]) if isinstance(v[3], str) else v[3]
                   for v in self.null_volumes]
        if media and not any(b is media[0] for b in bounded):
            self.medium(media[0])

    def sensor_medium_element(self, el):
        """The medium of sensor ``el``: the id it references, its nested <medium>, or None."""
        for c in el:
            if c.tag == "ref" and (c.get("name") == "medium" or c.get("id") in self.media):
                return c.get("id")
        nested = [c for c in el if c.tag == "medium"]
        return nested[0] if nested else None

    def medium_interface(self, el, kind: str, material, interior, exterior, transmits: bool,
                         emits: bool = False):
        """The material row of shape ``el`` that names media (interior / exterior: a medium id,
        a nested element, or None for vacuum), as Mitsuba 3's volpath renders them: a ray takes
        the medium on the side its next direction leaves to, at shapes that name a medium
        (elsewhere it keeps its own), and the sensor's medium is the camera's, jgi's scene
        medium (id 0). Sides that are the sensor's medium map to it; other homogeneous media,
        and vacuum where the sensor has a medium, become media bounded by the shape
        (:meth:`jgi.scene.builder.SceneBuilder.bounded_medium`). An opaque shape (no
        dielectric, no mask) with the sensor's medium outside keeps its material: its inside is
        never reached."""
        fill = self.sensor_medium_of_file

        def same(m):
            if m is None or fill is None:
                return m is fill
            return m == fill if isinstance(m, str) and isinstance(fill, str) else m is fill
        if same(exterior) and (same(interior) or not transmits):
            return material
        if emits and not same(exterior):
            self.fail(el, f"{kind}: an area emitter whose exterior medium is not the sensor's: "
                          "jgi's lights shine into the scene's own medium (the sensor's); "
                          "allowed: exterior the sensor's medium")
        names = [None if same(m) else self.bounded_medium(el, kind, m)
                 for m in (interior, exterior)]
        try:
            return self.b.medium_interface(material, interior=names[0], exterior=names[1])
        except SceneError as e:
            self.fail(el, f"{kind}: {e}")

    def null_shape(self, el, kind: str, m, shape_media: dict, emission):
        """A shape whose bsdf is ``null``: no surface (rays pass through it unchanged, as in
        Mitsuba 3). Without media of its own it is left out. A ``cube`` (any invertible affine
        to_world) or ``sphere`` (rotated, scaled uniformly, moved) whose
        interior is a medium and whose exterior is vacuum is Mitsuba's usual volume: jgi's
        grid medium cut to the shape (:mod:`jgi.physics.grid_media`; a heterogeneous
        interior's grid, zero outside its box too; a homogeneous one a constant grid), the
        scene's own medium. The sensor sits outside it in vacuum, or inside it with the
        interior as its medium: Mitsuba starts camera rays in the sensor's medium and changes
        media only where they cross a shape that names them, so either way a ray travels in the
        medium where it is inside the shape and in vacuum outside. Several such shapes are
        several volumes (two clouds; disjoint, with one phase function: the builder's
        grid_medium checks). Other null boundaries (inside another medium, meshes) are refused
        by name: jgi's surfaces that bound media scatter light."""
        if emission is not None:
            self.fail(el, f"{kind}: an area emitter on a 'null' bsdf is not supported (the "
                          "surface does not exist); give the shape a bsdf")
        interior, exterior = shape_media.get("interior"), shape_media.get("exterior")

        def same(a, b):
            if a is None or b is None:
                return a is b
            return a == b if isinstance(a, str) and isinstance(b, str) else a is b
        if same(interior, exterior):
            return   # no surface and no medium transition: nothing to render
        what = (f"{kind} with a 'null' bsdf bounding media: supported is a cube or a sphere "
                "whose interior is a medium and whose exterior is vacuum, the sensor outside "
                "it in vacuum or inside it in that medium (a volume in a convex shape)")
        if kind not in ("cube", "sphere") or exterior is not None or interior is None:
            self.fail(el, what)
        unit = np.asarray(m, float)   # the unit shape ([-1, 1]^3, the unit ball) to world
        if kind == "sphere":
            p = self.props(el)
            unit = unit @ xf.translate(p.get("center", np.zeros(3))) @ xf.scale(
                float(p.get("radius", 1.0)))
            cols = unit[:3, :3]
            if not np.allclose(cols.T @ cols, np.eye(3) * (cols[:, 0] @ cols[:, 0]), rtol=0,
                               atol=1e-9 * (cols[:, 0] @ cols[:, 0])):
                self.fail(el, "sphere: to_world must be a uniform scale, rotation and "
                              "translation (as Mitsuba's sphere)")
        if np.any(unit[3] != (0, 0, 0, 1)) or abs(np.linalg.det(unit[:3, :3])) < 1e-12:
            self.fail(el, f"{what}; its to_world must be an invertible affine map")
        if not self.null_volumes:   # the sensor's medium, unclipped, if the sensor came first
            self.b.medium_args = None   # (check_null_volume: the sensor in a volume or vacuum)
        self.null_volumes.append((el, kind, unit, interior, what))
        medium = self.media[interior] if isinstance(interior, str) else interior
        if self.check_type(medium) == "heterogeneous":
            return self.heterogeneous(medium, null=(kind, unit))
        q = self.homogeneous_params(medium)
        if kind == "cube" and axis_aligned(unit):   # a constant grid over the box
            lo, hi = unit[:3, 3] - np.diag(unit[:3, :3]), unit[:3, 3] + np.diag(unit[:3, :3])
            frame = dict()
        else:   # a constant grid over the shape's own [-1, 1]^3, cut to the ball
            lo, hi = -np.ones(3), np.ones(3)
            frame = dict(to_world=unit, clip=("sphere", unit) if kind == "sphere" else None)
        try:
            self.b.grid_medium(np.ones((1, 1, 1)), lo, hi, sigma_t=q["sigma_t"],
                               albedo=q["albedo"], g=q["g"], scale=q["scale"], **frame)
        except SceneError as e:
            self.fail(medium, str(e))

    def check_null_volume(self):
        """The sensor against the null shapes' volumes (:meth:`null_shape`), once all are
        read: inside one with its interior as the sensor's medium, or outside all in vacuum."""
        fill, cam = self.sensor_medium_of_file, self.b.camera_args
        element = lambda m: self.media[m] if isinstance(m, str) else m   # noqa: E731
        outside = None
        for el, kind, unit, interior, what in self.null_volumes:
            q = xf.apply_point(np.linalg.inv(unit), np.asarray(cam["position"], float))
            if not (np.all(np.abs(q) < 1) if kind == "cube" else q @ q < 1):
                outside = outside or (el, kind, what)
                continue
            if fill is None or element(fill) is not element(interior):
                self.fail(el, f"{what}; the sensor lies inside the {kind} but its medium is not "
                              "the interior (Mitsuba starts its rays in the sensor's medium); "
                              "give the sensor the interior's medium")
            return
        if outside is not None and fill is not None:
            el, kind, what = outside
            self.fail(el, f"{what}; the sensor lies outside the {kind} in a medium (allowed: "
                          "vacuum outside)")

    def bounded_medium(self, shape, kind: str, m) -> str:
        """The builder's name of medium ``m`` (an id, a nested element, or None: vacuum) bounded
        by a shape, defined on first use: homogeneous media only."""
        if m is None:
            name = "_vacuum"
            if name not in self.b.bounded_media:
                self.b.bounded_medium(name, sigma_t=0.0)
            return name
        el = self.media[m] if isinstance(m, str) else m
        if isinstance(m, str):
            name = m
        else:
            name = self.nested_media.setdefault(id(m), f"_medium{len(self.nested_media)}")
        if name not in self.b.bounded_media and name not in self.b.bounded_grids:
            if self.check_type(el) == "heterogeneous":   # a grid bounded by the shape
                self.heterogeneous(el, bounded=name)
                return name
            try:
                self.b.bounded_medium(name, **self.homogeneous_params(el))
            except SceneError as e:
                self.fail(el, str(e))
        return name

    def medium(self, el):
        """Mitsuba's homogeneous medium (sigma_t, albedo, scale; an isotropic or hg phase), as
        the medium that fills the scene (the sensor's; shapes' media: check_shape_media), or its
        heterogeneous one (:meth:`heterogeneous`)."""
        if self.check_type(el) == "heterogeneous":
            return self.heterogeneous(el)
        try:
            self.b.medium(**self.homogeneous_params(el))
        except SceneError as e:
            self.fail(el, str(e))

    def homogeneous_params(self, el) -> dict:
        """The builder's parameters of Mitsuba's homogeneous medium ``el``."""
        p = self.props(el)
        for k in p:
            if k not in ("sigma_t", "albedo", "scale", "sample_emitted"):
                self.fail(el, f"homogeneous medium: unknown parameter '{k}'; allowed: sigma_t, "
                              "albedo, scale, sample_emitted")
            if isinstance(p[k], TextureRef):
                self.fail(el, f"homogeneous medium: '{k}' must be a constant (a value or an "
                              "rgb), not a texture")
        return dict(sigma_t=p.get("sigma_t", 1.0), albedo=p.get("albedo", 0.75),
                    g=self.phase_g(el), scale=float(p.get("scale", 1.0)))

    def phase_g(self, el) -> float:
        """The asymmetry g of the medium ``el``'s phase function (isotropic: 0)."""
        g = 0.0
        for c in el:
            if c.tag == "phase" and self.check_type(c) == "hg":
                g = float(self.props(c).get("g", 0.8))    # Mitsuba's default g
        return g

    def heterogeneous(self, el, null=None, bounded: str | None = None):
        """Mitsuba's heterogeneous medium: sigma_t a single-channel ``gridvolume`` (.vol file;
        its box the unit cube or, with use_grid_bbox, the file's, through an affine to_world),
        an albedo (float, rgb, constvolume, or a gridvolume of 1 or 3 channels
        over the same box), scale, an isotropic or hg phase. Vacuum outside the grid's box, as
        Mitsuba clips the medium to it. ``null`` (shape, to_world): the null cube or sphere
        bounding it (:meth:`null_shape`), which cuts the grid where it differs from the grid's
        box. ``bounded``: the name of a medium bounded by shapes (a shape's
        interior or exterior), zero outside its grid's box too."""
        allowed = ("sigma_t", "albedo", "scale", "sample_emitted", "has_spectral_extinction")
        p, volumes = self.props(el), {}   # (props reads no <volume>)
        for c in el:
            name = c.get("name")
            if c.tag == "phase":
                continue
            if name not in allowed:
                self.fail(c, f"heterogeneous medium: unknown parameter '{name}'; allowed: "
                             f"{', '.join(allowed)}")
            if c.tag == "volume":
                volumes[name] = c
            elif c.tag not in ("float", "integer", "rgb", "color", "boolean", "spectrum"):
                self.fail(c, f"heterogeneous medium: '{name}' as <{c.tag}> is not supported; "
                             "allowed: <volume>, <float>, <rgb>, <boolean>")
        if "sigma_t" not in volumes:
            self.fail(el, "heterogeneous medium: sigma_t must be a <volume type=\"gridvolume\"> "
                          "(a constant extinction is a homogeneous medium)")
        grid, lo, hi, to_world = self.gridvolume(volumes["sigma_t"], "sigma_t", (1,))
        grid = grid[..., 0]
        exact = null is not None and same_region(null, lo, hi, to_world)
        clip = None if null is None or exact else null   # the grid cut to the null shape
        if to_world is not None and not exact and not zero_faces(grid):
            # Mitsuba bounds a gridvolume by the axis-aligned box around its turned box and
            # clamps lookups there, so its edge voxels' values reach into the corners between
            self.fail(el, "heterogeneous medium: a rotated or sheared gridvolume is taken where "
                          "a null cube is its very box, or where its outermost voxels are 0 "
                          "(Mitsuba extends their values to the axis-aligned box around it; jgi "
                          "does not); allowed: one of those")
        albedo = p.get("albedo", 0.75)
        if "albedo" in volumes:
            v = volumes["albedo"]
            if v.get("type") == "gridvolume":
                albedo, a_lo, a_hi, a_to_world = self.gridvolume(v, "albedo", (1, 3))
                if not (np.allclose(a_lo, lo, rtol=0, atol=1e-6)
                        and np.allclose(a_hi, hi, rtol=0, atol=1e-6)
                        and (a_to_world is None) == (to_world is None)
                        and (to_world is None or np.allclose(a_to_world, to_world, atol=1e-6))):
                    self.fail(v, f"albedo gridvolume: its box {a_lo.tolist()} - {a_hi.tolist()} "
                                 f"differs from sigma_t's {lo.tolist()} - {hi.tolist()}; allowed: "
                                 "an albedo grid over the same box")
            elif v.get("type") == "constvolume":
                q = self.props(v)
                if set(q) - {"value"}:
                    self.fail(v, "constvolume: allowed parameters: value")
                albedo = q.get("value", 1.0)
            else:
                self.fail(v, f"heterogeneous medium: albedo volume '{v.get('type')}' is not "
                             "supported; allowed: gridvolume, constvolume, <float>, <rgb>")
        params = dict(sigma_t=1.0, albedo=albedo, g=self.phase_g(el),
                      scale=float(p.get("scale", 1.0)), to_world=to_world, clip=clip)
        try:
            if bounded is not None:
                self.b.bounded_grid_medium(bounded, grid, lo, hi, **params)
            else:
                self.b.grid_medium(grid, lo, hi, **params)
        except SceneError as e:
            self.fail(el, str(e))

    def gridvolume(self, v, what: str, channels: tuple[int, ...]):
        """(data [nz, ny, nx, channels], box min, box max, to_world) of the ``gridvolume`` ``v``
        (the medium's ``what``) read from its .vol file (Mitsuba 3's conventions, see
        :mod:`jgi.physics.grid_media`): the box in world space and to_world None where the
        volume's to_world only scales (positively) and translates, else the box in the grid's
        frame and the 4 x 4 to_world that maps it (rotated, sheared, mirrored grids)."""
        if v.get("type") != "gridvolume":
            self.fail(v, f"volume '{v.get('type')}' is not supported for {what}; allowed: "
                         "gridvolume (a .vol file)")
        q = self.props(v)
        allowed = ("filename", "use_grid_bbox", "to_world", "filter_type", "wrap_mode", "raw",
                   "accel")
        for k in q:
            if k not in allowed:
                self.fail(v, f"gridvolume: unknown parameter '{k}'; allowed: "
                             f"{', '.join(allowed)}")
        if "filename" not in q:
            self.fail(v, "gridvolume: needs <string name=\"filename\"> (a .vol file)")
        if q.get("filter_type", "trilinear") != "trilinear":
            self.fail(v, f"gridvolume: filter_type '{q['filter_type']}' is not supported; "
                         "allowed: trilinear")
        if q.get("wrap_mode", "clamp") != "clamp":
            self.fail(v, f"gridvolume: wrap_mode '{q['wrap_mode']}' is not supported; "
                         "allowed: clamp")
        try:
            data, lo, hi = read_vol(self.resolve(v, q["filename"], "volume grid"))
        except VolError as e:
            self.fail(v, str(e))
        if data.shape[3] not in channels:
            self.fail(v, f"gridvolume '{q['filename']}': {data.shape[3]} channels; allowed for "
                         f"{what}: {' or '.join(map(str, channels))}")
        if not q.get("use_grid_bbox", False):
            lo, hi = np.zeros(3), np.ones(3)
        m = np.asarray(q.get("to_world", np.eye(4)), float)
        if axis_aligned(m):
            return data, m[:3, :3] @ lo + m[:3, 3], m[:3, :3] @ hi + m[:3, 3], None
        if np.any(m[3] != (0, 0, 0, 1)) or abs(np.linalg.det(m[:3, :3])) < 1e-12:
            self.fail(v, "gridvolume: to_world must be an invertible affine map (a projection "
                         "or a flattening scale is not)")
        return data, lo, hi, m

    def read_integrator(self, el):
        """Record the settings of the integrator ``el``, reading through ``moment`` and ``aov``
        wrappers to the integrator they nest (Mitsuba's moment and aov integrators render
        their nested integrator's image unchanged, adding channels)."""
        if self.integrator is not None:
            self.fail(el, "only one <integrator> is allowed (Mitsuba takes one)")
        wrappers = []
        while el.get("type") in WRAPPER_INTEGRATORS:
            wrappers.append(el.get("type"))
            inner = [c for c in el if c.tag == "integrator"]
            if not inner and el.get("type") == "aov":   # AOVs only: no light transport
                self.integrator = IntegratorSettings(None, wrappers=tuple(wrappers))
                return
            if len(inner) != 1:
                self.fail(el, f"integrator '{el.get('type')}': jgi reads through exactly one "
                              f"nested <integrator>, got {len(inner)}")
            el = inner[0]
        p = self.props(el)
        depth = int(p.get("max_depth", -1))
        if depth < -1:   # as Mitsuba checks it
            self.fail(el, f"integrator '{el.get('type')}': max_depth must be -1 (unbounded) "
                          f"or >= 0, got {depth}")
        self.integrator = IntegratorSettings(
            el.get("type"), None if depth == -1 else depth, int(p.get("rr_depth", 5)),
            bool(p.get("hide_emitters", False)), tuple(wrappers))

    # --- document -------------------------------------------------------------------------
    def children(self, root: ET.Element, file: Path, settings_only: bool = False):
        for el in root:
            tag = el.tag
            if tag == "integrator":
                self.read_integrator(el)
            elif settings_only and tag not in ("default", "path", "include"):
                continue
            elif tag == "default":
                self.defaults.setdefault(el.get("name"), el.get("value"))
            elif tag == "path":
                if not el.get("value"):
                    self.fail(el, "<path> needs a value (a folder)")
                folder = self.resolve(el, self.attr(el, "value"), "<path> folder")
                if not folder.is_dir():
                    self.fail(el, f"<path>: '{folder}' is not a folder")
                self.search_paths.insert(0, folder)
            elif tag == "include":
                inc = self.resolve(el, self.attr(el, "filename"), "included file")
                inc_root = _parse(inc, self.source)
                self.children(inc_root, inc, settings_only)
            elif tag == "bsdf":
                self.bsdf(el)
            elif tag == "shape":
                self.shape(el)
            elif tag == "emitter":
                self.emitter(el)
            elif tag == "sensor":
                self.sensor(el)
            elif tag == "texture":
                if not el.get("id"):
                    self.fail(el, "a top-level <texture> needs an id")
                self.texture(el)
            elif tag == "medium":
                if not el.get("id"):
                    self.fail(el, "a top-level <medium> needs an id (the sensor refers to it)")
                self.check_type(el)
                self.media.setdefault(el.get("id"), el)
            elif tag in IGNORED_TAGS:
                continue
            else:
                self.fail(el, f"<{tag}> is not supported; supported elements: default, path, "
                              "include, bsdf, shape, emitter, sensor, texture, medium (integrator, "
                              "sampler and rfilter are ignored)")

    def run(self, settings_only: bool = False) -> Scene | None:
        root = _parse(self.path, self.source)
        if root.tag != "scene":
            self.fail(root, f"the root element must be <scene>, got <{root.tag}>")
        # Mitsuba resolves references after parsing: a shape may <ref> an area emitter
        # defined at the top level after it
        self.area_emitters = {el.get("id"): el for el in root if el.tag == "emitter"
                              and el.get("type") == "area" and el.get("id")}
        self.media = {el.get("id"): el for el in root if el.tag == "medium" and el.get("id")}
        # the sensor's medium, which shapes' media are told apart from wherever the sensor
        # stands in the file
        sensors = [el for el in root if el.tag == "sensor"]
        self.sensor_medium_of_file = self.sensor_medium_element(sensors[0]) if sensors else None
        self.children(root, self.path, settings_only)
        if settings_only:
            return None
        if not self.sensor_done:
            raise ImportError_(f"{self.path}: the scene has no <sensor>")
        self.check_null_volume()
        return self.b.build()


def _unnormalised_rotation(axis, degrees: float) -> np.ndarray:
    """Mitsuba 3's rotate with the axis as given: c I + (1 - c) a a^T + s [a]_x."""
    a = np.asarray(axis, float)
    t = np.radians(degrees)
    c, s = np.cos(t), np.sin(t)
    cross = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    m = np.eye(4)
    m[:3, :3] = c * np.eye(3) + (1 - c) * np.outer(a, a) + s * cross
    return m


def _flat_normals(v, f, normals, to_world) -> bool:
    """Whether a mesh's vertex normals (an array in object space, or "smooth") equal its
    face normals at every corner (``v`` in world space): smooth shading would not change it."""
    if isinstance(normals, str):
        return normals_are_flat(v, f, smooth_vertex_normals(v, f))
    return normals_are_flat(v, f, normals @ np.linalg.inv(np.asarray(to_world, float)[:3, :3]))


def load_mitsuba_xml(path) -> Scene:
    """Load a Mitsuba 3 XML scene (see the module docstring for the supported subset)."""
    return _Importer(Path(path)).run()


def read_mitsuba_integrator(path) -> IntegratorSettings:
    """The integrator settings of a Mitsuba 3 XML scene (max_depth, rr_depth, hide_emitters:
    :class:`IntegratorSettings`), read through ``moment`` and ``aov`` wrappers; Mitsuba's
    defaults (a ``path`` integrator, max_depth -1, rr_depth 5) when the file has none. jgi's
    scenes do not carry render settings: pass these to the estimator."""
    importer = _Importer(Path(path))
    importer.run(settings_only=True)
    return importer.integrator or IntegratorSettings("path")

