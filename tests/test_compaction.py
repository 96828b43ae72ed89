"""jgi.core.compaction: the live entries' indices, and the batched map over them."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from jgi.core.compaction import compact_map, live_indices


@pytest.mark.parametrize("M, p", [(1, 1.0), (255, 0.0), (256, 1.0), (1000, 0.12), (4097, 0.5)])
def test_live_indices_are_nonzeros_in_order(rng_np, M, p):
    """Across block boundaries (256), with a partial last block, none or every entry set."""
    active = rng_np.random(M) < p
    want = np.concatenate([np.flatnonzero(active), np.full(M - active.sum(), M)])
    assert np.array_equal(np.asarray(live_indices(jnp.asarray(active))), want)


def test_compact_map_with_and_without_a_destination(rng_np):
    """Each live entry's value, at its own row or summed into its destination row (a pixel's
    contributions); batches of 64 with a padded last one; dead entries contribute nothing."""
    M, rows = 1000, 37
    active = rng_np.random(M) < 0.3
    x = rng_np.random(M).astype(np.float32)
    dest = rng_np.integers(0, rows, M).astype(np.int32)

    def fn(xb, live):
        return (xb * 2.0)[:, None] * jnp.ones((1, 3))

    own = compact_map(fn, jnp.asarray(active), jnp.asarray(x), jnp.zeros((M, 3)), 64)
    assert np.allclose(np.asarray(own), np.where(active, 2 * x, 0)[:, None] * np.ones(3))
    summed = compact_map(fn, jnp.asarray(active), jnp.asarray(x), jnp.zeros((rows, 3)), 64,
                         dest=jnp.asarray(dest))
    want = np.zeros(rows)
    np.add.at(want, dest[active], 2 * x[active])
    assert np.allclose(np.asarray(summed)[:, 0], want, rtol=1e-6)
