"""Microfacet BSDFs (:mod:`jgi.physics.bsdf.microfacet`, ``roughconductor``, ``roughdielectric``,
``roughplastic``) and the conductor Fresnel term.

* The distributions: integral of D(m) cos(theta_m) = 1 and of the visible-normal density = 1
  (quadrature), and the normal samplers against their densities (chi-square in m-space).
* Every BSDF sampler against its ``evaluate`` pdf (chi-square over the sphere, failed samples
  as their own category) at alpha 0.001 (zoomed rings about the lobe axis), 0.1, 0.5 and 1, at
  normal and grazing incidence, anisotropic, GGX and Beckmann, the rough dielectric from outside
  and from inside (total internal reflection); the weight is f |cos| / pdf at the sampled
  direction in both transport modes.
* Mitsuba 3's own ``roughconductor``, ``roughdielectric`` and ``roughplastic`` (``scalar_rgb``):
  f |cos theta_i| and pdf at random directions on both sides (Mitsuba's ``eval`` includes the
  cosine). GGX agrees to float32 rounding; Beckmann's f within 0.7 % (Mitsuba approximates
  Smith's G1 within 0.35 %) and its pdf not at all (Mitsuba samples Beckmann's visible normals,
  jgi D(m) cos(theta_m)), so Beckmann pdfs are not compared.
* Closed forms: the rough dielectric of ior 1 is invisible; a rough conductor with F = 1 loses
  only what masking removes, more as alpha grows; reciprocity (reflection) and the generalized
  reciprocity of refraction; albedo <= 1; the conductor Fresnel against complex float64 optics;
  eta = k = 0 gives F = 1 exactly; no NaN or Inf (nor in gradients) for degenerate inputs.

All kinds go through one compiled function per transport mode (``KINDS`` static, the material a
traced array, sample counts padded to a few sizes).
"""

from __future__ import annotations

import re
from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jgi.analysis.chi2 import SphereDomain, assert_chi2, cell_integrals
from jgi.core.vec import V3
from jgi.physics import bsdf as B
from jgi.physics.bsdf import microfacet as mf
from jgi.scene import (
    BECKMANN,
    GGX,
    MIRROR,
    NAMED_METALS,
    PLASTIC,
    ROUGH_CONDUCTOR,
    ROUGH_DIELECTRIC,
    ROUGH_PLASTIC,
    SceneBuilder,
    SceneError,
)
from tests.support.bsdf_samplers import fresnel_reference
from tests.support.directions import NORMAL, direction, reflect_np

KINDS = (MIRROR, ROUGH_CONDUCTOR, ROUGH_DIELECTRIC, ROUGH_PLASTIC, PLASTIC)
N = 1 << 18
Z = np.array([0.0, 0.0, 1.0])


# --- materials: one builder row as a flat tuple of arrays (traced, so one compilation) ---------

def material(kind: str, **kw):
    """The builder's row for one material (cached: roughplastic tables take ~0.5 s)."""
    key = (kind,) + tuple(sorted((k, np.asarray(v).tobytes() if not isinstance(v, str) else v)
                                 for k, v in kw.items()))
    if key not in _MATERIALS:
        _MATERIALS[key] = _material(kind, **kw)
    return _MATERIALS[key]


_MATERIALS: dict = {}


def _material(kind: str, **kw):
    b = SceneBuilder()
    b.material("m", kind, **kw)
    b.camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0))
    m = b.build().materials
    f = lambda a: np.asarray(a)[0]  # noqa: E731
    v = lambda a: np.array([f(a.x), f(a.y), f(a.z)], np.float32)  # noqa: E731
    return (f(m.kind), v(m.diffuse), v(m.specular), f(m.exponent), f(m.ior), f(m.alpha_u),
            f(m.alpha_v), f(m.distribution), v(m.eta), v(m.k), np.asarray(m.transmittance)[0],
            f(m.internal_reflectance), f(m.nonlinear))


def _params(mat, shape) -> B.MaterialParams:
    kind, kd, ks, ex, ior, au, av, dist, eta, k, table, ri, nl = mat
    b = lambda x: jnp.broadcast_to(x, shape)  # noqa: E731
    b3 = lambda c: V3(b(c[0]), b(c[1]), b(c[2]))  # noqa: E731
    return B.MaterialParams(b(kind), b3(kd), b3(ks), b(ex), b(ior), b(au), b(av), b(dist),
                            b3(eta), b3(k), jnp.zeros(shape, jnp.int32), table[None, :], b(ri),
                            b(nl))


def _v3(a, shape) -> V3:
    a = jnp.broadcast_to(jnp.asarray(a, jnp.float32), shape + (3,))
    return V3(a[..., 0], a[..., 1], a[..., 2])


CHUNK = 1 << 14   # every evaluation runs in chunks of this size: one compilation per mode


@partial(jax.jit, static_argnames="mode")
def _sample(mat, n, wo, u, mode=B.RADIANCE):
    shape = u.shape[1:]
    mp, n, wo = _params(mat, shape), _v3(n, shape), _v3(wo, shape)
    s = B.sample(KINDS, mp, n, wo, u[0], u[1], u[2], mode)
    f, pdf = B.evaluate(KINDS, mp, n, wo, s.wi, mode)
    return dict(wi=s.wi.stack(), weight=s.weight.stack(), pdf=s.pdf, delta=s.delta,
                valid=s.valid, f=f.stack(), eval_pdf=pdf)


@partial(jax.jit, static_argnames="mode")
def _evaluate(mat, n, wo, wi, mode=B.RADIANCE):
    shape = wi.shape[:-1]
    f, pdf = B.evaluate(KINDS, _params(mat, shape), V3.of(n), V3.of(wo), V3.of(wi), mode)
    return f.stack(), pdf


def chunked(fn, *arrays):
    """fn over rows of equally long [M, ...] arrays, in padded chunks of CHUNK rows."""
    m = len(arrays[0])
    outs = []
    for i in range(0, m, CHUNK):
        part = [a[i:i + CHUNK] for a in arrays]
        k = len(part[0])
        part = [np.concatenate([p, np.repeat(p[-1:], CHUNK - k, axis=0)]) for p in part]
        out = fn(*part)
        outs.append(jax.tree_util.tree_map(lambda x: np.asarray(x)[:k], out))
    return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs), *outs)


def sample(mat, n, wo, seed, count=N, mode=B.RADIANCE):
    """``count`` samples, in batches of CHUNK (one compilation per mode)."""
    u = np.random.default_rng(seed).random((count, 3), dtype=np.float32)
    return chunked(lambda x: _sample(mat, np.float32(n), np.float32(wo), x.T, mode), u)


