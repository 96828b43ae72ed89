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
path tracer's up to the error of b, which the bootstrap makes small.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..core import rng
from ..core.vec import V3, luminance
from ..physics import camera as C
from ..scene.data import Scene
from .path_tracer import PathTracerConfig, radiance
from .registry import Estimator, Render, param, register

_SALT = rng.SALTS["pssmlt"]


@dataclass(frozen=True)
class PSSMLTConfig:
    """PSSMLT's parameters, all static: the path tracer's (``pt``) and the mutation's. The
    kernels see a copy with the chain and bootstrap counts at fixed values (:func:`render`)."""

    p_large: float = param(0.3, "probability of a large step (fresh sample)", minimum=0.0,
                           maximum=1.0)
    chains: int = param(4096, "Markov chains run in parallel", minimum=1)
    bootstrap_samples: int = param(65536, "independent samples to estimate b = E[f]", minimum=16)
    max_depth: int = param(8, "maximum path segments", minimum=1, maximum=64)
    rr_depth: int = param(5, "Russian roulette from this many segments (-1 = off)", minimum=-1)
    strategy: str = param("mis", "path tracer strategy inside MLT", choices=("bsdf", "light", "mis"))
    s1: float = 1.0 / 1024.0    # smallest and largest small-step sizes (Kelemen's)
    s2: float = 1.0 / 64.0
    steps_per_call: int = 16    # mutations per chain and kernel call

    @property
    def pt(self) -> PathTracerConfig:
        """The path tracer whose primary samples the chains explore."""
        return PathTracerConfig(strategy=self.strategy, max_depth=self.max_depth,
                                rr_depth=self.rr_depth)

    @property
    def dims(self) -> int:
        return 2 + self.pt.max_depth * self.pt.dims_per_bounce


def contribution(scene: Scene, cfg: PSSMLTConfig, u):
    """(L(u), f(u), pixel index) for primary samples ``u`` of shape [dims, N]."""
    W, H = scene.camera.width, scene.camera.height
    fx, fy = u[0] * W, u[1] * H
    px = jnp.clip(jnp.floor(fx).astype(jnp.int32), 0, W - 1)
    py = jnp.clip(jnp.floor(fy).astype(jnp.int32), 0, H - 1)
    o, d = C.sample_ray(scene.camera, px, py, fx - px, fy - py)
    L = radiance(scene, cfg.pt, lambda k: jnp.take(u, k, axis=0), o, d)
    L = V3(*(jnp.where(jnp.isfinite(c), c, 0.0) for c in L))
    return L, jnp.maximum(luminance(L), 0.0), py * W + px


def kelemen_small_step(u, xi_size, xi_sign, s1: float, s2: float):
    """Symmetric perturbation on the unit torus: u +- s2 exp(-log(s2/s1) xi)."""
    step = s2 * jnp.exp(-jnp.log(s2 / s1) * xi_size)
    v = u + jnp.where(xi_sign < 0.5, step, -step)
    return v - jnp.floor(v)


def _uniforms(key, first_dim, shape_d):
    return jnp.stack([rng.uniform(key, first_dim + k) for k in range(shape_d)])


@partial(jax.jit, static_argnames=("cfg", "n"))
def bootstrap(scene: Scene, cfg: PSSMLTConfig, seed, n: int):
    """n independent primary-sample vectors, their f, and the estimate of b = E[f]."""
    key = rng.derive(rng.path_key(seed, jnp.arange(n, dtype=jnp.int32), 0), _SALT)
    u = _uniforms(key, 0, cfg.dims)
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
    C_ = u0.shape[1]
    chain = jnp.arange(C_, dtype=jnp.int32)
    L0, f0, pix0 = contribution(scene, cfg, u0)

    def step(carry, t):
        u, L, f, pix, img, accepted = carry
        key = rng.derive(rng.path_key(seed, chain, step0 + t), _SALT + 1)
        large = rng.uniform(key, 0) < cfg.p_large
        fresh = _uniforms(key, 3, cfg.dims)
        small = kelemen_small_step(u, fresh, _uniforms(rng.derive(key, 7), 0, cfg.dims),
                                   cfg.s1, cfg.s2)
        u_new = jnp.where(large[None, :], _uniforms(rng.derive(key, 11), 0, cfg.dims), small)
        L_new, f_new, pix_new = contribution(scene, cfg, u_new)
        a = jnp.where(f > 0, jnp.minimum(1.0, f_new / jnp.where(f > 0, f, 1.0)), 1.0)
        live = t < n_live
        # expected-value splatting of the current and the proposed sample
        w_cur = jnp.where(live & (f > 0), (1.0 - a) / jnp.where(f > 0, f, 1.0), 0.0) * scale
        w_new = jnp.where(live & (f_new > 0), a / jnp.where(f_new > 0, f_new, 1.0), 0.0) * scale
        vals = jnp.stack([L.x * w_cur, L.y * w_cur, L.z * w_cur], -1)
        vals_new = jnp.stack([L_new.x * w_new, L_new.y * w_new, L_new.z * w_new], -1)
        img = img.at[pix].add(vals).at[pix_new].add(vals_new)
        take = (rng.uniform(key, 1) < a) & live
        u = jnp.where(take[None, :], u_new, u)
        L = V3(*(jnp.where(take, n, o) for n, o in zip(L_new, L)))
        f = jnp.where(take, f_new, f)
        pix = jnp.where(take, pix_new, pix)
        return (u, L, f, pix, img, accepted + jnp.sum(take)), None

    img0 = jnp.zeros((W * H, 3), jnp.float32)
    (u, L, f, pix, img, acc), _ = jax.lax.scan(step, (u0, L0, f0, pix0, img0, jnp.int32(0)),
                                               jnp.arange(n_steps, dtype=jnp.int32))
    return u, img, acc


def render(scene: Scene, cfg: PSSMLTConfig = PSSMLTConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """PSSMLT image with spp * W * H mutations in total (the path tracer's path count).

    Stats: ``b`` (the bootstrap estimate of E[f]), ``acceptance`` (accepted / proposed
    mutations), ``mutations``."""
    W, H = scene.camera.width, scene.camera.height
    chains, bootstrap_samples, steps_per_call = cfg.chains, cfg.bootstrap_samples, cfg.steps_per_call
    cfg = replace(cfg, chains=0, bootstrap_samples=0, steps_per_call=0)  # the kernels' key
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
                   render, PSSMLTConfig))
