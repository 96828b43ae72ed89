"""Metropolis-Hastings: stationary distributions, Hastings correction, detailed balance."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from jgi.core import rng
from jgi.transport import mcmc

C = 4096  # independent chains: one final state each gives independent samples


def final_states(target, proposal, x0, steps, seed=1):
    fn = jax.jit(lambda x: mcmc.run_chains(target, proposal, x, steps, seed=seed))
    s, _ = fn(x0)
    return s


def test_discrete_target_histogram_matches(rng_np):
    w = jnp.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    target = lambda x: w[jnp.clip(jnp.floor(x[0] * 6).astype(jnp.int32), 0, 5)]
    prop = mcmc.mixture(0.2, mcmc.torus_random_walk(0.01, 0.2), mcmc.independent_uniform())
    s = final_states(target, prop, jnp.asarray(rng_np.random((1, C)), jnp.float32), 200)
    h = np.bincount(np.clip((np.asarray(s.x[0]) * 6).astype(int), 0, 5), minlength=6)
    expected = np.asarray(w, np.float64) / float(w.sum()) * C
    assert stats.chisquare(h, expected).pvalue > 1e-3, h
    rate = float(s.accepted.mean()) / 200
    assert 0.2 < rate < 1.0


def gamma3(x):
    """f(x) = x^2 e^-x on x > 0 (a Gamma(3) density up to a constant)."""
    return jnp.where(x[0] > 0, x[0] ** 2 * jnp.exp(-x[0]), 0.0)


def _hist_pvalue(samples):
    edges = np.concatenate([np.linspace(0, 10, 21), [np.inf]])
    h, _ = np.histogram(samples, edges)
    cdf = stats.gamma(3).cdf(edges)
    return stats.chisquare(h, np.diff(cdf) * len(samples)).pvalue


def test_hastings_correction_is_needed_and_applied(rng_np):
    x0 = jnp.asarray(rng_np.gamma(3.0, size=(1, C)), jnp.float32)
    prop = mcmc.log_normal_step(0.8)
    s = final_states(gamma3, prop, x0, 150)
    assert _hist_pvalue(np.asarray(s.x[0])) > 1e-3
    # the same asymmetric proposal treated as symmetric samples the wrong distribution: the
    # test has the power to see a missing Hastings term
    wrong = mcmc.Proposal(prop.sample, lambda x, y: jnp.zeros(x.shape[1:]))
    s_wrong = final_states(gamma3, wrong, x0, 150)
    assert _hist_pvalue(np.asarray(s_wrong.x[0])) < 1e-6


def test_detailed_balance_on_sampled_pairs(rng_np):
    x = jnp.asarray(rng_np.random((2, 2000)), jnp.float32)
    u = jnp.asarray(rng_np.random((9, 2000)), jnp.float32)
    f = lambda z: 1.0 + jnp.sin(6 * z[0]) ** 2 + z[1]
    for prop in (mcmc.torus_random_walk(0.01, 0.3),
                 mcmc.mixture(0.3, mcmc.torus_random_walk(), mcmc.independent_uniform())):
        y = prop.sample(x, u)
        t_xy, t_yx = prop.log_density(x, y), prop.log_density(y, x)
        a_xy = mcmc.acceptance_probability(f(x), f(y), t_xy, t_yx)
        a_yx = mcmc.acceptance_probability(f(y), f(x), t_yx, t_xy)
        lhs = f(x) * jnp.exp(t_xy) * a_xy
        rhs = f(y) * jnp.exp(t_yx) * a_yx
        np.testing.assert_allclose(np.asarray(lhs), np.asarray(rhs), rtol=2e-4)
    prop = mcmc.log_normal_step(0.5)
    xp = x + 0.1
    y = prop.sample(xp, u)
    lhs = (gamma3(xp) * jnp.exp(prop.log_density(xp, y))
           * mcmc.acceptance_probability(gamma3(xp), gamma3(y), prop.log_density(xp, y),
                                         prop.log_density(y, xp)))
    rhs = (gamma3(y) * jnp.exp(prop.log_density(y, xp))
           * mcmc.acceptance_probability(gamma3(y), gamma3(xp), prop.log_density(y, xp),
                                         prop.log_density(xp, y)))
    np.testing.assert_allclose(np.asarray(lhs), np.asarray(rhs), rtol=2e-4, atol=1e-30)


def test_torus_walk_samples_its_own_density(rng_np):
    """Step lengths |y - x| follow T: density 1/(t log(s2/s1)) on [s1, s2] (chi-square)."""
    s1, s2 = 0.001, 0.1
    prop = mcmc.torus_random_walk(s1, s2)
    x = jnp.full((1, 100000), 0.5)
    u = jnp.asarray(rng_np.random((3, 100000)), jnp.float32)
    t = np.abs(np.asarray(prop.sample(x, u)[0]) - 0.5)
    edges = np.geomspace(s1, s2, 21)
    h, _ = np.histogram(t, edges)
    assert stats.chisquare(h, np.full(20, len(t) / 20)).pvalue > 1e-3
    # and log_density integrates to one over the step
    grid = np.linspace(-s2, s2, 200001)
    dens = np.exp(np.asarray(prop.log_density(jnp.zeros((1, 1)),
                                              jnp.asarray(grid[None] % 1.0, jnp.float32))))
    assert abs(np.trapezoid(dens, grid) - 1) < 1e-2


def test_acceptance_is_one_when_proposals_only_go_uphill():
    target = lambda x: 1.0 + x[0]
    up = mcmc.Proposal(lambda x, u: x + 0.1 * u[:1], lambda x, y: jnp.zeros(x.shape[1:]))
    s = final_states(target, up, jnp.zeros((1, 64)), 20)
    assert np.all(np.asarray(s.accepted) == 20)


def test_same_seed_same_chain(rng_np):
    x0 = jnp.asarray(rng_np.random((1, 32)), jnp.float32)
    prop = mcmc.torus_random_walk()
    a = final_states(lambda x: 1 + x[0], prop, x0, 50, seed=4)
    b = final_states(lambda x: 1 + x[0], prop, x0, 50, seed=4)
    c = final_states(lambda x: 1 + x[0], prop, x0, 50, seed=5)
    np.testing.assert_array_equal(np.asarray(a.x), np.asarray(b.x))
    assert not np.array_equal(np.asarray(a.x), np.asarray(c.x))


# --- the kernel shared by the estimators (jgi.transport.mcmc.metropolis) -------------------------

W6 = jnp.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])


def _f6(x):
    """A piecewise-constant target on [0, 1): weight W6[k] on [k/6, (k+1)/6)."""
    return W6[jnp.clip(jnp.floor(x * 6).astype(jnp.int32), 0, 5)]


def _independent(x, key):
    """The large step: y uniform, T(x -> y) = 1. Kinds mixed in one kernel return Moves of one
    structure (lax.switch), so the optional fields are set as in _drift."""
    y = rng.uniform(key, 0)
    zero, true = jnp.zeros_like(x), jnp.ones_like(x) > 0
    return mcmc.Move(y, _f6(x), _f6(y), zero, zero, applicable=true, valid=true)


def _drift(x, key):
    """An asymmetric kind on [0, 1/2) only: y = x + s v, s = +1 with probability 0.8 and -1 with
    0.2, v uniform on [0, 0.1): T(x -> y) = 0.8 / 0.1 forwards, 0.2 / 0.1 backwards. It applies
    to x < 1/2, and a y outside [0, 1/2) is no state of it (valid = False), so the kind is a
    kernel on [0, 1/2) that preserves f there."""
    forward = rng.uniform(key, 2) < 0.8
    y = x + jnp.where(forward, 0.1, -0.1) * rng.uniform(key, 3)
    log_t_xy = jnp.log(jnp.where(forward, 8.0, 2.0))
    log_t_yx = jnp.log(jnp.where(forward, 2.0, 8.0))
    return mcmc.Move(y, _f6(x), _f6(jnp.clip(y, 0.0, 0.999)), log_t_xy, log_t_yx,
                     applicable=x < 0.5, valid=(y >= 0) & (y < 0.5))


def _drift_unmasked(x, key):
    """_drift treated as symmetric: the Hastings term dropped (the wrong chain)."""
    zero = jnp.zeros_like(x)
    return _drift(x, key)._replace(log_t_xy=zero, log_t_yx=zero)


def _run_kernel(mutations, x0, steps, **kw):
    probs = None if len(mutations) == 1 else jnp.array([0.2, 0.8])
    fn = jax.jit(lambda x: mcmc.metropolis(mutations, x, steps, seed=7, salt=11,
                                           kind_probs=probs, **kw))
    return jax.device_get(fn(x0))


def test_metropolis_kernel_mixes_kinds_with_hastings_term_and_counts_per_kind(rng_np):
    """Two kinds (independent large steps, and an asymmetric drift that applies on half the
    space) mixed by kind_probs: the final states of independent chains follow f (chi-square),
    they do not without the Hastings term, and the tally counts each kind's steps."""
    steps = 200
    x0 = jnp.asarray(rng_np.random(C), jnp.float32)
    x, _, tally, _ = _run_kernel([_independent, _drift], x0, steps)
    h = np.bincount(np.clip((x * 6).astype(int), 0, 5), minlength=6)
    expected = np.asarray(W6, np.float64) / float(W6.sum()) * C
    assert stats.chisquare(h, expected).pvalue > 1e-3, h
    proposed, applicable, accepted = (np.asarray(n) for n in tally)
    # one kind per step for all chains, drawn with probabilities (0.2, 0.8)
    assert np.all(proposed.sum(0) == steps) and np.all(proposed == proposed[:, :1])
    assert abs(proposed[1, 0] / steps - 0.8) < 5 * np.sqrt(0.16 / steps)
    # the large step always applies; the drift only from x < 1/2 (under 1/2 of f's mass)
    assert np.all(applicable[0] == proposed[0])
    share = applicable[1].sum() / proposed[1].sum()
    assert 0.1 < share < 0.5, share
    assert np.all(accepted <= applicable)
    assert 0.2 < accepted[1].sum() / applicable[1].sum() < 1.0
    # the same chains without the Hastings term drift upwards on [0, 1/2): the test has power
    x_w, *_ = _run_kernel([_independent, _drift_unmasked], x0, steps)
    h_w = np.bincount(np.clip((x_w * 6).astype(int), 0, 5), minlength=6)
    assert stats.chisquare(h_w, expected).pvalue < 1e-6, h_w


