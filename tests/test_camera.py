"""Pinhole camera (:mod:`jgi.physics.camera`): primary rays, projection and importance.

* ``project(o + t sample_ray(px + u))`` returns the raster position px + u (round trip), the
  distance t and the direction back to the pinhole.
* The directions of primary rays (uniform over the film) follow ``pdf_dir`` = 1 / (A cos^3)
  (chi-square over the cone of the frame), and ``pdf_dir`` integrates to one.
* The importance W_e = 1 / (A cos^4) is normalised: the integral of W_e cos over the frame is 1
  (pbrt-v4's PerspectiveCamera::We convention), checked by Monte Carlo with directions drawn
  independently of the camera (uniform in a cone around the frame).
* Degenerate points (the pinhole itself, 90 degrees off axis, behind) give no NaN or Inf.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from jgi.analysis.chi2 import SphereDomain, assert_chi2
from jgi.physics import camera as C
from tests.support.camera_samplers import (
    CAMERAS,
    camera,
    frame_cone,
    primary_rays,
    project,
    sample_rays,
    vec,
)


@pytest.mark.parametrize("name", CAMERAS)
def test_project_inverts_sample_ray(name):
    cam = camera(name)
    px, py, u, o, d = primary_rays(cam, 4096, seed=1)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(o, np.broadcast_to(vec(cam.position), o.shape), atol=1e-6)
    t = np.random.default_rng(2).uniform(0.5, 10.0, len(d))
    pr = project(cam, o + t[:, None] * d)
    assert pr["visible"].all()
    # raster positions to a thousandth of a pixel (float32 round trip through a direction)
    np.testing.assert_allclose(pr["px"], px + u[0], atol=2e-3)
    np.testing.assert_allclose(pr["py"], py + u[1], atol=2e-3)
    np.testing.assert_allclose(pr["dist"], t, rtol=1e-5)
    np.testing.assert_allclose(pr["wi"], -d, atol=1e-5)
    # importance and direction pdf: W_e = 1 / (A cos^4), pdf = 1 / (A cos^3)
    A = float(C.film_area(cam))
    cos = d @ vec(cam.forward)
    np.testing.assert_allclose(pr["importance"], 1.0 / (A * cos ** 4), rtol=1e-5)
    np.testing.assert_allclose(pr["pdf_dir"], 1.0 / (A * cos ** 3), rtol=1e-5)


def test_raster_orientation():
    """Row 0 is the top of the image; column 0 is on the left (the right on a mirrored camera)."""
    for name, sign in [("square", 1.0), ("tall-mirrored", -1.0)]:
        cam = camera(name)
        fwd, up = vec(cam.forward), vec(cam.up)
        right = np.cross(fwd, up / np.linalg.norm(up)) * sign  # geometric right of the view
        _, d_top = sample_rays(cam, jnp.int32([cam.width // 2]), jnp.int32([0]),
                               jnp.float32([0.5]), jnp.float32([0.5]))
        _, d_left = sample_rays(cam, jnp.int32([0]), jnp.int32([cam.height // 2]),
                                jnp.float32([0.5]), jnp.float32([0.5]))
        assert float(np.asarray(d_top)[0] @ up) > 0
        assert float(np.asarray(d_left)[0] @ right) < 0


def test_film_area_closed_form():
    for name, cfg in CAMERAS.items():
        cam = camera(name)
        t = np.tan(np.radians(cfg["fov"]) / 2)
        w, h = cfg["width"], cfg["height"]
        tx, ty = (t, t * h / w) if cfg.get("fov_axis", "y") == "x" else (t * w / h, t)
        np.testing.assert_allclose(float(C.film_area(cam)), 4 * tx * ty, rtol=1e-6)


@pytest.mark.parametrize("name", CAMERAS)
def test_primary_directions_follow_pdf_dir(name):
    cam = camera(name)
    _, _, _, o, d = primary_rays(cam, 200_000, seed=3)
    axis, a_max = frame_cone(cam)
    dom = SphereDomain(axis=axis, a_edges=np.linspace(0.0, 1.02 * a_max, 25), n_phi=32)
    pos = vec(cam.position)
    pdf = lambda w: project(cam, pos + w)["pdf_dir"]
    r = assert_chi2(d, pdf, dom, f"camera {name}", total=1.0, nodes=8)
    assert abs(r.pdf_integral - 1.0) < 1e-4, r.pdf_integral


@pytest.mark.parametrize("name", CAMERAS)
def test_importance_is_normalised(name):
    """integral over the frame of W_e cos(theta) d omega = 1, with directions uniform in the
    cone around the frame (independent of the camera's own sampling)."""
    cam = camera(name)
    axis, a_max = frame_cone(cam)
    n = 400_000
    u = np.random.default_rng(4).random((2, n))
    a = a_max * u[0]                                        # uniform in the cone
    phi = 2 * np.pi * u[1]
    dom = SphereDomain(axis=axis)
    w = dom.points(a, phi)
    pr = project(cam, vec(cam.position) + w)
    cos = w @ axis
    f = pr["importance"] * cos * (2 * np.pi * a_max)        # W_e cos / pdf_cone
    m, se = f.mean(), f.std() / np.sqrt(n)
    assert abs(m - 1.0) < 5 * se, (m, se)
    assert se < 0.01  # the test has power: a 5% error in W_e would be > 5 se
    # W_e cos = pdf_dir (so sampling primary rays with pdf_dir estimates it with zero variance)
    vis = pr["visible"]
    np.testing.assert_allclose(pr["importance"][vis] * cos[vis], pr["pdf_dir"][vis], rtol=1e-5)


def test_outside_the_frame_and_degenerate_points():
    cam = camera("wide-x")
    pos, fwd, r, u = vec(cam.position), vec(cam.forward), vec(cam.right), vec(cam.up)
    pts = np.stack([
        pos,                                   # the pinhole itself
        pos + r / np.linalg.norm(r),           # 90 degrees off axis
        pos - fwd,                             # behind
        pos + fwd + 1.01 * r,                  # just outside the frame horizontally
        pos + fwd + 1.01 * u,                  # vertically
        pos + fwd + 0.99 * r + 0.99 * u,       # just inside the corner
        pos + 1e-30 * fwd,                     # (almost) at the pinhole
    ])
    pr = project(cam, pts)
    for k, v in pr.items():
        assert np.all(np.isfinite(v)), k
    np.testing.assert_array_equal(pr["visible"], [False, False, False, False, False, True, False])
    assert (np.all(pr["importance"][~pr["visible"]] == 0)
            and np.all(pr["pdf_dir"][~pr["visible"]] == 0))
    # rays through the film's edges stay finite
    o, d = sample_rays(cam, jnp.int32([0, cam.width - 1]), jnp.int32([0, cam.height - 1]),
                       jnp.float32([0.0, 0.99999994]), jnp.float32([0.0, 0.99999994]))
    assert np.all(np.isfinite(np.asarray(d)))
