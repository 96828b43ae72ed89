"""The Metropolis-Hastings transition of every Markov-chain estimator in jgi, and a generic
sampler.

One transition of a chain (Veach 1997, ch. 11; Kelemen et al. 2002; Hachisuka et al. 2014):

1. a *mutation* proposes y ~ T(x -> .) from the current state x;
2. the move is accepted with probability

       a(x -> y) = min(1, f(y) T(y -> x) / (f(x) T(x -> y)))

   (:func:`acceptance_probability`), which makes f the chain's stationary density (detailed
   balance f(x) T(x -> y) a(x -> y) = f(y) T(y -> x) a(y -> x)) whatever the mutation, provided
   the mutations together are ergodic;
3. *expected-value splatting* (Veach 1997 and Kelemen et al. 2002 alike): the step records the
   current state with weight 1 - a and the proposal with weight a, the expected value of
   recording only the state the chain moves to, at the same cost and with less variance. In an
   image estimator, state z with weight w adds w (b M' / M) C(z) / f(z) to the pixel z lands on:
   C the contribution, f the target (its luminance), b = integral of f, M the number of
   mutations and M' the number of pixels;
4. a uniform u decides the move: the chain goes to y if u < a.

:func:`metropolis` runs this for many chains at once (one lane each, chain axis last in every
array of the state) and is the only place where jgi's estimators (PSSMLT, MMLT, Veach's MLT) and
:func:`run_chains` take a Metropolis step: each supplies its state, its mutations with their
transition densities, its target and what to record. Several mutation *kinds* (Veach's lens,
caustic and large steps) form a random mixture: each step applies one kind to all chains, chosen
with fixed probabilities; each kind preserves f, so the mixture does too, and only the chosen
kind's code runs. Acceptances are counted per kind.

Random numbers: step t of chain c reads the counter-based stream rng.derive(rng.path_key(seed,
c, t), salt) (its dimension ``accept_dim`` decides acceptance, the mutation uses the others and
derived sub-streams), so a chain is reproducible and independent of how many run beside it; the
kind of step t comes from stream rng.path_key(seed, -1, t), shared by all chains.

The generic sampler (:class:`Proposal`, :func:`run_chains`) writes mutations as (sample,
log_density) pairs, so the Hastings ratio is formed in one place for symmetric and asymmetric
mutations alike.
"""

from __future__ import annotations

import functools
import operator
from typing import Any, Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
from jax import Array

from ..core import rng

_SALT = rng.SALTS["mcmc"]
_KIND_CHAIN = -1   # the chain index of the stream that picks each step's mutation kind


# --- the transition -----------------------------------------------------------------------------

def acceptance_probability(f_x, f_y, log_t_xy, log_t_yx) -> Array:
    """a(x -> y) = min(1, f(y) T(y->x) / (f(x) T(x->y))); a = 1 when f(x) = 0 (a chain leaves a
    state of zero value at once). A ratio that is not finite (an overflow, 0/0, inf/inf) gives
    a = 0: rejecting the move in both directions keeps detailed balance, where accepting could
    trap a chain at a state of infinite f."""
    ratio = (jnp.where(f_x > 0, f_y / jnp.where(f_x > 0, f_x, 1.0), 1.0)
             * jnp.exp(log_t_yx - log_t_xy))
    return jnp.clip(jnp.where(jnp.isfinite(ratio), ratio, 0.0), 0.0, 1.0)


class Move(NamedTuple):
    """A proposed transition x -> y of every chain, as a mutation returns it to
    :func:`metropolis`. f and T may be written in any measure the mutation finds natural (film
    area, solid angle at a vertex, primary sample space), the same for f and T."""

    y: Any                           # the proposed state: the same pytree as x
    f_x: Array                       # [chains] f(x)
    f_y: Array                       # [chains] f(y)
    log_t_xy: Array | None = None    # [chains] log T(x -> y); both None: symmetric, T cancels
    log_t_yx: Array | None = None    # [chains] log T(y -> x)
    applicable: Array | None = None  # [chains] False: the mutation does not apply to x (a = 0)
    valid: Array | None = None       # [chains] False: it applied, but y is no state (a = 0)


