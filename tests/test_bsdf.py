"""BSDFs (:mod:`jgi.physics.bsdf`): sampling against evaluation, Dirac lobes against optics, and the
physical properties every BSDF must have.

* Diffuse and Phong: the valid directions of ``sample`` follow ``evaluate``'s pdf (chi-square
  over the sphere, failed samples as their own category, so the pdf must integrate to the
  probability that sampling succeeds); the returned weight is f |cos| / pdf at the same
  direction.
* Mirror: the exact reflection. Dielectric: the fraction of reflections is the Fresnel
  reflectance (binomial z-test against a float64 reference), refraction obeys Snell's law,
  total internal reflection only reflects, weights are the tint (importance transport) and the
  tint / eta^2 for refraction (radiance transport, Veach 1997 sec. 5.2).
* Reciprocity f(wo, wi) = f(wi, wo) and energy conservation (albedo <= k_d + k_s, equality at
  normal incidence), by hypothesis over directions, albedos and exponents.
* Degenerate inputs give no NaN or Inf.

All material kinds go through one compiled function (``tests.support.bsdf_samplers``: ``KINDS``
static, the kind a traced array).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from jgi.analysis.chi2 import SphereDomain, assert_chi2
from jgi.core.vec import EDGE_ON_COS
from jgi.physics import bsdf as B
from jgi.scene import DIELECTRIC, DIFFUSE, MIRROR, PHONG
from tests.support.bsdf_samplers import (
    N,
    evaluate,
    fresnel_reference,
    material,
    sample,
    sample_from_uniforms,
)
from tests.support.directions import NORMAL, direction, reflect_np


def luminance(c):
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


# --- diffuse and Phong: sampling matches evaluation ---------------------------------------------

GLOSSY = [
    ("diffuse", material(DIFFUSE, kd=(0.2, 0.5, 0.8)), 0.0),
    ("diffuse", material(DIFFUSE, kd=(0.2, 0.5, 0.8)), 50.0),
    ("diffuse", material(DIFFUSE, kd=0.7), 89.0),
    ("phong n=1", material(PHONG, kd=(0.5, 0.4, 0.3), ks=0.3, n=1.0), 30.0),
    ("phong n=10", material(PHONG, kd=0.2, ks=(0.7, 0.6, 0.5), n=10.0), 0.0),
    ("phong n=10", material(PHONG, kd=0.2, ks=(0.7, 0.6, 0.5), n=10.0), 70.0),
    ("phong n=100", material(PHONG, kd=0.4, ks=0.4, n=100.0), 89.0),
    ("phong n=1000", material(PHONG, kd=(0.05, 0.1, 0.0), ks=0.9, n=1000.0), 45.0),
    ("phong n=1000", material(PHONG, kd=0.0, ks=0.9, n=1000.0), 89.0),
    ("phong n=0", material(PHONG, kd=0.3, ks=0.3, n=0.0), 60.0),
]


@pytest.mark.parametrize("backside", [False, True])
@pytest.mark.parametrize("case", range(len(GLOSSY)), ids=[f"{g[0]}-{g[2]:g}deg" for g in GLOSSY])
def test_glossy_sampling_matches_evaluate(case, backside):
    """Chi-square of the sampled directions against evaluate's pdf; weight = f |cos| / pdf."""
    label, mat, theta = GLOSSY[case]
    n = -NORMAL if backside else NORMAL  # two-sided: wo below the geometric normal
    wo = direction(theta)
    s = sample(mat, n, wo, seed=case + 100 * backside)
    v = s["valid"]
    nf = NORMAL
    if mat[0] == DIFFUSE:
        dom = SphereDomain(axis=nf)
    else:  # rings about the mirror direction, fine near the axis for sharp lobes
        a_min = 0.02 / (float(mat[3]) + 1.0)
        dom = SphereDomain(axis=reflect_np(wo, nf),
                           a_edges=np.concatenate([[0.0], np.geomspace(a_min, 2.0, 40)]))
    r = assert_chi2(s["wi"][v], lambda w: evaluate(mat, np.float32(n), np.float32(wo),
                                                   np.float32(w))[1],
                    dom, f"{label} theta_o={theta}", n_total=N)
    # the pdf integrates to the probability that sampling succeeds (binomial error)
    frac = v.mean()
    se = np.sqrt(max(frac * (1 - frac), 1.0 / N) / N)
    assert abs(r.pdf_integral - frac) < 5 * se + 1e-4, (r.pdf_integral, frac, se)
    if mat[0] == DIFFUSE:
        assert frac == 1.0 and abs(r.pdf_integral - 1.0) < 1e-4
    # weight = f |cos| / pdf and pdf = evaluate's pdf at the sampled direction
    cos = np.abs(s["wi"] @ nf)
    np.testing.assert_allclose(s["pdf"][v], s["eval_pdf"][v], rtol=1e-5)
    f_over_pdf = s["f"][v] / s["eval_pdf"][v][:, None]
    expect = f_over_pdf * cos[v][:, None]
    # cos is rounded to ~1e-7 absolute in float32: that sets the tolerance at grazing wi
    err = np.abs(s["weight"][v] - expect)
    assert np.all(err <= 1e-5 * expect + 3e-7 * f_over_pdf), err.max()
    assert not s["delta"].any()
    assert np.all(s["weight"][~v] == 0) and np.all(np.isfinite(s["weight"]))
    assert np.all(s["wi"][v] @ nf > 0), "valid samples leave on wo's side"


