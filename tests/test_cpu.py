"""Decisions do not depend on the processor, nor on jgi's CPU devices (jgi._xla).

Edge cases (a surface seen exactly edge-on, grazing within ``vec.EDGE_ON_COS``, zero pdfs, a ray
in a primitive's plane, a ray through an edge shared by two triangles) are decided here under
the flags the suite runs with, and in subprocesses under

* XLA's defaults: no jgi flags, no materialize, plain division (``JGI_NO_*``);
* a processor without AVX-512 (``--xla_cpu_max_isa=AVX2``);
* a processor without FMA or AVX2 (``--xla_cpu_max_isa=AVX``, Sandy Bridge class). XLA
  contracts a * b + c into one fused multiply-add wherever the CPU has FMA, so this is the
  configuration whose rounding differs most: an exactly perpendicular float32 pair has the dot
  product 0 there and +-7e-9 elsewhere.

Every decision must be the same bits in all of them, and equal to what the geometry says it is
(an edge-on surface scatters nothing, an in-plane ray misses, a shared edge is hit). Small
renders are compared too: bit for bit where FMA is kept (vector width alone changes nothing),
to float32 rounding without FMA or with plain division (see ``jgi._xla``, "What is
guaranteed")."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jgi
from jgi.core.vec import EDGE_ON_COS, V3
from jgi.physics import bsdf as B
from jgi.physics import geometry as G
from jgi.physics import lights as LT
from jgi.scene import DIELECTRIC, DIFFUSE, MIRROR, PHONG, SceneBuilder
from jgi.transport.subpath import pdf_emission_dir

ROOT = Path(__file__).resolve().parents[1]
f32 = np.float32

# --- the cases ------------------------------------------------------------------------------


def _perpendicular_pairs():
    """(n, w) pairs of float32 unit vectors (to rounding) whose exact dot product is 0: w swaps
    two of n's components, scaled by a power of two (exact), so no rounding enters the pair."""
    s34 = f32(math.sqrt(0.75))
    pairs = [((0, 0, 1), (1, 0, 0)), ((0.6, 0.8, 0), (-0.8, 0.6, 0)),
             ((0.3, 0.4, s34), (2 * f32(0.4), -2 * f32(0.3), 0)),
             ((s34, -0.3, 0.4), (0, 2 * f32(0.4), 2 * f32(0.3))),
             ((-0.4, s34, -0.3), (2 * f32(0.3), 0, -2 * f32(0.4)))]
    out = []
    for n, w in pairs:
        n, w = np.array(n, f32), np.array(w, f32)
        assert math.fsum(np.float64(n) * np.float64(w)) == 0.0  # exactly perpendicular
        out += [(n, w), (n, -w), (-n, w)]
    return out


EDGE_ON = _perpendicular_pairs()
Z = np.array([0, 0, 1], f32)
# grazing: inside the edge-on band (nothing scattered), and just outside it (scattered)
GRAZING_IN = [(Z, np.array([1.0, 0.0, c], f32)) for c in (1e-7, -1e-7, 5e-7)]
GRAZING_OUT = [(Z, np.array([1.0, 0.0, c], f32)) for c in (4e-6, -4e-6)]
# ordinary directions: the uniforms' edges (the concentric map's rim and centre) decide alike
_N = np.array([0.3, -0.5, 0.8], f32) / f32(np.linalg.norm([0.3, -0.5, 0.8]))
_T = np.array([0.6, 0.8, 0.0], f32)
ORDINARY = [(_N, _N), (Z, Z), (_N, (0.5 * _N + 0.866 * _T).astype(f32)), (-_N, _N)]
MATERIALS = [(DIFFUSE, 0.5, 0.0, 1.0, 1.5), (PHONG, 0.3, 0.6, 50.0, 1.5),
             (PHONG, 0.0, 0.0, 1.0, 1.5), (MIRROR, 0.0, 1.0, 1.0, 1.5),
             (DIELECTRIC, 0.0, 1.0, 1.0, 1.5), (DIELECTRIC, 0.0, 1.0, 1.0, 1.0)]
KINDS = (DIFFUSE, MIRROR, DIELECTRIC, PHONG)
# uniforms including the ends of [0, 1): the warps' edges (concentric centre, rim)
U_EDGES = np.array([0.0, 0.5, 0.25, 0.75, f32(1 - 2**-24)], f32)


def _uniforms():
    g = np.stack(np.meshgrid(U_EDGES, U_EDGES, U_EDGES, indexing="ij"), 0).reshape(3, -1)
    r = np.random.default_rng(7).random((3, 131), dtype=np.float32)
    return np.concatenate([g, r], 1)


