"""MMLT mutations per second beside BDPT samples per second (issue 32), same scene, same depth,
same run.

    python -m experiments.bench.mmlt_vs_bdpt [--resolution 64] [--depths 16,5] [--spp 16]
                                             [--repeats 3] [--cache]

For each max_depth: a warm-up render of each estimator (spp 1: compilation, reported as
"compile+first"), then ``--repeats`` timed renders at ``--spp`` of the Cornell box; the best wall
time gives BDPT's samples per second (paths = pixels x spp, each with its light subpath and every
connection) and MMLT's mutations per second (``stats["mutations"]``, the proposals its chains
made; the render's time includes the bootstrap of b_L, which is part of the render's work, so
the figure is the whole render's rate, not only the chains'; the chains' rate alone, without
the bootstrap's seconds, is printed beside it). Prints the ratio mmlt / bdpt.
The persistent compilation cache is off unless ``--cache`` (so that compile times are real).
"""

from __future__ import annotations

import argparse
import os
import time


def timed(scene, name: str, spp: int, repeats: int, depth: int) -> dict:
    import jgi

    t0 = time.perf_counter()
    jgi.render_result(scene, name, spp=1, seed=0, max_depth=depth)
    compile_s = time.perf_counter() - t0
    best, cpu, work = None, None, 0
    for r in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        res = jgi.render_result(scene, name, spp=spp, seed=1 + r, max_depth=depth)
        wall, c = time.perf_counter() - t0, time.process_time() - c0
        if best is None or wall < best:
            best, cpu = wall, c
            W, H = scene.camera.width, scene.camera.height
            work = res.stats.get("mutations", W * H * spp)
            boot = res.stats.get("bootstrap_seconds", 0.0)
    return dict(compile_s=compile_s, wall_s=best, cpu_s=cpu, work=work, rate=work / best,
                boot_s=boot)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--depths", default="16,5")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cache", action="store_true", help="keep the persistent compile cache")
    a = ap.parse_args(argv)

    import jgi
    from jgi import compile_cache

    if not a.cache:
        compile_cache.disable()
    scene = jgi.load_scene("cornell_box", resolution=a.resolution)
    print(f"cornell_box {a.resolution}^2, {a.spp} spp, load {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} CPUs")
    for depth in (int(d) for d in a.depths.split(",")):
        bd = timed(scene, "bdpt", a.spp, a.repeats, depth)
        mm = timed(scene, "mmlt", a.spp, a.repeats, depth)
        for name, r, unit in (("bdpt", bd, "samples"), ("mmlt", mm, "mutations")):
            print(f"  depth {depth:2d} {name}: compile+first {r['compile_s']:6.1f} s; "
                  f"{r['work']} {unit} in {r['wall_s']:.3f} s ({r['cpu_s']:.2f} CPU-s): "
                  f"{r['rate']:9.0f} {unit}/s")
        chains_s = mm["wall_s"] - mm["boot_s"]
        print(f"  depth {depth:2d} mmlt: of which bootstrap {mm['boot_s']:.3f} s; the chains "
              f"alone {mm['work'] / chains_s:9.0f} mutations/s")
        ratio = mm["rate"] / bd["rate"]
        print(f"  depth {depth:2d} mmlt mutations/s / bdpt samples/s = {ratio:.2f}", flush=True)


if __name__ == "__main__":
    main()
