"""Multiple importance sampling weights (Veach 1997, ch. 9), in one place.

For strategies i = 1..k with n_i samples each and densities p_i(x), the one-sample weight of the
strategy s that produced x is

    balance heuristic:  w_s(x) = n_s p_s(x) / sum_i n_i p_i(x)
    power heuristic:    w_s(x) = (n_s p_s(x))^b / sum_i (n_i p_i(x))^b
                        (exponent b = ``power``, 2 usual)

and the combined estimator is sum_i (1/n_i) sum_j f(X_ij) w_i(X_ij) / p_i(X_ij) (the lecture's
two-strategy formula with n_f BSDF and n_g light samples). Weights are evaluated as
1 / (1 + sum_{i != s} (n_i p_i / n_s p_s)^b) so that no power of a pdf overflows. (``beta`` is
kept for the path throughput throughout jgi, so the exponent is called ``power``.)
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from .. import _xla


def heuristic_weight(n_s, p_s: Array, others: list[tuple], power: float = 1.0) -> Array:
    """w_s for the strategy with (n_s, p_s) against ``others = [(n_i, p_i), ...]``; ``power`` is
    the exponent b (1: the balance heuristic).

    Returns 0 where p_s = 0 (that strategy could not have produced the sample)."""
    a = n_s * p_s
    ok = a > 0
    a_safe = jnp.where(ok, a, 1.0)
    denom = jnp.ones_like(a_safe)
    for n_i, p_i in others:
        r = _xla.div(n_i * p_i, a_safe)
        denom = denom + (r if power == 1.0 else (r * r if power == 2.0 else r ** power))
    return jnp.where(ok, _xla.recip(denom), 0.0)


def balance(n_s, p_s, n_o, p_o) -> Array:
    return heuristic_weight(n_s, p_s, [(n_o, p_o)], 1.0)


def power(n_s, p_s, n_o, p_o, power: float = 2.0) -> Array:
    return heuristic_weight(n_s, p_s, [(n_o, p_o)], power)
