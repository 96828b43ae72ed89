"""Every warp in :mod:`jgi.core.warps` against its own pdf (chi-square goodness of fit).

Each sampler is jitted once and fed float32 uniforms from a fixed-seed numpy generator; the
claimed density is integrated over every cell of the test grid by Gauss-Legendre quadrature
(jgi/analysis/chi2.py), which also checks that it integrates to one. Negative controls (a sampler
tested against a slightly wrong pdf) show that the tests have the power to reject.
"""

from __future__ import annotations

import numpy as np
import pytest

from jgi.analysis.chi2 import PlaneDomain, SphereDomain, assert_chi2, chi2_test
from jgi.core import warps
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

# --- directions -----------------------------------------------------------------------------------

def test_cosine_hemisphere():
    d = stack(sample_cosine(*uniforms(1)))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    r = assert_chi2(d, lambda p: warps.pdf_cosine_hemisphere(z_of(p)), SphereDomain(),
                    "cosine hemisphere")
    assert abs(r.pdf_integral - 1.0) < 1e-4


def test_uniform_sphere():
    d = stack(sample_sphere(*uniforms(2)))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    r = assert_chi2(d, lambda p: np.full(len(p), float(warps.pdf_uniform_sphere())),
                    SphereDomain(), "uniform sphere")
    assert abs(r.pdf_integral - 1.0) < 1e-6


@pytest.mark.parametrize("cos_max", [-0.7, 0.0, 0.5, 0.95, 0.9999, 0.999999])
def test_uniform_cone(cos_max):
    """Zoomed on the cone: a in [0, 1 - cos_max]; any sample outside the cone rejects."""
    c = np.float32(cos_max)
    a_max = 1.0 - float(c)
    d = stack(sample_cone(*uniforms(int(1000 * cos_max) + 3000), f32(c)))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    dom = SphereDomain(a_edges=np.linspace(0.0, a_max, 33))
    pdf = float(warps.pdf_uniform_cone(f32(c)))
    r = assert_chi2(d, lambda p: np.full(len(p), pdf), dom, f"cone cos_max={cos_max}",
                    total=1.0)
    assert abs(r.pdf_integral - 1.0) < 1e-4


def test_uniform_cone_degenerate_has_no_nan():
    for c in [1.0, -1.0]:
        d = stack(sample_cone(*uniforms(4, 1000), f32(c)))
        assert np.all(np.isfinite(d))
    assert float(warps.pdf_uniform_cone(f32(1.0))) == 0.0


@pytest.mark.parametrize("n", [0.0, 1.0, 10.0, 1000.0, 100000.0])
def test_phong_lobe(n):
    d = stack(sample_phong(*uniforms(5), f32(n)))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    r = assert_chi2(d, lambda p: warps.pdf_phong_lobe(z_of(p), f32(n)), phong_domain(n),
                    f"Phong lobe n={n}", total=1.0)
    assert abs(r.pdf_integral - 1.0) < 1e-3


def test_phong_lobe_negative_control():
    """Samples of exponent 10 are told apart from the exponent-11 density."""
    d = stack(sample_phong(*uniforms(6), f32(10.0)))
    r = chi2_test(d, lambda p: warps.pdf_phong_lobe(z_of(p), f32(11.0)), phong_domain(10.0),
                  total=1.0)
    assert not r.ok(), r.message


def test_cosine_negative_control():
    """Cosine samples are told apart from a uniform hemisphere."""
    d = stack(sample_cosine(*uniforms(7)))
    r = chi2_test(d, lambda p: np.where(p[:, 2] > 0, 0.5 / np.pi, 0.0), SphereDomain())
    assert not r.ok(), r.message


# --- planar ---------------------------------------------------------------------------------------

def test_concentric_disc():
    x, y = sample_disc(*uniforms(8))
    p = np.stack([np.asarray(x), np.asarray(y)], axis=-1)
    assert np.all(p[:, 0] ** 2 + p[:, 1] ** 2 <= 1.0 + 1e-6)
    dom = PlaneDomain(np.linspace(-1, 1, 41), np.linspace(-1, 1, 41))
    pdf = float(warps.pdf_disc())
    assert_chi2(p, lambda q: np.where((q ** 2).sum(1) <= 1.0, pdf, 0.0), dom, "concentric disc",
                nodes=24)
    # the indicator's quadrature is only O(1/nodes) accurate on cut cells: check the mass exactly
    assert abs(pdf * np.pi - 1.0) < 1e-6


def test_concentric_disc_is_continuous_at_the_centre():
    x, y = sample_disc(f32([0.5, 0.5, 0.5 + 1e-6]), f32([0.5, 0.5 - 1e-6, 0.5]))
    assert np.all(np.abs(np.asarray(x)) < 1e-5) and np.all(np.abs(np.asarray(y)) < 1e-5)


def test_uniform_triangle():
    b1, b2 = sample_triangle(*uniforms(9))
    b = np.stack([np.asarray(b1), np.asarray(b2)], axis=-1)
    assert np.all(b >= 0) and np.all(b.sum(1) <= 1.0 + 1e-6)
    dom = PlaneDomain(np.linspace(0, 1, 32), np.linspace(0, 1, 32))  # hypotenuse off the nodes
    # uniform barycentrics: density 1 / area = 2 on the unit right triangle
    assert_chi2(b, lambda q: np.where(q.sum(1) <= 1.0, 2.0, 0.0), dom, "uniform triangle",
                nodes=24)


def test_samples_where_the_pdf_is_zero_reject():
    """Negative control: cosine samples mirrored below the horizon, where the pdf is 0."""
    d = stack(sample_cosine(*uniforms(10, 20_000)))
    d[:100, 2] *= -1.0
    r = chi2_test(d, lambda p: warps.pdf_cosine_hemisphere(z_of(p)), SphereDomain())
    assert not r.ok() and "pdf is 0" in r.message, r.message
