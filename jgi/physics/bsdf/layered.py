"""pbrt-v4's stochastic layered BSDFs, ``coateddiffuse`` and ``coatedconductor`` (pbrt-v4's
``LayeredBxDF`` with ``twoSided``; Guo, Hasan and Zhao 2018, "Position-free Monte Carlo
simulation for arbitrary layered BSDFs").

A slab of optical ``thickness`` (extinction sigma_t = 1) lies between a rough dielectric
*coating* on top (relative index ``ior``, GGX roughness ``alpha_u`` / ``alpha_v``; the
outside is above it) and a *base* at its bottom: Lambertian (``kd``, coateddiffuse) or a
conductor of index (eta + i k) / ior (coatedconductor: pbrt-v4 divides the metal's index,
given against air, by the coating's), rough (GGX, the layer's ``base_alpha_*``) or smooth
(alpha below 1e-3, a Dirac mirror inside the slab). The slab may hold a medium of
single-scattering ``albedo`` and Henyey-Greenstein asymmetry ``g``. Light is followed through
the slab by a position-free random walk: only the depth z matters, and the transmittance
along a direction w over a depth dz is Tr(dz, w) = exp(-|dz / w_z|).

Three estimators, each a random walk of at most ``max_depth`` steps (pbrt's maxdepth), with
Russian roulette after step 3, averaged over ``samples`` walks (pbrt's nsamples):

* :func:`f_estimate`, an unbiased estimate of f(wo, wi) (of the BSDF truncated at max_depth):
  the coating's reflection, plus walks entering by a transmission sample ``wos`` of the
  coating; at each base bounce (and medium scattering event) next event estimation towards
  wi through a presampled transmission ``wis`` of the coating seen from wi (mode flipped:
  it carries the adjoint quantity), combined by the power heuristic with the base's (or phase
  function's) sampled direction evaluated through the coating's exit.
* :func:`sample_walk`, pbrt's Sample_f: the coating is sampled first (a reflection leaves at
  once), then the walk scatters off base and coating until a sample transmits out through
  the coating; the weight f cos / pdf is the product of the sampled steps' weights, an
  unbiased estimate of the BSDF's weight without knowing f or pdf (pbrt's pdfIsProportional).
* :func:`pdf_estimate`, pbrt's PDF: the coating's reflection density plus an MIS estimate
  of the density of the transmit-reflect-transmit path, mixed with a uniform density:
  0.1 / (4 pi) + 0.9 estimate (pbrt's Lerp(0.9, 1 / (4 pi), estimate)).

Why the estimators stay unbiased with stochastic f and pdf: a path throughput that uses an
unbiased estimate of f in place of f has the same expectation (the walk's randomness is
independent of the rest of the path given its directions); the pdf estimates enter only MIS
weights (and photon radii nowhere), and MIS weights need not be exact densities to keep an
estimator unbiased, only to sum to one over the strategies of a path, which every estimator
ensures by evaluating the same function for the same vertex (BDPT and VCM recompute the
reverse density with the same estimator). Sampled directions carry the walk's own weight, as
pbrt-v4 does, never f / pdf of the estimates. The truncation at max_depth is the same in f's
walk and in the sampler's (each base bounce takes two steps in both).

Randomness without hidden state: the walks draw their numbers from a counter-based hash
(:func:`uniform`) seeded by the bit patterns of the arguments, as pbrt-v4 seeds its RNG from
Hash(seed, wo), Hash(wi) (f), Hash(wi), Hash(wo) (pdf) and Hash(wo), Hash(uc, u) (sampling):
each call is a pure function of its inputs, the same on every run and device.

jgi's conventions where pbrt's differ, documented: the multiple importance sampling inside
f's walk weights the base's (or phase function's) sampled direction d, which is then
evaluated through the coating towards wi, against the density with which the competing
strategy, the presampled ``wis``, produces d (the coating's transmission density from wi,
:func:`coating_eval` (wi, -d)); pbrt-v4 uses the density of the reverse sampling, from -d
towards wi, which differs by the refraction Jacobian, so that its two weights of one path do
not sum to one (measured with pbrt's weights: f(a, b) vs f(b, a) Welch t = 7.2 and 4.7 for a
medium and a metal base, and the sampler's energy per cos theta bin off f's integral by up
to 4.7 standard errors; with these weights both agree). The sampler keeps pbrt's f and pdf
products as their ratio (the weight so far), which float32 cannot overflow. The microfacet masking is jgi's separable
Smith G (pbrt-v4 uses the height-correlated one), as in jgi's other rough kinds; the pdf is 0
(not pbrt's uniform 0.1 / (4 pi)) for wi on the other side from wo, where a reflection-only
material has no density; the coating must be rough (a smooth coating, pbrt's
EffectivelySmooth, adds a Dirac reflection lobe that jgi's estimators carry for the smooth
plastic only: the scene builder refuses it). Local directions: z along the normal on wo's
side (two-sided, as pbrt's coated materials), x, y the anisotropy frame's tangents.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ...core import warps
from ...core.vec import V3, coordinate_system, dot, where
from ...scene.tables import COATED_CONDUCTOR, COATED_DIFFUSE, GGX
from . import roughconductor, roughdielectric
from .common import IMPORTANCE, RADIANCE, MaterialParams, lit
from .fresnel import fresnel_conductor_rgb

SMOOTH_ALPHA = 1e-3        # pbrt-v4's EffectivelySmooth: max(alpha_x, alpha_y) below it
UNIFORM_MIX = 0.1          # pbrt's PDF: Lerp(0.9, 1 / (4 pi), estimate)
_FLT_MIN = float(np.finfo(np.float32).tiny)
_SLOTS = 8                 # random numbers per walk step
ALL, REFLECTION, TRANSMISSION = 0, 1, 2   # pbrt's BxDFReflTransFlags, for the coating


# --- counter-based random numbers ---------------------------------------------------------------

def _mix(x: Array) -> Array:
    """A 32-bit integer hash (the "lowbias32" finaliser: xor-shift, multiply, twice)."""
    x = x ^ (x >> 16)
    x = x * np.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * np.uint32(0x846CA68B)
    return x ^ (x >> 16)


def seed_of(*values) -> Array:
    """A seed hashed from the float32 bit patterns of ``values`` (arrays, broadcast)."""
    h = jnp.uint32(0x9E3779B9)
    for v in values:
        bits = jax.lax.bitcast_convert_type(jnp.asarray(v, jnp.float32), jnp.uint32)
        h = _mix(h ^ bits)
    return h


def uniform(seed: Array, counter) -> Array:
    """The ``counter``-th number in [0, 1 - 2^-24] of the stream ``seed``."""
    c = jnp.asarray(counter).astype(jnp.uint32)
    bits = _mix(seed ^ _mix(c * np.uint32(0x9E3779B1) + np.uint32(0x632BE5AB)))
    return (bits >> 8).astype(jnp.float32) * np.float32(2.0 ** -24)


# --- small helpers --------------------------------------------------------------------------------

def _ones(like: Array) -> V3:
    one = jnp.ones_like(like)
    return V3(one, one, one)


def _flipz(w: V3, flip: Array) -> V3:
    return V3(w.x, w.y, jnp.where(flip, -w.z, w.z))


def _max3(v: V3) -> Array:
    return jnp.maximum(jnp.maximum(v.x, v.y), v.z)


def _safe_div(a: Array, b: Array) -> Array:
    ok = b > 0
    return jnp.where(ok, a / jnp.where(ok, b, 1.0), 0.0)


def power_heuristic(f: Array, g: Array) -> Array:
    """Veach's power heuristic with one sample each: f^2 / (f^2 + g^2) (0 where both are 0)."""
    f2, g2 = f * f, g * g
    return _safe_div(f2, f2 + g2)


