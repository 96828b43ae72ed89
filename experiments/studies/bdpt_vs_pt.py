"""Equal-time comparison of path tracing, BDPT and light tracing on the caustic Cornell box
(or ``--scene``).

    python -m experiments.studies.bdpt_vs_pt [--scene cornell_box_caustics] [--resolution 32]
                                             [--budget 2 8] [--repetitions 3] [--reference-spp 4096]
                                             [--out out/bdpt_vs_pt]

A long path-tracing render (max depth 5, no Russian roulette, ``--reference-spp``; cached in
``OUT/reference.npy`` with its per-pixel variance) is the reference. For every time budget T
(seconds per render), each estimator's cost per sample is measured after compilation and the spp
that fits T chosen; ``--repetitions`` independent renders then give the relative MSE
(jgi.analysis.stats: (bias^2 + variance) / (ref^2 + 0.01), the reference's own variance removed,
image average) of one render of T seconds, for the whole image and for the floor below the
spheres (where the caustics are); ``relMSE@T`` rescales it by measured seconds / T (variance
~ 1 / time), which corrects for renders that did not take exactly T on a shared machine.
Output: a table on stdout, ``OUT/results.json``, EXR/PNG of one render per estimator at the
largest budget.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ESTIMATORS = {
    "pt": dict(max_depth=5, rr_depth=-1),
    "bdpt": dict(max_depth=5, heuristic="power"),
    "lt": dict(max_depth=5),
}


def reference(scene, spp: int, out: Path):
    import jgi

    path = out / f"reference_{scene.name}_{scene.camera.width}_{spp}.npz"
    if path.exists():
        z = np.load(path)
        return z["mean"], z["variance"]
    chunks = [jgi.render(scene, "pt", spp=spp // 8, seed=10_000 + k, **ESTIMATORS["pt"])
              for k in range(8)]
    x = np.stack(chunks).astype(np.float64)
    mean, variance = x.mean(0), x.var(0, ddof=1) / len(chunks)
    out.mkdir(parents=True, exist_ok=True)
    np.savez(path, mean=mean, variance=variance)
    return mean, variance


def seconds_per_spp(scene, name, params) -> float:
    import jgi

    jgi.render(scene, name, spp=1, seed=0, **params)         # compile
    for spp in (4, 16, 64, 256, 1024, 4096):
        t0 = time.perf_counter()
        jgi.render(scene, name, spp=spp, seed=1, **params)
        if time.perf_counter() - t0 > 0.5:
            break
    best = min(_timed(scene, name, spp, params) for _ in range(3))
    return best / spp


def _timed(scene, name, spp, params) -> float:
    import jgi

    t0 = time.perf_counter()
    jgi.render(scene, name, spp=spp, seed=2, **params)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cornell_box_caustics",
                    help="e.g. glass_sphere: a caustic under a small light")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--budget", type=float, nargs="+", default=[2.0, 8.0])
    ap.add_argument("--repetitions", type=int, default=3)
    ap.add_argument("--reference-spp", type=int, default=4096)
    ap.add_argument("--out", default="out/bdpt_vs_pt")
    a = ap.parse_args(argv)

    import jgi
    from jgi.analysis import stats
    from jgi.core.imageio import write_exr, write_png

    out = Path(a.out)
    scene = jgi.load_scene(a.scene).with_resolution(a.resolution, a.resolution)
    t0 = time.perf_counter()
    ref, ref_var = reference(scene, a.reference_spp, out)
    print(f"reference: pt {a.reference_spp} spp in {time.perf_counter() - t0:.0f} s "
          f"(mean {ref.mean():.4f})", file=sys.stderr)
    H = a.resolution
    floor = (slice(int(0.7 * H), H), slice(0, H))           # rows with the floor under the spheres
    cost = {n: seconds_per_spp(scene, n, p) for n, p in ESTIMATORS.items()}
    rows = []
    for budget in a.budget:
        for name, params in ESTIMATORS.items():
            spp = max(1, int(round(budget / cost[name])))
            imgs, secs = [], []
            for r in range(a.repetitions):
                t0 = time.perf_counter()
                imgs.append(jgi.render(scene, name, spp=spp, seed=100 + r, **params))
                secs.append(time.perf_counter() - t0)
            e = stats.error_stats(np.stack(imgs), ref, ref_var)
            seconds = float(np.mean(secs))
            rows.append(dict(budget_s=budget, estimator=name, spp=spp, seconds=seconds,
                             rel_mse=float(e.rel_mse.mean()),
                             # variance ~ 1 / time: the relative MSE rescaled to exactly T seconds
                             rel_mse_at_budget=float(e.rel_mse.mean() * seconds / budget),
                             rel_mse_floor=float(e.rel_mse[floor].mean()),
                             bias2_rel=float((e.bias2 / (ref * ref + 1e-2)).mean()),
                             mean=float(np.mean(imgs))))
            if budget == max(a.budget):
                write_exr(out / f"{name}.exr", imgs[0])
                write_png(out / f"{name}.png", imgs[0])
    print(f"{'budget':>7} {'estimator':>9} {'spp':>6} {'seconds':>8} {'relMSE':>9} "
          f"{'relMSE@T':>9} {'relMSE floor':>12} {'bias^2 rel':>10}")
    for r in rows:
        print(f"{r['budget_s']:7.1f} {r['estimator']:>9} {r['spp']:6d} {r['seconds']:8.2f} "
              f"{r['rel_mse']:9.5f} {r['rel_mse_at_budget']:9.5f} {r['rel_mse_floor']:12.5f} "
              f"{r['bias2_rel']:10.5f}")
    result = dict(scene=a.scene, resolution=a.resolution,
                  reference_spp=a.reference_spp, seconds_per_spp=cost, rows=rows,
                  load_average=os.getloadavg()[0], cpus=os.cpu_count())
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
