"""Shared pieces of the importers: refractive indices by name, mesh loading, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ..data import SceneError

# Indices of refraction by name (Mitsuba 3's documented table; facts, not code).
NAMED_IOR = {
    "vacuum": 1.0, "helium": 1.000036, "hydrogen": 1.000132, "air": 1.000277,
    "carbon dioxide": 1.00045, "water": 1.3330, "acetone": 1.36, "ethanol": 1.361,
    "carbon tetrachloride": 1.461, "glycerol": 1.4729, "benzene": 1.501,
    "silicone oil": 1.52045, "bromine": 1.661, "water ice": 1.31, "fused quartz": 1.458,
    "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046,
    "sodium chloride": 1.544, "amber": 1.55, "pet": 1.5750, "diamond": 2.419,
}


class ImportError_(SceneError):
    """An unsupported or malformed construct in an imported scene file."""


def load_mesh(path: Path, where: str, allow_vertex_normals: bool):
    """Vertices and faces of an OBJ/PLY file via trimesh. jgi shades with geometric normals, so
    a file carrying vertex normals is refused unless the caller allows flat shading."""

    if not path.is_file():
        raise ImportError_(f"{where}: mesh file '{path}' does not exist")
    if not allow_vertex_normals and _has_vertex_normals(path):
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
    return v, f


def _has_vertex_normals(path: Path) -> bool:
    suffix = path.suffix.lower()
    if suffix == ".obj":
        with open(path, "rb") as fh:
            return any(line.startswith(b"vn ") for line in fh)
    if suffix == ".ply":
        with open(path, "rb") as fh:
            header = fh.read(4096).split(b"end_header")[0]
        return b" nx" in header
    return False