def transmittance(dz: Array, w: V3) -> Array:
    """Tr(dz, w) = exp(-|dz / w_z|) (sigma_t = 1); 1 for |dz| at most FLT_MIN (pbrt's)."""
    az = jnp.abs(w.z)
    t = jnp.exp(-jnp.abs(dz) / jnp.where(az > 0, az, 1.0))
    return jnp.where(jnp.abs(dz) <= _FLT_MIN, 1.0, jnp.where(az > 0, t, 0.0))


# --- the Henyey-Greenstein phase function (pbrt's convention: both directions leave) ---------------

def hg(cos: Array, g: Array) -> Array:
    """p(wo, wi) = HG(wo . wi, g), g clamped to [-0.99, 0.99] (pbrt-v4's)."""
    g = jnp.clip(g, -0.99, 0.99)
    denom = 1.0 + g * g + 2.0 * g * cos
    return (1.0 - g * g) / (4.0 * jnp.pi * denom * jnp.sqrt(jnp.maximum(denom, 1e-12)))


def sample_hg(wo: V3, g: Array, u1: Array, u2: Array) -> tuple[V3, Array]:
    """(wi, pdf) with density p(wo, wi) (pbrt-v4's SampleHenyeyGreenstein)."""
    g = jnp.clip(g, -0.99, 0.99)
    small = jnp.abs(g) < 1e-3
    gs = jnp.where(small, 1.0, g)
    sq = (1.0 - gs * gs) / (1.0 + gs - 2.0 * gs * u1)
    cos = jnp.where(small, 1.0 - 2.0 * u1, -1.0 / (2.0 * gs) * (1.0 + gs * gs - sq * sq))
    cos = jnp.clip(cos, -1.0, 1.0)
    sin = jnp.sqrt(jnp.maximum(1.0 - cos * cos, 0.0))
    phi = 2.0 * jnp.pi * u2
    s, t = coordinate_system(wo)
    wi = s * (sin * jnp.cos(phi)) + t * (sin * jnp.sin(phi)) + wo * cos
    return wi, hg(cos, g)


