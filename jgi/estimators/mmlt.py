"""Multiplexed Metropolis light transport (Hachisuka, Kaplanyan, Dachsbacher 2014).

Metropolis-Hastings in the primary sample space of *bidirectional* path tracing, with the
choice of BDPT strategy made part of the state (pbrt-v4's MLTIntegrator is the model for the
structure; the code is ours and drives :func:`jgi.estimators.bdpt.contributions` through its
``uniforms`` argument). For a path length L (segments, s + t - 1 = L) the state is one vector
u of primary samples, in three streams as in pbrt-v4:

* u[0]: the strategy choice, s = floor(u[0] n_L) among the n_L strategies (s, t) of length L
  (``BDPTConfig.strategies``: s = 0 .. L, t = L + 1 - s, without (1, 1));
* the camera stream: film position (u_1 W, u_2 H) over the whole film, then 6 numbers per
  camera vertex (BSDF lobe and direction; the s = 1 light sample, i.e. the connection);
* the light stream: 5 numbers for the emission sample, then 3 per light vertex.

The target is f_L(u) = luminance of n_L w_{s,t} C*_{s,t}: the chosen strategy's MIS-weighted
contribution divided by the probability 1 / n_L of choosing it, so that E_u[n_L w C] over the
strategy dimension is the BDPT estimate of paths of length L. t = 1 strategies splat at the
film position that their light subpath projects to.

Chains: each path length L has its own chains (a fixed number, run in parallel as lanes), its
own normalisation b_L = E_u[f_L] from ``bootstrap_samples`` independent samples, and starts
from a resampling of its bootstrap samples in proportion to f (no start-up bias). Mutations
are shared out between lengths in proportion to b_L (pbrt-v4 picks each chain's depth with
probability proportional to b_L); the image uses each length's exact mutation count M_L, so
the allocation only affects efficiency:

    I_j = sum_L  W H b_L / M_L  sum_{mutations of length L}  (expected-value weight) C / f,

with Kelemen's small steps (every coordinate, the strategy choice included, moved by
+- s2 exp(-log(s2/s1) xi) on the torus: symmetric) and large steps (a fresh vector) as in
:mod:`jgi.estimators.pssmlt` (:func:`~jgi.estimators.pssmlt.kelemen_mutation`), acceptance
min(1, f'/f), and expected-value splatting of the current state (weight 1 - a) and the proposal
(weight a), all in the Metropolis kernel :func:`jgi.transport.mcmc.metropolis`.

Cost: every mutation evaluates all strategies of its length with subpaths of L and L - 1
segments (a BDPT sample restricted to length L: a next-event shadow ray at every camera vertex,
every interior connection, MIS of all L + 1 strategies) and keeps one (simple, not pbrt's
single-strategy evaluation); at equal lane counts that costs what a BDPT sample of max_depth L
does (measured, L = 5, 4096 lanes: 1.1e6 evaluations/s beside BDPT's 1.07e6 samples/s), and the
Metropolis step (mutation of 9 L + 5 coordinates, splats) about as much again. The chains are
shared by the path lengths (``chains // max_depth`` lanes each: 128 at max_depth 16, where XLA's
CPU backend is far from full speed), and the bootstrap costs ``bootstrap_samples`` evaluations
per length whatever the spp. Compilation dominates small renders: one chain kernel per path
length (the bootstrap runs through it too). ``experiments/bench/mmlt_vs_bdpt.py``, Cornell box
64^2, 16 spp, two shared CPU cores: max_depth 16, 4.2-4.9e4 mutations/s (the whole render,
bootstrap included) beside BDPT's 5.6-6.2e4 samples/s (ratio 0.67-0.87), compile 284 s beside
63 s; max_depth 5, 1.7-2.4e5 mutations/s beside 8.2-9.7e5 samples/s (ratio 0.17-0.26), compile
63 s beside 21 s.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..core import rng
from ..core.vec import V3, luminance, where
from ..scene.tables import Scene
from ..transport import mcmc
from ..transport.subpath import (
    CAMERA_DIMS0,
    CAMERA_DIMS_PER_STEP,
    LIGHT_DIMS0,
    LIGHT_DIMS_PER_STEP,
)
from .bdpt import BDPTConfig, contributions
from .pssmlt import PrimarySample, kelemen_mutation, splat_at
from .registry import Estimator, Render, param, register

_SALT = rng.SALTS["mmlt"]


@dataclass(frozen=True)
class MMLTConfig:
    """MMLT's parameters. The chain kernels see only heuristic, power, s1 and s2 (static):
    :func:`render` passes them a copy with the rest at fixed values, so one compilation per path
    length serves every max_depth, p_large (traced), chain and bootstrap count."""

    max_depth: int = param(5, "maximum path length (segments)", minimum=1, maximum=16)
    heuristic: str = param("power", "MIS heuristic over the strategies of one length",
                           choices=("balance", "power"))
    power: float = param(2.0, "power-heuristic exponent", minimum=0.1, maximum=16)
    p_large: float = param(0.3, "probability of a large step (fresh sample)", minimum=0.0,
                           maximum=1.0)
    chains: int = param(2048, "Markov chains run in parallel (shared evenly by the path lengths)",
                        minimum=1)
    bootstrap_samples: int = param(16384, "independent samples per path length to estimate b_L",
                                   minimum=16)
    s1: float = 1.0 / 1024.0    # smallest and largest small-step sizes (Kelemen's)
    s2: float = 1.0 / 64.0
    steps_per_call: int = 16    # mutations per chain and kernel call

    def bdpt(self, length: int) -> BDPTConfig:
        """BDPT restricted to one path length: subpaths just long enough for it."""
        return BDPTConfig(max_depth=length, heuristic=self.heuristic, power=self.power,
                          path_length=length)


def strategies(cfg: MMLTConfig, length: int) -> list[tuple[int, int]]:
    return cfg.bdpt(length).strategies()


def n_strategies(cfg: MMLTConfig, length: int) -> int:
    return len(strategies(cfg, length))


def stream_dims(length: int) -> tuple[int, int]:
    """(camera dims, light dims) for paths of ``length`` segments."""
    cam = CAMERA_DIMS0 + CAMERA_DIMS_PER_STEP * length
    light = LIGHT_DIMS0 + LIGHT_DIMS_PER_STEP * max(length - 1, 0)
    return cam, light


def dims(length: int) -> int:
    c, li = stream_dims(length)
    return 1 + c + li


def _callable(block):
    """uniform(dim) over the rows of ``block`` [d, N] (static or traced dim)."""
    def u(k):
        if isinstance(k, (int, np.integer)):
            return block[int(k)]
        return jax.lax.dynamic_index_in_dim(block, k, 0, keepdims=False)
    return u


def primary_streams(scene: Scene, length: int, u):
    """Split primary samples u [dims, N] into (strategy sample, flat pixel, camera uniform(dim),
    light uniform(dim)): the film position u_1 W, u_2 H picks the pixel, its fractional part is
    the camera's pixel jitter (dims 0, 1 of the camera stream)."""
    W, H = scene.camera.width, scene.camera.height
    nc, _ = stream_dims(length)
    cam = u[1:1 + nc]
    light = u[1 + nc:]
    fx, fy = cam[0] * W, cam[1] * H
    px = jnp.clip(jnp.floor(fx).astype(jnp.int32), 0, W - 1)
    py = jnp.clip(jnp.floor(fy).astype(jnp.int32), 0, H - 1)
    jitter = jnp.stack([jnp.clip(fx - px, 0.0, 0.99999994), jnp.clip(fy - py, 0.0, 0.99999994)])
    cam = jnp.concatenate([jitter, cam[2:]], 0)
    return u[0], py * W + px, _callable(cam), _callable(light)