def _bsdf_batch(pairs):
    """Every (material, pair, uniform) combination as flat float32 columns."""
    u = _uniforms()
    m, p, k = np.meshgrid(np.arange(len(MATERIALS)), np.arange(len(pairs)),
                          np.arange(u.shape[1]), indexing="ij")
    m, p, k = m.ravel(), p.ravel(), k.ravel()
    mat = np.array(MATERIALS, f32)[m]
    n = np.stack([pairs[i][0] for i in p]).astype(f32)
    wo = np.stack([pairs[i][1] for i in p]).astype(f32)
    return mat, n, wo, u[:, k]


@jax.jit
def _bsdf_decisions(mat, n, wo, u):
    v3 = lambda a: V3(a[:, 0], a[:, 1], a[:, 2])  # noqa: E731
    kd, ks = mat[:, 1], mat[:, 2]
    mp = B.MaterialParams(mat[:, 0].astype(jnp.int32), V3(kd, kd, kd), V3(ks, ks, ks),
                          mat[:, 3], mat[:, 4])
    out = {}
    for mode in (B.RADIANCE, B.IMPORTANCE):
        s = B.sample(KINDS, mp, v3(n), v3(wo), u[0], u[1], u[2], mode)
        f, pdf = B.evaluate(KINDS, mp, v3(n), v3(wo), s.wi)
        out[f"valid{mode}"] = s.valid
        out[f"delta{mode}"] = s.delta
        out[f"pdf_pos{mode}"] = s.pdf > 0
        out[f"weight_pos{mode}"] = s.weight.x > 0
        out[f"eval_pos{mode}"] = (pdf > 0) | (f.x > 0)
        out[f"finite{mode}"] = (jnp.isfinite(s.weight.x) & jnp.isfinite(s.pdf) & jnp.isfinite(pdf)
                                & jnp.isfinite(s.wi.x))
    # evaluated the other way round: wo at normal incidence, wi edge-on
    f, pdf = B.evaluate(KINDS, mp, v3(n), v3(n), v3(wo))
    out["eval_edge_wi"] = (pdf > 0) | (f.x > 0)
    return out


def _light_scene():
    b = SceneBuilder("edge_light")
    b.material("white", "diffuse", diffuse=(0.5, 0.5, 0.5))
    b.quad((-0.5, 1.0, -0.5), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), "white", emission=(1, 1, 1))
    b.camera(position=(0, 0, 3), look_at=(0, 0, 0), width=4, height=4)
    return b.build()


@jax.jit
def _light_decisions(lights, n, w):
    v3 = lambda a: V3(a[:, 0], a[:, 1], a[:, 2])  # noqa: E731
    k = jnp.zeros(n.shape[0], jnp.int32)
    return {"emitted": LT.emitted(lights, k, v3(n), v3(w)).x > 0,
            "pdf_emission_dir": pdf_emission_dir(lights, k, v3(n), v3(w)) > 0}


def _plane_scene(bvh=False):
    """A tilted quad, a tilted square of two triangles (shared diagonal) and a sphere; the
    triangles tested one by one, or through a BVH."""
    b = SceneBuilder("edge_planes", bvh=bvh)
    b.material("white", "diffuse", diffuse=(0.5, 0.5, 0.5))
    b.quad((-2.0, -0.3, 0.1), (0.8, 0.6, 0.0), (0.0, 0.0, 1.0), "white")
    v = np.array([[1.0, -0.2, 0.0], [2.0, 0.3, 0.2], [1.9, 0.4, 1.2], [0.9, -0.1, 1.0]])
    b.mesh(v, [[0, 1, 2], [0, 2, 3]], "white")
    b.sphere((0.0, 3.0, 0.0), 0.5, "white")
    b.camera(position=(0, 0, 6), look_at=(0, 0, 0), width=4, height=4)
    return b.build(), v


def _plane_rays():
    """(origins, directions, expected hit) for rays in the quad's and triangles' planes (miss),
    rays through the shared diagonal (hit), and rays grazing past (miss)."""
    _, v = _plane_scene()
    o, d, hit = [], [], []
    q0, qu, qv = np.array([-2.0, -0.3, 0.1]), np.array([0.8, 0.6, 0.0]), np.array([0, 0, 1.0])
    for a in np.linspace(0.1, 0.9, 5):        # in the quad's plane, along edge_v and diagonally
        o.append(q0 + a * qu - 0.5 * qv), d.append(qv), hit.append(False)
        o.append(q0 - 0.5 * (qu + qv)), d.append((qu + a * qv) / np.linalg.norm(qu + a * qv))
        hit.append(False)
    e1, e2 = v[1] - v[0], v[2] - v[0]
    normal = np.cross(e1, e2) / np.linalg.norm(np.cross(e1, e2))
    for a in np.linspace(0.1, 0.9, 5):
        p = v[0] + a * (v[2] - v[0])           # on the shared diagonal
        for tilt in (normal, normal + 0.3 * e1, normal - 0.2 * e2):
            dd = -tilt / np.linalg.norm(tilt)
            o.append(p - 2.0 * dd), d.append(dd), hit.append(True)
        inplane = (e1 - e2 * a) / np.linalg.norm(e1 - e2 * a)  # in the triangles' plane
        o.append(p - 3.0 * inplane), d.append(inplane), hit.append(False)
    o = np.array(o, f32)
    d = np.array(d, f32)
    return o, d / np.linalg.norm(d, axis=1, keepdims=True).astype(f32), np.array(hit)


