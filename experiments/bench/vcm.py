"""jgi's bidirectional estimators against SmallVCM, on the same scene in the same run.

    python -m experiments.bench.vcm [--iterations 4] [--max-depth 10]
        [--modes vcm,bpm,bpt,ppm,lt,pt] [--check-seeds 8] [--check-iterations 1] [--json out.json]

SmallVCM (experiments.bench.smallvcm) is built from ``../shared/peers/smallvcm`` in a temporary
folder; without its source or a compiler the benchmark prints why and exits. Both render its
Cornell box (``smallvcm_box``: the light box under the ceiling, a mirror and a glass ball),
512^2, paths of at most ``--max-depth`` segments, one light and one camera subpath per pixel
and iteration, SmallVCM's merge radius r_0 = 0.003 x the scene's bounding-sphere radius with
its schedule (alpha 0.75), the balance heuristic (SmallVCM's) and the box filter (its kernel).
A *sample* is one pixel's pair (light subpath + camera subpath with every technique), what
SmallVCM calls a path. jgi's ``pt`` is its path tracer (Russian roulette from the first
bounce, as SmallVCM's), ``lt`` its light tracer (SmallVCM's splats no emitter seen directly, so
the pixels that see one are left out of that mode's comparison).

First, per mode, both render ``--check-seeds`` independent images of ``--check-iterations``
iterations each, compared per 4 x 4 region and channel by Welch's t (both sides' seed spreads,
Bonferroni-corrected: :func:`jgi.analysis.stats.region_agreement`): a rate is only worth
comparing between renderers that compute the same image. Then the rates: SmallVCM's from the
wall clock of ``n`` and ``2 n`` iterations (its start-up left out), jgi's from a render of
``n`` iterations after a compiling one. Printed per mode: SmallVCM's and jgi's M samples/s and
their ratio (also per CPU-second, less sensitive to other jobs), jgi's compile seconds, and the
agreement. One JSON object on stdout (or --json FILE).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from . import smallvcm

MODES = ("vcm", "bpm", "bpt", "ppm", "lt", "pt")
REGIONS = 4


def jgi_estimator(mode: str, max_depth: int, radius: float) -> tuple[str, dict]:
    """jgi's estimator and parameters for SmallVCM's algorithm ``mode``."""
    if mode == "pt":
        return "pt", dict(max_depth=max_depth, rr_depth=1)
    if mode == "lt":
        return "lt", dict(max_depth=max_depth)
    return "vcm", dict(mode=mode, max_depth=max_depth, radius=radius, radius_alpha=0.75,
                       heuristic="balance", filter="box")


def bench_jgi(scene, estimator: str, params: dict, iterations: int) -> dict:
    import jgi

    t0 = time.perf_counter()
    jgi.render(scene, estimator, spp=1, seed=0, **params)
    compile_s = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    jgi.render(scene, estimator, spp=iterations, seed=1, **params)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = scene.camera.width * scene.camera.height * iterations
    return dict(compile_s=compile_s, seconds=wall, samples_per_s=n / wall,
                samples_per_cpu_s=n / cpu)


def agreement(peer: smallvcm.SmallVCM, scene, mode: str, estimator: str, params: dict,
              seeds: int, iterations: int) -> dict:
    import jgi

    ours = np.stack([jgi.render(scene, estimator, spp=iterations, seed=100 + s, **params)
                     for s in range(seeds)])
    theirs = peer.images(mode, iterations, seeds=range(1, seeds + 1))
    if mode == "lt":
        # SmallVCM's light tracer splats no light vertex itself (emitters seen directly stay
        # black in its image); jgi's does: both leave out the pixels that see an emitter
        seen = jgi.render(scene, "pt", spp=16, seed=0, max_depth=1).max(-1) > 0
        ours, theirs = ours * ~seen[..., None], theirs * ~seen[..., None]
    return agreement_summary(ours, theirs)


def agreement_summary(ours: np.ndarray, theirs: np.ndarray) -> dict:
    """Per-region agreement of two stacks of seeds (:func:`jgi.analysis.stats.region_agreement`)
    as the benchmark's JSON reports it."""
    from jgi.analysis.stats import region_agreement

    r = region_agreement(ours, theirs, REGIONS)
    w = r.worst
    return dict(agree=r.agree, max_t=float(r.t.max()), worst_region=[int(i) for i in w],
                worst_t=float(r.t[w]), critical_t=float(r.critical[w]),
                mean_jgi=ours.reshape(-1, 3).mean(0).tolist(),
                mean_smallvcm=theirs.reshape(-1, 3).mean(0).tolist())