def select(out: dict, sts: list, pixel, u_strat):
    """From BDPT's per-strategy results ``out`` (:func:`~jgi.estimators.bdpt.contributions`)
    pick the strategy numbered floor(u_strat n) of ``sts``: (n w C, f = its luminance >= 0,
    film pixel; value 0 and pixel 0 where it lands nowhere)."""
    n = len(sts)
    k = jnp.clip(jnp.floor(u_strat * n).astype(jnp.int32), 0, n - 1)
    z = jnp.zeros_like(u_strat)
    value = V3(z, z, z)
    pix = pixel
    for j, st in enumerate(sts):
        p, weighted, _ = out[st]
        sel = k == j
        value = where(sel, weighted, value)
        if p is not None:
            pix = jnp.where(sel, p, pix)
    ok = pix >= 0
    value = V3(*(jnp.where(ok & jnp.isfinite(c), c * n, 0.0) for c in value))
    f = jnp.maximum(luminance(value), 0.0)
    return value, f, jnp.where(ok, pix, 0)


def evaluate(scene: Scene, cfg: MMLTConfig, length: int, u):
    """(value V3, f, pixel) of primary samples u [dims(length), N]: the chosen strategy's
    n_L w_{s,t} C*_{s,t}, its luminance (the target) and the film pixel it lands on."""
    bcfg = cfg.bdpt(length)
    u_strat, pixel, uc, ul = primary_streams(scene, length, u)
    out = contributions(scene, bcfg, 0, pixel, 0, uniforms=(uc, ul))
    return select(out, bcfg.strategies(), pixel, u_strat)


