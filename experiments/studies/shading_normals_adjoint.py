"""Shading normals: can the tests tell? Two measurements on tests/test_shading_normals.py's
smooth Cornell box (16^2, max_depth 3):

1. the light tracer WITHOUT Veach's adjoint correction (jgi.physics.bsdf.adjoint_correction
   replaced by 1, so light paths use f |cos ns| as camera paths do) against the path tracer,
   and with it: Welch |t| per 4 x 4 region and over the image, and the relative difference of
   the image means;
2. jgi's path tracer with flat shading (the same meshes, face_normals="true") against
   Mitsuba 3's smooth render: the Mitsuba comparison must fail then.

Run: python -m experiments.studies.shading_normals_adjoint [--skip-mitsuba]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]   # the children run the module from here
SPP = 256       # samples per pixel of each of the 16 renders per estimator


def welch(a, b, regions):
    from tests.support.stats import critical_t, region_stats
    ma, sa = region_stats(a, regions)
    mb, sb = region_stats(b, regions)
    var = sa**2 + sb**2
    t = np.abs(ma - mb) / np.sqrt(np.maximum(var, 1e-30))
    dof = var**2 / np.maximum(sa**4 / (len(a) - 1) + sb**4 / (len(b) - 1), 1e-300)
    return t.max(), float(critical_t(np.clip(dof, 1, None), t.size).min())


def stack(scene, est, seeds, **kw):
    import jgi
    return np.stack([np.asarray(jgi.render(scene, est, seed=s, **kw)) for s in seeds])


def light_tracer(corrected: bool) -> None:
    """Child process: the light tracer with or without the correction, and the path tracer."""
    import jgi.physics.bsdf as B
    from jgi.scene.importers.mitsuba import load_mitsuba_xml
    from tests.support.smooth_cornell import DEPTH, smooth_cornell_xml
    if not corrected:
        B.adjoint_correction = lambda ns, ng, wo, wi: 1.0   # noqa: E731
    folder = Path(tempfile.mkdtemp())
    scene = load_mitsuba_xml(smooth_cornell_xml(folder))
    import time
    t0 = time.time()
    pt = stack(scene, "pt", range(100, 116), spp=SPP, max_depth=DEPTH)
    t1_ = time.time()
    lt = stack(scene, "lt", range(16), spp=SPP, max_depth=DEPTH)
    print(f"(PT {t1_ - t0:.1f} s, LT {time.time() - t1_:.1f} s for 16 x {SPP} spp)")
    t4, c4 = welch(lt, pt, 4)
    t1, c1 = welch(lt, pt, 1)
    rel = lt.mean() / pt.mean() - 1
    print(f"LT {'with' if corrected else 'WITHOUT'} the adjoint correction vs PT: max |t| = "
          f"{t4:.2f} over 4 x 4 regions (critical {c4:.2f}), {t1:.2f} over the image "
          f"(critical {c1:.2f}); image mean {100 * rel:+.2f} %")


def flat_vs_mitsuba() -> None:
    from jgi.scene.importers.mitsuba import load_mitsuba_xml
    from tests.support.mitsuba import load_mitsuba
    from tests.support.smooth_cornell import DEPTH, smooth_cornell_xml
    mi = load_mitsuba()
    folder = Path(tempfile.mkdtemp())
    xml = smooth_cornell_xml(folder)
    theirs = np.stack([np.asarray(mi.render(mi.load_file(str(xml)), spp=SPP, seed=s))[..., :3]
                       for s in range(16)])
    flat_xml = folder / "flat.xml"
    flat_xml.write_text(xml.read_text().replace(
        '<string name="filename" value="sphere.obj"/>',
        '<string name="filename" value="sphere.obj"/><boolean name="face_normals" value="true"/>'
    ).replace('<string name="filename" value="strip.obj"/>',
              '<string name="filename" value="strip.obj"/>'
              '<boolean name="face_normals" value="true"/>'))
    for label, path in (("smooth", xml), ("flat", flat_xml)):
        mine = stack(load_mitsuba_xml(path), "pt", range(100, 116), spp=SPP, max_depth=DEPTH)
        t4, c4 = welch(mine, theirs, 4)
        t1, c1 = welch(mine, theirs, 1)
        print(f"jgi PT ({label} shading) vs Mitsuba 3 (smooth): max |t| = {t4:.2f} over 4 x 4 "
              f"regions (critical {c4:.2f}), {t1:.2f} over the image (critical {c1:.2f}); image "
              f"mean {100 * (mine.mean() / theirs.mean() - 1):+.2f} %")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--child", choices=("corrected", "uncorrected"))
    ap.add_argument("--skip-mitsuba", action="store_true")
    a = ap.parse_args()
    if a.child:
        light_tracer(a.child == "corrected")
    else:
        for mode in ("uncorrected", "corrected"):   # separate processes: no shared jit cache
            subprocess.run([sys.executable, "-m", __spec__.name, "--child", mode], check=True,
                           cwd=ROOT)
        if not a.skip_mitsuba:
            flat_vs_mitsuba()
