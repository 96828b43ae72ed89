"""Light tracing and BDPT in a scene filled by a homogeneous medium (issue 34): medium vertices
in the shared subpaths and connections (jgi.transport). Each estimator against the path tracer
per 4 x 4 image region in a fog box with RGB extinction and albedo and an anisotropic phase
function (Welch's t with both sides' seed spreads, Bonferroni-corrected; no widened tolerance),
with a negative control: the same estimator with sigma_t 15% higher must fail the same test.
"""

from __future__ import annotations

import numpy as np
import pytest

import jgi
from jgi.analysis.stats import region_agreement

FOG = dict(sigma_t=(0.45, 0.6, 0.8), albedo=(0.9, 0.8, 0.7), g=0.4)
RES, SEEDS = 24, 16


def _fog(scale: float = 1.0):
    kw = dict(FOG, sigma_t=tuple(scale * s for s in FOG["sigma_t"]))
    return jgi.load_scene("cornell_box_fog", resolution=RES, **kw)


def _stack(scene, name, spp, seed0, **kw):
    return np.stack([jgi.render(scene, name, spp=spp, seed=seed0 + s, **kw)
                     for s in range(SEEDS)])


@pytest.fixture(scope="module")
def pt_reference():
    return {d: _stack(_fog(), "pt", 128, 1000, max_depth=d, rr_depth=-1) for d in (2, 5)}


@pytest.mark.parametrize("name, spp", [("lt", 16)])
def test_agrees_with_the_path_tracer_in_fog(pt_reference, name, spp):
    mine = _stack(_fog(), name, spp, 0, max_depth=5)
    assert np.all(np.isfinite(mine))
    r = region_agreement(mine, pt_reference[5], 4)
    print(f"{name} vs pt: max t {r.t.max():.2f} (critical {r.critical.min():.2f})")
    assert r.agree, f"{name} vs pt: worst t {r.t[r.worst]:.1f} > {r.critical[r.worst]:.1f}"
    # negative control: a 15% denser medium must be told apart by the same test
    off = _stack(_fog(1.15), name, spp, 0, max_depth=5)
    r_off = region_agreement(off, pt_reference[5], 4)
    print(f"{name} (sigma_t x 1.15) vs pt: max t {r_off.t.max():.2f}")
    assert not r_off.agree