def test_phong_lobe_choice_follows_albedo_luminance():
    """With k_d = 0 every sample comes from the lobe; the lobe fraction is lum(k_s) / lum(sum)."""
    kd, ks = np.array([0.1, 0.6, 0.2]), np.array([0.5, 0.1, 0.3])
    mat = material(PHONG, kd=kd, ks=ks, n=5000.0)
    wo = direction(0.0)
    s = sample(mat, NORMAL, wo, seed=7, count=100_000)
    near_axis = (s["wi"] @ NORMAL) > np.cos(np.radians(5.0))  # lobe of n = 5000: ~1 deg wide
    p_lobe = luminance(ks) / (luminance(kd) + luminance(ks))
    p_diffuse_near = (1 - p_lobe) * np.sin(np.radians(5.0)) ** 2
    expect = p_lobe * 1.0 + p_diffuse_near
    se = np.sqrt(expect * (1 - expect) / len(near_axis))
    assert abs(near_axis.mean() - expect) < 5 * se, (near_axis.mean(), expect)


# --- Dirac lobes ----------------------------------------------------------------------------------

@pytest.mark.parametrize("backside", [False, True])
def test_mirror_gives_the_exact_reflection(backside):
    n = -NORMAL if backside else NORMAL
    ks = (0.9, 0.8, 0.7)
    mat = material(MIRROR, ks=ks)
    for theta in [0.0, 37.0, 89.0]:
        wo = direction(theta)
        s = sample(mat, n, wo, seed=3, count=64)
        np.testing.assert_allclose(s["wi"], np.broadcast_to(reflect_np(wo, NORMAL), (64, 3)),
                                   atol=2e-6)
        np.testing.assert_allclose(s["weight"], np.broadcast_to(ks, (64, 3)), rtol=1e-6)
        assert s["delta"].all() and s["valid"].all() and np.all(s["pdf"] == 0)
        assert np.all(s["f"] == 0) and np.all(s["eval_pdf"] == 0)  # no non-Dirac part


def test_fresnel_against_reference():
    cos = np.linspace(0.0, 1.0, 1001)
    for eta in [1.0, 1.33, 1.5, 2.4, 1 / 1.5, 1 / 2.4]:
        got = np.asarray(B.fresnel_dielectric(jnp.float32(cos), jnp.float32(eta)))
        np.testing.assert_allclose(got, fresnel_reference(cos, np.float32(eta)), atol=2e-6)
    # normal incidence: ((eta - 1) / (eta + 1))^2
    assert abs(float(B.fresnel_dielectric(jnp.float32(1.0), jnp.float32(1.5))) - 0.04) < 1e-6


DIELECTRIC_CASES = [  # (theta_o in degrees, wo outside the glass?, ior)
    (0.0, True, 1.5), (30.0, True, 1.5), (75.0, True, 1.5), (89.0, True, 1.5),
    (20.0, False, 1.5), (40.0, False, 1.5), (45.0, False, 1.5), (80.0, False, 1.5),
    (60.0, True, 2.4), (60.0, True, 1.0),
]


