"""The paper's pipeline: every number, table and figure in jgi.tex is written by a step here.

    python paper/pipeline.py [--scale small|full] [--only STEP ...] [--no-pdf]

Each step is a function ``step(scale, out) -> None`` that writes exactly the files it
declares in ``STEPS`` under ``paper/generated/``. ``tests/test_paper.py`` checks that every
file the LaTeX source includes is declared by some step, so no number is typed by hand.
The PDF is built with pdflatex when it is installed (Debian: texlive-latex-recommended).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
GEN = HERE / "generated"

SCALES = {  # image side, repetitions, spp multiplier
    "small": dict(res=16, reps=4, spp=1),
    "full": dict(res=64, reps=16, spp=8),
}


def _tex_num(x, digits=3):
    return f"{x:.{digits}g}"


def _write(path: Path, text: str):
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


# --- steps --------------------------------------------------------------------------------------

def furnace(scale, out: Path):
    """White furnace: measured radiance against L_e sum_k rho^k for several depths."""
    import jgi
    from jgi import scenes

    s = SCALES[scale]
    rows = []
    for rho in (0.3, 0.8):
        scene = scenes.furnace(resolution=s["res"], albedo=rho, emission=1.0)
        for depth in (1, 2, 4, 8):
            imgs = np.stack([jgi.render(scene, "pt", spp=4 * s["spp"], seed=r, max_depth=depth,
                                        rr_depth=-1)[..., 0].mean() for r in range(s["reps"])])
            expected = sum(rho**k for k in range(depth))
            se = imgs.std(ddof=1) / np.sqrt(len(imgs)) if len(imgs) > 1 else 0.0
            rows.append((rho, depth, expected, imgs.mean(), se))
    lines = [r"\begin{tabular}{rrrrr}", r"\toprule",
             r"$\rho$ & depth & closed form & measured & std.\ error \\", r"\midrule"]
    for rho, depth, e, m, se in rows:
        lines.append(f"{rho} & {depth} & {e:.5f} & {m:.5f} & {se:.1e} \\\\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    _write(out / "furnace_table.tex", "\n".join(lines) + "\n")
    worst = max(abs(m - e) / max(se, 1e-12) for _, _, e, m, se in rows)
    _write(out / "furnace_macros.tex", f"\\newcommand{{\\furnaceWorstZ}}{{{worst:.2f}}}\n")


def pt_convergence(scale, out: Path):
    """MSE of path tracing against spp on the Cornell box; log-log slope (theory: -1)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import jgi
    from jgi import fitting

    s = SCALES[scale]
    scene = jgi.scenes.cornell_box(resolution=s["res"])
    ref_spp = 256 * s["spp"]
    ref = jgi.render(scene, "pt", spp=ref_spp, seed=10_000)
    spps = [1, 2, 4, 8, 16, 32]
    mse = []
    for n in spps:
        errs = [np.mean((jgi.render(scene, "pt", spp=n, seed=r) - ref) ** 2) for r in range(s["reps"])]
        mse.append(np.mean(errs))
    # the reference's own variance adds a constant ~ mse(1)/ref_spp: subtract it
    mse = np.array(mse) - mse[0] / ref_spp
    slope, c, se = fitting.power_law(spps, mse)
    fig, ax = plt.subplots(figsize=(3.4, 2.5))
    ax.loglog(spps, mse, "o-", label=f"path tracing (slope {slope:.2f} $\\pm$ {se:.2f})")
    ax.loglog(spps, c * np.asarray(spps, float) ** -1.0, "k--", lw=0.8, label="$1/N$")
    ax.set_xlabel("samples per pixel $N$")
    ax.set_ylabel("MSE")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "pt_convergence.pdf")
    plt.close(fig)
    _write(out / "pt_convergence_macros.tex",
           f"\\newcommand{{\\ptSlope}}{{{slope:.3f}}}\n\\newcommand{{\\ptSlopeSE}}{{{se:.3f}}}\n")


