"""Work on the live lanes only: a batched map over the indices where a mask is set.

A fixed-shape kernel costs the same for a dead lane (a path ended by Russian roulette, a Dirac
vertex that cannot be connected) as for a live one. :func:`compact_map` gathers the live entries
of a mask into batches of static size and runs the kernel on those alone, in a loop whose trip
count is the number of live batches (traced: one compilation for any count), scattering the
results back. Its cost follows the live work; the price is a gather and a scatter per input and
output, and no reverse-mode derivative (the loop's trip count is data-dependent): callers that
differentiate keep the dense form.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array


def padded_size(n: int, minimum: int = 1024) -> int:
    """n rounded up to one of four sizes per octave (at least ``minimum``): arrays of a few
    different lengths (photon maps, whose length changes every pass) then share one compiled
    program, for at most 25% padding (a power of two wastes up to half)."""
    if n <= minimum:
        return minimum
    step = 1 << (int(np.floor(np.log2(n))) - 2)
    return int(-(-n // step) * step)


def _prefix_count(active: Array, block: int = 256) -> Array:
    """The inclusive running count of ``active`` ([M]): a cumulative sum within blocks and
    one over the blocks' totals (XLA's CPU cumsum over the whole array, a reduce-window,
    took twice as long)."""
    M = active.shape[0]
    pad = -M % block
    x = jnp.pad(active.astype(jnp.int32), (0, pad)).reshape(-1, block)
    inner = jnp.cumsum(x, axis=1)
    total = inner[:, -1]
    return (inner + (jnp.cumsum(total) - total)[:, None]).reshape(-1)[:M]


def live_indices(active: Array, fill: int | None = None) -> Array:
    """``jnp.nonzero(active, size=M, fill_value=fill)[0]`` as int32 (fill: M by default): the
    indices of the set entries in order, then ``fill`` (one scatter to the running count's
    positions; measured 1.9 against 3.6 ms for 295 k entries,
    docs/performance.md#vcm-live-vertices)."""
    M = active.shape[0]
    at = jnp.where(active, _prefix_count(active) - 1, M)
    return jnp.full((M,), M if fill is None else fill, jnp.int32).at[at].set(
        jnp.arange(M, dtype=jnp.int32), mode="drop")


def compact_map(fn: Callable, active: Array, inputs, out_like, batch: int,
                dest: Array | None = None):
    """``fn(inputs[idx], live) -> outputs[idx]`` over the entries where ``active`` ([M] bool).

    ``inputs``: a pytree of [M, ...] arrays; ``out_like``: a pytree of zero arrays [M, ...]
    giving the outputs' shapes (entries not active stay zero). ``fn`` receives each batch's rows
    ([batch, ...]) and a [batch] mask of real entries (the last batch is padded by repeating
    the last index) and returns the batch's outputs; rows of padding are discarded.
    ``dest`` ([M] int): entry i's output is added to row dest[i] instead (out_like then has
    the rows dest indexes: a sum over entries, such as a pixel's contributions)."""
    M = active.shape[0]
    idx = jnp.concatenate([live_indices(active), jnp.full((batch,), M, jnp.int32)])
    n_batches = (jnp.sum(active) + batch - 1) // batch

    def body(i, out):
        sel = jax.lax.dynamic_slice(idx, (i * batch,), (batch,))
        live = sel < M
        rows = jnp.minimum(sel, M - 1)
        got = fn(jax.tree_util.tree_map(lambda a: a[rows], inputs), live)
        put = rows if dest is None else dest[rows]
        return jax.tree_util.tree_map(   # padding is dropped by the scatter
            lambda o, v: o.at[jnp.where(live, put, o.shape[0])].add(
                jnp.where(live.reshape((-1,) + (1,) * (v.ndim - 1)), v, 0).astype(o.dtype),
                mode="drop"),
            out, got)

    return jax.lax.fori_loop(0, n_batches, body, out_like)
