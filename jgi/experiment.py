"""Experiments from TOML config files: sweeps, repetitions, references, metrics, plots, resume.

    jgi run configs/NAME.toml [--dry-run] [--out runs]

```toml
[experiment]
name = "pt_strategies"        # output folder runs/NAME/
scene = "cornell_box"         # built-in name or scene file (relative to the config)
resolution = 32               # optional film size override
repetitions = 4               # independent seeds per configuration
seed = 0                      # base seed; every (estimator, sweep point, repetition) derives
                              # its own independent one from it (see plan)
# nested_seeds = true: the sweep points of an estimator share a repetition's seed (an spp = 16
#     render then contains the spp = 8 one's samples: correlated points, on purpose)
reference = { estimator = "pt", spp = 512, params = { strategy = "mis" } }
# or: reference = { closed_form = 1.5 }   (a constant image, e.g. a furnace), or the name of
#     a built-in scene with an exact image (jgi.analysis.closed_form.IMAGES: "mirror_sds")
# match = ["path_length"]: one reference per value of these swept keys, rendered with it

[[estimator]]
name = "pt"                   # a registered estimator (jgi render --list)
label = "MIS"                 # optional
spp = 4                       # or a list in sweep.spp
params = { strategy = "mis" }
sweep = { spp = [1, 2, 4, 8] }   # lists; the cartesian product of all keys is run
```
Every key and value is checked before any rendering (an error names the file and the key path).
Each (estimator, sweep point, repetition) is written atomically to ``results/<hash>.npz``
(the hash covers everything that determines the image), so an interrupted run resumes
without recomputing; ``--dry-run`` prints the plan. Outputs: ``config.toml`` (as run),
``provenance.json``, ``metrics.csv`` / ``metrics.json`` (jgi.analysis.stats per sweep point), EXR
means, and log-log plots of MSE, bias^2 and variance against each numeric swept parameter.
"""

from __future__ import annotations

import argparse
import copy
import csv
import hashlib
import itertools
import json
import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import jax
import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from . import __version__
from .analysis import closed_form, stats
from .analysis.stats import fit_error_slope
from .api import render as render_image
from .core.errors import ParameterError
from .core.imageio import tonemap, write_exr
from .estimators.registry import get
from .scene.files import load_scene

EXPERIMENT_KEYS = {"name", "scene", "resolution", "repetitions", "seed", "reference",
                   "nested_seeds"}
ESTIMATOR_KEYS = {"name", "label", "spp", "params", "sweep"}


class ConfigError(ValueError):
    """A bad experiment config: the message names the file and the key path."""


def _fail(path, key, msg):
    raise ConfigError(f"{path}: {key}: {msg}")