@jax.jit
def _hit_decisions(scene, o, d):
    v3 = lambda a: V3(a[:, 0], a[:, 1], a[:, 2])  # noqa: E731
    h = G.intersect(scene, v3(o), v3(d))
    return {"hit": h.valid,
            "occluded": G.occluded(scene, v3(o), v3(d), jnp.full(o.shape[0], 100.0))}


# Veach's Phong plates (the most rounding-sensitive kernel); mirror and glass decisions are the
# BSDF cases above, light paths' the emission cases (the caustic Cornell box's render, left out
# for the suite's time, compiled once more in each process)
RENDERS = [("veach_plates", "pt", {})]


def decisions() -> dict[str, np.ndarray]:
    """Every decision of the cases above, and the small renders, as numpy arrays."""
    out = {}
    # every case in one batch, so that each kernel compiles once a process (batches of four
    # shapes compiled four times: 4.5 s of the BSDF's against about 1.3 s, in each of the four
    # processes), then split by case
    sets = (("edge_on", EDGE_ON), ("grazing_in", GRAZING_IN), ("grazing_out", GRAZING_OUT),
            ("ordinary", ORDINARY))
    every = [pair for _, pairs in sets for pair in pairs]
    bsdf = {k: np.asarray(v).reshape(len(MATERIALS), len(every), -1)
            for k, v in _bsdf_decisions(*_bsdf_batch(every)).items()}
    n = np.stack([p[0] for p in every]).astype(f32)
    w = np.stack([p[1] for p in every]).astype(f32)
    light = {k: np.asarray(v) for k, v in _light_decisions(_light_scene().lights, n, w).items()}
    start = 0
    for label, pairs in sets:
        cases = slice(start, start + len(pairs))
        start += len(pairs)
        for k, v in bsdf.items():   # (material, pair, uniform), flat as _bsdf_batch orders them
            out[f"bsdf_{label}_{k}"] = v[:, cases].ravel()
        for k, v in light.items():
            out[f"light_{label}_{k}"] = v[cases]
    o, d, _ = _plane_rays()
    for bvh in (False, True):
        for k, v in _hit_decisions(_plane_scene(bvh)[0], o, d).items():
            out[f"ray_{k}_bvh{int(bvh)}"] = np.asarray(v)
    for name, est, params in RENDERS:
        out[f"image_{name}_{est}"] = np.asarray(
            jgi.render(jgi.load_scene(name, resolution=8), est, spp=4, seed=3, **params))
    return out


# --- the tests ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def here():
    return decisions()


def test_edge_on_scatters_nothing(here):
    """An exactly edge-on surface, or one within the edge-on band, scatters nothing, for every
    material and both transport modes; values stay finite."""
    for label in ("edge_on", "grazing_in"):
        for mode in (B.RADIANCE, B.IMPORTANCE):
            assert not here[f"bsdf_{label}_valid{mode}"].any(), (label, mode)
            assert not here[f"bsdf_{label}_weight_pos{mode}"].any(), (label, mode)
            assert not here[f"bsdf_{label}_eval_pos{mode}"].any(), (label, mode)
            assert here[f"bsdf_{label}_finite{mode}"].all(), (label, mode)
        assert not here[f"bsdf_{label}_eval_edge_wi"].any(), label
        assert not here[f"light_{label}_emitted"].any(), label
        assert not here[f"light_{label}_pdf_emission_dir"].any(), label


def test_grazing_outside_the_band_scatters(here):
    """Just outside the band the surface scatters as usual (the band is not wider than it says):
    every material but the black Phong one has valid samples from above and from below."""
    for mode in (B.RADIANCE, B.IMPORTANCE):
        valid = here[f"bsdf_grazing_out_valid{mode}"].reshape(len(MATERIALS), len(GRAZING_OUT), -1)
        assert here[f"bsdf_grazing_out_finite{mode}"].all()
        for m, mat in enumerate(MATERIALS):
            if mat[1] + mat[2] > 0:
                assert valid[m].any(axis=1).all(), (mat, mode)


