"""Scene loading: built-in names, jgi TOML files, Mitsuba 3 XML and pbrt-v4 files.

The TOML format is documented in ``docs/scene-format.md``. Every mistake in a scene file is a
:class:`jgi.SceneError` naming the file, the key path (``shape[3].radius``) and what is
allowed; nothing is silently ignored (an unknown key is an error, since it is usually a typo).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

from . import scenes
from . import transform as xf
from .scene import MATERIAL_KINDS, Scene, SceneBuilder, SceneError

TOP_KEYS = {"name", "camera", "material", "shape", "light"}
CAMERA_KEYS = {"position": "vec3", "look_at": "vec3", "up": "vec3", "fov": "number",
               "fov_axis": "str", "width": "int", "height": "int"}
MATERIAL_KEYS = {"name": "str", "type": "str", "diffuse": "rgb", "specular": "rgb",
                 "exponent": "number", "ior": "number"}
SHAPE_KEYS = {
    "sphere": {"center": "vec3", "radius": "number"},
    "quad": {"origin": "vec3", "edge_u": "vec3", "edge_v": "vec3"},
    "rectangle": {},
    "cube": {},
    "mesh": {"file": "str"},
}
SHAPE_COMMON = {"type": "str", "material": "str", "emission": "rgb", "transform": "table"}
LIGHT_KEYS = {
    "point": {"position": "vec3", "intensity": "rgb"},
    "spot": {"position": "vec3", "target": "vec3", "intensity": "rgb", "cutoff": "number",
             "falloff": "number"},
    "directional": {"direction": "vec3", "irradiance": "rgb"},
    "environment": {"radiance": "rgb"},
}
REQUIRED = {
    "sphere": ("center", "radius"), "quad": ("origin", "edge_u", "edge_v"), "mesh": ("file",),
    "point": ("position", "intensity"), "spot": ("position", "target", "intensity"),
    "directional": ("direction", "irradiance"), "environment": ("radiance",),
}
TRANSFORM_KEYS = {"matrix", "translate", "rotate", "scale"}


def load_scene(source: str | Path, **kwargs) -> Scene:
    """A built-in scene by name (``kwargs`` go to its constructor, e.g. ``resolution``), or a
    scene file: ``.toml`` (jgi), ``.xml`` (Mitsuba 3), ``.pbrt`` (pbrt-v4)."""
    src = str(source)
    if src in scenes.BUILTINS:
        return scenes.get(src, **kwargs)
    path = Path(src)
    suffix = path.suffix.lower()
    if suffix == ".xml":
        from .importers import load_mitsuba_xml
        return load_mitsuba_xml(path)
    if suffix == ".pbrt":
        from .importers import load_pbrt
        return load_pbrt(path)
    if suffix != ".toml":
        raise SceneError(f"{src}: not a built-in scene ({', '.join(scenes.BUILTINS)}) and not a "
                         "scene file (.toml, .xml, .pbrt)")
    return _TomlLoader(path).load()


class _TomlLoader:
    def __init__(self, path: Path):
        self.path = path

    def fail(self, key: str, msg: str):
        raise SceneError(f"{self.path}: {key}: {msg}")

    # --- typed values ---------------------------------------------------------------------
    def value(self, key: str, v, kind: str):
        if kind == "str":
            if not isinstance(v, str):
                self.fail(key, f"expected a string, got {v!r}")
            return v
        if kind == "int":
            if isinstance(v, bool) or not isinstance(v, int):
                self.fail(key, f"expected an integer, got {v!r}")
            return v
        if kind == "number":
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                self.fail(key, f"expected a finite number, got {v!r}")
            return float(v)
        if kind in ("vec3", "rgb"):
            if kind == "rgb" and isinstance(v, (int, float)) and not isinstance(v, bool):
                v = [v, v, v]
            if (not isinstance(v, list) or len(v) != 3 or
                    not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)):
                allowed = "3 numbers [r, g, b] or one number" if kind == "rgb" else "3 numbers [x, y, z]"
                self.fail(key, f"expected {allowed}, got {v!r}")
            a = np.asarray(v, float)
            if not np.all(np.isfinite(a)):
                self.fail(key, f"values must be finite, got {v!r}")
            if kind == "rgb" and np.any(a < 0):
                self.fail(key, f"colours must be non-negative, got {v!r}")
            return a
        if kind == "table":
            if not isinstance(v, dict):
                self.fail(key, f"expected a table, got {v!r}")
            return v
        raise AssertionError(kind)

    def table(self, key: str, t: dict, allowed: dict, required=()) -> dict:
        if not isinstance(t, dict):
            self.fail(key, f"expected a table, got {t!r}")
        unknown = sorted(set(t) - set(allowed))
        if unknown:
            self.fail(f"{key}.{unknown[0]}", f"unknown key; allowed: {', '.join(sorted(allowed))}")
        for r in required:
            if r not in t:
                self.fail(f"{key}.{r}", "missing (required)")
        return {k: self.value(f"{key}.{k}", v, allowed[k]) for k, v in t.items()}

    def transform(self, key: str, t: dict) -> np.ndarray:
        unknown = sorted(set(t) - TRANSFORM_KEYS)
        if unknown:
            self.fail(f"{key}.{unknown[0]}", f"unknown key; allowed: {', '.join(sorted(TRANSFORM_KEYS))}")
        if "matrix" in t:
            if set(t) != {"matrix"}:
                self.fail(key, "give either matrix or translate/rotate/scale, not both")
            m = t["matrix"]
            if (not isinstance(m, list) or len(m) != 4 or
                    not all(isinstance(r, list) and len(r) == 4 for r in m)):
                self.fail(f"{key}.matrix", "expected 4 rows of 4 numbers")
            m = np.asarray(m, float)
        else:
            m = np.eye(4)
            if "scale" in t:
                s = t["scale"]
                s = self.value(f"{key}.scale", s, "number") if not isinstance(s, list) else self.value(f"{key}.scale", s, "vec3")
                m = xf.scale(s) @ m
            rots = t.get("rotate", [])
            rots = [rots] if isinstance(rots, dict) else rots
            if not isinstance(rots, list):
                self.fail(f"{key}.rotate", "expected {axis = [x, y, z], angle = degrees} or a list of them")
            for i, r in enumerate(rots):
                rr = self.table(f"{key}.rotate[{i}]", r, {"axis": "vec3", "angle": "number"}, ("axis", "angle"))
                if np.linalg.norm(rr["axis"]) == 0:
                    self.fail(f"{key}.rotate[{i}].axis", "must be non-zero")
                m = xf.rotate(rr["axis"], rr["angle"]) @ m
            if "translate" in t:
                m = xf.translate(self.value(f"{key}.translate", t["translate"], "vec3")) @ m
        if not np.all(np.isfinite(m)) or abs(np.linalg.det(m[:3, :3])) < 1e-12:
            self.fail(key, "the transform is degenerate (zero determinant) or not finite")
        return m

    # --- document -------------------------------------------------------------------------
    def load(self) -> Scene:
        try:
            doc = tomllib.loads(self.path.read_text())
        except OSError as e:
            raise SceneError(f"{self.path}: cannot read: {e}") from None
        except tomllib.TOMLDecodeError as e:
            raise SceneError(f"{self.path}: TOML syntax error: {e}") from None
        unknown = sorted(set(doc) - TOP_KEYS)
        if unknown:
            self.fail(unknown[0], f"unknown table or key; allowed: {', '.join(sorted(TOP_KEYS))}")
        b = SceneBuilder(str(doc.get("name", self.path.stem)))
        if "camera" not in doc:
            self.fail("camera", "missing: a scene needs a [camera] table")
        cam = self.table("camera", doc["camera"], CAMERA_KEYS, ("position", "look_at"))
        mats = doc.get("material", [])
        if not isinstance(mats, list):
            self.fail("material", "use [[material]] (an array of tables)")
        for i, m in enumerate(mats):
            key = f"material[{i}]"
            mm = self.table(key, m, MATERIAL_KEYS, ("name", "type"))
            if mm["type"] not in MATERIAL_KINDS:
                self.fail(f"{key}.type", f"unknown type '{mm['type']}'; allowed: {', '.join(MATERIAL_KINDS)}")
            kw = {k: mm[k] for k in ("diffuse", "specular", "exponent", "ior") if k in mm}
            if mm.get("ior", 1.0) <= 0:
                self.fail(f"{key}.ior", "must be > 0")
            if mm.get("exponent", 0.0) < 0:
                self.fail(f"{key}.exponent", "must be >= 0")
            try:
                b.material(mm["name"], mm["type"], **kw)
            except SceneError as e:
                self.fail(key, str(e))
        shapes = doc.get("shape", [])
        if not isinstance(shapes, list):
            self.fail("shape", "use [[shape]] (an array of tables)")
        for i, s in enumerate(shapes):
            self.shape(b, f"shape[{i}]", s)
        lights = doc.get("light", [])
        if not isinstance(lights, list):
            self.fail("light", "use [[light]] (an array of tables)")
        for i, l in enumerate(lights):
            self.light(b, f"light[{i}]", l)
        axis = cam.get("fov_axis", "y")
        if axis not in ("x", "y", "smaller"):
            self.fail("camera.fov_axis", f"'{axis}' is not allowed; allowed: x, y, smaller")
        w, h = cam.get("width", 256), cam.get("height", 256)
        if w <= 0 or h <= 0:
            self.fail("camera.width", f"width and height must be positive, got {w}x{h}")
        fov = cam.get("fov", 40.0)
        if not 0 < fov < 180:
            self.fail("camera.fov", f"must be in (0, 180) degrees, got {fov}")
        try:
            b.camera(cam["position"], cam["look_at"], up=cam.get("up", (0, 1, 0)), fov=fov,
                     width=w, height=h, fov_axis=axis)
            return b.build()
        except SceneError as e:
            raise SceneError(f"{self.path}: {e}") from None

    def shape(self, b: SceneBuilder, key: str, s: dict):
        if not isinstance(s, dict) or "type" not in s:
            self.fail(f"{key}.type", f"missing; allowed: {', '.join(SHAPE_KEYS)}")
        kind = s["type"]
        if kind not in SHAPE_KEYS:
            self.fail(f"{key}.type", f"unknown type '{kind}'; allowed: {', '.join(SHAPE_KEYS)}")
        t = self.table(key, s, {**SHAPE_COMMON, **SHAPE_KEYS[kind]},
                       ("material",) + REQUIRED.get(kind, ()))
        if t["material"] not in b.material_names:
            self.fail(f"{key}.material", f"unknown material '{t['material']}'; defined: "
                                         f"{', '.join(b.material_names) or '(none)'}")
        m = self.transform(f"{key}.transform", t["transform"]) if "transform" in t else np.eye(4)
        e = t.get("emission")
        if kind == "sphere":
            if t["radius"] < 0:
                self.fail(f"{key}.radius", f"must be >= 0, got {t['radius']}")
            s3 = np.linalg.norm(m[:3, :3], axis=0)
            if not np.allclose(s3, s3[0], rtol=1e-6):
                self.fail(f"{key}.transform", "spheres allow only uniform scaling")
            b.sphere(xf.apply_point(m, t["center"]), t["radius"] * s3[0], t["material"], e)
        elif kind == "quad":
            o = xf.apply_point(m, t["origin"])
            u, v = xf.apply_vector(m, t["edge_u"]), xf.apply_vector(m, t["edge_v"])
            if np.linalg.norm(np.cross(u, v)) == 0:
                self.fail(key, "edge_u and edge_v are parallel or zero: the quad has no area")
            b.quad(o, u, v, t["material"], e)
        elif kind == "rectangle":
            b.rectangle(m, t["material"], e)
        elif kind == "cube":
            b.cube(m, t["material"], e)
        else:
            from .importers._common import load_mesh
            v, f = load_mesh(self.path.parent / t["file"], f"{self.path}: {key}.file", True)
            b.mesh(v, f, t["material"], e, to_world=m)

    def light(self, b: SceneBuilder, key: str, l: dict):
        if not isinstance(l, dict) or "type" not in l:
            self.fail(f"{key}.type", f"missing; allowed: {', '.join(LIGHT_KEYS)}")
        kind = l["type"]
        if kind not in LIGHT_KEYS:
            self.fail(f"{key}.type", f"unknown type '{kind}'; allowed: {', '.join(LIGHT_KEYS)}")
        t = self.table(key, l, {"type": "str", **LIGHT_KEYS[kind]}, REQUIRED[kind])
        try:
            if kind == "point":
                b.point_light(t["position"], t["intensity"])
            elif kind == "spot":
                b.spot_light(t["position"], t["target"], t["intensity"],
                             cutoff_deg=t.get("cutoff", 30.0), falloff_deg=t.get("falloff"))
            elif kind == "directional":
                if np.linalg.norm(t["direction"]) == 0:
                    self.fail(f"{key}.direction", "must be non-zero")
                b.directional_light(t["direction"], t["irradiance"])
            else:
                b.environment_light(t["radiance"])
        except SceneError as e:
            self.fail(key, str(e))