@pytest.mark.parametrize("theta,outside,ior", DIELECTRIC_CASES)
def test_dielectric_branches_fresnel_and_snell(theta, outside, ior):
    ks = np.array([0.9, 0.95, 1.0])
    mat = material(DIELECTRIC, ks=ks, ior=ior)
    n = NORMAL
    wo = direction(theta, n=n if outside else -n)
    eta_i, eta_t = (1.0, ior) if outside else (ior, 1.0)
    count = 200_000
    out = {mode: sample(mat, n, wo, seed=int(theta) + 11, count=count, mode=mode)
           for mode in (B.RADIANCE, B.IMPORTANCE)}
    s = out[B.IMPORTANCE]
    assert s["valid"].all() and s["delta"].all() and np.all(s["pdf"] == 0)
    n_side = n if outside else -n                # the normal on wo's side
    cos_i = float(np.dot(wo, n_side))
    F = float(fresnel_reference(cos_i, np.float32(eta_t / eta_i)))
    refl = (s["wi"] @ n_side) > 0
    # reflection: the mirror direction; fraction = Fresnel reflectance (binomial z-test)
    np.testing.assert_allclose(s["wi"][refl],
                               np.broadcast_to(reflect_np(wo, n_side), (refl.sum(), 3)), atol=3e-6)
    se = np.sqrt(max(F * (1 - F), 1.0 / count) / count)
    assert abs(refl.mean() - F) < 5 * se, (refl.mean(), F, se)
    if F == 1.0:  # total internal reflection
        assert refl.all()
    t = s["wi"][~refl]
    if len(t):  # Snell: eta_i sin_i = eta_t sin_t, in the plane of incidence, on the far side
        np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=2e-6)
        sin_i = np.sqrt(1 - cos_i ** 2)
        sin_t = np.linalg.norm(np.cross(t, n_side), axis=1)
        np.testing.assert_allclose(eta_t * sin_t, eta_i * sin_i, atol=3e-6)
        assert np.all(t @ n_side < 0)
        plane_normal = np.cross(n_side, wo)
        np.testing.assert_allclose(t @ plane_normal, 0.0, atol=3e-6)
        tangential_o = wo - cos_i * n_side   # the tangential parts point opposite ways
        assert np.all(t @ tangential_o <= 1e-6)
    # energy: importance transport carries the tint on both branches, E[weight] = k_s
    np.testing.assert_allclose(s["weight"], np.broadcast_to(ks, s["weight"].shape), rtol=1e-6)
    # radiance transport: refraction scales by (eta_i / eta_t)^2, reflection does not
    r = out[B.RADIANCE]
    np.testing.assert_array_equal(r["wi"], s["wi"])  # same uniforms, same branch choices
    rr = (r["wi"] @ n_side) > 0
    np.testing.assert_allclose(r["weight"][rr], np.broadcast_to(ks, (rr.sum(), 3)), rtol=1e-6)
    np.testing.assert_allclose(r["weight"][~rr],
                               np.broadcast_to(ks * (eta_i / eta_t) ** 2, ((~rr).sum(), 3)),
                               rtol=1e-5)


# --- reciprocity and energy conservation (hypothesis) ---------------------------------------------

def _unit(a):
    """Directions on the upper hemisphere of NORMAL from uniforms (theta up to 89.9 deg)."""
    th = np.radians(89.9) * a[:, 0]
    ph = 2 * np.pi * a[:, 1]
    return np.stack([direction(np.degrees(t), np.degrees(p)) for t, p in zip(th, ph)])


def phong_reference(kd, ks, n_exp, nrm, wo, wi):
    """Modified Phong f (Lafortune & Willems 1994) in float64."""
    cos_a = np.maximum(np.einsum("ij,ij->i", wi, 2 * (wo @ nrm)[:, None] * nrm - wo), 0.0)
    lobe = np.where(cos_a > 0, cos_a, 1.0) ** n_exp * (cos_a > 0)
    return np.broadcast_to(kd / np.pi + ks * (n_exp + 2) / (2 * np.pi) * lobe[:, None],
                           (len(wo), 3))


BATCH = 64
HYP = settings(max_examples=30, deadline=None, derandomize=True)


@HYP
@given(dirs=hnp.arrays(np.float64, (BATCH, 4), elements=st.floats(0.0, 1.0)),
       kd=st.floats(0.0, 1.0), split=st.floats(0.0, 1.0), n_exp=st.floats(0.0, 1000.0),
       kind=st.sampled_from([DIFFUSE, PHONG]))
