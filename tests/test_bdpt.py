"""Bidirectional path tracing: MIS weights, per-strategy unbiasedness, agreement with the path
tracer, delta lights, robustness.

Statistical checks use fixed seeds and Student-t thresholds with Bonferroni correction on
standard errors measured from independent renders (tests.support.stats.assert_agree). Images are
16 x 16 and every configuration is compiled once per session (module fixtures).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import jgi
from jgi.estimators import bdpt as BD
from jgi.scene import builtin as scenes
from tests.support.scenes import degenerate_scene, point_light_reference
from tests.support.stats import assert_agree, critical_t, region_stats

DEPTH = 3   # lengths 1..3: every kind of strategy, (2, 2) included; compile time grows with
            # the number of strategies
SEEDS = range(12)


def renders(scene, estimator, seeds=SEEDS, spp=16, **params):
    return np.stack([jgi.render(scene, estimator, spp=spp, seed=s, **params) for s in seeds])


# --- MIS weights: a partition of unity over the strategies of every path -------------------------

def mis_weight_reference(camera: list[tuple], light: list[tuple], delta_light, exponent: float):
    """w_{s,t} for the strategy with s = len(light), t = len(camera), one strategy at a time and
    written straight from the formula: the reference the rendered form
    (:func:`jgi.estimators.bdpt.ratio_chain`, :func:`~jgi.estimators.bdpt.mis_weights`) is
    checked against.

    ``camera[i] = (p_fwd, p_rev, delta)`` for z_i, i < t, and ``light[i]`` likewise for y_i,
    i < s: area densities with *this strategy's* values already put into the last two
    vertices of each subpath (their reverse densities, and delta = False at the connection).

    Moving the connection one vertex towards the camera turns z_{i} into a light-subpath vertex:
    the density ratio of the two strategies is p_rev(z_i) / p_fwd(z_i). Walking outwards from
    the connection, r_i is the running product of these ratios (raised to the heuristic's
    exponent), and a strategy counts only if both vertices it would connect are not Dirac
    (and, at y_0, the light is not a delta light). Then w = 1 / (1 + sum_i r_i)."""
    s, t = len(light), len(camera)
    if s + t == 2:
        return jnp.ones_like(camera[0][0])
    sum_r = jnp.zeros_like(camera[0][0])
    # hypothetical strategies (s + k, t - k): the camera subpath gives up vertices
    log_r = jnp.zeros_like(sum_r)
    for i in range(t - 1, 0, -1):
        p_fwd, p_rev, delta = camera[i]
        log_r = log_r + exponent * (BD.log_remap0(p_rev) - BD.log_remap0(p_fwd))
        r_i = jnp.exp(jnp.minimum(log_r, BD.LOG_RATIO_MAX))
        sum_r = sum_r + jnp.where(~delta & ~camera[i - 1][2], r_i, 0.0)
    # hypothetical strategies (s - k, t + k): the light subpath gives up vertices
    log_r = jnp.zeros_like(sum_r)
    for i in range(s - 1, -1, -1):
        p_fwd, p_rev, delta = light[i]
        log_r = log_r + exponent * (BD.log_remap0(p_rev) - BD.log_remap0(p_fwd))
        r_i = jnp.exp(jnp.minimum(log_r, BD.LOG_RATIO_MAX))
        prev_delta = light[i - 1][2] if i > 0 else delta_light
        sum_r = sum_r + jnp.where(~delta & ~prev_delta, r_i, 0.0)
    return 1.0 / (1.0 + sum_r)


def mis_weight_rendered(camera: list[tuple], light: list[tuple], delta_light, exponent: float):
    """:func:`mis_weight_reference`'s arguments as rows, weighted by the form renders run."""
    log_pdf, flags = [], []

    def vertex(p_fwd, p_rev, delta):
        log_pdf.extend([BD.log_remap0(p_fwd), BD.log_remap0(p_rev)])
        flags.append(delta)
        return BD.ChainVertex(len(log_pdf) - 2, len(log_pdf) - 1, len(flags) - 1)

    cam, lig = [vertex(*v) for v in camera], [vertex(*v) for v in light]
    flags.append(jnp.broadcast_to(delta_light, camera[0][0].shape))
    chain = BD.ratio_chain(cam, lig, len(flags) - 1)
    return BD.mis_weights(log_pdf, flags, [chain], exponent)[0]


def _full_path(rng, n, N):
    """Random full paths x_0 (light) .. x_{n-1} (camera): p_L[k] (density of x_k sampled from
    the light side), p_E[k] (from the camera side), Dirac flags, delta lights."""
    p_L = np.exp(rng.uniform(-14, 14, (n, N))).astype(np.float32)
    p_E = np.exp(rng.uniform(-14, 14, (n, N))).astype(np.float32)
    delta = rng.uniform(size=(n, N)) < 0.3
    delta[0] = delta[-1] = False                 # the light vertex and the pinhole
    delta_light = rng.uniform(size=N) < 0.3
    return p_L, p_E, delta, delta_light