def strategies(scale, out: Path):
    """Veach's plates under BSDF, light and MIS sampling at equal spp: images and rel. MSE."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import jgi
    from jgi.imageio import tonemap

    s = SCALES[scale]
    res = max(48, s["res"] * 3)
    scene = jgi.scenes.veach_plates(resolution=res)
    ref = jgi.render(scene, "pt", spp=128 * s["spp"], seed=999, strategy="mis", heuristic="power")
    configs = [("BSDF", dict(strategy="bsdf")), ("light", dict(strategy="light")),
               ("MIS balance", dict(strategy="mis")),
               ("MIS power", dict(strategy="mis", heuristic="power"))]
    fig, axes = plt.subplots(1, len(configs), figsize=(7, 2.0))
    rows = []
    for ax, (name, p) in zip(axes, configs):
        img = jgi.render(scene, "pt", spp=4 * s["spp"], seed=1, **p)
        rel = np.mean((img - ref) ** 2 / (ref**2 + 1e-2))
        rows.append((name, rel))
        ax.imshow(tonemap(img))
        ax.set_title(f"{name}\nrelMSE {rel:.3g}", fontsize=7)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out / "strategies.pdf")
    plt.close(fig)
    lines = [r"\begin{tabular}{lr}", r"\toprule", r"strategy & relative MSE \\", r"\midrule"]
    lines += [f"{n} & {r:.4g} \\\\" for n, r in rows]
    lines += [r"\bottomrule", r"\end{tabular}"]
    _write(out / "strategies_table.tex", "\n".join(lines) + "\n")


def performance(scale, out: Path):
    """Throughput against Mitsuba 3 on the same Cornell box, measured in the same run."""
    sys.path.insert(0, str(HERE.parent / "experiments"))
    import bench_pt

    spp = 4 if scale == "small" else 64
    res = 64 if scale == "small" else 256
    r = bench_pt.main(["--spp", str(spp), "--resolution", str(res), "--repeats", "2"])
    j = r["jgi"]
    m = r.get("mitsuba")
    text = (f"\\newcommand{{\\perfJgi}}{{{j['mpaths_per_s']:.2f}}}\n"
            f"\\newcommand{{\\perfCompile}}{{{j['compile_s']:.1f}}}\n"
            f"\\newcommand{{\\perfRes}}{{{res}}}\n")
    if m:
        text += (f"\\newcommand{{\\perfMitsuba}}{{{m['mpaths_per_s']:.2f}}}\n"
                 f"\\newcommand{{\\perfRatio}}{{{r['ratio']:.2f}}}\n")
    else:
        text += "\\newcommand{\\perfMitsuba}{n/a}\n\\newcommand{\\perfRatio}{n/a}\n"
    _write(out / "performance_macros.tex", text)


def density_fit(scale, out: Path):
    """MSE-optimal photon radius against photon count, and fitted filters (exact irradiance)."""
    sys.path.insert(0, str(HERE.parent / "experiments"))
    import fit_density

    args = (["--photons", "2500", "5000", "10000", "--reps", "4"] if scale == "small"
            else ["--reps", "16"])
    r = fit_density.main(["--out", str(out / "fit_density_run")] + args)
    shutil.copy(out / "fit_density_run" / "fit_density.png", out / "density_fit.png")
    f = r["filters"]
    macros = dict(dfRExp=f"{r['r_star_exponent']:.3f}", dfRExpSE=f"{r['r_star_exponent_se']:.3f}",
                  dfMseExp=f"{r['mse_exponent']:.3f}", dfMseExpSE=f"{r['mse_exponent_se']:.3f}",
                  dfPhotons=str(f["photons"]), dfRadius=f"{f['radius']:.3f}",
                  dfBox=f"{f['box']:.2e}", dfEpan=f"{f['epanechnikov']:.2e}",
                  dfConeK=f"{f['cone']['k']:.3f}", dfCone=f"{f['cone']['rel_mse']:.2e}",
                  dfJensen=f"{f['gaussian_jensen']['rel_mse']:.2e}",
                  dfJensenIntegral=f"{f['gaussian_jensen']['integral']:.3f}",
                  dfGaussAlpha=f"{f['gaussian_fitted']['alpha']:.3f}",
                  dfGaussBeta=f"{f['gaussian_fitted']['beta']:.3f}",
                  dfGauss=f"{f['gaussian_fitted']['rel_mse']:.2e}",
                  dfGaussIntegral=f"{f['gaussian_fitted']['integral']:.3f}", dfReps=str(r["repetitions"]),
                  dfPpmPasses=str(r["progressive"]["passes"]), dfPpmAlpha=f"{r['progressive']['alpha']:.3f}",
                  dfPpmMse=f"{r['progressive']['rel_mse']:.2e}",
                  dfPpmCurve=", ".join(f"{v:.2e} ($\\alpha={al:.2f}$)" for al, v in r["progressive"]["curve"][::6]))
    _write(out / "density_fit_macros.tex",
           "".join(f"\\newcommand{{\\{k}}}{{{v}}}\n" for k, v in macros.items()))


def equal_time(scale, out: Path):
    """Path tracing, BDPT and MLT at equal render time on the caustic Cornell box."""
    sys.path.insert(0, str(HERE.parent / "experiments"))
    import equal_time as et

    args = (["--res", "16", "--budget", "2", "--reps", "2", "--ref-spp", "1024"] if scale == "small"
            else ["--res", "64", "--budget", "30", "--reps", "4", "--ref-spp", "16384"])
    r = et.main(["--out", str(out / "equal_time_run")] + args)
    shutil.copy(out / "equal_time_run" / "equal_time.png", out / "equal_time.png")
    lines = [r"\begin{tabular}{lrrrr}", r"\toprule",
             r"estimator & spp & time (s) & relative MSE & acceptance \\", r"\midrule"]
    for row in r["rows"]:
        acc = "--" if row["acceptance"] is None else f"{row['acceptance']:.3f}"
        lines.append(f"{row['label']} & {row['spp']} & {row['seconds']:.1f} & {row['rel_mse']:.3g} & {acc} \\\\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    _write(out / "equal_time_table.tex", "\n".join(lines) + "\n")
    _write(out / "equal_time_macros.tex",
           f"\\newcommand{{\\etBudget}}{{{r['budget_s']:g}}}\n\\newcommand{{\\etRes}}{{{r['resolution']}}}\n"
           f"\\newcommand{{\\etRefSpp}}{{{r['reference_spp']}}}\n")


STEPS = {
    "furnace": (furnace, ["furnace_table.tex", "furnace_macros.tex"]),
    "pt_convergence": (pt_convergence, ["pt_convergence.pdf", "pt_convergence_macros.tex"]),
    "strategies": (strategies, ["strategies.pdf", "strategies_table.tex"]),
    "performance": (performance, ["performance_macros.tex"]),
    "density_fit": (density_fit, ["density_fit.png", "density_fit_macros.tex"]),
    "equal_time": (equal_time, ["equal_time.png", "equal_time_table.tex", "equal_time_macros.tex"]),
}


def declared_outputs() -> set[str]:
    return {f for _, files in STEPS.values() for f in files}


def build_pdf() -> Path | None:
    if shutil.which("pdflatex") is None:
        print("pdflatex not found: install Debian's texlive-latex-recommended to build the PDF",
              file=sys.stderr)
        return None
    for _ in range(2):
        subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "jgi.tex"],
                       cwd=HERE, check=True, stdout=subprocess.DEVNULL)
    return HERE / "jgi.pdf"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", choices=list(SCALES), default="small")
    ap.add_argument("--only", nargs="*", default=None, choices=list(STEPS))
    ap.add_argument("--no-pdf", action="store_true")
    a = ap.parse_args(argv)
    GEN.mkdir(exist_ok=True)
    log = {}
    for name in a.only or STEPS:
        fn, files = STEPS[name]
        t0 = time.perf_counter()
        print(f"[paper] {name} ...", file=sys.stderr, flush=True)
        fn(a.scale, GEN)
        missing = [f for f in files if not (GEN / f).exists()]
        if missing:
            raise RuntimeError(f"step {name} did not write {missing}")
        log[name] = round(time.perf_counter() - t0, 2)
    _write(GEN / "provenance.json", json.dumps({"scale": a.scale, "seconds": log}, indent=2))
    if not a.no_pdf:
        pdf = build_pdf()
        if pdf:
            print(f"wrote {pdf}")


if __name__ == "__main__":
    main()
