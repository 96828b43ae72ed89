"""Scene loading: built-in names, jgi TOML scene files, Mitsuba 3 XML and pbrt-v4 files.

The TOML format is documented key by key in ``docs/scene-format.md``; ``scenes/*.toml`` are
examples. A file is read with :mod:`tomllib`, checked completely, and turned into a
:class:`~jgi.scene.Scene` through :class:`~jgi.scene.SceneBuilder`. Loading runs on the host
(numpy), never under ``jit``, so a mistake can never surface as a JAX traceback.

Validation policy: every mistake is a :class:`jgi.SceneError` whose message is
``FILE: KEY PATH: what is wrong; allowed: ...``, with key paths counted from 0 in file order
(``shape[3].radius``, ``shape[0].transform.rotate[1].angle``, ``material[1].type``). Nothing is
silently ignored: an unknown key is an error (it is usually a typo, and a close match is
suggested). Degenerate geometry (zero-radius spheres, zero-area quads, singular transforms) is
refused rather than warned about, since it renders as nothing or as NaN. Two conditions that
can be deliberate only warn (:class:`SceneWarning`): a scene without any light, and a mesh
containing zero-area triangles.
"""

from __future__ import annotations

import difflib
import inspect
import math
import re
import tomllib
import warnings
from pathlib import Path

import numpy as np

from ..core import transform as xf
from . import builtin as scenes
from .builder import ENVIRONMENT_MAPPINGS, IOR_AIR, SceneBuilder, SceneError
from .importers import load_mitsuba_xml, load_pbrt
from .importers._common import (
    has_texture_coordinates,
    has_vertex_normals,
    load_mesh,
    load_mesh_with_normals,
)
from .importers.volgrid import VolError, read_vol
from .tables import ENVIRONMENT, MATERIAL_KINDS, MICROFACET_DISTRIBUTIONS, NAMED_METALS, Scene


class SceneWarning(UserWarning):
    """A scene that loads but is probably not what was meant (no light, degenerate triangles)."""


# ------------------------------------------------------------------------------------------------
# Schema: key -> value kind, per table and per type
# ------------------------------------------------------------------------------------------------

TOP_KEYS = ("name", "camera", "texture", "material", "shape", "light", "medium")

CAMERA_KEYS = {"position": "vec3", "look_at": "vec3", "up": "vec3", "fov": "number",
               "fov_axis": "str", "width": "int", "height": "int", "medium": "str"}
CAMERA_REQUIRED = ("position", "look_at")
FOV_AXES = ("x", "y", "smaller")

# [[medium]] tables (SceneBuilder.medium): Mitsuba's sigma_t and albedo, or pbrt-v4's sigma_a
# and sigma_s, times scale; Henyey-Greenstein g. The camera's medium fills the scene.
MEDIUM_KEYS = {"homogeneous": {"name": "str", "type": "str", "sigma_t": "rgb", "albedo": "rgb",
                               "sigma_a": "rgb", "sigma_s": "rgb", "g": "number",
                               "scale": "number"},
               # a density grid (SceneBuilder.grid_medium): from a Mitsuba .vol file (its box by
               # default) or inline, density = [[[x values] per y] per z]; transform: the
               # grid's frame (its box) to the world; clip: "cube" or "sphere", a convex null
               # boundary cutting the medium (its unit shape placed by clip_transform)
               "grid": {"name": "str", "type": "str", "file": "str", "density": "grid",
                        "bbox_min": "vec3", "bbox_max": "vec3", "sigma_t": "rgb", "albedo": "rgb",
                        "albedo_file": "str", "g": "number", "scale": "number",
                        "border": "str", "transform": "table", "clip": "str",
                        "clip_transform": "table"}}

# Each material type accepts only the parameters its BSDF uses (a key another type uses is a
# likely mistake, e.g. `ior` on a mirror). Defaults are filled in by `_material`.
# "rgb|texture" and "number|texture": a value, or the name of a [[texture]].
_ROUGH = {"alpha": "number|texture", "alpha_u": "number|texture", "alpha_v": "number|texture",
          "distribution": "str"}
_METAL = {"metal": "str", "eta": "rgb", "k": "rgb", "specular": "rgb|texture"}
_IOR = {"ior": "number", "int_ior": "number", "ext_ior": "number"}
MATERIAL_KEYS = {
    "diffuse": {"diffuse": "rgb|texture"},
    "mirror": {"specular": "rgb|texture"},
    "dielectric": {**_IOR, "specular": "rgb|texture", "transmittance": "rgb"},
    "phong": {"diffuse": "rgb|texture", "specular": "rgb|texture", "exponent": "number"},
    "conductor": _METAL,
    "roughconductor": {**_METAL, **_ROUGH},
    "roughdielectric": {**_IOR, "specular": "rgb|texture", "transmittance": "rgb", **_ROUGH},
    "roughplastic": {"diffuse": "rgb|texture", "specular": "rgb|texture", **_IOR,
                     "nonlinear": "bool", "alpha": "number", "distribution": "str"},
    "plastic": {"diffuse": "rgb|texture", "specular": "rgb|texture", **_IOR, "nonlinear": "bool"},
}
# the reflective types may be one-sided (Mitsuba's default; jgi's is two-sided, as pbrt's)
for _kind, _keys in MATERIAL_KEYS.items():
    if _kind not in ("dielectric", "roughdielectric"):
        _keys["one_sided"] = "bool"
    # an opacity mask (Mitsuba's mask, pbrt-v4's alpha): a probability, or a texture
    _keys["opacity"] = "number|texture"
