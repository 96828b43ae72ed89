"""A jgi ``SceneBuilder``, before ``build()``, as a Mitsuba 3 scene dictionary: benchmarks render
the same scene in both (geometry, materials, emitters and camera), whatever the builder holds.

Supported: quads (as ``rectangle``), spheres, oriented boxes (``cube``), area emission on
them, point lights, the pinhole camera; materials diffuse, mirror / conductor, dielectric,
rough conductor, rough dielectric, rough plastic (opaque ones wrapped in ``twosided``: jgi's
are two-sided). Triangles, Phong (Mitsuba 3 has none) and the other lights raise ValueError.
"""

from __future__ import annotations

import numpy as np

from jgi.scene import SceneBuilder
from jgi.scene.tables import (
    BECKMANN,
    DIELECTRIC,
    DIFFUSE,
    MIRROR,
    POINT,
    ROUGH_CONDUCTOR,
    ROUGH_DIELECTRIC,
    ROUGH_PLASTIC,
)


def _rgb(c) -> dict:
    return {"type": "rgb", "value": [float(x) for x in c]}


def _roughness(m) -> dict:
    d = {"distribution": "beckmann" if m.distribution == BECKMANN else "ggx"}
    if m.alpha_u == m.alpha_v:
        d["alpha"] = m.alpha_u
    else:
        d["alpha_u"], d["alpha_v"] = m.alpha_u, m.alpha_v
    return d


def bsdf(m) -> dict:
    """One builder material as a Mitsuba BSDF."""
    if m.kind == DIFFUSE:
        b = {"type": "diffuse", "reflectance": _rgb(m.diffuse)}
    elif m.kind in (MIRROR, ROUGH_CONDUCTOR):
        b = {"type": "conductor" if m.kind == MIRROR else "roughconductor",
             "specular_reflectance": _rgb(m.specular)}
        if max(m.eta) == 0:
            b["material"] = "none"
        else:
            b["eta"], b["k"] = _rgb(m.eta), _rgb(m.k)
        if m.kind == ROUGH_CONDUCTOR:
            b.update(_roughness(m))
    elif m.kind in (DIELECTRIC, ROUGH_DIELECTRIC):
        b = {"type": "dielectric" if m.kind == DIELECTRIC else "roughdielectric",
             "int_ior": m.ior, "ext_ior": 1.0, "specular_reflectance": _rgb(m.specular),
             "specular_transmittance": _rgb(m.specular)}
        if m.kind == ROUGH_DIELECTRIC:
            b.update(_roughness(m))
        return b
    elif m.kind == ROUGH_PLASTIC:
        b = {"type": "roughplastic", "int_ior": m.ior, "ext_ior": 1.0,
             "diffuse_reflectance": _rgb(m.diffuse), "specular_reflectance": _rgb(m.specular),
             "nonlinear": bool(m.nonlinear), **_roughness(m)}
    else:
        raise ValueError(f"material kind {m.kind} has no Mitsuba 3 equivalent")
    return {"type": "twosided", "bsdf": b}


def to_mitsuba(b: SceneBuilder, mi, *, max_depth: int = 8, rr_depth: int = 5) -> dict:
    """The builder's scene as a dictionary for ``mi.load_dict`` (path integrator, box filter)."""
    T = mi.ScalarTransform4f
    if b.triangles:
        raise ValueError("triangles are not translated")
    d: dict = {"type": "scene",
               "integrator": {"type": "path", "max_depth": max_depth, "rr_depth": rr_depth}}
    for i, m in enumerate(b.materials):
        d[f"mat{i}"] = {**bsdf(m), "id": f"mat{i}"}
    ref = lambda i: {"type": "ref", "id": f"mat{i}"}  # noqa: E731

    def emitter(e):
        return {} if e is None else {"emitter": {"type": "area", "radiance": _rgb(e)}}

    for i, (o, u, v, m, e) in enumerate(b.quads):
        n = np.cross(u, v)
        mat = np.eye(4)
        mat[:3, 0], mat[:3, 1] = u / 2, v / 2
        mat[:3, 2] = n / np.linalg.norm(n)
        mat[:3, 3] = o + u / 2 + v / 2
        d[f"quad{i}"] = {"type": "rectangle", "to_world": T(mat), "bsdf": ref(m), **emitter(e)}
    for i, (c, r, m, e) in enumerate(b.spheres):
        d[f"sphere{i}"] = {"type": "sphere", "center": [float(x) for x in c], "radius": r,
                           "bsdf": ref(m), **emitter(e)}
    for i, (c, axes, half, m) in enumerate(b.boxes):
        mat = np.eye(4)
        mat[:3, :3] = axes.T * half[None, :]
        mat[:3, 3] = c
        d[f"box{i}"] = {"type": "cube", "to_world": T(mat), "bsdf": ref(m)}
    for i, light in enumerate(b.lights):
        if light["kind"] != POINT:
            raise ValueError(f"light kind {light['kind']} is not translated")
        d[f"light{i}"] = {"type": "point", "position": [float(x) for x in light["p0"]],
                          "intensity": _rgb(light["emission"])}
    a = b.camera_args
    axis = a.get("fov_axis", "y")
    if a.get("mirror"):
        raise ValueError("mirrored cameras are not translated")
    d["sensor"] = {
        "type": "perspective", "fov": a["fov"], "fov_axis": axis,
        "to_world": T().look_at(origin=[float(x) for x in a["position"]],
                                target=[float(x) for x in a["look_at"]],
                                up=[float(x) for x in a["up"]]),
        "film": {"type": "hdrfilm", "width": int(a["width"]), "height": int(a["height"]),
                 "rfilter": {"type": "box"}},
        "sampler": {"type": "independent"},
    }
    return d