def evaluate(mat, n, wo, wi, mode=B.RADIANCE):
    """(f, pdf) at directions wi [M, 3]; n and wo one direction or one per row."""
    wi = np.asarray(wi, np.float32).reshape(-1, 3)
    n = np.broadcast_to(np.asarray(n, np.float32), wi.shape)
    wo = np.broadcast_to(np.asarray(wo, np.float32), wi.shape)
    return chunked(lambda a, b, c: _evaluate(mat, a, b, c, mode), n, wo, wi)


def refract_np(w, n, eta):
    """Snell's law for w on n's side, eta = eta_t / eta_i (None under total reflection)."""
    c = np.dot(w, n)
    c2t = 1.0 - (1.0 - c * c) / (eta * eta)
    if c2t <= 0:
        return None
    return -w / eta + n * (c / eta - np.sqrt(c2t))


def rings(axis, alpha):
    """Rings about ``axis``, geometric in a = 1 - cos from well inside a lobe of width alpha to
    the whole sphere (so no sample falls outside the grid)."""
    a_min = min(1e-3, 0.05 * alpha * alpha)
    return SphereDomain(axis=axis, a_edges=np.concatenate([[0.0], np.geomspace(a_min, 2.0, 40)]))


# --- the distributions ---------------------------------------------------------------------------

@jax.jit
def _ndf_density(dist, au, av, wo, m):
    """(D(m) cos(theta_m), the visible-normal density of wo) at local normals m."""
    mm, w = V3.of(m), _v3(wo, m.shape[:-1])
    return mf.pdf_dcos(dist, mm, au, av), mf.pdf_vndf(dist, w, mm, au, av)


@jax.jit
def _sample_normals(dist, au, av, wo, u):
    w = _v3(wo, u.shape[1:])
    return mf.sample_normal(dist, w, au, av, u[0], u[1]).stack()


DISTS = [(GGX, 0.001, 0.001), (GGX, 0.1, 0.1), (GGX, 1.0, 1.0), (GGX, 0.05, 0.4),
         (BECKMANN, 0.001, 0.001), (BECKMANN, 0.3, 0.3), (BECKMANN, 1.0, 1.0),
         (BECKMANN, 0.4, 0.05)]


def _density(dist, au, av, wo, which):
    def density(m):
        out = chunked(lambda x: _ndf_density(np.int32(dist), np.float32(au), np.float32(av),
                                             np.float32(wo), x), np.float32(m))
        return np.float64(out[0 if which == "dcos" else 1])
    return density


@pytest.mark.parametrize("dist,au,av", DISTS)
def test_distributions_are_normalised(dist, au, av):
    """Integral of D(m) cos(theta_m) and of the visible-normal density D_wo(m) over the
    hemisphere = 1 (adaptive Gauss-Legendre on rings about the normal). The second holds only
    with the exact Smith Lambda."""
    dom = rings(Z, min(au, av))
    total = cell_integrals(_density(dist, au, av, Z, "dcos"), dom).sum()
    assert abs(total - 1.0) < 2e-4, total
    for theta in (0.0, 45.0, 85.0):
        wo = direction(theta, 20.0, Z)
        total = cell_integrals(_density(dist, au, av, wo, "vndf"), dom).sum()
        assert abs(total - 1.0) < 5e-4, (theta, total)


@pytest.mark.parametrize("dist,au,av", DISTS[1:4] + DISTS[5:])
def test_normal_samplers_follow_their_densities(dist, au, av):
    """sample_normal (GGX: visible normals of wo; Beckmann: D cos) against pdf_normal."""
    for theta, seed in ((10.0, 1), (80.0, 2)):
        wo = direction(theta, 20.0, Z)
        u = np.random.default_rng(seed).random((2, N), dtype=np.float32)
        m = np.asarray(_sample_normals(np.int32(dist), np.float32(au), np.float32(av),
                                       np.float32(wo), u))
        which = "vndf" if dist == GGX else "dcos"
        r = assert_chi2(m, _density(dist, au, av, wo, which), rings(Z, min(au, av)),
                        f"normals {dist} {au} {av} theta={theta}", n_total=N)
        print(f"p = {r.p_value:.3g}")


# --- sampling matches evaluation ----------------------------------------------------------------

def _check_sampler(mat, n, wo, seed, lobes, alpha, label, modes=(B.RADIANCE,), eta=None):
    """Chi-square of the valid samples against evaluate's pdf, one side of the surface at a
    time (``lobes``: (axis, side) with side +1 for wo's side, -1 for the other): the samples on
    that side in rings about the lobe's axis, against the pdf restricted to that side, with
    every other sample as "no sample" (so a sharp lobe on the far side, which a grid about
    this axis cannot resolve, needs no quadrature here). The side integrals add up to the
    fraction of valid samples; weight = f |cos| / pdf, pdf = evaluate's. ``eta``: the
    dielectric's eta_t / eta_i seen from wo."""
    out = {mode: sample(mat, n, wo, seed=seed, mode=mode) for mode in modes}
    s = out[modes[0]]
    v = s["valid"]
    nf = np.asarray(n, float) * np.sign(np.dot(n, wo))
    integral = 0.0
    for axis, side in lobes:
        here = v & (side * (s["wi"] @ nf) > 0)

        def pdf(w):
            return evaluate(mat, n, wo, w)[1] * (side * (np.asarray(w) @ nf) > 0)

        r = assert_chi2(s["wi"][here], pdf, rings(axis, alpha), label, n_total=N)
        print(f"{label} side {side}: p = {r.p_value:.3g}, fraction {here.mean():.4f}")
        integral += r.pdf_integral
    frac = v.mean()
    se = np.sqrt(max(frac * (1 - frac), 1.0 / N) / N)
    assert abs(integral - frac) < 5 * se + 2e-4, (integral, frac, se)
    for mode, s in out.items():
        v = s["valid"]
        assert np.array_equal(v, out[modes[0]]["valid"])
        assert not s["delta"].any()
        assert np.all(np.isfinite(s["weight"])) and np.all(s["weight"][~v] == 0)
        # pdf = evaluate's pdf, to float32 rounding (sample and evaluate are separate XLA
        # fusions), amplified by the sharpest lobes (rounding of the half-vector against
        # alpha); and inside a dielectric, F is a square root of the distance to the critical
        # angle: there (wo.m within 0.01 of its cosine) the relative error is unbounded
        p, q = s["pdf"][v], s["eval_pdf"][v]
        off = ~np.isclose(p, q, rtol=2e-5 + 1e-6 / alpha, atol=0)
        if eta is not None and eta < 1:
            wi = s["wi"][v]
            refl = (wi @ nf) > 0
            h = wo + wi * np.where(refl, 1.0, eta)[:, None]
            h *= (np.sign(h @ nf) / np.linalg.norm(h, axis=1))[:, None]
            near = np.abs(h @ wo - np.sqrt(1.0 - eta * eta)) < 0.01
            assert not (off & ~near).any(), (p[off & ~near], q[off & ~near])
            off = off & ~near
        assert not off.any(), (p[off], q[off])
        np.testing.assert_allclose(p, q, rtol=2e-3 + 1e-6 / alpha)
        cos = np.abs(s["wi"][v] @ nf)
        f_over_pdf = s["f"][v] / s["eval_pdf"][v][:, None]
        expect = f_over_pdf * cos[:, None]
        # cos is rounded to ~1e-7 absolute in float32: that sets the tolerance at grazing wi
        err = np.abs(s["weight"][v] - expect)
        assert np.all(err <= (1e-5 + 1e-6 / alpha) * expect + 3e-7 * f_over_pdf), err.max()
    return out


