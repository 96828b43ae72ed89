"""The paper's pipeline: every number, table and figure in jgi.tex is written by a step here.

    python -m paper.pipeline [--scale small|full] [--only STEP ...] [--no-pdf]

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


def _tex_sci(x, digits=2):
    """x in LaTeX scientific notation (math mode), e.g. $3.3\times10^{-4}$."""
    if x == 0:
        return "$0$"
    m, e = f"{x:.{digits - 1}e}".split("e")
    return f"${m}\\times10^{{{int(e)}}}$"


def _write(path: Path, text: str):
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


# --- steps --------------------------------------------------------------------------------------

def furnace(scale, out: Path):
    """White furnace: measured radiance against L_e sum_k rho^k for several depths."""
    import jgi
    from jgi.scene import builtin as scenes

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
    from jgi.analysis import fitting

    s = SCALES[scale]
    scene = jgi.scenes.cornell_box(resolution=s["res"])
    ref_spp = 256 * s["spp"]
    ref = jgi.render(scene, "pt", spp=ref_spp, seed=10_000)
    spps = [1, 2, 4, 8, 16, 32]
    mse = []
    for n in spps:
        errs = [np.mean((jgi.render(scene, "pt", spp=n, seed=r) - ref) ** 2)
                for r in range(s["reps"])]
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
    """Veach's plates (GGX rough conductors, as in Mitsuba's documentation) under BSDF, light
    and MIS (balance, power) sampling at equal spp: images and rel. MSE."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import jgi
    from jgi.core.imageio import tonemap

    s = SCALES[scale]
    res = max(48, s["res"] * 3)
    scene = jgi.scenes.veach_plates_ggx(resolution=res)
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
    from experiments.bench import pt as bench_pt

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
    from experiments.studies import fit_density

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
                  dfGaussAlpha=f"{f['gaussian_fitted']['gauss_alpha']:.3f}",
                  dfGaussBeta=f"{f['gaussian_fitted']['gauss_beta']:.3f}",
                  dfGauss=f"{f['gaussian_fitted']['rel_mse']:.2e}",
                  dfGaussIntegral=f"{f['gaussian_fitted']['integral']:.3f}",
                  dfReps=str(r["repetitions"]),
                  dfPpmPasses=str(r["progressive"]["passes"]),
                  dfPpmAlpha=f"{r['progressive']['radius_alpha']:.3f}",
                  dfPpmMse=f"{r['progressive']['rel_mse']:.2e}",
                  dfPpmCurve=", ".join(f"{v:.2e} ($\\alpha={al:.2f}$)"
                                       for al, v in r["progressive"]["curve"][::6]))
    _write(out / "density_fit_macros.tex",
           "".join(f"\\newcommand{{\\{k}}}{{{v}}}\n" for k, v in macros.items()))


