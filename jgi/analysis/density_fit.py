"""Fitting photon-density-estimation parameters by gradient, where the answer is known.

The test bed is the lecture's point light over a diffuse plane: a point light of intensity I at
height h gives the plane the irradiance E(rho) = I h / (h^2 + rho^2)^(3/2) at distance rho from
the foot point, so the error of every photon estimate E_hat(x; theta) is exact, not measured
against a noisy reference. For a parameter vector theta (radius, cone k, the Gaussian's
gauss_alpha and gauss_beta) and R photon maps traced with fixed seeds (common random numbers)
the objective is the sample-average relative MSE over query points x_j:

    MSE_R(theta) = (1 / (R J)) sum_r sum_j (E_hat_r(x_j; theta) - E(x_j))^2 / E(x_j)^2

which is smooth in theta wherever the filter vanishes at the radius (cone with k = 1,
Epanechnikov): a photon crossing the disc's edge then changes the estimate continuously and
the pathwise gradient is the gradient of MSE_R. For filters that do not vanish at r (box,
Gaussian), crossings are jumps that ``jax.grad`` cannot see; their radius should not be fitted
by gradient (fitting gauss_alpha and gauss_beta at a fixed radius is fine).

Theory for the radius (2D kernel density estimation): bias ~ c_b r^2, variance ~ c_v / (N r^2),
so the MSE-optimal radius scales as r* ~ N^(-1/6) and the optimal MSE as N^(-2/3).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..core.vec import V3
from ..scene.builtin import point_light_plane
from ..transport import density, hash_grid
from ..transport.photons import trace_photons


class DensityProblem(NamedTuple):
    """Candidates (nearest photons first) around J query points, for R photon maps."""

    d2: Array          # [R, J, C] squared distances, ascending (inf past the last photon)
    power: Array       # [R, J, C] photon flux (one channel: the light is white)
    exact: Array       # [J] exact irradiance E(x_j)
    photons: int       # photons emitted per map
    r_max: float       # candidates are complete within this radius


def irradiance(rho, intensity: float, height: float):
    """E(rho) = I h / (h^2 + rho^2)^(3/2) for a point light at height h over a plane."""
    return intensity * height / (height * height + rho * rho) ** 1.5


def point_light_problem(photons: int, repetitions: int, *, intensity: float = 10.0,
                        height: float = 1.0,
                        extent: float = 0.8, points: int = 8, r_max: float = 0.6,
                        candidates: int = 2048, seed: int = 0) -> DensityProblem:
    """Trace ``repetitions`` photon maps of the point-light plane and gather, around a
    ``points`` x ``points`` grid of query points in [-extent, extent]^2, the ``candidates``
    nearest photons through the library's hash grid. Raises ValueError if the candidates do not
    cover ``r_max`` (the fit would then see a truncated estimate)."""
    scene = point_light_plane(resolution=4, intensity=intensity, height=height, albedo=0.5)
    u = np.linspace(-extent, extent, points)
    px, pz = (a.ravel() for a in np.meshgrid(u, u))
    x = V3(jnp.asarray(px, jnp.float32), jnp.zeros(px.size, jnp.float32),
           jnp.asarray(pz, jnp.float32))
    n = V3(jnp.zeros(px.size), jnp.ones(px.size), jnp.zeros(px.size))
    d2s, pows = [], []
    for r in range(repetitions):
        pm = trace_photons(scene, photons, seed=seed + 7919 * r, max_depth=1)
        grid = hash_grid.build_grid(pm, r_max)
        g = density.gather(grid, x, n, hash_grid.auto_cap(grid, limit=1 << 14))
        if bool(jnp.any(g.truncated)):
            raise ValueError(f"a grid cell holds more photons than the gather cap: "
                             f"lower r_max ({r_max})")
        neg, idx = jax.lax.top_k(-g.d2, candidates)
        d2 = -neg
        if bool(jnp.any(d2[:, -1] <= r_max * r_max)):
            raise ValueError(f"{candidates} candidates do not cover r_max = {r_max}; "
                             f"raise candidates")
        d2s.append(d2)
        pows.append(jnp.take_along_axis(g.power.x, idx, axis=1))
    exact = irradiance(jnp.sqrt(jnp.asarray(px * px + pz * pz, jnp.float32)), intensity, height)
    return DensityProblem(jnp.stack(d2s), jnp.stack(pows), exact, photons, r_max)


def estimate(problem: DensityProblem, r, kind: str = "epanechnikov", normalised: bool = True,
             **filter_params):
    """[R, J] irradiance estimates sum_p W(d_p) Phi_p / K; with ``normalised=False`` the Gaussian
    is used as Jensen wrote it, divided by pi r^2 only (``gauss_alpha`` then sets its scale)."""
    gathered = density.Gathered(problem.d2, V3(problem.power, problem.power, problem.power),
                                None, jnp.isfinite(problem.d2), None)
    E, _ = density.estimate(gathered, r * r, jnp.float32(1.0), kind, **filter_params)
    if kind == "gaussian" and not normalised:
        alpha = filter_params.get("gauss_alpha", density.JENSEN_ALPHA)
        return E.x * density.gaussian_normaliser(alpha, filter_params.get("gauss_beta",
                                                                          density.JENSEN_BETA))
    return E.x


def relative_mse(problem: DensityProblem, r, kind: str = "epanechnikov", normalised: bool = True,
                 **filter_params) -> Array:
    """MSE_R(theta) of the module docstring."""
    e = estimate(problem, r, kind, normalised, **filter_params) / problem.exact - 1.0
    return jnp.mean(e * e)


def mse_terms(problem: DensityProblem, r, kind: str = "epanechnikov", **filter_params):
    """(bias^2, variance) of the relative error averaged over query points, from the R maps."""
    e = estimate(problem, r, kind, **filter_params) / problem.exact - 1.0
    return jnp.mean(jnp.mean(e, 0) ** 2), jnp.mean(jnp.var(e, 0, ddof=1))


def progressive_estimate(problem: DensityProblem, passes: int, r0, radius_alpha):
    """Progressive photon mapping's estimate after ``passes`` passes (Hachisuka et al. 2008),
    with the R photon maps of ``problem`` split into R / passes independent sequences. Each pass
    i adds M_i photons of flux Phi_i found within r_i and shrinks the radius:

        N_{i+1} = N_i + a M_i,   r_{i+1}^2 = r_i^2 (N_i + a M_i) / (N_i + M_i),   (a = radius_alpha)
        tau_{i+1} = (tau_i + Phi_i) r_{i+1}^2 / r_i^2,   E = tau / (pi r^2 passes).

    M_i and Phi_i use the Epanechnikov kernel (M_i = sum_p W(d_p) / 0.5, the kernel integrating
    to half the disc), so the estimate is smooth in radius_alpha and r0 and ``jax.grad`` gives the
    derivative of the sample-average MSE. Returns [R / passes, J]. Candidates must cover r0."""
    R, J, Cn = problem.d2.shape
    seqs = R // passes
    d2 = problem.d2[: seqs * passes].reshape(seqs, passes, J, Cn)
    pw = problem.power[: seqs * passes].reshape(seqs, passes, J, Cn)
    r2 = jnp.full((seqs, J), r0 * r0, jnp.float32)
    n = jnp.zeros((seqs, J), jnp.float32)
    tau = jnp.zeros((seqs, J), jnp.float32)
    for i in range(passes):
        inside = d2[:, i] < r2[..., None]
        # the padded candidates are at infinity: keep them out of the division (NaN gradients)
        w = jnp.where(inside, 1.0 - jnp.where(inside, d2[:, i], 0.0) / r2[..., None], 0.0) / 0.5
        m = jnp.sum(w, -1)
        phi = jnp.sum(w * pw[:, i], -1)
        shrink = jnp.where(n + m > 0, (n + radius_alpha * m) / jnp.maximum(n + m, 1e-30), 1.0)
        tau = (tau + phi) * shrink
        r2 = r2 * shrink
        n = n + radius_alpha * m
    return tau / (jnp.pi * r2 * passes)


def progressive_relative_mse(problem: DensityProblem, passes: int, r0, radius_alpha) -> Array:
    e = progressive_estimate(problem, passes, r0, radius_alpha) / problem.exact - 1.0
    return jnp.mean(e * e)
