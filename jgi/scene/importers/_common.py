"""Shared pieces of the importers: refractive indices by name, mesh loading, errors."""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np

from ...core import transform as xf
from ..builder import SceneError
from ..tables import NAMED_METALS

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


# The PLY vertex properties read as texture coordinates (u, v), the first pair present winning:
# Mitsuba 3's PLY loader reads these three pairs (checked with Mitsuba 3.9.1: texture_s /
# texture_t stay other attributes), pbrt-v4's (plymesh.cpp) texture_s / texture_t as well.
# Neither flips v.
MITSUBA_PLY_UV = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"))
PBRT_PLY_UV = MITSUBA_PLY_UV + (("texture_s", "texture_t"),)


def _mesh_attributes(path: Path) -> set[str]:
    """What an OBJ or PLY file carries per vertex besides positions: "uv" (texture
    coordinates; for PLY, Mitsuba's property names) and "normal"; {"unknown"} for other
    formats."""
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
        uv = names & {n for pair in MITSUBA_PLY_UV for n in pair}
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


def _read_ply(path: Path, where: str, uv_names=MITSUBA_PLY_UV):
    """Vertices, triangles, texture coordinates (the first pair of ``uv_names`` the file has,
    or None) and vertex normals (or None) of a PLY file, all in the file's vertex order:
    trimesh's parser without its re-indexing of textured vertices (``fix_texture``), so that
    the uv and normals stay with their vertices."""
    import trimesh  # on use: its import costs every start-up 0.4 s

    try:
        with open(path, "rb") as fh:
            kw = trimesh.exchange.ply.load_ply(fh, fix_texture=False, skip_materials=True)
        mesh = trimesh.Trimesh(vertices=kw["vertices"], faces=kw.get("faces"), process=False)
        data = kw["metadata"]["_ply_raw"]["vertex"]["data"]
    except Exception as e:  # trimesh raises many kinds
        raise ImportError_(f"{where}: cannot read mesh '{path}': {e}") from None
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    if len(f) == 0:
        raise ImportError_(f"{where}: mesh '{path}' has no faces")
    uv = None
    for a, b in uv_names:
        try:
            uv = np.stack([np.asarray(data[a], float).reshape(-1),
                           np.asarray(data[b], float).reshape(-1)], 1)
            break
        except (KeyError, ValueError, IndexError):
            continue
    normals = kw.get("vertex_normals")
    normals = None if normals is None else np.asarray(normals, float)
    for what, arr in (("texture coordinates", uv), ("vertex normals", normals)):
        if arr is not None and len(arr) != len(v):
            raise ImportError_(f"{where}: mesh '{path.name}': expected {len(v)} {what}, got "
                               f"{len(arr)}")
    return v, f, uv, normals


SERIALIZED_HEADER = 0x041C
# Mitsuba's serialized mesh flags (its serialized.cpp)
_HAS_NORMALS, _HAS_TEXCOORDS, _HAS_COLORS, _FACE_NORMALS, _DOUBLE = 0x1, 0x2, 0x8, 0x10, 0x2000


def read_serialized(path: Path, where: str, shape_index: int = 0):
    """Mesh ``shape_index`` of a Mitsuba ``.serialized`` file, as Mitsuba 3 reads it (its
    documented format: little endian; uint16 0x041C, uint16 version 3 or 4, then a zlib
    stream holding uint32 flags, [version 4: the shape's null-terminated name], uint64 vertex
    and face counts, positions, [normals], [uv], [colours, skipped], uint32 triangle indices;
    several meshes are concatenated, with their offsets (uint64, version 3: uint32) and
    their count (uint32) at the end of the file). Returns (v [V, 3], f [F, 3], uv [V, 2] or
    None, normals [V, 3] or None, face_normals: the file's face-normal flag)."""
    try:
        data = path.read_bytes()
    except OSError as e:
        raise ImportError_(f"{where}: cannot read mesh '{path}': {e}") from None

    def bad(msg):
        raise ImportError_(f"{where}: serialized mesh '{path.name}': {msg}")

    if len(data) < 8:
        bad("the file is too short")
    fmt, version = np.frombuffer(data[:4], "<u2")
    if fmt != SERIALIZED_HEADER:
        bad(f"not a serialized file (header {fmt:#06x}, expected {SERIALIZED_HEADER:#06x})")
    if version not in (3, 4):
        bad(f"version {version} is not supported (Mitsuba reads versions 3 and 4)")
    offset = 0
    if shape_index != 0:
        count = int(np.frombuffer(data[-4:], "<u4")[0])
        if not 0 <= shape_index < count:
            bad(f"shape_index {shape_index} is out of range: the file holds {count} meshes "
                f"(0..{count - 1})")
        size = 8 if version == 4 else 4
        at = len(data) - 4 - size * (count - shape_index)
        offset = int(np.frombuffer(data[at:at + size], "<u8" if size == 8 else "<u4")[0])
        if data[offset:offset + 2] != data[:2]:
            bad(f"the offset of mesh {shape_index} ({offset}) does not point at a mesh")
    try:
        stream = zlib.decompressobj().decompress(data[offset + 4:])
    except zlib.error as e:
        bad(f"cannot decompress mesh {shape_index}: {e}")
    try:
        flags = int(np.frombuffer(stream[:4], "<u4")[0])
        at = 4
        if version == 4:
            at = stream.index(b"\0", at) + 1
        n_v, n_f = (int(x) for x in np.frombuffer(stream[at:at + 16], "<u8"))
        at += 16
        real = np.dtype("<f8" if flags & _DOUBLE else "<f4")

        def take(n, dtype):
            nonlocal at
            arr = np.frombuffer(stream, dtype, count=n, offset=at)
            at += n * np.dtype(dtype).itemsize
            return arr

        v = take(3 * n_v, real).reshape(-1, 3).astype(float)
        normals = take(3 * n_v, real).reshape(-1, 3).astype(float) \
            if flags & _HAS_NORMALS else None
        uv = take(2 * n_v, real).reshape(-1, 2).astype(float) if flags & _HAS_TEXCOORDS else None
        if flags & _HAS_COLORS:
            take(3 * n_v, real)
        f = take(3 * n_f, "<u4").reshape(-1, 3).astype(np.int64)
    except (ValueError, IndexError):
        bad(f"mesh {shape_index} is truncated or malformed")
    if n_f == 0:
        bad(f"mesh {shape_index} has no faces")
    if f.max() >= n_v:
        bad(f"mesh {shape_index} refers to a vertex that does not exist")
    return v, f, uv, normals, bool(flags & _FACE_NORMALS)


