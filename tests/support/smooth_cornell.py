"""tests/test_shading_normals.py's scene: Mitsuba's Cornell box holding a smooth low-poly
sphere and a smooth bent metal strip, written as Mitsuba XML (the study
experiments/studies/shading_normals_adjoint.py renders it too)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1] / "data"
DEPTH = 3       # path segments: direct light and two bounces (short compiles)
RES = 16


def uv_sphere(nu: int = 8, nv: int = 5):
    """A low-poly unit sphere: (vertices, outward-wound triangles), poles on z."""
    verts = [[0.0, 0.0, 1.0]]
    for j in range(1, nv):
        th = np.pi * j / nv
        verts += [[np.sin(th) * np.cos(2 * np.pi * i / nu), np.sin(th) * np.sin(2 * np.pi * i / nu),
                   np.cos(th)] for i in range(nu)]
    verts.append([0.0, 0.0, -1.0])
    last = len(verts) - 1
    f = [[0, 1 + i, 1 + (i + 1) % nu] for i in range(nu)]
    for j in range(nv - 2):
        a, b = 1 + j * nu, 1 + (j + 1) * nu
        for i in range(nu):
            i1 = (i + 1) % nu
            f += [[a + i, b + i, b + i1], [a + i, b + i1, a + i1]]
    ring = 1 + (nv - 2) * nu
    f += [[last, ring + (i + 1) % nu, ring + i] for i in range(nu)]
    return np.array(verts), np.array(f)


def bent_strip(n: int = 4):
    """A quarter cylinder (radius 1, y in [-1, 1]) as 2n triangles, with the cylinder's normals:
    (vertices, triangles, vertex normals)."""
    v, nrm = [], []
    for i in range(n + 1):
        a = 0.5 * np.pi * i / n
        for y in (-1.0, 1.0):
            v.append([np.cos(a), y, np.sin(a)])
            nrm.append([np.cos(a), 0.0, np.sin(a)])
    f = []
    for i in range(n):
        k = 2 * i
        f += [[k, k + 1, k + 2], [k + 1, k + 3, k + 2]]     # wound outwards, as the normals
    return np.array(v), np.array(f), np.array(nrm)


def write_obj(path: Path, v, f, normals=None):
    """A Wavefront OBJ of triangles ``f`` over vertices ``v``, with per-vertex ``normals`` if
    given."""
    lines = [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in v]
    if normals is None:
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    else:
        lines += [f"vn {a:.9g} {b:.9g} {c:.9g}" for a, b, c in normals]
        lines += [f"f {a + 1}//{a + 1} {b + 1}//{b + 1} {c + 1}//{c + 1}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")


SMOOTH_SHAPES = """    <bsdf type="twosided" id="metal">
        <bsdf type="roughconductor">
            <string name="material" value="Au"/>
            <string name="distribution" value="ggx"/>
            <float name="alpha" value="0.2"/>
        </bsdf>
    </bsdf>
    <shape type="obj">
        <string name="filename" value="sphere.obj"/>
        <transform name="to_world">
            <scale value="0.4"/><translate x="-0.35" y="-0.6" z="0"/>
        </transform>
        <ref id="white"/>
    </shape>
    <shape type="obj">
        <string name="filename" value="strip.obj"/>
        <transform name="to_world">
            <scale x="0.4" y="0.45" z="0.4"/><rotate y="1" angle="-45"/>
            <translate x="0.35" y="-0.55" z="-0.4"/>
        </transform>
        <ref id="metal"/>
    </shape>
</scene>
"""


CAMERA = '<lookat origin="0, 0, 3.9" target="0, 0, 0" up="0, 1, 0"/>'
CLOSE_UP = '<lookat origin="0, 0.1, 2" target="0, -0.6, 0" up="0, 1, 0"/>'


def smooth_cornell_xml(folder: Path, res: int = RES, depth: int = DEPTH,
                       camera: str = CLOSE_UP) -> Path:
    """Mitsuba's Cornell box with a smooth low-poly diffuse sphere (an OBJ without normals:
    Mitsuba computes them) and a bent gold strip (rough conductor, an OBJ with the cylinder's
    normals) in place of the blocks; no face_normals, so both shade with vertex normals. The
    camera looks at the two from close by, so that most regions of the image show them."""
    write_obj(folder / "sphere.obj", *uv_sphere(6, 4))
    write_obj(folder / "strip.obj", *bent_strip())
    xml = (DATA / "cornell_box_mitsuba.xml").read_text()
    xml = xml.replace('value="256"', f'value="{res}"').replace(
        '<integer name="max_depth" value="8"/>', f'<integer name="max_depth" value="{depth}"/>')
    xml = xml.replace(CAMERA, camera)
    head = xml[:xml.index('    <shape type="cube">')]
    path = folder / "smooth_cornell.xml"
    path.write_text(head + SMOOTH_SHAPES)
    return path
