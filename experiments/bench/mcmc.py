"""Speed and reproducibility of the Metropolis estimators (PSSMLT, MMLT, path-space MLT).

    python -m experiments.bench.mcmc [--which pssmlt,mmlt,mlt] [--resolution 64] [--repeats 3]
                                     [--save-images DIR]

For each estimator: one warm-up render (compilation), then ``--repeats`` timed renders of the
Cornell box; prints the best wall-clock and CPU seconds (``time.process_time``, less sensitive to
other jobs on a shared machine) and mutations per CPU-second. ``--save-images DIR`` also writes
``DIR/<name>.npy``: a 16^2 render at 4 spp, seed 1, default parameters, to compare two versions
of the code bit for bit (``np.array_equal``).

The timed renders (about a CPU-second each) use default parameters except the spp
(PSSMLT 512, MMLT 256, MLT 1024), MMLT's ``max_depth=3`` (lengths 1..3: three chain kernels to
compile instead of five) and MLT's ``b_paths=0`` (b from the bootstrap, so the figure is MLT's
own work, not the path tracer's).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import jgi

TIMED = {
    "pssmlt": dict(spp=512),
    "mmlt": dict(spp=256, max_depth=3),
    "mlt": dict(spp=1024, b_paths=0),
}


def save_images(names, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    scene = jgi.load_scene("cornell_box", resolution=16)
    for name in names:
        img = jgi.render(scene, name, spp=4, seed=1)
        np.save(out / f"{name}.npy", img)
        print(f"{name}: saved 16^2 image, mean {img.mean():.6f}")


def bench(name: str, resolution: int, repeats: int) -> dict:
    scene = jgi.load_scene("cornell_box", resolution=resolution)
    params = dict(TIMED[name])
    spp = params.pop("spp")
    t0 = time.perf_counter()
    jgi.render(scene, name, spp=spp, seed=0, **params)
    compile_s = time.perf_counter() - t0
    wall, cpu = [], []
    for r in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        jgi.render(scene, name, spp=spp, seed=1 + r, **params)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    mutations = spp * resolution * resolution
    return dict(name=name, compile_s=compile_s, wall_s=min(wall), cpu_s=min(cpu),
                mutations_per_cpu_s=mutations / min(cpu))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--which", default="pssmlt,mmlt,mlt")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--save-images", default=None)
    ap.add_argument("--no-bench", action="store_true")
    a = ap.parse_args(argv)
    names = a.which.split(",")
    if a.save_images:
        save_images(names, Path(a.save_images))
    if a.no_bench:
        return
    for name in names:
        r = bench(name, a.resolution, a.repeats)
        print(f"{r['name']:7s} {a.resolution}^2: compile+first {r['compile_s']:6.1f} s, best of "
              f"{a.repeats}: {r['wall_s']:6.2f} s wall, {r['cpu_s']:6.2f} s CPU, "
              f"{r['mutations_per_cpu_s']:9.0f} mutations per CPU-second")


if __name__ == "__main__":
    main()
