"""Lights (:mod:`jgi.physics.lights`): next-event sampling, its pdf, emission sampling and
selection.

* ``sample_li`` from a reference point: directions follow ``pdf_li`` (chi-square over the
  sphere of directions, zoomed on the light; ``pdf_li`` evaluated where an independent float64
  ray cast hits the emitter); ``pdf_li`` at the sampled point equals the returned pdf; Monte
  Carlo irradiance sum(L_i cos / pdf) / N matches closed forms (Lambert's polygon formula for
  quads and triangles, pi L (r/d)^2 cos(alpha) for spheres) within 5 standard errors.
* Delta lights: point L_i = I / d^2 exactly, spot smoothstep falloff, directional.
* ``sample_emission``: positions uniform over the emitter and directions cosine-distributed
  about its normal (chi-square), the returned densities, and the mean ``weight`` equals the
  analytic emitted power (pi A L, 4 pi I, spot 2 pi I (1 - (cos_total + cos_falloff) / 2), ...).
* Selection frequencies are proportional to power (chi-square on element counts).
* Degenerate emitters and reference points give no NaN or Inf.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jgi.analysis.chi2 import PlaneDomain, SphereDomain, assert_chi2, pearson
from jgi.physics import lights as LT
from jgi.scene import AREA_QUAD, AREA_SPHERE, SceneBuilder
from tests.support.light_samplers import (
    L_RGB,
    N_REF,
    QUAD,
    TRI,
    X_REF,
    build,
    cast_parallelogram,
    cast_sphere,
    direction_pdf,
    emitted,
    local_frames,
    normalize,
    pdf_li,
    quad_lights,
    sample_emission,
    sample_li,
    sample_li_from_uniforms,
    tri_lights,
    uniforms,
    zoom_domain,
)

# --- closed forms (independent of jgi) ------------------------------------------------------------

def polygon_irradiance(L, x, n_x, verts):
    """Lambert's formula: E = L / 2 sum_i Theta_i (n_x . Gamma_i) for a uniformly emitting
    polygon entirely above x's horizon (Theta_i: angle subtended by edge i, Gamma_i: unit normal
    of the plane through x and the edge)."""
    u = normalize(np.asarray(verts, float) - np.asarray(x, float))
    s = 0.0
    for i in range(len(u)):
        a, b = u[i], u[(i + 1) % len(u)]
        c = np.cross(a, b)
        s += np.arccos(np.clip(a @ b, -1, 1)) * (np.asarray(n_x) @ c) / np.linalg.norm(c)
    return L * abs(s) / 2.0


def test_polygon_irradiance_reference_is_right():
    """The reference itself, against the corner formula for a parallel rectangle."""
    a, b, d = 1.3, 0.7, 0.9
    X, Y = a / d, b / d
    F = (X / np.sqrt(1 + X * X) * np.arctan(Y / np.sqrt(1 + X * X))
         + Y / np.sqrt(1 + Y * Y) * np.arctan(X / np.sqrt(1 + Y * Y))) / (2 * np.pi)
    E = polygon_irradiance(1.0, [0, 0, 0], [0, 0, 1], [[0, 0, d], [a, 0, d], [a, b, d], [0, b, d]])
    assert abs(E - np.pi * F) < 1e-12


# --- area lights: sample_li -----------------------------------------------------------------------

def check_area_light(lights, cast, corners_or_none, seed, label, x=X_REF):
    s = sample_li(lights, x, seed)
    v = s["valid"]
    assert v.all(), f"{label}: every direction towards a light in full view is valid"
    assert not s["delta"].any()
    # directions follow pdf_li (as a density over solid angle)
    pts = corners_or_none
    dom = zoom_domain(x, pts)
    r = assert_chi2(s["wi"], direction_pdf(lights, 0, x, cast), dom, label, total=1.0, nodes=16)
    # pdf_li at the sampled point equals the returned pdf
    y = x + s["wi"] * s["dist"][:, None]
    hit, _, n_y = cast(np.asarray(x, float), normalize(s["wi"].astype(np.float64)))
    assert hit.mean() > 0.999
    p = np.asarray(pdf_li(lights, np.int32(0), np.float32(x), np.float32(y), np.float32(n_y)))
    np.testing.assert_allclose(p[hit], s["pdf"][hit], rtol=2e-4)
    return s, r


def irradiance_estimate(s, n_x):
    cos = np.maximum(s["wi"] @ n_x, 0.0)
    e = np.where(s["valid"][:, None],
                 s["Li"] * (cos / np.where(s["valid"], s["pdf"], 1.0))[:, None], 0.0)
    return e.mean(0), e.std(0) / np.sqrt(len(e))


def test_quad_light_sample_li():
    lights = quad_lights()
    p0, e1, e2 = QUAD
    corners = [p0, p0 + e1, p0 + e1 + e2, p0 + e2]
    s, r = check_area_light(lights, lambda x, w: cast_parallelogram(x, w, p0, e1, e2), corners,
                            1, "quad")
    assert abs(r.pdf_integral - 1.0) < 1e-4
    m, se = irradiance_estimate(s, N_REF)
    E = polygon_irradiance(L_RGB, X_REF, N_REF, corners)
    assert np.all(np.abs(m - E) < 5 * se), (m, E, se)


def test_triangle_light_sample_li():
    lights = tri_lights()
    a, b, c = TRI
    # the mesh was given as (a, c, b), so that its normal faces X_REF
    s, r = check_area_light(lights, lambda x, w: cast_parallelogram(x, w, a, c - a, b - a, True),
                            [a, b, c], 2, "triangle")
    assert abs(r.pdf_integral - 1.0) < 1e-4
    m, se = irradiance_estimate(s, N_REF)
    E = polygon_irradiance(L_RGB, X_REF, N_REF, [a, b, c])
    assert np.all(np.abs(m - E) < 5 * se), (m, E, se)


@pytest.mark.parametrize("radius,distance", [(0.5, 1.5), (0.3, 3.0), (0.002, 2.0)])
def test_sphere_light_from_outside(radius, distance):
    """Uniform cone sampling: chi-square zoomed on the cone (cells exactly inside it),
    irradiance pi L (r/d)^2 cos(alpha) (the sphere fully above the horizon)."""
    alpha = np.radians(25.0)
    c = X_REF + distance * np.array([np.sin(alpha), 0.0, np.cos(alpha)])
    lights = build(lambda b: b.sphere(c, radius, "m", emission=L_RGB))
    s = sample_li(lights, X_REF, seed=int(1000 * radius) + 30)
    assert s["valid"].all() and not s["delta"].any()
    axis = normalize(c - X_REF)
    sin2 = (radius / distance) ** 2
    one_minus = sin2 / (1 + np.sqrt(1 - sin2))
    dom = SphereDomain(axis=axis, a_edges=np.linspace(0.0, one_minus, 25))
    cast = lambda x, w: cast_sphere(x, w, c, radius)
    r = assert_chi2(s["wi"], direction_pdf(lights, 0, X_REF, cast), dom,
                    f"sphere r={radius} d={distance}", total=1.0)
    assert abs(r.pdf_integral - 1.0) < 1e-3
    # the returned point lies on the sphere, and pdf_li there is the returned pdf
    y = X_REF + s["wi"] * s["dist"][:, None]
    np.testing.assert_allclose(np.linalg.norm(y - c, axis=1), radius, rtol=1e-3, atol=1e-5)
    p = np.asarray(pdf_li(lights, np.int32(0), np.float32(X_REF), np.float32(y),
                          np.float32(normalize(y - c))))
    np.testing.assert_allclose(p, s["pdf"], rtol=1e-5)
    m, se = irradiance_estimate(s, N_REF)
    E = np.pi * L_RGB * sin2 * np.cos(alpha)
    assert np.all(np.abs(m - E) < 5 * se + 1e-6 * E), (m, E, se)


def test_sphere_light_from_inside_and_on_it_gives_nothing():
    """Spheres emit outwards only (``emitted`` is zero on the inner side), so a point inside, or
    on the surface, receives nothing by next-event estimation, and pdf_li is zero there."""
    c, r = np.array([0.0, 0.0, 1.0]), 0.5
    lights = build(lambda b: b.sphere(c, r, "m", emission=L_RGB))
    for x in [c, c + np.array([0.1, -0.2, 0.3]), c + np.array([0.0, 0.0, r])]:
        s = sample_li(lights, x, seed=4, n=1000)
        for k, v in s.items():
            assert np.all(np.isfinite(v)), k
        assert not s["valid"].any() and np.all(s["Li"] == 0)
    # emitted radiance seen from inside is zero, from outside L
    n_y = np.array([0.0, 0.0, 1.0])
    inner = emitted(lights, np.int32(0), np.float32(n_y), np.float32([[0.0, 0.0, -1.0]]))
    outer = emitted(lights, np.int32(0), np.float32(n_y), np.float32([[0.0, 0.0, 1.0]]))
    assert np.all(np.asarray(inner) == 0) and np.allclose(np.asarray(outer), L_RGB)
    y = c + np.array([[0.0, 0.0, r]])
    assert float(pdf_li(lights, np.int32(0), np.float32(c), np.float32(y),
                        np.float32(n_y))[0]) == 0


def test_one_sided_area_light_seen_from_behind():
    lights = quad_lights()
    x_behind = np.array([0.0, 0.0, 3.0])
    s = sample_li(lights, x_behind, seed=5, n=1000)
    assert not s["valid"].any() and np.all(s["Li"] == 0) and np.all(np.isfinite(s["pdf"]))
    p0, e1, e2 = QUAD
    y = (p0 + 0.5 * e1 + 0.5 * e2)[None]
    n_q = normalize(np.cross(e1, e2))
    assert float(pdf_li(lights, np.int32(0), np.float32(x_behind), np.float32(y),
                        np.float32(n_q))[0]) == 0


def test_environment_sample_li():
    lights = build(lambda b: b.environment_light(L_RGB))
    s = sample_li(lights, X_REF, seed=6)
    assert s["valid"].all() and np.all(np.isinf(s["dist"]))
    k = lights.environment
    env_pdf = lambda w: np.asarray(pdf_li(lights, np.int32(k), np.float32(X_REF),
                                          np.float32(X_REF + w), np.float32(-w)))
    r = assert_chi2(s["wi"], env_pdf, SphereDomain(), "environment")
    assert abs(r.pdf_integral - 1.0) < 1e-4
    np.testing.assert_allclose(s["pdf"], 1 / (4 * np.pi), rtol=1e-6)
    m, se = irradiance_estimate(s, N_REF)  # uniform sky over a hemisphere: E = pi L
    assert np.all(np.abs(m - np.pi * L_RGB) < 5 * se), (m, se)


def test_pdf_li_includes_selection_pmf():
    """Two emitters in different directions: the returned pdf (and pdf_li with the element
    that was hit) is pmf_k times the element's own density; irradiance adds up."""
    c, rad = np.array([-1.5, 0.0, 1.5]), 0.4
    lights = build(lambda b: (b.quad(*QUAD, "m", emission=L_RGB),
                              b.sphere(c, rad, "m", emission=2 * L_RGB)))
    pmf = np.asarray(lights.pmf)
    s = sample_li(lights, X_REF, seed=7)
    w = normalize(s["wi"].astype(np.float64))
    p0, e1, e2 = QUAD
    hit_q, yq, nq = cast_parallelogram(X_REF, w, p0, e1, e2)
    hit_s, ys, ns = cast_sphere(X_REF, w, c, rad)
    assert np.all(hit_q | hit_s)
    ks_ = int(np.flatnonzero(np.asarray(lights.kind) == AREA_SPHERE)[0])
    kq = int(np.flatnonzero(np.asarray(lights.kind) == AREA_QUAD)[0])
    k_of = np.where(hit_s, ks_, kq)
    y = np.where(hit_s[:, None], ys, yq)
    n = np.where(hit_s[:, None], ns, nq)
    p = np.asarray(pdf_li(lights, np.int32(k_of), np.float32(X_REF), np.float32(y), np.float32(n)))
    np.testing.assert_allclose(p, s["pdf"], rtol=2e-4)
    frac_sphere = hit_s.mean()
    se = np.sqrt(pmf[ks_] * (1 - pmf[ks_]) / len(w))
    assert abs(frac_sphere - pmf[ks_]) < 5 * se
    m, se = irradiance_estimate(s, N_REF)
    corners = [p0, p0 + e1, p0 + e1 + e2, p0 + e2]
    d = np.linalg.norm(c - X_REF)
    E = polygon_irradiance(L_RGB, X_REF, N_REF, corners) + np.pi * 2 * L_RGB * (rad / d) ** 2 * (
        (c - X_REF) @ N_REF / d)
    assert np.all(np.abs(m - E) < 5 * se), (m, E, se)


