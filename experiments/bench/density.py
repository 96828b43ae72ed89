"""Photon-density benchmark: hash-grid build time and density queries per second at 10^5, 10^6
and 10^7 photons, beside scipy's cKDTree on the same points and queries (the same run).

    python -m experiments.bench.density [--sizes 100000 1000000 10000000] [--queries 65536] [--k 50]

Photons lie on the plane z = 0, uniformly or in Gaussian clusters (the lumpy distribution of a
caustic). Both libraries answer the same question: the density estimate over the disc holding
about k photons (jgi: fixed radius through the hash grid; cKDTree: the k nearest neighbours,
`workers=-1`). Prints a table and one JSON line per row.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def photons(n: int, kind: str, rng):
    if kind == "uniform":
        xy = rng.random((n, 2))
    else:  # 64 Gaussian clusters of standard deviation 0.02 plus 20% uniform background
        centres = rng.random((64, 2))
        m = int(0.8 * n)
        xy = np.concatenate([centres[rng.integers(0, 64, m)] + 0.02 * rng.standard_normal((m, 2)),
                             rng.random((n - m, 2))])
    return np.concatenate([xy, np.zeros((n, 1))], 1).astype(np.float32)


def bench_jgi(p: np.ndarray, q: np.ndarray, radius: float) -> dict:
    import jax
    import jax.numpy as jnp

    from jgi.core.vec import V3
    from jgi.transport import density, hash_grid
    from jgi.transport.photons import PhotonMap

    n = len(p)
    col = lambda a: V3(a[:, 0], a[:, 1], a[:, 2])  # noqa: E731
    ones = np.full(n, 1.0 / n, np.float32)
    up = np.zeros((n, 3), np.float32)
    up[:, 2] = 1
    pm = PhotonMap(col(p), V3(ones, ones, ones), col(up), col(up), np.zeros(n, bool),
                   np.zeros(n, np.int32))
    t0 = time.perf_counter()
    grid = hash_grid.build_grid(pm, radius)
    jax.block_until_ready(grid.start)
    build = time.perf_counter() - t0
    cap = hash_grid.auto_cap(grid, limit=4096)
    chunk = hash_grid.query_chunk(cap)

    @jax.jit
    def query(grid, x, y):
        z = jnp.zeros_like(x)
        g = density.gather(grid, V3(x, y, z), V3(z, z, z + 1.0), cap)
        E, count = density.estimate(g, jnp.float32(radius * radius), jnp.float32(1.0))
        return E.x, count

    def run_all():
        outs = [query(grid, jnp.asarray(q[i:i + chunk, 0]), jnp.asarray(q[i:i + chunk, 1]))
                for i in range(0, len(q), chunk)]
        return jax.block_until_ready(outs)

    t0 = time.perf_counter()
    outs = run_all()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    outs = run_all()
    dt = time.perf_counter() - t0
    counts = np.concatenate([np.asarray(c) for _, c in outs])
    return dict(build_s=build, first_call_s=compile_s, queries_per_s=len(q) / dt, cap=cap,
                mean_photons_in_disc=float(counts.mean()))


def bench_kdtree(p: np.ndarray, q: np.ndarray, k: int) -> dict:
    from scipy.spatial import cKDTree

    t0 = time.perf_counter()
    tree = cKDTree(p)
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    tree.query(q, k=k, workers=-1)
    dt = time.perf_counter() - t0
    return dict(build_s=build, queries_per_s=len(q) / dt)


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000, 10_000_000])
    ap.add_argument("--queries", type=int, default=65536)
    ap.add_argument("--k", type=int, default=50)
    ap.add_argument("--kinds", nargs="+", default=["uniform", "clustered"])
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    rows = []
    print(f"{'photons':>10} {'kind':>9} | {'grid build s':>12} {'jgi Mq/s':>9} | "
          f"{'kd build s':>10} {'kd Mq/s':>8} | ratio")
    for n in a.sizes:
        for kind in a.kinds:
            p = photons(n, kind, rng)
            q = np.concatenate([rng.random((a.queries, 2)), np.zeros((a.queries, 1))],
                               1).astype(np.float32)
            radius = float(np.sqrt(a.k / (np.pi * n)))  # k photons in the disc at uniform density
            ours = bench_jgi(p, q, radius)
            theirs = bench_kdtree(p, q, a.k)
            row = dict(photons=n, kind=kind, k=a.k, radius=radius, jgi=ours, ckdtree=theirs,
                       ratio=ours["queries_per_s"] / theirs["queries_per_s"])
            rows.append(row)
            print(f"{n:>10} {kind:>9} | {ours['build_s']:>12.3f} "
                  f"{ours['queries_per_s'] / 1e6:>9.3f} | "
                  f"{theirs['build_s']:>10.3f} {theirs['queries_per_s'] / 1e6:>8.3f} | "
                  f"{row['ratio']:.2f}x")
            print(json.dumps(row))
    return rows


if __name__ == "__main__":
    main()