del _kind, _keys
# [[texture]] tables: Mitsuba's checkerboard and bitmap (SceneBuilder.texture).
TEXTURE_KEYS = {
    "checkerboard": {"color0": "rgb", "color1": "rgb"},
    "bitmap": {"filename": "str", "raw": "bool"},
}
TEXTURE_COMMON = {"name": "str", "type": "str", "scale": "uv", "offset": "uv"}
MATERIAL_REQUIRED = {"phong": ("specular", "exponent")}
# Defaults that differ from the builder's (SceneBuilder.material documents the others: ior,
# int_ior, ext_ior, alpha 0.1, distribution "ggx", metal "none", nonlinear false).
MATERIAL_DEFAULTS = {
    "diffuse": {"diffuse": 0.5},
    "mirror": {"specular": 1.0},
    "dielectric": {"specular": 1.0},
    "phong": {"diffuse": 0.0},
    "conductor": {"specular": 1.0},
    "roughconductor": {"specular": 1.0},
    "roughdielectric": {"specular": 1.0},
    "roughplastic": {"diffuse": 0.5, "specular": 1.0},
    "plastic": {"diffuse": 0.5, "specular": 1.0},
}
# English names of common metals, for the suggestion in an unknown-metal error
METAL_WORDS = {"gold": "Au", "silver": "Ag", "copper": "Cu", "aluminium": "Al",
               "aluminum": "Al", "chromium": "Cr", "chrome": "Cr", "tungsten": "W",
               "mercury": "Hg", "nickel": "Ni_palik", "iridium": "Ir", "rhodium": "Rh"}
# Material types that the importers know but the TOML format refuses, with what to use instead.
MATERIAL_ALTERNATIVES: dict = {}

SHAPE_COMMON = {"type": "str", "material": "str", "emission": "rgb", "transform": "table",
                # media the shape bounds: [[medium]] names (SceneBuilder.medium_interface; a
                # side left out is the camera's medium, the scene's own)
                "interior": "str", "exterior": "str"}
SHAPE_KEYS = {
    "sphere": {"center": "vec3", "radius": "number"},
    "quad": {"origin": "vec3", "edge_u": "vec3", "edge_v": "vec3"},
    "rectangle": {},
    "cube": {},
    "mesh": {"file": "str", "flat": "bool"},
}
SHAPE_REQUIRED = {"sphere": ("center", "radius"), "quad": ("origin", "edge_u", "edge_v"),
                  "mesh": ("file",)}
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")

LIGHT_KEYS = {
    "point": {"position": "vec3", "intensity": "rgb"},
    "spot": {"position": "vec3", "target": "vec3", "intensity": "rgb", "cutoff": "number",
             "falloff": "number"},
    "directional": {"direction": "vec3", "irradiance": "rgb"},
    "environment": {"radiance": "rgb", "image": "str", "scale": "number", "transform": "table",
                    "mapping": "str"},
}
LIGHT_REQUIRED = {"point": ("position", "intensity"),
                  "spot": ("position", "target", "intensity"),
                  "directional": ("direction", "irradiance"), "environment": ()}

TRANSFORM_KEYS = ("matrix", "translate", "rotate", "scale")
ROTATE_KEYS = {"axis": "vec3", "angle": "number"}

# A linear map whose smallest singular value is below this fraction of its largest flattens
# the shape (zero volume/area) within float32 precision.
SINGULAR_RTOL = 1e-7

FILE_OPTIONS = ("resolution", "width", "height")


# ------------------------------------------------------------------------------------------------
# Entry point
# ------------------------------------------------------------------------------------------------

def load_scene(source: str | Path, **kwargs) -> Scene:
    """A built-in scene by name, or a scene file: ``.toml`` (jgi), ``.xml`` (Mitsuba 3) or
    ``.pbrt`` (pbrt-v4).

    For a built-in, ``kwargs`` go to its constructor (e.g. ``resolution=64``). For a file they
    override the film size: ``width=`` and/or ``height=``, or ``resolution=N`` (width N); a
    dimension not given keeps the file's aspect ratio. The field of view is unchanged.
    """
    src = str(source)
    if src in scenes.BUILTINS:
        fn = scenes.BUILTINS[src]
        allowed = list(inspect.signature(fn).parameters)
        unknown = sorted(set(kwargs) - set(allowed))
        if unknown:
            raise SceneError(f"built-in scene '{src}': unknown option '{unknown[0]}'; allowed: "
                             f"{', '.join(allowed) or '(none)'}")
        return fn(**kwargs)
    path = Path(src)
    unknown = sorted(set(kwargs) - set(FILE_OPTIONS))
    if unknown:
        raise SceneError(f"{src}: unknown option '{unknown[0]}' for a scene file; allowed: "
                         f"{', '.join(FILE_OPTIONS)}")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        scene = _TomlLoader(path).load()
    elif suffix == ".xml":
        scene = load_mitsuba_xml(path)
    elif suffix == ".pbrt":
        scene = load_pbrt(path)
    else:
        raise SceneError(f"{src}: not a built-in scene ({', '.join(scenes.BUILTINS)}) and not a "
                         "scene file (.toml, .xml, .pbrt)")
    return _resize(scene, src, kwargs)


def _resize(scene: Scene, src: str, opts: dict) -> Scene:
    if not opts:
        return scene
    for k, v in opts.items():
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise SceneError(f"{src}: option {k}: expected a positive integer, got {v!r}")
    w0, h0 = scene.camera.width, scene.camera.height
    w = opts.get("width", opts.get("resolution"))
    h = opts.get("height")
    if w is None:
        w = max(1, round(h * w0 / h0))
    if h is None:
        h = max(1, round(w * h0 / w0))
    return scene.with_resolution(int(w), int(h))


# ------------------------------------------------------------------------------------------------
# TOML loader
# ------------------------------------------------------------------------------------------------

