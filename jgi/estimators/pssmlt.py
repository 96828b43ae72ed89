"""Primary-sample-space Metropolis light transport (Kelemen, Szirmay-Kalos, Antal, Csonka 2002).

The path tracer is a deterministic function of a vector of uniforms u in [0,1)^d (its
*primary samples*): u_0, u_1 choose the film position, the rest drive every decision along
the path. PSSMLT runs Metropolis-Hastings on u with target f(u) = luminance of the path's
radiance L(u) (the lecture's "once we find a good path, perturb it"):

* **small step** (probability 1 - p_large): every coordinate moves by
  +- s2 exp(-log(s2 / s1) xi), wrapped onto the unit torus; symmetric, T(u->u') = T(u'->u);
* **large step** (probability p_large): a fresh uniform vector; independent of u, so also
  symmetric in the ratio; it keeps the chain ergodic;
* acceptance a = min(1, f(u') / f(u)) (the transition densities cancel);
* **expected-value splatting**: every step records the current sample with weight (1 - a) and
  the proposal with weight a, each as b L / f at its film position, where
  b = E_u[f(u)] is estimated from ``bootstrap`` independent samples. With M mutations in total
  and a box pixel filter, pixel j receives (W H b / M) sum (weight L / f).

Chains start from a resampling of the bootstrap samples in proportion to f (no start-up bias)
and run in parallel (one lane per chain). The image is consistent: its expectation equals the
path tracer's up to the error of b, which the bootstrap makes small. The Metropolis step itself
(acceptance, splatting, the accept decision) is :func:`jgi.transport.mcmc.metropolis`; this module
supplies the state (:class:`PrimarySample`), the mutation and the target.

Participating media come with the path tracer: its free-flight numbers (channel, distance) are
two more primary samples per bounce, mutated like the others.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..core import rng
from ..core.vec import V3, luminance
from ..physics import camera
from ..scene.tables import Scene
from ..transport import mcmc
from .path_tracer import PathTracerConfig, dims_per_bounce, radiance
from .registry import Estimator, Render, param, register

_SALT = rng.SALTS["pssmlt"]


@dataclass(frozen=True)
class PSSMLTConfig:
    """PSSMLT's parameters, all static: the path tracer's (``pt``) and the mutation's. The
    compiled kernels see a copy with the chain and bootstrap counts at fixed values
    (:func:`render`)."""

    p_large: float = param(0.3, "probability of a large step (fresh sample)", minimum=0.0,
                           maximum=1.0)
    chains: int = param(4096, "Markov chains run in parallel", minimum=1)
    bootstrap_samples: int = param(65536, "independent samples to estimate b = E[f]", minimum=16)
    max_depth: int = param(8, "maximum path segments", minimum=1, maximum=64)
    rr_depth: int = param(5, "Russian roulette from this many segments (-1 = off)", minimum=-1)
    strategy: str = param("mis", "path tracer strategy inside MLT",
                          choices=("bsdf", "light", "mis"))
    s1: float = 1.0 / 1024.0    # smallest and largest small-step sizes (Kelemen's)
    s2: float = 1.0 / 64.0
    steps_per_call: int = 16    # mutations per chain and kernel call

    @property
    def pt(self) -> PathTracerConfig:
        """The path tracer whose primary samples the chains explore."""
        return PathTracerConfig(strategy=self.strategy, max_depth=self.max_depth,
                                rr_depth=self.rr_depth)


def dims(cfg: PSSMLTConfig, scene: Scene) -> int:
    """Length of the primary-sample vector: the pixel position, then the path tracer's numbers
    per bounce (:func:`~jgi.estimators.path_tracer.dims_per_bounce`: two more in a medium)."""
    return 2 + cfg.pt.max_depth * dims_per_bounce(cfg.pt, scene)


def contribution(scene: Scene, cfg: PSSMLTConfig, u):
    """(L(u), f(u), pixel index) for primary samples ``u`` of shape [dims, N]."""
    W, H = scene.camera.width, scene.camera.height
    fx, fy = u[0] * W, u[1] * H
    px = jnp.clip(jnp.floor(fx).astype(jnp.int32), 0, W - 1)
    py = jnp.clip(jnp.floor(fy).astype(jnp.int32), 0, H - 1)
    o, d = camera.sample_ray(scene.camera, px, py, fx - px, fy - py)
    L = radiance(scene, cfg.pt, lambda k: jnp.take(u, k, axis=0), o, d)
    L = V3(*(jnp.where(jnp.isfinite(c), c, 0.0) for c in L))
    return L, jnp.maximum(luminance(L), 0.0), py * W + px


def kelemen_small_step(u, xi_size, xi_sign, s1: float, s2: float):
    """Symmetric perturbation on the unit torus: u +- s2 exp(-log(s2/s1) xi)."""
    step = s2 * jnp.exp(-jnp.log(s2 / s1) * xi_size)
    v = u + jnp.where(xi_sign < 0.5, step, -step)
    return v - jnp.floor(v)


def kelemen_mutation(u, key, p_large, s1: float, s2: float):
    """Kelemen's mutation of primary samples u [d, chains], from the step's stream ``key`` of
    :func:`jgi.transport.mcmc.metropolis`: with probability p_large (dimension 0) a large step,
    a fresh vector (sub-stream 11); else a small step of every coordinate, sizes from dimensions
    3 .. d + 2 and directions from sub-stream 7. Both are symmetric, so T cancels in
    a(u -> v)."""
    d = u.shape[0]
    large = rng.uniform(key, 0) < p_large
    small = kelemen_small_step(u, rng.uniforms(key, 3, d), rng.uniforms(rng.derive(key, 7), 0, d),
                               s1, s2)
    return jnp.where(large[None, :], rng.uniforms(rng.derive(key, 11), 0, d), small)


class PrimarySample(NamedTuple):
    """A chain's state in primary sample space, with its evaluation (all [chains] but u)."""

    u: Array          # [dims, chains] the primary samples
    value: V3         # the contribution it splats (PSSMLT: L(u))
    f: Array          # the target f(u), the luminance of ``value``
    pixel: Array      # int32 flat film pixel it splats to