def _valid(s, n, delta, delta_light):
    """Strategy s (t = n - s) can produce the path: its connection is between non-Dirac
    vertices, and s = 0 needs a light that can be hit."""
    if n == 2 and s == 1:
        return np.zeros_like(delta_light)        # (1, 1) is not used
    if s == 0:
        return ~delta_light
    return ~delta[s - 1] & ~delta[s]


def _weights_reference(p_L, p_E, delta, delta_light, power):
    n = p_L.shape[0]
    out = {}
    for s in range(0, n):
        t = n - s
        cam = [(jnp.asarray(p_E[n - 1 - i]), jnp.asarray(p_L[n - 1 - i]),
                jnp.asarray(delta[n - 1 - i]))
               for i in range(t)]
        light = [(jnp.asarray(p_L[i]), jnp.asarray(p_E[i]), jnp.asarray(delta[i]))
                 for i in range(s)]
        out[s] = np.asarray(mis_weight_reference(cam, light, jnp.asarray(delta_light), power))
    return out


def _weights_rendered(p_L, p_E, delta, delta_light, power):
    """Every strategy's weight at once, as a render computes them: the path's densities as rows,
    each strategy's view of its subpaths (connected vertices non-Dirac), its ratio chain."""
    n = p_L.shape[0]
    log_pdf = np.concatenate([p_L, p_E, np.zeros_like(p_L[:1])])   # rows L_k, E_k, zero
    flags = np.concatenate([delta, delta_light[None], np.zeros_like(delta[:1]),
                            np.ones_like(delta[:1])])              # rows delta_k, light, F, T
    L, E, DL, F = 0, n, n, n + 1
    chains = []
    for s in range(n):
        t = n - s
        camera = [BD.ChainVertex(E + n - 1 - i, L + n - 1 - i, F if i == t - 1 else n - 1 - i)
                  for i in range(t)]
        light = [BD.ChainVertex(L + i, E + i, F if i == s - 1 else i) for i in range(s)]
        chains.append(BD.ratio_chain(camera, light, DL))
    log_rows = BD.log_remap0(jnp.asarray(log_pdf))
    w = BD.mis_weights([log_rows[r] for r in range(log_rows.shape[0])],
                       [jnp.asarray(f) for f in flags], chains, power)
    return {s: np.asarray(w[s]) for s in range(n)}


@pytest.mark.parametrize("power", [1.0, 2.0])
@pytest.mark.parametrize("n", [2, 3, 4, 6])
def test_mis_weights_sum_to_one_over_strategies(rng_np, n, power):
    N = 2000
    p_L, p_E, delta, delta_light = _full_path(rng_np, n, N)
    ref = _weights_reference(p_L, p_E, delta, delta_light, power)
    bat = _weights_rendered(p_L, p_E, delta, delta_light, power)
    total = np.zeros(N)
    any_valid = np.zeros(N, bool)
    for s in range(n):
        ok = _valid(s, n, delta, delta_light)
        assert np.all(np.isfinite(ref[s])) and np.all((ref[s] >= 0) & (ref[s] <= 1))
        np.testing.assert_allclose(bat[s][ok], ref[s][ok], rtol=2e-5, atol=1e-7)
        total += np.where(ok, ref[s], 0.0)
        any_valid |= ok
    np.testing.assert_allclose(total[any_valid], 1.0, rtol=1e-4)


def infinite_endpoint_path(rng, n, N, directional: bool):
    """Full paths x_0 .. x_{n-1} whose x_0 is a direction at infinity, with the densities BDPT
    gives such a path (pbrt-v4's measure): p_L[0] the direction's solid-angle density with
    selection, p_E[0] the BSDF's solid-angle density at x_1 towards it, p_L[1] the bounding
    disc's area density times |cos| at x_1; the rest area densities. A directional light's
    direction is Dirac (``delta_light``)."""
    cos = rng.uniform(0.05, 1.0, (n, N))
    d2 = rng.uniform(0.1, 4.0, (n, N))
    pdf_dir = np.exp(rng.uniform(-3, 3, (n, N)))           # BSDF solid-angle densities
    disc = 1.0 / (np.pi * 2.0 ** 2)
    p_L = pdf_dir * cos / d2
    p_E = np.roll(pdf_dir, 1, 0) * cos / d2
    p_L[0] = 1.0 if directional else 0.3 * np.exp(rng.uniform(-4, 4, N))
    p_E[0] = pdf_dir[0]
    p_L[1] = disc * cos[1]
    delta = rng.uniform(size=(n, N)) < 0.25
    delta[0] = delta[-1] = False
    return (p_L.astype(np.float32), p_E.astype(np.float32), delta,
            np.full(N, directional))


