"""BSDF sampling and evaluation (:mod:`jgi.physics.bsdf`) on numpy inputs, all material kinds
through one compiled function, and a float64 Fresnel reference; used by tests/test_bsdf.py and
the paper's table (paper/chi2_table.py)."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jgi.analysis.chi2 import bucket
from jgi.core.vec import V3
from jgi.physics import bsdf as B
from jgi.scene import DIELECTRIC, DIFFUSE, MIRROR, PHONG

KINDS = (DIFFUSE, MIRROR, DIELECTRIC, PHONG)
N = 1 << 18  # samples per test unless told


def material(kind, kd=0.0, ks=0.0, n=1.0, ior=1.5):
    """A material as the tuple (kind, k_d, k_s, exponent, ior) of numpy float32 values."""
    return (np.int32(kind), np.broadcast_to(np.asarray(kd, np.float32), (3,)).copy(),
            np.broadcast_to(np.asarray(ks, np.float32), (3,)).copy(), np.float32(n),
            np.float32(ior))


def _params(mat, shape) -> B.MaterialParams:
    kind, kd, ks, n, ior = mat
    b = lambda x: jnp.broadcast_to(x, shape)
    return B.MaterialParams(b(kind), V3(b(kd[0]), b(kd[1]), b(kd[2])),
                            V3(b(ks[0]), b(ks[1]), b(ks[2])), b(n), b(ior))


def _v3(a, shape) -> V3:
    a = jnp.broadcast_to(jnp.asarray(a, jnp.float32), shape + (3,))
    return V3(a[..., 0], a[..., 1], a[..., 2])


@partial(jax.jit, static_argnames="mode")
def sample_from_uniforms(mat, n, wo, u, mode=B.RADIANCE):
    """``B.sample`` with the uniforms u [3, ...], and ``B.evaluate`` at the sampled directions."""
    shape = u.shape[1:]
    mp, n, wo = _params(mat, shape), _v3(n, shape), _v3(wo, shape)
    s = B.sample(KINDS, mp, n, wo, u[0], u[1], u[2], mode)
    f, pdf = B.evaluate(KINDS, mp, n, wo, s.wi)
    return dict(wi=s.wi.stack(), weight=s.weight.stack(), pdf=s.pdf, delta=s.delta,
                valid=s.valid, f=f.stack(), eval_pdf=pdf)


@jax.jit
def evaluate(mat, n, wo, wi):
    """(f, pdf) of ``B.evaluate`` for the directions wi [..., 3]."""
    shape = wi.shape[:-1]
    f, pdf = B.evaluate(KINDS, _params(mat, shape), _v3(n, shape), _v3(wo, shape),
                        _v3(wi, shape))
    return f.stack(), pdf


def sample(mat, n, wo, seed, count=N, mode=B.RADIANCE):
    """``count`` samples (computed in a padded batch: few sizes, few compilations)."""
    u = np.random.default_rng(seed).random((3, bucket(count)), dtype=np.float32)
    out = sample_from_uniforms(mat, np.float32(n), np.float32(wo), u, mode)
    return {k: np.asarray(v)[:count] for k, v in out.items()}


def fresnel_reference(cos_i, eta):
    """Unpolarised Fresnel reflectance in float64 (Born & Wolf), eta = eta_t / eta_i."""
    cos_i = np.asarray(cos_i, np.float64)
    sin2_t = (1.0 - cos_i ** 2) / eta ** 2
    tir = sin2_t >= 1.0
    cos_t = np.sqrt(np.where(tir, 0.0, 1.0 - sin2_t))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
        rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return np.where(tir, 1.0, 0.5 * (rs ** 2 + rp ** 2))