def load_config(path) -> dict:
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as e:
        raise ConfigError(f"{path}: cannot read: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: TOML syntax error: {e}") from None
    unknown = sorted(set(doc) - {"experiment", "estimator"})
    if unknown:
        _fail(path, unknown[0], "unknown table; allowed: experiment, estimator")
    exp = doc.get("experiment")
    if not isinstance(exp, dict):
        _fail(path, "experiment", "missing [experiment] table")
    bad = sorted(set(exp) - EXPERIMENT_KEYS)
    if bad:
        _fail(path, f"experiment.{bad[0]}",
              f"unknown key; allowed: {', '.join(sorted(EXPERIMENT_KEYS))}")
    for key in ("name", "scene"):
        if not isinstance(exp.get(key), str) or not exp.get(key):
            _fail(path, f"experiment.{key}", "required, a non-empty string")
    for key, lo in (("repetitions", 2), ("seed", 0), ("resolution", 1)):
        if key in exp and (isinstance(exp[key], bool) or not isinstance(exp[key], int)
                           or exp[key] < lo):
            _fail(path, f"experiment.{key}", f"must be an integer >= {lo}, got {exp[key]!r}")
    if not isinstance(exp.get("nested_seeds", False), bool):
        _fail(path, "experiment.nested_seeds", f"must be true or false, got "
                                               f"{exp['nested_seeds']!r}")
    ref = exp.get("reference")
    if not isinstance(ref, dict) or not ({"estimator", "spp"} <= set(ref) or "closed_form" in ref):
        _fail(path, "experiment.reference",
              "required: { estimator, spp, params } or { closed_form }")
    if "closed_form" in ref:
        cf = ref["closed_form"]
        if isinstance(cf, str):
            if cf not in closed_form.IMAGES:
                _fail(path, "experiment.reference.closed_form",
                      f"unknown closed form {cf!r}; allowed: {', '.join(closed_form.IMAGES)} "
                      "(or a number, or [r, g, b])")
            if cf != exp.get("scene"):
                _fail(path, "experiment.reference.closed_form",
                      f"the closed form {cf!r} is the image of the built-in scene {cf!r}, not "
                      f"of {exp.get('scene')!r}")
        if set(ref) != {"closed_form"} or not isinstance(cf, (int, float, list, str)):
            _fail(path, "experiment.reference.closed_form",
                  "a number, [r, g, b] or a built-in scene's name, alone")
    else:
        bad = sorted(set(ref) - {"estimator", "spp", "params", "match"})
        if bad:
            _fail(path, f"experiment.reference.{bad[0]}",
                  "unknown key; allowed: estimator, spp, params, match")
        match = ref.get("match", [])
        if not isinstance(match, list) or not all(isinstance(k, str) for k in match):
            _fail(path, "experiment.reference.match", "a list of swept parameter names")
        _check_estimator(path, "experiment.reference", ref["estimator"], ref.get("params", {}))
    ests = doc.get("estimator")
    if not isinstance(ests, list) or not ests:
        _fail(path, "estimator", "at least one [[estimator]] table is required")
    for i, e in enumerate(ests):
        key = f"estimator[{i}]"
        bad = sorted(set(e) - ESTIMATOR_KEYS)
        if bad:
            _fail(path, f"{key}.{bad[0]}",
                  f"unknown key; allowed: {', '.join(sorted(ESTIMATOR_KEYS))}")
        if "name" not in e:
            _fail(path, f"{key}.name", "required")
        sweep = e.get("sweep", {})
        if not isinstance(sweep, dict):
            _fail(path, f"{key}.sweep", "a table of lists")
        for k, v in sweep.items():
            if not isinstance(v, list) or not v:
                _fail(path, f"{key}.sweep.{k}", "must be a non-empty list")
        if "spp" not in e and "spp" not in sweep:
            _fail(path, f"{key}.spp", "required (or sweep.spp)")
        for point in _points(e):
            params = {k: v for k, v in point.items() if k != "spp"}
            _check_estimator(path, key, e["name"], params)
            if "match" in ref:
                missing = [k for k in ref["match"] if k not in point]
                if missing:
                    _fail(path, "experiment.reference.match",
                          f"{missing[0]!r} is not a parameter of {key}")
                _check_estimator(path, "experiment.reference.match", ref["estimator"],
                                 {**ref.get("params", {}), **{k: point[k] for k in ref["match"]}})
            spp = point["spp"]
            if isinstance(spp, bool) or not isinstance(spp, int) or spp < 1:
                _fail(path, f"{key}.spp", f"must be a positive integer, got {spp!r}")
    return doc


def _check_estimator(path, key, name, params):
    try:
        get(name).resolve(params)
    except ParameterError as err:
        _fail(path, key, str(err))


def _points(e: dict):
    base = dict(e.get("params", {}))
    if "spp" in e:
        base["spp"] = e["spp"]
    sweep = e.get("sweep", {})
    keys = sorted(sweep)
    for values in itertools.product(*(sweep[k] for k in keys)):
        yield {**base, **dict(zip(keys, values))}


