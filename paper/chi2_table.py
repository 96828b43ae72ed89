"""Chi-square goodness of fit of every sampling routine, as a table (the paper's validation).

    python -m paper.chi2_table [--samples 262144] [--alpha 0.01] [--out runs/chi2]

The cases are the test suite's: this script reuses the samplers, reference densities (float64 ray
casts for the lights) and grids that the tests share through :mod:`tests.support`, and
:mod:`jgi.analysis.chi2` for the statistic, but reports the statistic and p-value of each routine
instead of asserting. Each routine is one hypothesis; the family is judged at ``--alpha`` with
Bonferroni's correction (each p-value against alpha / m for m routines). Discrete choices (the
dielectric's Fresnel split, light selection in proportion to power) are chi-square tests over
their categories; the mirror, whose sample is a single direction, is checked exactly (largest
angle from the reflection).

Writes chi2.json; returns the same dictionary.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jgi.analysis.chi2 import PlaneDomain, SphereDomain, chi2_test, pearson
from jgi.core import warps
from jgi.physics import bsdf as B
from jgi.physics import lights as LT
from jgi.scene import DIELECTRIC, DIFFUSE, MIRROR, PHONG
from tests.support import bsdf_samplers, camera_samplers
from tests.support.directions import NORMAL, direction, reflect_np
from tests.support.light_samplers import (
    L_RGB,
    QUAD,
    TRI,
    X_REF,
    build,
    cast_parallelogram,
    cast_sphere,
    direction_pdf,
    local_frames,
    normalize,
    pdf_li,
    quad_lights,
    sample_emission,
    sample_li,
    tri_lights,
    zoom_domain,
)
from tests.support.light_samplers import uniforms as light_uniforms
from tests.support.warp_samplers import (
    f32,
    phong_domain,
    sample_cone,
    sample_cosine,
    sample_disc,
    sample_phong,
    sample_sphere,
    sample_triangle,
    stack,
    uniforms,
    z_of,
)


def _cells(domain) -> int:
    return (len(domain.a_edges) - 1) * (len(domain.b_edges) - 1)


# --- cases: each returns (jgi.analysis.chi2.Result, number of grid cells or categories) -----------

def warp_cases(n):
    def cosine():
        d = stack(sample_cosine(*uniforms(1, n)))
        dom = SphereDomain()
        return chi2_test(d, lambda p: warps.pdf_cosine_hemisphere(z_of(p)), dom), _cells(dom)

    def sphere():
        d = stack(sample_sphere(*uniforms(2, n)))
        dom = SphereDomain()
        return (chi2_test(d, lambda p: np.full(len(p), float(warps.pdf_uniform_sphere())), dom),
                _cells(dom))

    def cone(cos_max):
        def run():
            c = np.float32(cos_max)
            d = stack(sample_cone(*uniforms(int(1000 * cos_max) + 3000, n), f32(c)))
            dom = SphereDomain(a_edges=np.linspace(0.0, 1.0 - float(c), 33))
            pdf = float(warps.pdf_uniform_cone(f32(c)))
            return chi2_test(d, lambda p: np.full(len(p), pdf), dom, total=1.0), _cells(dom)
        return run

    def phong(e):
        def run():
            d = stack(sample_phong(*uniforms(5, n), f32(e)))
            dom = phong_domain(e)
            return chi2_test(d, lambda p: warps.pdf_phong_lobe(z_of(p), f32(e)), dom,
                             total=1.0), _cells(dom)
        return run

    def disc():
        x, y = sample_disc(*uniforms(8, n))
        p = np.stack([np.asarray(x), np.asarray(y)], axis=-1)
        dom = PlaneDomain(np.linspace(-1, 1, 41), np.linspace(-1, 1, 41))
        pdf = float(warps.pdf_disc())
        return chi2_test(p, lambda q: np.where((q ** 2).sum(1) <= 1.0, pdf, 0.0), dom,
                         nodes=24), _cells(dom)

    def triangle():
        b1, b2 = sample_triangle(*uniforms(9, n))
        b = np.stack([np.asarray(b1), np.asarray(b2)], axis=-1)
        dom = PlaneDomain(np.linspace(0, 1, 32), np.linspace(0, 1, 32))
        return (chi2_test(b, lambda q: np.where(q.sum(1) <= 1.0, 2.0, 0.0), dom, nodes=24),
                _cells(dom))

    return [("warp", "sample\\_cosine\\_hemisphere", cosine),
            ("warp", "sample\\_uniform\\_sphere", sphere),
            ("warp", "sample\\_uniform\\_cone, $\\cos\\theta_{\\max}=0.5$", cone(0.5)),
            ("warp", "sample\\_uniform\\_cone, $\\cos\\theta_{\\max}=0.9999$", cone(0.9999)),
            ("warp", "sample\\_phong\\_lobe, $n=10$", phong(10.0)),
            ("warp", "sample\\_phong\\_lobe, $n=1000$", phong(1000.0)),
            ("warp", "sample\\_concentric\\_disc", disc),
            ("warp", "sample\\_uniform\\_triangle", triangle)]


def bsdf_cases(n):
    nrm = NORMAL

    def lobe(mat, theta, seed):
        def run():
            wo = direction(theta)
            s = bsdf_samplers.sample(mat, nrm, wo, seed=seed, count=n)
            v = s["valid"]
            if mat[0] == DIFFUSE:
                dom = SphereDomain(axis=nrm)
            else:
                a_min = 0.02 / (float(mat[3]) + 1.0)
                dom = SphereDomain(axis=reflect_np(wo, nrm),
                                   a_edges=np.concatenate([[0.0], np.geomspace(a_min, 2.0, 40)]))
            pdf = lambda w: bsdf_samplers.evaluate(  # noqa: E731
                mat, np.float32(nrm), np.float32(wo), np.float32(w))[1]
            return chi2_test(s["wi"][v], pdf, dom, n_total=n), _cells(dom) + 1  # + "no sample"
        return run

    def fresnel(theta, outside, ior):
        def run():
            mat = bsdf_samplers.material(DIELECTRIC, ks=1.0, ior=ior)
            wo = direction(theta, n=nrm if outside else -nrm)
            eta = ior if outside else 1.0 / ior
            side = nrm if outside else -nrm
            F = float(bsdf_samplers.fresnel_reference(float(np.dot(wo, side)), np.float32(eta)))
            s = bsdf_samplers.sample(mat, nrm, wo, seed=int(theta) + 11, count=n, mode=B.IMPORTANCE)
            refl = int(((s["wi"] @ side) > 0).sum())
            return pearson([refl, n - refl], [n * F, n * (1.0 - F)]), 2
        return run

    cases = [
        ("BSDF", "diffuse, $\\theta_o=50^\\circ$",
         lobe(bsdf_samplers.material(DIFFUSE, kd=(0.2, 0.5, 0.8)), 50.0, 1)),
        ("BSDF", "diffuse, $\\theta_o=89^\\circ$",
         lobe(bsdf_samplers.material(DIFFUSE, kd=0.7), 89.0, 2)),
        ("BSDF", "Phong $n=1$, $\\theta_o=30^\\circ$",
         lobe(bsdf_samplers.material(PHONG, kd=(0.5, 0.4, 0.3), ks=0.3, n=1.0), 30.0, 3)),
        ("BSDF", "Phong $n=10$, $\\theta_o=70^\\circ$",
         lobe(bsdf_samplers.material(PHONG, kd=0.2, ks=(0.7, 0.6, 0.5), n=10.0), 70.0, 4)),
        ("BSDF", "Phong $n=100$, $\\theta_o=89^\\circ$",
         lobe(bsdf_samplers.material(PHONG, kd=0.4, ks=0.4, n=100.0), 89.0, 5)),
        ("BSDF", "Phong $n=1000$, $\\theta_o=45^\\circ$",
         lobe(bsdf_samplers.material(PHONG, kd=(0.05, 0.1, 0.0), ks=0.9, n=1000.0), 45.0, 6)),
        ("BSDF", "dielectric (Fresnel split), outside, $30^\\circ$", fresnel(30.0, True, 1.5)),
        ("BSDF", "dielectric (Fresnel split), outside, $75^\\circ$", fresnel(75.0, True, 1.5)),
        ("BSDF", "dielectric (Fresnel split), inside, $40^\\circ$", fresnel(40.0, False, 1.5)),
    ]
    return cases


def mirror_check(n):
    """Largest angle (radians) between a mirror's sampled direction and the exact reflection."""
    worst = 0.0
    for theta in (0.0, 37.0, 89.0):
        wo = direction(theta)
        s = bsdf_samplers.sample(bsdf_samplers.material(MIRROR, ks=0.9), NORMAL, wo, seed=3,
                                 count=n)
        w = s["wi"].astype(np.float64)
        r = reflect_np(wo, NORMAL)
        angle = np.arctan2(np.linalg.norm(np.cross(w, r), axis=1), w @ r)  # accurate near 0
        ok = s["valid"].all() and s["delta"].all()
        worst = max(worst, float(angle.max()) if ok else np.inf)
    return worst


