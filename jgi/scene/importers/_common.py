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


def has_vertex_normals(path: Path) -> bool:
    """Whether an OBJ or PLY file carries vertex normals."""
    return "normal" in _mesh_attributes(path)


def _read_obj(path: Path, where: str):
    """Vertices, triangles, texture coordinates and vertex normals of an OBJ file, read as
    Mitsuba 3's OBJ loader reads it: a mesh vertex per distinct (position, texture coordinate,
    normal) index triple of the faces, in order of first use; polygons as triangle fans.
    Returns (v [V, 3], f [F, 3], uv [V, 2] or None, normals [V, 3] or None)."""
    pos, tex, nrm, faces, keys, index = [], [], [], [], [], {}
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError as e:
        raise ImportError_(f"{where}: cannot read mesh '{path}': {e}") from None
    for no, line in enumerate(lines, 1):
        parts = line.split()
        if not parts:
            continue
        try:
            if parts[0] == "v":
                pos.append([float(x) for x in parts[1:4]])
            elif parts[0] == "vt":
                tex.append([float(x) for x in parts[1:3]])
            elif parts[0] == "vn":
                nrm.append([float(x) for x in parts[1:4]])
            elif parts[0] == "f":
                ids = []
                for c in parts[1:]:
                    k = tuple(int(x) if x else 0 for x in (c.split("/") + ["", ""])[:3])
                    k = tuple(x if x >= 0 else n + 1 + x   # negative indices count back
                              for x, n in zip(k, (len(pos), len(tex), len(nrm))))
                    if k not in index:
                        index[k] = len(keys)
                        keys.append(k)
                    ids.append(index[k])
                faces += [[ids[0], ids[i], ids[i + 1]] for i in range(1, len(ids) - 1)]
        except ValueError:
            raise ImportError_(f"{where}: mesh '{path.name}', line {no}: cannot parse "
                               f"'{line.strip()}'") from None
    if not faces:
        raise ImportError_(f"{where}: mesh '{path}' has no faces")
    k = np.asarray(keys, np.int64)
    for col, table, what in ((0, pos, "vertex"), (1, tex, "texture coordinate"),
                             (2, nrm, "normal")):
        used = k[:, col][k[:, col] != 0]
        if np.any(used > len(table)) or np.any(used < 1) or (col == 0 and len(used) < len(k)):
            raise ImportError_(f"{where}: mesh '{path.name}' refers to a {what} that does not "
                               "exist")
    v = np.asarray(pos, float)[k[:, 0] - 1]
    uv = np.asarray(tex, float)[k[:, 1] - 1] if tex and np.all(k[:, 1] > 0) else None
    normals = None
    if nrm:
        if not np.all(k[:, 2] > 0):
            raise ImportError_(f"{where}: mesh '{path.name}' gives normals for some face "
                               "vertices only")
        normals = np.asarray(nrm, float)[k[:, 2] - 1]
    return v, np.asarray(faces, np.int64), uv, normals


def normals_are_flat(v, f, normals, tol: float = 1e-6) -> bool:
    """Whether vertex normals ([V, 3], any length; world space) equal the face normals of the
    triangles ``f`` of vertices ``v`` at every corner: smooth shading would change nothing."""
    n = np.asarray(normals, float)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    tri = np.asarray(v, float)[np.asarray(f)]
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face = face / np.maximum(np.linalg.norm(face, axis=1, keepdims=True), 1e-300)
    return bool(np.all(np.sum(n[np.asarray(f)] * face[:, None, :], axis=2) > 1 - tol))


def load_mesh_with_normals(path: Path, where: str):
    """Vertices, faces, texture coordinates (or None) and the file's vertex normals (or None
    when it has none) of an OBJ or PLY file, for smooth shading: OBJ files as Mitsuba 3 reads
    them (:func:`_read_obj`), PLY files through trimesh (vertices as listed)."""
    if not path.is_file():
        raise ImportError_(f"{where}: mesh file '{path}' does not exist")
    if path.suffix.lower() == ".obj":
        return _read_obj(path, where)
    v, f, uv = load_mesh(path, where, allow_vertex_normals=True, with_uv=True)
    normals = None
    if has_vertex_normals(path):
        try:   # the file's values (trimesh.load may replace normals it disagrees with)
            with open(path, "rb") as fh:
                normals = np.asarray(trimesh.exchange.ply.load_ply(fh)["vertex_normals"],
                                     float)
        except Exception as e:  # trimesh raises many kinds
            raise ImportError_(f"{where}: cannot read the normals of mesh '{path}': {e}") from None
        if normals.shape != v.shape:
            raise ImportError_(f"{where}: mesh '{path.name}': expected {len(v)} vertex normals, "
                               f"got {len(normals)}")
    return v, f, uv, normals


def load_mesh(path: Path, where: str, allow_vertex_normals: bool = True, with_uv: bool = False):
    """Vertices and faces of an OBJ/PLY file via trimesh (any vertex normals it carries are
    not read: callers that shade smoothly use :func:`load_mesh_with_normals`). With
    ``with_uv``, also the vertices' texture coordinates (trimesh's, [V, 2]) or None.
    ``allow_vertex_normals`` is kept for callers: every file is accepted."""

    if not path.is_file():
        raise ImportError_(f"{where}: mesh file '{path}' does not exist")
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

