"""Homogeneous participating media: transmittance and free-flight sampling with spectral MIS.

A medium is described per RGB channel c by its extinction sigma_t,c = sigma_a,c + sigma_s,c and
its single-scattering albedo rho_c = sigma_s,c / sigma_t,c (Mitsuba's parametrisation), with a
phase function (:mod:`jgi.physics.phase`). Along a ray x(t) = o + t d in a homogeneous medium:

    transmittance     T_c(t) = exp(-sigma_t,c t)                               (Beer-Lambert)
    RTE, integrated   L(o, -d) = int_0^s T(t) sigma_s int p L_i dw dt + T(s) L_surface(x(s))

Free-flight sampling picks the distance of the next interaction. With RGB extinction no single
exponential matches all three channels, so a channel c is chosen with probability q_c (the
path's throughput in each channel, normalised: Mitsuba's ``volpathmis`` and pbrt-v4's hero
channel) and t is drawn from sigma_t,c exp(-sigma_t,c t). The estimator divides by the
one-sample MIS (balance) density over the channel choice,

    p(t)   = sum_c q_c sigma_t,c exp(-sigma_t,c t)           (an interaction at t < s)
    P(s)   = sum_c q_c exp(-sigma_t,c s)                     (no interaction before the surface)

so a medium interaction weighs T(t) sigma_s / p(t) and reaching the surface weighs T(s) / P(s)
(both RGB): unbiased in every channel, and exactly 1 (resp. the albedo) in the grey case.
Channels of zero extinction are never chosen to sample (they would put t at infinity) unless
all are zero (vacuum: no interaction ever).

Bidirectional estimators (light tracing, BDPT) need a distance density that is the same
whichever end of a segment sampled it, so their subpaths pick the channel with probabilities
that do not depend on the throughput (:func:`channel_probabilities_uniform`, ``throughput=None``):
p(t) and P(s) above are then functions of the segment alone, and the area density of a vertex
reached by free flight is p_omega |cos| / d^2 times p(d) (a medium vertex) or P(d) (a surface),
:func:`segment_pdf` (Veach 1997 sec. 10.2 with pbrt-v4's BDPT in media).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from ..core.vec import V3


class FreeFlight(NamedTuple):
    t: Array          # distance of the sampled interaction (= t_max where it reached it)
    scattered: Array  # bool: a medium interaction before t_max
    weight: V3        # T(t) sigma_s / p(t) if scattered, else T(t_max) / P(t_max)
    pdf: Array        # p(t) if scattered, else P(t_max) (the MIS density of the sample)


def transmittance(sigma_t: V3, t: Array) -> V3:
    """T_c(t) = exp(-sigma_t,c t) per channel (t may be inf for an escaping ray: T = 0 where
    sigma_t > 0, 1 in vacuum)."""
    return V3(*(jnp.exp(-jnp.where(s > 0, s * t, 0.0)) for s in sigma_t))


def channel_probabilities(sigma_t: V3, throughput: V3) -> V3:
    """q_c: proportional to the path throughput in channels that can interact; uniform over
    those if the throughput is zero there; all zero in vacuum."""
    can = [s > 0 for s in sigma_t]
    w = [jnp.where(ok, jnp.abs(b), 0.0) for ok, b in zip(can, throughput)]
    total = w[0] + w[1] + w[2]
    n_can = sum(ok.astype(jnp.float32) for ok in can)
    uniform = [jnp.where(ok, 1.0 / jnp.maximum(n_can, 1.0), 0.0) for ok in can]
    return V3(*(jnp.where(total > 0, wc / jnp.where(total > 0, total, 1.0), uc)
                for wc, uc in zip(w, uniform)))


def channel_probabilities_uniform(sigma_t: V3) -> V3:
    """q_c uniform over the channels that can interact (sigma_t,c > 0), all zero in vacuum: the
    throughput-independent choice of subpaths, whose densities must not depend on which end
    sampled a segment (see the module)."""
    can = [s > 0 for s in sigma_t]
    n_can = sum(ok.astype(jnp.float32) for ok in can)
    return V3(*(jnp.where(ok, 1.0 / jnp.maximum(n_can, 1.0), 0.0) for ok in can))


def segment_pdf(sigma_t: V3, t: Array, at_medium: Array) -> Array:
    """The distance density of a segment of length t sampled by free flight with the uniform
    channel choice: p(t) = sum_c q_c sigma_t,c T_c(t) where it ends at a medium vertex
    (``at_medium``), else P(t) = sum_c q_c T_c(t) (a surface reached). Symmetric in the
    segment's ends; a constant for derivatives (detached sampling)."""
    sigma_t = jax.lax.stop_gradient(sigma_t)
    return _mixture_pdf(channel_probabilities_uniform(sigma_t), sigma_t, t, at_medium)