CONDUCTOR_CASES = [  # (distribution, alpha or (alpha_u, alpha_v), theta_o, wo behind n)
    (d, a, th, False) for d in ("ggx", "beckmann") for a in (0.001, 0.1, 0.5, 1.0)
    for th in (0.0, 87.0)] + [(d, (0.05, 0.4), th, False) for d in ("ggx", "beckmann")
                              for th in (30.0, 85.0)] + [
    (d, a, 0.0, True) for d in ("ggx", "beckmann") for a in (0.001, 0.5)]


def _rough(alpha):
    return dict(alpha=alpha) if np.isscalar(alpha) else dict(alpha_u=alpha[0], alpha_v=alpha[1])


@pytest.mark.parametrize("case", range(len(CONDUCTOR_CASES)),
                         ids=[f"{c[0]}-{c[1]}-{c[2]:g}deg{'-back' if c[3] else ''}"
                              for c in CONDUCTOR_CASES])
def test_roughconductor_sampling_matches_evaluate(case):
    """Two-sided: ``back`` puts wo behind the geometric normal."""
    dist, alpha, theta, backside = CONDUCTOR_CASES[case]
    mat = material("roughconductor", metal="Cu", distribution=dist, **_rough(alpha))
    n = -NORMAL if backside else NORMAL
    wo = direction(theta)
    _check_sampler(mat, n, wo, case, [(reflect_np(wo, NORMAL), 1)], np.min(alpha),
                   f"roughconductor {dist} {alpha} {theta}")


DIELECTRIC_CASES = [  # (distribution, alpha, theta_o, outside)
    (d, a, th, out) for d in ("ggx", "beckmann")
    for a, th, out in [(0.001, 30.0, True), (0.001, 30.0, False), (0.1, 0.0, True),
                       (0.1, 85.0, True), (0.1, 30.0, False), (0.1, 60.0, False),
                       (0.5, 45.0, True), (0.5, 60.0, False), (1.0, 20.0, True),
                       ((0.05, 0.4), 40.0, True), ((0.05, 0.4), 50.0, False)]]


@pytest.mark.parametrize("case", range(len(DIELECTRIC_CASES)),
                         ids=[f"{c[0]}-{c[1]}-{c[2]:g}deg-{'out' if c[3] else 'in'}"
                              for c in DIELECTRIC_CASES])
def test_roughdielectric_sampling_matches_evaluate(case):
    """Both lobes, from outside and from inside (60 degrees inside is past the critical angle
    41.8: total internal reflection off most microfacets); rings about the mirror and about the
    refracted direction; weights in both transport modes."""
    dist, alpha, theta, outside = DIELECTRIC_CASES[case]
    ior = 1.5
    mat = material("roughdielectric", ior=ior, distribution=dist, **_rough(alpha))
    wo = direction(theta, n=NORMAL if outside else -NORMAL)
    nside = NORMAL if outside else -NORMAL
    t = refract_np(wo, nside, ior if outside else 1 / ior)
    lobes = [(reflect_np(wo, nside), 1), (-nside if t is None else t, -1)]
    out = _check_sampler(mat, NORMAL, wo, 100 + case, lobes, np.min(alpha),
                         f"roughdielectric {dist} {alpha} {theta} {'out' if outside else 'in'}",
                         modes=(B.RADIANCE, B.IMPORTANCE), eta=ior if outside else 1 / ior)
    # the transport modes differ by eta^2 on transmission only
    r, i = out[B.RADIANCE], out[B.IMPORTANCE]
    trans = r["valid"] & ((r["wi"] @ nside) < 0)
    eta = ior if outside else 1 / ior
    np.testing.assert_allclose(i["weight"][trans], r["weight"][trans] * eta * eta, rtol=1e-5)
    refl = r["valid"] & ~trans
    np.testing.assert_array_equal(i["weight"][refl], r["weight"][refl])
    if not outside and theta == 60.0 and alpha == 0.001:
        assert not trans.any()


PLASTIC_CASES = [(d, a, th) for d in ("ggx", "beckmann") for a in (0.001, 0.1, 0.5)
                 for th in (0.0, 70.0)] + [("ggx", 1.0, 88.0)]


@pytest.mark.parametrize("case", range(len(PLASTIC_CASES)),
                         ids=[f"{c[0]}-{c[1]}-{c[2]:g}deg" for c in PLASTIC_CASES])
def test_roughplastic_sampling_matches_evaluate(case):
    dist, alpha, theta = PLASTIC_CASES[case]
    mat = material("roughplastic", diffuse=(0.2, 0.5, 0.7), specular=0.8, alpha=alpha,
                   distribution=dist, nonlinear=case % 2 == 1)
    wo = direction(theta)
    _check_sampler(mat, NORMAL, wo, 200 + case, [(reflect_np(wo, NORMAL), 1)], alpha,
                   f"roughplastic {dist} {alpha} {theta}")


SMOOTH_PLASTIC_CASES = [  # (theta_o, diffuse, specular, int_ior, nonlinear)
    (0.0, (0.2, 0.5, 0.7), 1.0, None, False), (0.0, (0.9, 0.6, 0.3), 0.5, 1.9, True),
    (75.0, (0.2, 0.5, 0.7), 1.0, None, True), (88.0, (0.5, 0.5, 0.5), 0.8, 1.3, False)]


@pytest.mark.parametrize("case", range(len(SMOOTH_PLASTIC_CASES)),
                         ids=[f"{c[0]:g}deg-{i}" for i, c in enumerate(SMOOTH_PLASTIC_CASES)])
