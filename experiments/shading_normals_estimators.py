"""Every estimator on tests/test_shading_normals.py's smooth Cornell box (16^2, max_depth 3)
against the path tracer: Welch |t| per 4 x 4 region (whole image for the consistent photon
estimators, whose bias at these radii is not zero), with the Bonferroni critical value.
Whitted and the irradiance cache estimate other quantities (direct light only; direct + cached
indirect diffuse with glossy light by Monte Carlo): they are checked against the path tracer
restricted to what they compute where a closed comparison exists (Whitted: path length 2),
and otherwise only for finite output.

Run: PYTHONPATH=. python experiments/shading_normals_estimators.py [estimator ...]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import jgi  # noqa: E402
from jgi.scene.importers.mitsuba import load_mitsuba_xml  # noqa: E402
from tests.conftest import critical_t, region_stats  # noqa: E402
from tests.test_shading_normals import DEPTH, smooth_cornell_xml  # noqa: E402

CASES = {
    "mlt": (dict(max_depth=DEPTH, chains=512, b_paths=1 << 16), 64, 8, 4),
    "pssmlt": (dict(max_depth=DEPTH, chains=512), 64, 8, 4),
    "mmlt": (dict(max_depth=DEPTH, chains=512), 64, 8, 4),
    # photon max_depth counts photon bounces: stored at their (max_depth)-th hit at most,
    # so paths of up to max_depth + 1 segments, the path tracer's DEPTH with DEPTH - 1
    "pm": (dict(max_depth=DEPTH - 1, photons=400_000, radius=0.03), 16, 4, 1),
    "sppm": (dict(max_depth=DEPTH - 1, photons=50_000, passes=16, radius=0.05), 4, 4, 1),
    "pm_jensen": (dict(photons=100_000, caustic_photons=20_000,
                       final_gather=16), 4, 4, 1),
    "whitted": (dict(max_depth=DEPTH), 64, 8, 4),
    "irradiance_cache": (dict(), 4, 2, 1),
}


def welch(a, b, regions):
    ma, sa = region_stats(a, regions)
    mb, sb = region_stats(b, regions)
    var = np.maximum(sa**2 + sb**2, 1e-30)
    t = np.abs(ma - mb) / np.sqrt(var)
    dof = var**2 / np.maximum(sa**4 / (len(a) - 1) + sb**4 / (len(b) - 1), 1e-300)
    return t.max(), float(critical_t(np.clip(dof, 1, None), t.size).min())


def main(names):
    scene = load_mitsuba_xml(smooth_cornell_xml(Path(tempfile.mkdtemp())))
    stack = lambda est, seeds, **kw: np.stack(  # noqa: E731
        [np.asarray(jgi.render(scene, est, seed=s, **kw)) for s in seeds])
    pt = stack("pt", range(100, 116), spp=256, max_depth=DEPTH)
    pt2 = stack("pt", range(200, 216), spp=256, max_depth=2)   # direct light only (Whitted)
    pt8 = stack("pt", range(300, 316), spp=256, max_depth=8)   # Jensen's split, the cache
    for name in names:
        params, spp, n, regions = CASES[name]
        t0 = time.time()
        imgs = stack(name, range(n), spp=spp, **params)
        ref = pt2 if name == "whitted" else pt8 if name in ("pm_jensen", "irradiance_cache") else pt
        t, crit = welch(imgs, ref, regions)
        finite = np.isfinite(imgs).all()
        print(f"{name:17s} vs pt{' (2 segments)' if name == 'whitted' else ''}: max |t| = "
              f"{t:6.2f} (critical {crit:.2f}, {regions}x{regions} regions), image mean "
              f"{100 * (imgs.mean() / ref.mean() - 1):+.2f} %, finite {finite}, "
              f"{time.time() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or list(CASES))