def splat_at(x: PrimarySample):
    """(pixel, value, f) of a primary sample, for :func:`jgi.transport.mcmc.splatting`."""
    return x.pixel, x.value, x.f


@partial(jax.jit, static_argnames=("cfg", "n"))
def bootstrap(scene: Scene, cfg: PSSMLTConfig, seed, n: int):
    """n independent primary-sample vectors, their f, and the estimate of b = E[f]."""
    key = rng.derive(rng.path_key(seed, jnp.arange(n, dtype=jnp.int32), 0), _SALT)
    u = rng.uniforms(key, 0, dims(cfg, scene))
    _, f, _ = contribution(scene, cfg, u)
    return u, f


@partial(jax.jit, static_argnames=("cfg", "n_steps"))
def run_chains(scene: Scene, cfg: PSSMLTConfig, seed, u0, step0, n_steps: int, scale, n_live=None):
    """Advance chains (state u0 [dims, C]) by n_steps mutations, of which only the first
    ``n_live`` (traced; default all) count: the last block of a render runs masked instead of
    compiling a shorter one. Returns the new state, the splatted image sums (times ``scale``)
    and the number of accepted proposals."""
    n_live = n_steps if n_live is None else n_live
    W, H = scene.camera.width, scene.camera.height

    def mutation(x: PrimarySample, key) -> mcmc.Move:
        v = kelemen_mutation(x.u, key, cfg.p_large, cfg.s1, cfg.s2)
        y = PrimarySample(v, *contribution(scene, cfg, v))
        return mcmc.Move(y, x.f, y.f)

    x0 = PrimarySample(u0, *contribution(scene, cfg, u0))
    x, img, tally, _ = mcmc.metropolis([mutation], x0, n_steps, seed=seed, salt=_SALT + 1,
                                       step0=step0, n_live=n_live,
                                       record=mcmc.splatting(splat_at, scale),
                                       acc0=jnp.zeros((W * H, 3), jnp.float32))
    return x.u, img, jnp.sum(tally.accepted)


def render(scene: Scene, cfg: PSSMLTConfig = PSSMLTConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """PSSMLT image with spp * W * H mutations in total (the path tracer's path count).

    Stats: ``b`` (the bootstrap estimate of E[f]), ``acceptance`` (accepted / proposed
    mutations), ``mutations``."""
    W, H = scene.camera.width, scene.camera.height
    chains, bootstrap_samples, steps_per_call = (cfg.chains, cfg.bootstrap_samples,
                                                 cfg.steps_per_call)
    cfg = replace(cfg, chains=0, bootstrap_samples=0, steps_per_call=0)  # the compile key
    u_b, f_b = bootstrap(scene, cfg, jnp.uint32(seed), bootstrap_samples)
    f_np = np.asarray(f_b, np.float64)
    b = f_np.mean()
    if not b > 0:
        return Render(np.zeros((H, W, 3), np.float32), {})
    # start chains from the bootstrap samples, resampled in proportion to f
    cdf = np.cumsum(f_np) / f_np.sum()
    r = (np.arange(chains) + 0.5) / chains  # stratified resampling: deterministic given seed
    pick = np.minimum(np.searchsorted(cdf, r), bootstrap_samples - 1)
    u = jnp.asarray(np.asarray(u_b)[:, pick])
    total = spp * W * H
    n_steps_total = max(1, -(-total // chains))
    # blocks of steps_per_call, the last one masked: one compiled kernel for every spp
    scale = jnp.float32(b * W * H / (n_steps_total * chains))
    img = np.zeros((W * H, 3), np.float64)
    accepted = 0
    done = 0
    while done < n_steps_total:
        n = min(steps_per_call, n_steps_total - done)
        u, part, acc = run_chains(scene, cfg, jnp.uint32(seed), u, jnp.int32(done), steps_per_call,
                                  scale, jnp.int32(n))
        img += np.asarray(part, np.float64)
        accepted += int(acc)
        done += n
    stats = dict(b=b, acceptance=accepted / (n_steps_total * chains),
                 mutations=n_steps_total * chains)
    return Render(img.reshape(H, W, 3).astype(np.float32), stats)


register(Estimator("pssmlt", "primary-sample-space Metropolis light transport over the path tracer",
                   render, PSSMLTConfig, media=True, grid_media=True))