def equal_time(scale, out: Path):
    """Path tracing, BDPT and MLT at equal render time on the caustic Cornell box."""
    from experiments.studies import equal_time as study

    # the reference needs many more paths than the fastest estimator traces in the budget (the
    # path tracer: ~28k spp at 16^2 in 2 s), else its variance dominates the error estimate
    args = (["--res", "16", "--budget", "2", "--reps", "2", "--ref-spp", "262144"]
            if scale == "small"
            else ["--res", "64", "--budget", "30", "--reps", "4", "--ref-spp", "262144"])
    r = study.main(["--out", str(out / "equal_time_run")] + args)
    shutil.copy(out / "equal_time_run" / "equal_time.png", out / "equal_time.png")
    lines = [r"\begin{tabular}{lrrrrr}", r"\toprule",
             r"estimator & spp & time (s) & relative MSE & acceptance & lens / caustic \\",
             r"\midrule"]
    for row in r["rows"]:
        acc = "--" if row["acceptance"] is None else f"{row['acceptance']:.3f}"
        per_kind = (f"{row['lens_acceptance']:.2f} / {row['caustic_acceptance']:.2f}"
                    if "lens_acceptance" in row else "--")
        lines.append(f"{row['label']} & {row['spp']} & {row['seconds']:.1f} & "
                     f"{row['rel_mse']:.3g} & {acc}"
                     f" & {per_kind} \\\\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    _write(out / "equal_time_table.tex", "\n".join(lines) + "\n")
    _write(out / "equal_time_macros.tex",
           f"\\newcommand{{\\etBudget}}{{{r['budget_s']:g}}}\n\\newcommand{{\\etRes}}{{{r['resolution']}}}\n"
           f"\\newcommand{{\\etRefSpp}}{{{r['reference_spp']}}}\n")


def vcm_equal_time(scale, out: Path):
    """Path tracing, BDPT, SPPM and VCM at equal time, on the caustic Cornell box with its
    area light and with a point light (references: path tracing, and VCM for the point light,
    whose caustics seen in the spheres no unbiased technique samples)."""
    from experiments.studies import equal_time as study

    small = scale == "small"
    base = (["--res", "16", "--budget", "2", "--reps", "2"] if small
            else ["--res", "64", "--budget", "30", "--reps", "4"])
    runs = {"area": study.main(["--set", "vcm", "--out", str(out / "vcm_equal_time_area"),
                                "--ref-spp", "65536" if small else "262144"] + base),
            "point": study.main(["--set", "vcm", "--scene", "cornell_box_caustics_point",
                                 "--ref", "vcm", "--ref-spp", "2048" if small else "4096",
                                 "--out", str(out / "vcm_equal_time_point")] + base)}
    lines = [r"\begin{tabular}{llrrr}", r"\toprule",
             r"light & estimator & samples & time (s) & relative MSE \\", r"\midrule"]
    for light, r in runs.items():
        for row in r["rows"]:
            n = f"{row['spp']} {'passes' if row['budget_key'] == 'passes' else 'spp'}"
            lines.append(f"{light} & {row['label']} & {n} & {row['seconds']:.1f} & "
                         f"{_tex_sci(row['rel_mse'])} \\\\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    _write(out / "vcm_equal_time_table.tex", "\n".join(lines) + "\n")
    a, p = runs["area"], runs["point"]
    _write(out / "vcm_equal_time_macros.tex",
           f"\\newcommand{{\\vcmEtBudget}}{{{a['budget_s']:g}}}\n"
           f"\\newcommand{{\\vcmEtRes}}{{{a['resolution']}}}\n"
           f"\\newcommand{{\\vcmEtRefSpp}}{{{a['reference_spp']}}}\n"
           f"\\newcommand{{\\vcmEtRefIterations}}{{{p['reference_spp']}}}\n")


def chi2(scale, out: Path):
    """Chi-square goodness of fit of every sampling routine (the test suite's cases), tabulated."""
    from paper import chi2_table

    n = 1 << 18 if scale == "small" else 1 << 20
    r = chi2_table.main(["--samples", str(n), "--out", str(out / "chi2_run")])
    lines = [r"\begin{tabular}{llrrrrrl}", r"\toprule",
             r"& routine & samples & bins & $\chi^2$ & dof & $p$ & \\", r"\midrule"]
    group = None
    for row in r["rows"]:
        if group is not None and row["group"] != group:
            lines.append(r"\midrule")
        g = row["group"] if row["group"] != group else ""
        group = row["group"]
        lines.append(f"{g} & {row['routine']} & {row['samples']} & {row['cells']} & "
                     f"{row['statistic']:.1f} & {row['dof']} & {row['p_value']:.3g} & "
                     f"{'pass' if row['passed'] else 'FAIL'} \\\\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    _write(out / "chi2_table.tex", "\n".join(lines) + "\n")
    p = r["worst_p"]
    macros = dict(chiRoutines=str(len(r["rows"])), chiSamples=str(r["samples"]),
                  chiAlpha=f"{r['alpha']:g}", chiLevel=_tex_sci(r["level"]),
                  chiWorstP=f"{p:.2g}" if p >= 1e-3 else _tex_sci(p),
                  chiFailures=str(r["failures"]),
                  chiMirrorAngle=_tex_sci(r["mirror_max_angle"]), chiSeconds=f"{r['seconds']:.0f}")
    _write(out / "chi2_macros.tex",
           "".join(f"\\newcommand{{\\{k}}}{{{v}}}\n" for k, v in macros.items()))


AGREEMENT = [  # label, registry name, parameters, unbiased?  (every path has <= 5 segments)
    ("PT, BSDF", "pt", dict(strategy="bsdf", max_depth=5), True),
    ("PT, light", "pt", dict(strategy="light", max_depth=5), True),
    ("PT, MIS balance", "pt", dict(strategy="mis", heuristic="balance", max_depth=5), True),
    ("PT, MIS power", "pt", dict(strategy="mis", heuristic="power", max_depth=5), True),
    ("light tracing", "lt", dict(max_depth=5), True),
    ("BDPT, power", "bdpt", dict(max_depth=5), True),
    ("PSSMLT", "pssmlt", dict(max_depth=5), True),
    ("Veach MLT", "mlt", dict(max_depth=5), True),
    # photon bounces 0..3 before storage, plus the camera segment: paths of <= 5 segments
    ("photon mapping", "pm", dict(max_bounces=4, photons=50_000, radius=0.05), False),
]
AGREEMENT_SPP = {"pm": 0.25}  # fraction of the common spp (pm's cost is its photon queries)
AGREEMENT_REFERENCE = "PT, MIS balance"


def agreement(scale, out: Path):
    """Cornell box: image-mean luminance of each estimator over independent repetitions, and its
    z-score against PT with MIS (balance heuristic)."""
    import jgi

    s = SCALES[scale]
    reps = 2 * s["reps"]
    spp = 64 if scale == "small" else 256
    scene = jgi.scenes.cornell_box(resolution=s["res"])
    lum = np.array([0.2126, 0.7152, 0.0722])
    stats = {}
    for k, (label, name, params, _) in enumerate(AGREEMENT):
        t0 = time.perf_counter()
        # independent seeds per estimator (equal seeds share camera streams: correlated means)
        n = max(1, int(spp * AGREEMENT_SPP.get(name, 1)))
        rgb = np.stack([jgi.render(scene, name, spp=n, seed=1000 * (k + 1) + r, **params)
                        .astype(np.float64).mean((0, 1)) for r in range(reps)])
        stats[label] = dict(mean=rgb.mean(0), se=rgb.std(0, ddof=1) / np.sqrt(reps),
                            lum=rgb @ lum, seconds=time.perf_counter() - t0)
        stats[label]["lum_mean"] = stats[label]["lum"].mean()
        stats[label]["lum_se"] = stats[label]["lum"].std(ddof=1) / np.sqrt(reps)
        print(f"[agreement] {label}: {stats[label]['lum_mean']:.5f} "
              f"+- {stats[label]['lum_se']:.5f} "
              f"({stats[label]['seconds']:.1f} s)", file=sys.stderr, flush=True)
    ref = stats[AGREEMENT_REFERENCE]
    lines = [r"\begin{tabular}{lrrrr}", r"\toprule",
             r"estimator & $\bar Y$ & s.e. & $z$ & $\max|z_c|$ \\", r"\midrule"]
    worst, worst_biased, worst_label = 0.0, 0.0, ""
    for label, _, _, unbiased in AGREEMENT:
        st = stats[label]
        if label == AGREEMENT_REFERENCE:
            z, zc = "--", "--"
        else:
            zl = (st["lum_mean"] - ref["lum_mean"]) / np.hypot(st["lum_se"], ref["lum_se"])
            zrgb = np.max(np.abs((st["mean"] - ref["mean"]) / np.hypot(st["se"], ref["se"])))
            z, zc = f"{zl:+.2f}", f"{zrgb:.2f}"
            m = max(abs(zl), zrgb)
            if unbiased and m > worst:
                worst, worst_label = m, label
            else:
                worst_biased = max(worst_biased, m)
        mark = "" if unbiased else r"$^\dagger$"
        lines.append(f"{label}{mark} & {st['lum_mean']:.4f} & {st['lum_se']:.1e} & {z} & {zc} \\\\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    _write(out / "agreement_table.tex", "\n".join(lines) + "\n")
    _write(out / "agreement_macros.tex",
           f"\\newcommand{{\\agRes}}{{{s['res']}}}\n\\newcommand{{\\agReps}}{{{reps}}}\n"
           f"\\newcommand{{\\agSpp}}{{{spp}}}\n\\newcommand{{\\agWorstZ}}{{{worst:.2f}}}\n"
           f"\\newcommand{{\\agBiasedZ}}{{{worst_biased:.2f}}}\n"
           f"\\newcommand{{\\agWorstLabel}}{{{worst_label}}}\n"
           f"\\newcommand{{\\agEstimators}}{{{sum(u for *_, u in AGREEMENT) - 1}}}\n")


def bdpt_pyramid(scale, out: Path):
    """Veach's pyramid (thesis fig. 10.3): BDPT's MIS-weighted image of every (s, t) strategy,
    one row per path length, on the Cornell box with a mirror and a glass sphere."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import jgi
    from jgi.core.imageio import tonemap
    from jgi.estimators.bdpt import BDPTConfig, render_strategies

    res, spp = (48, 64) if scale == "small" else (128, 1024)
    max_depth = 4
    scene = jgi.scenes.cornell_box_caustics(resolution=res)
    imgs = render_strategies(scene, BDPTConfig(max_depth=max_depth, heuristic="power"), spp=spp,
                             seed=5)
    full = sum(w for _, w in imgs.values())
    cols = max_depth + 1                       # row L holds s = 0 .. L (t = L + 1 - s)
    size, pad, top, left = 1.0, 0.08, 0.22, 0.25   # inches
    fig = plt.figure(figsize=(left + cols * (size + pad) + pad,
                              max_depth * (size + top) + top + size + 0.1))
    W_in, H_in = fig.get_size_inches()
    for L in range(1, max_depth + 1):
        y = H_in - L * (size + top)
        x0 = left + pad + 0.5 * (cols - (L + 1)) * (size + pad)   # rows centred: a pyramid
        for s_ in range(L + 1):
            t = L + 1 - s_
            ax = fig.add_axes([(x0 + s_ * (size + pad)) / W_in, y / H_in, size / W_in, size / H_in])
            ax.set_xticks([])
            ax.set_yticks([])
            if (s_, t) in imgs:
                ax.imshow(tonemap(imgs[(s_, t)][1]), interpolation="nearest")
            else:                              # (1, 1): a light seen directly is s = 0's
                ax.set_facecolor("0.85")
                ax.text(0.5, 0.5, "unused", ha="center", va="center", fontsize=6)
            ax.set_title(f"$s={s_},\\ t={t}$", fontsize=6, pad=2)
        fig.text(0.05 / W_in, (y + 0.5 * size) / H_in, f"$L={L}$", fontsize=7, rotation=90,
                 va="center")
    ax = fig.add_axes([(left + pad + 0.5 * (cols - 1) * (size + pad)) / W_in, 0.05 / H_in,
                       size / W_in, size / H_in])
    ax.imshow(tonemap(full), interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title("sum (BDPT)", fontsize=6, pad=2)
    fig.savefig(out / "bdpt_pyramid.png", dpi=200)
    plt.close(fig)
    _write(out / "bdpt_pyramid_macros.tex",
           f"\\newcommand{{\\pyrRes}}{{{res}}}\n\\newcommand{{\\pyrSpp}}{{{spp}}}\n"
           f"\\newcommand{{\\pyrDepth}}{{{max_depth}}}\n")


STEPS = {
    "furnace": (furnace, ["furnace_table.tex", "furnace_macros.tex"]),
    "pt_convergence": (pt_convergence, ["pt_convergence.pdf", "pt_convergence_macros.tex"]),
    "strategies": (strategies, ["strategies.pdf", "strategies_table.tex"]),
    "performance": (performance, ["performance_macros.tex"]),
    "density_fit": (density_fit, ["density_fit.png", "density_fit_macros.tex"]),
    "equal_time": (equal_time, ["equal_time.png", "equal_time_table.tex", "equal_time_macros.tex"]),
    "vcm_equal_time": (vcm_equal_time, ["vcm_equal_time_table.tex", "vcm_equal_time_macros.tex"]),
    "chi2": (chi2, ["chi2_table.tex", "chi2_macros.tex"]),
    "agreement": (agreement, ["agreement_table.tex", "agreement_macros.tex"]),
    "bdpt_pyramid": (bdpt_pyramid, ["bdpt_pyramid.png", "bdpt_pyramid_macros.tex"]),
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
    prov = GEN / "provenance.json"
    if a.only and prov.exists():  # --only: keep the other steps' record from the same scale
        old = json.loads(prov.read_text())
        if old.get("scale") == a.scale:
            log = {**old.get("seconds", {}), **log}
    _write(prov, json.dumps({"scale": a.scale, "seconds": log}, indent=2))
    if not a.no_pdf:
        pdf = build_pdf()
        if pdf:
            print(f"wrote {pdf}")


if __name__ == "__main__":
    main()
