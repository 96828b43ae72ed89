"""Shared pieces of the importers: refractive indices by name, mesh loading, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ..data import NAMED_METALS, SceneError

# Indices of refraction by name (Mitsuba 3's documented table; facts, not code).
NAMED_IOR = {
    "vacuum": 1.0, "helium": 1.000036, "hydrogen": 1.000132, "air": 1.000277,
    "carbon dioxide": 1.00045, "water": 1.3330, "acetone": 1.36, "ethanol": 1.361,
    "carbon tetrachloride": 1.461, "glycerol": 1.4729, "benzene": 1.501,
    "silicone oil": 1.52045, "bromine": 1.661, "water ice": 1.31, "fused quartz": 1.458,
    "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046,
    "sodium chloride": 1.544, "amber": 1.55, "pet": 1.5750, "diamond": 2.419,
}


def tangent_frame(n) -> tuple[np.ndarray, np.ndarray]:
    """The tangents (s, t) jgi's microfacet BSDFs orient anisotropic roughness by (alpha_u along
    s): ``jgi.core.vec.coordinate_system`` of the unit geometric normal n (Duff et al. 2017),
    here in numpy."""
    x, y, z = (float(c) for c in np.asarray(n, float) / np.linalg.norm(n))
    sign = 1.0 if z >= 0 else -1.0
    a = -1.0 / (sign + z)
    b = x * y * a
    return (np.array([1.0 + sign * x * x * a, sign * b, -sign * x]),
            np.array([b, sign + y * y * a, -y]))


def _mesh_attributes(path: Path) -> set[str]:
    """What an OBJ or PLY file carries per vertex besides positions: "uv" (texture
    coordinates) and "normal"; {"unknown"} for other formats."""
    suffix = path.suffix.lower()
    if suffix == ".obj":
        with open(path, "rb") as fh:
            starts = {line[:3] for line in fh}
        return ({"uv"} if b"vt " in starts else set()) | ({"normal"} if b"vn " in starts
                                                           else set())
    if suffix == ".ply":
        with open(path, "rb") as fh:
            header = fh.read(4096).split(b"end_header")[0].decode("latin-1")
        names = {line.split()[-1] for line in header.splitlines()
                 if line.startswith("property") and len(line.split()) >= 3}
        uv = names & {"u", "v", "s", "t", "texture_u", "texture_v", "texture_s", "texture_t"}
        return ({"uv"} if uv else set()) | ({"normal"} if "nx" in names else set())
    return {"unknown"}


def has_texture_coordinates(path: Path) -> bool:
    """Whether an OBJ or PLY file carries texture coordinates (Mitsuba then orients the
    shading frame, and anisotropic roughness, along dp/du); True when it cannot tell."""
    attrs = _mesh_attributes(path)
    return "uv" in attrs or "unknown" in attrs


def named_metals() -> tuple[str, ...]:
    """The metal names the builder's conductors accept (Mitsuba's names, "none" included)."""
    return tuple(NAMED_METALS)


class ImportError_(SceneError):
    """An unsupported or malformed construct in an imported scene file."""


def load_mesh(path: Path, where: str, allow_vertex_normals: bool, with_uv: bool = False):
    """Vertices and faces of an OBJ/PLY file via trimesh. jgi shades with geometric normals, so
    a file carrying vertex normals is refused unless the caller allows flat shading. With
    ``with_uv``, also the vertices' texture coordinates (trimesh's, [V, 2]) or None."""

    if not path.is_file():
        raise ImportError_(f"{where}: mesh file '{path}' does not exist")
    if not allow_vertex_normals and "normal" in _mesh_attributes(path):
        raise ImportError_(
            f"{where}: mesh '{path.name}' has vertex normals (smooth shading); jgi shades with "
            "geometric normals only. Set face_normals=true (Mitsuba) or remove the normals.")
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:  # trimesh raises many kinds
        raise ImportError_(f"{where}: cannot read mesh '{path}': {e}") from None
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    if len(f) == 0:
        raise ImportError_(f"{where}: mesh '{path}' has no faces")
    if not with_uv:
        return v, f
    uv = getattr(mesh.visual, "uv", None)
    uv = None if uv is None or len(uv) != len(v) else np.asarray(uv, float)
    return v, f, uv

