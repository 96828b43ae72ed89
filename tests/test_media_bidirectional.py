"""Light tracing, BDPT and MMLT in a scene filled by a homogeneous medium (issue 34): medium
vertices in the shared subpaths and connections (jgi.transport).

Each estimator against the path tracer per 4 x 4 image region in a fog box with RGB extinction
and albedo and an anisotropic phase function (g = 0.4, so a phase function evaluated for
the wrong pair of directions would show), Welch's t with both sides' seed spreads,
Bonferroni-corrected (no widened tolerance). (BDPT at max_depth 2, single scattering and
direct light only, ran here too until 2026-12-08, with a path-traced reference of its own:
its single scattering has a closed form, test_bdpt_single_scattering_from_a_point_light, and
depth 5 holds its paths; the two compiles went for the suite's time.) Power: the
estimator's stack offset by what sigma_t 15% higher changes in the path tracer's image must
fail the same test (tests.support.stats.tells_apart, in place of a second render of each
estimator in the denser medium).
Measured (24 x 24, 16 seeds each side, 2026-12-06): max |t| 2.7 (lt), 1.9 and 2.1 (bdpt at
depths 2 and 5), 2.2 (mmlt) against critical values near 5.9; offset by the denser medium's
change 13.2 (lt), 65.6 and 17.3 (bdpt), 12.2 (mmlt) (renders of the denser medium gave 13.5,
77, 17, 14.4); VCM (medium vertices in its walks, connections and volume merges,
tests/test_vcm.py for its MIS) 1.9, offset 15.3; merging alone (``bpm``: surface and volume
merges at every camera vertex, r = 0.1 in the 2-unit room) at 32 spp 2.7 against 5.9, offset
8.6 (at 16 spp the offset reached 6.38 against 6.40: no power; its render of the denser
medium had passed 9.0, its kernel bias growing with the density).
MMLT's one-strategy evaluation equals BDPT's per lane in this fog too
(tests/test_mmlt.py), which checks its MIS weights where this test cannot (below).

What this test cannot see: MIS densities that are wrong *consistently* across strategies keep
BDPT unbiased (only its variance changes); measured, dropping p_dist from every density leaves
the test passing, while dropping it only from the connections' densities (an inconsistent
error) fails it with t ~ 90 (a 30% bias).
"""

from __future__ import annotations

import numpy as np
import pytest

import jgi
from jgi.analysis.stats import region_agreement
from tests.support.stats import mean_change, tells_apart

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
    return {d: _stack(_fog(), "pt", 128, 1000, max_depth=d, rr_depth=-1) for d in (5,)}


@pytest.fixture(scope="module")
def denser_change():
    """What sigma_t 15% higher changes in the path tracer's image, per depth (64 spp x 16 seeds
    a side): the bias each power check must detect."""
    def at(depth):
        return mean_change(lambda scene, seed: jgi.render(scene, "pt", spp=64, seed=seed,
                                                          max_depth=depth, rr_depth=-1),
                           _fog(), _fog(1.15), range(SEEDS))
    return {d: at(d) for d in (5,)}


VCM_MERGING_ONLY = dict(mode="bpm", radius=0.1)   # every camera vertex merges, no connection


@pytest.mark.parametrize("name, spp, depth, kw", [
    ("lt", 16, 5, {}), ("bdpt", 64, 5, {}), ("mmlt", 32, 5, {}),
    ("vcm", 16, 5, {}), ("vcm", 32, 5, VCM_MERGING_ONLY)])
def test_agrees_with_the_path_tracer_in_fog(pt_reference, denser_change, name, spp, depth, kw):
    mine = _stack(_fog(), name, spp, 0, max_depth=depth, **kw)
    assert np.all(np.isfinite(mine))
    r = region_agreement(mine, pt_reference[depth], 4)
    print(f"{name} depth {depth} vs pt: max t {r.t.max():.2f} (critical {r.critical.min():.2f})")
    assert r.agree, f"{name} vs pt: worst t {r.t[r.worst]:.1f} > {r.critical[r.worst]:.1f}"
    # power: a bias as large as a 15% denser medium's must be told apart by the same test
    r_off = tells_apart(mine, pt_reference[depth], denser_change[depth], 4)
    print(f"{name} depth {depth} offset by sigma_t x 1.15's change: max t {r_off.t.max():.2f}")
    assert not r_off.agree


@pytest.fixture(scope="module")
def caustic_bdpt():
    """BDPT in glass_sphere_fog, the reference of both volumetric-caustic tests below."""
    return _stack(jgi.load_scene("glass_sphere_fog", resolution=RES), "bdpt", 16, 100,
                  max_depth=8)