# --- the two interfaces ---------------------------------------------------------------------------

class Scatter(NamedTuple):
    wi: V3
    f: V3          # the interface's f (no cosine)
    pdf: Array     # its sampling density (1 for a Dirac mirror, whose f carries 1 / cos)
    valid: Array
    transmitted: Array


def coating(mp: MaterialParams) -> MaterialParams:
    """The top interface as jgi's rough dielectric (untinted, GGX)."""
    one = _ones(mp.alpha_u)
    return mp._replace(ks=one, kt=None, distribution=GGX)


def _coating_frame(top: MaterialParams, wo: V3):
    """(whether wo is below, i.e. inside the slab; wo mirrored to z > 0; eta seen from wo)."""
    below = wo.z < 0
    return below, _flipz(wo, below), jnp.where(below, 1.0 / top.ior, top.ior)


def coating_eval(top: MaterialParams, wo: V3, wi: V3, mode: int) -> tuple[Array, Array, Array]:
    """(f, pdf, pdf of wi's lobe alone) of the coating for wo on either side (pbrt's
    DielectricBxDF: the outside above, wo.z < 0 seen from inside the slab)."""
    below, wo_l, eta = _coating_frame(top, wo)
    wi_l = _flipz(wi, below)
    ok = (wo_l.z > 0) & (wi_l.z != 0)
    f, pdf, pdf_lobe = roughdielectric.evaluate_lobes(top, wo_l, wi_l, eta, ok, mode)
    return f.x, pdf, pdf_lobe


