"""BVH benchmark: build time, traversal rays/s, brute force vs BVH crossover, mesh renders.

    python -m experiments.bench.bvh [--quick] [--json runs/bench_bvh.json]

Meshes are tori made by code (``trimesh.creation.torus`` with 2n x n sections: exactly 4 n^2
triangles, none degenerate), so the sizes are 10^3 (n = 16: 1024), 10^4, 10^5 (99 856) and 10^6.
Rays start on a sphere of radius 3 around the mesh and aim at uniform points of its bounding
box (about half hit it), in batches of ``RAYS``; every figure is the best of a few timed calls
after a warm-up call (compile time is reported separately).

  * build: :func:`jgi.core.bvh.build_bvh` wall time (numpy, one thread), nodes and leaves;
  * traversal: closest-hit and any-hit rays/s of :func:`jgi.core.bvh.intersect_closest` and
    :func:`jgi.core.bvh.intersect_any`;
  * crossover: rays/s of :func:`jgi.physics.geometry.intersect` followed by
    :func:`jgi.physics.geometry.occluded` (the path tracer's two queries per segment) for small
    meshes with and without a BVH, which is what ``jgi.scene.BVH_MIN_TRIANGLES`` is chosen from;
  * render: path tracing Mpaths/s of the mesh above a floor under an area light, 128 x 128 at
    4 spp (the wavefront renderer's full 2^14 lanes; a 32 x 32 image has only 1024, and then
    every traversal loop runs half-empty: about 6 kpaths/s at 10^5 triangles).

Measured on 2 CPU cores shared with other jobs (load 4-6, so absolute figures are pessimistic;
the crossover is from interleaved best-of-5 timings):

     triangles  build s  closest Mrays/s  any Mrays/s     render 128^2 x 4 spp
          1024    0.11        0.80           0.93
         10000    0.14        0.60           0.60
         99856    1.42        0.17           0.23          0.027 Mpaths/s (compile 20 s)
       1000000   12.9         0.22           0.17          0.0069 Mpaths/s (compile 27 s)

    intersect + occluded, BVH / brute force: 0.27 at 64 triangles, 0.54 at 100, 0.83 at 196,
    0.92-1.05 at 256, 1.43-1.46 at 400, 2.0-2.1 at 576, 3.1 at 1024 (two runs): crossover at
    250-280 triangles. Since the brute-force scan takes blocks of 8 rows per loop iteration
    (2026-12-02, best of 3): 0.22 at 196, 0.24 at 256, 0.40 at 400, 0.55 at 576, 0.79 at 1024,
    1.16 at 1600, 1.71 at 2304, 2.67 at 4096: crossover at about 1400 triangles ->
    jgi.scene.BVH_MIN_TRIANGLES = 1400.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

RAYS = 1 << 16
CROSSOVER_SIZES = [16, 64, 196, 400, 1024, 1600, 2304, 4096]


def torus(n: int):
    """Triangles (v0, v1, v2) of a torus (major radius 1, minor 0.35) with 2n x n sections."""
    import trimesh

    m = trimesh.creation.torus(1.0, 0.35, major_sections=2 * n, minor_sections=n)
    f = np.asarray(m.vertices)[np.asarray(m.faces)]
    return f[:, 0], f[:, 1], f[:, 2]


def sections(triangles: int) -> int:
    return max(2, int(round(np.sqrt(triangles / 4))))


def rays(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n, 3))
    o = 3.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
    target = rng.uniform([-1.35, -1.35, -0.35], [1.35, 1.35, 0.35], (n, 3))
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    from jgi.core.vec import V3
    return V3.of(jnp.asarray(o, jnp.float32)), V3.of(jnp.asarray(d, jnp.float32))


def _time(fn, repeats: int):
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t0)
    return first, best


def bench_build_and_traversal(sizes, repeats: int) -> list[dict]:
    from jgi.core import bvh as B

    closest = jax.jit(lambda b, o, d: B.intersect_closest(b, o, d).t)
    anyhit = jax.jit(lambda b, o, d: B.intersect_any(b, o, d))
    o, d = rays(RAYS)
    rows = []
    for T in sizes:
        tris = torus(sections(T))
        t0 = time.perf_counter()
        bvh = B.build_bvh(*tris)
        build = time.perf_counter() - t0
        row = dict(bench="bvh", triangles=len(tris[0]), build_s=build,
                   nodes=bvh.node_count, leaves=int(bvh.leaves.shape[0]))
        c_first, c_best = _time(lambda: closest(bvh, o, d), repeats)
        a_first, a_best = _time(lambda: anyhit(bvh, o, d), repeats)
        hit = float(jnp.mean(jnp.isfinite(closest(bvh, o, d))))
        row.update(closest_mrays_s=RAYS / c_best / 1e6, any_mrays_s=RAYS / a_best / 1e6,
                   hit_fraction=hit, closest_first_call_s=c_first, any_first_call_s=a_first)
        rows.append(row)
        print(_fmt(row), flush=True)
    return rows


def _mesh_scene(tris, use_bvh: bool, resolution: int = 32):
    from jgi.scene import SceneBuilder

    b = SceneBuilder("torus", bvh=use_bvh)
    b.material("m", "diffuse", diffuse=(0.7, 0.7, 0.7))
    v = np.concatenate(tris)
    T = len(tris[0])
    f = np.arange(3 * T).reshape(3, T).T
    b.mesh(v, f, "m")
    b.quad((-3, -0.4, -3), (0, 0, 6), (6, 0, 0), "m")
    b.quad((-0.5, 2.0, -0.5), (1, 0, 0), (0, 0, 1), "m", emission=(8, 8, 8))
    b.camera((0, 1.5, 3.5), (0, 0, 0), width=resolution, height=resolution)
    return b.build()


def bench_crossover(sizes, repeats: int) -> list[dict]:
    """intersect + occluded rays/s with brute force and with a BVH: the torus, a floor and a
    light quad (best of ``repeats`` calls, the two variants interleaved)."""
    from jgi.physics import geometry as G

    @jax.jit
    def segment(scene, o, d):
        hit = G.intersect(scene, o, d)
        # shadow rays from the hit points (or the origins on a miss) towards a fixed point
        p = G.offset_origin(hit.p, hit.n, d * -1.0)
        target = jnp.asarray([0.0, 2.0, 0.0])
        from jgi.core.vec import V3
        to = V3(target[0] - p.x, target[1] - p.y, target[2] - p.z)
        return hit.t, G.occluded(scene, p, to, jnp.full(p.x.shape, 1.0 - 1e-4))

    o, d = rays(RAYS, seed=1)
    rows = []
    for T in sizes:
        tris = torus(sections(T))
        row = dict(bench="crossover", triangles=len(tris[0]))
        scenes = {"brute": _mesh_scene(tris, False), "bvh": _mesh_scene(tris, True)}
        best = {}
        for key, scene in scenes.items():
            row[f"{key}_first_call_s"], best[key] = _time(lambda: segment(scene, o, d), 0)
        for _ in range(repeats):
            for key, scene in scenes.items():
                best[key] = min(best[key], _time(lambda: segment(scene, o, d), 0)[0])
        for key in scenes:
            row[f"{key}_mrays_s"] = RAYS / best[key] / 1e6
        row["speedup"] = row["bvh_mrays_s"] / row["brute_mrays_s"]
        rows.append(row)
        print(_fmt(row), flush=True)
    return rows


def bench_render(sizes, spp: int, resolution: int = 128) -> list[dict]:
    import jgi

    rows = []
    for T in sizes:
        tris = torus(sections(T))
        t0 = time.perf_counter()
        scene = _mesh_scene(tris, True, resolution)
        scene_s = time.perf_counter() - t0
        W, H = scene.resolution
        first, best = _time(lambda: jgi.render(scene, "pt", spp=spp, seed=1), 1)
        img = jgi.render(scene, "pt", spp=spp, seed=1)
        row = dict(bench="render_pt", triangles=len(tris[0]), resolution=W, spp=spp,
                   mpaths_per_s=W * H * spp / best / 1e6, first_call_s=first,
                   scene_build_s=scene_s, mean=float(img.mean()),
                   nan=int(np.isnan(img).sum()))
        rows.append(row)
        print(_fmt(row), flush=True)
    return rows


def _fmt(row: dict) -> str:
    return "  ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                     for k, v in row.items())


def run(quick: bool) -> list[dict]:
    """All benchmarks (the hook for experiments/bench/bench.py)."""
    sizes = [10**3, 10**4, 10**5] if quick else [10**3, 10**4, 10**5, 10**6]
    small = CROSSOVER_SIZES[:-2] if quick else CROSSOVER_SIZES
    rows = bench_build_and_traversal(sizes, repeats=2)
    rows += bench_crossover(small, repeats=3 if quick else 5)
    rows += bench_render([10**5] if quick else [10**5, 10**6], spp=4)
    return rows


def table(rows: list[dict]) -> str:
    out = []
    b = [r for r in rows if r["bench"] == "bvh"]
    if b:
        out.append(f"{'triangles':>10} {'build s':>8} {'nodes':>9} {'closest Mrays/s':>16} "
                   f"{'any Mrays/s':>12} {'hit':>5}")
        out += [f"{r['triangles']:>10} {r['build_s']:>8.3f} {r['nodes']:>9} "
                f"{r['closest_mrays_s']:>16.3f} {r['any_mrays_s']:>12.3f} "
                f"{r['hit_fraction']:>5.2f}" for r in b]
    c = [r for r in rows if r["bench"] == "crossover"]
    if c:
        out.append(f"\n{'triangles':>10} {'brute Mrays/s':>14} {'BVH Mrays/s':>12} "
                   f"{'BVH/brute':>10}"
                   "   (intersect + occluded)")
        out += [f"{r['triangles']:>10} {r['brute_mrays_s']:>14.3f} {r['bvh_mrays_s']:>12.3f} "
                f"{r['speedup']:>10.2f}" for r in c]
    p = [r for r in rows if r["bench"] == "render_pt"]
    if p:
        out.append(f"\n{'triangles':>10} {'res':>4} {'spp':>4} {'Mpaths/s':>9} {'compile s':>10} "
                   f"{'scene s':>8} {'NaN':>4}")
        out += [f"{r['triangles']:>10} {r['resolution']:>4} {r['spp']:>4} "
                f"{r['mpaths_per_s']:>9.4f} {r['first_call_s']:>10.1f} {r['scene_build_s']:>8.2f} "
                f"{r['nan']:>4}" for r in p]
    return "\n".join(out)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="up to 10^5 triangles")
    ap.add_argument("--only", choices=["build", "crossover", "render"], default=None)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    sizes = [10**3, 10**4, 10**5] if a.quick else [10**3, 10**4, 10**5, 10**6]
    if a.only == "build":
        rows = bench_build_and_traversal(sizes, repeats=2)
    elif a.only == "crossover":
        rows = bench_crossover(CROSSOVER_SIZES, repeats=5)
    elif a.only == "render":
        rows = bench_render([10**5] if a.quick else [10**5, 10**6], spp=4)
    else:
        rows = run(a.quick)
    out = dict(rays=RAYS, backend=jax.default_backend(), rows=rows)
    print(json.dumps(out, indent=2, default=float))
    print(table(rows))
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(out, indent=2, default=float))
    return out


if __name__ == "__main__":
    main()