@partial(jax.jit, static_argnames=("cfg", "length", "n_steps"))
def run_chains(scene: Scene, cfg: MMLTConfig, length: int, seed, state, step0, n_steps: int,
               scale, p_large):
    """Advance chains of one path length by n_steps mutations. ``state`` = (u [dims, C], value,
    f, pixel) of the current samples; returns the new state, the splatted image (times
    ``scale``), the number of accepted proposals and the proposals (u [n_steps, dims, C],
    value, f, pixel [n_steps, C]).

    With ``p_large = 1`` every proposal is an independent uniform sample: the bootstrap runs
    through this same kernel (one compilation per path length, not two)."""
    W, H = scene.camera.width, scene.camera.height

    def mutation(x: PrimarySample, key) -> mcmc.Move:
        v = kelemen_mutation(x.u, key, p_large, cfg.s1, cfg.s2)
        y = PrimarySample(v, *evaluate(scene, cfg, length, v))
        return mcmc.Move(y, x.f, y.f)

    x, img, tally, proposals = mcmc.metropolis(
        [mutation], PrimarySample(*state), n_steps, seed=seed, salt=_SALT + 1 + length,
        step0=step0, record=mcmc.splatting(splat_at, scale),
        acc0=jnp.zeros((W * H, 3), jnp.float32), emit_proposals=True)
    return x, img, jnp.sum(tally.accepted), proposals


_BOOT_STEP0 = 1 << 30     # bootstrap proposals: step indices no chain reaches