class Tally(NamedTuple):
    """Per mutation kind and chain ([kinds, chains] int32), over the counted steps."""

    proposed: Array
    applicable: Array
    accepted: Array


def metropolis(mutations: Sequence[Callable], x0, n_steps: int, *, seed, salt, step0=0,
               n_live=None, kind_probs=None, record: Callable | None = None, acc0=None,
               burn_in: int = 0, accept_dim: int = 1, emit_proposals: bool = False):
    """Run ``n_steps`` Metropolis-Hastings transitions of the chains in state ``x0`` (lax.scan).

    mutations: ``mutation(x, key) -> Move``, one per kind; ``key`` [chains] is the step's stream
        (the mutation may use every dimension but ``accept_dim``, and rng.derive sub-streams).
        Several kinds run under lax.switch, so their Moves must have one structure (the same
        optional fields set).
    seed, salt, step0: the streams (see the module docstring); step t of this call is step
        step0 + t of the chain.
    n_live: only the first ``n_live`` (traced) steps count: the others neither record, move nor
        count (a render's last block runs masked instead of compiling a shorter one); None: all.
    kind_probs: [kinds] probabilities of the mutation kinds (needed with more than one).
    record: ``record(acc, x, w_x, y, w_y) -> acc`` folds each step into ``acc`` (initially
        ``acc0``) with the expected-value weights w_x = 1 - a, w_y = a (0 on uncounted steps);
        from step ``burn_in`` on (static); see :func:`splatting`.
    accept_dim: the dimension of the step's stream whose uniform decides acceptance.
    emit_proposals: also return every step's proposal y, stacked on a leading axis.

    Returns (state, acc, :class:`Tally`, proposals or None)."""
    C = jax.tree_util.tree_leaves(x0)[0].shape[-1]
    chain = jnp.arange(C, dtype=jnp.int32)
    n_kinds = len(mutations)
    if (n_kinds > 1) != (kind_probs is not None):
        raise ValueError("kind_probs is needed exactly when there is more than one mutation kind")
    if kind_probs is not None:
        kind_cdf = jnp.cumsum(kind_probs / jnp.sum(kind_probs))[:-1]

    def transition(carry, t):
        x, acc, tally = carry
        step = step0 + t
        key = rng.derive(rng.path_key(seed, chain, step), salt)
        # 1. propose y ~ T(x -> .) with one mutation kind for all chains
        if n_kinds == 1:
            kind, move = 0, mutations[0](x, key)
        else:
            u_kind = rng.uniform(rng.path_key(seed, _KIND_CHAIN, step), 0)
            kind = jnp.sum(u_kind >= kind_cdf).astype(jnp.int32)
            move = jax.lax.switch(kind, mutations, x, key)
        # 2. a(x -> y)
        if move.log_t_xy is None and move.log_t_yx is None:
            a = acceptance_probability(move.f_x, move.f_y, 0.0, 0.0)
        else:
            a = acceptance_probability(move.f_x, move.f_y, move.log_t_xy, move.log_t_yx)
        masks = [m for m in (move.applicable, move.valid) if m is not None]
        if masks:
            a = jnp.where(functools.reduce(operator.and_, masks), a, 0.0)
        counted = jnp.ones(C, bool) if n_live is None else jnp.broadcast_to(t < n_live, (C,))
        # 3. expected-value splatting: x with 1 - a, y with a
        w_x, w_y = 1.0 - a, a
        if n_live is not None:
            w_x, w_y = jnp.where(counted, w_x, 0.0), jnp.where(counted, w_y, 0.0)
        if record is not None and burn_in:
            acc = jax.lax.cond(t >= burn_in, lambda acc: record(acc, x, w_x, move.y, w_y),
                               lambda acc: acc, acc)
        elif record is not None:
            acc = record(acc, x, w_x, move.y, w_y)
        # 4. accept by a uniform; chain axis last in every leaf, so [chains] masks broadcast
        take = (rng.uniform(key, accept_dim) < a) & counted
        x = jax.tree_util.tree_map(lambda y_, x_: jnp.where(take, y_, x_), move.y, x)
        applicable = counted if move.applicable is None else counted & move.applicable
        tally = Tally(*(n.at[kind].add(m.astype(jnp.int32))
                        for n, m in zip(tally, (counted, applicable, take))))
        return (x, acc, tally), (move.y if emit_proposals else None)

    zeros = jnp.zeros((n_kinds, C), jnp.int32)
    (x, acc, tally), proposals = jax.lax.scan(transition, (x0, acc0, Tally(zeros, zeros, zeros)),
                                              jnp.arange(n_steps, dtype=jnp.int32))
    return x, acc, tally, proposals