def coating_sample(top: MaterialParams, wo: V3, uc: Array, u1: Array, u2: Array, mode: int,
                   lobe: int) -> Scatter:
    """A direction from the coating: both lobes (``ALL``, reflection with probability F), or
    one (pbrt's sampleFlags: ``REFLECTION`` or ``TRANSMISSION``, whose pdf is then that of the
    lobe alone); invalid where the lobe cannot be taken (total internal reflection for
    ``TRANSMISSION``)."""
    below, wo_l, eta = _coating_frame(top, wo)
    u_lobe = {ALL: uc, REFLECTION: jnp.full_like(uc, -1.0), TRANSMISSION: jnp.full_like(uc, 2.0)}
    wi_l = roughdielectric.sample_direction(top, wo_l, eta, u_lobe[lobe], u1, u2)
    out = {ALL: wi_l.z != 0, REFLECTION: wi_l.z > 0, TRANSMISSION: wi_l.z < 0}[lobe]
    ok = out & (wo_l.z > 0)
    f, pdf, pdf_lobe = roughdielectric.evaluate_lobes(top, wo_l, wi_l, eta, ok, mode)
    p = pdf if lobe == ALL else pdf_lobe
    valid = ok & (p > 0) & (f.x > 0)
    return Scatter(_flipz(wi_l, below), _ones(p) * f.x, p, valid, wi_l.z < 0)


def _conductor(mp: MaterialParams) -> MaterialParams:
    """The base conductor as jgi's rough conductor: index relative to the coating's medium."""
    lay = mp.layer
    inv = 1.0 / mp.ior
    return mp._replace(ks=_ones(mp.alpha_u), eta=mp.eta * inv, k=mp.k * inv,
                       alpha_u=lay.base_alpha_u, alpha_v=lay.base_alpha_v, distribution=GGX)


def _base_smooth(mp: MaterialParams) -> Array:
    lay = mp.layer
    return ((mp.kind == COATED_CONDUCTOR)
            & (jnp.maximum(lay.base_alpha_u, lay.base_alpha_v) < SMOOTH_ALPHA))


def base_eval(kinds, mp: MaterialParams, wo: V3, wi: V3) -> tuple[V3, Array]:
    """(f, pdf) of the base, both directions above it (z > 0); 0 for a smooth conductor."""
    ok = (wo.z > 0) & (wi.z > 0)
    zero = jnp.zeros_like(wo.z)
    f, pdf = V3(zero, zero, zero), zero
    if COATED_DIFFUSE in kinds:
        sel = mp.kind == COATED_DIFFUSE
        f = where(sel, mp.kd * np.float32(1.0 / np.pi), f)
        pdf = jnp.where(sel, warps.pdf_cosine_hemisphere(jnp.maximum(wi.z, 0.0)), pdf)
    if COATED_CONDUCTOR in kinds:
        sel = (mp.kind == COATED_CONDUCTOR) & ~_base_smooth(mp)
        f_c, pdf_c = roughconductor.evaluate(_conductor(mp), wo, wi, ok)
        f, pdf = where(sel, f_c, f), jnp.where(sel, pdf_c, pdf)
    return where(ok, f, V3(zero, zero, zero)), jnp.where(ok, pdf, 0.0)


def base_sample(kinds, mp: MaterialParams, wo: V3, u1: Array, u2: Array) -> Scatter:
    """A direction from the base (wo above it): cosine-weighted for the diffuse base, the
    conductor's microfacet sampler, or the smooth conductor's mirror direction (pdf 1, f =
    F / cos, pbrt's specular convention)."""
    zero = jnp.zeros_like(wo.z)
    wi = warps.sample_cosine_hemisphere(u1, u2)
    if COATED_CONDUCTOR in kinds:
        cmp = _conductor(mp)
        smooth = _base_smooth(mp)
        conductor = mp.kind == COATED_CONDUCTOR
        mirror = V3(-wo.x, -wo.y, wo.z)
        wi = where(conductor, where(smooth, mirror, roughconductor.sample_direction(
            cmp, wo, u1, u2)), wi)
    f, pdf = base_eval(kinds, mp, wo, wi)
    if COATED_CONDUCTOR in kinds:
        cos = jnp.maximum(wo.z, 0.0)
        f_mirror = fresnel_conductor_rgb(cos, cmp.eta, cmp.k) * _safe_div(1.0, cos)
        f = where(smooth, f_mirror, f)
        pdf = jnp.where(smooth, 1.0, pdf)
    valid = (wo.z > 0) & (wi.z > 0) & (pdf > 0) & (_max3(f) > 0)
    return Scatter(wi, f, pdf, valid, zero > 0)


