"""Vertex connection and merging (issue 22).

* The recursive MIS quantities give, for every technique of a path, the weight the full path
  densities give (Veach's formula with merging's density eta p), and they sum to one.
* ``bpt`` mode is jgi's BDPT path for path (same random numbers, the same weights computed the
  other way).
* ``vcm`` agrees with the path tracer on the Cornell box per image region.
* On ``mirror_sds`` (a point light, a mirror and a diffuse floor seen in the mirror), the merging
  modes converge to the closed form, which includes specular-diffuse-specular light, while BDPT
  and ``bpt`` find only the direct part (its closed form).
* The technique images sum to the image; the image's derivative in r_0 matches finite
  differences; bad scenes are refused by name.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jgi
from jgi.analysis.closed_form import mirror_sds_image
from jgi.core.errors import ParameterError
from jgi.estimators import vcm
from jgi.scene import SceneBuilder, builtin
from tests.support.stats import FAMILY_ALPHA, assert_agree, critical_t, region_stats

# --- MIS: recursive weights against full path densities -------------------------------------------


def _unit(v):
    return v / np.linalg.norm(v)


def _random_path(rng, k):
    """x_0 on an area light (area A) .. x_{k-1} on diffuse surfaces, x_k the pinhole: positions
    and unit normals facing the neighbours (every cosine positive)."""
    x = rng.uniform(-1, 1, (k + 1, 3))
    n = []
    for i in range(k):
        towards = [x[j] - x[i] for j in (i - 1, i + 1) if 0 <= j <= k]
        n.append(_unit(sum(_unit(t) for t in towards) + rng.normal(0, 0.2, 3)))
    return x, n


def _cos(x, n, i, j, med=None):
    """|cos| at x_i towards x_j (1 at a medium vertex)."""
    if med is not None and med[i]:
        return 1.0
    return abs(np.dot(n[i], _unit(x[j] - x[i])))


def _d2(x, i, j):
    return float(np.sum((x[j] - x[i]) ** 2))


def _pdf_dir(x, n, i, j, med=None):
    """Solid-angle density at x_i of the direction towards x_j: cosine-weighted at a surface,
    the isotropic phase function 1 / 4 pi at a medium vertex."""
    if med is not None and med[i]:
        return 1.0 / (4 * np.pi)
    return _cos(x, n, i, j) / np.pi


def _p_dist(x, i, j, med, sigma):
    """The distance density of segment x_i x_j towards x_j's kind (one channel, sigma): p(d)
    at a medium vertex, P(d) at a surface; 1 in vacuum."""
    if med is None:
        return 1.0
    d = np.sqrt(_d2(x, i, j))
    return sigma * np.exp(-sigma * d) if med[j] else np.exp(-sigma * d)


def _recursive_weights(x, n, area, p_film, fs, b, mode, med=None, sigma=0.0):
    """{technique: weight} from jgi.estimators.vcm's recursion and weight functions (``med``:
    per vertex, a medium vertex; x_0 and x_k are surfaces)."""
    k = len(x) - 1
    c = lambda i, j: jnp.float32(_cos(x, n, i, j, med))  # noqa: E731
    d2 = lambda i, j: jnp.float32(_d2(x, i, j))  # noqa: E731
    pw = lambda i, j: jnp.float32(_pdf_dir(x, n, i, j, med))  # noqa: E731
    pd = lambda i, j: jnp.float32(_p_dist(x, i, j, med, sigma))  # noqa: E731
    at = lambda i: fs.at(None if med is None else jnp.bool_(med[i]))  # noqa: E731

    def arrive(m, i, j):   # from x_i to x_j
        if med is None:
            return vcm.mis_arrive(m, d2(i, j), c(j, i), b)
        return vcm.mis_arrive(m, d2(i, j), c(j, i), b, pd(j, i), pd(i, j))

    light = [None] * k
    m = vcm.mis_light_start(pw(0, 1), jnp.float32(1.0 / area), c(0, 1), False, fs.surface, b)
    for i in range(1, k):
        m = arrive(m, i - 1, i)
        light[i] = m
        m = vcm.mis_scatter(m, c(i, i + 1), pw(i, i + 1), pw(i, i - 1), False, at(i), b)
    camera = [None] * (k + 1)
    m = vcm.mis_camera_start(jnp.float32(p_film), b)
    for i in range(k - 1, -1, -1):
        m = arrive(m, i + 1, i)
        camera[i] = m
        if i > 0:
            m = vcm.mis_scatter(m, c(i, i - 1), pw(i, i - 1), pw(i, i + 1), False, at(i), b)
    w = {}
    connects, merges = mode in ("vcm", "bpt"), mode in ("vcm", "bpm")
    area_of = lambda i, j: pw(i, j) * c(j, i) / d2(i, j) * pd(i, j)  # x_j sampled from x_i
    if connects:
        w[("connect", 0, k + 1)] = vcm.weight_emission(camera[0], jnp.float32(1 / area),
                                                       pw(0, 1), b)
        if k >= 2:
            w[("connect", 1, k)] = vcm.weight_next_event(
                camera[1], jnp.float32(1 / area), area_of(1, 0), area_of(0, 1), pw(1, 2),
                False, at(1), b)
        for s in range(2, k):
            y, z = s - 1, s
            w[("connect", s, k + 1 - s)] = vcm.weight_connection(
                light[y], camera[z], area_of(z, y), area_of(y, z), pw(y, y - 1), pw(z, z + 1),
                at(y), b, at(z))
        if k >= 2:
            pdf_cam = p_film * c(k - 1, k) / d2(k - 1, k) * pd(k, k - 1)
            w[("connect", k, 1)] = vcm.weight_camera_connection(
                light[k - 1], pdf_cam, pw(k - 1, k - 2), at(k - 1), b)
    if merges:
        for i in range(1, k):
            w[("merge", i)] = vcm.weight_merge(light[i], camera[i], pw(i, i - 1), pw(i, i + 1),
                                               at(i), b)
    return {t: float(v) for t, v in w.items()}


def _explicit_weights(x, n, area, p_film, eta, b, mode, med=None, sigma=0.0, eta_volume=None):
    """The same weights from full path densities (area measure; volume measure at a medium
    vertex, with the segments' distance densities), Veach's w = p^b / sum p^b with a merge at
    x_i of density eta_i p_fwd(x_0..x_i) p_rev(x_i..x_{k-1}) (eta_i the merge disc's area, or
    at a medium vertex the ball's volume, times N_L)."""
    k = len(x) - 1

    def area_of(i, j):   # x_j sampled from x_i
        return (_pdf_dir(x, n, i, j, med) * _cos(x, n, j, i, med) / _d2(x, i, j)
                * _p_dist(x, i, j, med, sigma))
    fwd = [1.0 / area] + [area_of(i - 1, i) for i in range(1, k)]
    rev = [area_of(i + 1, i) for i in range(0, k - 1)]
    rev.append(p_film * _cos(x, n, k - 1, k, med) / _d2(x, k - 1, k)
               * _p_dist(x, k, k - 1, med, sigma))
    P = {}
    if mode in ("vcm", "bpt"):
        for s in range(0, k + 1):
            if (s, k + 1 - s) != (1, 1):
                P[("connect", s, k + 1 - s)] = np.prod(fwd[:s]) * np.prod(rev[s:])
    if mode in ("vcm", "bpm"):
        for i in range(1, k):
            eta_i = eta_volume if med is not None and med[i] else eta
            P[("merge", i)] = eta_i * np.prod(fwd[:i + 1]) * np.prod(rev[i:])
    total = sum(p ** b for p in P.values())
    return {t: p ** b / total for t, p in P.items()}


@pytest.mark.parametrize("mode", ["vcm", "bpt", "bpm"])
@pytest.mark.parametrize("b", [1.0, 2.0])
def test_mis_weights_of_all_techniques_sum_to_one(mode, b):
    rng = np.random.default_rng(7)
    for k in (2, 3, 4, 5):
        for _ in range(4):
            x, n = _random_path(rng, k)
            area, p_film, eta = 0.3, 0.8, float(rng.uniform(0.05, 5.0))
            cfg = vcm.VCMConfig(mode=mode, heuristic="power" if b == 2.0 else "balance")
            f = vcm.mis_factors(jnp.float32(np.sqrt(eta / np.pi)), 1, cfg)
            got = _recursive_weights(x, n, area, p_film, vcm.Factors(f), b, mode)
            want = _explicit_weights(x, n, area, p_film, eta, b, mode)
            assert set(got) == set(want), (mode, k)
            for t in want:
                assert got[t] == pytest.approx(want[t], rel=2e-4, abs=1e-6), (mode, b, k, t)
            assert sum(got.values()) == pytest.approx(1.0, abs=1e-5), (mode, b, k)


@pytest.mark.parametrize("mode", ["vcm", "bpt", "bpm"])
@pytest.mark.parametrize("b", [1.0, 2.0])
def test_mis_weights_with_medium_vertices(mode, b):
    """Paths whose interior vertices are medium vertices at random (no cosine, the isotropic
    phase function, distance densities p(d) or P(d) per segment, a merge ball of volume
    eta_V / N_L there): the recursion gives the explicit weights too, which needs the
    distance densities at arrival and the per-vertex eta in the scatter and merge steps."""
    rng = np.random.default_rng(11)
    sigma = 0.7
    for k in (2, 3, 4, 5):
        for _ in range(6):
            x, n = _random_path(rng, k)
            med = [False] + [bool(rng.uniform() < 0.5) for _ in range(k - 1)] + [False]
            area, p_film = 0.3, 0.8
            eta, eta_v = float(rng.uniform(0.05, 5.0)), float(rng.uniform(0.05, 5.0))
            cfg = vcm.VCMConfig(mode=mode, heuristic="power" if b == 2.0 else "balance")
            r = jnp.float32(np.sqrt(eta / np.pi))
            r_v = jnp.float32((eta_v * 3 / (4 * np.pi)) ** (1 / 3))
            fs = vcm.Factors(vcm.mis_factors(r, 1, cfg), None)
            fs = fs._replace(volume=vcm.volume_mis_factors(r_v, fs.surface, r, 1, cfg))
            got = _recursive_weights(x, n, area, p_film, fs, b, mode, med, sigma)
            want = _explicit_weights(x, n, area, p_film, eta, b, mode, med, sigma, eta_v)
            assert set(got) == set(want), (mode, k)
            for t in want:
                assert got[t] == pytest.approx(want[t], rel=2e-4, abs=1e-6), (mode, b, k, t, med)
            assert sum(got.values()) == pytest.approx(1.0, abs=1e-5), (mode, b, k)


# --- bpt mode is BDPT -----------------------------------------------------------------------------

def test_bpt_mode_is_bdpt_path_for_path():
    """Same streams, same paths: the images differ only by float rounding (the weights are
    computed by SmallVCM's recursion here, by pbrt's ratios in BDPT). Only without Dirac
    vertices: there the two conventions differ (SmallVCM keeps a specular bounce's cosines in
    the ratios, pbrt's remap0 drops its whole area density), both valid weightings. In fog
    (RGB extinction and albedo, g = 0.4) the free flights, medium vertices and the distance
    densities of both recursions agree too (measured: 3e-8 apart, values up to 0.28). The fog
    box's paths reach its walls too, so surface vertices are compared as well (the same box
    without fog, a compile of each estimator more, is left out for the suite's time)."""
    scene = builtin.cornell_box_fog(resolution=8, sigma_t=(0.45, 0.6, 0.8),
                                    albedo=(0.9, 0.8, 0.7), g=0.4)
    a = jgi.render(scene, "vcm", spp=2, seed=4, mode="bpt", max_depth=4, roulette=False)
    b = jgi.render(scene, "bdpt", spp=2, seed=4, max_depth=4)
    assert np.all(np.isfinite(a))
    np.testing.assert_allclose(a, b, rtol=2e-3, atol=2e-4 * b.max())


# --- vcm against the path tracer ------------------------------------------------------------------

def test_vcm_agrees_with_path_tracer_on_the_cornell_box():
    """The caustic Cornell box (mirror and glass spheres): Dirac vertices in both subpaths."""
    scene = builtin.cornell_box_caustics(resolution=16)
    seeds = range(8)
    pt = np.stack([jgi.render(scene, "pt", spp=256, seed=100 + s, max_depth=4, rr_depth=-1)
                   for s in seeds])
    imgs = np.stack([jgi.render(scene, "vcm", spp=16, seed=s, max_depth=4, radius=0.03)
                     for s in seeds])
    assert np.all(np.isfinite(imgs)) and imgs.min() >= 0
    assert_agree(imgs, pt, label="vcm vs pt, cornell_box_caustics")


# --- specular-diffuse-specular light: the closed form ---------------------------------------------

def _assert_matches_closed_form(images, expected, label, bias):
    """One-sample t-test per region and channel against a closed form (Bonferroni), with an
    allowance ``bias`` (relative) for a consistent estimator's filter bias."""
    m, s = region_stats(images)
    e, _ = region_stats(np.stack([expected, expected]))   # two copies: region means, se 0
    t = np.abs(m - e) / np.sqrt(s ** 2 + (bias * e) ** 2 + 1e-20)
    crit = critical_t(len(images) - 1, t.size, FAMILY_ALPHA)
    assert t.max() < crit, f"{label}: t = {t.max():.2f} > {crit:.2f}; {m.ravel()} vs {e.ravel()}"


@pytest.fixture(scope="module")
def sds():
    scene = builtin.mirror_sds(resolution=16)
    return scene, mirror_sds_image(scene), mirror_sds_image(scene, sds=False)


@pytest.mark.parametrize("mode", ["vcm", "ppm"])   # bpm: its weights in the MIS test above
def test_merging_finds_specular_diffuse_specular_light(sds, mode):
    """A box filter of radius r averages the floor irradiance E = I h / d^3 over a disc; its
    relative bias is largest under the light, -(3/4) (r / h)^2 (second order), so at most
    0.75% for r_0 = 0.1, h = 1 (and it shrinks with r_i): 1% is allowed. The SDS part is ~23%
    of the image: found at > 5 standard errors."""
    scene, full, direct = sds
    imgs = np.stack([jgi.render(scene, "vcm", spp=16, seed=s, mode=mode, max_depth=4,
                                radius=0.1) for s in range(6)])
    assert np.all(np.isfinite(imgs))
    _assert_matches_closed_form(imgs, full, f"{mode} vs closed form (L D S E + L S D S E)", 0.01)
    means = imgs.mean((1, 2, 3))
    excess = (means.mean() - direct.mean()) / (means.std(ddof=1) / np.sqrt(len(means)))
    assert excess > 5.0, f"{mode}: the SDS light is not found ({excess:.1f} standard errors)"


def test_connections_miss_specular_diffuse_specular_light(sds):
    """BDPT (and so ``bpt`` mode, equal to it: above) finds the direct part alone."""
    scene, full, direct = sds
    imgs = np.stack([jgi.render(scene, "bdpt", spp=4, seed=s, max_depth=4) for s in range(6)])
    _assert_matches_closed_form(imgs, direct, "bdpt vs closed form (L D S E only)", 0.0)


# --- technique images, derivatives, errors --------------------------------------------------------

def test_technique_images_sum_to_the_image():
    """Each technique's image (rows kept per technique) against the render, which sums a
    pixel's connections and merges as it goes (depth 3: connections with s, t >= 2 too)."""
    scene = builtin.cornell_box_caustics(resolution=8)
    cfg = vcm.VCMConfig(max_depth=3, radius=0.1)
    techs = vcm.render_techniques(scene, cfg, spp=2, seed=5)
    assert list(techs) == cfg.techniques()
    img = vcm.render(scene, cfg, spp=2, seed=5).image
    total = sum(w for _, w in techs.values())
    np.testing.assert_allclose(total, img, rtol=1e-4, atol=1e-5 * img.max())
    for t, (unw, wtd) in techs.items():
        assert np.all(np.isfinite(unw)) and np.all(wtd <= unw + 1e-5 * (1 + unw)), t
    assert techs[("merge", 2)][0].sum() > 0 and techs[("connect", 1, 2)][1].sum() > 0
    assert techs[("connect", 2, 2)][1].sum() > 0


def test_image_is_differentiable_in_the_radius():
    """d(mean image)/d(r_0) by jax.grad against a central difference, with the Epanechnikov
    filter: the image is continuous in r, its slope jumps where a light vertex crosses the
    disc's edge, so the difference step is small (no crossing within it at this seed)."""
    scene = builtin.cornell_box(resolution=8)
    cfg = vcm.VCMConfig(max_depth=3, filter="epanechnikov")

    @jax.jit
    @jax.value_and_grad
    def mean(r):
        return jnp.mean(vcm.iteration_image(scene, cfg, jnp.uint32(3), jnp.uint32(0), r, {},
                                            pairs_per_vertex=256))

    r0, h = 0.3, 5e-4
    g = float(mean(jnp.float32(r0))[1])
    fd = (float(mean(jnp.float32(r0 + h))[0]) - float(mean(jnp.float32(r0 - h))[0])) / (2 * h)
    assert np.isfinite(g) and abs(g) > 1e-3
    assert g == pytest.approx(fd, rel=0.03)


def test_directional_light_on_a_plane_matches_the_closed_form():
    """A diffuse plane (albedo 0.5) under a directional light of irradiance 1 at normal
    incidence has radiance 0.5 / pi everywhere; VCM starts light subpaths on the light's
    bounding disc (SmallVCM's background light) and weighs them against light sampling. The
    image (the plane fills it) over 4 seeds: within 4 standard errors."""
    b = SceneBuilder("sun")
    b.material("white", "diffuse", diffuse=(0.5, 0.5, 0.5))
    b.quad((-1, 0, -1), (0, 0, 2), (2, 0, 0), "white")
    b.directional_light((0, -1, 0), (1, 1, 1))
    b.camera(position=(0, 2, 0.01), look_at=(0, 0, 0), fov=30, width=4, height=4)
    scene = b.build()
    means = [jgi.render(scene, "vcm", spp=4, seed=s, max_depth=2).mean() for s in range(4)]
    m, se = np.mean(means), np.std(means, ddof=1) / 2.0
    assert abs(m - 0.5 / np.pi) < 4 * se + 1e-4, (m, 0.5 / np.pi, se)


def test_kernel_was_renamed_filter():
    """The merge filter is called ``filter``, as in photon mapping; the former name says so."""
    scene = builtin.cornell_box(resolution=4)
    with pytest.raises(ParameterError,
                       match="estimator 'vcm': parameter 'kernel' was renamed 'filter'"):
        jgi.render(scene, "vcm", spp=1, seed=0, kernel="box")


def test_volume_merging_refuses_a_filter_without_a_3d_form():
    """In a medium a merge at a medium vertex needs the filter's 3-D kernel: the Gaussian and
    cone filters have none in jgi, and the error names the allowed ones (before any compile);
    connections alone (bpt) need no filter and ignore it: the image is the box filter's, bit for
    bit (bpt mode's compile key drops the filter, so this reuses the fog-box programs of the
    test above)."""
    scene = builtin.cornell_box_fog(resolution=8, sigma_t=(0.45, 0.6, 0.8),
                                    albedo=(0.9, 0.8, 0.7), g=0.4)
    with pytest.raises(ParameterError, match=r"filter 'gaussian'.*box, epanechnikov"):
        jgi.render(scene, "vcm", spp=1, seed=0, filter="gaussian")
    kw = dict(spp=1, seed=0, mode="bpt", max_depth=4, roulette=False)
    img = jgi.render(scene, "vcm", filter="gaussian", **kw)
    assert np.all(np.isfinite(img))
    np.testing.assert_array_equal(img, jgi.render(scene, "vcm", **kw))
