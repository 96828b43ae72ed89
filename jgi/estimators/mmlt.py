"""Multiplexed Metropolis light transport (Hachisuka, Kaplanyan, Dachsbacher 2014).

Metropolis-Hastings in the primary sample space of *bidirectional* path tracing, with the
choice of BDPT strategy made part of the state (pbrt-v4's MLTIntegrator::L is the model; the
code is ours). A chain has a fixed path length L (segments, s + t - 1 = L); its state is one
vector u of primary samples sized for max_depth, in three streams as in pbrt-v4 (a path of
length L reads a prefix of each):

* u[0]: the strategy choice, s = floor(u[0] n_L) among the n_L strategies (s, t) of length L
  (``BDPTConfig.strategies``: s = 0 .. L, t = L + 1 - s, without (1, 1));
* the camera stream: film position (u_1 W, u_2 H) over the whole film, then 6 numbers per
  camera vertex (BSDF lobe and direction; the s = 1 light sample, i.e. the connection);
* the light stream: 5 numbers for the emission sample, then 3 per light vertex.

The target is f_L(u) = luminance of n_L w_{s,t} C*_{s,t}: the chosen strategy's MIS-weighted
contribution divided by the probability 1 / n_L of choosing it, so that E_u[n_L w C] over the
strategy dimension is the BDPT estimate of paths of length L. t = 1 strategies splat at the
film position that their light subpath projects to.

A mutation evaluates only its chosen strategy (:func:`evaluate`): the subpaths are traced from
the streams, one connection of the kind (s, t) needs is made (s = 0: the emitter or the
environment found by z_{t-1}; s = 1: next-event estimation at z_{t-1}; t = 1: y_{s-1} to the
pinhole; s, t >= 2: y_{s-1} to z_{t-1}), with BDPT's own functions for each
(:func:`~jgi.estimators.bdpt.emitter_strategy`, ``environment_strategy``,
``next_event_strategy``, :mod:`jgi.transport.connection`), one shadow ray per lane, and only
w_{s,t}, by :func:`jgi.estimators.bdpt.strategy_weight` (BDPT's ratio steps,
:func:`~jgi.estimators.bdpt.ratio_step`, walked for one traced (s, t) per lane). tests/test_mmlt.py
checks it lane by lane against BDPT's all-strategy evaluation (:func:`select`).

Participating media (a scene filled by a homogeneous medium) come with BDPT's subpaths: each
walk step draws its two free-flight numbers too (:func:`stream_dims`), and the strategies'
densities carry the segments' distance densities as BDPT's do. In a grid medium too: the
trackings' streams are functions of the primary samples (the flights' of two of each step's
numbers, :func:`jgi.core.rng.substream`; a connection's of its shadow ray,
:func:`jgi.transport.connection.shadow_transmittance`), so a primary sample still maps to one
path and one contribution, and a lane tracks only the connection its strategy makes.

Chains: one kernel (:func:`run_chains`) runs chains of every length, L a traced value per
lane. The bootstrap runs through it with p_large = 1 (lanes assigned lengths round-robin) and
gives each length's normalisation b_L = E_u[f_L] from ``bootstrap_samples`` independent
samples. The chains are then shared between lengths in proportion to b_L (each length with
b_L > 0 gets at least one; pbrt-v4 picks each chain's depth with probability proportional to
b_L) and start from a resampling of their length's bootstrap samples in proportion to f (no
start-up bias). The image uses each length's exact mutation count M_L, so the allocation only
affects efficiency:

    I_j = sum_L  W H b_L / M_L  sum_{mutations of length L}  (expected-value weight) C / f,

with Kelemen's small steps (every coordinate, the strategy choice included, moved by
+- s2 exp(-log(s2/s1) xi) on the torus: symmetric) and large steps (a fresh vector) as in
:mod:`jgi.estimators.pssmlt` (:func:`~jgi.estimators.pssmlt.kelemen_mutation`), acceptance
min(1, f'/f), and expected-value splatting of the current state (weight 1 - a) and the proposal
(weight a), all in the Metropolis kernel :func:`jgi.transport.mcmc.metropolis`.

Cost (docs/performance.md#mmlt): a mutation traces both subpaths as far as its length needs
(static sizes, but the walk stops where no lane of the batch needs another vertex) and makes
one connection and one shadow ray, where a BDPT sample
makes every connection (a shadow ray at each camera vertex and for every (s, t)); and the
Metropolis step adds the mutation of dims(max_depth) coordinates and two splats. One
compilation per max_depth. ``experiments/bench/mmlt_vs_bdpt.py``
(Cornell box 64^2, 16 spp, two CPU cores shared with another job, three runs): max_depth 5,
6.2-6.3e5 mutations/s (the whole render, bootstrap included) beside BDPT's 5.0-6.4e5 samples/s
in the same runs (ratio 1.22, 1.24, 0.98), the chains alone 1.4e6/s; max_depth 16, 2.2-6.1e4
beside 2.0-6.1e4 (ratio 0.86, 0.99, 1.09), the chains alone 9.5e4/s under load (the bootstrap,
16384 samples per length, is 4x the render's mutations there). Compile+first render 20-23 s
(max_depth 5) and 18-33 s (16), against 63 s and 284 s for the former per-length kernels.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._xla import materialize
from ..core import calls, rng
from ..core.vec import V3, dot, luminance, where
from ..physics import bsdf
from ..scene.tables import Scene
from ..transport import mcmc
from ..transport.connection import connect_camera, occluded_many
from ..transport.subpath import (
    CAMERA_DIMS0,
    CAMERA_DIMS_PER_STEP,
    LIGHT_DIMS0,
    LIGHT_DIMS_PER_STEP,
    area_density,
    camera_dims_per_step,
    light_dims_per_step,
    light_subpath,
    mis_delta,
    segment_density,
)
from .bdpt import (
    BDPTConfig,
    LaneSubpath,
    camera_subpath,
    emitter_strategy,
    environment_strategy,
    interior_connection,
    log_remap0,
    next_event_strategy,
    reverse_at_predecessor,
    strategy_weight,
)
from .pssmlt import PrimarySample, kelemen_mutation, splat_at
from .registry import Estimator, Render, param, register

_SALT = rng.SALTS["mmlt"]
_CHAIN_SALT = _SALT + 2     # the chains' streams (one kernel for every path length)


@dataclass(frozen=True)
class MMLTConfig:
    """MMLT's parameters. The chain kernel sees only max_depth (the size of the primary-sample
    vector and of the subpaths), heuristic, power, s1 and s2 (static): :func:`render` passes it
    a copy with the rest at fixed values, so one compilation per max_depth serves every
    p_large (traced), chain and bootstrap count."""

    max_depth: int = param(5, "maximum path length (segments)", minimum=1, maximum=16)
    heuristic: str = param("power", "MIS heuristic over the strategies of one length",
                           choices=("balance", "power"))
    power: float = param(2.0, "power-heuristic exponent", minimum=0.1, maximum=16)
    p_large: float = param(0.3, "probability of a large step (fresh sample)", minimum=0.0,
                           maximum=1.0)
    chains: int = param(2048, "Markov chains run in parallel (shared by the path lengths in "
                        "proportion to b_L)", minimum=1)
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


def stream_dims(length: int, scene: Scene | None = None) -> tuple[int, int]:
    """(camera dims, light dims) for paths of up to ``length`` segments (in a scene filled by a
    medium each step has its two free-flight numbers more: ``scene``; None: vacuum)."""
    cam_step = CAMERA_DIMS_PER_STEP if scene is None else camera_dims_per_step(scene)
    light_step = LIGHT_DIMS_PER_STEP if scene is None else light_dims_per_step(scene)
    cam = CAMERA_DIMS0 + cam_step * length
    light = LIGHT_DIMS0 + light_step * max(length - 1, 0)
    return cam, light


def dims(length: int, scene: Scene | None = None) -> int:
    c, li = stream_dims(length, scene)
    return 1 + c + li


def _callable(block):
    """uniform(dim) over the rows of ``block`` [d, N] (static or traced dim)."""
    def u(k):
        if isinstance(k, (int, np.integer)):
            return block[int(k)]
        return jax.lax.dynamic_index_in_dim(block, k, 0, keepdims=False)
    return u


def _streams(scene: Scene, length: int, u):
    """(strategy sample, flat pixel, camera stream [dims, N], light stream [dims, N]) of
    primary samples u [dims(length), N]; see :func:`primary_streams`."""
    W, H = scene.camera.width, scene.camera.height
    nc, _ = stream_dims(length, scene)
    cam = u[1:1 + nc]
    light = u[1 + nc:]
    fx, fy = cam[0] * W, cam[1] * H
    px = jnp.clip(jnp.floor(fx).astype(jnp.int32), 0, W - 1)
    py = jnp.clip(jnp.floor(fy).astype(jnp.int32), 0, H - 1)
    jitter = jnp.stack([jnp.clip(fx - px, 0.0, 0.99999994), jnp.clip(fy - py, 0.0, 0.99999994)])
    cam = jnp.concatenate([jitter, cam[2:]], 0)
    return u[0], py * W + px, cam, light


def primary_streams(scene: Scene, length: int, u):
    """Split primary samples u [dims, N] into (strategy sample, flat pixel, camera uniform(dim),
    light uniform(dim)): the film position u_1 W, u_2 H picks the pixel, its fractional part is
    the camera's pixel jitter (dims 0, 1 of the camera stream). ``length`` is the longest path
    the vector serves (max_depth): a shorter path uses a prefix of each stream."""
    u_strat, pixel, cam, light = _streams(scene, length, u)
    return u_strat, pixel, _callable(cam), _callable(light)


def select(out: dict, sts: list, pixel, u_strat):
    """From BDPT's per-strategy results ``out`` (:func:`~jgi.estimators.bdpt.contributions`)
    pick the strategy numbered floor(u_strat n) of ``sts``: (n w C, f = its luminance >= 0,
    film pixel; value 0 and pixel 0 where it lands nowhere). The reference that
    :func:`evaluate` (one strategy per lane) is tested against."""
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
    return _target(value, n, pix)


def _target(weighted: V3, n, pix):
    """(n w C, f, pixel): zero where the strategy lands nowhere or is not finite."""
    ok = pix >= 0
    value = V3(*(jnp.where(ok & jnp.isfinite(c), c * n, 0.0) for c in weighted))
    f = jnp.maximum(luminance(value), 0.0)
    return value, f, jnp.where(ok, pix, 0)


def choose_strategy(u_strat, length):
    """(s, t, n_L) per lane: strategy number floor(u_strat n_L) of paths of ``length`` segments
    (traced [N]), in :meth:`BDPTConfig.strategies`'s order: s = 0 .. L, t = L + 1 - s, without
    (1, 1) (length 1 has only (0, 2))."""
    n = jnp.where(length >= 2, length + 1, 1)
    s = jnp.clip(jnp.floor(u_strat * n).astype(jnp.int32), 0, n - 1)
    return s, length + 1 - s, n


def _at(tree, idx):
    """Row ``idx`` (traced [N], one per lane) of every [K, N] leaf, by a chain of selects (a
    gather runs as a slow, unfused loop on XLA's CPU backend)."""
    def pick(x):
        out = x[0]
        for k in range(1, x.shape[0]):
            out = jnp.where(idx == k, x[k], out)
        return out
    return jax.tree_util.tree_map(pick, tree)


def _select_ray(masks_rays, default):
    """The shadow ray of the connection each lane makes: the first of (mask, ray) whose mask
    holds, else ``default``."""
    o, d, tmax = default
    for m, (o2, d2, t2) in reversed(masks_rays):
        o, d, tmax = where(m, o2, o), where(m, d2, d), jnp.where(m, t2, tmax)
    return o, d, tmax


def evaluate(scene: Scene, cfg: MMLTConfig, u, length):
    """(value V3, f, pixel) of primary samples u [dims(cfg.max_depth), N] for paths of
    ``length`` segments (traced [N], 1 .. max_depth): the chosen strategy's n_L w_{s,t}
    C*_{s,t}, its luminance (the target) and the film pixel it lands on.

    Only that strategy is evaluated (pbrt-v4's MLTIntegrator::L): the subpaths are traced to
    max_depth (static sizes; a lane reads the s and t vertices it needs), one connection of the
    kind (s, t) needs is made, with one shadow ray per lane, and its MIS weight is
    :func:`jgi.estimators.bdpt.strategy_weight`, the ratio steps BDPT's weights are made of."""
    D = cfg.max_depth
    bcfg = cfg.bdpt(D)
    lights = scene.lights
    mats = scene.materials
    env = lights.environment >= 0
    u_strat, pixel, cam_u, light_u = _streams(scene, D, u)
    s, t, n = choose_strategy(u_strat, length)

    def records(v):
        return dict(alive=v.state.alive, pdf_dir=v.state.pdf_dir) if env else None

    # walk only as far as some lane of the batch needs: z_1 .. z_{t-1}, y_1 .. y_{s-1}
    cam, rec = camera_subpath(scene, bcfg, None, pixel, _callable(cam_u), visit=records,
                              n_live=jnp.max(t) - 1)
    lp = light_subpath(scene, None, D, infinite=True, uniform=_callable(light_u),
                       n_live=jnp.max(s) - 1)
    light = lp.vertices
    is_s0, is_s1, is_t1 = s == 0, s == 1, t == 1
    z, zm = _at(cam, t - 1), _at(cam, jnp.maximum(t - 2, 0))
    y, ym = _at(light, jnp.maximum(s - 1, 0)), _at(light, jnp.maximum(s - 2, 0))
    # in a grid medium each connection below tracks its transmittance on the lanes where it is
    # valid: only the lanes whose strategy makes it (the others' values are not read)
    grid = scene.has_grid_medium
    only = lambda v, kind: v._replace(valid=v.valid & kind) if grid else v  # noqa: E731
    zero = jnp.zeros_like(u_strat)
    Z = V3(zero, zero, zero)
    # z_{t-1} and the vertex before it, as the walk that found z_{t-1} saw them
    vz = z.p - zm.p
    d2_prev, cos_prev = dot(vz, vz), dot(zm.n, -z.wo)

    # ---- s = 0: z_{t-1} on an emitter, or at infinity on the environment ----
    em = emitter_strategy(lights, z.emitter, z.n, z.wo, z.beta, d2_prev, cos_prev,
                          zm.on_surface)
    c0, pt0, ptm0 = em["s0_value"], em["s0_rev_pt"], em["s0_rev_ptm"]
    if cam.in_medium is not None:   # z_{t-2} reached from the light across a medium segment
        ptm0 = ptm0 * segment_density(scene, d2_prev, ~zm.on_surface, z.medium)
    if env:
        alive, pdf_dir = _at((rec["alive"], rec["pdf_dir"]), jnp.maximum(t - 2, 0))
        escaped = alive & ~z.valid
        ev = environment_strategy(lights, escaped, z.beta, -z.wo, pdf_dir, zm.n, zm.on_surface)
        c0 = where(escaped, ev["env_value"], c0)
        pt0 = jnp.where(escaped, ev["env_rev_pt"], pt0)
        ptm0 = jnp.where(escaped, ev["env_rev_ptm"], ptm0)
    # ---- s = 1: light sampling at z_{t-1}, with the walk's light-sample numbers there ----
    step = camera_dims_per_step(scene)
    ne_u = [_at(jnp.stack([cam_u[CAMERA_DIMS0 + step * j + k]
                           for j in range(D)]), jnp.maximum(t - 2, 0)) for k in (3, 4, 5)]
    mp = bsdf.lookup_specialised(mats, z.material, z.uv)
    c1, shadow1, d1 = next_event_strategy(scene, mp, z.p, z.n, z.ns, z.wo, z.beta, *ne_u,
                                          only(z, is_s1).valid, d2_prev, cos_prev,
                                          zm.on_surface, z.in_medium, z.medium, z.material)
    # ---- t = 1: y_{s-1} seen from the pinhole, splatted where it projects ----
    conn = connect_camera(scene, only(y, is_t1))
    vy = ym.p - y.p
    qsm_t1 = reverse_at_predecessor(lights, lp, s - 1, conn.pdf_y_rev, area_density(
        scene, conn.pdf_y_rev, dot(vy, vy), dot(ym.n, y.wo), ym.on_surface, ym.in_medium,
        y.medium))
    # ---- s, t >= 2: y_{s-1} <-> z_{t-1} ----
    c_in, shadow_in, rev_in = interior_connection(scene, y, ym,
                                                  only(z, ~is_s0 & ~is_s1 & ~is_t1), zm)
    qsm_in = reverse_at_predecessor(lights, lp, s - 1, rev_in.get("qsm_solid"), rev_in["qsm"])
    # ---- one shadow ray per lane: the one its connection needs (none for s = 0) ----
    occ, = occluded_many(scene, [_select_ray([(is_s1, shadow1), (is_t1, conn.shadow)],
                                             shadow_in)])
    c = where(is_s0, c0, where(occ, Z, where(is_s1, c1, where(is_t1, conn.value, c_in))))
    pix = jnp.where(is_t1, jnp.where(occ, -1, conn.pixel), pixel)

    # ---- MIS: this strategy's view of the subpaths' densities, then w_{s,t} ----
    pt = jnp.where(is_s0, pt0, jnp.where(is_s1, d1["s1_rev_pt"], rev_in["pt"]))
    ptm = jnp.where(is_s0, ptm0, jnp.where(is_s1, d1["s1_rev_ptm"], rev_in["ptm"]))
    cam_delta = mis_delta(cam)
    cam_rows = LaneSubpath([], [], [])
    for k in range(D + 1):
        fwd = cam.pdf_fwd[k]
        if env:
            fwd = jnp.where(is_s0 & escaped & (t - 1 == k), ev["env_fwd"], fwd)
        rev = jnp.where(t - 1 == k, pt, jnp.where(t - 2 == k, ptm, cam.pdf_rev[k]))
        cam_rows.log_fwd.append(log_remap0(fwd))
        cam_rows.log_rev.append(log_remap0(rev))
        cam_rows.delta.append(cam_delta[k] & (t - 1 != k))
    qs = jnp.where(is_t1, conn.pdf_cam, rev_in["qs"])
    qsm = jnp.where(is_t1, qsm_t1, qsm_in)
    light_delta = mis_delta(light)
    light_rows = LaneSubpath([], [], [])
    for k in range(D):
        y0 = is_s1 & (k == 0)
        fwd = jnp.where(y0, d1["s1_fwd_y"], light.pdf_fwd[k])
        rev = jnp.where(y0, d1["s1_rev_y"],
                        jnp.where(s - 1 == k, qs, jnp.where(s - 2 == k, qsm, light.pdf_rev[k])))
        light_rows.log_fwd.append(log_remap0(fwd))
        light_rows.log_rev.append(log_remap0(rev))
        light_rows.delta.append(light_delta[k] & (s - 1 != k))
    delta_light = jnp.where(is_s1, d1["s1_delta_light"], lp.delta_light)
    w = strategy_weight(cam_rows, light_rows, delta_light, s, t, bcfg.exponent)
    return _target(c * w, n.astype(jnp.float32), pix)


@partial(jax.jit, static_argnames=("cfg", "n_steps"))
def run_chains(scene: Scene, cfg: MMLTConfig, seed, state, lengths, step0, n_steps: int, scale,
               p_large):
    """Advance chains by n_steps mutations. ``state`` = (u [dims, C], value, f, pixel) of the
    current samples, ``lengths`` [C] each chain's path length, ``scale`` [C] its splat scale;
    returns the new state, the splatted image, the number of accepted proposals and the
    proposals (u [n_steps, dims, C], value, f, pixel [n_steps, C]).

    One kernel for every path length (lengths are traced); with ``p_large = 1`` every proposal
    is an independent uniform sample: the bootstrap runs through this same kernel."""
    W, H = scene.camera.width, scene.camera.height

    def mutation(x: PrimarySample, key) -> mcmc.Move:
        # the proposal and its evaluation stored once, row by row (perf: docs/performance.md#mmlt)
        v = kelemen_mutation(x.u, key, p_large, cfg.s1, cfg.s2)
        v = jnp.stack(materialize([v[i] for i in range(v.shape[0])]))
        y = PrimarySample(v, *materialize(evaluate(scene, cfg, v, lengths)))
        return mcmc.Move(y, x.f, y.f)

    x, img, tally, proposals = mcmc.metropolis(
        [mutation], PrimarySample(*state), n_steps, seed=seed, salt=_CHAIN_SALT,
        step0=step0, record=mcmc.splatting(splat_at, scale),
        acc0=jnp.zeros((W * H, 3), jnp.float32), emit_proposals=True)
    return x, img, jnp.sum(tally.accepted), proposals


_BOOT_STEP0 = 1 << 30     # bootstrap proposals: step indices no chain reaches
_GROUP_STEPS = 1 << 26    # chain group g runs steps g * _GROUP_STEPS + ...: its own streams


def _empty_state(d: int, chains: int):
    z = jnp.zeros((chains,), jnp.float32)
    return (jnp.zeros((d, chains), jnp.float32), V3(z, z, z), z, jnp.zeros((chains,), jnp.int32))


def _lanes(chains: int, max_depth: int, streams: int) -> int:
    """Lanes per kernel call: the chains shared by ``streams`` concurrent calls, and at least one
    lane per path length (the bootstrap's round-robin)."""
    return max(-(-chains // streams), max_depth)


def bootstrap(scene: Scene, cfg: MMLTConfig, seed: int, n: int, lanes: int, steps_per_call: int,
              streams: int = 1):
    """At least n independent samples of every path length 1 .. cfg.max_depth, made by the chain
    kernel (``lanes`` lanes) with p_large = 1 (each step a fresh vector, accepted whatever its
    f). Each call samples one length in all its lanes (call c: length 1 + c mod max_depth), so
    its walks stop at that length (:func:`evaluate`); the calls are independent and run
    ``streams`` at a time (perf: docs/performance.md#concurrent-calls). Returns (u [max_depth,
    samples, dims, lanes], value, f, pixel [max_depth, samples, lanes]) and {L: numpy f of
    length L, flat, as float64}."""
    D = cfg.max_depth
    per_length = max(1, -(-n // (lanes * steps_per_call)))
    empty = _empty_state(dims(D, scene), lanes)
    zero = jnp.zeros((lanes,), jnp.float32)

    def call(c):
        length = jnp.full((lanes,), 1 + c % D, jnp.int32)
        *_, prop = run_chains(scene, cfg, jnp.uint32(seed), empty, length,
                              jnp.int32(_BOOT_STEP0 + c * steps_per_call), steps_per_call, zero,
                              jnp.float32(1.0))
        return jax.block_until_ready(prop)

    parts = list(calls.ordered_calls(call, per_length * D, streams=streams))
    # [length, call, step, ...]: shapes that depend on no estimate (no recompilation per render)
    out = jax.tree_util.tree_map(
        lambda *xs: jnp.stack(xs).reshape((per_length, D) + xs[0].shape).swapaxes(0, 1)
        .reshape((D, per_length * steps_per_call) + xs[0].shape[1:]), *parts)
    f_np = np.asarray(out[2], np.float64)
    return out, {L: f_np[L - 1].reshape(-1) for L in range(1, D + 1)}


def _chain_counts(b: dict, chains: int) -> dict:
    """Chains per path length in proportion to b_L, at least one for every b_L > 0, summing to
    ``chains`` (at least the number of such lengths)."""
    live = [L for L in b if b[L] > 0]
    if not live:
        return {L: 0 for L in b}
    total = sum(b[L] for L in live)
    chains = max(chains, len(live))
    share = {L: chains * b[L] / total for L in live}
    counts = {L: max(1, int(share[L])) for L in live}
    while sum(counts.values()) > chains:
        L = max(counts, key=lambda k: (counts[k], k))
        counts[L] -= 1
    for L in sorted(live, key=lambda k: share[k] - int(share[k]), reverse=True):
        if sum(counts.values()) >= chains:
            break
        counts[L] += 1
    while sum(counts.values()) < chains:
        counts[max(live, key=lambda k: b[k])] += 1
    return {L: counts.get(L, 0) for L in b}


def render(scene: Scene, cfg: MMLTConfig = MMLTConfig(), *, spp: int, seed: int,
           progress: bool = False) -> Render:
    """MMLT image with at least spp * W * H mutations in total. Every chain has one path length;
    the chains are shared between lengths in proportion to b_L (each length with b_L > 0 gets
    at least one), sorted by length, and all run in one kernel, as ``CALL_STREAMS`` groups of
    lanes, each group's
    calls in its own thread (perf: docs/performance.md#mmlt); the image weighs each length's
    splats by b_L W H / M_L with M_L its exact mutation count, so it stays unbiased. The groups'
    images are added in group order: nothing depends on timing.

    Stats: ``b`` (sum of b_L), ``b_per_length``, ``chains_per_length``, ``calls`` (per group),
    ``acceptance`` (accepted / proposed mutations), ``mutations``, ``bootstrap_seconds`` (of
    ``seconds``, the whole render's wall time)."""
    W, H = scene.camera.width, scene.camera.height
    img = np.zeros((W * H, 3), np.float64)
    t0 = time.perf_counter()
    if scene.lights.count == 0:
        return Render(img.reshape(H, W, 3).astype(np.float32), {})
    D = cfg.max_depth
    streams = calls.CALL_STREAMS
    lanes = _lanes(cfg.chains, D, streams)
    chains = lanes * streams
    steps = cfg.steps_per_call
    p_large = jnp.float32(cfg.p_large)
    # the kernel sees neither p_large (a traced argument) nor the counts: one compilation per
    # max_depth (and lane count) serves every p_large, chain and bootstrap count
    kcfg = replace(cfg, p_large=0.0, chains=0, bootstrap_samples=0, steps_per_call=0)
    boot, f_boot = bootstrap(scene, kcfg, seed, cfg.bootstrap_samples, lanes, steps, streams)
    b = {L: float(f_boot[L].mean()) for L in f_boot}
    t_boot = time.perf_counter() - t0
    counts = _chain_counts(b, chains)
    live = [L for L in counts if counts[L] > 0]
    if not live:
        return Render(img.reshape(H, W, 3).astype(np.float32),
                      dict(b=0.0, b_per_length=b, chains_per_length=counts, calls=0,
                           acceptance=0.0, mutations=0, bootstrap_seconds=t_boot,
                           seconds=time.perf_counter() - t0))
    n_calls = max(1, -(-spp * W * H // (chains * steps)))
    lane_len, picks, scale = [], [], []
    for L in live:       # chains sorted by length: a group of short ones walks less far
        f_np = f_boot[L]
        cdf = np.cumsum(f_np) / f_np.sum()
        r = (np.arange(counts[L]) + 0.5) / counts[L]   # stratified resampling in proportion to f
        picks.append(np.minimum(np.searchsorted(cdf, r), len(f_np) - 1))
        lane_len += [L] * counts[L]
        scale += [b[L] * W * H / (n_calls * steps * counts[L])] * counts[L]
    pick = np.concatenate(picks)
    Li = jnp.asarray(np.array(lane_len) - 1)
    si, li = jnp.asarray(pick // lanes), jnp.asarray(pick % lanes)
    u_b, v_b, f_b, p_b = boot
    state = (u_b[Li, si, :, li].T, V3(*(c[Li, si, li] for c in v_b)), f_b[Li, si, li],
             p_b[Li, si, li])
    del boot, u_b, v_b, f_b, p_b
    lane_len = np.array(lane_len, np.int32)
    scale = np.array(scale, np.float32)

    def group(g):
        """Chains g * lanes .. (g + 1) * lanes - 1, all their calls, in order."""
        part = slice(g * lanes, (g + 1) * lanes)
        x = jax.tree_util.tree_map(lambda a: a[..., part], state)
        lengths, sc = jnp.asarray(lane_len[part]), jnp.asarray(scale[part])
        acc_img, accepted = np.zeros((W * H, 3), np.float64), 0
        for blk in range(n_calls):
            x, part_img, acc, _ = run_chains(scene, kcfg, jnp.uint32(seed), x, lengths,
                                             jnp.int32(g * _GROUP_STEPS + blk * steps), steps,
                                             sc, p_large)
            acc_img += np.asarray(part_img, np.float64)
            accepted += int(acc)
        return acc_img, accepted

    accepted = 0
    for part_img, acc in calls.ordered_calls(group, streams, streams=streams):
        img += part_img
        accepted += acc
    mutations = n_calls * steps * chains
    stats = dict(b=sum(b.values()), b_per_length=b, chains_per_length=counts, calls=n_calls,
                 acceptance=accepted / mutations, mutations=mutations,
                 bootstrap_seconds=t_boot, seconds=time.perf_counter() - t0)
    return Render(img.reshape(H, W, 3).astype(np.float32), stats)


register(Estimator(
    "mmlt", "multiplexed Metropolis light transport over BDPT (strategy in the chain state)",
    render, MMLTConfig, renamed={"beta": "power"}, media=True, grid_media=True))


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