# --- the estimators ---------------------------------------------------------------------------------

def _walk_seeds(seed: Array, s: int) -> Array:
    return _mix(seed ^ np.uint32((0x68BC21EB * (s + 1)) & 0xFFFFFFFF))


def f_estimate(kinds, mp: MaterialParams, wo: V3, wi: V3, seed: Array, mode: int) -> V3:
    """An unbiased estimate of f(wo, wi) (pbrt-v4's LayeredBxDF::f), local directions with
    wo.z > 0 and wi.z > 0 (the caller masks the rest)."""
    lay = mp.layer
    top = coating(mp)
    adjoint = IMPORTANCE if mode == RADIANCE else RADIANCE
    zero = jnp.zeros_like(wo.z)
    Z = V3(zero, zero, zero)
    thick = jnp.maximum(lay.thickness, _FLT_MIN)
    medium = _max3(lay.albedo) > 0
    base_specular = _base_smooth(mp) if COATED_CONDUCTOR in kinds else zero > 0
    f_top, _, _ = coating_eval(top, wo, wi, mode)
    total = Z
    for s in range(lay.samples_bound):
        sd = _walk_seeds(seed, s)
        wos = coating_sample(top, wo, uniform(sd, 0), uniform(sd, 1), uniform(sd, 2), mode,
                             TRANSMISSION)
        wis = coating_sample(top, wi, uniform(sd, 3), uniform(sd, 4), uniform(sd, 5), adjoint,
                             TRANSMISSION)
        start = (s < lay.samples) & wos.valid & wis.valid
        wis_weight = _safe_div(wis.f.x, wis.pdf)   # the light arriving through the coating
        beta0 = wos.f * _safe_div(jnp.abs(wos.wi.z), wos.pdf)

        def step(depth, state, sd=sd, wis=wis, wis_weight=wis_weight):
            acc, beta, w, z, alive = state
            r = lambda slot: uniform(sd, 8 + depth * _SLOTS + slot)  # noqa: E731
            alive = alive & (depth < lay.max_depth)
            # Russian roulette
            b = _max3(beta)
            rr = alive & (depth > 3) & (b < 0.25)
            q = jnp.maximum(0.0, 1.0 - b)
            alive = alive & ~(rr & (r(0) < q))
            beta = where(rr & alive, beta * _safe_div(1.0, 1.0 - q), beta)
            # to the other interface (no medium), or to a scattering event in the medium
            z_next = jnp.where(z == thick, 0.0, thick)
            beta_next = beta * transmittance(thick, w)
            interface = alive
            if lay.has_medium:
                dz = -jnp.log1p(-r(1)) * jnp.abs(w.z)
                zp = jnp.where(w.z > 0, z + dz, z - dz)
                moved = zp != z
                inside = medium & moved & (0 < zp) & (zp < thick)
                scat = alive & inside
                # next event through the coating along the presampled wis
                p_nee = hg(dot(w, wis.wi), lay.g)   # p(-w, -wis.wi)
                wt = power_heuristic(wis.pdf, p_nee)
                acc = acc + where(scat, beta * lay.albedo * (p_nee * wt * wis_weight
                                                             * transmittance(zp - thick, wis.wi)), Z)
                w_ps, p_ps = sample_hg(-w, lay.g, r(2), r(3))
                ps_ok = scat & (p_ps > 0) & (w_ps.z != 0)
                beta_s = beta * lay.albedo
                up = ps_ok & (w_ps.z > 0)
                f_exit, _, _ = coating_eval(top, -w_ps, wi, mode)
                _, _, p_wis = coating_eval(top, wi, -w_ps, adjoint)   # wis's density of it
                wt = power_heuristic(p_ps, p_wis)
                acc = acc + where(up, beta_s * (transmittance(zp - thick, w_ps) * f_exit * wt), Z)
                beta = where(ps_ok, beta_s, beta)
                w = where(ps_ok, w_ps, w)
                z = jnp.where(ps_ok, zp, z)
                # a medium lane that leaves the slab reaches the clamped interface unattenuated
                interface = alive & jnp.where(medium, moved & ~inside, True)
                z_next = jnp.where(medium, jnp.clip(zp, 0.0, thick), z_next)
                beta_next = where(medium, beta, beta_next)
            at_top = z_next == thick
            # the coating's internal reflection (the exit interface)
            bt = coating_sample(top, -w, r(4), r(5), r(6), mode, REFLECTION)
            # the base: next event through the coating along wis, then a sampled direction
            # whose exit through the coating is evaluated (MIS between the two)
            f_b, pdf_b = base_eval(kinds, mp, -w, -wis.wi)
            wt = jnp.where(base_specular, 1.0, power_heuristic(wis.pdf, pdf_b))
            nee = beta_next * f_b * (jnp.abs(wis.wi.z) * wt * transmittance(thick, wis.wi)
                                     * wis_weight)
            bb = base_sample(kinds, mp, -w, r(5), r(6))
            beta_b = beta_next * bb.f * _safe_div(jnp.abs(bb.wi.z), bb.pdf)
            f_exit, _, _ = coating_eval(top, -bb.wi, wi, mode)
            _, _, p_wis = coating_eval(top, wi, -bb.wi, adjoint)   # wis's density of -bb.wi
            wt = jnp.where(base_specular, 1.0, power_heuristic(bb.pdf, p_wis))
            exit_b = beta_b * (transmittance(thick, bb.wi) * f_exit * wt)
            at_base = interface & ~at_top
            acc = acc + where(at_base, nee, Z)
            acc = acc + where(at_base & bb.valid, exit_b, Z)
            beta_t = beta_next * bt.f * _safe_div(jnp.abs(bt.wi.z), bt.pdf)
            ok = jnp.where(at_top, bt.valid, bb.valid)
            beta = where(interface, where(at_top, beta_t, beta_b), beta)
            w = where(interface, where(at_top, bt.wi, bb.wi), w)
            z = jnp.where(interface, z_next, z)
            alive = alive & (~interface | ok)
            return acc, beta, w, z, alive

        state = (Z, beta0, wos.wi, thick, start)
        acc = jax.lax.fori_loop(0, lay.depth_bound, step, state)[0]
        total = total + acc
    n = jnp.maximum(lay.samples, 1).astype(jnp.float32)
    return V3(*(f_top + c / n for c in total))


