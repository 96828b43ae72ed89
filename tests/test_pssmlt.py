"""Primary-sample-space MLT has the path tracer's expectation, per region of the image."""

from __future__ import annotations

import numpy as np
import pytest

import jgi
from jgi.estimators import pssmlt
from tests.support.stats import assert_agree


def test_kelemen_small_step_is_symmetric_and_stays_on_the_torus(rng_np):
    u = rng_np.random((5, 20000)).astype(np.float32)
    xi = rng_np.random((5, 20000)).astype(np.float32)
    sign = rng_np.random((5, 20000)).astype(np.float32)
    v = np.asarray(pssmlt.kelemen_small_step(u, xi, sign, 1 / 1024, 1 / 64))
    assert np.all((v >= 0) & (v < 1))
    # symmetric: the step distance (on the torus) has the same law forwards and backwards
    d = (v - u + 0.5) % 1.0 - 0.5
    assert abs(np.mean(d > 0) - 0.5) < 5 * np.sqrt(0.25 / d.size)
    assert np.all(np.abs(d) <= 1 / 64 + 1e-6) and np.all(np.abs(d) >= 1 / 1024 - 1e-6)
    # reverse move with the same xi and the opposite direction returns to u: T(u->v) = T(v->u)
    # (the direction is sign < 0.5; 1 - sign would keep the direction of sign = 0.5)
    opposite = np.where(sign < 0.5, 0.75, 0.25).astype(np.float32)
    back = np.asarray(pssmlt.kelemen_small_step(v, xi, opposite, 1 / 1024, 1 / 64))
    err = (back - u + 0.5) % 1.0 - 0.5
    assert np.abs(err).max() < 1e-5


@pytest.mark.parametrize("p_large", [0.3, 1.0])
def test_pssmlt_matches_path_tracer_per_region(p_large):
    scene = jgi.scenes.cornell_box(resolution=16)
    seeds = range(12)
    mlt = np.stack([jgi.render(scene, "pssmlt", spp=32, seed=s, chains=512,
                               bootstrap_samples=8192, p_large=p_large) for s in seeds])
    pt = np.stack([jgi.render(scene, "pt", spp=32, seed=100 + s) for s in seeds])
    assert_agree(mlt, pt, regions=4, label=f"pssmlt p_large={p_large}")


def test_acceptance_statistics_are_reported():
    # the settings of the agreement test above: its compiled kernels serve this one too
    scene = jgi.scenes.cornell_box(resolution=16)
    stats = pssmlt.render(scene, pssmlt.PSSMLTConfig(chains=512, bootstrap_samples=8192,
                                                     p_large=0.3), spp=2, seed=0).stats
    assert 0.05 < stats["acceptance"] < 1.0 and stats["b"] > 0
