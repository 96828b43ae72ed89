"""BDPT throughput beside the path tracer's, on the Cornell box (same run, same machine).

    python -m experiments.bench.bdpt [--spp 16] [--resolution 64] [--max-depth 5] [--json out.json]

Prints, for pt (NEE + MIS, no Russian roulette) and bdpt (all (s, t) strategies, power
heuristic) at the same max depth: compile time, samples (camera paths; for BDPT each with its
light subpath and every connection) per second of wall clock and per CPU-second of the process
(less sensitive to other jobs on a shared machine), and the image means (both estimate the same
image). Output: one JSON object on stdout (or --json FILE), and a summary line on stderr.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time


def bench(scene, estimator: str, spp: int, repeats: int, **params) -> dict:
    import jgi

    t0 = time.perf_counter()
    jgi.render(scene, estimator, spp=1, seed=0, **params)
    compile_s = time.perf_counter() - t0
    times, cpu, img = [], [], None
    for r in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        img = jgi.render(scene, estimator, spp=spp, seed=1 + r, **params)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    W, H = scene.camera.width, scene.camera.height
    n = W * H * spp
    return dict(estimator=estimator, params=params, spp=spp, resolution=[W, H],
                compile_s=compile_s, seconds=min(times),
                samples_per_s=n / min(times), samples_per_cpu_s=n / min(cpu),
                mean_rgb=img.reshape(-1, 3).mean(0).tolist())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--max-depth", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scene", default="cornell_box")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)

    import jgi

    scene = jgi.load_scene(a.scene).with_resolution(a.resolution, a.resolution)
    load = os.getloadavg()[0]
    pt = bench(scene, "pt", a.spp, a.repeats, max_depth=a.max_depth, rr_depth=-1)
    bd = bench(scene, "bdpt", a.spp, a.repeats, max_depth=a.max_depth)
    out = dict(scene=a.scene, load_average=load, cpus=os.cpu_count(), pt=pt, bdpt=bd,
               bdpt_over_pt_samples=bd["samples_per_s"] / pt["samples_per_s"],
               bdpt_over_pt_cpu=bd["samples_per_cpu_s"] / pt["samples_per_cpu_s"])
    text = json.dumps(out, indent=2)
    if a.json:
        with open(a.json, "w") as f:
            f.write(text)
    print(text)
    print(f"{a.scene} {a.resolution}^2 depth {a.max_depth}: pt {pt['samples_per_s'] / 1e6:.3f} "
          f"Mpaths/s, bdpt {bd['samples_per_s'] / 1e6:.3f} Msamples/s "
          f"({bd['samples_per_s'] / pt['samples_per_s']:.2f}x; per CPU-s "
          f"{out['bdpt_over_pt_cpu']:.2f}x); load {load:.1f} on {os.cpu_count()} CPUs",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