def sample_walk(kinds, mp: MaterialParams, wo: V3, uc: Array, u1: Array, u2: Array,
                mode: int) -> tuple[V3, V3, Array]:
    """(wi, weight f cos / pdf, valid) by pbrt-v4's LayeredBxDF::Sample_f (local, wo.z > 0):
    the coating's sample, then, for a transmission, the random walk through the slab until a
    sample leaves through the coating."""
    lay = mp.layer
    top = coating(mp)
    (wo,) = _broadcast(wo, V3(uc, u1, u2))[:1]
    zero = jnp.zeros_like(wo.z)
    Z = V3(zero, zero, zero)
    thick = jnp.maximum(lay.thickness, _FLT_MIN)
    medium = _max3(lay.albedo) > 0
    b0 = coating_sample(top, wo, uc, u1, u2, mode, ALL)
    reflected = b0.valid & ~b0.transmitted
    w0 = b0.f * _safe_div(jnp.abs(b0.wi.z), b0.pdf)
    sd = seed_of(wo.x, wo.y, wo.z, uc, u1, u2)

    def step(depth, state):
        # beta = f / pdf of the walk so far (pbrt keeps f and pdf apart; their products
        # overflow float32 within a few bounces off sharp lobes, and only the ratio and
        # Russian roulette's rrBeta = max(f) / pdf = max(beta) are used)
        beta, w, z, alive, out_w, out_weight, done = state
        r = lambda slot: uniform(sd, depth * _SLOTS + slot)  # noqa: E731
        alive = alive & (depth < lay.max_depth)
        rr_beta = _max3(beta)
        rr = alive & (depth > 3) & (rr_beta < 0.25)
        q = jnp.maximum(0.0, 1.0 - rr_beta)
        alive = alive & ~(rr & (r(0) < q)) & (w.z != 0)
        beta = where(rr & alive, beta * _safe_div(1.0, 1.0 - q), beta)
        z_next = jnp.where(z == thick, 0.0, thick)
        beta_next = beta * transmittance(thick, w)
        interface = alive
        if lay.has_medium:
            dz = -jnp.log1p(-r(1)) * jnp.abs(w.z)
            zp = jnp.where(w.z > 0, z + dz, z - dz)
            moved = zp != z
            inside = medium & moved & (0 < zp) & (zp < thick)
            w_ps, p_ps = sample_hg(-w, lay.g, r(2), r(3))
            ps_ok = alive & inside & (p_ps > 0) & (w_ps.z != 0)
            beta = where(ps_ok, beta * lay.albedo, beta)   # p / pdf = 1
            w = where(ps_ok, w_ps, w)
            z = jnp.where(ps_ok, zp, z)
            alive = alive & ~(medium & (~moved | (inside & ~ps_ok)))
            interface = alive & ~(medium & inside)
            z_next = jnp.where(medium, jnp.clip(zp, 0.0, thick), z_next)
            beta_next = where(medium, beta, beta_next)
        at_top = z_next == thick
        bt = coating_sample(top, -w, r(4), r(5), r(6), mode, ALL)
        bb = base_sample(kinds, mp, -w, r(5), r(6))
        bs = Scatter(*(where(at_top, a, b) if isinstance(a, V3) else jnp.where(at_top, a, b)
                       for a, b in zip(bt, bb)))
        alive = alive & (~interface | bs.valid)
        go = interface & alive
        beta_new = beta_next * bs.f * _safe_div(jnp.abs(bs.wi.z), bs.pdf)
        leaves = go & at_top & bs.transmitted
        out_w = where(leaves, bs.wi, out_w)
        out_weight = where(leaves, beta_new, out_weight)
        done = done | leaves
        alive = alive & ~leaves
        beta = where(go, beta_new, beta)
        w = where(go, bs.wi, w)
        z = jnp.where(go, z_next, z)
        return beta, w, z, alive, out_w, out_weight, done

    state = (w0, b0.wi, thick, b0.valid & b0.transmitted, b0.wi, Z, zero > 0)
    _, _, _, _, out_w, out_weight, done = jax.lax.fori_loop(0, lay.depth_bound, step, state)
    wi = where(reflected, b0.wi, out_w)
    weight = where(reflected, w0, out_weight)
    valid = (reflected | done) & (wi.z > 0)
    return wi, where(valid, weight, Z), valid


