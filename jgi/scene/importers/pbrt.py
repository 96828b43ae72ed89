"""pbrt-v4 scene files -> jgi scenes, for the subset jgi represents (see "Approximations").

Supported (anything else is refused with the file, the line, the directive/plugin and what is
supported):

  camera     Camera "perspective" ("float fov": the shorter image axis, as in pbrt), placed by
             the transform current at the Camera directive (LookAt etc.); Film "rgb"/"gbuffer"
             xresolution, yresolution. Sampler, Integrator, PixelFilter, ColorSpace, Option,
             Accelerator are ignored (jgi has its own estimators and box pixel filtering).
  transforms Identity, Translate, Scale, Rotate, LookAt, Transform, ConcatTransform,
             AttributeBegin/End (and pbrt-v3's TransformBegin/End), CoordinateSystem /
             CoordSysTransform (with pbrt's predefined "camera" and "world"; an unknown name
             is refused, where pbrt warns and keeps the transform), ReverseOrientation (as
             pbrt: a mesh's geometric normal turns under ReverseOrientation xor a
             handedness-swapping transform, deciding which side an area light lights)
  materials  Material / MakeNamedMaterial + NamedMaterial: "diffuse" (reflectance);
             "conductor" (eta and k as rgb, constant spectra or pbrt's named metal spectra
             "metal-X-eta" / "metal-X-k" of one metal X, default copper, mapped to jgi's metal X;
             or "reflectance" r, which pbrt turns into eta 1, k = 2 sqrt(r) / sqrt(1 - r));
             "dielectric" ("float eta" or a constant spectrum; named glass spectra are
             dispersive and refused). Both with roughness (or equal uroughness and vroughness:
             anisotropy is refused, as pbrt orients it along dp/du and jgi along a frame built
             from the normal) and remaproughness (default true: alpha = sqrt(roughness),
             pbrt-v4's TrowbridgeReitzDistribution::RoughnessToAlpha): GGX (Trowbridge-Reitz)
             microfacets, jgi's roughconductor / roughdielectric; where pbrt treats the surface
             as smooth (the smaller alpha below 1e-3) jgi's smooth conductor / dielectric.
             "interface": no surface; a shape with it is left out, or, a sphere or a mesh
             forming a box (any transform) with a medium inside and vacuum outside (pbrt's
             usual volume), becomes jgi's grid medium cut to the shape, the camera outside in
             vacuum or inside in that medium (_Importer.null_shape).
             Refused: "coateddiffuse" (a stochastic layered BSDF that no jgi material equals;
             use a Mitsuba or TOML roughplastic, or plastic for a smooth coating), the other
             materials, displacement and normal
             maps.
  textures   Texture "name" "spectrum" "imagemap" (filename, filter bilinear, wrap repeat,
             encoding sRGB | linear, scale) and "checkerboard" (dimension 2, rgb tex1 / tex2),
             "scale" (tex x float scale) and "mix" ((1 - float amount) tex1 + amount tex2) of
             constants, one checkerboard or one imagemap, or two of one kind with one mapping
             (folded into one jgi texture or a constant; others refused), with
             the uv mapping (uscale, vscale, udelta, vdelta), for diffuse "texture reflectance",
             on trianglemesh shapes with "point2 uv" and plymesh shapes whose file has texture
             coordinates (pbrt-v4's names: vertex properties u, v or s, t or texture_u,
             texture_v or texture_s, texture_t; v as written). Other shapes with a textured
             material are refused (pbrt's sphere uv is not jgi's), as are meshes without uv
             (pbrt's default triangle uv is not jgi's).
  shapes     "sphere" (radius), "disk" (radius, height; innerradius 0 and phimax 360 only),
             "cylinder" (radius, zmin, zmax; phimax 360 only; a transform that keeps it
             circular), both analytic with pbrt's normals and uv, "trianglemesh" (P,
             indices, N: per-vertex shading normals,
             interpolated and normalised as pbrt-v4 does), "plymesh" (filename; its normals, if
             any, as N), inside AreaLightSource "diffuse" (L, scale, power; one-sided; N only
             where it equals the face normals: jgi's emitters radiate about the geometric
             normal). pbrt-v4 also turns the geometric normal towards N; jgi keeps it as
             wound (it decides only which side an emitter lights). "float alpha" or
             "texture alpha" (a "float" checkerboard or imagemap texture, the image's first
             channel as pbrt-v4 reads it): jgi's opacity mask, tested in ray traversal with
             a hash of the ray as pbrt-v4 does; refused inside an AreaLightSource (pbrt-v4
             masks the light's emission by a hash of the point, which jgi's light sampling
             does not model)
  lights     LightSource "point" (I, from, scale, power), "spot" (I, from, to, coneangle,
             conedelta, scale, power), "distant" (L, from, to, scale, illuminance),
             "uniform" / "infinite" (L, scale, illuminance; or filename: a square equal-area
             octahedral image, EXR or PNG, nearest texel, +z up in the light's frame, with
             scale and illuminance; "portal" refused)
  media      MakeNamedMedium "name" "string type" "homogeneous" (sigma_a, sigma_s as rgb or a
             grey float, scale, g: pbrt-v4's defaults 1, 1, 1, 0) and MediumInterface
             ("inside" "outside", or one name for both; "" is vacuum): the medium outside the
             Camera is jgi's scene medium; a ray keeps its medium at every surface that is no
             medium transition and, at a Shape whose inside and outside differ, takes the
             outside on the side of the shape's normal (turned towards the shading normals N
             on meshes that have them, as pbrt-v4 does) and the inside on the other: other
             homogeneous media (and vacuum, where the camera sits in a medium) become media
             bounded by shapes (fog inside glass). "uniformgrid" (density [nx ny nz] values, x
             fastest, over the box p0 p1 in the medium's space, sigma_a, sigma_s, scale, g):
             jgi's grid medium with pbrt-v4's zero border, its box mapped by the transform
             current at MakeNamedMedium (any invertible affine one), as the camera's medium, an
             interface shape's or as grids bounded by shapes (smoke in glass jars). Refused
             by name: a grid bounded by shapes with the camera's or an interface shape's, an
             area light whose outside is not the camera's medium, other medium types
             (rgbgrid, cloud, nanovdb), "preset", emissive media (Le, temperature)
  files      Include / Import; relative file names (includes, meshes, images, spectra)
             are found in the main scene file's folder, also from included files, as pbrt-v4
             resolves them
  spectra    "spectrum" values ((wavelength, value) pairs, a .spd file next to the scene file,
             or a named illuminant: stdillum-D65, stdillum-A, stdillum-F1..F12) and
             "blackbody" values (one temperature) for lights' L / I, diffuse reflectance and
             checkerboard tex1 / tex2, converted to the RGB pbrt-v4's RGB film (sensor
             "cie1931") sees (jgi.scene.spectra.pbrt_rgb): a light spectrum at luminance 1
             times the light's scale (pbrt divides it by its photometric integral), a
             reflectance under the sRGB colour space's D65 white. Named metal spectra:
             see conductor; glass-* (dispersive) are refused

Units (pbrt-v4's RGB lights): an "rgb" emission spectrum is normalised by pbrt to the colour
space's illuminant, so its RGB values are radiance/intensity in jgi's units, times ``scale``.
``power`` sets the total emitted power: a point light's I becomes P / (4 pi), a spot light's
I becomes P / (2 pi (1 - (cos_start + cos_end) / 2)), an area light's L becomes P / (pi A) (one
sided), each divided by the luminance of the given RGB so that the *luminous* power is P (as
pbrt divides by the spectrum's photometric integral). A distant light's "illuminance" E sets
its irradiance to E / luminance(rgb) times the rgb.

Approximations: pbrt-v4 renders spectrally and jgi in RGB: a reflectance spectrum is its RGB
under white (D65) light, exact only for light of that colour; a conductor's varying eta / k
spectrum becomes its RGB as a reflectance would (pbrt evaluates Fresnel per wavelength); a
spectrum outside the sRGB gamut has its negative channels set to 0 (pbrt's film keeps them;
jgi's emission and albedos are non-negative), as Mitsuba's conversion does;
a named metal spectrum becomes the
RGB eta / k of jgi's metal of that name (Mitsuba's RGB-mode values of the measured data, which
Mitsuba's documentation says is pbrt's); and pbrt-v4's rough conductor and dielectric use the
height-correlated Smith masking-shadowing G = 1 / (1 + Lambda(wo) + Lambda(wi)) where jgi's
microfacet BSDFs (Mitsuba's) use the separable G1(wo) G1(wi), which is a little darker at
grazing angles.
"""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np

from ...core import transform as xf
from ...core.imageio import read_image
from .. import spectra
from ..builder import SceneBuilder, SceneError, pbrt_map_illuminance
from ..tables import Scene
from ._common import (
    PBRT_PLY_UV,
    ImportError_,
    axis_aligned,
    load_mesh_with_normals,
    named_metals,
    normals_are_flat,
    same_region,
)

_TOKEN = re.compile(r'"[^"]*"|\[|\]|[^\s\[\]"]+')
IGNORED = {"Sampler", "Integrator", "PixelFilter", "ColorSpace", "Option", "Accelerator",
           "WorldEnd", "Attribute"}
HOMOGENEOUS_MEDIUM_PARAMETERS = ("type", "sigma_a", "sigma_s", "scale", "g", "preset", "Le",
                                 "Lescale")
UNIFORMGRID_PARAMETERS = ("type", "density", "nx", "ny", "nz", "p0", "p1", "sigma_a", "sigma_s",
                          "scale", "g", "Le", "Lescale", "temperature", "temperaturecutoff",
                          "temperaturescale")
