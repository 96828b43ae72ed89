"""Phase functions and homogeneous free-flight sampling against their densities and closed forms.

Chi-square (jgi/analysis/chi2.py) of the Henyey-Greenstein sampler over the sphere for several
asymmetries, and of free-flight distances over a segment (the samples that pass the segment are
the chi-square's "no sample" category, expected with probability P(t_max)); a negative control
for each shows the tests can reject. Then the estimator identities: the free-flight weights
average to the transmittance and to the in-scattering integral, per RGB channel, within
4 measured standard errors.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jgi.analysis.chi2 import PlaneDomain, SphereDomain, chi2_test
from jgi.core.vec import V3
from jgi.physics import media, phase

N = 200_000
D_IN = (0.36, -0.48, 0.8)   # unit


def _uniforms(seed, k=2, n=N):
    return np.random.default_rng(seed).random((k, n), dtype=np.float32)


@jax.jit
def _sample_hg(g, u1, u2):
    d = V3(*(jnp.full_like(u1, c) for c in D_IN))
    s = phase.sample(jnp.full_like(u1, g), d, u1, u2)
    return jnp.stack(list(s.d_out), -1), s.pdf


def _hg_pdf(g):
    axis = np.asarray(D_IN, np.float64)
    return lambda p: np.asarray(phase.henyey_greenstein(
        jnp.asarray(np.clip(p @ axis, -1, 1), jnp.float32), jnp.float32(g)), np.float64)


def _hg_domain(g):
    # geometric edges in a = 1 - mu resolve a forward lobe (width ~ (1 - g)^2) and a backward one
    if g > 0.5:
        edges = np.concatenate([[0.0], np.geomspace(1e-4, 2.0, 40)])
    else:
        edges = np.linspace(0.0, 2.0, 33)
    return SphereDomain(axis=D_IN, a_edges=edges, n_phi=16)


@pytest.mark.parametrize("g", [0.0, 0.3, -0.7, 0.9])
def test_henyey_greenstein_sampler_follows_its_density(g):
    d, pdf = _sample_hg(jnp.float32(g), *_uniforms(11))
    d, pdf = np.asarray(d), np.asarray(pdf)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=2e-6)
    assert np.all(np.isfinite(pdf)) and np.all(pdf > 0)
    # the reported density is the phase function at the sample
    np.testing.assert_allclose(pdf, _hg_pdf(g)(d.astype(np.float64)), rtol=2e-4)
    r = chi2_test(d, _hg_pdf(g), _hg_domain(g))
    assert r.ok(), f"HG g={g}: {r.message}"
    assert abs(r.pdf_integral - 1.0) < 1e-3, r.pdf_integral     # p integrates to one
    mean_mu = float(np.mean(d @ np.asarray(D_IN)))
    assert abs(mean_mu - g) < 4 * np.sqrt((1 - g * g) / 3 / N) + 1e-3    # E[mu] = g


def test_henyey_greenstein_negative_control():
    d, _ = _sample_hg(jnp.float32(0.5), *_uniforms(12))
    r = chi2_test(np.asarray(d), _hg_pdf(0.55), _hg_domain(0.55))
    assert not r.ok(), "a sampler for g = 0.5 passed as g = 0.55: the test has no power"


def test_phase_reciprocity_and_isotropy():
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(2, 1000, 3)).astype(np.float32)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    A, B = V3(*a.T), V3(*b.T)
    g = jnp.float32(0.6)
    np.testing.assert_allclose(phase.evaluate(g, A, B), phase.evaluate(g, -B, -A), rtol=1e-6)
    np.testing.assert_allclose(phase.evaluate(jnp.float32(0.0), A, B), 1 / (4 * np.pi),
                               rtol=1e-6)


# --- free flight ----------------------------------------------------------------------------------

SIGMA_T = (0.8, 1.7, 0.0)     # the blue channel is vacuum-like: it never samples
ALBEDO = (0.9, 0.5, 0.7)
T_MAX = 1.5


@jax.jit
def _flight(sigma_t, albedo, beta, t_max, u1, u2):
    return media.sample_free_flight(V3(*(jnp.full_like(u1, c) for c in sigma_t)),
                                    V3(*(jnp.full_like(u1, c) for c in albedo)),
                                    V3(*(jnp.full_like(u1, c) for c in beta)),
                                    jnp.full_like(u1, t_max), u1, u2)


def _mixture(sigma_t, beta):
    q = np.array([b if s > 0 else 0.0 for s, b in zip(sigma_t, beta)], np.float64)
    return q / q.sum()


@pytest.mark.parametrize("beta", [(1.0, 1.0, 1.0), (0.2, 3.0, 1.0)])
def test_free_flight_distances_follow_their_density(beta):
    f = _flight(SIGMA_T, ALBEDO, beta, T_MAX, *_uniforms(21))
    t, hit = np.asarray(f.t, np.float64), np.asarray(f.scattered)
    q, s = _mixture(SIGMA_T, beta), np.asarray(SIGMA_T, np.float64)

    def density(p):     # p(t) over (t, dummy) in [0, T_MAX] x [0, 1]
        return (q * s * np.exp(-np.outer(p[:, 0], s))).sum(1)

    passing = float((q * np.exp(-s * T_MAX)).sum())
    dummy = np.random.default_rng(0).random(int(hit.sum()))
    samples = np.stack([t[hit], dummy], 1)
    domain = PlaneDomain(np.linspace(0, T_MAX, 41), np.array([0.0, 1.0]))
    r = chi2_test(samples, density, domain, n_total=N, total=1.0 - passing)
    assert r.ok(), f"free flight beta={beta}: {r.message}"
    # the sampler's own pdf agrees with the mixture
    pdf = np.asarray(f.pdf, np.float64)
    np.testing.assert_allclose(pdf[hit], density(samples), rtol=1e-4)
    np.testing.assert_allclose(pdf[~hit], passing, rtol=1e-4)
    # negative control: the density of the first channel alone is rejected
    wrong = lambda p: s[0] * np.exp(-p[:, 0] * s[0])   # noqa: E731
    bad = chi2_test(samples, wrong, domain, n_total=N, total=1.0 - np.exp(-s[0] * T_MAX))
    assert not bad.ok()


def _mean_and_error(x):
    x = np.asarray(x, np.float64)
    return x.mean(0), x.std(0, ddof=1) / np.sqrt(len(x))


@pytest.mark.parametrize("beta", [(1.0, 1.0, 1.0), (0.2, 3.0, 1.0)])
def test_free_flight_weights_are_unbiased(beta):
    """E[weight 1{pass}] = T(t_max) and E[weight 1{scatter} h(t)] = int_0^tmax T sigma_s h dt per
    channel, with h(t) = cos(t) a smooth test function."""
    f = _flight(SIGMA_T, ALBEDO, beta, T_MAX, *_uniforms(31))
    w = np.stack([np.asarray(c, np.float64) for c in f.weight], 1)
    t, hit = np.asarray(f.t, np.float64), np.asarray(f.scattered)
    s, a = np.asarray(SIGMA_T), np.asarray(ALBEDO)
    m, e = _mean_and_error(np.where(~hit[:, None], w, 0.0))
    np.testing.assert_array_less(np.abs(m - np.exp(-s * T_MAX)), 4 * e + 1e-7)
    m, e = _mean_and_error(np.where(hit[:, None], w * np.cos(t)[:, None], 0.0))
    tt = np.linspace(0, T_MAX, 20001)
    exact = np.trapezoid(np.exp(-np.outer(tt, s)) * (a * s) * np.cos(tt)[:, None], tt, axis=0)
    np.testing.assert_array_less(np.abs(m - exact), 4 * e + 1e-7)
    assert np.all(np.isfinite(w))


def test_free_flight_vacuum_and_unbounded():
    f = _flight((0.0, 0.0, 0.0), ALBEDO, (1.0, 1.0, 1.0), T_MAX, *_uniforms(41, n=1000))
    assert not np.any(np.asarray(f.scattered))
    np.testing.assert_array_equal(np.stack(list(f.weight)), 1.0)
    # an escaping ray (t_max = inf) always scatters in a medium; weights stay finite
    g = _flight((0.5, 0.5, 0.5), ALBEDO, (1.0, 1.0, 1.0), np.inf, *_uniforms(42, n=1000))
    assert np.all(np.asarray(g.scattered))
    w = np.stack([np.asarray(c) for c in g.weight])
    np.testing.assert_allclose(w, np.broadcast_to(np.asarray(ALBEDO)[:, None], w.shape),
                               rtol=1e-5)   # grey: the albedo
    # grazing: t_max = 0 passes with weight 1
    h = _flight((0.5, 0.5, 0.5), ALBEDO, (1.0, 1.0, 1.0), 0.0, *_uniforms(43, n=1000))
    assert not np.any(np.asarray(h.scattered))
    np.testing.assert_allclose(np.stack(list(h.weight)), 1.0)


def test_transmittance_of_a_slab():
    d = jnp.asarray([0.0, 0.5, 2.0, np.inf], jnp.float32)
    tr = media.transmittance(V3(jnp.float32(0.7), jnp.float32(0.0), jnp.float32(3.0)), d)
    np.testing.assert_allclose(np.asarray(tr.x), np.exp(-0.7 * np.asarray(d)), rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(tr.y), 1.0)
    np.testing.assert_allclose(np.asarray(tr.z), np.exp(-3.0 * np.asarray(d)), rtol=1e-6)