# --- delta lights -------------------------------------------------------------------------------

def test_point_light_is_inverse_square_exactly():
    pos = np.array([0.3, 1.0, -0.4])
    I = np.array([10.0, 5.0, 2.0])
    lights = build(lambda b: b.point_light(pos, I))
    xs = np.random.default_rng(8).normal(size=(256, 3)).astype(np.float32)
    out = {k: np.asarray(v)
           for k, v in sample_li_from_uniforms(lights, xs, uniforms(9, 3, 256)).items()}
    d = pos - xs.astype(np.float64)
    d2 = (d ** 2).sum(1)
    np.testing.assert_allclose(out["Li"], I / d2[:, None], rtol=2e-6)
    np.testing.assert_allclose(out["wi"], d / np.sqrt(d2)[:, None], atol=1e-6)
    np.testing.assert_allclose(out["dist"], np.sqrt(d2), rtol=1e-6)
    assert out["valid"].all() and out["delta"].all() and np.all(out["pdf"] == 1.0)


def smoothstep_falloff(cos_t, cos_total, cos_falloff):
    t = np.clip((cos_t - cos_total) / (cos_falloff - cos_total), 0, 1)
    return np.where(cos_t >= cos_falloff, 1.0, t * t * (3 - 2 * t))


def test_spot_light_falloff():
    pos, I = np.array([0.0, 0.0, 2.0]), np.array([8.0, 8.0, 8.0])
    lights = build(lambda b: b.spot_light(pos, (0, 0, 0), I, cutoff_deg=30.0, falloff_deg=20.0))
    angles = np.array([0.0, 10.0, 19.9, 20.5, 23.0, 25.0, 28.0, 29.9, 30.5, 60.0, 120.0, 180.0])
    dist = 1.7
    th = np.radians(angles)
    xs = pos + dist * np.stack([np.sin(th), np.zeros_like(th), -np.cos(th)], axis=1)
    out = {k: np.asarray(v)
           for k, v in sample_li_from_uniforms(lights, np.float32(xs),
                                               uniforms(10, 3, len(xs))).items()}
    fall = smoothstep_falloff(np.cos(th), np.cos(np.radians(30.0)), np.cos(np.radians(20.0)))
    np.testing.assert_allclose(out["Li"], I * fall[:, None] / dist ** 2, rtol=2e-5, atol=1e-5)
    np.testing.assert_array_equal(out["valid"], fall > 0)
    assert 0 < fall[4] < 1 and fall[0] == 1 and fall[8] == 0  # the test spans all three regimes