SUPPORTED_MEDIUM_TYPES = {"homogeneous": HOMOGENEOUS_MEDIUM_PARAMETERS,
                          "uniformgrid": UNIFORMGRID_PARAMETERS}
PBRT_MEDIUM_TYPES = ("homogeneous", "uniformgrid", "rgbgrid", "cloud", "nanovdb")
SUPPORTED = {
    "Camera": ("perspective",), "Film": ("rgb", "gbuffer", "spectral"),
    "Material": ("diffuse", "conductor", "dielectric", "interface"),
    "Shape": ("sphere", "disk", "cylinder", "trianglemesh", "plymesh"),
    "LightSource": ("point", "spot", "distant", "uniform", "infinite"),
    "AreaLightSource": ("diffuse",),
}


_ROUGH = ("roughness", "uroughness", "vroughness", "remaproughness")
MATERIAL_PARAMETERS = {
    "diffuse": ("reflectance",),
    "conductor": ("eta", "k", "reflectance") + _ROUGH,
    "dielectric": ("eta",) + _ROUGH,
    "interface": (),
}
PBRT_SMOOTH_ALPHA = 1e-3   # TrowbridgeReitzDistribution::EffectivelySmooth: min(alpha) < 1e-3
# pbrt-v4's named metal spectra (util/spectrum.cpp), mapped to the builder's metal of that name
PBRT_METALS = ("Ag", "Al", "Au", "Cu", "CuZn", "MgO", "TiO2")
PBRT_METAL = re.compile(r"metal-(\w+)-(eta|k)")
_UV_MAPPING = ("mapping", "uscale", "vscale", "udelta", "vdelta")
TEXTURE_PARAMETERS = {
    "imagemap": ("filename", "filter", "wrap", "encoding", "scale") + _UV_MAPPING,
    "checkerboard": ("dimension", "tex1", "tex2") + _UV_MAPPING,
    "scale": ("tex", "scale"),
    "mix": ("tex1", "tex2", "amount"),
}
# parameters that take "spectrum" / "blackbody" values, and whether pbrt reads them as
# illuminants (normalised to luminance 1) or as reflectances (seen under D65)
SPECTRUM_PARAMETERS = {"L": True, "I": True, "reflectance": False, "tex1": False,
                       "tex2": False}
COATEDDIFFUSE_REFUSAL = (
    "material 'coateddiffuse' is not supported: pbrt-v4's coateddiffuse is a stochastic "
    "layered BSDF (a random walk, truncated at maxdepth, between a dielectric coating and a "
    "diffuse base through a medium of the given thickness and albedo), and no choice of its "
    "parameters equals a jgi material: Mitsuba's roughplastic and smooth plastic (jgi's "
    "'roughplastic' and 'plastic') are analytic approximations of such a layer. Use a Mitsuba "
    "XML or TOML scene with a roughplastic (or, for a smooth coating, a plastic) instead.")


def _lum(rgb) -> float:
    r, g, b = rgb
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


class _Tokens:
    def __init__(self, path: Path):
        self.path = path
        try:
            text = path.read_text()
        except OSError as e:
            raise ImportError_(f"{path}: cannot read: {e}") from None
        self.items = []
        for lineno, line in enumerate(text.splitlines(), 1):
            line = line.split("#", 1)[0] if '"' not in line else _strip_comment(line)
            for m in _TOKEN.finditer(line):
                self.items.append((m.group(0), lineno))
        self.i = 0

    def peek(self):
        return self.items[self.i] if self.i < len(self.items) else (None, None)

    def next(self):
        tok = self.peek()
        self.i += 1
        return tok


def _strip_comment(line: str) -> str:
    out, quoted = [], False
    for ch in line:
        if ch == '"':
            quoted = not quoted
        if ch == "#" and not quoted:
            break
        out.append(ch)
    return "".join(out)


