"""Experiments from TOML config files: sweeps, repetitions, references, metrics, plots, resume.

    jgi run configs/NAME.toml [--dry-run] [--out runs] [--workers N | --scheduler ADDRESS]

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
#     rendered as seeded chunks of chunk_spp samples (default 256, at least two chunks), each a
#     task with its own file: an interrupted reference resumes, a cluster spreads it
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
Each (estimator, sweep point, repetition) is one task (:mod:`jgi.experiment.plan`), written
atomically to ``results/<hash>.npz`` (the hash covers everything that determines the image);
each reference chunk likewise to ``<out>/.cache/references/``, shared by studies of the same
scene. An interrupted run resumes without recomputing; ``--dry-run`` prints the plan. Tasks run
in this process, or on Dask with ``--workers N`` (a LocalCluster) or ``--scheduler ADDRESS``
(:mod:`jgi.experiment.executors`), with the same results bit for bit. Outputs: ``config.toml``
(as run), ``provenance.json``, ``metrics.csv`` / ``metrics.json`` (jgi.analysis.stats per sweep
point), EXR means, and log-log plots of MSE, bias^2 and variance against each numeric swept
parameter.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import time
from pathlib import Path

import jax
import numpy as np

from .. import __version__
from ..analysis import closed_form, stats
from ..core.imageio import write_exr
from .checkpoint import combine
from .config import ConfigError, load_config, smoke
from .executors import run_tasks
from .outputs import error_maps, plots, slug
from .plan import content_hash, plan, reference_params, scene_source, study_scene, tasks
from .tasks import StudyJob


def run(config_path, *, out_root="runs", dry_run: bool = False, reduced: bool = False,
        render=None, progress=True, workers: int | None = None,
        scheduler: str | None = None) -> Path:
    """Run (or resume) an experiment; returns its output folder. ``reduced`` runs the
    :func:`~jgi.experiment.config.smoke` version (into ``runs/NAME-smoke``). ``render``
    defaults to :func:`jgi.render` (tests pass a counting wrapper; it must accept
    ``progress=``). ``workers`` / ``scheduler``: run the tasks on Dask (see
    :mod:`jgi.experiment.executors`)."""

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
    chunk_folder = Path(out_root) / ".cache" / "references"
    chunk_folder.mkdir(parents=True, exist_ok=True)
    (out / "config.toml").write_text(Path(config_path).read_text())
    (out / "config_as_run.json").write_text(json.dumps(doc, indent=2))
    t_start = time.perf_counter()
    scene_src, scene_id = scene_source(doc, config_path)
    todo, references = tasks(doc, runs, scene_id)
    job = StudyJob(scene_src, exp.get("resolution"),
                   {"run": str(out / "results"), "chunk": str(chunk_folder)}, render)
    run_tasks(job, todo, exp["name"], workers=workers, scheduler=scheduler, progress=progress)
    return aggregate(doc, config_path, out, runs, references, job, reduced, t_start)


def aggregate(doc, config_path, out: Path, runs, references, job: StudyJob, reduced: bool,
              t_start: float) -> Path:
    """Metrics, plots and provenance from the result files (the study's plan says which)."""
    exp = doc["experiment"]
    scene = None
    ref_images = {}

    def reference_for(point):
        """(image, variance of the image) of the reference for a sweep point: a closed form,
        or its chunks combined (jgi.analysis.stats.combine_chunks)."""
        nonlocal scene
        cfg = exp["reference"]
        matched, _ = reference_params(doc, point)
        rkey = json.dumps(matched, sort_keys=True)
        if rkey in ref_images:
            return ref_images[rkey]
        if "closed_form" in cfg:
            if scene is None:
                scene = study_scene(doc, config_path)[0]
            cf = cfg["closed_form"]
            img = (closed_form.IMAGES[cf](scene) if isinstance(cf, str) else
                   np.broadcast_to(np.asarray(cf, np.float32),
                                   (scene.camera.height, scene.camera.width, 3)).copy())
            ref_images[rkey] = (img, np.zeros_like(img))
        else:
            ref_images[rkey] = combine(job, references[rkey]["chunks"])
        suffix = "" if not matched else "_" + "_".join(f"{k}{v}" for k, v in matched.items())
        write_exr(out / f"reference{suffix}.exr", ref_images[rkey][0])
        return ref_images[rkey]

    rows, means, render_seconds, compile_seconds = [], [], {}, {}
    groups = {}
    for r in runs:
        groups.setdefault((r["index"], json.dumps(r["point"], sort_keys=True)), []).append(r)
    for (i, pkey), rs in groups.items():
        imgs, secs, comp = [], [], []
        for r in rs:
            with np.load(job.path(dict(kind="run", key=r["key"]))) as z:
                imgs.append(z["image"])
                secs.append(float(z["seconds"]))
                comp.append(float(z["compile_seconds"]) if "compile_seconds" in z else 0.0)
        label = rs[0]["label"]
        render_seconds[label] = render_seconds.get(label, 0.0) + float(np.sum(secs))
        compile_seconds[label] = compile_seconds.get(label, 0.0) + float(np.sum(comp))
        ref, ref_var = reference_for(rs[0]["point"])
        s = stats.error_stats(np.stack(imgs), ref, ref_var)
        # Render time excludes compilation (jgi.core.progress); the fastest repetition also
        # leaves out a first call's other start-up costs.
        seconds = float(np.min(secs))
        row = dict(estimator=rs[0]["name"], label=label, **json.loads(pkey))
        z = 1.959963984540054          # 95 % normal intervals from the standard errors
        for name, per_pixel in (("mse", s.mse), ("bias2", s.bias2), ("variance", s.variance)):
            mean, se = stats.pixel_mean_and_se(per_pixel)
            row.update({name: mean, f"{name}_se": se, f"{name}_lo": mean - z * se,
                        f"{name}_hi": mean + z * se})
        mse = row["mse"]
        row.update(rel_mse=float(s.rel_mse.mean()), seconds=seconds,
                   efficiency=stats.efficiency(mse, seconds) if mse > 0 else None)
        rows.append(row)
        name = f"mean_{slug(label)}_{content_hash(pkey)[:6]}.exr"
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
    slopes = plots(out, rows, doc)
    error_maps(out, means, reference_for(runs[0]["point"])[0])
    (out / "slopes.json").write_text(json.dumps(slopes, indent=2))
    prov = dict(jgi_version=__version__, jax_version=jax.__version__,
                devices=[str(d) for d in jax.devices()], git_commit=_git_commit(),
                config=str(Path(config_path).resolve()), reduced=reduced,
                seeds=sorted({r["seed"] for r in runs}), wall_seconds=time.perf_counter() - t_start,
                render_seconds=render_seconds, compile_seconds=compile_seconds)
    (out / "provenance.json").write_text(json.dumps(prov, indent=2))
    for sl in slopes:   # each slope with its 95 % interval (jgi.analysis.stats.fit_error_slope)
        parts = "".join(f", {p} ~ {sl['key']}^{sl[p + '_slope']:.2f} "
                        f"[{sl[p + '_lo']:.2f}, {sl[p + '_hi']:.2f}]"
                        for p in ("bias2", "variance") if p + "_slope" in sl)
        print(f"  {sl['label']:20s} MSE ~ {sl['key']}^{sl['slope']:.2f} "
              f"[{sl['lo']:.2f}, {sl['hi']:.2f}]{parts}  {sl['fixed']}")
    print(f"wrote {out}/ ({len(rows)} configurations: metrics.csv, slopes.json, plots, EXR means)")
    return out


def _git_commit():
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent).stdout.strip() or None
    except OSError:
        return None


def main_run(argv) -> int:
    ap = argparse.ArgumentParser(prog="jgi run", description="Run an experiment config.")
    ap.add_argument("config")
    ap.add_argument("--dry-run", action="store_true")
    ap.add_argument("--out", default="runs")
    ap.add_argument("--reduced", action="store_true",
                    help="run the study at a tiny size (resolution 8, 2 repetitions, "
                         "capped counts)")
    ap.add_argument("--workers", type=int, default=None,
                    help="run the renders on a local Dask cluster of N worker processes, "
                         "each pinned to its share of the cores")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="run the renders on the Dask cluster whose scheduler is at ADDRESS "
                         "(e.g. one started by dask-jobqueue on Slurm)")
    ap.add_argument("--quiet", action="store_true", help="no progress display")
    a = ap.parse_args(argv)
    if a.workers is not None and a.scheduler is not None:
        ap.error("give --workers or --scheduler, not both")
    try:
        run(a.config, out_root=a.out, dry_run=a.dry_run, reduced=a.reduced,
            workers=a.workers, scheduler=a.scheduler, progress=not a.quiet)
    except ConfigError as e:
        raise SystemExit(f"jgi: {e}") from None
    return 0
