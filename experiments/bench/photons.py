"""jgi's photon-mapping estimators against SmallVCM's PPM, on the same scene in the same run.

    python -m experiments.bench.photons [--iterations 4] [--max-depth 10]
        [--modes pm,ppm,sppm,vcm_ppm] [--check-seeds 8] [--json out.json]

The peer is SmallVCM's progressive photon mapping (``-a ppm``), built from
``../shared/peers/smallvcm`` (:mod:`experiments.bench.smallvcm`; without its source or a
compiler the benchmark prints why and exits). One SmallVCM iteration shoots W x H photons
(one light subpath per pixel, 512^2 = 262,144), stores them at every non-specular hit, traces
one camera path per pixel to its first non-specular vertex and gathers there within the
iteration's radius r_i = r_0 i^((alpha - 1) / 2), r_0 = 0.003 x the scene's bounding radius,
alpha = 0.75, with a constant (box) kernel. jgi runs the same work per iteration:

* ``pm``: one photon map of 262,144 photons, one visible point per pixel, every photon within
  r_0 (:func:`jgi.transport.density.sum_within`, exact); one iteration = one render.
* ``ppm`` / ``sppm``: Hachisuka's progressive passes of 262,144 photons from radius r_0 (the
  per-pixel radius update, which at equal photon counts shrinks as SmallVCM's global schedule
  does in expectation); one iteration = one pass. ``ppm`` keeps its first visible points.
* ``vcm_ppm``: jgi's VCM in its ``ppm`` mode, the algorithm SmallVCM runs, line for line.

Paths: SmallVCM's limit of ``--max-depth`` segments in all (light subpath plus one camera
segment to a diffuse surface): jgi's photons make at most max_depth - 1 surface hits.

First, per mode, both render ``--check-seeds`` independent one-iteration images (radius r_0 on
both sides, so the same kernel bias), compared per 4 x 4 region and channel by Welch's t with
both sides' seed spreads (:func:`jgi.analysis.stats.region_agreement`). Then the rates:
SmallVCM's from the wall clock of ``n`` and ``2 n`` iterations (its start-up left out), jgi's
from a run of ``n`` iterations after a compiling one. Printed per mode: both sides' seconds
per iteration and the ratio of iterations per second (also per CPU-second).
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
from .vcm import agreement_summary, scene_radius

MODES = ("pm", "ppm", "sppm", "vcm_ppm")
ALPHA = 0.75


def jgi_estimator(mode: str, max_depth: int, radius: float, photons: int,
                  iterations: int) -> tuple[str, dict, int]:
    """(estimator, parameters, spp) doing ``iterations`` of SmallVCM's PPM iterations."""
    if mode == "pm":
        if iterations != 1:
            raise ValueError("pm has no iterations: one photon map per render")
        return "pm", dict(photons=photons, radius=radius, max_bounces=max_depth - 1), 1
    if mode in ("ppm", "sppm"):
        return mode, dict(passes=iterations, photons=photons, radius=radius, radius_alpha=ALPHA,
                          max_bounces=max_depth - 1), 1
    if mode == "vcm_ppm":
        return "vcm", dict(mode="ppm", max_depth=max_depth, radius=radius, radius_alpha=ALPHA,
                           heuristic="balance", filter="box"), iterations
    raise ValueError(f"unknown mode {mode!r}; allowed: {', '.join(MODES)}")


def bench_jgi(scene, mode: str, max_depth: int, radius: float, photons: int,
              iterations: int) -> dict:
    """Seconds per iteration: a one-iteration call compiles, then ``iterations`` of them (pm:
    that many renders) are timed."""
    import jgi

    t0 = time.perf_counter()
    est, params, spp = jgi_estimator(mode, max_depth, radius, photons, 1)
    jgi.render(scene, est, spp=spp, seed=0, **params)
    compile_s = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    if mode == "pm":
        for i in range(iterations):
            jgi.render(scene, est, spp=spp, seed=1 + i, **params)
    else:
        est, params, spp = jgi_estimator(mode, max_depth, radius, photons, iterations)
        jgi.render(scene, est, spp=spp, seed=1, **params)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return dict(compile_s=compile_s, seconds_per_iteration=wall / iterations,
                iterations_per_s=iterations / wall, iterations_per_cpu_s=iterations / cpu)


def agreement(peer: smallvcm.SmallVCM, scene, mode: str, max_depth: int, radius: float,
              photons: int, seeds: int) -> dict:
    import jgi

    est, params, spp = jgi_estimator(mode, max_depth, radius, photons, 1)
    ours = np.stack([jgi.render(scene, est, spp=spp, seed=100 + s, **params)
                     for s in range(seeds)])
    theirs = peer.images("ppm", 1, seeds=range(1, seeds + 1))
    return agreement_summary(ours, theirs)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-depth", type=int, default=10)
    ap.add_argument("--iterations", type=int, default=4)
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--check-seeds", type=int, default=8,
                    help="independent one-iteration images per side (0: skip the check)")
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
        photons = smallvcm.RESOLUTION * smallvcm.RESOLUTION
        radius = 0.003 * scene_radius()
        load = os.getloadavg()[0]
        peer_rate = peer.rate("ppm", a.iterations)
        peer_rate["seconds_per_iteration"] = peer_rate["seconds"] / a.iterations
        rows = []
        for mode in modes:
            row = dict(mode=mode)
            if a.check_seeds > 1:
                row["agreement"] = agreement(peer, scene, mode, a.max_depth, radius, photons,
                                             a.check_seeds)
            ours = bench_jgi(scene, mode, a.max_depth, radius, photons, a.iterations)
            row["jgi"] = ours
            row["smallvcm"] = peer_rate
            row["ratio"] = ours["iterations_per_s"] * peer_rate["seconds_per_iteration"]
            # SmallVCM's samples_per_cpu_s counts W x H samples per iteration
            peer_iter_cpu = peer_rate["samples_per_cpu_s"] / photons
            row["ratio_cpu"] = ours["iterations_per_cpu_s"] / peer_iter_cpu
            rows.append(row)
            _summary(row)
    out = dict(scene="smallvcm_box", resolution=smallvcm.RESOLUTION, photons=photons,
               max_depth=a.max_depth, radius=radius, alpha=ALPHA, iterations=a.iterations,
               load_average=load, cpus=os.cpu_count(), rows=rows)
    text = json.dumps(out, indent=2)
    if a.json:
        Path(a.json).write_text(text)
    print(text)
    print(f"load {load:.1f} on {os.cpu_count()} CPUs", file=sys.stderr)
    return 0


def _summary(row: dict) -> None:
    peer, ours = row["smallvcm"], row["jgi"]
    check = row.get("agreement")
    agree = ("" if check is None else
             f"  images {'agree' if check['agree'] else 'DIFFER'} (max t {check['max_t']:.1f}, "
             f"worst {check['worst_t']:.1f} vs {check['critical_t']:.1f})")
    print(f"{row['mode']:8s} {smallvcm.RESOLUTION}^2, 262,144 photons/iteration: SmallVCM PPM "
          f"{peer['seconds_per_iteration']:.3f} s, jgi {ours['seconds_per_iteration']:.3f} s per "
          f"iteration = {row['ratio']:.2f}x ({row['ratio_cpu']:.2f}x per CPU-s; jgi compile+1 "
          f"{ours['compile_s']:.1f} s){agree}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
