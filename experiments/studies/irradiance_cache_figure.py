"""Irradiance cache figure: record positions over the Cornell box, and the error of indirect
irradiance against the number of gather rays, with and without the cache.

    python -m experiments.studies.irradiance_cache_figure [--res 48] [--out runs/irradiance_cache]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import jgi
from jgi.core.imageio import tonemap
from jgi.estimators import irradiance_cache as IC


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=48)
    ap.add_argument("--out", default="runs/irradiance_cache")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = jgi.scenes.cornell_box(resolution=a.res)
    v = IC.shade(scene, IC.CacheConfig(), 0, 1)
    pts = IC.ShadingPoints(np.stack([np.asarray(c) for c in v.p]),
                           np.stack([np.asarray(c) for c in v.n]), np.asarray(v.found))
    pix = np.arange(len(pts.found))
    raster = (pix % a.res, pix // a.res)
    ref = IC.irradiance(scene, pts, cfg=IC.CacheConfig(gather_m=24, gather_n=64, cached=False),
                        seed=99).E
    lum = lambda E: 0.2126 * E[0] + 0.7152 * E[1] + 0.0722 * E[2]
    f = pts.found
    err = lambda E: float(np.sqrt(np.mean((lum(E)[f] - lum(ref)[f]) ** 2)) / lum(ref)[f].mean())
    plain, cached = [], []
    for m, n in [(2, 6), (4, 12), (8, 24), (12, 32)]:
        E, _, st = IC.irradiance(scene, pts, cfg=IC.CacheConfig(gather_m=m, gather_n=n,
                                                                cached=False), seed=1)
        plain.append((st.gather_rays, err(E)))
    records = None
    for a_ in (0.6, 0.4, 0.2, 0.1):
        E, rec, st = IC.irradiance(scene, pts, cfg=IC.CacheConfig(a=a_), seed=1, raster=raster)
        cached.append((st.gather_rays, err(E), a_))
        if a_ == 0.4:
            records = rec
    img = IC.render(scene, IC.CacheConfig(a=0.4), spp=1, seed=0).image
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(8, 3.6))
    ax0.imshow(tonemap(img))
    ax0.scatter(records % a.res, records // a.res, s=4, c="cyan", marker="o", linewidths=0)
    ax0.set_title(f"{len(records)} records (a = 0.4)")
    ax0.axis("off")
    ax1.loglog(*zip(*plain), "o-", label="final gathering at every point")
    ax1.loglog([c[0] for c in cached], [c[1] for c in cached], "s-",
               label="irradiance cache (a = 0.6 .. 0.1)")
    ax1.set_xlabel("gather rays")
    ax1.set_ylabel("relative RMS error of E")
    ax1.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "irradiance_cache.png", dpi=150)
    (out / "irradiance_cache.json").write_text(json.dumps({"plain": plain, "cached": cached},
                                                          indent=2))
    for r, e in plain:
        print(f"plain   rays={r:8d}  error={e:.4f}")
    for r, e, a_ in cached:
        print(f"cached  rays={r:8d}  error={e:.4f}  a={a_}")


if __name__ == "__main__":
    main()
