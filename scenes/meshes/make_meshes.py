"""Regenerates the mesh files used by the example scenes (run from anywhere):

    .venv/bin/python scenes/meshes/make_meshes.py

torus.ply: a torus (major radius 1, minor radius 0.35) around the z axis, 48 x 24 sections,
built with trimesh and written as binary PLY (positions and triangles only).
"""

from pathlib import Path

import trimesh

HERE = Path(__file__).resolve().parent

if __name__ == "__main__":
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.35,
                                   major_sections=48, minor_sections=24)
    mesh = trimesh.Trimesh(torus.vertices, torus.faces, process=False)
    (HERE / "torus.ply").write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary",
                                                                     vertex_normal=False))
    print(f"torus.ply: {len(mesh.vertices)} vertices, {len(mesh.faces)} triangles")