def pdf_estimate(kinds, mp: MaterialParams, wo: V3, wi: V3, seed: Array, mode: int) -> Array:
    """pbrt-v4's LayeredBxDF::PDF for wi on wo's side (local, both z > 0): the coating's
    reflection density, plus an MIS estimate of the transmit-reflect-transmit density (the
    base's density between two presampled coating transmissions, and the coating's exit
    density after a base sample), mixed with the uniform sphere density."""
    lay = mp.layer
    top = coating(mp)
    adjoint = IMPORTANCE if mode == RADIANCE else RADIANCE
    base_specular = _base_smooth(mp) if COATED_CONDUCTOR in kinds else jnp.zeros(wo.z.shape, bool)
    _, _, p_refl = coating_eval(top, wo, wi, mode)
    n = jnp.maximum(lay.samples, 1).astype(jnp.float32)
    total = p_refl * n
    for s in range(lay.samples_bound):
        sd = _walk_seeds(seed, s)
        r = lambda slot, sd=sd: uniform(sd, slot)  # noqa: E731
        wos = coating_sample(top, wo, r(0), r(1), r(2), mode, TRANSMISSION)
        wis = coating_sample(top, wi, r(3), r(4), r(5), adjoint, TRANSMISSION)
        ok = (s < lay.samples) & wos.valid & wis.valid
        rs = base_sample(kinds, mp, -wos.wi, r(6), r(7))
        ok_r = ok & rs.valid
        _, p_exit, _ = coating_eval(top, -rs.wi, wi, mode)
        _, p_base = base_eval(kinds, mp, -wos.wi, -wis.wi)
        mis = (power_heuristic(wis.pdf, p_base) * p_base
               + power_heuristic(rs.pdf, p_exit) * p_exit)
        total = total + jnp.where(ok_r, jnp.where(base_specular, p_exit, mis), 0.0)
    return UNIFORM_MIX / (4.0 * jnp.pi) + (1.0 - UNIFORM_MIX) * total / n


