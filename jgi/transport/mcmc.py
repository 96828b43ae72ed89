"""Metropolis-Hastings as a pure, reusable sampler (the lecture's "basic algorithm").

A chain moves from x to a proposal x' ~ T(x -> .) and accepts it with probability

    a(x -> x') = min(1, f(x') T(x' -> x) / (f(x) T(x -> x')))

so that, with ergodic mutations, the samples are distributed in proportion to f. Proposals are
(sample, log_density) pairs, so the Hastings ratio is computed in one place
(:func:`acceptance_probability`) for symmetric and asymmetric mutations alike. Many chains run
in parallel (one lane each); every step's random numbers come from the counter-based hash of
(seed, chain, step), so a chain is reproducible and independent of how many run beside it.
Recorders receive both the current and the proposed state with their expected-value weights
(1 - a) and a, as Kelemen-style MLT splatting needs.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from ..core import rng

_SALT = rng.SALTS["mcmc"]


class Proposal(NamedTuple):
    """``sample(x, u) -> x'`` with u a [4 d + 1, chains] array of uniforms; ``log_density(x, x')``
    = log T(x -> x') (up to a constant shared by both directions)."""

    sample: Callable
    log_density: Callable


def acceptance_probability(f_x, f_y, log_t_xy, log_t_yx) -> Array:
    """a(x -> y) = min(1, f(y) T(y->x) / (f(x) T(x->y))); a = 1 when f(x) = 0."""
    ratio = jnp.where(f_x > 0, f_y / jnp.where(f_x > 0, f_x, 1.0), 1.0) * jnp.exp(log_t_yx - log_t_xy)
    return jnp.clip(jnp.where(jnp.isfinite(ratio), ratio, 0.0), 0.0, 1.0)


def gaussian_random_walk(sigma: float) -> Proposal:
    """x' = x + sigma N(0, 1) per coordinate (Box-Muller); symmetric."""
    def sample(x, u):
        d = x.shape[0]
        r = jnp.sqrt(-2.0 * jnp.log(jnp.maximum(u[:d], 1e-12)))
        return x + sigma * r * jnp.cos(2.0 * jnp.pi * u[d:2 * d])
    def log_density(x, y):
        return -0.5 * jnp.sum(((y - x) / sigma) ** 2, axis=0)
    return Proposal(sample, log_density)


def torus_random_walk(s1: float = 1 / 1024, s2: float = 1 / 64) -> Proposal:
    """Kelemen's small step on [0,1)^d: +-s2 exp(-log(s2/s1) xi), wrapped; symmetric."""
    def sample(x, u):
        d = x.shape[0]
        step = s2 * jnp.exp(-jnp.log(s2 / s1) * u[:d])
        y = x + jnp.where(u[d:2 * d] < 0.5, step, -step)
        return y - jnp.floor(y)
    def log_density(x, y):
        dist = jnp.abs((y - x + 0.5) % 1.0 - 0.5)
        # density of |step| = t: 1 / (t log(s2/s1)) on [s1, s2], halved for the sign
        inside = (dist >= s1 * (1 - 1e-6)) & (dist <= s2 * (1 + 1e-6))
        return jnp.sum(jnp.where(inside, -jnp.log(2.0 * dist * jnp.log(s2 / s1)), -jnp.inf), axis=0)
    return Proposal(sample, log_density)


def independent_uniform() -> Proposal:
    """A fresh uniform point of [0,1)^d (the MLT large step): T(x -> y) = 1."""
    return Proposal(lambda x, u: u[: x.shape[0]], lambda x, y: jnp.zeros(x.shape[1:]))


def log_normal_step(sigma: float) -> Proposal:
    """x' = x exp(sigma N(0,1)) on positive reals: asymmetric, T(x -> y) = N(log y; log x, s) / y."""
    def sample(x, u):
        d = x.shape[0]
        r = jnp.sqrt(-2.0 * jnp.log(jnp.maximum(u[:d], 1e-12)))
        return x * jnp.exp(sigma * r * jnp.cos(2.0 * jnp.pi * u[d:2 * d]))
    def log_density(x, y):
        z = (jnp.log(y) - jnp.log(x)) / sigma
        return jnp.sum(-0.5 * z * z - jnp.log(y), axis=0)
    return Proposal(sample, log_density)


def mixture(p_large: float, small: Proposal, large: Proposal) -> Proposal:
    """With probability p_large the large proposal, else the small one; the transition density is
    the mixture (1 - p) T_small + p T_large, as detailed balance requires."""
    def sample(x, u):
        d = x.shape[0]
        choose_large = u[0] < p_large
        return jnp.where(choose_large[None], large.sample(x, u[1:2 * d + 1]), small.sample(x, u[2 * d + 1:]))
    def log_density(x, y):
        return jnp.logaddexp(jnp.log1p(-p_large) + small.log_density(x, y),
                             jnp.log(p_large) + large.log_density(x, y))
    return Proposal(sample, log_density)


class ChainState(NamedTuple):
    x: Array         # [d, chains]
    f: Array         # [chains] target value f(x)
    accepted: Array  # [chains] accepted proposals
    steps: Array     # [chains]


def run_chains(target: Callable[[Array], Array], proposal: Proposal, x0: Array, n_steps: int,
               seed: int = 0, burn_in: int = 0, record: Callable | None = None, record_init=None,
               step0: int = 0):
    """Run ``x0.shape[1]`` chains for ``burn_in + n_steps`` steps (lax.scan). ``record(acc, x,
    w_x, y, w_y)`` folds every post-burn-in step into ``acc`` with expected-value weights
    (w_x = 1 - a for the current state, w_y = a for the proposal); without a recorder the final
    states are returned. Returns (state, acc)."""
    d, C = x0.shape
    n_u = 4 * d + 2
    chain = jnp.arange(C, dtype=jnp.int32)

    def step(carry, t):
        s, acc = carry
        key = rng.derive(rng.path_key(seed, chain, step0 + t), _SALT)
        u = jnp.stack([rng.uniform(key, k) for k in range(n_u)])
        y = proposal.sample(s.x, u[1:])
        f_y = target(y)
        a = acceptance_probability(s.f, f_y, proposal.log_density(s.x, y), proposal.log_density(y, s.x))
        if record is not None:
            live = t >= burn_in
            acc = jax.lax.cond(live, lambda a_: record(a_, s.x, 1.0 - a, y, a), lambda a_: a_, acc)
        take = u[0] < a
        x = jnp.where(take[None], y, s.x)
        return (ChainState(x, jnp.where(take, f_y, s.f), s.accepted + take, s.steps + 1), acc), None

    s0 = ChainState(x0, target(x0), jnp.zeros(C, jnp.int32), jnp.zeros(C, jnp.int32))
    (s, acc), _ = jax.lax.scan(step, (s0, record_init), jnp.arange(burn_in + n_steps, dtype=jnp.int32))
    return s, acc