def test_metropolis_splats_expected_values_and_masked_steps_do_nothing(rng_np):
    """Each counted step splats weights (1 - a) + a = 1 per chain (value = f, so each splat is
    its weight), and steps past n_live neither splat, move nor count: 10 steps with n_live = 6
    give the bits of 6 steps."""
    x0 = jnp.asarray(rng_np.random(256), jnp.float32)
    bins = 6

    def measure(x):
        return jnp.clip(jnp.floor(x * bins).astype(jnp.int32), 0, bins - 1), (_f6(x),), _f6(x)

    kw = dict(record=mcmc.splatting(measure, 0.5), acc0=jnp.zeros((bins, 1), jnp.float32))
    x6, img6, tally6, _ = _run_kernel([_independent, _drift], x0, 6, **kw)
    x10, img10, tally10, _ = _run_kernel([_independent, _drift], x0, 10, n_live=jnp.int32(6), **kw)
    np.testing.assert_allclose(img6.sum(), 0.5 * 6 * 256, rtol=1e-5)
    np.testing.assert_array_equal(x10, x6)
    np.testing.assert_array_equal(img10, img6)
    for a, b in zip(tally10, tally6):
        np.testing.assert_array_equal(a, b)
    # emitted proposals: one per step, the state the chain moved to when it accepted
    x1, _, tally1, ys = _run_kernel([_independent], x0, 1, emit_proposals=True)
    assert ys.shape == (1, 256)
    moved = x1 != np.asarray(x0)
    np.testing.assert_array_equal(x1[moved], ys[0][moved])
    assert tally1.accepted.sum() == moved.sum()
