"""Microfacet normal distributions: GGX (Trowbridge-Reitz) and Beckmann, isotropic or
anisotropic, with Smith's masking and their samplers (pbrt style: ``sample_x`` next to
``pdf_x``).

Directions here are *local*: (x, y, z) along (s, t, n_f), where s, t =
``vec.coordinate_system(n)`` of the primitive's geometric normal n and n_f is n flipped onto
wo's side (:func:`.common.side`). The tangents come from n, not n_f, so that both sides of a
surface (and both sides of a rough dielectric interface) share one anisotropy frame; D and
Smith's Lambda depend on x^2 and y^2 only, so the frame's handedness does not matter.
alpha_u is the roughness along s, alpha_v along t. For Beckmann alpha is the RMS slope
(sqrt 2 times the standard deviation of each slope), as in Mitsuba 3 and Walter et al. 2007.

* D(m): GGX 1 / (pi a_u a_v (x^2 / a_u^2 + y^2 / a_v^2 + z^2)^2); Beckmann
  exp(-(x^2 / a_u^2 + y^2 / a_v^2) / z^2) / (pi a_u a_v z^4). Both satisfy
  integral D(m) cos(theta_m) dm = 1.
* Smith: Lambda(v) from tan^2 = (a_u^2 v_x^2 + a_v^2 v_y^2) / v_z^2, GGX
  (sqrt(1 + tan^2) - 1) / 2, Beckmann (exp(-a^2) / (a sqrt(pi)) - erfc(a)) / 2 with
  a = 1 / tan (exact; Mitsuba 3 uses a rational approximation within 0.35 %);
  G1(v, m) = 1 / (1 + Lambda(v)), 0 where v sees the back of m; and the *separable*
  shadowing-masking G(wo, wi, m) = G1(wo, m) G1(wi, m), as Mitsuba 3 uses.
* Sampling: GGX by its distribution of visible normals D_wo(m) = G1(wo, m) max(0, wo.m) D(m)
  / wo_z (Heitz 2018, "Sampling the GGX Distribution of Visible Normals"); Beckmann by
  D(m) cos(theta_m) (Walter et al. 2007; both are exact, through the slope distribution).
  :func:`sample_normal` / :func:`pdf_normal` pick per lane.

The roughness is clamped to at least ``MIN_ALPHA`` = 1e-4 (Mitsuba's floor): below it D's peak
(1 / (pi alpha^2)) no longer fits float32 comfortably. ``dist`` is a per-lane int array (GGX or
BECKMANN) or a Python int: :func:`.common.lookup_specialised` gives a Python int when the scene
uses one distribution, and then only that one's code is traced.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from ... import _xla
from ...core import optics, warps
from ...core.vec import V3, coordinate_system, cross, dot, normalize
from ...scene.tables import BECKMANN, GGX

MIN_ALPHA = 1e-4
_INV_PI = 1.0 / jnp.pi
# float32 below 1: keeps 1 - rho^2 > 0 on the concentric disc's rim (rho = 1 at u = 0)
_ONE_MINUS = 1.0 - 2.0 ** -24


# --- the local frame ----------------------------------------------------------------------------

def frame(n: V3) -> tuple[V3, V3]:
    """Tangents (s, t) of the anisotropy frame: those of the geometric normal n."""
    return coordinate_system(n)


def to_local(w: V3, s: V3, t: V3, nf: V3) -> V3:
    return V3(dot(w, s), dot(w, t), dot(w, nf))


def from_local(v: V3, s: V3, t: V3, nf: V3) -> V3:
    return s * v.x + t * v.y + nf * v.z


def alphas(alpha_u, alpha_v) -> tuple[Array, Array]:
    """The roughness pair with Mitsuba's floor of 1e-4."""
    return jnp.maximum(alpha_u, MIN_ALPHA), jnp.maximum(alpha_v, MIN_ALPHA)


def _pick(dist, ggx_fn, beckmann_fn):
    """ggx_fn() or beckmann_fn() per lane; only one is traced when ``dist`` is a Python int."""
    if isinstance(dist, int):
        return ggx_fn() if dist == GGX else beckmann_fn()
    a, b = ggx_fn(), beckmann_fn()
    if isinstance(a, V3):
        return V3(*(jnp.where(dist == GGX, p, q) for p, q in zip(a, b)))
    return jnp.where(dist == GGX, a, b)


# --- D and Smith's masking ----------------------------------------------------------------------

def ndf(dist, m: V3, au: Array, av: Array) -> Array:
    """D(m) for a local microfacet normal m (0 for m_z <= 0)."""
    z2 = m.z * m.z
    up = m.z > 0
    xa, yb = m.x / au, m.y / av
    inv_norm = _INV_PI / (au * av)

    def ggx():
        q = xa * xa + yb * yb + z2
        q = jnp.where(up, q, 1.0)
        return jnp.where(up, inv_norm / (q * q), 0.0)

    def beckmann():
        e = (xa * xa + yb * yb) / jnp.where(up, z2, 1.0)
        ok = up & (e < 80.0)   # exp(-80) = 2e-35: beyond it D is 0 (and z^4 may underflow)
        z2s = jnp.where(ok, z2, 1.0)
        return jnp.where(ok, inv_norm * jnp.exp(-jnp.where(ok, e, 0.0)) / (z2s * z2s), 0.0)

    return _pick(dist, ggx, beckmann)