def test_volumetric_caustic_needs_light_subpaths(caustic_bdpt):
    """glass_sphere_fog: a spot light focused by a glass sphere into fog (L S S M E). Light
    tracing and BDPT render the bright cone below the sphere and agree per region; the path
    tracer cannot sample it (its shadow rays stop at the glass, its phase-sampled rays never
    hit the point light), so its mean there is far lower. lt and bdpt are compared in the
    image's lower third (the cone and the floor), as light tracing cannot see the glass itself
    (paths ending ... S E reach a pinhole by no connection): there it reads 0.043 where bdpt
    reads 0.056 (t 15). Measured at 24 x 24 (16 seeds): lower third max |t| 2.2 (critical
    5.9); in the cone lt 0.16, pt 0.02."""
    scene = jgi.load_scene("glass_sphere_fog", resolution=RES)
    lt = _stack(scene, "lt", 64, 0, max_depth=8)
    bdpt = caustic_bdpt
    r = region_agreement(lt[:, 16:], bdpt[:, 16:], 3)
    assert r.agree, f"lt vs bdpt: worst t {r.t[r.worst]:.1f} > {r.critical[r.worst]:.1f}"
    pt = _stack(scene, "pt", 64, 200, max_depth=8)
    cone = (slice(15, 22), slice(9, 15))       # below the sphere, above the floor
    means = {k: v[:, cone[0], cone[1]].mean((1, 2, 3)) for k, v in (("lt", lt), ("pt", pt))}
    gap = means["lt"].mean() - means["pt"].mean()
    se = np.sqrt(sum(m.var(ddof=1) / len(m) for m in means.values()))
    assert gap > 10 * se and means["pt"].mean() < 0.5 * means["lt"].mean(), (means, se)


def test_volumetric_caustic_seen_through_the_glass_needs_merging(caustic_bdpt):
    """VCM in glass_sphere_fog: below the sphere it agrees with BDPT per region (the cone and
    the floor); through the sphere it is brighter, by the light of paths L S S M S S E (one
    medium vertex lit through the glass and seen through it), which no connection samples
    (both of the medium vertex's neighbours are Dirac) and a volume merge does. Measured at
    24 x 24 (16 seeds, r = 0.05): lower third max |t| 1.8 (critical 5.65); through the sphere
    (its central 8 x 8 pixels) 0.086 against BDPT's 0.056 (5.3 standard errors), where
    merging alone (bpm) reads 0.090 and progressive photon mapping (ppm mode) 0.092, each
    +-0.015: the merging estimators agree with each other on the light BDPT misses."""
    scene = jgi.load_scene("glass_sphere_fog", resolution=RES)
    bdpt = caustic_bdpt
    mine = _stack(scene, "vcm", 16, 0, max_depth=8, radius=0.05)
    assert np.all(np.isfinite(mine))
    r = region_agreement(mine[:, 16:], bdpt[:, 16:], 3)
    print(f"vcm vs bdpt, lower third: max t {r.t.max():.2f} (critical {r.critical.min():.2f})")
    assert r.agree, f"vcm vs bdpt: worst t {r.t[r.worst]:.1f} > {r.critical[r.worst]:.1f}"
    sphere = (slice(8, 16), slice(8, 16))
    means = {k: v[:, sphere[0], sphere[1]].mean((1, 2, 3)) for k, v in (("vcm", mine),
                                                                          ("bdpt", bdpt))}
    gap = means["vcm"].mean() - means["bdpt"].mean()
    se = np.sqrt(sum(m.var(ddof=1) / len(m) for m in means.values()))
    print(f"through the sphere: vcm {means['vcm'].mean():.4f}, bdpt {means['bdpt'].mean():.4f}"
          f" (gap {gap / se:.1f} standard errors)")
    assert gap > 4 * se, (means, se)


# g = 0.7 only: the phase functions' isotropic branch (|g| small) is chi-square tested in
# tests/test_media.py, and estimators call the same sample/pdf functions for every g
@pytest.mark.parametrize("g", [0.7])
def test_bdpt_single_scattering_from_a_point_light(g):
    """BDPT's paths of exactly two segments from a point light (a delta y_0) in an infinite
    medium, no surfaces: strategies (1, 2) (light sampling at a medium vertex) and (2, 1) (the
    medium vertex y_1 seen from the pinhole), MIS-weighted, against the quadrature of
    tests/test_media_estimators.py within 4 standard errors over seeds."""
    from tests.support.media import point_light_scene, single_scattering_mean

    scene = point_light_scene(g)
    imgs = np.stack([jgi.render(scene, "bdpt", spp=1024, seed=s, max_depth=2, path_length=2)
                     for s in range(8)])
    assert np.all(np.isfinite(imgs))
    means = imgs.reshape(len(imgs), -1, 3).mean(1)
    mean, err = means.mean(0), means.std(0, ddof=1) / np.sqrt(len(means))
    exact = single_scattering_mean(scene)
    print("bdpt", mean, "+-", err, "exact", exact)
    np.testing.assert_array_less(np.abs(mean - exact), 4 * err + 1e-4 * exact)