def test_plastic_sampling_matches_evaluate(case):
    """Smooth plastic: the base's samples (non-Dirac) against evaluate's pdf over the
    hemisphere, with the Dirac samples as the "no sample" category, so the chi-square also tests
    the lobe choice: evaluate's pdf integrates to 1 - p (p the coating's probability). The
    Dirac samples are the mirror direction, with weight k_s F / p (Mitsuba's); the base's weight
    is f |cos| / pdf; both transport modes alike (f is symmetric)."""
    theta, kd, ks, int_ior, nonlinear = SMOOTH_PLASTIC_CASES[case]
    kw = {} if int_ior is None else dict(int_ior=int_ior)
    mat = material("plastic", diffuse=kd, specular=ks, nonlinear=nonlinear, **kw)
    wo = direction(theta)
    out = {mode: sample(mat, NORMAL, wo, seed=300 + case, mode=mode)
           for mode in (B.RADIANCE, B.IMPORTANCE)}
    s = out[B.RADIANCE]
    for key in ("wi", "weight", "pdf", "delta", "valid"):
        np.testing.assert_array_equal(out[B.IMPORTANCE][key], s[key])
    d, v = s["delta"], s["valid"]
    base = v & ~d

    def pdf(w):
        return evaluate(mat, NORMAL, wo, w)[1]

    r = assert_chi2(s["wi"][base], pdf, rings(NORMAL, 1.0), f"plastic {theta}", n_total=N)
    # the coating's probability, as evaluate's pdf implies it and as Mitsuba defines it
    eta = (1.49 if int_ior is None else int_ior) / 1.000277
    cos_o = float(wo @ NORMAL)
    F = float(fresnel_reference(cos_o, eta))
    w = np.mean(ks) / (np.mean(kd) + np.mean(ks))
    p = F * w / (F * w + (1 - F) * (1 - w))
    se = np.sqrt(p * (1 - p) / N)
    print(f"plastic {theta}: p = {r.p_value:.3g}, Dirac fraction {d.mean():.5f} "
          f"(expected {p:.5f}, z = {(d.mean() - p) / se:.2f}), "
          f"1 - base mass {1 - r.pdf_integral:.5f}")
    assert abs(d.mean() - p) < 5 * se
    assert abs(r.pdf_integral - (1 - p)) < 1e-4
    np.testing.assert_allclose(s["wi"][d], np.broadcast_to(reflect_np(wo, NORMAL), (d.sum(), 3)),
                               atol=1e-6)
    np.testing.assert_allclose(s["weight"][d], np.broadcast_to(np.float32(ks) * F / p,
                                                               (d.sum(), 3)), rtol=1e-5)
    assert np.all(s["pdf"][d] == 0) and np.all(s["eval_pdf"][d] > 0)   # base's pdf there
    np.testing.assert_allclose(s["pdf"][base], s["eval_pdf"][base], rtol=1e-6)
    cos = s["wi"][base] @ NORMAL
    np.testing.assert_allclose(s["weight"][base],
                               s["f"][base] * (cos / s["eval_pdf"][base])[:, None], rtol=5e-5)


# --- Mitsuba 3's definitions ------------------------------------------------------------------

def _mitsuba():
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    return mi


def _mitsuba_eval(mi, spec, wo, wi, mode):
    bsdf = mi.load_dict(spec)
    ctx = mi.BSDFContext(mi.TransportMode.Radiance if mode == B.RADIANCE
                         else mi.TransportMode.Importance)
    f, p = [], []
    for a, b in zip(wo, wi):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*map(float, a))
        si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        d = mi.Vector3f(*map(float, b))
        v = bsdf.eval(ctx, si, d)
        f.append([v[0], v[1], v[2]])
        p.append(bsdf.pdf(ctx, si, d))
    return np.array(f), np.array(p)


def _random_dirs(rng, count, sign):
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = sign * np.maximum(np.abs(v[:, 2]), 0.02)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v.astype(np.float32).astype(np.float64)