def test_directional_light():
    d, E = normalize(np.array([0.3, -1.0, 0.2])), np.array([3.0, 2.0, 1.0])
    lights = build(lambda b: b.directional_light(d, E))
    s = sample_li(lights, X_REF, seed=11, n=64)
    np.testing.assert_allclose(s["wi"], np.broadcast_to(-d, (64, 3)), atol=1e-6)
    np.testing.assert_allclose(s["Li"], np.broadcast_to(E, (64, 3)))
    assert s["delta"].all() and s["valid"].all() and np.all(np.isinf(s["dist"]))


# --- emission sampling ----------------------------------------------------------------------------

def local_direction_test(d, n, label):
    """Directions d [N,3] are cosine-distributed about their own normals n [N,3]."""
    s_, t_, z = local_frames(n)
    loc = np.stack([(d * s_).sum(1), (d * t_).sum(1), (d * z).sum(1)], axis=1)
    assert_chi2(loc, lambda w: np.maximum(w[:, 2], 0) / np.pi, SphereDomain(), label)
    return loc


def test_quad_emission():
    lights = quad_lights()
    p0, e1, e2 = QUAD
    e = sample_emission(lights, seed=12)
    A = np.linalg.norm(np.cross(e1, e2))
    n = normalize(np.cross(e1, e2))
    G = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
    ab = np.linalg.solve(G, np.stack([(e["p"] - p0) @ e1, (e["p"] - p0) @ e2])).T
    np.testing.assert_allclose((e["p"] - p0) @ n, 0.0, atol=1e-5)  # on the quad's plane
    assert_chi2(ab, lambda q: np.ones(len(q)), PlaneDomain(np.linspace(-1e-6, 1 + 1e-6, 25),
                                                           np.linspace(-1e-6, 1 + 1e-6, 25)),
                "quad emission positions")
    np.testing.assert_allclose(e["n"], np.broadcast_to(n, e["n"].shape), atol=1e-6)
    loc = local_direction_test(e["d"], e["n"], "quad emission directions")
    np.testing.assert_allclose(e["pdf_dir"], loc[:, 2] / np.pi, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(e["pdf_pos"], 1 / A, rtol=1e-5)
    power = np.pi * A * L_RGB
    np.testing.assert_allclose(e["weight"].mean(0), power, rtol=1e-5)
    assert not e["delta_pos"].any() and not e["delta_dir"].any()


def test_triangle_emission():
    lights = tri_lights()
    a, b, c = TRI
    e = sample_emission(lights, seed=13)
    e1, e2 = c - a, b - a  # the mesh was given as (a, c, b)
    G = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
    bary = np.linalg.solve(G, np.stack([(e["p"] - a) @ e1, (e["p"] - a) @ e2])).T
    assert_chi2(bary, lambda q: np.where(q.sum(1) <= 1, 2.0, 0.0),
                PlaneDomain(np.linspace(-1e-6, 1 + 1e-6, 24), np.linspace(-1e-6, 1 + 1e-6, 24)),
                "triangle emission positions", nodes=16)
    local_direction_test(e["d"], e["n"], "triangle emission directions")
    A = 0.5 * np.linalg.norm(np.cross(e1, e2))
    np.testing.assert_allclose(e["weight"].mean(0), np.pi * A * L_RGB, rtol=1e-5)


def test_sphere_emission():
    c, r = np.array([0.1, 0.2, 0.3]), 0.7
    lights = build(lambda b: b.sphere(c, r, "m", emission=L_RGB))
    e = sample_emission(lights, seed=14)
    np.testing.assert_allclose(e["p"], c + r * e["n"], atol=1e-5)
    assert_chi2(e["n"], lambda w: np.full(len(w), 1 / (4 * np.pi)), SphereDomain(),
                "sphere emission positions")
    local_direction_test(e["d"], e["n"], "sphere emission directions")
    np.testing.assert_allclose(e["pdf_pos"], 1 / (4 * np.pi * r * r), rtol=1e-5)
    np.testing.assert_allclose(e["weight"].mean(0), np.pi * 4 * np.pi * r * r * L_RGB, rtol=1e-5)


def test_point_and_spot_emission():
    pos, I = np.array([0.0, 1.0, 0.0]), np.array([5.0, 4.0, 3.0])
    e = sample_emission(build(lambda b: b.point_light(pos, I)), seed=15)
    np.testing.assert_allclose(e["p"], np.broadcast_to(pos, e["p"].shape), atol=1e-6)
    assert_chi2(e["d"], lambda w: np.full(len(w), 1 / (4 * np.pi)), SphereDomain(),
                "point emission")
    np.testing.assert_allclose(e["weight"].mean(0), 4 * np.pi * I, rtol=1e-5)
    assert e["delta_pos"].all() and not e["delta_dir"].any()
    # spot: uniform in the cutoff cone, weighted by the falloff; power has a closed form
    ct, cf = np.cos(np.radians(40.0)), np.cos(np.radians(15.0))
    target = np.array([1.0, -1.0, 0.5])
    axis = normalize(target - pos)
    e = sample_emission(build(lambda b: b.spot_light(pos, target, I, 40.0, 15.0)), seed=16)
    dom = SphereDomain(axis=axis, a_edges=np.linspace(0.0, 1 - np.float32(ct), 25))
    assert_chi2(e["d"], lambda w: np.full(len(w), 1 / (2 * np.pi * (1 - np.float32(ct)))), dom,
                "spot emission", total=1.0)
    fall = smoothstep_falloff(e["d"] @ axis, ct, cf)
    np.testing.assert_allclose(e["weight"], I * fall[:, None] * 2 * np.pi * (1 - ct), rtol=2e-4,
                               atol=1e-4)
    m, se = e["weight"].mean(0), e["weight"].std(0) / np.sqrt(len(e["weight"]))
    power = 2 * np.pi * I * (1 - 0.5 * (ct + cf))
    assert np.all(np.abs(m - power) < 5 * se), (m, power, se)


@pytest.mark.parametrize("kind", ["directional", "environment"])
def test_parallel_emission_from_the_bounding_disc(kind):
    d0, E = normalize(np.array([0.2, -1.0, 0.4])), np.array([2.0, 1.0, 0.5])
    lights = build(lambda b: b.directional_light(d0, E) if kind == "directional"
                   else b.environment_light(E))
    R = float(lights.bound_radius)
    center = np.array([float(c) for c in lights.bound_center])
    e = sample_emission(lights, seed=17 if kind == "directional" else 25)
    d = e["d"].astype(np.float64)
    if kind == "directional":
        np.testing.assert_allclose(d, np.broadcast_to(d0, d.shape), atol=1e-6)
        assert e["delta_dir"].all()
        power = np.pi * R * R * E
    else:
        assert_chi2(d, lambda w: np.full(len(w), 1 / (4 * np.pi)), SphereDomain(),
                    "environment emission directions")
        np.testing.assert_allclose(e["pdf_dir"], 1 / (4 * np.pi), rtol=1e-6)
        power = 4 * np.pi * np.pi * R * R * E
    # origins: uniform on the disc of radius R through centre - R d, perpendicular to d
    off = e["p"] - (center - R * d)
    np.testing.assert_allclose((off * d).sum(1), 0.0, atol=1e-4 * R)
    s_, t_, _ = local_frames(d)
    xy = np.stack([(off * s_).sum(1), (off * t_).sum(1)], axis=1) / R
    assert_chi2(xy, lambda q: np.where((q ** 2).sum(1) <= 1, 1 / np.pi, 0.0),
                PlaneDomain(np.linspace(-1, 1, 25), np.linspace(-1, 1, 25)),
                f"{kind} emission origins", nodes=16)
    np.testing.assert_allclose(e["pdf_pos"], 1 / (np.pi * R * R), rtol=1e-5)
    np.testing.assert_allclose(e["weight"].mean(0), power, rtol=1e-5)


def analytic_power(kind, **p):
    lum = 0.2126 * p["L"][0] + 0.7152 * p["L"][1] + 0.0722 * p["L"][2]
    return {"area": lambda: np.pi * p.get("A", 0) * lum, "point": lambda: 4 * np.pi * lum,
            "spot": lambda: 2 * np.pi * (1 - 0.5 * (p["ct"] + p["cf"])) * lum}[kind]()


def test_selection_is_proportional_to_power_and_total_power():
    """Mixed emitters: element frequencies match power / total (chi-square), and the mean
    emission weight is the total emitted power per channel (5 standard errors)."""
    c, r = np.array([1.0, 1.0, 1.0]), 0.3
    I_p, I_s = np.array([3.0, 3.0, 3.0]), np.array([20.0, 10.0, 5.0])
    spot_pos, spot_target = np.array([0.0, 2.0, 0.0]), np.array([0.0, 0.0, 0.0])
    ct, cf = np.cos(np.radians(30.0)), np.cos(np.radians(20.0))

    def add(b):
        b.sphere(c, r, "m", emission=L_RGB)
        b.quad(*QUAD, "m", emission=0.5 * L_RGB)
        b.mesh(np.array(TRI), [[0, 1, 2]], "m", emission=2 * L_RGB)
        b.point_light((0.0, 1.5, 0.0), I_p)
        b.spot_light(spot_pos, spot_target, I_s, 30.0, 20.0)
    lights = build(add)
    A_q = np.linalg.norm(np.cross(QUAD[1], QUAD[2]))
    A_t = 0.5 * np.linalg.norm(np.cross(TRI[1] - TRI[0], TRI[2] - TRI[0]))
    rgb = [L_RGB * np.pi * 4 * np.pi * r * r, 0.5 * L_RGB * np.pi * A_q, 2 * L_RGB * np.pi * A_t,
           4 * np.pi * I_p, 2 * np.pi * (1 - 0.5 * (ct + cf)) * I_s]
    power = np.array([analytic_power("area", A=4 * np.pi * r * r, L=L_RGB),
                      analytic_power("area", A=A_q, L=0.5 * L_RGB),
                      analytic_power("area", A=A_t, L=2 * L_RGB),
                      analytic_power("point", L=I_p),
                      analytic_power("spot", L=I_s, ct=ct, cf=cf)])
    pmf = power / power.sum()
    np.testing.assert_allclose(np.asarray(lights.pmf), pmf, rtol=1e-5)
    e = sample_emission(lights, seed=18)
    counts = np.bincount(e["element"], minlength=len(pmf))
    r_ = pearson(counts, len(e["element"]) * pmf)
    assert r_.ok(), r_.message
    m, se = e["weight"].mean(0), e["weight"].std(0) / np.sqrt(len(e["weight"]))
    total = np.sum(rgb, axis=0)
    assert np.all(np.abs(m - total) < 5 * se), (m, total, se)
    # next-event selection uses the same pmf
    sel = np.asarray(jax.jit(LT.select_light)(lights, jnp.asarray(uniforms(19, 1)[0])))
    r_ = pearson(np.bincount(sel, minlength=len(pmf)), len(sel) * pmf)
    assert r_.ok(), r_.message


# --- degenerate inputs ----------------------------------------------------------------------------

def all_finite(d):
    for k, v in d.items():
        assert np.all(np.isfinite(v) | np.isinf(v) & (k == "dist")), k


def test_zero_area_quad_and_zero_radius_sphere_lights():
    for add in [lambda b: b.quad((0, 0, 1), (1, 0, 0), (0, 0, 0), "m", emission=L_RGB),
                lambda b: b.quad((0, 0, 1), (1, 0, 0), (2, 0, 0), "m", emission=L_RGB),
                lambda b: b.sphere((0, 0, 1), 0.0, "m", emission=L_RGB)]:
        lights = build(add)
        for x in [X_REF, np.array([0.0, 0.0, 1.0])]:  # away from and on the emitter
            s = sample_li(lights, x, seed=20, n=1000)
            all_finite(s)
            assert not s["valid"].any() and np.all(s["Li"] == 0)
            p = pdf_li(lights, np.int32(0), np.float32(x), np.float32([[0.0, 0.0, 1.0]]),
                       np.float32([[0.0, 0.0, -1.0]]))
            assert np.all(np.isfinite(np.asarray(p)))
        e = sample_emission(lights, seed=21, n=1000)
        all_finite(e)
        assert np.all(e["weight"] == 0)


def test_reference_point_on_the_light():
    lights = quad_lights()
    p0, e1, e2 = QUAD
    n = normalize(np.cross(e1, e2))
    # interior, corners, and in the light's plane just outside it: the light subtends no solid
    # angle; float32 rounding of y - x leaves cosines ~1e-7 / d, so some samples are valid,
    # but with negligible irradiance
    for x in [p0 + 0.3 * e1 + 0.6 * e2, p0, p0 + e1 + e2, p0 + 1.5 * e1 + 0.5 * e2]:
        s = sample_li(lights, x, seed=22, n=20_000)
        all_finite(s)
        m, _ = irradiance_estimate(s, n)
        assert np.all(m < 1e-6 * L_RGB), m
    # point light at the reference point
    lights = build(lambda b: b.point_light((0.0, 0.0, 0.0), (1.0, 1.0, 1.0)))
    s = sample_li(lights, np.zeros(3), seed=24, n=16)
    all_finite(s)
    assert not s["valid"].any() and np.all(s["Li"] == 0)


@pytest.mark.parametrize("count", [1, 2, 5, 8, 9, 12])
def test_light_selection_inverts_the_power_cdf(count):
    """Small tables count CDF entries with compares, larger ones use searchsorted: both give
    numpy's searchsorted(cdf, u, 'right'), also at the CDF's own values and for lights of zero
    power (never chosen)."""
    rng = np.random.default_rng(count)
    b = SceneBuilder("lights")
    b.material("m", "diffuse", diffuse=(0.5, 0.5, 0.5))
    for i in range(count):
        power = 0.0 if (i == 1 and count > 2) else float(rng.uniform(0.5, 4.0))
        b.quad((3.0 * i, 2, 0), (1, 0, 0), (0, 0, 1), "m", emission=(power, power, power))
    b.quad((-5, 0, -5), (0, 0, 10), (40, 0, 0), "m")
    b.camera(position=(0, 1, 5), look_at=(0, 0, 0), width=4, height=4)
    lights = b.build().lights
    assert lights.count == count
    cdf = np.asarray(lights.cdf)
    u = np.concatenate([rng.uniform(0, 1, 4096), cdf[:-1], [0.0, 0.99999994]]).astype(np.float32)
    got = np.asarray(jax.jit(lambda uu: LT.select_light(lights, uu))(u))
    want = np.clip(np.searchsorted(cdf, u, side="right"), 0, count - 1)
    np.testing.assert_array_equal(got, want)
    if count > 2:
        assert not np.any(got == 1)  # the light of zero power