def _toml_type(v) -> str:
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, int):
        return "an integer"
    if isinstance(v, float):
        return "a float"
    if isinstance(v, str):
        return "a string"
    if isinstance(v, list):
        return f"an array of {len(v)}"
    if isinstance(v, dict):
        return "a table"
    return f"a {type(v).__name__}"


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


class _TomlLoader:
    """One pass over a parsed document; ``fail`` raises with the file and key path."""

    def __init__(self, path: Path):
        self.path = path
        self.medium_tables: dict = {}   # [[medium]] name -> (key, table)
        self.camera_medium = None

    def fail(self, key: str, msg: str):
        raise SceneError(f"{self.path}: {key}: {msg}" if key else f"{self.path}: {msg}")

    # --- typed values ------------------------------------------------------------------------
    def value(self, key: str, v, kind: str):
        """Check one value against its kind: str, int, number, bool, vec3, rgb or table."""
        got = f"got {v!r} ({_toml_type(v)})"
        if kind == "str":
            if not isinstance(v, str):
                self.fail(key, f"expected a string, {got}")
            return v
        if kind.endswith("|texture"):
            if isinstance(v, str):   # a texture's name (checked by the material)
                return v
            try:
                return self.value(key, v, kind.split("|")[0])
            except SceneError:
                what = "3 numbers [r, g, b] or one number" if kind.startswith("rgb") else "a number"
                self.fail(key, f"expected {what}, or a texture's name (a string), {got}")
        if kind == "uv":
            if _is_number(v):
                v = [v, v]
            if (not isinstance(v, list) or len(v) != 2 or not all(_is_number(x) for x in v)
                    or not all(math.isfinite(x) for x in v)):
                self.fail(key, f"expected one number or 2 numbers [u, v], {got}")
            return np.asarray(v, float)
        if kind == "int":
            if isinstance(v, bool) or not isinstance(v, int):
                self.fail(key, f"expected an integer, {got}")
            return v
        if kind == "number":
            if not _is_number(v):
                self.fail(key, f"expected a number, {got}")
            if not math.isfinite(v):
                self.fail(key, f"expected a finite number, got {v!r}")
            return float(v)
        if kind in ("vec3", "rgb"):
            if kind == "rgb" and _is_number(v):
                v = [v, v, v]
            if not isinstance(v, list) or len(v) != 3 or not all(_is_number(x) for x in v):
                allowed = ("3 numbers [r, g, b] or one number (grey)" if kind == "rgb"
                           else "3 numbers [x, y, z]")
                self.fail(key, f"expected {allowed}, {got}")
            a = np.asarray(v, float)
            if not np.all(np.isfinite(a)):
                self.fail(key, f"expected finite numbers, got {v!r}")
            if kind == "rgb" and np.any(a < 0):
                self.fail(key, f"colours must be non-negative, got {v!r}")
            return a
        if kind == "grid":
            try:
                a = np.asarray(v, float)
            except (TypeError, ValueError):
                a = None
            if a is None or a.ndim != 3 or a.size == 0 or not np.all(np.isfinite(a)):
                self.fail(key, f"expected a [nz][ny][nx] nested array of finite numbers, {got}")
            return a
        if kind == "bool":
            if not isinstance(v, bool):
                self.fail(key, f"expected true or false, {got}")
            return v
        if kind == "table":
            if not isinstance(v, dict):
                self.fail(key, f"expected a table {{ ... }}, {got}")
            return v
        raise AssertionError(kind)

    def table(self, key: str, t, allowed: dict, required=(), what: str = "") -> dict:
        """Check a table's keys (unknown ones, missing required ones) and each value's kind."""
        if not isinstance(t, dict):
            self.fail(key, f"expected a table, got {t!r} ({_toml_type(t)})")
        for k in t:
            if k not in allowed:
                near = difflib.get_close_matches(k, list(allowed), n=1)
                hint = f" (did you mean '{near[0]}'?)" if near else ""
                self.fail(f"{key}.{k}", f"unknown key{what}{hint}; allowed: "
                                        f"{', '.join(sorted(allowed))}")
        for r in required:
            if r not in t:
                self.fail(f"{key}.{r}", f"missing (required{what}); required keys: "
                                        f"{', '.join(required)}")
        return {k: self.value(f"{key}.{k}", v, allowed[k]) for k, v in t.items()}

    def array_of_tables(self, doc: dict, name: str) -> list:
        items = doc.get(name, [])
        if not isinstance(items, list):
            self.fail(name, f"expected an array of tables: write [[{name}]] (double brackets) "
                            "before each entry")
        return items

    def type_of(self, key: str, t, allowed) -> str:
        """The ``type`` of a [[material]]/[[shape]]/[[light]] entry, checked against ``allowed``."""
        if not isinstance(t, dict):
            self.fail(key, f"expected a table, got {t!r} ({_toml_type(t)})")
        if "type" not in t:
            self.fail(f"{key}.type", f"missing (required); allowed: {', '.join(allowed)}")
        kind = t["type"]
        if not isinstance(kind, str) or kind not in allowed:
            self.fail(f"{key}.type", f"unknown type {kind!r}; allowed: {', '.join(allowed)}")
        return kind

    # --- transforms --------------------------------------------------------------------------
    def transform(self, key: str, t: dict) -> np.ndarray:
        """The 4x4 matrix of a ``transform`` table: ``matrix``, or translate * rotate * scale."""
        for k in t:
            if k not in TRANSFORM_KEYS:
                self.fail(f"{key}.{k}", f"unknown key; allowed: {', '.join(TRANSFORM_KEYS)}")
        if "matrix" in t:
            if len(t) != 1:
                self.fail(key, "give either matrix or translate/rotate/scale, not both")
            m = t["matrix"]
            if (not isinstance(m, list) or len(m) != 4 or not all(
                    isinstance(r, list) and len(r) == 4 and all(_is_number(x) for x in r)
                    for r in m)):
                self.fail(f"{key}.matrix", f"expected 4 rows of 4 numbers (row-major), got {m!r}")
            m = np.asarray(m, float)
            if not np.all(np.isfinite(m)):
                self.fail(f"{key}.matrix", "expected finite numbers")
            if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
                self.fail(f"{key}.matrix", f"the last row must be [0, 0, 0, 1] (affine), got "
                                           f"{m[3].tolist()}")
        else:
            S = np.eye(4)
            if "scale" in t:
                s = t["scale"]
                s = self.value(f"{key}.scale", s, "vec3" if isinstance(s, list) else "number")
                S = xf.scale(s)
            R = np.eye(4)
            rots = t.get("rotate", [])
            rots = [rots] if isinstance(rots, dict) else rots
            if not isinstance(rots, list):
                self.fail(f"{key}.rotate", "expected { axis = [x, y, z], angle = degrees } or an "
                                           f"array of them, got {rots!r} ({_toml_type(rots)})")
            sub = f"{key}.rotate" if isinstance(t.get("rotate"), dict) else None
            for i, r in enumerate(rots):
                rk = sub or f"{key}.rotate[{i}]"
                rr = self.table(rk, r, ROTATE_KEYS, ("axis", "angle"))
                if not np.any(rr["axis"]):
                    self.fail(f"{rk}.axis", "must be non-zero")
                R = xf.rotate(rr["axis"], rr["angle"]) @ R  # listed order = application order
            T = xf.translate(self.value(f"{key}.translate", t["translate"], "vec3")) \
                if "translate" in t else np.eye(4)
            m = T @ R @ S
        sv = np.linalg.svd(m[:3, :3], compute_uv=False)
        if not sv[0] > 0 or sv[-1] <= SINGULAR_RTOL * sv[0]:
            self.fail(key, "the transform is singular (it flattens the shape, e.g. a zero "
                           "scale); allowed: an invertible transform")
        return m

    # --- document ----------------------------------------------------------------------------
    def parse(self) -> dict:
        try:
            text = self.path.read_bytes().decode("utf-8")
        except OSError as e:
            self.fail("", f"cannot read the scene file: {e.strerror or e}")
        except UnicodeDecodeError as e:
            self.fail("", f"not a UTF-8 text file (byte {e.start}); TOML files are UTF-8")
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            msg = f"TOML syntax error: {e}"
            line = re.search(r"line (\d+)", str(e))
            if line:
                lines = text.splitlines()
                n = int(line.group(1))
                if 1 <= n <= len(lines):
                    msg += f"\n    {n} | {lines[n - 1]}"
            self.fail("", msg)

    def load(self) -> Scene:
        doc = self.parse()
        for k in doc:
            if k not in TOP_KEYS:
                near = difflib.get_close_matches(k, TOP_KEYS, n=1)
                hint = f" (did you mean '{near[0]}'?)" if near else ""
                self.fail(k, f"unknown table or key{hint}; allowed: {', '.join(TOP_KEYS)}")
        name = self.value("name", doc["name"], "str") if "name" in doc else self.path.stem
        b = SceneBuilder(name)
        if "camera" not in doc:
            self.fail("camera", "missing: a scene needs a [camera] table with at least "
                                "position and look_at")
        self.camera(b, doc["camera"])
        self.media(b, self.array_of_tables(doc, "medium"), doc["camera"].get("medium"))
        for i, t in enumerate(self.array_of_tables(doc, "texture")):
            self.texture(b, f"texture[{i}]", t)
        for i, m in enumerate(self.array_of_tables(doc, "material")):
            self.material(b, f"material[{i}]", m)
        for i, s in enumerate(self.array_of_tables(doc, "shape")):
            self.shape(b, f"shape[{i}]", s)
        for name, (key, _) in self.medium_tables.items():
            if name != self.camera_medium and name not in b.bounded_media \
                    and name not in b.bounded_grids:
                self.fail(key, f"medium '{name}' is not used; allowed: name it as the camera's "
                               "(camera.medium), or as a shape's interior or exterior")
        for i, l in enumerate(self.array_of_tables(doc, "light")):
            self.light(b, f"light[{i}]", l)
        if not b.lights and not any(s[-1] is not None for s in b.spheres + b.quads + b.triangles):
            warnings.warn(f"{self.path}: the scene has no light (no [[light]] and no shape with "
                          "emission): it renders black", SceneWarning, stacklevel=3)
        try:
            return b.build()
        except SceneError as e:  # the loader checks everything first; this is a safety net
            self.fail("", str(e))

    def camera(self, b: SceneBuilder, c):
        cam = self.table("camera", c, CAMERA_KEYS, CAMERA_REQUIRED)
        pos, look = cam["position"], cam["look_at"]
        up = cam.get("up", np.array([0.0, 1.0, 0.0]))
        fov = cam.get("fov", 40.0)
        axis = cam.get("fov_axis", "y")
        w, h = cam.get("width", 256), cam.get("height", 256)
        if np.array_equal(pos, look):
            self.fail("camera.look_at", "equals camera.position; allowed: any other point")
        fwd = (look - pos) / np.linalg.norm(look - pos)
        if np.linalg.norm(np.cross(fwd, up)) <= 1e-6 * np.linalg.norm(up):
            self.fail("camera.up", f"{up.tolist()} is zero or parallel to the viewing direction "
                                   "look_at - position; allowed: any other direction")
        if not 0 < fov < 180:
            self.fail("camera.fov", f"must be in (0, 180) degrees, got {fov}")
        if axis not in FOV_AXES:
            self.fail("camera.fov_axis", f"unknown value {axis!r}; allowed: {', '.join(FOV_AXES)}")
        for k, v in (("width", w), ("height", h)):
            if v <= 0:
                self.fail(f"camera.{k}", f"must be a positive number of pixels, got {v}")
        b.camera(pos, look, up=up, fov=fov, width=w, height=h, fov_axis=axis)

    def media(self, b: SceneBuilder, tables: list, camera_medium):
        """The [[medium]] tables; the one named by camera.medium is the scene's own medium (the
        camera's, filling the space no shape bounds); shapes' ``interior`` / ``exterior`` name
        the others, homogeneous media bounded by those shapes (:meth:`shape_media`)."""
        names = {}
        for i, t in enumerate(tables):
            key = f"medium[{i}]"
            kind = self.type_of(key, t, tuple(MEDIUM_KEYS))
            m = self.table(key, t, MEDIUM_KEYS[kind], ("name", "type"))
            if m["name"] in names:
                self.fail(f"{key}.name",
                          f"'{m['name']}' is already the name of {names[m['name']][0]}")
            names[m["name"]] = (key, m)
        self.medium_tables, self.camera_medium = names, camera_medium
        if camera_medium is None:
            return
        if camera_medium not in names:
            self.fail("camera.medium", f"unknown medium {camera_medium!r}; defined: "
                                       f"{', '.join(names) or '(none: add a [[medium]])'}")
        key, m = names[camera_medium]
        if m["type"] == "grid":
            return self.grid_medium(b, key, m)
        try:
            b.medium(**self.homogeneous(key, m))
        except SceneError as e:
            self.fail(key, str(e))

    def homogeneous(self, key: str, m: dict) -> dict:
        """The builder's parameters of a homogeneous [[medium]] table, its forms checked."""
        has_t = "sigma_t" in m or "albedo" in m
        has_as = "sigma_a" in m or "sigma_s" in m
        if has_t == has_as:
            self.fail(key, "give sigma_t (and albedo), or sigma_a and sigma_s; allowed: one of "
                           "the two forms")
        if has_t and "sigma_t" not in m:
            self.fail(f"{key}.sigma_t", "missing (required with albedo)")
        return dict(sigma_t=m.get("sigma_t"), albedo=m.get("albedo"), sigma_a=m.get("sigma_a"),
                    sigma_s=m.get("sigma_s"), g=m.get("g", 0.0), scale=m.get("scale", 1.0))

    def shape_media(self, b: SceneBuilder, key: str, t: dict, mat: str):
        """The material row of shape ``key`` that bounds the media its ``interior`` and
        ``exterior`` name (SceneBuilder.medium_interface; the camera's medium, or a side left
        out, is the scene's own): homogeneous or grid [[medium]] tables."""
        sides = {}
        for side in ("interior", "exterior"):
            name = t.get(side)
            if name is None or name == self.camera_medium:
                sides[side] = None
                continue
            if name not in self.medium_tables:
                self.fail(f"{key}.{side}", f"unknown medium {name!r}; defined: "
                                           f"{', '.join(self.medium_tables) or '(none)'}")
            mkey, m = self.medium_tables[name]
            if m["type"] == "grid":
                if name not in b.bounded_grids:
                    self.grid_medium(b, mkey, m, bounded=name)
            elif name not in b.bounded_media:
                try:
                    b.bounded_medium(name, **self.homogeneous(mkey, m))
                except SceneError as e:
                    self.fail(mkey, str(e))
            sides[side] = name
        if sides["exterior"] is not None and t.get("emission") is not None:
            self.fail(f"{key}.exterior", "an emitting shape's exterior must be the camera's "
                                         "medium (lights shine into the scene's own medium)")
        try:
            return b.medium_interface(mat, **sides)
        except SceneError as e:
            self.fail(key, str(e))

    def grid_medium(self, b: SceneBuilder, key: str, m: dict, bounded: str | None = None):
        """A [[medium]] of type grid: ``file`` (a Mitsuba .vol file, one channel; its box unless
        bbox_min / bbox_max are given) or ``density`` (inline, with bbox_min and bbox_max); a
        constant ``albedo`` or an ``albedo_file`` (.vol, 1 or 3 channels, over the same box).
        The camera's medium, or, with ``bounded`` (its name), a grid bounded by shapes."""
        if ("file" in m) == ("density" in m):
            self.fail(key, "a grid medium takes file (a .vol file) or density (an inline "
                           "[nz][ny][nx] array); allowed: one of the two")
        if "file" in m:
            data, lo, hi = self.vol(f"{key}.file", m["file"], (1,))
            grid = data[..., 0]
        else:
            grid, lo, hi = m["density"], None, None
            for k in ("bbox_min", "bbox_max"):
                if k not in m:
                    self.fail(f"{key}.{k}", "missing (required with an inline density)")
        lo, hi = m.get("bbox_min", lo), m.get("bbox_max", hi)
        albedo = m.get("albedo", 1.0)
        if "albedo_file" in m:
            if "albedo" in m:
                self.fail(key, "give albedo or albedo_file; allowed: one of the two")
            albedo = self.vol(f"{key}.albedo_file", m["albedo_file"], (1, 3))[0]
        frame = {}
        if "transform" in m:
            frame["to_world"] = self.transform(f"{key}.transform", m["transform"])
        if ("clip" in m) != ("clip_transform" in m):
            self.fail(key, "clip and clip_transform go together (the shape, and where its unit "
                           "cube or sphere lies)")
        if "clip" in m:
            if m["clip"] not in ("cube", "sphere"):
                self.fail(f"{key}.clip", f"unknown shape {m['clip']!r}; allowed: cube, sphere")
            frame["clip"] = (m["clip"], self.transform(f"{key}.clip_transform",
                                                       m["clip_transform"]))
        params = dict(sigma_t=m.get("sigma_t", 1.0), albedo=albedo, g=m.get("g", 0.0),
                      scale=m.get("scale", 1.0), border=m.get("border", "clamp"), **frame)
        try:
            if bounded is None:
                b.grid_medium(grid, lo, hi, **params)
            else:
                b.bounded_grid_medium(bounded, grid, lo, hi, **params)
        except SceneError as e:
            self.fail(key, str(e))

    def vol(self, key: str, name: str, channels: tuple[int, ...]):
        """(data [nz, ny, nx, c], box min, box max) of the .vol file ``name`` (relative to the
        scene file), with c one of ``channels``."""
        path = (self.path.parent / name).resolve()
        try:
            data, lo, hi = read_vol(path)
        except VolError as e:
            self.fail(key, str(e))
        if data.shape[3] not in channels:
            self.fail(key, f"{path}: {data.shape[3]} channels; allowed: "
                           f"{' or '.join(map(str, channels))}")
        return data, lo, hi

    def texture(self, b: SceneBuilder, key: str, t):
        kind = self.type_of(key, t, tuple(TEXTURE_KEYS))
        tt = self.table(key, t, {**TEXTURE_COMMON, **TEXTURE_KEYS[kind]},
                        ("name", "type") + (("filename",) if kind == "bitmap" else ()),
                        f" for a {kind} texture")
        if tt["name"] in b.texture_names:
            self.fail(f"{key}.name", f"texture '{tt['name']}' is defined twice; names must be "
                                     "unique")
        args = {k: tt[k] for k in ("scale", "offset", "color0", "color1", "raw") if k in tt}
        if kind == "bitmap":
            path = (self.path.parent / tt["filename"]).resolve()
            if not path.is_file():
                self.fail(f"{key}.filename", f"file '{path}' does not exist; allowed: a PNG, "
                                             "JPEG or EXR image (relative to the scene file)")
            args["filename"] = path
        try:
            b.texture(tt["name"], kind, **args)
        except SceneError as e:
            self.fail(key, str(e))

    def material(self, b: SceneBuilder, key: str, m):
        if isinstance(m, dict) and m.get("type") in MATERIAL_ALTERNATIVES:
            self.fail(f"{key}.type", f"{MATERIAL_ALTERNATIVES[m['type']]}; allowed: "
                                     f"{', '.join(MATERIAL_KINDS)}")
        kind = self.type_of(key, m, tuple(MATERIAL_KINDS))
        allowed = {"name": "str", "type": "str", **MATERIAL_KEYS[kind]}
        mm = self.table(key, m, allowed, ("name",) + MATERIAL_REQUIRED.get(kind, ()),
                        f" for type '{kind}'")
        if mm["name"] in b.material_names:
            self.fail(f"{key}.name", f"material '{mm['name']}' is defined twice; names must be "
                                     "unique")
        p = {k: mm.get(k, d) for k, d in MATERIAL_DEFAULTS.get(kind, {}).items()}
        p.update({k: mm[k] for k in MATERIAL_KEYS[kind] if k in mm})
        for k, v in mm.items():
            if k in MATERIAL_KEYS[kind] and MATERIAL_KEYS[kind][k].endswith("|texture") \
                    and isinstance(v, str):
                if v not in b.texture_names:
                    self.fail(f"{key}.{k}", f"unknown texture '{v}'; defined: "
                                            f"{', '.join(b.texture_names) or '(none)'}")
        textured = {k for k, v in mm.items() if k != "name" and k != "type" and isinstance(v, str)
                    and MATERIAL_KEYS[kind][k].endswith("|texture")}
        mm = {k: v for k, v in mm.items() if k not in textured}   # the checks below: values only
        # Reflectances above 1 create energy; the estimators' variance would then diverge.
        for k in ("diffuse", "specular", "transmittance"):
            if k in mm and np.any(mm[k] > 1):
                what = "transmittance" if k == "transmittance" else "reflectance"
                self.fail(f"{key}.{k}", f"{what} must be in [0, 1], got {mm[k].tolist()}")
        if "transmittance" in mm and "specular" in textured:
            self.fail(f"{key}.transmittance", "'specular' is a texture, which tints the "
                                              "transmitted light too; give no transmittance")
        if kind == "phong" and not textured and np.any(np.broadcast_to(p["diffuse"], 3)
                                                       + mm["specular"] > 1):
            self.fail(f"{key}.specular", "diffuse + specular must be <= 1 in every channel "
                                         "(energy conservation of the modified Phong BSDF)")
        if "opacity" in mm and not 0 <= mm["opacity"] <= 1:
            self.fail(f"{key}.opacity", f"must be in [0, 1] (the probability that a ray stops "
                                        f"at the surface), got {mm['opacity']}")
        if "exponent" in mm and mm["exponent"] < 0:
            self.fail(f"{key}.exponent", f"must be >= 0, got {mm['exponent']}")
        for k in ("ior", "int_ior", "ext_ior"):
            if k in mm and mm[k] <= 0:
                what = "inside / outside" if k == "ior" else "an index of refraction"
                self.fail(f"{key}.{k}", f"must be > 0 ({what}), got {mm[k]}")
        if "ior" in mm and ("int_ior" in mm or "ext_ior" in mm):
            self.fail(f"{key}.ior", "give either ior (inside / outside) or int_ior and ext_ior, "
                                    "not both")
        if kind in ("conductor", "roughconductor"):
            self.metal(key, mm)
        if "distribution" in MATERIAL_KEYS[kind]:
            self.roughness(key, kind, mm, textured)
        if kind in ("roughplastic", "plastic") and (mm.get("ior") == 1 or (
                "int_ior" in mm and mm["int_ior"] == mm.get("ext_ior", IOR_AIR))):
            self.fail(f"{key}.{'ior' if 'ior' in mm else 'int_ior'}",
                      "the coating's inside and outside indices are equal (no interface); "
                      "allowed: ior != 1, int_ior != ext_ior")
        try:
            b.material(mm["name"], kind, **p)   # p keeps the texture names
        except SceneError as e:  # the checks above should catch everything; a safety net
            self.fail(key, str(e))

    def metal(self, key: str, mm: dict):
        """A conductor names a metal, or gives eta and k together, or neither (metal "none",
        a perfect mirror)."""
        if "metal" in mm:
            if "eta" in mm or "k" in mm:
                self.fail(f"{key}.metal", "give either metal or eta and k, not both")
            metals = tuple(NAMED_METALS)
            if mm["metal"] not in metals:
                given = mm["metal"].lower()
                near = [m for m in metals if m.lower() == given] or \
                    [m for e, m in METAL_WORDS.items() if e == given] or \
                    difflib.get_close_matches(mm["metal"], metals, n=1)
                hint = f" (did you mean '{near[0]}'?)" if near else ""
                self.fail(f"{key}.metal", f"unknown metal {mm['metal']!r}{hint}; allowed: "
                                          f"{', '.join(metals)}")
        elif "eta" in mm or "k" in mm:
            if "eta" not in mm or "k" not in mm:
                missing = "k" if "eta" in mm else "eta"
                self.fail(f"{key}.{missing}", "missing: eta and k go together (the complex "
                                              "index of refraction eta + i k)")

    def roughness(self, key: str, kind: str, mm: dict, textured=()):
        """distribution is ggx or beckmann; alpha, or alpha_u and alpha_v together, all > 0
        (``mm`` the constants, ``textured`` the keys given as texture names)."""
        if "distribution" in mm and mm["distribution"] not in MICROFACET_DISTRIBUTIONS:
            self.fail(f"{key}.distribution", f"unknown distribution {mm['distribution']!r}; "
                                             f"allowed: {', '.join(MICROFACET_DISTRIBUTIONS)}")
        given = set(mm) | set(textured)
        if "alpha" in given and ("alpha_u" in given or "alpha_v" in given):
            self.fail(f"{key}.alpha", "give either alpha (isotropic) or alpha_u and alpha_v "
                                      "(anisotropic), not both")
        if ("alpha_u" in given) != ("alpha_v" in given):
            missing = "alpha_v" if "alpha_u" in given else "alpha_u"
            self.fail(f"{key}.{missing}", "missing: alpha_u and alpha_v go together")
        for k in ("alpha", "alpha_u", "alpha_v"):
            if k in mm and not mm[k] > 0:
                self.fail(f"{key}.{k}", f"must be > 0 (the roughness; use the smooth type for "
                                        f"0), got {mm[k]}")

    def shape(self, b: SceneBuilder, key: str, s):
        kind = self.type_of(key, s, tuple(SHAPE_KEYS))
        t = self.table(key, s, {**SHAPE_COMMON, **SHAPE_KEYS[kind]},
                       ("type", "material") + SHAPE_REQUIRED.get(kind, ()), f" for a {kind}")
        mat = t["material"]
        if mat not in b.material_names:
            self.fail(f"{key}.material", f"unknown material '{mat}'; defined: "
                                         f"{', '.join(b.material_names) or '(none)'}")
        if "interior" in t or "exterior" in t:
            mat = self.shape_media(b, key, t, mat)
        m = self.transform(f"{key}.transform", t["transform"]) if "transform" in t else np.eye(4)
        e = t.get("emission")
        if kind == "sphere":
            if t["radius"] <= 0:
                self.fail(f"{key}.radius", f"must be > 0, got {t['radius']}")
            sv = np.linalg.svd(m[:3, :3], compute_uv=False)
            if sv[-1] < sv[0] * (1 - 1e-6):
                self.fail(f"{key}.transform", "a sphere allows only uniform scaling "
                                              f"(scale factors {sv.round(6).tolist()})")
            b.sphere(xf.apply_point(m, t["center"]), t["radius"] * sv[0], mat, e)
        elif kind == "quad":
            u, v = t["edge_u"], t["edge_v"]
            if np.linalg.norm(np.cross(u, v)) \
                    <= SINGULAR_RTOL * np.linalg.norm(u) * np.linalg.norm(v) \
                    or not np.any(u) or not np.any(v):
                self.fail(key, "edge_u and edge_v are zero or parallel: the quad has no area; "
                               "allowed: two non-parallel edges")
            b.quad(xf.apply_point(m, t["origin"]), xf.apply_vector(m, u), xf.apply_vector(m, v),
                   mat, e)
        elif kind == "rectangle":
            b.rectangle(m, mat, e)
        elif kind == "cube":
            b.cube(m, mat, e)
        else:
            # the file's vertex normals shade it smoothly, unless flat = true; emitters are
            # flat (they radiate about the geometric normal)
            smooth = not t.get("flat", False) and e is None
            row = mat if isinstance(mat, int) else b.material_names[mat]
            textured = bool(b.materials[row].textures)
            v, f, normals, uv = self.mesh(f"{key}.file", t["file"], smooth, textured)
            b.mesh(v, f, mat, e, to_world=m, normals=normals, uv=uv)

    def mesh(self, key: str, name: str, normals: bool = False, uv: bool = False):
        """Vertices, triangles, (with ``normals``) the vertex normals and (with ``uv``) the
        texture coordinates of a mesh file (relative to the scene file): OBJ and PLY files
        that carry normals are read as Mitsuba reads them
        (:func:`jgi.scene.importers._common.load_mesh_with_normals`), others via trimesh; the
        normals are None where the file has none (the mesh shades flat). The uv are Mitsuba's:
        an OBJ file's vt with v flipped, a PLY file's u, v (or s, t, or texture_u, texture_v);
        None where the file has none (each triangle then has (0,0), (1,0), (0,1)). Other
        formats with texture coordinates (or that jgi cannot tell) are refused with ``uv``."""

        path = self.path.parent / name
        if path.suffix.lower() not in MESH_SUFFIXES:
            self.fail(key, f"'{name}': unsupported mesh format '{path.suffix}'; allowed: "
                           f"{', '.join(MESH_SUFFIXES)}")
        if not path.is_file():
            what = "is not a file" if path.exists() else "does not exist"
            self.fail(key, f"mesh file '{path}' {what} (paths are relative to the scene file)")
        try:
            with open(path, "rb"):
                pass
        except OSError as e:
            self.fail(key, f"cannot read mesh file '{path}': {e.strerror or e}")
        # the loaders raise SceneError naming `where` for unparsable or empty files
        nrm = tex = None
        suffix = path.suffix.lower()
        if uv and suffix not in (".obj", ".ply") and has_texture_coordinates(path):
            self.fail(key, f"'{name}' is used with a textured material: texture coordinates "
                           "are read from OBJ and PLY files only; allowed: an OBJ or PLY file, "
                           "or an untextured material")
        try:
            if normals and suffix in (".obj", ".ply") and has_vertex_normals(path):
                v, f, tex, nrm = load_mesh_with_normals(path, f"{self.path}: {key}")
            elif uv:
                v, f, tex = load_mesh(path, f"{self.path}: {key}", with_uv=True)
            else:
                v, f = load_mesh(path, f"{self.path}: {key}")
        except SceneError as e:
            raise SceneError(f"{e} (expected a valid {path.suffix[1:].upper()} file that trimesh "
                             "can read)") from None
        if uv and has_texture_coordinates(path):
            if tex is None:
                self.fail(key, f"mesh '{name}' has texture coordinates that cannot be read (an "
                               "OBJ file must give vt on every face vertex; a PLY file's are "
                               "the vertex properties u, v or s, t or texture_u, texture_v)")
            if suffix == ".obj":   # as Mitsuba reads OBJ files: v flipped
                tex = np.stack([tex[:, 0], 1.0 - tex[:, 1]], 1)
        else:
            tex = None
        if f.ndim != 2 or f.shape[1] != 3 or f.min() < 0 or f.max() >= len(v):
            self.fail(key, f"mesh '{name}' has malformed faces (expected triangles indexing "
                           f"{len(v)} vertices)")
        if not np.all(np.isfinite(v)):
            self.fail(key, f"mesh '{name}' has non-finite vertex coordinates")
        area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
        if np.any(area2 == 0):
            warnings.warn(f"{self.path}: {key}: mesh '{name}' has {int(np.sum(area2 == 0))} "
                          "zero-area triangles (rays never hit them)", SceneWarning, stacklevel=5)
        if nrm is not None and not np.all(np.isfinite(nrm)):
            self.fail(key, f"mesh '{name}' has non-finite vertex normals")
        if tex is not None and not np.all(np.isfinite(tex)):
            self.fail(key, f"mesh '{name}' has non-finite texture coordinates")
        return v, f, nrm, tex

    def light(self, b: SceneBuilder, key: str, l):
        kind = self.type_of(key, l, tuple(LIGHT_KEYS))
        t = self.table(key, l, {"type": "str", **LIGHT_KEYS[kind]}, LIGHT_REQUIRED[kind],
                       f" for a {kind} light")
        if kind == "point":
            b.point_light(t["position"], t["intensity"])
        elif kind == "spot":
            if np.array_equal(t["position"], t["target"]):
                self.fail(f"{key}.target", "equals position; allowed: any other point")
            cutoff = t.get("cutoff", 30.0)
            falloff = t.get("falloff", 0.75 * cutoff)
            if not 0 < cutoff <= 90:
                self.fail(f"{key}.cutoff", f"must be in (0, 90] degrees, got {cutoff}")
            if not 0 <= falloff <= cutoff:
                self.fail(f"{key}.falloff", f"must be in [0, cutoff = {cutoff}] degrees, got "
                                            f"{falloff}")
            b.spot_light(t["position"], t["target"], t["intensity"], cutoff_deg=cutoff,
                         falloff_deg=falloff)
        elif kind == "directional":
            if not np.any(t["direction"]):
                self.fail(f"{key}.direction", "must be non-zero")
            b.directional_light(t["direction"], t["irradiance"])
        else:
            if any(l_["kind"] == ENVIRONMENT for l_ in b.lights):
                self.fail(key, "a second environment light; allowed: at most one")
            if ("radiance" in t) == ("image" in t):
                self.fail(key, "an environment light needs exactly one of 'radiance' (constant) "
                               "and 'image' (a map)")
            if "radiance" in t:
                for k in ("scale", "transform", "mapping"):
                    if k in t:
                        self.fail(f"{key}.{k}", "applies to an 'image' environment only")
                b.environment_light(t["radiance"])
                return
            path = (self.path.parent / t["image"]).resolve()
            if not path.is_file() or path.suffix.lower() not in (".exr", ".hdr", ".rgbe", ".png",
                                                                 ".jpg", ".jpeg"):
                self.fail(f"{key}.image", f"file '{path}' does not exist or is not an image; "
                                          "allowed: an EXR, Radiance HDR, PNG or JPEG "
                                          "map (relative to the scene file)")
            m = (self.transform(f"{key}.transform", t["transform"]) if "transform" in t
                 else np.eye(4))
            mapping = t.get("mapping", "latlong")
            if mapping not in ENVIRONMENT_MAPPINGS:
                self.fail(f"{key}.mapping", f"'{mapping}'; allowed: "
                                            f"{', '.join(ENVIRONMENT_MAPPINGS)}")
            b.environment_map(path, scale=t.get("scale", 1.0), to_world=m,
                              where=f"{self.path}: {key}.image", mapping=mapping)
