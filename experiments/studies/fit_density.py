"""Differentiable fitting of photon-density parameters on the point light over a plane (exact
irradiance, see jgi.analysis.density_fit): the MSE-optimal radius as a function of photon count
and its scaling exponent (theory: -1/6), the optimal cone k, a Gaussian filter fitted by
gradient beside Jensen's constants (gauss_alpha = 0.918, gauss_beta = 1.953), and progressive
photon mapping's radius_alpha.

    python -m experiments.studies.fit_density [--out runs/fit_density] [--reps 8]
                                              [--photons 2500 5000 ...]

Prints a table and writes fit_density.json and fit_density.png.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def radius_guess(photons: int) -> float:
    return 0.57 * (photons / 5000) ** (-1 / 6)  # measured r* at 5000 photons, theory's scaling


def problem_for(photons: int, reps: int, seed: int):
    from jgi.analysis import density_fit as D

    r_max = 2.0 * radius_guess(photons)
    return D.point_light_problem(photons, reps, r_max=r_max,
                                 candidates=_candidates(photons, r_max), seed=seed)


def _candidates(photons: int, r_max: float) -> int:
    expected = 0.375 * photons * r_max * r_max  # photons within r_max of the brightest point
    return int(2 ** np.ceil(np.log2(max(64, 1.3 * expected))))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/fit_density")
    ap.add_argument("--reps", type=int, default=8)
    ap.add_argument("--photons", type=int, nargs="+", default=[2500, 5000, 10000, 20000, 40000])
    a = ap.parse_args(argv)

    import jax
    import jax.numpy as jnp
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jgi.analysis import density_fit as D
    from jgi.analysis import fitting as F
    from jgi.transport.density import gaussian_normaliser

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows = []
    curves = {}
    for i, n in enumerate(a.photons):
        p = problem_for(n, a.reps, seed=100 * i)
        loss = jax.jit(lambda r, p=p: D.relative_mse(p, r))
        fit = F.minimise(loss, radius_guess(n), log_space=True)
        r_star = float(fit.theta)
        grid = np.geomspace(0.3 * r_star, min(p.r_max, 1.8 * r_star), 24)
        curves[n] = (grid, np.array([float(loss(r)) for r in grid]))
        b2, var = (float(v) for v in D.mse_terms(p, r_star))
        rows.append(dict(photons=n, r_star=r_star, rel_mse=float(fit.value), bias2=b2, variance=var,
                         converged=fit.converged, steps=fit.steps))
        print(f"N={n:7d}  r*={r_star:.4f}  relMSE={float(fit.value):.3e}  "
              f"(bias² {b2:.2e}, variance {var:.2e})",
              file=sys.stderr)
    ns = np.array([r["photons"] for r in rows], float)
    slope_r, _, se_r = F.power_law(ns, [r["r_star"] for r in rows])
    slope_m, _, se_m = F.power_law(ns, [r["rel_mse"] for r in rows])

    # Filters at the middle photon count and its optimal radius.
    mid = rows[len(rows) // 2]
    p = problem_for(mid["photons"], a.reps, seed=999)
    r = mid["r_star"]
    cone = F.minimise(lambda y: D.relative_mse(p, r, "cone", k=1.0 + y * y), jnp.float32(0.5))
    cone_k = 1.0 + float(cone.theta) ** 2
    box = float(D.relative_mse(p, r, "box"))
    jensen = float(D.relative_mse(p, r, "gaussian", normalised=False, gauss_alpha=0.918,
                                  gauss_beta=1.953))

    def gauss(theta):
        return D.relative_mse(p, r, "gaussian", normalised=False, gauss_alpha=theta[0],
                              gauss_beta=jnp.exp(theta[1]))

    g = F.minimise(gauss, jnp.array([0.918, np.log(1.953)], jnp.float32))
    gauss_alpha, gauss_beta = float(g.theta[0]), float(np.exp(g.theta[1]))
    # Progressive photon mapping's radius_alpha, fitted by gradient for 8 passes from r0 = 2 r*(N).
    passes = 8
    r0 = min(2 * r, 1.2)
    pp = D.point_light_problem(mid["photons"], passes * max(2, a.reps // 2), r_max=r0,
                               candidates=_candidates(mid["photons"], r0), seed=4242)
    ploss = jax.jit(lambda al: D.progressive_relative_mse(pp, passes, r0, al))
    pfit = F.minimise(lambda y: ploss(jax.nn.sigmoid(y)), jnp.float32(0.0))
    alpha_star = float(jax.nn.sigmoid(pfit.theta))
    alphas = np.linspace(0.05, 0.95, 19)
    progressive = dict(passes=passes, r0=r0, radius_alpha=alpha_star, rel_mse=float(pfit.value),
                       curve=[(float(al), float(ploss(jnp.float32(al)))) for al in alphas])
    filters = dict(radius=r, photons=mid["photons"], box=box, epanechnikov=mid["rel_mse"],
                   cone=dict(k=cone_k, rel_mse=float(cone.value)),
                   gaussian_jensen=dict(gauss_alpha=0.918, gauss_beta=1.953, rel_mse=jensen,
                                        integral=float(gaussian_normaliser(0.918, 1.953))),
                   gaussian_fitted=dict(gauss_alpha=gauss_alpha, gauss_beta=gauss_beta,
                                        rel_mse=float(g.value),
                                        integral=float(gaussian_normaliser(gauss_alpha,
                                                                           gauss_beta))))
    summary = dict(rows=rows, r_star_exponent=slope_r, r_star_exponent_se=se_r,
                   theory_r_exponent=-1 / 6,
                   mse_exponent=slope_m, mse_exponent_se=se_m, theory_mse_exponent=-2 / 3,
                   filters=filters, progressive=progressive, repetitions=a.reps,
                   seconds=time.perf_counter() - t0)
    (out / "fit_density.json").write_text(json.dumps(summary, indent=2))

    fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    for n, (x, y) in curves.items():
        ax[0].loglog(x, y, label=f"N={n}")
    ax[0].loglog([r["r_star"] for r in rows], [r["rel_mse"] for r in rows], "k*", label="fitted r*")
    ax[0].set_xlabel("radius r")
    ax[0].set_ylabel("relative MSE (Epanechnikov)")
    ax[0].legend(fontsize=7)
    ax[1].loglog(ns, [r["r_star"] for r in rows], "o-", label=f"r* ~ N^{slope_r:.3f}±{se_r:.3f}")
    ax[1].loglog(ns, rows[0]["r_star"] * (ns / ns[0]) ** (-1 / 6), "k--", label="N^(-1/6)")
    ax[1].set_xlabel("photons N")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "fit_density.png", dpi=130)
    print(f"r* ~ N^{slope_r:.3f} ± {se_r:.3f} (theory -0.167); "
          f"relMSE* ~ N^{slope_m:.3f} ± {se_m:.3f} "
          f"(theory -0.667)")
    print(f"at N={mid['photons']}, r={r:.3f}: box {box:.3e}, Epanechnikov {mid['rel_mse']:.3e}, "
          f"cone k={cone_k:.3f} {float(cone.value):.3e}, Gaussian Jensen {jensen:.3e}, "
          f"Gaussian fitted gauss_alpha={gauss_alpha:.3f} gauss_beta={gauss_beta:.3f} "
          f"{float(g.value):.3e}")
    print(f"progressive photon mapping, {passes} passes from r0={progressive['r0']:.3f}: "
          f"MSE-optimal radius_alpha {alpha_star:.3f} (relMSE {progressive['rel_mse']:.3e}); "
          + ", ".join(f"radius_alpha {al:.2f}: {v:.2e}" for al, v in progressive["curve"][::6]))
    return summary


if __name__ == "__main__":
    main()