@pytest.mark.parametrize("directional", [False, True])
@pytest.mark.parametrize("n", [3, 4, 5])
def test_weights_with_an_infinite_light_endpoint_sum_to_one(n, directional):
    """The scalar reference, the rendered ratio chains and the strategies' full path densities
    p_s = prod_{i<s} p_L[i] prod_{i>=s} p_E[i] (float64) give the same weights (power 2), and
    they sum to one over the strategies that can make the path (no s = 0 for a Dirac
    direction; (1, 1) unused)."""
    rng = np.random.default_rng(31 + n)
    N = 1000
    p_L, p_E, delta, delta_light = infinite_endpoint_path(rng, n, N, directional)
    ref = _weights_reference(p_L, p_E, delta, delta_light, 2.0)
    bat = _weights_rendered(p_L, p_E, delta, delta_light, 2.0)
    L, E = p_L.astype(np.float64), p_E.astype(np.float64)
    valid = {}
    for s in range(n):
        if n == 2 and s == 1:
            valid[s] = np.zeros(N, bool)
        elif s == 0:
            valid[s] = ~delta_light
        else:
            valid[s] = ~delta[s - 1] & ~delta[s]
    # Dirac vertices: remap0 (the zero density of a Dirac lobe counts as 1), as the chain does
    p = {s: np.prod(L[:s], 0) * np.prod(E[s:], 0) for s in range(n)}
    total = sum(np.where(valid[s], p[s] ** 2, 0.0) for s in range(n))
    checked = 0
    for s in range(n):
        ok = valid[s] & (total > 0)
        np.testing.assert_allclose(bat[s][ok], ref[s][ok], rtol=2e-5, atol=1e-7)
        w_true = p[s][ok] ** 2 / total[ok]
        np.testing.assert_allclose(ref[s][ok], w_true, rtol=1e-3, atol=1e-6)
        checked += ok.sum()
    assert checked > N
    w_sum = sum(np.where(valid[s], ref[s], 0.0) for s in range(n))
    np.testing.assert_allclose(w_sum[total > 0], 1.0, rtol=1e-4)


@pytest.mark.parametrize("weight", [mis_weight_reference, mis_weight_rendered])
def test_mis_weights_are_finite_for_extreme_and_zero_densities(weight):
    z = jnp.zeros(4)
    dens = jnp.asarray([0.0, 1e-38, 1e30, 3e38])
    cam = [(dens, dens[::-1], z > 0), (dens[::-1], dens, z > 0), (dens, z, z > 0)]
    light = [(z, dens, z > 0), (dens, dens * 0 + 1e-30, z > 0)]
    for power in (1.0, 2.0, 4.0):
        w = np.asarray(weight(cam, light, z > 0, power))
        assert np.all(np.isfinite(w)) and np.all((w >= 0) & (w <= 1)), w


@pytest.mark.parametrize("weight", [mis_weight_reference, mis_weight_rendered])
def test_mis_weight_gradients_are_finite(weight):
    import jax

    def f(x):
        one = jnp.ones(3)
        cam = [(one, one, one < 0), (x, x * 1e-30, one < 0), (x * 0, x, one < 0)]
        light = [(x * 1e30, x * 0, one < 0)]
        return jnp.sum(weight(cam, light, one < 0, 2.0))

    g = jax.grad(f)(jnp.asarray([0.0, 1e-20, 1.0]))
    assert np.all(np.isfinite(np.asarray(g)))


# --- the Cornell box: per-strategy images ---------------------------------------------------------

@pytest.fixture(scope="module")
def cornell():
    return scenes.cornell_box(resolution=16)


@pytest.fixture(scope="module")
def cornell_strategies(cornell):
    """Per-strategy (unweighted, weighted) images of 12 independent renders."""
    return [BD.render_strategies(cornell, BD.BDPTConfig(max_depth=DEPTH), spp=128, seed=s)
            for s in SEEDS]


@pytest.fixture(scope="module")
def cornell_pt(cornell):
    # seeds disjoint from BDPT's: equal seeds share the pixel jitter streams, and the correlated
    # pairs would weaken the comparison
    return renders(cornell, "pt", seeds=range(1000, 1012), spp=64, max_depth=DEPTH, rr_depth=-1)