MITSUBA_CASES = [  # (label, jgi kind and keywords, Mitsuba dict, sides of wo)
    ("roughconductor Au", "roughconductor", dict(metal="Au", alpha=0.3),
     {"type": "roughconductor", "material": "Au", "alpha": 0.3}, (1,)),
    ("roughconductor aniso", "roughconductor",
     dict(eta=(1.5, 0.2, 0.9), k=(3.0, 2.0, 1.0), alpha_u=0.1, alpha_v=0.4),
     {"type": "roughconductor", "eta": (1.5, 0.2, 0.9), "k": (3.0, 2.0, 1.0),
      "alpha_u": 0.1, "alpha_v": 0.4}, (1,)),
    ("roughdielectric", "roughdielectric", dict(alpha=0.3, int_ior=1.5, ext_ior=1.0),
     {"type": "roughdielectric", "alpha": 0.3, "int_ior": 1.5, "ext_ior": 1.0}, (1, -1)),
    ("roughdielectric aniso", "roughdielectric", dict(alpha_u=0.05, alpha_v=0.3),
     {"type": "roughdielectric", "alpha_u": 0.05, "alpha_v": 0.3, "int_ior": 1.5,
      "ext_ior": 1.0}, (1, -1)),
    ("roughplastic", "roughplastic", dict(diffuse=(0.2, 0.5, 0.9), alpha=0.2),
     {"type": "roughplastic", "alpha": 0.2,
      "diffuse_reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.9]}}, (1,)),
    ("roughplastic white", "roughplastic", dict(diffuse=1.0, alpha=0.4),
     {"type": "roughplastic", "alpha": 0.4,
      "diffuse_reflectance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}, (1,)),
    ("roughplastic nonlinear", "roughplastic",
     dict(diffuse=(0.9, 0.5, 0.1), alpha=0.05, nonlinear=True, int_ior=1.7),
     {"type": "roughplastic", "alpha": 0.05, "nonlinear": True, "int_ior": 1.7,
      "diffuse_reflectance": {"type": "rgb", "value": [0.9, 0.5, 0.1]}}, (1,)),
]
MITSUBA_ERRORS: dict = {}   # (label, dist) -> (max relative error of f, of pdf), for reports


PLASTIC_MITSUBA = [  # (jgi keywords, Mitsuba dict)
    (dict(diffuse=(0.2, 0.5, 0.9)),
     {"type": "plastic", "diffuse_reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.9]}}),
    (dict(diffuse=(0.9, 0.5, 0.1), specular=(0.8, 0.9, 1.0), int_ior=1.7, ext_ior=1.1,
          nonlinear=True),
     {"type": "plastic", "int_ior": 1.7, "ext_ior": 1.1, "nonlinear": True,
      "diffuse_reflectance": {"type": "rgb", "value": [0.9, 0.5, 0.1]},
      "specular_reflectance": {"type": "rgb", "value": [0.8, 0.9, 1.0]}}),
]


@pytest.mark.parametrize("case", range(len(PLASTIC_MITSUBA)), ids=["default", "nonlinear"])
def test_plastic_against_mitsuba(case):
    """Smooth plastic against Mitsuba 3's ``plastic`` (scalar_rgb), n = +z: eval (f |cos|, the
    base alone) and pdf at random directions on both sides, in both transport modes; and
    ``sample`` with the same three random numbers: the same lobe (Dirac or not), direction and
    weight (jgi's cosine warp is Mitsuba's). Measured: agreement to 1e-6 relative."""
    mi = _mitsuba()
    kw, spec = PLASTIC_MITSUBA[case]
    mat = material("plastic", **kw)
    bsdf = mi.load_dict(spec)
    rng = np.random.default_rng(40 + case)
    for j, wo in enumerate(_random_dirs(rng, 4, 1)):
        wi = np.concatenate([_random_dirs(rng, 16, 1), _random_dirs(rng, 4, -1)])
        wo_ = np.broadcast_to(wo, wi.shape)
        for mode in (B.RADIANCE, B.IMPORTANCE):
            f_mi, p_mi = _mitsuba_eval(mi, spec, wo_, wi, mode)
            f, p = evaluate(mat, Z, wo_, wi, mode)
            np.testing.assert_allclose(f * np.abs(wi[:, 2:3]), f_mi, rtol=2e-5, atol=1e-7)
            np.testing.assert_allclose(p, p_mi, rtol=2e-5, atol=1e-7)
        s = sample(mat, Z, wo, seed=j, count=CHUNK)   # its random numbers: u below
        u = np.random.default_rng(j).random((CHUNK, 3), dtype=np.float32)[:64]
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*map(float, wo))
        si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        for k in range(64):
            bs, value = bsdf.sample(mi.BSDFContext(), si, float(u[k, 0]),
                                    mi.Point2f(float(u[k, 1]), float(u[k, 2])))
            delta = bool(mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta))
            assert s["delta"][k] == delta, (k, u[k])
            np.testing.assert_allclose(s["wi"][k], [bs.wo[0], bs.wo[1], bs.wo[2]], atol=2e-6)
            np.testing.assert_allclose(s["weight"][k], [value[0], value[1], value[2]],
                                       rtol=2e-5)


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("case", range(len(MITSUBA_CASES)), ids=[c[0] for c in MITSUBA_CASES])
def test_against_mitsuba(case, dist):
    """f |cos theta_i| (Mitsuba's eval) and pdf, n = +z (where jgi's shading frame is the
    identity), in both transport modes, at directions wi drawn from jgi's sampler (where the
    lobes are) and uniformly (both hemispheres). GGX: the same numbers to float32 rounding
    (measured max relative error 3e-5 over all cases, both sides; tolerance 2e-5 for wo
    outside, 2e-4 for wo inside the dielectric, whose refraction is ill-conditioned near the
    critical angle). Beckmann: f within 0.6 % (Mitsuba's rational G1, 0.35 % per factor);
    pdfs differ by design (see the module docstring)."""
    mi = _mitsuba()
    label, kind, kw, spec, sides = MITSUBA_CASES[case]
    mat = material(kind, distribution=dist, **kw)
    spec = {k: mi.ScalarColor3f(*v) if isinstance(v, tuple) else v for k, v in spec.items()}
    spec["distribution"] = dist
    rng = np.random.default_rng(case)
    err_f = err_p = 0.0
    for so in sides:
        for j, wo in enumerate(_random_dirs(rng, 4, so)):
            s = sample(mat, Z, wo, seed=j, count=CHUNK)
            wi = np.concatenate([s["wi"][s["valid"]][:24], _random_dirs(rng, 8, 1),
                                 _random_dirs(rng, 8, -1)]).astype(np.float64)
            wo_ = np.broadcast_to(wo, wi.shape)
            for mode in (B.RADIANCE, B.IMPORTANCE):
                f_mi, p_mi = _mitsuba_eval(mi, spec, wo_, wi, mode)
                f, p = evaluate(mat, Z, wo_, wi, mode)
                f = f * np.abs(wi[:, 2:3])
                rtol = (2e-4 if so < 0 else 2e-5) if dist == "ggx" else 7e-3
                msg = f"{label} {dist} wo {wo} mode {mode}"
                np.testing.assert_allclose(f, f_mi, rtol=rtol, atol=1e-6 * f_mi.max(),
                                           err_msg=msg)
                big = f_mi > 1e-6 * f_mi.max()
                err_f = max(err_f, float(np.max(np.abs(f - f_mi)[big] / f_mi[big])))
                if dist == "ggx":
                    np.testing.assert_allclose(p, p_mi, rtol=rtol, atol=1e-6 * p_mi.max(),
                                               err_msg=msg)
                    big = p_mi > 1e-6 * p_mi.max()
                    err_p = max(err_p, float(np.max(np.abs(p - p_mi)[big] / p_mi[big])))
    MITSUBA_ERRORS[label, dist] = (err_f, err_p)
    print(f"{label} {dist}: max relative error f {err_f:.2e}, pdf {err_p:.2e}")


def test_named_metals_are_mitsubas():
    """The table holds Mitsuba's RGB eta and k (spot checks against Mitsuba itself) and its
    default conductor, "none", is eta 0, k 1."""
    mi = _mitsuba()
    assert NAMED_METALS["none"] == ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    for name in ("Au", "Ag", "Cu", "Al", "Cr", "W", "TiN"):
        p = mi.traverse(mi.load_dict({"type": "conductor", "material": name}))
        np.testing.assert_allclose(NAMED_METALS[name][0], list(p["eta.value"]), rtol=1e-5)
        np.testing.assert_allclose(NAMED_METALS[name][1], list(p["k.value"]), rtol=1e-5)
    p = mi.traverse(mi.load_dict({"type": "conductor"}))
    assert float(p["eta.value"]) == 0.0 and float(p["k.value"]) == 1.0


# --- closed forms ---------------------------------------------------------------------------------

def test_rough_dielectric_of_ior_one_is_invisible():
    wo = direction(50.0, n=Z)
    for outside in (True, False):
        n = Z if outside else -Z
        for mode in (B.RADIANCE, B.IMPORTANCE):
            mat = material("roughdielectric", ior=1.0, alpha=0.5, specular=0.9)
            s = sample(mat, n, wo, seed=3, count=1000, mode=mode)
            assert s["valid"].all() and s["delta"].all() and np.all(s["pdf"] == 0)
            np.testing.assert_array_equal(s["wi"], np.broadcast_to(-np.float32(wo), (1000, 3)))
            np.testing.assert_array_equal(s["weight"], np.float32(0.9))
            f, pdf = evaluate(mat, n, wo, np.stack([-wo, reflect_np(wo, Z), -Z]), mode)
            assert np.all(f == 0) and np.all(pdf == 0)


def albedo(mat, wo, seed, n=NORMAL, mode=B.RADIANCE):
    """Monte Carlo albedo E[f |cos| / pdf] under BSDF sampling (N samples) and its standard
    error."""
    w = np.float64(sample(mat, n, wo, seed, mode=mode)["weight"])
    return w.mean(0), w.std(0) / np.sqrt(len(w))


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_white_rough_conductor_loses_only_to_masking(dist):
    """F = 1 (eta = k = 0): albedo = E[G1(wi)] for visible-normal sampling, <= 1, 1 at tiny
    alpha, falling as alpha grows (more masking); at 0 degrees and at 70."""
    for theta in (0.0, 70.0):
        prev = 1.0 + 1e-6
        for i, a in enumerate((0.001, 0.1, 0.3, 0.6, 1.0)):
            mat = material("roughconductor", eta=0.0, k=0.0, alpha=a, distribution=dist)
            m, se = albedo(mat, direction(theta), seed=i)
            m, se = float(m[0]), float(se[0])
            assert m <= 1.0 + 5 * se + 1e-6, (a, m, se)
            assert m <= prev + 5 * se + 1e-6, (a, m, prev)
            if a == 0.001:
                assert m > 0.999, m
            prev = m
        assert prev < 0.97 if theta == 70.0 else prev < 0.995, prev


@settings(max_examples=12, deadline=None, derandomize=True)
@given(kind=st.sampled_from(["roughconductor", "roughdielectric", "roughplastic"]),
       dist=st.sampled_from(["ggx", "beckmann"]), alpha=st.floats(0.001, 1.0),
       aniso=st.floats(0.2, 1.0), theta=st.floats(0.0, 89.0), inside=st.booleans(),
       seed=st.integers(0, 2 ** 16))
def test_energy_conservation(kind, dist, alpha, aniso, theta, inside, seed):
    """Albedo (importance transport for the dielectric: radiance mode scales by 1 / eta^2)
    <= 1 within 5 standard errors."""
    kw = dict(distribution=dist)
    if kind == "roughplastic":
        kw.update(alpha=alpha, diffuse=1.0)
    else:
        kw.update(alpha_u=alpha, alpha_v=alpha * aniso)
    if kind == "roughconductor":
        kw.update(eta=0.0, k=0.0)
    mat = material(kind, **kw)
    n = -NORMAL if (inside and kind == "roughdielectric") else NORMAL
    m, se = albedo(mat, direction(theta), seed, n=n, mode=B.IMPORTANCE)
    assert np.all(m <= 1.0 + 5 * se + 1e-5), (m, se)


def _unit(rng, count, sign=1.0):
    th = np.radians(89.0) * rng.random(count)
    ph = 360.0 * rng.random(count)
    return np.stack([direction(np.degrees(t), p) for t, p in zip(th, ph)]) * sign


@pytest.mark.parametrize("kind,dist", [(k, d) for k in ("roughconductor", "roughplastic",
                                                        "roughdielectric")
                                       for d in ("ggx", "beckmann")])
def test_reciprocity(kind, dist):
    """Reflection: f(wo, wi) = f(wi, wo). Refraction, radiance transport (Veach 1997, 5.2):
    f(wo, wi) / eta_wo^2 = f(wi, wo) / eta_wi^2, indices on each direction's side; and the
    importance-transport BTDF is the radiance BTDF with the arguments swapped (the adjoint)."""
    kw = dict(alpha=0.3) if kind == "roughplastic" else dict(alpha_u=0.2, alpha_v=0.5)
    mat = material(kind, distribution=dist, diffuse=0.5, **kw) if kind == "roughplastic" \
        else material(kind, distribution=dist, **kw)
    rng = np.random.default_rng(7)
    wo = _unit(rng, 64)
    for sign in ((1.0, -1.0) if kind == "roughdielectric" else (1.0,)):
        wi = _unit(rng, 64, sign)
        f_oi, f_io = evaluate(mat, NORMAL, wo, wi)[0], evaluate(mat, NORMAL, wi, wo)[0]
        scale = 1.0 if sign > 0 else 1.5 ** 2   # wo outside (index 1), wi inside (1.5)
        peak = max(f_oi.max(), 1e-30)
        np.testing.assert_allclose(f_oi * scale, f_io, rtol=1e-4, atol=1e-6 * peak)
        if sign < 0:
            f_imp = evaluate(mat, NORMAL, wi, wo, B.IMPORTANCE)[0]
            np.testing.assert_allclose(f_imp, f_oi, rtol=1e-4, atol=1e-6 * peak)
        assert (f_oi > 0).any()


# --- Fresnel ----------------------------------------------------------------------------------

def conductor_reference(cos_i, eta, k):
    """Unpolarised reflectance of a conductor n = eta + i k from complex optics, float64."""
    n = eta + 1j * k
    cos_i = np.asarray(cos_i, np.float64)
    sin2 = 1.0 - cos_i ** 2
    cos_t = np.sqrt(1.0 - sin2 / (n * n) + 0j)
    rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def test_conductor_fresnel_against_reference():
    """The float32 formula against complex optics at the float32 inputs it receives (near a
    critical angle, k = 0 and eta < 1, F is a square root of the distance to it, so the input's
    own rounding would dominate)."""
    cos = np.linspace(0.0, 1.0, 1001).astype(np.float32)
    for eta, k in [(0.143, 3.98), (1.66, 9.22), (0.2, 0.0), (2.4, 0.0), (0.5, 0.1),
                   (4.37, 5.2), (1.0, 1.0), (0.06, 2.1)]:
        got = np.asarray(B.fresnel_conductor(jnp.float32(cos), jnp.float32(eta),
                                             jnp.float32(k)))
        ref = conductor_reference(np.float64(cos), np.float32(eta), np.float32(k))
        np.testing.assert_allclose(got, ref, atol=3e-6, err_msg=f"eta {eta} k {k}")
    # eta = 0 reflects everything, exactly (the mirror kind's eta = k = 0 keeps weight k_s)
    for k in (0.0, 1.0, 3.0):
        got = np.asarray(B.fresnel_conductor(jnp.float32(cos), jnp.float32(0.0),
                                             jnp.float32(k)))
        assert np.all(got == 1.0), k


def test_mirror_and_conductor():
    """The mirror (and the conductor "none") weighs exactly k_s; a named metal k_s F(cos_o)."""
    ks = np.float32([0.9, 0.8, 0.7])
    for kind, kw in (("mirror", {}), ("conductor", {}), ("conductor", dict(metal="none"))):
        s = sample(material(kind, specular=ks, **kw), NORMAL, direction(60.0), 1, count=64)
        np.testing.assert_array_equal(s["weight"], np.broadcast_to(ks, (64, 3)))
        assert s["delta"].all()
    for theta in (0.0, 60.0, 88.0):
        s = sample(material("conductor", metal="Au", specular=ks), NORMAL, direction(theta), 1,
                   count=64)
        eta, k = NAMED_METALS["Au"]
        ref = [conductor_reference(np.cos(np.radians(theta)), np.float32(e), np.float32(kk))
               for e, kk in zip(eta, k)]
        np.testing.assert_allclose(s["weight"][0], ks * np.array(ref), rtol=2e-5)
        np.testing.assert_allclose(s["wi"][0], reflect_np(direction(theta), NORMAL), atol=2e-6)


# --- degenerate inputs and gradients --------------------------------------------------------

DEGENERATE = [("roughconductor", dict(alpha=1e-4)), ("roughconductor", dict(alpha=1e-4,
                                                                            distribution="beckmann")),
              ("roughconductor", dict(alpha_u=1e-4, alpha_v=1.0, eta=0.0, k=0.0)),
              ("roughdielectric", dict(alpha=1e-4)),
              ("roughdielectric", dict(alpha=1e-4, distribution="beckmann", ior=1.0001)),
              ("roughdielectric", dict(alpha=0.3, ior=1.0)),
              ("roughdielectric", dict(alpha=1.0, ior=1.5, distribution="beckmann")),
              ("roughplastic", dict(alpha=1e-4, diffuse=1.0)),
              ("roughplastic", dict(alpha=1.0, distribution="beckmann", nonlinear=True,
                                    diffuse=1.0))]


@pytest.mark.parametrize("mi", range(len(DEGENERATE)))
def test_degenerate_inputs_are_finite(mi):
    kind, kw = DEGENERATE[mi]
    mat = material(kind, **kw)
    eps = 1e-7
    cases = [(Z, np.array([1.0, 0.0, 0.0])), (Z, np.array([np.sqrt(1 - eps ** 2), 0.0, eps])),
             (Z, np.array([np.sqrt(1 - eps ** 2), 0.0, -eps])), (Z, Z), (-Z, Z),
             (NORMAL, direction(89.99)), (NORMAL, direction(0.0))]
    for n, wo in cases:
        for mode in (B.RADIANCE, B.IMPORTANCE):
            s = sample(mat, n, wo, seed=1, count=4096, mode=mode)
            for key, v in s.items():
                assert np.all(np.isfinite(v)), (key, n, wo)
            assert np.all(s["weight"][~s["valid"]] == 0)
            # wi at the degenerate configurations: -wo (the half-vector wo + eta wi = 0 for
            # eta = 1), the mirror direction, grazing, and the normal
            wis = np.stack([-wo, reflect_np(wo, n), np.array([1.0, 0.0, 0.0]), n, -n,
                            np.array([0.0, np.sqrt(1 - eps ** 2), eps])])
            f, pdf = evaluate(mat, n, wo, wis, mode)
            assert np.all(np.isfinite(f)) and np.all(np.isfinite(pdf)), (n, wo)


def _with_alpha(mat, alpha):
    m = list(mat)
    m[5] = m[6] = alpha
    return tuple(m)


@jax.jit
def _grad_evaluate(mat, n, wo, wi):
    """d/d alpha of sum(f) + sum(pdf) over the directions wi, per transport mode."""
    def value(alpha, mode):
        shape = wi.shape[:-1]
        f, pdf = B.evaluate(KINDS, _params(_with_alpha(mat, alpha), shape), _v3(n, shape),
                            _v3(wo, shape), _v3(wi, shape), mode)
        return jnp.sum(f.stack()) + jnp.sum(pdf)
    return [jax.grad(value)(mat[5], mode) for mode in (B.RADIANCE, B.IMPORTANCE)]


@jax.jit
def _tangent_sample(mat, n, wo, u):
    """d/d alpha (forward mode) of the sampled direction, weight and pdf: the derivative an
    estimator that differentiates through its sampling sees."""
    def value(alpha):
        shape = u.shape[1:]
        s = B.sample(KINDS, _params(_with_alpha(mat, alpha), shape), _v3(n, shape),
                     _v3(wo, shape), u[0], u[1], u[2])
        return s.wi.stack(), s.weight.stack(), s.pdf
    return jax.jvp(value, (mat[5],), (jnp.ones_like(mat[5]),))[1]


def _grad_cases():
    eps = 1e-7
    wo_grazing = np.array([np.sqrt(1 - eps ** 2), 0.0, eps], np.float32)
    wis = np.stack([-wo_grazing, Z, np.array([1.0, 0.0, 0.0]), reflect_np(wo_grazing, Z), -Z,
                    direction(40.0, n=Z), direction(140.0, n=Z),
                    -direction(30.0, n=Z)]).astype(np.float32)
    wos = (wo_grazing, direction(30.0, n=Z).astype(np.float32), Z.astype(np.float32))
    return wos, wis


@pytest.mark.parametrize("kind", ["roughconductor", "roughdielectric", "roughplastic"])
def test_gradients_wrt_alpha_are_finite(kind):
    """d/d alpha of f and pdf at tiny and large alpha, at grazing and degenerate directions
    (wi = -wo, the normal, the surface plane), ior 1 included: the inner-where trick keeps
    0 * inf out of the derivatives."""
    wos, wis = _grad_cases()
    for dist in ("ggx", "beckmann"):
        for alpha in (1e-4, 0.05, 1.0):
            kw = dict(ior=1.0) if kind == "roughdielectric" and alpha == 0.05 else {}
            mat = material(kind, alpha=alpha, distribution=dist, **kw)
            for wo in wos:
                for n in (Z, -Z):
                    g = np.asarray(_grad_evaluate(mat, np.float32(n), wo, wis))
                    assert np.all(np.isfinite(g)), (dist, alpha, wo, n, g)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["roughconductor", "roughdielectric", "roughplastic"])
def test_gradients_through_sampling_are_finite(kind):
    """Forward-mode derivative of the sample (direction, weight, pdf) with respect to alpha,
    at tiny and large alpha and grazing incidence (slow: compiling it takes ~20 s, and the
    derivative program is large: ~250 us per lane on one core)."""
    wos, _ = _grad_cases()
    u = np.random.default_rng(0).random((3, 256), dtype=np.float32)
    for dist in ("ggx", "beckmann"):
        for alpha in (1e-4, 0.05, 1.0):
            mat = material(kind, alpha=alpha, distribution=dist)
            for wo in wos:
                for part in _tangent_sample(mat, np.float32(Z), wo, u):
                    assert np.all(np.isfinite(np.asarray(part))), (dist, alpha, wo)


@pytest.mark.parametrize("kind", ["roughconductor", "roughdielectric", "roughplastic"])
def test_reverse_mode_gradients_of_samples_are_finite(kind):
    """jax.grad (reverse mode) of sampled directions, weights and pdfs with respect to alpha,
    with wo on both sides (the rough dielectric's total internal reflection included): the
    refraction's sqrt(cos^2 theta_t) at 0 once made 0 * inf = NaN of every lane's gradient."""
    b = SceneBuilder()
    b.material("m", kind, alpha=0.2)
    b.camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0))
    mats = b.build().materials
    rng = np.random.default_rng(3)
    n_lanes = 256
    unit = lambda a: a / np.linalg.norm(a, axis=0)  # noqa: E731
    n = V3(*jnp.asarray(unit(rng.normal(size=(3, n_lanes))), jnp.float32))
    wo = V3(*jnp.asarray(unit(rng.normal(size=(3, n_lanes))), jnp.float32))
    u = jnp.asarray(rng.random((3, n_lanes)), jnp.float32)
    m = jnp.zeros(n_lanes, jnp.int32)

    def total(scale):
        mt = eqx.tree_at(lambda t: (t.alpha_u, t.alpha_v), mats,
                         (mats.alpha_u * scale, mats.alpha_v * scale))
        s = B.sample(mt.kinds, B.lookup_specialised(mt, m), n, wo, u[0], u[1], u[2])
        return jnp.sum(s.weight.x + s.pdf * 1e-3 + s.wi.x)

    g = float(jax.jit(jax.grad(total))(jnp.float32(1.0)))
    assert np.isfinite(g), g


def test_grad_of_f_wrt_alpha_matches_finite_differences():
    mat = list(material("roughconductor", alpha=0.2, metal="Au"))
    wo, wi = direction(30.0, n=Z), direction(50.0, 200.0, n=Z)

    wis = np.stack([wi] * 8).astype(np.float32)
    g = float(np.asarray(_grad_evaluate(mat, np.float32(Z), np.float32(wo), wis))[0]) / 8
    h = 1e-3

    def value(alpha):
        f, pdf = evaluate(_with_alpha(mat, np.float32(alpha)), Z, wo, wi[None])
        return float(f.sum() + pdf.sum())

    fd = (value(0.2 + h) - value(0.2 - h)) / (2 * h)
    assert abs(g - fd) < 1e-3 * max(abs(fd), 1e-3), (g, fd)


# --- the builder and the table -----------------------------------------------------------------

def test_builder_fills_the_table():
    b = SceneBuilder()
    b.material("gold", "roughconductor", metal="Au", alpha_u=0.1, alpha_v=0.3,
               distribution="beckmann")
    b.material("glass", "roughdielectric", int_ior=1.5, ext_ior=1.25, alpha=0.2)
    b.material("plastic", "roughplastic", diffuse=0.5)
    b.material("copper", "conductor", metal="Cu")
    b.material("mirror", "mirror")
    b.camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0))
    m = b.build().materials
    assert m.kinds == (MIRROR, ROUGH_CONDUCTOR, ROUGH_DIELECTRIC, ROUGH_PLASTIC)
    assert m.distributions == (GGX, BECKMANN)
    np.testing.assert_allclose(np.asarray(m.alpha_u), [0.1, 0.2, 0.1, 0.1, 0.1])
    np.testing.assert_allclose(np.asarray(m.alpha_v), [0.3, 0.2, 0.1, 0.1, 0.1])
    np.testing.assert_allclose(np.asarray(m.ior)[1:3], [1.2, 1.49 / 1.000277], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(m.eta.x), [NAMED_METALS["Au"][0][0], 0, 0,
                                                     NAMED_METALS["Cu"][0][0], 0], rtol=1e-6)
    assert np.asarray(m.kind).tolist() == [ROUGH_CONDUCTOR, ROUGH_DIELECTRIC, ROUGH_PLASTIC,
                                           MIRROR, MIRROR]
    assert m.transmittance.shape == (5, 64)
    t = np.asarray(m.transmittance)[2]
    assert 0.0 < t[0] < t[-1] < 1.0 and 0.0 < float(m.internal_reflectance[2]) < 1.0
    # lookup_specialised reads what lookup reads for the kinds present
    idx = jnp.array([0, 1, 2, 3, 4, 2], jnp.int32)
    a, s = B.lookup(m, idx), B.lookup_specialised(m, idx)
    for name in ("kind", "ior", "alpha_u", "alpha_v", "distribution", "row",
                 "internal_reflectance", "nonlinear"):
        np.testing.assert_array_equal(np.asarray(getattr(a, name)),
                                      np.asarray(getattr(s, name)), err_msg=name)
    for name in ("kd", "ks", "eta", "k"):
        np.testing.assert_array_equal(np.asarray(getattr(a, name).stack()),
                                      np.asarray(getattr(s, name).stack()), err_msg=name)
    glossy = np.asarray(B.is_glossy(a)).tolist()
    assert glossy == [False, False, False, False, False, False]
    assert np.asarray(B.is_delta(a)).tolist() == [False, False, False, True, True, False]