def sample_free_flight(sigma_t: V3, albedo: V3, throughput: V3 | None, t_max: Array,
                       u_channel: Array, u_distance: Array) -> FreeFlight:
    """Sample the next interaction along a ray segment of length t_max (inf: unbounded) in a
    homogeneous medium, with spectral MIS over the channel choice (see the module);
    ``throughput=None``: the uniform channel choice of bidirectional subpaths."""
    q = (channel_probabilities_uniform(sigma_t) if throughput is None
         else channel_probabilities(sigma_t, throughput))
    # the channel: the first whose cumulative probability exceeds u_channel
    c0 = u_channel < q.x
    c1 = ~c0 & (u_channel < q.x + q.y)
    sig = jnp.where(c0, sigma_t.x, jnp.where(c1, sigma_t.y, sigma_t.z))
    any_medium = (q.x + q.y + q.z) > 0
    sig_safe = jnp.where(sig > 0, sig, 1.0)
    # -log(1 - u) / sigma: u < 1 in float32, so t is finite
    t = jnp.where(any_medium & (sig > 0), -jnp.log1p(-u_distance) / sig_safe, jnp.inf)
    scattered = t < t_max
    t = jnp.where(scattered, t, t_max)
    pdf = _mixture_pdf(q, sigma_t, t, scattered)
    return FreeFlight(t, scattered, free_flight_weight(sigma_t, albedo, t, scattered, pdf), pdf)


def _mixture_pdf(q: V3, sigma_t: V3, t: Array, scattered: Array) -> Array:
    """p(t) = sum_c q_c sigma_t,c T_c(t) where ``scattered``, else P(t) = sum_c q_c T_c(t) (1 in
    vacuum, where no channel is chosen)."""
    tr = transmittance(sigma_t, t)
    p_int = sum(qc * jnp.where(s > 0, s, 0.0) * trc for qc, s, trc in zip(q, sigma_t, tr))
    p_pass = sum(qc * trc for qc, trc in zip(q, tr))
    any_medium = (q.x + q.y + q.z) > 0
    return jnp.where(scattered, p_int, jnp.where(any_medium, p_pass, 1.0))


def free_flight_weight(sigma_t: V3, albedo: V3, t: Array, scattered: Array, pdf: Array) -> V3:
    """The weight of a sampled free flight (distance t, event, density pdf) as a function of
    the medium's parameters: T(t) sigma_s / p(t) if scattered, else T(t_max) / P(t_max), with
    the density a constant for derivatives, so those with respect to sigma_t and the albedo are
    the integrand's alone (detached sampling, Zeltner et al. 2021): an unbiased estimate of the
    derivative of the expectation, where differentiating the sampled distance would miss the
    jump of the event (interaction or surface) as t crosses the surface."""
    pdf = jax.lax.stop_gradient(pdf)
    safe = jnp.where(pdf > 0, pdf, 1.0)
    tr = transmittance(sigma_t, t)
    sigma_s = V3(*(a * s for a, s in zip(albedo, sigma_t)))
    return V3(*(jnp.where(pdf > 0, jnp.where(scattered, trc * ss, trc) / safe, 0.0)
                for trc, ss in zip(tr, sigma_s)))
