"""Lights (:mod:`jgi.physics.lights`) on numpy inputs, the test emitters, and float64 ray casts
independent of jgi that turn ``pdf_li`` into a density over directions; used by
tests/test_lights.py and the paper's table (paper/chi2_table.py)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jgi.analysis.chi2 import SphereDomain, bucket
from jgi.core.vec import V3
from jgi.physics import lights as LT
from jgi.scene import SceneBuilder

N = 1 << 18  # samples per test unless told
L_RGB = np.array([4.0, 2.0, 1.0])


def build(add) -> LT.Lights:
    """The lights of a scene to which ``add(builder)`` adds the emitters."""
    b = SceneBuilder(name="lights")
    b.material("m", "diffuse", diffuse=0.5)
    b.sphere((0.0, 0.0, 0.0), 2.0, "m")  # sets the bounding sphere of directional/env lights
    add(b)
    b.camera(position=(0, 0, 8), look_at=(0, 0, 0), width=4, height=4)
    return b.build().lights


def _v3(a, shape):
    a = jnp.broadcast_to(jnp.asarray(a, jnp.float32), shape + (3,))
    return V3(a[..., 0], a[..., 1], a[..., 2])


@jax.jit
def sample_li_from_uniforms(lights, x, u):
    """``LT.sample_li`` from x with the uniforms u [3, ...], as a dict of arrays."""
    s = LT.sample_li(lights, _v3(x, u.shape[1:]), u[0], u[1], u[2])
    return dict(wi=s.wi.stack(), dist=s.dist, Li=s.Li.stack(), pdf=s.pdf, delta=s.delta,
                valid=s.valid)


@jax.jit
def pdf_li(lights, k, x, y, n_y):
    """``LT.pdf_li`` of element k for points y [..., 3] with normals n_y, seen from x."""
    shape = y.shape[:-1]
    return LT.pdf_li(lights, jnp.broadcast_to(k, shape), _v3(x, shape), _v3(y, shape),
                     _v3(n_y, shape))


@jax.jit
def emitted(lights, k, n_y, wo):
    """``LT.emitted`` of element k towards wo [..., 3]."""
    shape = wo.shape[:-1]
    return LT.emitted(lights, jnp.broadcast_to(k, shape), _v3(n_y, shape), _v3(wo, shape)).stack()


@jax.jit
def _sample_emission(lights, u):
    e = LT.sample_emission(lights, u[0], u[1], u[2], u[3], u[4])
    return dict(p=e.p.stack(), n=e.n.stack(), d=e.d.stack(), weight=e.weight.stack(),
                pdf_pos=e.pdf_pos, pdf_dir=e.pdf_dir, delta_pos=e.delta_pos,
                delta_dir=e.delta_dir, element=e.element)


def uniforms(seed, k, n=N):
    """k rows of n float32 uniforms from a fixed-seed numpy generator."""
    return np.random.default_rng(seed).random((k, n), dtype=np.float32)


def _numpy(out):
    # float64 copies: numpy sums float32 columns naively (0.2% off over 2e5 rows)
    return {k: np.asarray(v, np.float64) if np.asarray(v).dtype == np.float32 else np.asarray(v)
            for k, v in out.items()}


def sample_li(lights, x, seed, n=N):
    """n next-event samples from x (float32 columns as float64)."""
    u = uniforms(seed, 3, bucket(n))  # padded: few sizes, few compilations
    return {k: v[:n] for k, v in _numpy(sample_li_from_uniforms(lights, np.float32(x), u)).items()}


def sample_emission(lights, seed, n=N):
    """n emission samples (float32 columns as float64)."""
    return {k: v[:n]
            for k, v in _numpy(_sample_emission(lights, uniforms(seed, 5, bucket(n)))).items()}


def normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def local_frames(n):
    """Per-row orthonormal frames (s, t, z) about the unit vectors n [N, 3] (numpy, float64)."""
    z = normalize(np.asarray(n, np.float64))
    helper = np.where(np.abs(z[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    s_ = normalize(np.cross(helper, z))
    return s_, np.cross(z, s_), z


# --- float64 ray casts (independent of jgi) -------------------------------------------------------

def cast_parallelogram(x, w, p0, e1, e2, triangle=False):
    """(hit, y, n) of rays x + t w, t > 0, with p0 + a e1 + b e2 (a, b in [0,1], or a + b <= 1)."""
    n = normalize(np.cross(e1, e2))
    denom = w @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((p0 - x) @ n) / denom
    y = x + t[:, None] * w
    G = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
    ab = np.linalg.solve(G, np.stack([(y - p0) @ e1, (y - p0) @ e2]))
    a, b = ab
    inside = (a >= 0) & (b >= 0) & ((a + b <= 1) if triangle else ((a <= 1) & (b <= 1)))
    hit = np.isfinite(t) & (t > 0) & inside
    return hit, y, np.broadcast_to(n, y.shape)


def cast_sphere(x, w, c, r):
    """(hit, y, n) of rays x + t w, t > 0, with the sphere of centre c and radius r."""
    oc = x - c
    b = w @ oc
    disc = b * b - (oc @ oc - r * r)
    t = -b - np.sqrt(np.maximum(disc, 0))
    hit = (disc >= 0) & (t > 0)
    y = x + t[:, None] * w
    return hit, y, normalize(y - c)


def direction_pdf(lights, k, x, cast):
    """pdf_li as a density over directions from x: cast each direction, evaluate at the hit."""
    def pdf(w):
        w = normalize(np.asarray(w, np.float64))
        hit, y, n = cast(np.asarray(x, float), w)
        p = np.asarray(pdf_li(lights, np.int32(k), np.float32(x),
                              np.float32(np.where(hit[:, None], y, 0)), np.float32(n)))
        return np.where(hit, p, 0.0)
    return pdf


# --- area lights seen from a reference point ------------------------------------------------------

X_REF = np.array([0.2, -0.1, 0.0])
N_REF = np.array([0.0, 0.0, 1.0])
QUAD = (np.array([-0.5, -0.3, 1.0]), np.array([0.0, 0.8, -0.1]), np.array([1.0, 0.0, 0.3]))
TRI = (np.array([-0.4, -0.2, 0.8]), np.array([0.9, 0.5, 1.1]), np.array([0.1, 0.7, 1.3]))


def quad_lights():
    """The quad QUAD (origin, edge, edge), emitting L_RGB towards X_REF."""
    return build(lambda b: b.quad(*QUAD, "m", emission=L_RGB))


def tri_lights():
    """The triangle TRI, given as (a, c, b) so that it emits L_RGB towards X_REF."""
    return build(lambda b: b.mesh(np.array(TRI)[[0, 2, 1]], [[0, 1, 2]], "m", emission=L_RGB))


def zoom_domain(x, points, n_a=24, n_phi=32):
    """Rings about the direction to the centroid, out to just past the farthest point."""
    d = normalize(np.asarray(points, float) - x)
    axis = normalize(d.mean(0))
    a_max = min(2.0, 1.05 * (1.0 - (d @ axis).min()))
    return SphereDomain(axis=axis, a_edges=np.linspace(0.0, a_max, n_a + 1), n_phi=n_phi)
