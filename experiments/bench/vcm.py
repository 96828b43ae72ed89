"""VCM throughput: light and camera subpaths per second on the caustic Cornell box.

    python -m experiments.bench.vcm [--resolution 512] [--max-depth 10] [--iterations 3]
                                    [--modes vcm,bpm,bpt,ppm] [--json out.json]

The issue's setting (SmallVCM's own benchmark): a Cornell box with a mirror and a glass sphere
(``cornell_box_caustics``), 512^2, paths of at most 10 segments, one light and one camera
subpath per pixel and iteration. A *sample* is one pixel's pair (light subpath + camera subpath
with every technique); samples per second is what SmallVCM reports as paths per second.
SmallVCM was not run here (it is a C++ program outside the package registries); its figures
measured on this 2-core CPU, from the issue, are the peer: VCM 0.12, BPT 0.18, PPM 0.40 and PT
0.47 M samples/s. jgi's path tracer (NEE + MIS, no Russian roulette) is measured in the same run.

Prints per mode: compile seconds (first iteration, compiles included), then samples per second
of wall clock and per CPU-second of the process (less sensitive to other jobs), and the ratio
to SmallVCM's figure. One JSON object on stdout (or --json FILE).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

SMALLVCM = {"vcm": 0.12e6, "bpt": 0.18e6, "ppm": 0.40e6, "pt": 0.47e6}


def bench_vcm(scene, mode: str, iterations: int, max_depth: int, radius: float) -> dict:
    from jgi.estimators import vcm

    cfg = vcm.VCMConfig(mode=mode, max_depth=max_depth, radius=radius)
    t0 = time.perf_counter()
    first = vcm.render(scene, cfg, spp=1, seed=0)
    compile_s = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    r = vcm.render(scene, cfg, spp=iterations, seed=1)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = scene.camera.width * scene.camera.height * iterations
    return dict(mode=mode, compile_s=compile_s, seconds=wall, samples_per_s=n / wall,
                samples_per_cpu_s=n / cpu, stats={**first.stats, **r.stats},
                mean_rgb=r.image.reshape(-1, 3).mean(0).tolist())


def bench_pt(scene, spp: int, max_depth: int) -> dict:
    import jgi

    t0 = time.perf_counter()
    jgi.render(scene, "pt", spp=1, seed=0, max_depth=max_depth, rr_depth=-1)
    compile_s = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    img = jgi.render(scene, "pt", spp=spp, seed=1, max_depth=max_depth, rr_depth=-1)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = scene.camera.width * scene.camera.height * spp
    return dict(mode="pt", compile_s=compile_s, seconds=wall, samples_per_s=n / wall,
                samples_per_cpu_s=n / cpu, mean_rgb=img.reshape(-1, 3).mean(0).tolist())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--max-depth", type=int, default=10)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--radius", type=float, default=0.003 * 3 ** 0.5 * 2,
                    help="r_0 (default SmallVCM's: 0.003 x the scene's bounding-sphere radius)")
    ap.add_argument("--modes", default="vcm,bpm,bpt,ppm")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)

    import jgi

    scene = jgi.load_scene("cornell_box_caustics").with_resolution(a.resolution, a.resolution)
    load = os.getloadavg()[0]
    rows = [bench_vcm(scene, m, a.iterations, a.max_depth, a.radius)
            for m in a.modes.split(",")]
    rows.append(bench_pt(scene, a.iterations, a.max_depth))
    for r in rows:
        peer = SMALLVCM.get(r["mode"])
        r["over_smallvcm"] = r["samples_per_s"] / peer if peer else None
    out = dict(scene="cornell_box_caustics", resolution=a.resolution, max_depth=a.max_depth,
               load_average=load, cpus=os.cpu_count(), rows=rows)
    text = json.dumps(out, indent=2)
    if a.json:
        with open(a.json, "w") as f:
            f.write(text)
    print(text)
    for r in rows:
        ratio = "" if r["over_smallvcm"] is None else f"  {r['over_smallvcm']:.2f}x SmallVCM"
        print(f"{r['mode']:4s} {a.resolution}^2 depth {a.max_depth}: compile+1 "
              f"{r['compile_s']:.1f} s, {r['samples_per_s'] / 1e6:.3f} M samples/s "
              f"({r['samples_per_cpu_s'] / 1e6:.3f} per CPU-s){ratio}", file=sys.stderr)
    print(f"load {load:.1f} on {os.cpu_count()} CPUs", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