def test_reciprocity(dirs, kd, split, n_exp, kind):
    """f(wo, wi) = f(wi, wo), and f equals the float64 formula."""
    kd, n_exp = float(np.float32(kd)), float(np.float32(n_exp))  # what the material stores
    ks = float(np.float32((1.0 - kd) * split))
    mat = material(kind, kd=kd, ks=ks if kind == PHONG else 0.0, n=n_exp)
    wo, wi = _unit(dirs[:, :2]), _unit(dirs[:, 2:])
    f_oi, _ = evaluate(mat, np.float32(NORMAL), np.float32(wo), np.float32(wi))
    f_io, _ = evaluate(mat, np.float32(NORMAL), np.float32(wi), np.float32(wo))
    f_oi, f_io = np.asarray(f_oi), np.asarray(f_io)
    # float32 rounding of cos(alpha) ~ 1e-7 is amplified n times by cos^n
    rtol = 2e-6 * (1.0 + n_exp)
    peak = kd / np.pi + (ks if kind == PHONG else 0) * (n_exp + 2) / (2 * np.pi)
    np.testing.assert_allclose(f_oi, f_io, rtol=rtol, atol=1e-6 * peak)
    ref = phong_reference(kd, ks if kind == PHONG else 0.0, n_exp, NORMAL, wo, wi)
    np.testing.assert_allclose(f_oi, ref, rtol=rtol, atol=1e-6 * peak)


ALBEDO_SAMPLES = 16_384


@jax.jit
def _albedo(mat, n, wo, u):
    """Monte Carlo albedo E[f |cos| / pdf] under BSDF sampling, with its standard error."""
    s = sample_from_uniforms(mat, n, wo, u)
    w = s["weight"]
    m = w.mean(0)
    se = w.std(0) / jnp.sqrt(w.shape[0])
    return m, se


def albedo(mat, wo, seed):
    u = np.random.default_rng(seed).random((3, ALBEDO_SAMPLES), dtype=np.float32)
    m, se = _albedo(mat, np.float32(NORMAL), np.float32(wo), u)
    return np.asarray(m), np.asarray(se)


@HYP
@given(theta=st.floats(0.0, 89.9), kd=st.floats(0.0, 1.0), split=st.floats(0.0, 1.0),
       n_exp=st.floats(0.0, 1000.0), seed=st.integers(0, 2 ** 16))
def test_energy_conservation(theta, kd, split, n_exp, seed):
    """Albedo = integral of f cos over wi <= k_d + k_s <= 1 (5 standard errors)."""
    ks = (1.0 - kd) * split
    mat = material(PHONG, kd=kd, ks=ks, n=n_exp)
    m, se = albedo(mat, direction(theta), seed)
    assert np.all(m <= kd + ks + 5 * se + 1e-6), (m, se, kd + ks)
    assert np.all(m <= 1.0 + 5 * se + 1e-6)


@pytest.mark.parametrize("kd,ks,n_exp", [(0.5, 0.0, 1.0), (0.0, 1.0, 1.0), (0.3, 0.6, 20.0),
                                         (0.1, 0.9, 1000.0), (0.0, 1.0, 0.0)])
def test_albedo_at_normal_incidence_is_kd_plus_ks(kd, ks, n_exp):
    """At wo = n the Phong lobe lies above the surface: its albedo is exactly k_s, with the
    normalisation (n + 2) / (2 pi) (a wrong normalisation changes the mean)."""
    mat = material(PHONG, kd=kd, ks=ks, n=n_exp)
    m, se = albedo(mat, NORMAL, seed=int(n_exp) + 5)
    assert np.all(np.abs(m - (kd + ks)) <= 5 * se + 1e-5), (m, se)
    mat = material(DIFFUSE, kd=kd)
    m, se = albedo(mat, direction(80.0), seed=9)
    np.testing.assert_allclose(m, kd, rtol=1e-5)  # diffuse: weight = k_d exactly


# --- degenerate inputs ----------------------------------------------------------------------------

DEGENERATE_MATERIALS = [material(DIFFUSE, kd=0.5), material(PHONG, kd=0.3, ks=0.6, n=50.0),
                        material(PHONG, kd=0.0, ks=0.0, n=0.0), material(MIRROR, ks=1.0),
                        material(DIELECTRIC, ks=1.0, ior=1.5),
                        material(DIELECTRIC, ks=1.0, ior=1.0)]