def test_bdpt_agrees_with_path_tracer_on_cornell_box(cornell_strategies, cornell_pt):
    bdpt = np.stack([sum(w for _, w in r.values()) for r in cornell_strategies])
    assert_agree(bdpt, cornell_pt, regions=4, label="bdpt vs pt, cornell_box")
    # BDPT with MIS has lower variance per sample than the path tracer here (bdpt: 128 spp,
    # pt: 64 spp; standard errors scale as 1 / sqrt(spp))
    _, se_b = region_stats(bdpt)
    _, se_p = region_stats(cornell_pt)
    assert np.median(se_b * np.sqrt(128 / 64) / np.maximum(se_p, 1e-12)) < 1.0


def test_pyramid_has_every_strategy(cornell_strategies):
    keys = list(cornell_strategies[0])
    expected = [(0, 2), (0, 3), (1, 2), (2, 1), (0, 4), (1, 3), (2, 2), (3, 1)]
    assert keys == expected
    r = cornell_strategies[0]
    for (s, t), (unw, wtd) in r.items():
        assert np.all(np.isfinite(unw)) and np.all(np.isfinite(wtd))
        assert unw.max() > 0 and wtd.max() > 0, (s, t)
    # (0, 2): the light seen directly, weight one
    np.testing.assert_array_equal(r[(0, 2)][0], r[(0, 2)][1])


@pytest.mark.parametrize("length", [2, 3])
def test_each_unweighted_strategy_is_unbiased_for_its_path_length(cornell, cornell_strategies,
                                                                  length):
    """s = 0 (BSDF sampling hits the light), s = 1 (light sampling), s >= 2 (interior
    connections) and t = 1 (light tracing, splatted) each estimate all paths of one length on
    their own: compare each with the path tracer restricted to that length (Veach fig. 10.3)."""
    pt = renders(cornell, "pt", seeds=[1000 + s for s in SEEDS], spp=64, path_length=length,
                 rr_depth=-1)
    for s in range(length + 1):
        t = length + 1 - s
        unw = np.stack([r[(s, t)][0] for r in cornell_strategies])
        # s = 0 must hit the small light by BSDF sampling: rare, so compare coarser regions
        assert_agree(unw, pt, regions=2 if s == 0 else 4,
                     label=f"unweighted (s={s}, t={t}) vs pt length {length}")
    wtd = np.stack([sum(r[(s, length + 1 - s)][1] for s in range(length + 1))
                    for r in cornell_strategies])
    assert_agree(wtd, pt, regions=4, label=f"MIS sum of length {length} vs pt")


def test_strategy_images_are_written(cornell, cornell_strategies, tmp_path):
    img = jgi.render(cornell, "bdpt", spp=128, seed=0, max_depth=DEPTH,
                     strategy_images=str(tmp_path))
    np.testing.assert_allclose(img, sum(w for _, w in cornell_strategies[0].values()),
                               rtol=1e-5, atol=1e-6)
    assert (tmp_path / "pyramid.png").exists()
    assert (tmp_path / "s2_t2_weighted.exr").exists()
    assert (tmp_path / "s3_t1_unweighted.png").exists()


# --- caustics, point lights, robustness ----------------------------------------------------------

def test_bdpt_agrees_with_path_tracer_on_caustics():
    scene = scenes.cornell_box_caustics(resolution=16)
    bdpt = renders(scene, "bdpt", spp=64, max_depth=DEPTH)
    pt = renders(scene, "pt", seeds=[2000 + s for s in SEEDS], spp=128, max_depth=DEPTH,
                 rr_depth=-1)
    assert_agree(bdpt, pt, regions=4, label="bdpt vs pt, cornell_box_caustics")


def test_point_light_over_plane_matches_closed_form():
    """A delta light: no s = 0 strategy; light sampling (s = 1) and light tracing (t = 1) share
    the paths by MIS."""
    rho, I, h = 0.5, 10.0, 1.0
    scene = scenes.point_light_plane(resolution=16, intensity=I, height=h, albedo=rho)
    imgs = renders(scene, "bdpt", spp=8, max_depth=2)
    ref = point_light_reference(scene, rho, I, h)
    mean, se = region_stats(imgs, regions=4)
    ref_regions = ref.reshape(4, 4, 4, 4).mean(axis=(1, 3))
    z = np.abs(mean[..., 0] - ref_regions) / se[..., 0]
    assert z.max() < critical_t(len(imgs) - 1, z.size), z


def test_no_nan_or_inf_on_degenerate_inputs():
    with np.errstate(all="raise"):
        img = jgi.render(degenerate_scene(), "bdpt", spp=8, seed=0, max_depth=2)
    assert np.all(np.isfinite(img))
    assert img.max() > 0


def test_reproducible():
    scene = scenes.point_light_plane(resolution=16)
    a = jgi.render(scene, "bdpt", spp=2, seed=5, max_depth=2)
    b = jgi.render(scene, "bdpt", spp=2, seed=5, max_depth=2)
    np.testing.assert_array_equal(a, b)