def bootstrap(scene: Scene, cfg: MMLTConfig, length: int, seed: int, n: int, chains: int,
              steps_per_call: int):
    """At least n independent samples of one path length, made by the chain kernel with
    p_large = 1 (each step a fresh vector, accepted whatever its f). Returns their states
    (u [dims, n'], value, f, pixel), numpy f as float64."""
    d = dims(length)
    z = jnp.zeros((chains,), jnp.float32)
    empty = (jnp.zeros((d, chains), jnp.float32), V3(z, z, z), z, jnp.zeros((chains,), jnp.int32))
    calls = max(1, -(-n // (chains * steps_per_call)))
    parts = []
    for c in range(calls):
        *_, prop = run_chains(scene, cfg, length, jnp.uint32(seed), empty,
                              jnp.int32(_BOOT_STEP0 + c * steps_per_call), steps_per_call,
                              jnp.float32(0.0), jnp.float32(1.0))
        parts.append(prop)
    # [calls, steps, ...] -> sample axis last (u) or flat
    u = jnp.concatenate([jnp.moveaxis(p_[0], 1, 0).reshape(d, -1) for p_ in parts], 1)
    val = V3(*(jnp.concatenate([p_[1][k].reshape(-1) for p_ in parts]) for k in range(3)))
    f = jnp.concatenate([p_[2].reshape(-1) for p_ in parts])
    pix = jnp.concatenate([p_[3].reshape(-1) for p_ in parts])
    return (u, val, f, pix), np.asarray(f, np.float64)


def render(scene: Scene, cfg: MMLTConfig = MMLTConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """MMLT image with about spp * W * H mutations in total, shared between path lengths in
    proportion to b_L (whole blocks of ``steps_per_call`` steps of ``chains // max_depth``
    chains per length; the image counts the mutations actually made, so it stays unbiased).

    Stats: ``b`` (sum of b_L), ``b_per_length``, ``blocks_per_length``, ``chains_per_length``,
    ``acceptance`` (accepted / proposed mutations), ``mutations``, ``seconds``."""
    W, H = scene.camera.width, scene.camera.height
    img = np.zeros((W * H, 3), np.float64)
    t0 = time.perf_counter()
    if scene.lights.count == 0:
        return Render(img.reshape(H, W, 3).astype(np.float32), {})
    chains, bootstrap_samples, steps_per_call = (cfg.chains, cfg.bootstrap_samples,
                                                 cfg.steps_per_call)
    lengths = list(range(1, cfg.max_depth + 1))
    per_len = max(1, chains // len(lengths))
    p_large = jnp.float32(cfg.p_large)
    # the kernels see neither max_depth nor p_large (a traced argument) nor the counts: one
    # compilation per path length serves every max_depth and p_large
    cfg = replace(cfg, max_depth=0, p_large=0.0, chains=0, bootstrap_samples=0, steps_per_call=0)
    boot = {}
    b = {}
    for L in lengths:
        boot[L] = bootstrap(scene, cfg, L, seed, bootstrap_samples, per_len, steps_per_call)
        b[L] = float(boot[L][1].mean())
    b_total = sum(b.values())
    total = spp * W * H
    accepted = mutations = 0
    blocks = {}
    for L in lengths:
        if not b[L] > 0:
            blocks[L] = 0
            continue
        (u_b, v_b, f_b, p_b), f_np = boot[L]
        cdf = np.cumsum(f_np) / f_np.sum()
        r = (np.arange(per_len) + 0.5) / per_len     # stratified resampling in proportion to f
        pick = jnp.asarray(np.minimum(np.searchsorted(cdf, r), len(f_np) - 1))
        state = (u_b[:, pick], V3(*(c[pick] for c in v_b)), f_b[pick], p_b[pick])
        n_blocks = max(1, int(round(total * b[L] / b_total / (per_len * steps_per_call))))
        blocks[L] = n_blocks
        n_mut = n_blocks * steps_per_call * per_len
        scale = jnp.float32(b[L] * W * H / n_mut)
        for blk in range(n_blocks):
            state, part, acc, _ = run_chains(scene, cfg, L, jnp.uint32(seed), state,
                                             jnp.int32(blk * steps_per_call), steps_per_call,
                                             scale, p_large)
            img += np.asarray(part, np.float64)
            accepted += int(acc)
        mutations += n_mut
    stats = dict(b=b_total, b_per_length=b, blocks_per_length=blocks, chains_per_length=per_len,
                 acceptance=accepted / mutations if mutations else 0.0, mutations=mutations,
                 seconds=time.perf_counter() - t0)
    return Render(img.reshape(H, W, 3).astype(np.float32), stats)


register(Estimator(
    "mmlt", "multiplexed Metropolis light transport over BDPT (strategy in the chain state)",
    render, MMLTConfig, renamed={"beta": "power"}))


def small_step_density(u, v, s1: float = MMLTConfig.s1, s2: float = MMLTConfig.s2):
    """Transition density T(u -> v) of :func:`~jgi.estimators.pssmlt.kelemen_small_step` on
    the unit torus, product over the first axis (float64 numpy): per coordinate the step is
    +-r with probability 1/2 each and log r uniform on [log s1, log s2], so the wrapped
    displacement d = v - u mod 1 has density (g(d) + g(1 - d)) / 2, g(r) = 1 / (r log(s2/s1))
    on [s1, s2]. Symmetric: T(u -> v) = T(v -> u), hence no correction in the acceptance."""
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    d = np.mod(v - u, 1.0)
    lo, hi = s1 * (1 - 1e-5), s2 * (1 + 1e-5)      # float32 rounding of the stored samples

    def g(r):
        inside = (r >= lo) & (r <= hi)
        return np.where(inside, 1.0 / (np.maximum(r, 1e-30) * np.log(s2 / s1)), 0.0)

    return np.prod(0.5 * (g(d) + g(1.0 - d)), axis=0)
