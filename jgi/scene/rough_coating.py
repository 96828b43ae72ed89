"""The rough dielectric coating of ``roughplastic``, precomputed at scene build (float64 numpy).

Mitsuba 3's ``roughplastic`` (``src/bsdfs/roughplastic.cpp``, ``parameters_changed``) tabulates,
once per material, two properties of its rough dielectric interface (relative index
eta = int_ior / ext_ior, distribution and alpha of the specular lobe):

* the *external transmittance* T(mu): the fraction of light arriving from outside at
  cos(theta) = mu that the rough interface transmits into the coating, at
  mu_i = max(1e-6, i / 63), i = 0 .. 63 (``MI_ROUGH_TRANSMITTANCE_RES`` = 64 entries):
  T(mu) = integral over the visible normals m of wi of G1(wt, m) (1 - F(wi.m, eta)), wt the
  refracted direction, counted where wt is below the surface (``eval_transmittance`` in
  ``include/mitsuba/render/microfacet.h``);
* the *internal reflectance* Ri: the same interface seen from inside (index 1 / eta) reflecting
  back, R(mu) = integral of G1(wr, m) F(wi.m, 1 / eta) over the visible normals, wr the mirror
  direction, counted where it stays inside; Ri = 2 * mean_i(R(mu_i) mu_i) over the same 64
  cosines (Mitsuba's discrete cosine-weighted hemispherical average, reproduced as it is).

The BSDF reads T at cos(theta_o) and cos(theta_i) by linear interpolation between the entries
(Mitsuba's ``lerp_gather``). These tables are computed from the *numbers* alpha and eta at build
time: they are not differentiable (``jax.grad`` with respect to a roughplastic's alpha or ior
sees the specular lobe's dependence only; rebuild the scene to change them).

Quadrature: Mitsuba integrates over its visible-normal sampler's unit square with 32^2
Gauss-Legendre nodes (128^2 for eta < 1) in float32. GGX here does the same in float64, through
the same map of the square (Shirley-Chiu's concentric disc, then Heitz's visible-normal warp),
so the tables agree with Mitsuba 3.9.1's to float32 rounding (Ri and T(1) within 3e-7, the
BSDF within 3e-6, measured; the 32-node quadrature itself is within 4e-4 of the converged
integral at alpha = 0.2, and Mitsuba's value is the definition we match).
Beckmann integrates through D(m) cos(theta_m) sampling (Walter et al. 2007) weighted by
VNDF / pdf, with 128^2 nodes (within 2e-5 of 512^2); Smith's G1 is the exact one (erf), where
Mitsuba uses a rational G1 within 0.35 %, so Beckmann tables differ from Mitsuba's by up to
0.2 % (measured at alpha 0.01 .. 0.7; Ri by 1.4e-4 at alpha 0.2).
"""

from __future__ import annotations

import numpy as np
from scipy import special

from ..core import optics, warps
from .tables import BECKMANN, GGX

TABLE_SIZE = 64        # Mitsuba's MI_ROUGH_TRANSMITTANCE_RES
# Gauss-Legendre nodes per axis of the unit square: GGX as Mitsuba (32, or 128 for eta < 1),
# through the same map, so that the tables agree with Mitsuba's to float32 rounding; Beckmann
# (another map, with a kink) with enough nodes to converge to 2e-5 (measured against 512).
_NODES = {GGX: (32, 128), BECKMANN: (128, 128)}


def table_cosines() -> np.ndarray:
    """The 64 cosines mu_i = max(1e-6, i / 63) at which T is tabulated."""
    return np.maximum(1e-6, np.linspace(0.0, 1.0, TABLE_SIZE))


def smith_lambda(dist: int, v: np.ndarray, alpha: float) -> np.ndarray:
    """Smith's Lambda(v) for an isotropic distribution, v [..., 3] with v_z != 0."""
    t2 = alpha * alpha * (v[..., 0] ** 2 + v[..., 1] ** 2) / (v[..., 2] ** 2)
    if dist == GGX:
        return optics.smith_lambda_ggx(t2, np)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = optics.smith_lambda_beckmann(1.0 / np.sqrt(t2), np, special.erfc)
    return np.where(t2 > 0, lam, 0.0)


def smith_g1(dist: int, v: np.ndarray, m: np.ndarray, alpha: float) -> np.ndarray:
    """G1(v, m) = 1 / (1 + Lambda(v)), zero where v sees the back of m."""
    ok = np.sum(v * m, axis=-1) * v[..., 2] > 0
    return np.where(ok, 1.0 / (1.0 + smith_lambda(dist, v, alpha)), 0.0)