def load_mesh_with_normals(path: Path, where: str, ply_uv=MITSUBA_PLY_UV):
    """Vertices, faces, texture coordinates (or None) and the file's vertex normals (or None
    when it has none) of an OBJ or PLY file, for smooth shading: OBJ files as Mitsuba 3 reads
    them (:func:`_read_obj`; its vt as written, v not flipped), PLY files with the texture
    coordinates named by ``ply_uv`` (:func:`_read_ply`)."""
    if not path.is_file():
        raise ImportError_(f"{where}: mesh file '{path}' does not exist")
    if path.suffix.lower() == ".obj":
        return _read_obj(path, where)
    if path.suffix.lower() == ".ply":
        return _read_ply(path, where, ply_uv)
    v, f, uv = load_mesh(path, where, with_uv=True)
    return v, f, uv, None


def load_mesh(path: Path, where: str, allow_vertex_normals: bool = True, with_uv: bool = False,
              ply_uv=MITSUBA_PLY_UV):
    """Vertices and faces of a mesh file via trimesh (any vertex normals it carries are
    not read: callers that shade smoothly use :func:`load_mesh_with_normals`). With
    ``with_uv``, also the vertices' texture coordinates ([V, 2], as the file has them) or None:
    trimesh's for OBJ files, the pairs ``ply_uv`` names for PLY files (:func:`_read_ply`).
    ``allow_vertex_normals`` is kept for callers: every file is accepted."""

    if not path.is_file():
        raise ImportError_(f"{where}: mesh file '{path}' does not exist")
    if path.suffix.lower() == ".ply":
        v, f, uv, _ = _read_ply(path, where, ply_uv)
        return (v, f, uv) if with_uv else (v, f)
    import trimesh  # on use: its import costs every start-up 0.4 s

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


def axis_aligned(m: np.ndarray) -> bool:
    """Whether the affine 4 x 4 map m only scales (positively, per axis) and translates."""
    lin = m[:3, :3]
    return bool(np.all(np.abs(lin - np.diag(np.diag(lin))) <= 1e-9) and np.all(np.diag(lin) > 0)
                and np.all(m[3] == (0, 0, 0, 1)))


def zero_faces(grid: np.ndarray) -> bool:
    """Whether every voxel on the faces of grid [nz, ny, nx] is 0."""
    return not any(np.any(np.take(grid, i, axis=a)) for a in range(3) for i in (0, -1))


def same_region(null, lo, hi, to_world) -> bool:
    """Whether the null shape ``null`` (shape, unit shape to world: Mitsuba's cube or sphere
    with a null bsdf, pbrt-v4's box or sphere with the interface material) is the grid's box
    [lo, hi] (in the frame ``to_world`` maps to the world; None: the world's): then it cuts
    nothing."""
    shape, unit = null
    if shape != "cube":
        return False
    box = xf.translate((np.asarray(lo) + hi) / 2) @ xf.scale((np.asarray(hi) - lo) / 2)
    grid = box if to_world is None else np.asarray(to_world, float) @ box
    return bool(np.allclose(grid, unit, rtol=0, atol=1e-6 * max(np.abs(unit).max(), 1.0)))
