"""Quickstart study (about a minute on a laptop CPU): BSDF, light and MIS sampling on the
Cornell box, their MSE against a long reference as the sample count grows, and the fitted
convergence slopes (Monte Carlo theory: -1).

    python experiments/quickstart.py [--out runs/quickstart] [--res 64]

Writes metrics.csv / metrics.json (one row per strategy, spp and repetition), convergence.png
(log-log MSE with fitted slopes), images.png (one render per strategy beside the reference),
EXR images, and provenance.json.
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/quickstart")
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--reps", type=int, default=3)
    a = ap.parse_args(argv)

    import jax
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import jgi
    from jgi.analysis import fitting
    from jgi.core.imageio import tonemap, write_exr

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    scene = jgi.scenes.cornell_box(resolution=a.res)
    print(f"[quickstart] reference: {a.res}x{a.res}, 512 spp, MIS", file=sys.stderr)
    ref_spp = 512
    ref = jgi.render(scene, "pt", spp=ref_spp, seed=1_000_000)
    write_exr(out / "reference.exr", ref)
    strategies = {"bsdf": dict(strategy="bsdf"), "light": dict(strategy="light"),
                  "mis": dict(strategy="mis", heuristic="power")}
    spps = [1, 2, 4, 8, 16]
    rows, images = [], {}
    for name, params in strategies.items():
        for spp in spps:
            for rep in range(a.reps):
                t0 = time.perf_counter()
                img = jgi.render(scene, "pt", spp=spp, seed=1000 * spp + rep, **params)
                dt = time.perf_counter() - t0
                mse = float(np.mean((img - ref) ** 2))
                rows.append(dict(strategy=name, spp=spp, rep=rep, mse=mse, seconds=dt))
            if spp == spps[-1]:
                images[name] = img
                write_exr(out / f"{name}_{spp}spp.exr", img)
        print(f"[quickstart] {name} done", file=sys.stderr)
    # the reference's own noise adds var/ref_spp to every MSE: estimate it from spp = 1
    summary = {}
    for name in strategies:
        m = {s: np.mean([r["mse"] for r in rows if r["strategy"] == name and r["spp"] == s])
             for s in spps}
        ref_var = m[1] / ref_spp
        corrected = [max(m[s] - ref_var, 1e-30) for s in spps]
        slope, c, se = fitting.power_law(spps, corrected)
        summary[name] = dict(slope=slope, slope_se=se, mse_at_max_spp=corrected[-1])
    with open(out / "metrics.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (out / "metrics.json").write_text(json.dumps({"rows": rows, "summary": summary}, indent=2))

    fig, ax = plt.subplots(figsize=(4.5, 3.2))
    for name in strategies:
        m = [np.mean([r["mse"] for r in rows if r["strategy"] == name and r["spp"] == s])
             for s in spps]
        s = summary[name]
        ax.loglog(spps, m, "o-", label=f"{name}: slope {s['slope']:.2f} ± {s['slope_se']:.2f}")
    ax.set_xlabel("samples per pixel")
    ax.set_ylabel("MSE against reference")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "convergence.png", dpi=150)
    fig, axes = plt.subplots(1, len(images) + 1, figsize=(3 * (len(images) + 1), 3.2))
    for ax, (name, img) in zip(axes, list(images.items()) + [("reference", ref)]):
        ax.imshow(tonemap(img))
        ax.set_title(name if name == "reference" else f"{name}, {spps[-1]} spp")
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out / "images.png", dpi=120)
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).parent).stdout.strip() or None
    except OSError:
        commit = None
    prov = dict(jgi_version=jgi.__version__, git_commit=commit, jax_version=jax.__version__,
                devices=[str(d) for d in jax.devices()], python=platform.python_version(),
                seconds=time.perf_counter() - t_start, resolution=a.res, reference_spp=ref_spp)
    (out / "provenance.json").write_text(json.dumps(prov, indent=2))
    for name, s in summary.items():
        print(f"{name:6s} MSE slope {s['slope']:+.3f} ± {s['slope_se']:.3f}   "
              f"MSE at {spps[-1]} spp {s['mse_at_max_spp']:.3e}")
    print(f"wrote {out}/ (metrics.csv, convergence.png, images.png, EXRs) "
          f"in {prov['seconds']:.0f} s")
    return summary


if __name__ == "__main__":
    main()
