"""Mitsuba 3 XML scenes -> jgi scenes, for the subset jgi represents exactly.

Supported (anything else is refused with the file, the line, the plugin and this list):

  sensor     perspective: fov, fov_axis (x | y | smaller | larger | diagonal), to_world;
             film hdrfilm: width, height (pixel filter, sampler and integrator are ignored:
             jgi uses box pixel filtering and its own estimators)
  bsdf       diffuse (reflectance), conductor with material="none" (perfect mirror,
             specular_reflectance), dielectric (int_ior / ext_ior as numbers or Mitsuba's
             names; ior = int / ext), twosided (unwrapped: jgi's opaque BSDFs are two-sided)
  shape      rectangle, cube, sphere (center/radius or a uniform-scale to_world), obj, ply
             (meshes with vertex normals need face_normals="true": jgi shades flat)
  emitter    area (radiance), point (intensity, position or to_world), spot (intensity,
             cutoff_angle; only with beam_width equal to cutoff_angle, since Mitsuba's falloff
             curve differs from jgi's), directional (direction, irradiance), constant (radiance)
  values     rgb, float, spectrum with a single constant value; <default> and $name
             substitution; <ref>; <include>; transforms translate, rotate, scale, matrix,
             lookat (each applied after the previous one, as Mitsuba does)

Units need no conversion: Mitsuba's radiance (W m^-2 sr^-1), intensity (W sr^-1) and
irradiance (W m^-2) are jgi's.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
import xml.parsers.expat as expat
from pathlib import Path

import numpy as np

from ...core import transform as xf
from ..data import Scene, SceneBuilder
from ._common import NAMED_IOR, ImportError_, load_mesh

SUPPORTED = {
    "sensor": ("perspective",),
    "bsdf": ("diffuse", "conductor", "dielectric", "twosided"),
    "shape": ("rectangle", "cube", "sphere", "obj", "ply"),
    "emitter": ("area", "point", "spot", "directional", "constant"),
}
IGNORED_TAGS = ("integrator", "sampler", "rfilter")


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
        self.n_anon = 0
        self.sensor_done = False
        self.source: dict = {}

    # --- helpers --------------------------------------------------------------------------
    def where(self, el) -> str:
        file, line, _ = self.source.get(id(el), (self.path, "?", None))
        return f"{file}:{line}"

    def file_of(self, el) -> Path:
        return self.source.get(id(el), (self.path, 0, None))[0]

    def fail(self, el, msg):
        raise ImportError_(f"{self.where(el)}: {msg}")

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
                v = self.attr(c, "value", "")
                try:
                    out[name] = np.full(3, float(v))
                except ValueError:
                    self.fail(c, f"spectrum '{name}': only a single constant value is supported")
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
                self.fail(c, f"textures are not supported (parameter '{name}')")
        return out

    def transform(self, el) -> np.ndarray:
        m = np.eye(4)
        for op in el:
            if op.tag == "translate":
                t = xf.translate(self.vec3(op))
            elif op.tag == "rotate":
                axis = self.vec3(op) if op.get("value") else np.array(
                    [float(self.attr(op, k, "0")) for k in "xyz"])
                t = xf.rotate(axis, float(self.attr(op, "angle", "0")))
            elif op.tag == "scale":
                s = self.vec3(op) if op.get("value") else np.array(
                    [float(self.attr(op, k, "1")) for k in "xyz"])
                t = xf.scale(s)
            elif op.tag == "matrix":
                vals = [float(x) for x in self.attr(op, "value").replace(",", " ").split()]
                if len(vals) != 16:
                    self.fail(op, "matrix needs 16 values")
                t = np.array(vals).reshape(4, 4)
            elif op.tag == "lookat":
                def pt(k):
                    return np.array([float(x) for x in self.attr(op, k).replace(",", " ").split()])
                t = xf.look_at(pt("origin"), pt("target"), pt("up") if op.get("up") else [0, 1, 0])
            else:
                self.fail(op, f"unknown transform operation <{op.tag}>; supported: translate, "
                              "rotate, scale, matrix, lookat")
            m = t @ m
        return m

    def check_type(self, el):
        kind = el.get("type")
        allowed = SUPPORTED[el.tag]
        if kind not in allowed:
            self.fail(el, f"{el.tag} plugin '{kind}' is not supported by jgi; supported "
                          f"{el.tag} plugins: {', '.join(allowed)}")
        return kind

    # --- objects --------------------------------------------------------------------------
    def bsdf(self, el) -> str:
        """Register a BSDF, return its material name in the builder."""
        kind = self.check_type(el)
        p = self.props(el)
        name = el.get("id") or f"_bsdf{self.n_anon}"
        self.n_anon += 1
        if kind == "twosided":
            inner = [c for c in el if c.tag == "bsdf"]
            if len(inner) != 1:
                self.fail(el, "twosided needs exactly one nested bsdf")
            inner_name = self.bsdf(inner[0])
            self.bsdfs[name] = self.bsdfs[inner_name]
            self.b.material_names[name] = self.b.material_names[inner_name]
            return name
        if kind == "diffuse":
            self.b.material(name, "diffuse", diffuse=p.get("reflectance", np.full(3, 0.5)))
        elif kind == "conductor":
            material = p.get("material", "none")
            if material != "none" or "eta" in p or "k" in p:
                self.fail(el, "conductor: only material='none' (a perfect mirror) is supported; "
                              "jgi has no complex-IOR Fresnel")
            self.b.material(name, "mirror", specular=p.get("specular_reflectance", np.ones(3)))
        elif kind == "dielectric":
            def ior(key, default):
                v = p.get(key, default)
                if isinstance(v, str):
                    if v not in NAMED_IOR:
                        self.fail(el, f"dielectric {key} '{v}' is unknown; names: "
                                      f"{', '.join(NAMED_IOR)}")
                    return NAMED_IOR[v]
                return float(v)
            refl = p.get("specular_reflectance", np.ones(3))
            trans = p.get("specular_transmittance", np.ones(3))
            if not np.allclose(refl, trans):
                self.fail(el, "dielectric: jgi needs equal specular_reflectance and "
                              "specular_transmittance (one tint)")
            self.b.material(name, "dielectric", specular=refl,
                            ior=ior("int_ior", "bk7") / ior("ext_ior", "air"))
        self.bsdfs[name] = (kind, p)
        return name

    def shape(self, el):
        kind = self.check_type(el)
        p = self.props(el)
        m = p.get("to_world", np.eye(4))
        material = None
        emission = None
        for c in el:
            if c.tag == "bsdf":
                material = self.bsdf(c)
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
                emission = self.props(c).get("radiance", np.ones(3))
        if material is None:  # Mitsuba's default: diffuse, reflectance 0.5
            material = f"_default{self.n_anon}"
            self.n_anon += 1
            self.b.material(material, "diffuse", diffuse=(0.5, 0.5, 0.5))
        if kind == "rectangle":
            self.b.rectangle(m, material, emission)
        elif kind == "cube":
            self.b.cube(m, material, emission)
        elif kind == "sphere":
            cols = m[:3, :3]
            scales = np.linalg.norm(cols, axis=0)
            if not np.allclose(scales, scales[0], rtol=1e-6) or not np.allclose(
                    cols.T @ cols, np.diag(scales**2), atol=1e-9 * scales[0] ** 2 + 1e-12):
                self.fail(el, "sphere: to_world must be a uniform scale, rotation and translation")
            center = xf.apply_point(m, p.get("center", np.zeros(3)))
            self.b.sphere(center, float(p.get("radius", 1.0)) * scales[0], material, emission)
        else:  # obj, ply
            fname = p.get("filename")
            if not fname:
                self.fail(el, f"{kind} shape needs a 'filename'")
            base = self.file_of(el).parent
            v, f = load_mesh(base / fname, self.where(el), bool(p.get("face_normals", False)))
            if p.get("flip_normals", False):
                f = f[:, ::-1]
            self.b.mesh(v, f, material, emission, to_world=m)

    def emitter(self, el):
        kind = self.check_type(el)
        if kind == "area":
            self.fail(el, "an area emitter must be nested in a shape")
        p = self.props(el)
        m = p.get("to_world", np.eye(4))
        if kind == "point":
            pos = p.get("position", xf.apply_point(m, np.zeros(3)))
            self.b.point_light(pos, p.get("intensity", np.ones(3)))
        elif kind == "spot":
            cutoff = float(p.get("cutoff_angle", 20.0))
            beam = float(p.get("beam_width", cutoff * 0.75))
            if not math.isclose(beam, cutoff, rel_tol=1e-6):
                self.fail(el, "spot: Mitsuba's falloff between beam_width and cutoff_angle differs "
                              "from jgi's; set beam_width equal to cutoff_angle")
            pos = xf.apply_point(m, np.zeros(3))
            target = xf.apply_point(m, np.array([0.0, 0.0, 1.0]))
            self.b.spot_light(pos, target, p.get("intensity", np.ones(3)), cutoff_deg=cutoff,
                              falloff_deg=cutoff)
        elif kind == "directional":
            d = p.get("direction", xf.apply_vector(m, np.array([0.0, 0.0, 1.0])))
            self.b.directional_light(d, p.get("irradiance", np.ones(3)))
        elif kind == "constant":
            self.b.environment_light(p.get("radiance", np.ones(3)))

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

    # --- document -------------------------------------------------------------------------
    def children(self, root: ET.Element, file: Path):
        for el in root:
            tag = el.tag
            if tag == "default":
                self.defaults.setdefault(el.get("name"), el.get("value"))
            elif tag == "include":
                inc = file.parent / self.attr(el, "filename")
                inc_root = _parse(inc, self.source)
                self.children(inc_root, inc)
            elif tag == "bsdf":
                self.bsdf(el)
            elif tag == "shape":
                self.shape(el)
            elif tag == "emitter":
                self.emitter(el)
            elif tag == "sensor":
                self.sensor(el)
            elif tag in IGNORED_TAGS:
                continue
            else:
                self.fail(el, f"<{tag}> is not supported; supported elements: default, include, "
                              "bsdf, shape, emitter, sensor (integrator/sampler are ignored)")

    def run(self) -> Scene:
        root = _parse(self.path, self.source)
        if root.tag != "scene":
            self.fail(root, f"the root element must be <scene>, got <{root.tag}>")
        self.children(root, self.path)
        if not self.sensor_done:
            raise ImportError_(f"{self.path}: the scene has no <sensor>")
        return self.b.build()


def load_mitsuba_xml(path) -> Scene:
    """Load a Mitsuba 3 XML scene (see the module docstring for the supported subset)."""
    return _Importer(Path(path)).run()