def fresnel(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """Unpolarised dielectric Fresnel reflectance, cos_i >= 0, eta = eta_t / eta_i."""
    cos2_t = optics.cos2_transmitted(cos_i, eta)
    cos_t = np.sqrt(np.maximum(cos2_t, 0.0))
    return np.where(cos2_t <= 0, 1.0, optics.fresnel_dielectric_reflectance(cos_i, cos_t, eta, np))


def _normals(dist: int, wi: np.ndarray, alpha: float, u1, u2):
    """Microfacet normals m [..., 3] over the unit square (u1, u2) and the weight VNDF / pdf
    of the map, for wi [..., 3] with wi_z > 0."""
    if dist == GGX:   # Heitz 2018: visible normals directly (weight 1)
        vh = wi * np.array([alpha, alpha, 1.0])
        vh = vh / np.linalg.norm(vh, axis=-1, keepdims=True)
        lensq = vh[..., 0] ** 2 + vh[..., 1] ** 2
        inv = np.where(lensq > 0, 1.0 / np.sqrt(np.where(lensq > 0, lensq, 1.0)), 0.0)
        t1 = np.stack([-vh[..., 1] * inv, vh[..., 0] * inv, np.zeros_like(inv)], -1)
        t1 = np.where((lensq > 0)[..., None], t1, np.array([1.0, 0.0, 0.0]))
        t2 = np.cross(vh, t1)
        p1, p2, _ = warps.concentric_disc_polar(u1, u2, np)
        s = 0.5 * (1.0 + vh[..., 2])
        p2 = (1.0 - s) * np.sqrt(1.0 - p1 * p1) + s * p2
        nh = (p1[..., None] * t1 + p2[..., None] * t2
              + np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))[..., None] * vh)
        m = nh * np.array([alpha, alpha, 1.0])
        m[..., 2] = np.maximum(m[..., 2], 0.0)
        m = m / np.linalg.norm(m, axis=-1, keepdims=True)
        return m, np.ones(m.shape[:-1])
    # Beckmann: slopes from the (scaled) Gaussian, D(m) cos(theta_m) dm = P22 dslope
    r, phi = np.sqrt(-np.log1p(-u1)), 2.0 * np.pi * u2
    m = np.stack(np.broadcast_arrays(-alpha * r * np.cos(phi), -alpha * r * np.sin(phi),
                                     np.ones_like(r)), -1)
    m = m / np.linalg.norm(m, axis=-1, keepdims=True)
    m = np.broadcast_to(m, np.broadcast_shapes(m.shape, wi.shape))
    cos_im = np.sum(wi * m, axis=-1)
    weight = (smith_g1(dist, wi, m, alpha) * np.maximum(cos_im, 0.0)
              / (wi[..., 2] * m[..., 2]))
    return m, weight


def _integrate(dist: int, alpha: float, eta: float, transmit: bool) -> np.ndarray:
    """T(mu_i) (``transmit``) or R(mu_i) for the 64 table cosines."""
    n = _NODES[dist][0 if eta > 1 else 1]
    x, w = np.polynomial.legendre.leggauss(n)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    u1, u2 = (a.ravel() for a in np.meshgrid(x, x, indexing="ij"))
    ww = np.outer(w, w).ravel()
    mu = table_cosines()
    wi = np.stack([np.sqrt(1.0 - mu * mu), np.zeros_like(mu), mu], -1)[:, None, :]
    m, weight = _normals(dist, wi, alpha, u1[None, :], u2[None, :])
    cos_im = np.sum(wi * m, axis=-1)
    F = fresnel(np.maximum(cos_im, 0.0), eta)
    if transmit:
        cos2_t = optics.cos2_transmitted(cos_im, eta)
        cos_t = np.sqrt(np.maximum(cos2_t, 0.0))
        wo = -wi / eta + m * (cos_im / eta - cos_t)[..., None]
        ok = (wo[..., 2] < 0) & (cos2_t > 0)
        value = (1.0 - F) * smith_g1(dist, wo, m, alpha)
    else:
        wo = 2.0 * cos_im[..., None] * m - wi
        ok = wo[..., 2] > 0
        value = F * smith_g1(dist, wo, m, alpha)
    return np.sum(np.where(ok & (cos_im > 0), value * weight, 0.0) * ww, axis=-1)


def fresnel_diffuse_reflectance(eta: float) -> float:
    """Mitsuba 3's ``fresnel_diffuse_reflectance`` (``include/mitsuba/render/fresnel.h``): the
    fraction of diffuse (cosine-weighted) light that a smooth interface of relative index eta
    reflects, by the fits it uses, in float32 as Mitsuba evaluates them: Egan and Hilgeman's
    (1973) for eta < 1, d'Eon and Irving's (2011) polynomial in 1 / eta otherwise. The smooth
    ``plastic``'s fdr_int is this at 1 / eta (its coating seen from inside)."""
    eta = np.float32(eta)
    inv = np.float32(1.0) / eta
    if eta < 1:
        return float(np.float32(0.0636) * inv
                     + (eta * (eta * np.float32(-1.4399) + np.float32(0.7099))
                        + np.float32(0.6681)))
    acc = np.float32(0.0)
    for c in (-1.36881, 4.98554, -7.80989, 6.75335, -3.4793, 0.919317):   # Horner
        acc = acc * inv + np.float32(c)
    return float(acc)


def plastic_tables(dist: int, alpha: float, eta: float) -> tuple[np.ndarray, float]:
    """(external transmittance T [64], internal reflectance Ri) of a roughplastic coating with
    relative index eta = int_ior / ext_ior (alpha clamped to >= 1e-4 as the BSDF does)."""
    alpha = max(float(alpha), 1e-4)
    transmittance = _integrate(dist, alpha, float(eta), transmit=True)
    reflect = _integrate(dist, alpha, 1.0 / float(eta), transmit=False)
    internal = 2.0 * float(np.mean(reflect * table_cosines()))
    return transmittance, internal
