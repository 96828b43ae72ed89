"""A study's outputs: log-log plots of MSE, bias^2 and variance with fitted slopes and their
intervals, MSE against render time, and the grid of error maps."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from ..analysis.stats import fit_error_slope
from ..core.imageio import tonemap


def slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "-" for c in text)


def _numeric(values) -> bool:
    return len(values) >= 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                    and x > 0 for x in values)


def plots(out: Path, rows, doc) -> list[dict]:
    """Log-log MSE / bias^2 / variance against each numeric swept key (one curve per label and
    setting of the other swept keys) and MSE against render time; returns the fitted slopes."""
    matplotlib.use("Agg")

    swept_all = {k for e in doc["estimator"] for k in e.get("sweep", {})}
    numeric = sorted(k for k in swept_all
                     if _numeric([x for e in doc["estimator"]
                                  for x in e.get("sweep", {}).get(k, [])]))
    slopes = []
    for key in numeric:
        fig, ax = plt.subplots(figsize=(5, 3.6))
        curves = {}
        for r in rows:
            if key not in r:
                continue
            fixed = tuple(sorted((k, r[k]) for k in swept_all if k != key and k in r))
            curves.setdefault((r["label"], fixed), []).append(r)
        for n, ((label, fixed), rs) in enumerate(sorted(curves.items(), key=lambda kv: str(kv[0]))):
            rs = sorted(rs, key=lambda r: r[key])
            if len(rs) < 2:
                continue
            x = np.array([r[key] for r in rs], float)
            mse, b2, var = (np.array([r[m] for r in rs]) for m in ("mse", "bias2", "variance"))
            name = label + ("" if not fixed else " " + ", ".join(f"{k}={v}" for k, v in fixed))
            colour = f"C{n % 10}"
            ok = mse > 0
            text = ""
            se = {m: np.array([r[m + "_se"] for r in rs]) for m in ("mse", "bias2", "variance")}
            if ok.sum() >= 2:
                fit = fit_error_slope(x[ok], mse[ok], se["mse"][ok])
                entry = dict(label=label, key=key, fixed=dict(fixed), slope=fit.slope,
                             stderr=fit.stderr, lo=fit.lo, hi=fit.hi, confidence=fit.confidence)
                # the two parts of the MSE on their own (a consistent estimator's bias^2 and
                # variance fall at different rates), where every point estimates a positive one
                for part, y in (("bias2", b2), ("variance", var)):
                    if np.all(y > 0):
                        f = fit_error_slope(x, y, se[part])
                        entry.update({f"{part}_slope": f.slope, f"{part}_stderr": f.stderr,
                                      f"{part}_lo": f.lo, f"{part}_hi": f.hi})
                slopes.append(entry)
                text = f" (slope {fit.slope:.2f} [{fit.lo:.2f}, {fit.hi:.2f}])"
            bars = 1.959963984540054 * se["mse"][ok]
            ax.errorbar(x[ok], mse[ok], yerr=np.stack([np.minimum(bars, 0.999 * mse[ok]), bars]),
                        fmt="o-", color=colour, capsize=2, label=f"{name} MSE{text}")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.loglog(x[var > 0], var[var > 0], ":", color=colour, label=f"{name} variance")
            ax.loglog(x[b2 > 0], b2[b2 > 0], "--", color=colour, label=f"{name} bias²")
        ax.set_xlabel(key)
        ax.set_ylabel("image-average error")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=5)
        fig.tight_layout()
        fig.savefig(out / f"mse_vs_{key}.png", dpi=130)
        plt.close(fig)
    # MSE against render time: equal-time comparisons read off vertically.
    fig, ax = plt.subplots(figsize=(5, 3.6))
    for n, label in enumerate(dict.fromkeys(r["label"] for r in rows)):
        rs = sorted((r for r in rows if r["label"] == label and r["mse"] > 0),
                    key=lambda r: r["seconds"])
        if rs:
            ax.loglog([r["seconds"] for r in rs], [r["mse"] for r in rs], "o-",
                      color=f"C{n % 10}", label=label)
    ax.set_xlabel("render time per image (s)")
    ax.set_ylabel("MSE")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out / "mse_vs_time.png", dpi=130)
    plt.close(fig)
    return slopes


def error_maps(out: Path, means, ref, max_rows: int = 12):
    """An image grid like the lecture's comparisons: per configuration the mean image with a
    magnified crop, the false-colour per-pixel MSE and variance (shared colour scales)."""
    matplotlib.use("Agg")

    means = means[:max_rows]
    h, w = ref.shape[:2]
    cy, cx, ch, cw = h // 2, w // 2, max(h // 4, 1), max(w // 4, 1)  # centre crop
    lum = lambda a: a.mean(-1)  # noqa: E731
    mse_max = max(float(np.percentile(lum(np.maximum(s.mse, 0)), 99)) for _, s in means) or 1.0
    var_max = max(float(np.percentile(lum(s.variance), 99)) for _, s in means) or 1.0
    fig, axes = plt.subplots(len(means) + 1, 4, figsize=(8, 2 * (len(means) + 1)), squeeze=False)
    panels = [("reference", ref, None)] + [(r["label"] + " " + ", ".join(
        f"{k}={v}" for k, v in r.items()
        if k in ("spp", "photons", "radius", "k", "passes", "radius_alpha")), s.mean, s)
        for r, s in means]
    for row, (title, img, s) in zip(axes, panels):
        row[0].imshow(tonemap(img))
        row[0].set_title(title, fontsize=6)
        row[1].imshow(tonemap(img[cy - ch // 2: cy + ch, cx - cw // 2: cx + cw]),
                      interpolation="nearest")
        row[1].set_title("crop", fontsize=6)
        if s is not None:
            im = row[2].imshow(lum(np.maximum(s.mse, 0)), cmap="inferno", vmin=0, vmax=mse_max)
            row[2].set_title("per-pixel MSE", fontsize=6)
            im2 = row[3].imshow(lum(s.variance), cmap="viridis", vmin=0, vmax=var_max)
            row[3].set_title("per-pixel variance", fontsize=6)
        for a in row:
            a.axis("off")
    fig.colorbar(im, ax=axes[:, 2], shrink=0.3)
    fig.colorbar(im2, ax=axes[:, 3], shrink=0.3)
    fig.savefig(out / "error_maps.png", dpi=130)
    plt.close(fig)