def light_cases(n):
    x = X_REF

    def area(kind):
        def run():
            if kind == "quad":
                lights = quad_lights()
                p0, e1, e2 = QUAD
                pts = [p0, p0 + e1, p0 + e1 + e2, p0 + e2]
                cast = lambda o, w: cast_parallelogram(o, w, p0, e1, e2)  # noqa: E731
            else:
                lights = tri_lights()
                a, b, c = TRI
                pts = [a, b, c]
                cast = lambda o, w: cast_parallelogram(o, w, a, c - a, b - a, True)  # noqa: E731
            s = sample_li(lights, x, 1 if kind == "quad" else 2, n)
            dom = zoom_domain(x, pts)
            return chi2_test(s["wi"], direction_pdf(lights, 0, x, cast), dom, total=1.0,
                             nodes=16), _cells(dom)
        return run

    def sphere():
        radius, distance, alpha = 0.5, 1.5, np.radians(25.0)
        c = x + distance * np.array([np.sin(alpha), 0.0, np.cos(alpha)])
        lights = build(lambda b: b.sphere(c, radius, "m", emission=L_RGB))
        s = sample_li(lights, x, 530, n)
        sin2 = (radius / distance) ** 2
        dom = SphereDomain(axis=normalize(c - x),
                           a_edges=np.linspace(0.0, sin2 / (1 + np.sqrt(1 - sin2)), 25))
        cast = lambda o, w: cast_sphere(o, w, c, radius)  # noqa: E731
        return chi2_test(s["wi"], direction_pdf(lights, 0, x, cast), dom, total=1.0), _cells(dom)

    def environment():
        lights = build(lambda b: b.environment_light(L_RGB))
        s = sample_li(lights, x, 6, n)
        k = lights.environment
        pdf = lambda w: np.asarray(pdf_li(lights, np.int32(k), np.float32(x),  # noqa: E731
                                          np.float32(x + w), np.float32(-w)))
        dom = SphereDomain()
        return chi2_test(s["wi"], pdf, dom), _cells(dom)

    def quad_emission(part):
        def run():
            p0, e1, e2 = QUAD
            e = sample_emission(quad_lights(), 12, n)
            if part == "positions":
                G = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
                ab = np.linalg.solve(G, np.stack([(e["p"] - p0) @ e1, (e["p"] - p0) @ e2])).T
                edges = np.linspace(-1e-6, 1 + 1e-6, 25)
                dom = PlaneDomain(edges, edges)
                return chi2_test(ab, lambda q: np.ones(len(q)), dom), _cells(dom)
            return cosine_about_normals(e["d"], e["n"])
        return run

    def cosine_about_normals(d, nrm):
        s_, t_, z = local_frames(nrm)
        loc = np.stack([(d * s_).sum(1), (d * t_).sum(1), (d * z).sum(1)], axis=1)
        dom = SphereDomain()
        return chi2_test(loc, lambda w: np.maximum(w[:, 2], 0) / np.pi, dom), _cells(dom)

    def sphere_emission():
        e = sample_emission(build(lambda b: b.sphere((0.1, 0.2, 0.3), 0.7, "m",
                                                     emission=L_RGB)), 14, n)
        dom = SphereDomain()
        return chi2_test(e["n"], lambda w: np.full(len(w), 1 / (4 * np.pi)), dom), _cells(dom)

    def point_emission():
        e = sample_emission(build(lambda b: b.point_light((0.0, 1.0, 0.0), (5.0, 4.0, 3.0))),
                            15, n)
        dom = SphereDomain()
        return chi2_test(e["d"], lambda w: np.full(len(w), 1 / (4 * np.pi)), dom), _cells(dom)

    def spot_emission():
        pos, target = np.array([0.0, 1.0, 0.0]), np.array([1.0, -1.0, 0.5])
        ct = np.float32(np.cos(np.radians(40.0)))
        lights = build(lambda b: b.spot_light(pos, target, (5.0, 4.0, 3.0), 40.0, 15.0))
        e = sample_emission(lights, 16, n)
        dom = SphereDomain(axis=normalize(target - pos), a_edges=np.linspace(0.0, 1 - ct, 25))
        pdf = 1 / (2 * np.pi * (1 - ct))
        return chi2_test(e["d"], lambda w: np.full(len(w), pdf), dom, total=1.0), _cells(dom)

    def environment_emission():
        lights = build(lambda b: b.environment_light((2.0, 1.0, 0.5)))
        R = float(lights.bound_radius)
        center = np.array([float(c) for c in lights.bound_center])
        e = sample_emission(lights, 25, n)
        d = e["d"].astype(np.float64)
        s_, t_, _ = local_frames(d)
        off = e["p"] - (center - R * d)
        xy = np.stack([(off * s_).sum(1), (off * t_).sum(1)], axis=1) / R
        dom = PlaneDomain(np.linspace(-1, 1, 25), np.linspace(-1, 1, 25))
        return chi2_test(xy, lambda q: np.where((q ** 2).sum(1) <= 1, 1 / np.pi, 0.0), dom,
                         nodes=16), _cells(dom)

    def selection():
        c, rad = np.array([-1.5, 0.0, 1.5]), 0.4
        lights = build(lambda b: (b.quad(*QUAD, "m", emission=L_RGB),
                                  b.sphere(c, rad, "m", emission=2 * L_RGB),
                                  b.point_light((0.0, 1.5, 0.0), (3.0, 3.0, 3.0))))
        pmf = np.asarray(lights.pmf, np.float64)
        sel = np.asarray(jax.jit(LT.select)(lights, jnp.asarray(light_uniforms(19, 1, n)[0])))
        return pearson(np.bincount(sel, minlength=len(pmf)), n * pmf / pmf.sum()), len(pmf)

    return [("light", "quad: sample\\_li", area("quad")),
            ("light", "triangle: sample\\_li", area("triangle")),
            ("light", "sphere: sample\\_li (cone)", sphere),
            ("light", "environment: sample\\_li", environment),
            ("light", "quad: sample\\_emission positions", quad_emission("positions")),
            ("light", "quad: sample\\_emission directions", quad_emission("directions")),
            ("light", "sphere: sample\\_emission positions", sphere_emission),
            ("light", "point: sample\\_emission", point_emission),
            ("light", "spot: sample\\_emission", spot_emission),
            ("light", "environment: sample\\_emission origins", environment_emission),
            ("light", "select (by power)", selection)]