def test_rays_in_a_plane_miss_and_shared_edges_are_hit(here):
    _, _, expected = _plane_rays()
    for bvh in (0, 1):
        np.testing.assert_array_equal(here[f"ray_hit_bvh{bvh}"], expected)
        np.testing.assert_array_equal(here[f"ray_occluded_bvh{bvh}"], expected)


def test_edge_on_threshold_exceeds_dot_rounding():
    """The band is wider than the rounding error of a dot product of unit vectors (3 roundings,
    and whatever FMA contraction does inside them) by a factor of 5."""
    assert EDGE_ON_COS >= 5 * 3 * 2.0**-24


ROUNDING_RTOL = 2e-4   # measured up to 7e-5 (Veach's plates: Phong's exp(n log cos) times n)
CONFIGS = {
    # the flags of jgi._xla off, and its devices: XLA's defaults
    "xla_defaults": dict(JGI_NO_XLA_FLAGS="1", JGI_NO_MATERIALIZE="1", JGI_NO_FAST_DIVISION="1"),
    "no_avx512": dict(XLA_ISA="AVX2"),
    "no_fma": dict(XLA_ISA="AVX"),
}


def _host_has_avx512() -> bool:
    try:
        return " avx512f" in Path("/proc/cpuinfo").read_text()
    except OSError:
        return True        # unknown: run the comparison


# Without AVX-512 on the host, XLA already generates AVX2 code here: the no_avx512 child would
# compile and run the same program again (a vacuous comparison, and a core's worth of the
# suite's time, 3 children running beside the other pytest worker).
APPLICABLE = [name for name in CONFIGS if name != "no_avx512" or _host_has_avx512()]


def _child(name: str, out: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    conf = dict(CONFIGS[name])
    isa = conf.pop("XLA_ISA", None)
    # the child starts from the suite's own XLA_FLAGS (jgi's flags with the suite's threshold)
    flags = os.environ.get("XLA_FLAGS", "").split()
    if conf.get("JGI_NO_XLA_FLAGS"):
        flags = []
    if isa:
        flags.append(f"--xla_cpu_max_isa={isa}")
    env.update(conf, XLA_FLAGS=" ".join(flags))
    script = textwrap.dedent(f"""
        import numpy as np
        from tests.test_cpu import decisions
        np.savez({str(out)!r}, **decisions())
    """)
    return subprocess.Popen([sys.executable, "-c", script], env=env, cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.fixture(scope="module")
def others(tmp_path_factory):
    d = tmp_path_factory.mktemp("cpu")
    procs = {name: (_child(name, d / f"{name}.npz"), d / f"{name}.npz") for name in APPLICABLE}
    out = {}
    for name, (p, path) in procs.items():
        log, _ = p.communicate(timeout=900)
        assert p.returncode == 0, f"{name}:\n{log[-4000:]}"
        out[name] = dict(np.load(path))
    return out


def _skip_if_not_run(others, name):
    if name not in others:
        pytest.skip(f"{name}: the host has no AVX-512, so its own code is that configuration's")


@pytest.mark.parametrize("name", list(CONFIGS))
def test_decisions_are_the_same_on_every_cpu(here, others, name):
    _skip_if_not_run(others, name)
    there = others[name]
    assert set(there) == set(here)
    for k in here:
        if k.startswith("image_"):
            continue
        np.testing.assert_array_equal(there[k], here[k], err_msg=f"{name}: {k}")


@pytest.mark.parametrize("name", list(CONFIGS))
def test_images_agree_to_float_rounding(here, others, name):
    _skip_if_not_run(others, name)
    for k in here:
        if not k.startswith("image_"):
            continue
        a, b = here[k], others[name][k]
        assert np.isfinite(b).all(), (name, k)
        if name == "no_avx512":   # same FMA contraction, another vector width: the same bits
            assert np.array_equal(a, b), (name, k, np.abs(a - b).max())
            continue
        # no FMA, or plain division: each path to rounding (amplified where f is steep); a path
        # that passes within a rounding of a decision boundary may go the other way (measured
        # at 32^2, 16 spp: 0-5 pixels in 1024 per render, photon mapping 46), so nearly all
        # pixels, and the image mean, agree
        close = np.isclose(b, a, rtol=ROUNDING_RTOL, atol=1e-6).all(-1)
        assert close.mean() >= 0.97, (name, k, close.mean())
        assert abs(b.mean() - a.mean()) <= 0.01 * a.mean(), (name, k, a.mean(), b.mean())