def splat(image: Array, pixel: Array, value, f: Array, w: Array, scale=1.0) -> Array:
    """Expected-value splat into ``image`` [pixels, channels]: image[pixel] += (w / f) scale
    value per chain (nothing where f = 0). ``value``: the channels of the contribution C, each
    [chains]; f its target value; scale = b M' / M (see the module docstring)."""
    wf = jnp.where(f > 0, w / jnp.where(f > 0, f, 1.0), 0.0) * scale
    return image.at[pixel].add(jnp.stack([c * wf for c in value], -1))


def splatting(measure: Callable, scale) -> Callable:
    """A ``record`` for :func:`metropolis` that splats the current and the proposed state into
    an image; ``measure(state) -> (pixel, value, f)`` says where a state lands, what it
    contributes and its target value."""
    def record(image, x, w_x, y, w_y):
        image = splat(image, *measure(x), w_x, scale)
        return splat(image, *measure(y), w_y, scale)
    return record


# --- generic proposals on R^d and [0, 1)^d ------------------------------------------------------

class Proposal(NamedTuple):
    """``sample(x, u) -> x'`` with u a [4 d + 1, chains] array of uniforms; ``log_density(x, x')``
    = log T(x -> x') (up to a constant shared by both directions)."""

    sample: Callable
    log_density: Callable


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
    """x' = x exp(sigma N(0,1)) on positive reals: asymmetric,
    T(x -> y) = N(log y; log x, s) / y."""
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
        return jnp.where(choose_large[None], large.sample(x, u[1:2 * d + 1]),
                         small.sample(x, u[2 * d + 1:]))
    def log_density(x, y):
        return jnp.logaddexp(jnp.log1p(-p_large) + small.log_density(x, y),
                             jnp.log(p_large) + large.log_density(x, y))
    return Proposal(sample, log_density)


class ChainState(NamedTuple):
    x: Array         # [d, chains]
    f: Array         # [chains] target value f(x)
    accepted: Array  # [chains] accepted proposals
    steps: Array     # [chains]


class _Point(NamedTuple):
    x: Array   # [d, chains]
    f: Array   # [chains] f(x)


def run_chains(target: Callable[[Array], Array], proposal: Proposal, x0: Array, n_steps: int,
               seed: int = 0, burn_in: int = 0, record: Callable | None = None, record_init=None,
               step0: int = 0):
    """Run ``x0.shape[1]`` chains for ``burn_in + n_steps`` steps of :func:`metropolis`.
    ``record(acc, x, w_x, y, w_y)`` folds every post-burn-in step into ``acc`` with
    expected-value weights (w_x = 1 - a for the current state, w_y = a for the proposal);
    without a recorder the final states are returned. Returns (state, acc)."""
    d, _ = x0.shape
    n_u = 4 * d + 2   # dimension 0 decides acceptance, the proposal reads 1 .. 4 d + 1

    def mutation(p: _Point, key) -> Move:
        y = proposal.sample(p.x, rng.uniforms(key, 1, n_u - 1))
        f_y = target(y)
        return Move(_Point(y, f_y), p.f, f_y, proposal.log_density(p.x, y),
                    proposal.log_density(y, p.x))

    on_points = None if record is None else (
        lambda acc, p, w_x, q, w_y: record(acc, p.x, w_x, q.x, w_y))
    p, acc, tally, _ = metropolis([mutation], _Point(x0, target(x0)), burn_in + n_steps,
                                  seed=seed, salt=_SALT, step0=step0, record=on_points,
                                  acc0=record_init, burn_in=burn_in, accept_dim=0)
    return ChainState(p.x, p.f, tally.accepted[0], tally.proposed[0]), acc