def camera_cases(n):
    def primary(name):
        def run():
            cam = camera_samplers.camera(name)
            _, _, _, _, d = camera_samplers.primary_rays(cam, n, seed=3)
            axis, a_max = camera_samplers.frame_cone(cam)
            dom = SphereDomain(axis=axis, a_edges=np.linspace(0.0, 1.02 * a_max, 25), n_phi=32)
            pos = camera_samplers.vec(cam.position)
            pdf = lambda w: camera_samplers.project(cam, pos + w)["pdf_dir"]  # noqa: E731
            return chi2_test(d, pdf, dom, total=1.0), _cells(dom)
        return run

    return [("camera", "sample\\_ray (square film)", primary("square")),
            ("camera", "sample\\_ray (wide film)", primary("wide-x"))]


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=1 << 18)
    ap.add_argument("--alpha", type=float, default=0.01, help="family-wise significance")
    ap.add_argument("--out", default="runs/chi2")
    a = ap.parse_args(argv)

    n = a.samples
    cases = warp_cases(n) + bsdf_cases(n) + light_cases(n) + camera_cases(n)
    level = a.alpha / len(cases)
    rows = []
    t0 = time.perf_counter()
    for group, label, run in cases:
        t = time.perf_counter()
        r, cells = run()
        rows.append(dict(group=group, routine=label, samples=n, cells=int(cells),
                         statistic=r.statistic,
                         dof=r.dof, p_value=r.p_value, passed=bool(r.p_value >= level),
                         seconds=round(time.perf_counter() - t, 2)))
        print(f"[chi2] {group:6s} {label:55s} chi2={r.statistic:9.1f} dof={r.dof:5d} "
              f"p={r.p_value:.3g} ({rows[-1]['seconds']:.1f} s)", file=sys.stderr, flush=True)
    mirror = mirror_check(n)
    result = dict(samples=n, alpha=a.alpha, level=level, rows=rows,
                  mirror_max_angle=mirror, seconds=round(time.perf_counter() - t0, 1),
                  worst_p=min(r["p_value"] for r in rows),
                  failures=sum(not r["passed"] for r in rows))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "chi2.json").write_text(json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    main()
