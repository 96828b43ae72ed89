"""The benchmark suite: one command, figures as a table and as JSON.

    python -m experiments.bench.bench [--quick] [--json runs/bench.json] [--no-mitsuba]

Measures, each after a warm-up call so compile time is reported separately:
  * path tracing throughput (Mpaths/s) on the Cornell box, and the ratio against Mitsuba 3
    (``llvm_ad_rgb``, its own ``cornell_box()``) measured in the same run;
  * scaling of path tracing with resolution and spp; path tracing on every built-in scene;
  * photon tracing throughput (photons/s) and its scaling with the photon count;
  * triangle-count scaling (a subdivided sphere, brute force or BVH as the scene builder
    chooses);
  * the BVH (``experiments/bench/bvh.py``): build time, traversal rays/s up to 10^6 triangles
    (10^5 with --quick), the brute-force crossover, path tracing a 10^5 / 10^6-triangle mesh;
  * BDPT samples/s, and hash-grid density queries/s beside scipy's cKDTree;
  * compile times and the process's peak resident memory.
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

import numpy as np


def _timed(fn, repeats=2):
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return first, best


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bench_pt_scaling(quick: bool) -> list[dict]:
    import jgi

    rows = []
    for res, spp in ([(64, 4), (128, 4)] if quick else [(64, 16), (128, 16), (256, 16), (256, 64)]):
        scene = jgi.scenes.cornell_box(resolution=res)
        first, best = _timed(lambda: jgi.render(scene, "pt", spp=spp, seed=1))
        rows.append(dict(bench="pt_scaling", resolution=res, spp=spp,
                         mpaths_per_s=res * res * spp / best / 1e6, first_call_s=first))
    return rows


def bench_pt_scenes(quick: bool) -> list[dict]:
    """Path tracing throughput (Mpaths per CPU-second, less sensitive to other jobs than wall
    time) on every built-in scene: a scene far below the Cornell box points at a kernel XLA left
    unvectorised or split into many launches (Veach's plates ran at a sixth of the Cornell box's
    rate before the shadow rays were stored separately; the metal ring at a twenty-fifth before the
    brute-force loop took blocks of rows)."""
    import jgi

    rows = []
    res, spp = (64, 4) if quick else (128, 16)
    for name in sorted(jgi.scenes.BUILTINS):
        scene = jgi.load_scene(name, resolution=res)
        t0 = time.perf_counter()
        jgi.render(scene, "pt", spp=1, seed=0)
        first = time.perf_counter() - t0
        best = float("inf")
        for r in range(2):
            c0 = time.process_time()
            jgi.render(scene, "pt", spp=spp, seed=1 + r)
            best = min(best, time.process_time() - c0)
        rows.append(dict(bench="pt_scenes", scene=name, resolution=res, spp=spp,
                         mpaths_per_cpu_s=res * res * spp / best / 1e6, first_call_s=first))
    return rows


def bench_photons(quick: bool) -> list[dict]:
    import jax

    import jgi
    from jgi.transport.photons import trace_photons

    scene = jgi.scenes.cornell_box_caustics(resolution=64)
    rows = []
    for n in ([10**5] if quick else [10**5, 10**6, 10**7]):
        first, best = _timed(lambda: trace_photons(scene, n, seed=0), repeats=1)
        pm = trace_photons(scene, n, seed=0)
        rows.append(dict(bench="photon_tracing", photons=n, stored=pm.count,
                         mphotons_per_s=n / best / 1e6, first_call_s=first,
                         bytes_per_stored_photon=sum(np.asarray(a).nbytes for a in
                                                     jax.tree_util.tree_leaves(pm)) / pm.count))
    return rows


def bench_triangles(quick: bool) -> list[dict]:
    import trimesh

    import jgi
    from jgi.scene import SceneBuilder

    rows = []
    for sub in ([1, 2] if quick else [1, 2, 3, 4]):
        mesh = trimesh.creation.icosphere(subdivisions=sub, radius=0.5)
        b = SceneBuilder("mesh")
        b.material("m", "diffuse", diffuse=(0.7, 0.7, 0.7))
        b.mesh(mesh.vertices, mesh.faces, "m")
        b.quad((-2, -0.5, -2), (0, 0, 4), (4, 0, 0), "m")
        b.quad((-0.3, 1.5, -0.3), (0.6, 0, 0), (0, 0, 0.6), "m", emission=(10, 10, 10))
        b.camera((0, 0.5, 2.5), (0, 0, 0), width=64, height=64)
        scene = b.build()
        first, best = _timed(lambda: jgi.render(scene, "pt", spp=4, seed=1), repeats=1)
        rows.append(dict(bench="triangles", triangles=len(mesh.faces),
                         mpaths_per_s=64 * 64 * 4 / best / 1e6, first_call_s=first))
    return rows


def bench_bvh(quick: bool) -> list[dict]:
    """experiments/bench/bvh.py: BVH build, traversal rays/s, brute-force crossover, mesh
    renders."""
    from experiments.bench import bvh

    return bvh.run(quick)


def bench_optional(quick: bool) -> list[dict]:
    """Estimators and structures that live in optional modules (measured when present)."""
    import jgi

    rows = []
    scene = jgi.scenes.cornell_box(resolution=64)
    if "bdpt" in jgi.REGISTRY:
        first, best = _timed(lambda: jgi.render(scene, "bdpt", spp=4, seed=1), repeats=1)
        rows.append(dict(bench="bdpt", msamples_per_s=64 * 64 * 4 / best / 1e6, first_call_s=first))
    return rows


def bench_density(quick: bool) -> list[dict]:
    """experiments/bench/density.py: hash-grid build and density queries/s beside scipy's
    cKDTree in the same run (10^5, 10^6 and, unless quick, 10^7 uniform photons)."""
    from experiments.bench import density

    sizes = ["100000", "1000000"] + ([] if quick else ["10000000"])
    rows = []
    for r in density.main(["--sizes", *sizes, "--kinds", "uniform",
                      "--queries", "16384" if quick else "65536"]):
        rows.append(dict(bench="density", photons=r["photons"], grid_build_s=r["jgi"]["build_s"],
                         mqueries_per_s=r["jgi"]["queries_per_s"] / 1e6,
                         ckdtree_mqueries_per_s=r["ckdtree"]["queries_per_s"] / 1e6,
                         ratio=r["ratio"]))
    return rows


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (about a minute)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--no-mitsuba", action="store_true")
    a = ap.parse_args(argv)
    from experiments.bench import pt

    out = {"cornell_vs_mitsuba": pt.main(
        ["--spp", "8" if a.quick else "64", "--repeats", "2"]
        + (["--no-mitsuba"] if a.no_mitsuba else []))}
    rows = []
    for fn in (bench_pt_scaling, bench_pt_scenes, bench_photons, bench_triangles, bench_bvh,
               bench_optional, bench_density):
        rows += fn(a.quick)
    out["rows"] = rows
    out["peak_rss_mb"] = peak_rss_mb()
    for r in rows:
        print("  ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                        for k, v in r.items()))
    print(f"peak resident memory: {out['peak_rss_mb']:.0f} MB")
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(out, indent=2, default=float))
    return out


if __name__ == "__main__":
    main()