@pytest.mark.parametrize("kind,kw,message", [
    ("roughconductor", dict(metal="gold"), "unknown metal 'gold'; allowed: none, a-C, Ag"),
    ("roughconductor", dict(alpha=0.0), "alpha must be a finite number > 0"),
    ("roughconductor", dict(alpha=0.1, alpha_u=0.2, alpha_v=0.2), "either alpha or alpha_u"),
    ("roughconductor", dict(alpha_u=0.2), "give both alpha_u and alpha_v"),
    ("roughconductor", dict(eta=-1.0), "eta must be >= 0"),
    ("roughconductor", dict(k=(1.0, -1.0, 0.0)), "k must be >= 0"),
    ("roughconductor", dict(metal="Au", eta=1.0), "either metal or eta / k"),
    ("roughdielectric", dict(distribution="phong"), "unknown distribution 'phong'; allowed: "
                                                     "ggx, beckmann"),
    ("roughdielectric", dict(ior=1.5, int_ior=1.5), "either ior or int_ior / ext_ior"),
    ("roughplastic", dict(alpha_u=0.1, alpha_v=0.2), "roughplastic is isotropic"),
    ("roughplastic", dict(int_ior=1.0, ext_ior=1.0), "must differ"),
    ("diffuse", dict(alpha=0.1), "'alpha' does not apply"),
    ("roughdielectric", dict(metal="Au"), "'metal' does not apply"),
    ("roughdielectric", dict(transmittance=(0.5, -0.1, 0.5)), "'transmittance' must be one "
                                                               "number or three (RGB)"),
    ("roughconductor", dict(transmittance=0.5), "'transmittance' does not apply"),
])
def test_builder_errors_name_the_material_and_what_is_allowed(kind, kw, message):
    with pytest.raises(SceneError, match=f"material 'x'.*{re.escape(message)}"):
        SceneBuilder().material("x", kind, **kw)