def scene_radius() -> float:
    """SmallVCM's scene radius: half the diagonal of its geometry's bounding box."""
    from jgi.scene.builtin import SMALLVCM_BOX

    return float(np.linalg.norm(SMALLVCM_BOX.max(0) - SMALLVCM_BOX.min(0)) / 2)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-depth", type=int, default=10)
    ap.add_argument("--iterations", type=int, default=4)
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--check-seeds", type=int, default=8,
                    help="independent images per side for the agreement check (0: skip it)")
    ap.add_argument("--check-iterations", type=int, default=1)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    modes = a.modes.split(",")
    unknown = sorted(set(modes) - set(MODES))
    if unknown:
        ap.error(f"unknown modes {unknown}; allowed: {', '.join(MODES)}")

    import jgi

    with tempfile.TemporaryDirectory() as tmp:
        try:
            peer = smallvcm.build(Path(tmp))
        except smallvcm.PeerUnavailable as e:
            print(f"skipped: SmallVCM is not available ({e})", file=sys.stderr)
            return 0
        scene = jgi.load_scene("smallvcm_box", resolution=smallvcm.RESOLUTION)
        radius = 0.003 * scene_radius()
        load = os.getloadavg()[0]
        rows = []
        for mode in modes:
            estimator, params = jgi_estimator(mode, a.max_depth, radius)
            row = dict(mode=mode, estimator=estimator, params=params)
            if a.check_seeds > 1:
                row["agreement"] = agreement(peer, scene, mode, estimator, params,
                                             a.check_seeds, a.check_iterations)
            row["smallvcm"] = peer.rate(mode, a.iterations)
            row["jgi"] = bench_jgi(scene, estimator, params, a.iterations)
            row["ratio"] = row["jgi"]["samples_per_s"] / row["smallvcm"]["samples_per_s"]
            row["ratio_cpu"] = (row["jgi"]["samples_per_cpu_s"]
                                / row["smallvcm"]["samples_per_cpu_s"])
            rows.append(row)
            _summary(row, a)
    out = dict(scene="smallvcm_box", resolution=smallvcm.RESOLUTION, max_depth=a.max_depth,
               radius=radius, iterations=a.iterations, load_average=load, cpus=os.cpu_count(),
               rows=rows)
    text = json.dumps(out, indent=2)
    if a.json:
        Path(a.json).write_text(text)
    print(text)
    print(f"load {load:.1f} on {os.cpu_count()} CPUs", file=sys.stderr)
    return 0


def _summary(row: dict, a) -> None:
    peer, ours = row["smallvcm"], row["jgi"]
    check = row.get("agreement")
    agree = ("" if check is None else
             f"  images {'agree' if check['agree'] else 'DIFFER'} (max t {check['max_t']:.1f}, "
             f"worst {check['worst_t']:.1f} vs {check['critical_t']:.1f})")
    print(f"{row['mode']:4s} 512^2 depth {a.max_depth}: SmallVCM {peer['samples_per_s'] / 1e6:.3f}"
          f", jgi {ours['samples_per_s'] / 1e6:.3f} M samples/s = {row['ratio']:.2f}x "
          f"({row['ratio_cpu']:.2f}x per CPU-s; jgi compile+1 {ours['compile_s']:.1f} s)"
          f"{agree}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
