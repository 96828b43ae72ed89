"""Equal-time comparison of estimators: path tracing, BDPT and Metropolis light transport on a
scene where light arrives through a glass caustic, reporting relative MSE against a long
reference and the MLT chains' acceptance rates.

    python -m experiments.studies.equal_time [--scene cornell_box_caustics] [--res 64] [--budget 20]
                                             [--reps 3] [--max-depth 5] [--set mlt|vcm]
                                             [--ref pt|vcm] [--only LABEL ...]
                                             [--out runs/equal_time]

``--set vcm`` compares path tracing, BDPT, SPPM and VCM instead (SPPM's budget sets its passes,
VCM's its iterations); ``--ref vcm`` renders the reference with VCM (for point-lit scenes,
whose caustics seen in mirrors no unbiased estimator samples).

Every estimator, and the reference, uses the same maximum path length (``--max-depth``), so
they estimate the same image.

Each estimator's cost per sample per pixel is measured after a warm-up (compilation excluded),
then its spp is set so that one render takes about ``--budget`` seconds. Writes
equal_time.json and equal_time.png (images and per-pixel relative error side by side).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ESTIMATORS = {  # label: (registry name, parameters[, the parameter the budget sets: spp])
    "path tracing": ("pt", {}),
    "BDPT": ("bdpt", {}),
    "PSSMLT": ("pssmlt", {"p_large": 0.3}),
    "MMLT": ("mmlt", {}),
    "Veach MLT": ("mlt", {}),
    "SPPM": ("sppm", {"photons": 20_000, "radius": 0.05, "radius_alpha": 0.7}, "passes"),
    "VCM": ("vcm", {"radius": 0.05}),
}
SETS = {  # --set: the estimators of one study
    "mlt": ["path tracing", "BDPT", "PSSMLT", "MMLT", "Veach MLT"],
    "vcm": ["path tracing", "BDPT", "SPPM", "VCM"],
}
REFERENCES = {  # --ref: (estimator, parameters); spp from --ref-spp
    "pt": ("pt", {}),
    # a consistent reference for light no unbiased technique samples (point-lit caustics seen
    # in a mirror): many VCM iterations, the radius shrinking to a small fraction of r_0
    "vcm": ("vcm", {"radius": 0.05}),
}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cornell_box_caustics")
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--budget", type=float, default=20.0, help="seconds per render")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--max-depth", type=int, default=5)
    ap.add_argument("--set", default="mlt", choices=sorted(SETS), help="the estimators compared")
    ap.add_argument("--ref", default="pt", choices=sorted(REFERENCES), help="reference estimator")
    ap.add_argument("--only", nargs="*", default=None, help="labels or estimator names to run")
    ap.add_argument("--out", default="runs/equal_time")
    a = ap.parse_args(argv)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import jgi
    from jgi.analysis import stats
    from jgi.core.imageio import tonemap, write_exr

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = jgi.load_scene(a.scene).with_resolution(a.res, a.res)
    ref_name, ref_params = REFERENCES[a.ref]
    print(f"[equal_time] reference: {ref_name}, {a.ref_spp} spp", file=sys.stderr)
    halves = [jgi.render(scene, ref_name, spp=a.ref_spp // 2, seed=777_000 + h,
                         max_depth=a.max_depth, **ref_params)
              for h in range(2)]
    ref = 0.5 * (halves[0] + halves[1])
    ref_var = 0.25 * (halves[0] - halves[1]) ** 2
    write_exr(out / "reference.exr", ref)
    rows, images = [], {}
    for label in SETS[a.set]:
        name, params, *key = ESTIMATORS[label]
        key = key[0] if key else "spp"
        if a.only is not None and label not in a.only and name not in a.only:
            continue
        # photon mapping bounds each subpath (max_bounces), the others a whole path (max_depth)
        depth = "max_bounces" if name in ("pm", "ppm", "sppm") else "max_depth"
        params = dict(params, **{depth: a.max_depth})
        render_result = _budgeted(jgi.render_result, key)
        render = lambda *args, **kw: render_result(*args, **kw)[0]  # noqa: E731
        if name not in jgi.REGISTRY:
            print(f"[equal_time] {label}: estimator '{name}' not available, skipped",
                  file=sys.stderr)
            continue
        # time = fixed + per_spp * spp (fixed: e.g. MLT's bootstrap), fitted from two probes
        # after a compiling call; then a render at the predicted spp corrects it once
        render(scene, name, spp=2, seed=1, **params)
        probes = []
        for spp in (2, 16):
            t0 = time.perf_counter()
            render(scene, name, spp=spp, seed=2, **params)
            probes.append((spp, time.perf_counter() - t0))
        (s1, t1), (s2, t2) = probes
        per_spp = max((t2 - t1) / (s2 - s1), t2 / s2 * 0.05)
        fixed = max(t1 - per_spp * s1, 0.0)
        spp = max(1, int((a.budget - fixed) / per_spp))
        t0 = time.perf_counter()
        render(scene, name, spp=spp, seed=3, **params)
        measured = time.perf_counter() - t0
        spp = max(1, int(spp * (a.budget - fixed) / max(measured - fixed, 1e-3)))
        imgs, secs, acc = [], [], []
        for r in range(a.reps):
            t0 = time.perf_counter()
            img, st = render_result(scene, name, spp=spp, seed=100 + r, **params)
            secs.append(time.perf_counter() - t0)
            imgs.append(img)
            if "acceptance" in st:
                acc.append(st)
        s = stats.error_stats(np.stack(imgs), ref, ref_var)
        row = dict(label=label, estimator=name, spp=spp, budget_key=key,
                   seconds=float(np.mean(secs)),
                   rel_mse=float(s.rel_mse.mean()), mse=float(s.mse.mean()),
                   acceptance=float(np.mean([st["acceptance"] for st in acc])) if acc else None)
        for kind in ("large", "lens", "caustic"):  # Veach MLT: per mutation kind
            if acc and f"{kind}_acceptance" in acc[0]:
                row[f"{kind}_acceptance"] = float(np.mean([st[f"{kind}_acceptance"] for st in acc]))
                row[f"{kind}_applicable"] = float(np.mean([st[f"{kind}_applicable"] /
                                                           max(st[f"{kind}_proposed"], 1)
                                                           for st in acc]))
        rows.append(row)
        images[label] = (imgs[0], s)
        print(f"[equal_time] {label:14s} spp {spp:5d}  {row['seconds']:.1f}s  "
              f"relMSE {row['rel_mse']:.4g}"
              + (f"  acceptance {row['acceptance']:.3f}" if acc else "")
              + "".join(f"  {k} {row[k + '_acceptance']:.3f} "
                        f"(applicable {row[k + '_applicable']:.2f})"
                        for k in ("large", "lens", "caustic") if k + "_acceptance" in row),
              file=sys.stderr)
    summary = dict(scene=a.scene, resolution=a.res, budget_s=a.budget, reference_spp=a.ref_spp,
                   reference=ref_name,
                   max_depth=a.max_depth,
                   repetitions=a.reps, rows=rows)
    (out / "equal_time.json").write_text(json.dumps(summary, indent=2))
    fig, axes = plt.subplots(2, len(images) + 1, figsize=(2.6 * (len(images) + 1), 5.2),
                             squeeze=False)
    axes[0, 0].imshow(tonemap(ref))
    axes[0, 0].set_title("reference", fontsize=8)
    axes[1, 0].axis("off")
    vmax = max(float(np.percentile(s.rel_mse.mean(-1), 99)) for _, s in images.values()) or 1.0
    for i, (label, (img, s)) in enumerate(images.items(), 1):
        row = next(r for r in rows if r["label"] == label)
        axes[0, i].imshow(tonemap(img))
        axes[0, i].set_title(f"{label} ({row['spp']} spp)", fontsize=8)
        axes[1, i].imshow(s.rel_mse.mean(-1), cmap="inferno", vmin=0, vmax=vmax)
        axes[1, i].set_title(f"relMSE {row['rel_mse']:.3g}", fontsize=8)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(out / "equal_time.png", dpi=130)
    return summary


def _budgeted(render_result, key: str):
    """``render_result`` whose ``spp`` argument sets parameter ``key`` instead (SPPM's
    passes), with one sample per pixel per pass."""
    if key == "spp":
        return render_result

    def call(scene, name, *, spp, seed, **params):
        return render_result(scene, name, spp=1, seed=seed, **{key: spp}, **params)

    return call


if __name__ == "__main__":
    main()