def _exact_cos(n, wo) -> float:
    """cos(n, wo) of the float32 vectors jgi receives, computed exactly (float32 products are
    exact in float64; fsum adds them without rounding)."""
    return math.fsum(np.float64(np.float32(n)) * np.float64(np.float32(wo)))


@pytest.mark.parametrize("mi", range(len(DEGENERATE_MATERIALS)))
def test_degenerate_directions_are_finite(mi):
    """Edge-on and grazing directions give finite values, and a surface seen edge-on (within
    ``vec.EDGE_ON_COS``) scatters nothing. Edge-on is decided on the float32 input itself: a
    direction built in float64 at 90 degrees (``direction(90.0)``) is not edge-on once rounded
    to float32 (its cosine is -9.4e-9 here, or 1e-17 before rounding on a CPU whose numpy sin and
    cos round differently), which made this test depend on the processor. The pair (0.3, 0.4,
    0.866), (0.8, -0.6, 0) is exactly perpendicular in float32, and FMA contraction computes its
    cosine as +-7e-9 rather than 0."""
    mat = DEGENERATE_MATERIALS[mi]
    z = np.array([0.0, 0.0, 1.0])
    eps = 1e-7
    n3 = np.array([0.3, 0.4, np.sqrt(0.75)], np.float32)
    w3 = np.array([2 * np.float32(0.4), -2 * np.float32(0.3), 0.0], np.float32)
    cases = [  # (normal, wo)
        (z, np.array([1.0, 0.0, 0.0])),                              # wo in the surface plane
        (n3, w3), (n3, -w3), (-n3, w3),                              # exactly edge-on in 3-D
        (z, np.array([np.sqrt(1 - eps ** 2), 0.0, eps])),           # grazing, cos = 1e-7
        (z, np.array([np.sqrt(1 - eps ** 2), 0.0, -eps])),          # grazing from below
        (NORMAL, direction(90.0)), (NORMAL, direction(0.0)), (-NORMAL, direction(0.0)),
    ]
    assert _exact_cos(n3, w3) == 0.0
    for n, wo in cases:
        edge_on = abs(_exact_cos(n, wo)) <= EDGE_ON_COS / 2  # clear of the band's rounding
        for mode in (B.RADIANCE, B.IMPORTANCE):
            s = sample(mat, n, wo, seed=1, count=4096, mode=mode)
            for k, v in s.items():
                assert np.all(np.isfinite(v)), (k, n, wo)
            v = s["valid"]
            assert np.all(s["weight"][~v] == 0)
            if edge_on:
                assert not v.any(), "nothing is scattered by a surface seen exactly edge-on"
        f, pdf = evaluate(mat, np.float32(n), np.float32(wo), np.float32(s["wi"]))
        assert np.all(np.isfinite(np.asarray(f))) and np.all(np.isfinite(np.asarray(pdf)))


def test_dielectric_at_exactly_the_critical_angle():
    """sin(theta_i) = 1 / ior from inside: total internal reflection (or a grazing refraction),
    never NaN; and just below it both branches occur."""
    ior = 1.5
    z = np.array([0.0, 0.0, 1.0])
    sin_c = np.float32(1.0 / ior)
    wo = np.array([sin_c, 0.0, -np.sqrt(1.0 - np.float64(sin_c) ** 2)], np.float32)
    mat = material(DIELECTRIC, ks=1.0, ior=ior)
    s = sample(mat, z, wo, seed=2, count=4096)
    for k, v in s.items():
        assert np.all(np.isfinite(v)), k
    assert s["valid"].all()
    np.testing.assert_allclose(np.linalg.norm(s["wi"], axis=1), 1.0, atol=1e-5)
    F = float(B.fresnel_dielectric(jnp.float32(-wo[2]), jnp.float32(1.0 / ior)))
    assert F > 0.999, F


def test_ior_one_passes_straight_through():
    z = np.array([0.0, 0.0, 1.0])
    wo = direction(40.0, n=z)
    for mode in (B.RADIANCE, B.IMPORTANCE):
        s = sample(material(DIELECTRIC, ks=0.8, ior=1.0), z, wo, seed=4, count=1000, mode=mode)
        np.testing.assert_allclose(s["wi"], np.broadcast_to(-wo, (1000, 3)), atol=2e-6)
        np.testing.assert_allclose(s["weight"], 0.8, rtol=1e-6)