def smith_lambda(dist, v: Array, au: Array, av: Array) -> Array:
    """Smith's Lambda(v) for a local direction v with v_z != 0 (callers mask v_z = 0)."""
    z2 = v.z * v.z
    t2 = ((au * v.x) ** 2 + (av * v.y) ** 2) / jnp.where(z2 > 0, z2, 1.0)

    def ggx():
        return optics.smith_lambda_ggx(t2, jnp)

    def beckmann():
        pos = t2 > 1e-30   # below it Lambda = 0 (a > 1e15); also keeps rsqrt normal
        a = _xla.rsqrt(jnp.where(pos, t2, 1.0))
        lam = optics.smith_lambda_beckmann(a, jnp, jax.lax.erfc)
        return jnp.where(pos, jnp.maximum(lam, 0.0), 0.0)

    return _pick(dist, ggx, beckmann)


def smith_g1(dist, v: V3, m: V3, au: Array, av: Array) -> Array:
    """G1(v, m) = 1 / (1 + Lambda(v)); 0 where v sees the back of m (v.m and v_z of opposite
    signs) or lies in the surface."""
    ok = (dot(v, m) * v.z > 0) & (v.z != 0)
    return jnp.where(ok, 1.0 / (1.0 + smith_lambda(dist, v, au, av)), 0.0)


def smith_g(dist, wo: V3, wi: V3, m: V3, au: Array, av: Array) -> Array:
    """Separable shadowing-masking G1(wo, m) G1(wi, m) (Mitsuba 3's choice)."""
    return smith_g1(dist, wo, m, au, av) * smith_g1(dist, wi, m, au, av)


# --- sampling: visible normals (GGX) ------------------------------------------------------------

def sample_vndf_ggx(wo: V3, au: Array, av: Array, u1: Array, u2: Array) -> V3:
    """A normal from GGX's visible normals seen from wo (local, wo_z > 0), Heitz 2018: stretch
    wo to the alpha = 1 configuration, sample the projected hemisphere there (a uniform disc
    point moved onto the visible half), unstretch."""
    vh = normalize(V3(au * wo.x, av * wo.y, wo.z))
    lensq = vh.x * vh.x + vh.y * vh.y
    pos = lensq > 0
    inv = jnp.where(pos, _xla.rsqrt(jnp.where(pos, lensq, 1.0)), 0.0)
    t1 = V3(jnp.where(pos, -vh.y * inv, 1.0), jnp.where(pos, vh.x * inv, 0.0), 0.0 * inv)
    t2 = cross(vh, t1)
    p1, p2, _ = warps.concentric_disc_polar(u1, u2)
    s = 0.5 * (1.0 + vh.z)
    p2 = (1.0 - s) * jnp.sqrt(jnp.maximum(1.0 - p1 * p1, 0.0)) + s * p2
    nh = t1 * p1 + t2 * p2 + vh * jnp.sqrt(jnp.maximum(1.0 - p1 * p1 - p2 * p2, 0.0))
    return normalize(V3(au * nh.x, av * nh.y, jnp.maximum(nh.z, 0.0)))


def pdf_vndf(dist, wo: V3, m: V3, au: Array, av: Array) -> Array:
    """D_wo(m) = G1(wo, m) max(0, wo.m) D(m) / wo_z, the density of visible normals."""
    cos_o = jnp.where(wo.z > 0, wo.z, 1.0)
    g1 = smith_g1(dist, wo, m, au, av)
    return jnp.where(wo.z > 0, g1 * jnp.maximum(dot(wo, m), 0.0) * ndf(dist, m, au, av) / cos_o,
                     0.0)


# --- sampling: D(m) cos(theta_m) (either distribution) ------------------------------------------

def sample_dcos(dist, au: Array, av: Array, u1: Array, u2: Array) -> V3:
    """A normal with density D(m) cos(theta_m), through the slope distribution: a uniform disc
    point (x, y) of radius rho becomes the stretched slope (x, y) g(rho) / rho with
    g = sqrt(-log(1 - rho^2)) (Beckmann: a Gaussian) or rho / sqrt(1 - rho^2) (GGX), then
    m = normalize(-a_u slope_x, -a_v slope_y, 1) (the sign is immaterial: D is even)."""
    x, y, rho = warps.concentric_disc_polar(u1, u2)
    r2 = jnp.minimum(rho * rho, _ONE_MINUS)

    def ggx():   # slope scale 1 / sqrt(1 - rho^2), multiplied through to keep m finite
        return normalize(V3(au * x, av * y, jnp.sqrt((1.0 - rho) * (1.0 + rho))))

    def beckmann():
        pos = r2 > 0
        q = jnp.where(pos, -jnp.log1p(-r2) / jnp.where(pos, r2, 1.0), 1.0)
        g = jnp.sqrt(q)
        return normalize(V3(au * x * g, av * y * g, jnp.ones_like(g)))

    return _pick(dist, ggx, beckmann)


def pdf_dcos(dist, m: V3, au: Array, av: Array) -> Array:
    return ndf(dist, m, au, av) * jnp.maximum(m.z, 0.0)


# --- the sampler the BSDFs use ------------------------------------------------------------------

def sample_normal(dist, wo: V3, au: Array, av: Array, u1: Array, u2: Array) -> V3:
    """GGX: a visible normal of wo; Beckmann: D(m) cos(theta_m)."""
    return _pick(dist, lambda: sample_vndf_ggx(wo, au, av, u1, u2),
                 lambda: sample_dcos(BECKMANN, au, av, u1, u2))


def pdf_normal(dist, wo: V3, m: V3, au: Array, av: Array) -> Array:
    """The density of :func:`sample_normal` over microfacet normals (solid angle)."""
    return _pick(dist, lambda: pdf_vndf(GGX, wo, m, au, av),
                 lambda: pdf_dcos(BECKMANN, m, au, av))