# --- what the dispatch calls ------------------------------------------------------------------------

def _broadcast(*vs: V3) -> list[V3]:
    """The directions' components broadcast to one shape (the walks' loop carries need it:
    density estimates pass wo as [N, 1] beside wi as [N, K])."""
    shape = jnp.broadcast_shapes(*(jnp.shape(c) for v in vs for c in v))
    return [V3(*(jnp.broadcast_to(c, shape) for c in v)) for v in vs]


_F_SALT, _PDF_SALT = 0x1B873593, 0xCC9E2D51


def evaluate(kinds, mp: MaterialParams, wo: V3, wi: V3, mode: int) -> tuple[V3, Array]:
    """(f estimate, pdf estimate) for local directions; 0 unless both are lit on one side.
    The streams are seeded by the directions (f: wo then wi; pdf: wi then wo, as pbrt)."""
    wo, wi = _broadcast(wo, wi)
    same = lit(wo.z) & lit(wi.z)
    up = lambda v: V3(v.x, v.y, jnp.where(same, v.z, 1.0))  # noqa: E731
    wo_u, wi_u = up(wo), up(wi)
    sf = seed_of(wo.x, wo.y, wo.z, wi.x, wi.y, wi.z) ^ np.uint32(_F_SALT)
    sp = seed_of(wi.x, wi.y, wi.z, wo.x, wo.y, wo.z) ^ np.uint32(_PDF_SALT)
    f = f_estimate(kinds, mp, wo_u, wi_u, sf, mode)
    pdf = pdf_estimate(kinds, mp, wo_u, wi_u, sp, mode)
    zero = jnp.zeros_like(pdf)
    return where(same, f, V3(zero, zero, zero)), jnp.where(same, pdf, 0.0)


def pdf(kinds, mp: MaterialParams, wo: V3, wi: V3, mode: int) -> Array:
    """The pdf estimate alone (what a sample's MIS weight needs), seeded as :func:`evaluate`'s."""
    wo, wi = _broadcast(wo, wi)
    same = lit(wo.z) & lit(wi.z)
    up = lambda v: V3(v.x, v.y, jnp.where(same, v.z, 1.0))  # noqa: E731
    sp = seed_of(wi.x, wi.y, wi.z, wo.x, wo.y, wo.z) ^ np.uint32(_PDF_SALT)
    return jnp.where(same, pdf_estimate(kinds, mp, up(wo), up(wi), sp, mode), 0.0)