class _Importer:
    def __init__(self, path: Path):
        self.path = path
        self.b = SceneBuilder(path.stem)
        self.ctm = np.eye(4)
        self.stack = []
        self.material = None
        self.area = None       # (L rgb) of the current AreaLightSource
        self.reverse = False
        self.coordinate_systems: dict[str, np.ndarray] = {}   # CoordinateSystem "name"
        self.material_kind: dict[str, str] = {}              # builder name -> pbrt material
        self.null_materials: set = set()     # "interface" materials (no surface: null_shape)
        self.null_volumes = []                 # the media interface shapes bound (null_shape)
        self.camera_volume = None              # the one of them the camera lies in
        self.camera_outside = None             # (where, message): the camera outside one
        self.named = {}
        self.n_mat = 0
        self.textures: dict[str, str] = {}   # pbrt texture name -> builder texture name
        # what each pbrt texture holds, for "scale" and "mix": ("const", rgb),
        # ("checker", rgb0, rgb1, to_uv) or ("image", (path, linear, scale) or array, to_uv)
        self.texture_recipes: dict[str, tuple] = {}
        self.constant_textures: dict[str, np.ndarray] = {}  # scale / mix of constants
        self.float_textures: dict[str, str] = {}   # pbrt float texture -> builder texture
        self.alpha_materials: dict[tuple, str] = {}  # (material, alpha) -> masked copy
        self.camera_seen = False
        self.media: dict[str, tuple] = {}      # MakeNamedMedium name -> (params, where)
        self.inside = self.outside = ""        # the current MediumInterface ("": vacuum)
        self.camera_medium = ("", None)        # (name, where) outside the Camera
        self.film = (1280, 720)
        self.cam = None

    def fail(self, where, msg):
        raise ImportError_(f"{where[0]}:{where[1]}: {msg}")

    def resolve(self, name: str) -> Path:
        """A file name as pbrt-v4 resolves it (ResolveFilename): relative names against the
        main scene file's folder, also inside Included files."""
        return self.path.parent / name

    # --- parameter lists ------------------------------------------------------------------
    def params(self, toks: _Tokens, where) -> dict:
        out = {}
        while True:
            tok, line = toks.peek()
            if tok is None or not tok.startswith('"'):
                return out
            toks.next()
            decl = tok.strip('"').split()
            if len(decl) != 2:
                self.fail((toks.path, line), f"malformed parameter declaration {tok}")
            typ, name = decl
            val, _ = toks.next()
            if val == "[":
                vals = []
                while True:
                    v, l2 = toks.next()
                    if v is None:
                        self.fail((toks.path, line), f"unterminated [ for parameter '{name}'")
                    if v == "]":
                        break
                    vals.append(v)
            else:
                vals = [val]
            if typ in ("float", "integer", "rgb", "point3", "point", "normal", "normal3",
                       "vector3", "vector", "point2", "color"):
                try:
                    vals = [float(v) for v in vals]
                except ValueError:
                    self.fail((toks.path, line), f"parameter '{name}' expects numbers")
            elif typ == "bool":
                vals = [v.strip('"') == "true" for v in vals]
            elif typ in ("string", "texture"):
                vals = [v.strip('"') for v in vals]
            elif typ == "spectrum":   # a named spectrum, a file name, or (lambda, value) pairs
                try:
                    vals = [float(v) for v in vals]
                except ValueError:
                    vals = [v.strip('"') for v in vals]
            elif typ == "blackbody":
                try:
                    vals = [float(v) for v in vals]
                except ValueError:
                    vals = []
                if len(vals) != 1:
                    self.fail((toks.path, line), f"parameter '{name}': blackbody takes one "
                                                 "temperature in kelvin (for pbrt-v3's "
                                                 "[T scale], give \"float scale\")")
            out[name] = (typ, vals)

    def texture(self, name, typ, cls, p, where):
        """pbrt-v4's "imagemap" and 2D "checkerboard" spectrum textures, with the "uv" mapping
        (uscale, vscale, udelta, vdelta), as jgi textures. pbrt's image lookup flips t
        (t = 1 - (vscale v + vdelta)) and its checkerboard has squares of size 1 in (s, t)
        (tex1 where floor(s) + floor(t) is even): both become the affine to_uv of a jgi
        texture."""
        if typ == "float" and cls in ("checkerboard", "imagemap"):
            self.float_texture(name, cls, p, where)
            return
        if typ != "spectrum":
            self.fail(where, f"Texture \"{name}\": only \"spectrum\" textures (for diffuse "
                             "reflectance) and \"float\" checkerboard and imagemap textures "
                             f"(for a shape's alpha) are supported, got \"{typ}\" \"{cls}\"")
        allowed = TEXTURE_PARAMETERS.get(cls)
        if allowed is None:
            self.fail(where, f"Texture \"{name}\": class \"{cls}\" is not supported; supported: "
                             f"{', '.join(TEXTURE_PARAMETERS)}")
        for key in p:
            if key not in allowed:
                self.fail(where, f"Texture \"{name}\" (\"{cls}\"): parameter '{key}' is not "
                                 f"supported; supported: {', '.join(allowed)}")
        su, sv = (float(self._get(p, k, 1.0, where, 1)) for k in ("uscale", "vscale"))
        du, dv = (float(self._get(p, k, 0.0, where, 1)) for k in ("udelta", "vdelta"))
        if self._get(p, "mapping", ["uv"], where)[0] != "uv":
            self.fail(where, f"Texture \"{name}\": only the \"uv\" mapping is supported")
        tex = f"_pbrt_texture_{name}"
        if cls in ("scale", "mix"):
            self.combined_texture(name, cls, p, where)
            return
        try:
            if cls == "checkerboard":
                if int(self._get(p, "dimension", 2, where, 1)) != 2:
                    self.fail(where, f"Texture \"{name}\": only 2D checkerboards are supported")
                to_uv = [[su / 2, 0, du / 2], [0, sv / 2, dv / 2], [0, 0, 1]]
                c0 = self._get(p, "tex1", np.ones(3), where, 3)
                c1 = self._get(p, "tex2", np.zeros(3), where, 3)
                self.b.texture(tex, "checkerboard", color0=c0, color1=c1, to_uv=to_uv)
                self.texture_recipes[name] = ("checker", np.asarray(c0, float),
                                              np.asarray(c1, float), to_uv)
            else:
                path, linear, scale = self.imagemap_source(name, p, where)
                to_uv = [[su, 0, du], [0, -sv, 1 - dv], [0, 0, 1]]
                if scale == 1.0:
                    self.b.texture(tex, "bitmap", filename=path, raw=linear, to_uv=to_uv)
                else:   # pbrt's imagemap "scale" multiplies the texels
                    self.b.texture(tex, "bitmap", data=self.image_texels(
                        (path, linear, scale), name, where), to_uv=to_uv)
                self.texture_recipes[name] = ("image", (path, linear, scale), to_uv)
        except SceneError as e:
            self.fail(where, str(e))
        self.textures[name] = tex

    def imagemap_source(self, name, p, where) -> tuple:
        """(file path, linear encoding?, texel scale) of an "imagemap", whose filter and wrap
        must be jgi's (bilinear, repeat)."""
        for key, ok in (("filter", "bilinear"), ("wrap", "repeat")):
            v = self._get(p, key, [ok], where)[0]
            if v != ok:
                self.fail(where, f"Texture \"{name}\": {key} \"{v}\" is not supported; "
                                 f"supported: \"{ok}\"")
        enc = self._get(p, "encoding", ["sRGB"], where)[0]
        if enc not in ("sRGB", "linear"):
            self.fail(where, f"Texture \"{name}\": encoding \"{enc}\" is not supported; "
                             "supported: \"sRGB\", \"linear\"")
        fname = self._get(p, "filename", None, where)
        if not fname:
            self.fail(where, f"Texture \"{name}\": imagemap needs \"string filename\"")
        return (self.resolve(fname[0]), enc == "linear",
                float(self._get(p, "scale", 1.0, where, 1)))

    def float_texture(self, name, cls, p, where):
        """A "float" checkerboard (float tex1 / tex2) or imagemap, for shapes' "texture alpha":
        a jgi texture whose three channels hold the float (its luminance is then the float).
        pbrt-v4's float imagemap reads the image's first channel; so does this."""
        allowed = TEXTURE_PARAMETERS[cls]
        for key in p:
            if key not in allowed:
                self.fail(where, f"Texture \"{name}\" (\"float\" \"{cls}\"): parameter '{key}' "
                                 f"is not supported; supported: {', '.join(allowed)}")
        if self._get(p, "mapping", ["uv"], where)[0] != "uv":
            self.fail(where, f"Texture \"{name}\": only the \"uv\" mapping is supported")
        su, sv = (float(self._get(p, k, 1.0, where, 1)) for k in ("uscale", "vscale"))
        du, dv = (float(self._get(p, k, 0.0, where, 1)) for k in ("udelta", "vdelta"))
        tex = f"_pbrt_float_texture_{name}"
        try:
            if cls == "checkerboard":
                if int(self._get(p, "dimension", 2, where, 1)) != 2:
                    self.fail(where, f"Texture \"{name}\": only 2D checkerboards are supported")
                c0, c1 = (float(self._get(p, k, d, where, 1))
                          for k, d in (("tex1", 1.0), ("tex2", 0.0)))
                self.b.texture(tex, "checkerboard", color0=(c0,) * 3, color1=(c1,) * 3,
                               to_uv=[[su / 2, 0, du / 2], [0, sv / 2, dv / 2], [0, 0, 1]])
            else:
                path, linear, scale = self.imagemap_source(name, p, where)
                img = self.image_texels((path, linear, scale), name, where)
                self.b.texture(tex, "bitmap", data=np.repeat(img[:, :, :1], 3, axis=2),
                               to_uv=[[su, 0, du], [0, -sv, 1 - dv], [0, 0, 1]])
        except SceneError as e:
            self.fail(where, str(e))
        self.float_textures[name] = tex

    def alpha_material(self, mat: str, p, where) -> str:
        """The material of a shape with pbrt-v4's "float alpha" or "texture alpha" (a float
        texture): a copy of ``mat`` with jgi's opacity (pbrt-v4: alpha 1, the default, is no
        mask)."""
        typ, vals = p.pop("alpha")
        if typ == "float" and len(vals) == 1:
            if not 0.0 <= vals[0] <= 1.0:   # pbrt-v4 compares a hash in [0, 1) with it
                vals = [float(np.clip(vals[0], 0.0, 1.0))]
            if vals[0] == 1.0:
                return mat
            key, opacity = (mat, vals[0]), dict(opacity=vals[0])
        elif typ == "texture" and len(vals) == 1:
            if vals[0] not in self.float_textures:
                self.fail(where, f"shape \"alpha\": '{vals[0]}' is not a \"float\" texture "
                                 f"defined before it; defined: "
                                 f"{', '.join(self.float_textures) or '(none)'}")
            key, opacity = (mat, vals[0]), dict(opacity_texture=self.b.texture_names[
                self.float_textures[vals[0]]])
        else:
            self.fail(where, "shape \"alpha\" must be one \"float\" or a \"texture\" name")
        if key not in self.alpha_materials:
            name = f"{mat}_alpha{len(self.alpha_materials)}"
            self.b.material_names[name] = len(self.b.materials)
            self.b.materials.append(dataclasses.replace(
                self.b.materials[self.b.material_names[mat]], **opacity))
            self.material_kind[name] = self.material_kind.get(mat)
            self.alpha_materials[key] = name
        return self.alpha_materials[key]

    def image_texels(self, source, name, where) -> np.ndarray:
        """An imagemap's linear texels ([H, W, 3]) times its scale, as the builder reads them."""
        if isinstance(source, np.ndarray):
            return source
        path, linear, scale = source
        try:
            img = np.asarray(read_image(path, raw=linear), float)
        except (OSError, ValueError) as e:
            self.fail(where, f"Texture \"{name}\": cannot read '{path}': {e}")
        img = np.repeat(img[:, :, None], 3, axis=2) if img.ndim == 2 else img[:, :, :3]
        return img * scale

    def texture_operand(self, p, key, default, name, where) -> tuple:
        """A spectrum operand of a "scale" or "mix" texture: a texture defined before, or a
        constant (float, rgb, spectrum), as a recipe (see texture_recipes)."""
        if key not in p:
            return ("const", np.full(3, default))
        typ, vals = p[key]
        if typ == "texture":
            if vals[0] not in self.texture_recipes:
                self.fail(where, f"Texture \"{name}\": '{key}' names texture '{vals[0]}', "
                                 "which is not a spectrum texture defined before it")
            return self.texture_recipes[vals[0]]
        if typ == "float":
            return ("const", np.full(3, float(vals[0])))
        if typ == "rgb" and len(vals) == 3:
            return ("const", np.array(vals, float))
        if typ in ("spectrum", "blackbody"):
            return ("const", self.spectrum_rgb(typ, vals, False, key, where))
        self.fail(where, f"Texture \"{name}\": '{key}' must be a texture, float, rgb or "
                         f"spectrum, got \"{typ}\"")

    def texture_weight(self, p, key, default, name, where) -> float:
        """A float operand of "scale" / "mix" (pbrt's float texture): a constant here."""
        if key not in p:
            return default
        typ, vals = p[key]
        if typ != "float" or len(vals) != 1:
            self.fail(where, f"Texture \"{name}\": '{key}' is supported as a \"float\" "
                             "constant only (jgi has no float textures)")
        return float(vals[0])

    def combined_texture(self, name, cls, p, where):
        """pbrt-v4's "scale" (tex x scale) and "mix" ((1 - amount) tex1 + amount tex2) of
        constants, one checkerboard, one imagemap, or two of one kind with equal mappings (and
        images of one size): folded into one jgi texture (or a constant) of that kind."""
        if cls == "scale":
            s = self.texture_weight(p, "scale", 1.0, name, where)
            a, b = self.texture_operand(p, "tex", 1.0, name, where), ("const", np.full(3, s))
            op = (lambda x, y: x * y)
        else:
            w = self.texture_weight(p, "amount", 0.5, name, where)
            a = self.texture_operand(p, "tex1", 0.0, name, where)
            b = self.texture_operand(p, "tex2", 1.0, name, where)
            op = (lambda x, y: (1 - w) * x + w * y)
        kinds = {a[0], b[0]} - {"const"}
        if len(kinds) > 1 or (a[0] == b[0] != "const" and not np.allclose(a[-1], b[-1])):
            self.fail(where, f"Texture \"{name}\" (\"{cls}\"): its operands are a "
                             f"{a[0]} and a {b[0]} texture with different mappings; supported: "
                             "constants with one checkerboard or one imagemap, or two of one "
                             "kind with the same uv mapping (a jgi texture is one checkerboard "
                             "or one image)")
        tex = f"_pbrt_texture_{name}"
        try:
            if not kinds:
                self.constant_textures[name] = op(a[1], b[1])
                self.texture_recipes[name] = ("const", self.constant_textures[name])
                return
            if kinds == {"checker"}:
                def colors(r):
                    return (r[1], r[2]) if r[0] == "checker" else (r[1], r[1])
                (a0, a1), (b0, b1) = colors(a), colors(b)
                to_uv = (a if a[0] == "checker" else b)[3]
                c0, c1 = np.maximum(op(a0, b0), 0), np.maximum(op(a1, b1), 0)
                self.b.texture(tex, "checkerboard", color0=c0, color1=c1, to_uv=to_uv)
                self.texture_recipes[name] = ("checker", c0, c1, to_uv)
            else:
                def texels(r):
                    return r[1] if r[0] == "const" else self.image_texels(r[1], name, where)
                x, y = texels(a), texels(b)
                if x.shape != y.shape and x.ndim == y.ndim:
                    self.fail(where, f"Texture \"{name}\" (\"{cls}\"): its images differ "
                                     f"in size ({x.shape[:2]} and {y.shape[:2]})")
                img = np.maximum(op(x, y), 0)
                to_uv = (a if a[0] == "image" else b)[2]
                self.b.texture(tex, "bitmap", data=img, to_uv=to_uv)
                self.texture_recipes[name] = ("image", img, to_uv)
        except SceneError as e:
            self.fail(where, str(e))
        self.textures[name] = tex

    def _get(self, p, name, default, where, n=None):
        if name not in p:
            return default
        typ, vals = p[name]
        if typ == "texture" and name == "reflectance" and vals[0] in self.textures:
            return self.textures[vals[0]]
        if typ == "texture" and name == "reflectance" and vals[0] in self.constant_textures:
            return self.constant_textures[vals[0]]
        if typ == "texture":
            self.fail(where, f"parameter '{name}': textures are not supported (jgi has no "
                             "textures; give a constant value)")
        if typ in ("spectrum", "blackbody"):
            if name not in SPECTRUM_PARAMETERS:
                self.fail(where, f"parameter '{name}': {typ} values are supported for "
                                 f"{', '.join(SPECTRUM_PARAMETERS)} (and a conductor's eta / "
                                 "k); give rgb here")
            return self.spectrum_rgb(typ, vals, SPECTRUM_PARAMETERS[name], name, where)
        if n == 1:
            return vals[0]
        if n is not None and len(vals) != n:
            self.fail(where, f"parameter '{name}' needs {n} values, got {len(vals)}")
        return np.array(vals) if typ not in ("string", "bool") else vals

    # --- directives -----------------------------------------------------------------------
    def material_from(self, kind, p, where) -> str:
        name = f"_pbrt_material{self.n_mat}"
        self.n_mat += 1
        self.material_kind[name] = kind
        if kind == "coateddiffuse":
            self.fail(where, COATEDDIFFUSE_REFUSAL)
        if kind not in MATERIAL_PARAMETERS:
            self.fail(where, f"material '{kind}' is not supported; supported: "
                             f"{', '.join(SUPPORTED['Material'])}")
        for key in p:
            if key in ("displacement", "normalmap"):
                self.fail(where, f"material '{kind}': {key} is not supported (jgi shades with "
                                 "geometric normals)")
            if key != "type" and key not in MATERIAL_PARAMETERS[kind]:
                self.fail(where, f"material '{kind}': unknown parameter '{key}'; {kind} takes: "
                                 f"{', '.join(MATERIAL_PARAMETERS[kind])}")
        if kind == "interface":   # no surface at all (null_shape)
            self.null_materials.add(name)
            return name
        if kind == "diffuse":
            refl = p.get("reflectance", ("rgb", []))
            if refl[0] == "texture" and refl[1][0] not in {**self.textures,
                                                            **self.constant_textures}:
                self.fail(where, f"material 'diffuse': reflectance names texture "
                                 f"'{refl[1][0]}', which is not defined before it")
            self.b.material(name, "diffuse",
                            diffuse=self._get(p, "reflectance", np.full(3, 0.5), where,
                                              None if refl[0] == "texture" else 3))
        elif kind == "conductor":
            rough = self.roughness(kind, p, where)
            jgi_kind = "conductor" if rough is None else "roughconductor"
            self.b.material(name, jgi_kind, **self.conductor_ior(p, where), **(rough or {}))
        else:  # dielectric
            eta = self.dielectric_eta(p, where)
            rough = self.roughness(kind, p, where)
            if rough is None:
                self.b.material(name, "dielectric", ior=eta)
            else:
                self.b.material(name, "roughdielectric", ior=eta, **rough)
        return name

    def roughness(self, kind, p, where) -> dict | None:
        """GGX roughness from roughness / uroughness / vroughness, remapped by pbrt-v4's
        TrowbridgeReitzDistribution::RoughnessToAlpha (alpha = sqrt(roughness)) unless
        remaproughness is false; None where pbrt's EffectivelySmooth() holds (the smaller
        alpha below 1e-3): pbrt then uses the smooth (Dirac) BSDF, and so does jgi."""
        r = float(self._get(p, "roughness", 0.0, where, 1))
        u = float(self._get(p, "uroughness", r, where, 1))
        v = float(self._get(p, "vroughness", r, where, 1))
        for key, x in (("roughness", r), ("uroughness", u), ("vroughness", v)):
            if not x >= 0:
                self.fail(where, f"material '{kind}': {key} must be >= 0, got {x}")
        remap = self._get(p, "remaproughness", [True], where)[0]
        au, av = (math.sqrt(u), math.sqrt(v)) if remap else (u, v)
        if min(au, av) < PBRT_SMOOTH_ALPHA:
            return None
        if au != av:
            self.fail(where, f"material '{kind}': anisotropic roughness (uroughness != "
                             "vroughness) is not supported: pbrt orients it along the shape's "
                             "dp/du, jgi along a frame built from the normal, so the highlight "
                             "would turn; give one roughness")
        return {"distribution": "ggx", "alpha": au}

    def spectrum_source(self, typ, vals, name, where):
        """A "spectrum" or "blackbody" value as a constant, (wavelengths, values) or values at
        pbrt's 1 nm wavelengths (jgi.scene.spectra.pbrt_sample); a name jgi does not carry
        nor a readable file is refused."""
        try:
            if typ == "blackbody":
                return spectra.pbrt_blackbody(float(vals[0]))
            if len(vals) == 1 and isinstance(vals[0], str):
                named = spectra.pbrt_named(vals[0])
                if named is not None:
                    return named
                path = self.resolve(vals[0])
                if not path.is_file():
                    self.fail(where, f"parameter '{name}': '{vals[0]}' is neither a named "
                                     "spectrum jgi carries ("
                                     f"{', '.join(spectra.pbrt_named_illuminants())}; "
                                     "metal-X-eta / metal-X-k for a conductor) nor a "
                                     "spectrum file")
                return spectra.read_spd(path)
            if not all(isinstance(x, float) for x in vals):
                self.fail(where, f"parameter '{name}': a spectrum is a name, a file name or "
                                 "(wavelength, value) pairs")
            return spectra.parse_pairs(vals, f"parameter '{name}'")
        except spectra.SpectrumError as e:
            self.fail(where, str(e))

    def spectrum_rgb(self, typ, vals, illuminant, name, where) -> np.ndarray:
        """The RGB pbrt-v4's RGB film sees of a "spectrum" / "blackbody" value
        (jgi.scene.spectra.pbrt_rgb): an ``illuminant`` at luminance 1 (pbrt divides light
        spectra by their photometric integral; the light's scale multiplies), a reflectance
        under the colour space's D65 white."""
        try:
            rgb = spectra.pbrt_rgb(self.spectrum_source(typ, vals, name, where), illuminant)
        except spectra.SpectrumError as e:
            self.fail(where, f"parameter '{name}': {e}")
        if not illuminant and name in ("reflectance", "tex1", "tex2"):
            rgb = np.clip(rgb, 0.0, 1.0)   # pbrt's albedo spectra are clamped to [0, 1]
        return np.maximum(rgb, 0.0)

    def spectrum(self, p, name, where):
        """An "rgb" value (3 numbers), a constant "spectrum" ((lambda, value) pairs with one
        value, or a single number) as 3 equal numbers, or a named spectrum as its name."""
        typ, vals = p[name]
        if typ == "texture":
            self.fail(where, f"parameter '{name}': textures are not supported (jgi has no "
                             "textures; give a constant value)")
        if typ == "rgb":
            if len(vals) != 3:
                self.fail(where, f"parameter '{name}' needs 3 values, got {len(vals)}")
            return np.array(vals, float)
        if typ == "spectrum":
            if len(vals) == 1 and isinstance(vals[0], str):
                if (PBRT_METAL.fullmatch(vals[0]) or vals[0].startswith("glass-")
                        or not (self.resolve(vals[0])).is_file()):
                    return vals[0]
            if all(isinstance(x, float) for x in vals):
                values = vals[1::2] if len(vals) > 1 else vals
                if len(vals) in (1,) or (len(vals) % 2 == 0 and len(set(values)) == 1):
                    return np.full(3, values[0])
            # a varying eta / k: its RGB under D65, as for a reflectance (an approximation:
            # pbrt evaluates the Fresnel equations per wavelength)
            return self.spectrum_rgb(typ, vals, False, name, where)
        if typ == "blackbody":
            self.fail(where, f"parameter '{name}': a blackbody is an emission spectrum")
        self.fail(where, f"parameter '{name}': expected \"rgb\" or \"spectrum\", got \"{typ}\"")

    def conductor_ior(self, p, where) -> dict:
        """Builder arguments for pbrt's conductor: eta / k (rgb or pbrt's named metal spectra,
        default copper) or the "reflectance" form (eta 1, k = 2 sqrt(r) / sqrt(1 - r) with r
        clamped to [0, 0.9999], as pbrt-v4's ConductorMaterial does)."""
        if "reflectance" in p:
            if "eta" in p or "k" in p:
                self.fail(where, "conductor: give either \"reflectance\" or \"eta\" and "
                                 "\"k\", not both (pbrt refuses both)")
            r = self.spectrum(p, "reflectance", where)
            if isinstance(r, str):
                self.fail(where, "conductor: \"reflectance\" must be rgb or a constant spectrum")
            r = np.clip(r, 0.0, 0.9999)
            return {"eta": np.ones(3), "k": 2 * np.sqrt(r) / np.sqrt(1 - r)}
        eta = self.spectrum(p, "eta", where) if "eta" in p else "metal-Cu-eta"
        k = self.spectrum(p, "k", where) if "k" in p else "metal-Cu-k"
        metals = named_metals()
        named = [x for x in (eta, k) if isinstance(x, str)]
        for x in named:
            m = PBRT_METAL.fullmatch(x)
            if m is None or m.group(1) not in metals or m.group(1) == "none":
                known = ", ".join(f"metal-{n}-eta/-k" for n in PBRT_METALS if n in metals)
                self.fail(where, f"conductor: named spectrum '{x}' is not supported; supported: "
                                 f"{known} (or rgb values)")
        if len(named) == 2:
            me, mk = PBRT_METAL.fullmatch(eta), PBRT_METAL.fullmatch(k)
            if me.group(1) != mk.group(1) or me.group(2) != "eta" or mk.group(2) != "k":
                self.fail(where, f"conductor: eta '{eta}' and k '{k}' must name the same metal "
                                 "(metal-X-eta with metal-X-k)")
            return {"metal": me.group(1)}
        if named:
            self.fail(where, f"conductor: '{named[0]}' cannot be mixed with an rgb value; give "
                             "both eta and k as named spectra of one metal, or both as rgb")
        if np.any(eta < 0) or np.any(k < 0):
            self.fail(where, "conductor: eta and k must be >= 0")
        return {"eta": eta, "k": k}

    def dielectric_eta(self, p, where) -> float:
        if "eta" not in p:
            return 1.5
        typ, vals = p["eta"]
        if typ == "float":
            eta = float(vals[0])
        else:
            v = self.spectrum(p, "eta", where)
            if isinstance(v, str) or not np.all(v == v[0]):
                self.fail(where, f"dielectric: eta '{v if isinstance(v, str) else p['eta'][1]}'"
                                 " varies with wavelength (dispersion), which jgi's RGB "
                                 "renderer cannot reproduce; give \"float eta\"")
            eta = float(v[0])
        if not eta > 0:
            self.fail(where, f"dielectric: eta must be > 0, got {eta}")
        return eta

    def check(self, directive, kind, where):
        if kind not in SUPPORTED[directive]:
            self.fail(where, f"{directive} \"{kind}\" is not supported by jgi; supported: "
                             f"{', '.join(SUPPORTED[directive])}")

    def light(self, kind, p, where):
        m = self.ctm
        scale = float(self._get(p, "scale", 1.0, where, 1))
        if kind in ("point", "spot"):
            I = self._get(p, "I", np.ones(3), where, 3) * scale
            frm = xf.apply_point(m, self._get(p, "from", np.zeros(3), where, 3))
            power = float(self._get(p, "power", -1.0, where, 1))
            if kind == "point":
                if power > 0:
                    I = I * power / (4 * math.pi * _lum(I / scale))
                self.b.point_light(frm, I)
            else:
                to = xf.apply_point(m, self._get(p, "to", np.array([0.0, 0, 1]), where, 3))
                cone = float(self._get(p, "coneangle", 30.0, where, 1))
                delta = float(self._get(p, "conedelta", 5.0, where, 1))
                if power > 0:
                    c_end, c_start = (math.cos(math.radians(cone)),
                                      math.cos(math.radians(cone - delta)))
                    I = I * power / (2 * math.pi * (1 - 0.5 * (c_start + c_end)) * _lum(I / scale))
                self.b.spot_light(frm, to, I, cutoff_deg=cone, falloff_deg=max(cone - delta, 0.0))
        elif kind == "distant":
            L = self._get(p, "L", np.ones(3), where, 3) * scale
            frm = self._get(p, "from", np.zeros(3), where, 3)
            to = self._get(p, "to", np.array([0.0, 0, 1]), where, 3)
            E = float(self._get(p, "illuminance", -1.0, where, 1))
            if E > 0:
                L = L * E / _lum(L / scale)
            self.b.directional_light(xf.apply_vector(m, to - frm), L)
        else:  # uniform / infinite
            self.infinite_light(kind, p, scale, m, where)

    def infinite_light(self, kind, p, scale, m, where):
        """pbrt-v4's "infinite" (and "uniform") light: constant "L", or with "filename" an
        equal-area octahedral image (square; nearest texel, +z up in the light's frame, turned
        by the CTM). "illuminance" E scales either so that a patch facing the light's +z
        receives E: L E / (pi lum(L)) for a constant; a map by E over the illuminance pbrt-v4
        ascribes to it (:func:`jgi.scene.builder.pbrt_map_illuminance`: about half its true
        one, so the map renders with about 2 E, as in pbrt)."""
        E = float(self._get(p, "illuminance", -1.0, where, 1))
        if "portal" in p:
            self.fail(where, f"LightSource \"{kind}\": \"portal\" is not supported (pbrt-v4's "
                             "PortalImageInfiniteLight); jgi samples the whole map")
        if "filename" not in p:
            L = self._get(p, "L", np.ones(3), where, 3) * scale
            if E > 0:
                if not _lum(L) > 0:
                    self.fail(where, "\"illuminance\" needs an \"L\" of positive luminance")
                L = L * E / (math.pi * _lum(L / scale))
            self.b.environment_light(L)
            return
        if "L" in p:
            self.fail(where, "LightSource \"infinite\": give either \"L\" or \"filename\", "
                             "not both (as pbrt-v4)")
        path = self.resolve(self._get(p, "filename", "", where, 1))
        try:
            img = np.asarray(read_image(path), float)
        except (OSError, ValueError) as e:
            self.fail(where, f"LightSource \"infinite\": cannot read \"filename\" '{path}': {e}")
        if img.shape[0] != img.shape[1]:
            self.fail(where, f"LightSource \"infinite\": \"filename\" '{path}' is "
                             f"{img.shape[1]} x {img.shape[0]} texels; allowed: a square "
                             "equal-area octahedral map (pbrt-v4 refuses other shapes too)")
        if E > 0:
            measured = pbrt_map_illuminance(img)
            if not measured > 0:
                self.fail(where, f"\"illuminance\": the map '{path}' is black over its upper "
                                 "hemisphere (+z), so no scale gives it an illuminance")
            scale = scale * E / measured
        try:
            self.b.environment_map(img, scale=scale, to_world=m, mapping="octahedral",
                                   where=f"{where[0]}:{where[1]}: LightSource \"infinite\"")
        except SceneError as e:
            self.fail(where, str(e))

    def flips_normals(self) -> bool:
        """pbrt-v4 turns a shape's geometric normal around under ReverseOrientation and under
        a transform that swaps handedness, and under both it keeps it (reverseOrientation ^
        transformSwapsHandedness): which side an area light lights, and which side of a
        dielectric is outside."""
        return self.reverse != bool(np.linalg.det(self.ctm[:3, :3]) < 0)

    def quadric(self, kind, p, where, mat, emission):
        """pbrt-v4's full "disk" (radius, height) and "cylinder" (radius, zmin, zmax): analytic
        jgi disks and cylinders in the object frame under the current transform, uv as pbrt's
        (disk: (phi / 2 pi, 1 - r); cylinder: (phi / 2 pi, (z - zmin) / (zmax - zmin))), the
        normal as pbrt's intersections give it (turned by ReverseOrientation xor a handedness
        swap). Partial shapes (phimax < 360, innerradius > 0) are refused."""
        phimax = float(self._get(p, "phimax", 360.0, where, 1))
        if phimax < 360.0:
            self.fail(where, f"{kind} with \"float phimax\" {phimax} < 360 is not supported: "
                             "jgi's disks and cylinders are full (phimax 360)")
        radius = float(self._get(p, "radius", 1.0, where, 1))
        if not radius > 0:
            self.fail(where, f"{kind}: \"float radius\" must be > 0, got {radius}")
        m = self.ctm
        lin = m[:3, :3]
        ex, ey, ez = lin[:, 0], lin[:, 1], lin[:, 2]
        if kind == "disk":
            inner = float(self._get(p, "innerradius", 0.0, where, 1))
            if inner != 0.0:
                self.fail(where, f"disk with \"float innerradius\" {inner} is not supported: "
                                 "jgi's disks are full (innerradius 0)")
            center = xf.apply_point(m, [0.0, 0.0, float(self._get(p, "height", 0.0, where, 1))])
            au, av = ex * radius, ey * radius
            n = np.cross(au, av)
            if not np.linalg.norm(n) > 0:
                self.fail(where, "disk under a singular transform")
            if self.reverse:
                n = -n
            if emission is not None and self.area[1] > 0:
                emission = emission * self.area[1] / (math.pi * math.pi * np.linalg.norm(n)
                                                      * _lum(emission))
            self.b.disk(center, au, av, mat, emission, normal=n, uv="pbrt")
            return
        z0, z1 = (float(self._get(p, k, d, where, 1)) for k, d in (("zmin", -1.0),
                                                                       ("zmax", 1.0)))
        z0, z1 = min(z0, z1), max(z0, z1)
        sx, sy, sz = (float(np.linalg.norm(e)) for e in (ex, ey, ez))
        gram = lin.T @ lin
        if not (z1 > z0 and abs(sx - sy) <= 1e-6 * sx and sz > 0
                and np.allclose(gram, np.diag(np.diag(gram)), atol=1e-6 * max(sx, sz) ** 2)):
            self.fail(where, "cylinder: zmax must exceed zmin, and the transform must keep it "
                             "circular and upright (rotation, translation, uniform scale and "
                             "scaling along z; no shear, no other non-uniform scale)")
        height = (z1 - z0) * sz
        r = radius * sx
        if emission is not None and self.area[1] > 0:
            emission = emission * self.area[1] / (math.pi * 2 * math.pi * r * height
                                                  * _lum(emission))
        self.b.cylinder(xf.apply_point(m, [0.0, 0.0, z0]), ex, ez, r, height, mat, emission,
                        outward=not self.flips_normals(), axis_v=ey)

    def shape(self, kind, p, where):
        mat = self.material
        if mat is None:
            mat = self.material_from("diffuse", {}, where)
            self.material = mat
        emission = None
        if self.area is not None:
            L, power, _ = self.area
            emission = L
        if mat in self.null_materials:
            return self.null_shape(kind, p, where, emission is not None)
        if "alpha" in p:
            if emission is not None:
                # pbrt-v4 masks an area light's emission too, by a hash of the point (not of
                # the ray): a light jgi could not sample consistently
                self.fail(where, f"shape \"{kind}\" with \"alpha\" inside an AreaLightSource is "
                                 "not supported: jgi's emitters are opaque; remove the alpha")
            mat = self.alpha_material(mat, p, where)
        row = self.b.materials[self.b.material_names[mat]]
        textured = bool(row.textures) or row.opacity_texture >= 0
        if textured and kind not in ("trianglemesh", "plymesh", "disk", "cylinder"):
            self.fail(where, f"shape \"{kind}\" with a textured material: jgi imports textures "
                             "of pbrt scenes on disks, cylinders, trianglemesh shapes with "
                             "\"point2 uv\" and plymesh shapes whose file has texture "
                             "coordinates only (pbrt's sphere parametrisation differs from "
                             "jgi's, which is Mitsuba's)")
        name = mat
        mat = self.interface_material(kind, mat, where, emission is not None)
        if kind in ("disk", "cylinder"):
            self.quadric(kind, p, where, mat, emission)
            return
        if kind == "sphere":
            cols = self.ctm[:3, :3]
            s = np.linalg.norm(cols, axis=0)
            if not np.allclose(s, s[0], rtol=1e-6):
                self.fail(where, "sphere under a non-uniform scale is not supported")
            r = float(self._get(p, "radius", 1.0, where, 1)) * s[0]
            if self.flips_normals() and (emission is not None
                                         or self.material_kind.get(name) == "dielectric"
                                         or mat != name):
                self.fail(where, "sphere with inward normals (ReverseOrientation, or a "
                                 "transform that swaps handedness) as an area light, a "
                                 "dielectric or a medium boundary is not supported: jgi's "
                                 "spheres face outwards; "
                                 "use a trianglemesh")
            if emission is not None and self.area[1] > 0:
                emission = emission * self.area[1] / (math.pi * 4 * math.pi * r * r
                                                      * _lum(emission))
            self.b.sphere(xf.apply_point(self.ctm, np.zeros(3)), r, mat, emission)
            return
        uv = normals = None
        if kind == "trianglemesh":
            P = self._get(p, "P", None, where)
            idx = self._get(p, "indices", None, where)
            if P is None or len(P) % 3:
                self.fail(where, "trianglemesh needs \"point3 P\" with 3 numbers per vertex")
            v = P.reshape(-1, 3)
            if idx is None:
                if len(v) != 3:
                    self.fail(where, "trianglemesh without indices must have exactly 3 vertices")
                idx = np.arange(3)
            f = np.asarray(idx, np.int64).reshape(-1, 3)
            if f.size and (f.min() < 0 or f.max() >= len(v)):
                self.fail(where, "trianglemesh indices out of range")
            uv = self._get(p, "uv", None, where)
            if uv is not None:
                if len(uv) != 2 * len(v):
                    self.fail(where, "trianglemesh \"point2 uv\" needs 2 numbers per vertex")
                uv = np.asarray(uv, float).reshape(-1, 2)
            elif textured:
                self.fail(where, "trianglemesh with a textured material needs \"point2 uv\" "
                                 "(pbrt's default uv differs from jgi's)")
            normals = self._get(p, "N", None, where)
            if normals is not None:
                if len(normals) != 3 * len(v):
                    self.fail(where, "trianglemesh \"normal N\" needs 3 numbers per vertex")
                normals = np.asarray(normals, float).reshape(-1, 3)
        else:  # plymesh
            fname = self._get(p, "filename", None, where)
            if not fname:
                self.fail(where, "plymesh needs \"string filename\"")
            v, f, uv, normals = load_mesh_with_normals(self.resolve(fname[0]),
                                                       f"{where[0]}:{where[1]}", PBRT_PLY_UV)
            if textured and uv is None:
                self.fail(where, f"plymesh '{fname[0]}' with a textured material needs texture "
                                 "coordinates in the file (vertex properties u, v or s, t or "
                                 "texture_u, texture_v or texture_s, texture_t; pbrt's default "
                                 "uv differs from jgi's)")
            uv = uv if textured else None
        if self.flips_normals():
            f = f[:, ::-1]
        v = xf.apply_point(self.ctm, v)
        if normals is not None and mat != name:
            # a medium boundary: pbrt-v4 turns a mesh's geometric normal towards its shading
            # normals N (FaceForward), whose side is then the outside
            n_rs = normals @ np.linalg.inv(self.ctm[:3, :3])
            n_rs = -n_rs if self.reverse else n_rs
            geo = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
            away = np.einsum("ij,ij->i", geo, n_rs[f].sum(1)) < 0
            f = np.where(away[:, None], f[:, ::-1], f)
        if normals is not None:
            # pbrt-v4's TriangleMesh: N to render space (the inverse transpose), negated under
            # ReverseOrientation; the hit's shading normal is their interpolation
            normals = normals @ np.linalg.inv(self.ctm[:3, :3])
            if self.reverse:
                normals = -normals
            if emission is not None:
                if not normals_are_flat(v, f, normals):
                    self.fail(where, f"{kind} with shading normals N is an area light: jgi's "
                                     "emitters radiate about their geometric normal; remove N")
                normals = None
        if emission is not None and self.area[1] > 0:
            tri = v[f]
            area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                        axis=1).sum()
            emission = emission * self.area[1] / (math.pi * area * _lum(emission))
        self.b.mesh(v, f, mat, emission, uv=uv, normals=normals)

    def run_file(self, path: Path):
        toks = _Tokens(path)
        while True:
            tok, line = toks.next()
            if tok is None:
                return
            where = (path, line)

            def kind():
                k, _ = toks.next()
                if k is None or not k.startswith('"'):
                    self.fail(where, f"{tok} expects a quoted type name")
                return k.strip('"')

            def numbers(n):
                vals = []
                for _ in range(n):
                    v, _ = toks.next()
                    if v == "[":
                        v, _ = toks.next()
                    try:
                        vals.append(float(v))
                    except (TypeError, ValueError):
                        self.fail(where, f"{tok} expects {n} numbers")
                if toks.peek()[0] == "]":
                    toks.next()
                return np.array(vals)

            if tok in ("AttributeBegin", "TransformBegin"):
                self.stack.append((self.ctm.copy(), self.material, self.area, self.reverse,
                                   self.inside, self.outside))
            elif tok in ("AttributeEnd", "TransformEnd"):
                if not self.stack:
                    self.fail(where, f"{tok} without a matching begin")
                (self.ctm, self.material, self.area, self.reverse, self.inside,
                 self.outside) = self.stack.pop()
            elif tok == "Identity":
                self.ctm = np.eye(4)
            elif tok == "Translate":
                self.ctm = self.ctm @ xf.translate(numbers(3))
            elif tok == "Scale":
                self.ctm = self.ctm @ xf.scale(numbers(3))
            elif tok == "Rotate":
                a = numbers(4)
                self.ctm = self.ctm @ xf.rotate(a[1:], a[0])
            elif tok in ("Transform", "ConcatTransform"):
                m = numbers(16).reshape(4, 4).T  # pbrt lists matrices column by column
                self.ctm = m if tok == "Transform" else self.ctm @ m
            elif tok == "LookAt":
                a = numbers(9)
                c2w = xf.look_at(a[0:3], a[3:6], a[6:9])
                # pbrt's camera frame has x = cross(up, dir); look_at gives x = cross(up, dir) too
                self.ctm = self.ctm @ np.linalg.inv(c2w)
            elif tok == "ReverseOrientation":
                self.reverse = not self.reverse
            elif tok == "Camera":
                k = kind()
                self.check("Camera", k, where)
                p = self.params(toks, where)
                self.cam = (np.linalg.inv(self.ctm), float(self._get(p, "fov", 90.0, where, 1)))
                self.coordinate_systems["camera"] = np.linalg.inv(self.ctm)
                self.camera_medium = (self.outside, where)
            elif tok == "CoordinateSystem":
                self.coordinate_systems[kind()] = self.ctm.copy()
            elif tok == "CoordSysTransform":
                name = kind()
                if name not in self.coordinate_systems:
                    self.fail(where, f"CoordSysTransform: unknown coordinate system \"{name}\"; "
                                     "defined: "
                                     f"{', '.join(self.coordinate_systems) or '(none)'}")
                self.ctm = self.coordinate_systems[name].copy()
            elif tok == "Film":
                k = kind()
                self.check("Film", k, where)
                p = self.params(toks, where)
                self.film = (int(self._get(p, "xresolution", 1280, where, 1)),
                             int(self._get(p, "yresolution", 720, where, 1)))
            elif tok == "WorldBegin":
                self.ctm = np.eye(4)
                self.coordinate_systems["world"] = self.ctm.copy()
            elif tok == "Material":
                k = kind()
                self.material = self.material_from(k, self.params(toks, where), where)
            elif tok == "MakeNamedMaterial":
                name = kind()
                p = self.params(toks, where)
                typ = self._get(p, "type", None, where)
                if typ is None:
                    self.fail(where, f"MakeNamedMaterial \"{name}\" needs \"string type\"")
                self.named[name] = self.material_from(typ[0], p, where)
            elif tok == "NamedMaterial":
                name = kind()
                if name not in self.named:
                    self.fail(where, f"unknown named material \"{name}\"; defined: "
                                     f"{', '.join(self.named) or '(none)'}")
                self.material = self.named[name]
            elif tok == "AreaLightSource":
                k = kind()
                self.check("AreaLightSource", k, where)
                p = self.params(toks, where)
                if self._get(p, "twosided", [False], where)[0]:
                    self.fail(where, "two-sided area lights are not supported "
                                     "(jgi's emit on one side)")
                L = (self._get(p, "L", np.ones(3), where, 3)
                     * float(self._get(p, "scale", 1.0, where, 1)))
                self.area = (L, float(self._get(p, "power", -1.0, where, 1)), where)
            elif tok == "LightSource":
                k = kind()
                self.check("LightSource", k, where)
                self.light(k, self.params(toks, where), where)
            elif tok == "MakeNamedMedium":
                name = kind()
                self.make_medium(name, self.params(toks, where), where)
            elif tok == "MediumInterface":
                names = []
                while toks.peek()[0] is not None and toks.peek()[0].startswith('"') \
                        and len(names) < 2:
                    names.append(toks.next()[0].strip('"'))
                if not names:
                    self.fail(where, "MediumInterface expects one or two quoted medium names "
                                     "(inside, outside; \"\" for vacuum)")
                self.inside, self.outside = names[0], names[-1]
            elif tok == "Shape":
                k = kind()
                self.check("Shape", k, where)
                self.shape(k, self.params(toks, where), where)
            elif tok == "Texture":
                tex_name, tex_type, tex_class = kind(), kind(), kind()
                self.texture(tex_name, tex_type, tex_class, self.params(toks, where), where)
            elif tok in ("Include", "Import"):
                f, _ = toks.next()
                self.run_file(self.resolve(f.strip('"')))
            elif tok in IGNORED:
                if tok not in ("WorldEnd",):
                    k, _ = (toks.next() if toks.peek()[0] and toks.peek()[0].startswith('"')
                            else (None, None))
                    self.params(toks, where)
            else:
                self.fail(where, f"directive '{tok}' is not supported; supported: transforms, "
                                 "Camera, Film, WorldBegin, Material, MakeNamedMaterial, "
                                 "NamedMaterial, AreaLightSource, LightSource, Shape, "
                                 "MakeNamedMedium, MediumInterface, AttributeBegin/End, "
                                 "Include")

    def interface_material(self, shape, mat: str, where, emits: bool):
        """The material row of a Shape under the current MediumInterface, as pbrt-v4 renders
        it: a shape whose inside and outside differ is a medium transition (a ray leaving it
        on the side of its normal travels outside, else inside); the camera's medium is jgi's
        scene medium, other homogeneous media (and vacuum, where the camera sits in a medium)
        become media bounded by the shape. An opaque shape (no dielectric) with the camera's
        medium outside keeps its material: no ray reaches its inside."""
        if self.inside == self.outside:
            return mat
        kind = self.material_kind.get(mat, "diffuse")
        camera = self.camera_medium[0]
        if kind != "dielectric" and self.outside == camera:
            return mat
        if emits and self.outside != camera:
            self.fail(where, f"Shape \"{shape}\" is an area light with outside medium "
                             f"\"{self.outside}\": jgi's lights shine into the camera's medium "
                             f"(\"{camera}\" here); allowed: that medium outside")
        names = [None if m == camera else self.bounded_medium(m, shape, where)
                 for m in (self.inside, self.outside)]
        try:
            return self.b.medium_interface(mat, interior=names[0], exterior=names[1])
        except SceneError as e:
            self.fail(where, f"Shape \"{shape}\": {e}")

    def null_shape(self, kind, p, where, emits: bool):
        """A Shape with the "interface" material: no surface (rays pass through it, as in
        pbrt-v4). Without a medium transition it is left out. A sphere (any transform: an
        ellipsoid too, as pbrt intersects it in object space) or a triangle mesh whose vertices
        are the corners of a box, axis-aligned in world or in object space (then any
        transform), with a medium inside and vacuum outside, is pbrt's usual volume: jgi's grid
        medium cut to the shape (a "uniformgrid", zero outside its bounds too; a homogeneous
        medium a constant grid; :mod:`jgi.physics.grid_media`), the scene's own medium. The
        camera sits outside it in vacuum, or inside it with the inside medium as its own
        (pbrt-v4 starts camera rays in the camera's medium and changes media where they cross
        a MediumInterface). Several such shapes are several volumes (disjoint, with one phase
        function: the builder's grid_medium checks). Other interface shapes that bound media
        are refused by name: jgi's surfaces that bound media scatter light."""
        if emits:
            self.fail(where, f"Shape \"{kind}\" with the \"interface\" material is an area "
                             "light: not supported (the surface does not exist)")
        if self.inside == self.outside:
            return
        what = (f"Shape \"{kind}\" with the \"interface\" material bounding media (inside "
                f"\"{self.inside}\", outside \"{self.outside}\"): supported is a sphere or a "
                "triangle mesh forming a box with a medium inside and vacuum outside, the camera "
                "outside it in vacuum or inside it in that medium (a volume in a convex shape)")
        if kind not in ("sphere", "trianglemesh", "plymesh") or self.outside or not self.inside:
            self.fail(where, what)
        if kind == "sphere":
            for k in ("zmin", "zmax", "phimax"):
                if k in p:
                    self.fail(where, f"{what}; a partial sphere (\"{k}\") bounds no volume")
            shape = "sphere"
            unit = self.ctm @ xf.scale(float(self._get(p, "radius", 1.0, where, 1)))
        else:
            shape, unit = "cube", self.interface_box(kind, p, where, what)
        if abs(np.linalg.det(unit[:3, :3])) < 1e-12 or np.any(unit[3] != (0, 0, 0, 1)):
            self.fail(where, f"{what}; its transform flattens it")
        if self.cam is not None:
            q = xf.apply_point(np.linalg.inv(unit), xf.apply_point(self.cam[0], np.zeros(3)))
            inside = bool(np.all(np.abs(q) < 1) if shape == "cube" else q @ q < 1)
            camera, named = self.camera_medium[0], "box" if shape == "cube" else shape
            if inside and camera != self.inside:
                self.fail(where, f"{what}; the camera lies inside the {named} but its medium is "
                                 f"\"{camera}\", not the inside's (pbrt-v4 starts its rays in the "
                                 "camera's medium)")
            if inside:
                self.camera_volume = self.inside
            elif camera and self.camera_outside is None:   # (fill_medium: in no volume)
                self.camera_outside = (where, f"{what}; the camera lies outside the {named} in "
                                              f"medium \"{camera}\" (allowed: vacuum outside)")
        if self.inside not in self.media:
            defined = ", ".join(self.media) or "(none)"
            self.fail(where, f"MediumInterface names medium \"{self.inside}\", which no "
                             f"MakeNamedMedium defines; defined: {defined}")
        self.null_volumes.append(self.inside)   # (fill_medium: not the camera's medium again)
        mp, mwhere, to_world = self.media[self.inside]
        params = self.homogeneous_params(self.inside, mp, mwhere)
        try:
            if self._get(mp, "type", None, mwhere)[0] == "uniformgrid":
                self.fill_uniformgrid(self.inside, mp, mwhere, to_world, params["sigma_a"],
                                      params["sigma_s"], params["scale"], params["g"],
                                      null=(shape, unit))
                return
            sigma_t = np.asarray(params["sigma_a"]) + np.asarray(params["sigma_s"])
            albedo = np.divide(params["sigma_s"], sigma_t, out=np.zeros(3), where=sigma_t > 0)
            if shape == "cube" and axis_aligned(unit):   # a constant grid over the box
                d = np.diag(unit[:3, :3])
                lo, hi, frame = unit[:3, 3] - d, unit[:3, 3] + d, {}
            else:   # a constant grid over the shape's own [-1, 1]^3, cut to the ball
                lo, hi = -np.ones(3), np.ones(3)
                frame = dict(to_world=unit, clip=(shape, unit) if shape == "sphere" else None)
            self.b.grid_medium(np.ones((1, 1, 1)), lo, hi, sigma_t=sigma_t, albedo=albedo,
                               g=params["g"], scale=params["scale"], **frame)
        except SceneError as e:
            self.fail(mwhere, f"MakeNamedMedium \"{self.inside}\": {e}")

    def interface_box(self, kind, p, where, what) -> np.ndarray:
        """The map of the unit cube [-1, 1]^3 to the box an interface mesh forms: its vertices
        the corners of a box axis-aligned in world space, or in object space (then under the
        current transform, whatever it is)."""
        if kind == "trianglemesh":
            P = self._get(p, "P", None, where)
            if P is None or len(P) % 3:
                self.fail(where, "trianglemesh needs \"point3 P\" with 3 numbers per vertex")
            v = np.asarray(P, float).reshape(-1, 3)
        else:
            fname = self._get(p, "filename", None, where)
            if not fname:
                self.fail(where, "plymesh needs \"string filename\"")
            v = load_mesh_with_normals(self.resolve(fname[0]), f"{where[0]}:{where[1]}",
                                       PBRT_PLY_UV)[0]
        for points, to_world in ((xf.apply_point(self.ctm, v), np.eye(4)), (v, self.ctm)):
            lo, hi = points.min(0), points.max(0)
            tol = 1e-6 * max(float(np.abs(points).max()), 1.0)
            corner = (np.abs(points - lo) <= tol) | (np.abs(points - hi) <= tol)
            if np.all(corner) and np.all(hi - lo > tol):
                return to_world @ xf.translate((lo + hi) / 2) @ xf.scale((hi - lo) / 2)
        self.fail(where, f"{what}; its vertices are not the corners of a box (axis-aligned in "
                         "world or object space)")

    def bounded_medium(self, name: str, shape, where) -> str:
        """The builder's name of medium ``name`` ("": vacuum) bounded by a shape, defined on
        first use: a homogeneous medium, or a "uniformgrid" (a grid bounded by shapes)."""
        key = name or "_vacuum"
        if key in self.b.bounded_media:
            return key
        if not name:
            self.b.bounded_medium(key, sigma_t=0.0)
            return key
        if name not in self.media:
            defined = ", ".join(self.media) or "(none)"
            self.fail(where, f"MediumInterface names medium \"{name}\", which no "
                             f"MakeNamedMedium defines; defined: {defined}")
        p, mwhere, to_world = self.media[name]
        params = self.homogeneous_params(name, p, mwhere)
        is_grid = self._get(p, "type", None, mwhere)[0] == "uniformgrid"
        try:
            if is_grid:
                if key not in self.b.bounded_grids:
                    self.fill_uniformgrid(name, p, mwhere, to_world, params["sigma_a"],
                                          params["sigma_s"], params["scale"], params["g"],
                                          bounded=key)
                return key
            self.b.bounded_medium(key, **params)
        except ImportError_:
            raise
        except SceneError as e:
            self.fail(mwhere, f"MakeNamedMedium \"{name}\": {e}")
        return key

    def homogeneous_params(self, name, p, where) -> dict:
        """The builder's parameters of pbrt-v4's homogeneous medium ``name``."""
        def rgb(key):
            v = np.asarray(self._get(p, key, np.ones(3), where), float).reshape(-1)
            if v.size not in (1, 3):
                self.fail(where, f"MakeNamedMedium \"{name}\": '{key}' takes an rgb or one "
                                 f"float, got {v.size} values")
            return np.broadcast_to(v, (3,))
        return dict(sigma_a=rgb("sigma_a"), sigma_s=rgb("sigma_s"),
                    scale=float(self._get(p, "scale", 1.0, where, 1)),
                    g=float(self._get(p, "g", 0.0, where, 1)))

    def make_medium(self, name, p, where):
        """MakeNamedMedium: pbrt-v4's homogeneous medium, checked here and built if the Camera
        sits in it (:meth:`fill_medium`)."""
        typ = self._get(p, "type", None, where)
        if typ is None:
            self.fail(where, f"MakeNamedMedium \"{name}\" needs \"string type\"")
        typ = typ[0]
        if typ not in SUPPORTED_MEDIUM_TYPES:
            known = typ in PBRT_MEDIUM_TYPES
            self.fail(where, f"MakeNamedMedium \"{name}\": medium type \"{typ}\" is "
                             f"{'not supported yet' if known else 'unknown'}; supported: "
                             f"{', '.join(SUPPORTED_MEDIUM_TYPES)}")
        allowed = SUPPORTED_MEDIUM_TYPES[typ]
        for key in p:
            if key not in allowed:
                self.fail(where, f"MakeNamedMedium \"{name}\" ({typ}): unknown parameter "
                                 f"'{key}'; {typ} takes: {', '.join(allowed)}")
        if "preset" in p:
            self.fail(where, f"MakeNamedMedium \"{name}\": \"preset\" (pbrt's measured media) is "
                             "not supported; give sigma_a and sigma_s")
        if "Le" in p and np.any(np.asarray(self._get(p, "Le", np.zeros(3), where)) != 0):
            self.fail(where, f"MakeNamedMedium \"{name}\": emissive media (Le) are not "
                             "supported")
        if "temperature" in p:
            self.fail(where, f"MakeNamedMedium \"{name}\": emissive media (temperature) are not "
                             "supported")
        self.media[name] = (p, where, self.ctm.copy())

    def fill_medium(self):
        """The medium outside the Camera fills the scene (pbrt-v4 keeps a ray's medium at
        surfaces that are no transition, and jgi refused every transition)."""
        name, where = self.camera_medium
        if self.null_volumes:   # then the camera's medium is one of theirs, or vacuum
            if name and self.camera_volume is None:
                self.fail(*(self.camera_outside or (where, f"the camera's medium \"{name}\" "
                            "with interface volumes: allowed: vacuum, or the inside of the "
                            "interface shape the camera lies in")))
            return
        if not name:
            return
        if name not in self.media:
            self.fail(where, f"the Camera's MediumInterface names medium \"{name}\", which no "
                             "MakeNamedMedium defines; defined: "
                             f"{', '.join(self.media) or '(none)'}")
        p, mwhere, to_world = self.media[name]
        params = self.homogeneous_params(name, p, mwhere)
        try:
            if self._get(p, "type", None, mwhere)[0] == "uniformgrid":
                self.fill_uniformgrid(name, p, mwhere, to_world, params["sigma_a"],
                                      params["sigma_s"], params["scale"], params["g"])
                return
            self.b.medium(**params)
        except SceneError as e:
            self.fail(mwhere, f"MakeNamedMedium \"{name}\": {e}")

    def fill_uniformgrid(self, name, p, where, to_world, sigma_a, sigma_s, scale, g, null=None,
                         bounded: str | None = None):
        """pbrt-v4's GridMedium: densities d[(z ny + y) nx + x] over the box [p0, p1] of the
        medium's space (its sample i at (i + 1/2) / n, lookups beyond the samples 0: jgi's
        "zero" border), extinction (sigma_a + sigma_s) scale d(x), albedo sigma_s / sigma_t.
        The box goes to world space by the transform current at MakeNamedMedium: an
        axis-aligned box where it only scales (per axis, flips too) and translates, else the
        grid's own frame (pbrt-v4 tracks in medium space, so the medium is the turned box). The
        camera's medium; with ``null`` (shape, unit shape to world), the volume of an
        interface shape, cut to it where it is not the grid's box; with ``bounded`` (the
        builder's name), the grid bounded by shapes (smoke in a glass jar)."""
        dims = [int(self._get(p, k, 1, where, 1)) for k in ("nx", "ny", "nz")]
        if min(dims) < 1:
            self.fail(where, f"MakeNamedMedium \"{name}\" (uniformgrid): nx, ny, nz must be "
                             f">= 1, got {dims}")
        if "density" not in p:
            self.fail(where, f"MakeNamedMedium \"{name}\" (uniformgrid) needs \"float density\" "
                             f"(nx ny nz = {int(np.prod(dims))} values)")
        values = np.asarray(self._get(p, "density", None, where), float).reshape(-1)
        if values.size != int(np.prod(dims)):
            self.fail(where, f"MakeNamedMedium \"{name}\" (uniformgrid): \"density\" has "
                             f"{values.size} values; nx ny nz = {dims[0]} x {dims[1]} x "
                             f"{dims[2]} needs {int(np.prod(dims))}")
        grid = values.reshape(dims[2], dims[1], dims[0])
        p0 = np.asarray(self._get(p, "p0", np.zeros(3), where, 3), float)
        p1 = np.asarray(self._get(p, "p1", np.ones(3), where, 3), float)
        if not np.all(p1 > p0):
            self.fail(where, f"MakeNamedMedium \"{name}\" (uniformgrid): p1 {p1.tolist()} must "
                             f"exceed p0 {p0.tolist()} in every axis")
        linear = to_world[:3, :3]
        if np.any(to_world[3] != (0, 0, 0, 1)) or abs(np.linalg.det(linear)) < 1e-12:
            self.fail(where, f"MakeNamedMedium \"{name}\" (uniformgrid): the current transform "
                             "projects or flattens the grid; allowed: an invertible affine one")
        frame = None
        if np.all(np.abs(linear - np.diag(np.diag(linear))) <= 1e-9 * np.abs(linear).max()):
            a, b = (xf.apply_point(to_world, q) for q in (p0, p1))
            lo, hi = np.minimum(a, b), np.maximum(a, b)
            for axis, flip in enumerate(np.diag(linear) < 0):   # a mirrored axis: reversed
                if flip:
                    grid = np.flip(grid, axis=2 - axis)
        else:   # rotated or sheared: the box in the grid's frame
            lo, hi, frame = p0, p1, to_world
        clip = None if null is None or same_region(null, lo, hi, frame) else null
        sigma_t = np.asarray(sigma_a) + np.asarray(sigma_s)
        albedo = np.divide(sigma_s, sigma_t, out=np.zeros(3), where=sigma_t > 0)
        params = dict(sigma_t=sigma_t, albedo=albedo, g=g, scale=scale, border="zero",
                      to_world=frame, clip=clip)
        if bounded is None:
            self.b.grid_medium(grid, lo, hi, **params)
        else:
            self.b.bounded_grid_medium(bounded, grid, lo, hi, **params)

    def run(self) -> Scene:
        self.run_file(self.path)
        if self.cam is None:
            raise ImportError_(f"{self.path}: the scene has no Camera")
        self.fill_medium()
        c2w, fov = self.cam
        w, h = self.film
        pos = xf.apply_point(c2w, np.zeros(3))
        fwd = xf.apply_vector(c2w, np.array([0.0, 0, 1]))
        up = xf.apply_vector(c2w, np.array([0.0, 1, 0]))
        x_axis = xf.apply_vector(c2w, np.array([1.0, 0, 0]))
        # pbrt's raster x runs along the camera's +x; jgi's along cross(forward, up)
        mirror = float(np.dot(x_axis, np.cross(fwd, up))) < 0
        self.b.camera(pos, pos + fwd, up=up, fov=fov, width=w, height=h, fov_axis="smaller",
                      mirror=mirror)
        return self.b.build()


def load_pbrt(path) -> Scene:
    """Load a pbrt-v4 scene (see the module docstring for the supported subset)."""
    return _Importer(Path(path)).run()