def _hash(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def run_seed(base: int, estimator: int, point: int, rep: int, nested: bool = False) -> int:
    """The seed of one render: independent streams for every (estimator, sweep point,
    repetition), drawn from ``base`` by numpy's SeedSequence (so no two renders of a study
    share samples and the errors of its sweep points are independent, as the slope fits
    assume); ``nested``: the points of an estimator share a repetition's seed."""
    key = (estimator, rep) if nested else (estimator, point, rep)
    return int(np.random.SeedSequence(base, spawn_key=key).generate_state(1)[0] >> 1)


def plan(doc: dict):
    exp = doc["experiment"]
    reps = exp.get("repetitions", 4)
    nested = exp.get("nested_seeds", False)
    runs = []
    for i, e in enumerate(doc["estimator"]):
        for j, point in enumerate(_points(e)):
            for r in range(reps):
                runs.append(dict(index=i, name=e["name"], label=e.get("label", e["name"]),
                                 point=point, rep=r,
                                 seed=run_seed(exp.get("seed", 0), i, j, r, nested)))
    return runs


# Reduced sizes for smoke runs (the test suite runs every bundled config this way).
SMOKE_RESOLUTION = 8
SMOKE_MAX = dict(spp=4, photons=20_000, caustic_photons=5_000, passes=2, chains=256,
                 bootstrap_samples=4096, final_gather=4, k=50, k_caustic=50, max_depth=3)


def smoke(doc: dict) -> dict:
    """The same study at a tiny size: resolution 8, two repetitions, at most two values per
    sweep key, and sample / photon counts capped by ``SMOKE_MAX`` (the structure, outputs and
    code paths are those of the full run)."""

    doc = copy.deepcopy(doc)
    exp = doc["experiment"]
    exp["resolution"] = min(exp.get("resolution", SMOKE_RESOLUTION), SMOKE_RESOLUTION)
    exp["repetitions"] = 2
    exp["name"] = exp["name"] + "-smoke"

    def cap(params):
        return {k: (min(v, SMOKE_MAX[k]) if k in SMOKE_MAX and isinstance(v, int)
                    and not isinstance(v, bool) else v)
                for k, v in params.items()}

    ref = exp["reference"]
    if "spp" in ref:
        ref["spp"] = min(ref["spp"], 16)
        ref["params"] = cap(ref.get("params", {}))
    for e in doc["estimator"]:
        if "spp" in e:
            e["spp"] = min(e["spp"], SMOKE_MAX["spp"])
        e["params"] = cap(e.get("params", {}))
        sweep = {}
        for k, v in e.get("sweep", {}).items():
            vals = [cap({k: x})[k] for x in v[:2]]
            sweep[k] = list(dict.fromkeys(vals))  # capping may merge values
        e["sweep"] = sweep
    return doc


def _scene(doc, config_path):
    exp = doc["experiment"]
    src = exp["scene"]
    if not src.endswith((".toml", ".xml", ".pbrt")):
        scene = load_scene(src)
        scene_id = src
    else:
        p = (Path(config_path).parent / src).resolve()
        scene = load_scene(p)
        scene_id = hashlib.sha256(p.read_bytes()).hexdigest()
    if "resolution" in exp:
        scene = scene.with_resolution(exp["resolution"], exp["resolution"])
    return scene, scene_id


def _atomic_save(path: Path, **arrays):
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def run(config_path, *, out_root="runs", dry_run: bool = False, reduced: bool = False,
        render=None, progress=True) -> Path:
    """Run (or resume) an experiment; returns its output folder. ``reduced`` runs the
    :func:`smoke` version (into ``runs/NAME-smoke``). ``render`` defaults to :func:`jgi.render`
    (tests pass a counting wrapper)."""

    render = render or render_image
    doc = load_config(config_path)
    if reduced:
        doc = smoke(doc)
    exp = doc["experiment"]
    runs = plan(doc)
    out = Path(out_root) / exp["name"]
    if dry_run:
        total = sum(r["point"]["spp"] for r in runs)
        print(f"{exp['name']}: {len(runs)} renders ({len(doc['estimator'])} estimators, "
              f"{exp.get('repetitions', 4)} repetitions), {total} samples per pixel in total "
              f"-> {out}/")
        for r in runs[: 50]:
            print(f"  {r['label']:16s} {r['point']} rep {r['rep']} seed {r['seed']}")
        return out
    (out / "results").mkdir(parents=True, exist_ok=True)
    (out / "config.toml").write_text(Path(config_path).read_text())
    (out / "config_as_run.json").write_text(json.dumps(doc, indent=2))
    scene, scene_id = _scene(doc, config_path)
    t_start = time.perf_counter()
    references = {}

    def reference_for(point):
        """(image, variance) of the reference for a sweep point, rendered once per matched
        value and cached across runs by content hash (its variance from two independent halves)."""
        cfg = exp["reference"]
        matched = {k: point[k] for k in cfg.get("match", [])}
        rkey = json.dumps(matched, sort_keys=True)
        if rkey in references:
            return references[rkey]
        if "closed_form" in cfg:
            cf = cfg["closed_form"]
            img = (closed_form.IMAGES[cf](scene) if isinstance(cf, str) else
                   np.broadcast_to(np.asarray(cf, np.float32),
                                   (scene.camera.height, scene.camera.width, 3)).copy())
            references[rkey] = (img, np.zeros_like(img))
            return references[rkey]
        params = {**cfg.get("params", {}), **matched}
        key = _hash(dict(scene=scene_id, res=exp.get("resolution"), est=cfg["estimator"],
                         spp=cfg["spp"], params=params, v=__version__))
        cache = Path(out_root) / ".cache" / f"reference-{key}.npz"
        if cache.exists():
            with np.load(cache) as z:
                references[rkey] = (z["image"], z["variance"])
        else:
            cache.parent.mkdir(parents=True, exist_ok=True)
            halves = [render(scene, cfg["estimator"], spp=max(1, cfg["spp"] // 2),
                             seed=900_001 + h, **params)
                      for h in range(2)]
            img = 0.5 * (halves[0] + halves[1])
            var = 0.25 * (halves[0] - halves[1]) ** 2  # variance of the mean of two halves
            _atomic_save(cache, image=img, variance=var)
            references[rkey] = (img, var)
        suffix = "" if not matched else "_" + "_".join(f"{k}{v}" for k, v in matched.items())
        write_exr(out / f"reference{suffix}.exr", references[rkey][0])
        return references[rkey]

    for r in runs:  # references first: a long render should not wait for the sweep
        reference_for(r["point"])
    done = 0
    t0 = time.perf_counter()
    for r in runs:
        params = {k: v for k, v in r["point"].items() if k != "spp"}
        key = _hash(dict(scene=scene_id, res=exp.get("resolution"), est=r["name"], point=r["point"],
                         seed=r["seed"], v=__version__))
        path = out / "results" / f"{key}.npz"
        r["file"] = path
        if path.exists():
            done += 1
            continue
        ts = time.perf_counter()
        img = render(scene, r["name"], spp=r["point"]["spp"], seed=r["seed"], **params)
        _atomic_save(path, image=img, seconds=np.float64(time.perf_counter() - ts))
        done += 1
        if progress and (sys.stderr.isatty() or done % max(1, len(runs) // 10) == 0
                         or done == len(runs)):
            el = time.perf_counter() - t0
            end = "\r" if sys.stderr.isatty() else "\n"
            sys.stderr.write(f"{end}[{done}/{len(runs)}] {r['label']} {r['point']} ETA "
                             f"{el / done * (len(runs) - done):.0f}s   ")
    if progress:
        sys.stderr.write("\n")
    # metrics per (estimator, point)
    rows, means, render_seconds = [], [], {}
    groups = {}
    for r in runs:
        groups.setdefault((r["index"], json.dumps(r["point"], sort_keys=True)), []).append(r)
    for (i, pkey), rs in groups.items():
        imgs, secs = [], []
        for r in rs:
            with np.load(r["file"]) as z:
                imgs.append(z["image"])
                secs.append(float(z["seconds"]))
        render_seconds[rs[0]["label"]] = (render_seconds.get(rs[0]["label"], 0.0)
                                          + float(np.sum(secs)))
        ref, ref_var = reference_for(rs[0]["point"])
        s = stats.error_stats(np.stack(imgs), ref, ref_var)
        # The fastest repetition: the first one of a configuration also pays for compilation.
        seconds = float(np.min(secs))
        row = dict(estimator=rs[0]["name"], label=rs[0]["label"], **json.loads(pkey))
        z = 1.959963984540054          # 95 % normal intervals from the standard errors
        for name, per_pixel in (("mse", s.mse), ("bias2", s.bias2), ("variance", s.variance)):
            mean, se = stats.pixel_mean_and_se(per_pixel)
            row.update({name: mean, f"{name}_se": se, f"{name}_lo": mean - z * se,
                        f"{name}_hi": mean + z * se})
        mse = row["mse"]
        row.update(rel_mse=float(s.rel_mse.mean()), seconds=seconds,
                   efficiency=stats.efficiency(mse, seconds) if mse > 0 else None)
        rows.append(row)
        name = f"mean_{_slug(rs[0]['label'])}_{_hash(pkey)[:6]}.exr"
        write_exr(out / name, s.mean.astype(np.float32))
        row["image"] = name
        means.append((row, s))
    fields = sorted({k for row in rows for k in row},
                    key=lambda k: (k not in ("estimator", "label"), k))
    with open(out / "metrics.csv.tmp", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
    os.replace(out / "metrics.csv.tmp", out / "metrics.csv")
    (out / "metrics.json").write_text(json.dumps(rows, indent=2))
    slopes = _plots(out, rows, doc)
    _maps(out, means, reference_for(runs[0]["point"])[0])
    (out / "slopes.json").write_text(json.dumps(slopes, indent=2))
    prov = dict(jgi_version=__version__, jax_version=jax.__version__,
                devices=[str(d) for d in jax.devices()], git_commit=_git_commit(),
                config=str(Path(config_path).resolve()), reduced=reduced,
                seeds=sorted({r["seed"] for r in runs}), wall_seconds=time.perf_counter() - t_start,
                render_seconds=render_seconds)
    (out / "provenance.json").write_text(json.dumps(prov, indent=2))
    for sl in slopes:   # each slope with its 95 % interval (jgi.analysis.stats.fit_error_slope)
        parts = "".join(f", {p} ~ {sl['key']}^{sl[p + '_slope']:.2f} "
                        f"[{sl[p + '_lo']:.2f}, {sl[p + '_hi']:.2f}]"
                        for p in ("bias2", "variance") if p + "_slope" in sl)
        print(f"  {sl['label']:20s} MSE ~ {sl['key']}^{sl['slope']:.2f} "
              f"[{sl['lo']:.2f}, {sl['hi']:.2f}]{parts}  {sl['fixed']}")
    print(f"wrote {out}/ ({len(rows)} configurations: metrics.csv, slopes.json, plots, EXR means)")
    return out


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "-" for c in text)


def _git_commit():
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent).stdout.strip() or None
    except OSError:
        return None


def _numeric(values) -> bool:
    return len(values) >= 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                    and x > 0 for x in values)


def _plots(out: Path, rows, doc) -> list[dict]:
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


def _maps(out: Path, means, ref, max_rows: int = 12):
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


def main_run(argv) -> int:
    ap = argparse.ArgumentParser(prog="jgi run", description="Run an experiment config.")
    ap.add_argument("config")
    ap.add_argument("--dry-run", action="store_true")
    ap.add_argument("--out", default="runs")
    ap.add_argument("--reduced", action="store_true",
                    help="run the study at a tiny size (resolution 8, 2 repetitions, "
                         "capped counts)")
    a = ap.parse_args(argv)
    try:
        run(a.config, out_root=a.out, dry_run=a.dry_run, reduced=a.reduced)
    except ConfigError as e:
        raise SystemExit(f"jgi: {e}") from None
    return 0
