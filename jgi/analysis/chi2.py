"""Chi-square goodness-of-fit tests for samplers (after Mitsuba 3's ``ChiSquareTest``).

A sampler is correct when the points it produces are distributed with the density its ``pdf``
claims. The test bins a domain into a grid, integrates the claimed density over every cell by
tensor-product Gauss-Legendre quadrature (in float64; cells on the edge of the pdf's support,
where it is discontinuous, are subdivided adaptively), histograms many samples into the same
cells, pools cells whose expected count is below ``min_expected`` (the chi-square approximation
needs about 5 per cell) and computes Pearson's statistic and its p-value with
``scipy.stats.chi2``. The null hypothesis "samples follow the pdf" is rejected at p < 1e-3.

Samplers that can fail (a BSDF lobe sample that lands below the surface) are tested with the
number of attempts ``n_total``: a cell then expects ``n_total * integral(pdf)`` samples and one
extra category, "no sample", expects ``n_total * (1 - sum of all integrals)``. This checks at
once that the pdf integrates to the probability that sampling succeeds.

Domains:

* :class:`SphereDomain`: unit directions, in coordinates ``(a, phi)`` about an axis with
  ``a = 1 - cos(theta)`` in [0, 2] (solid angle is ``da dphi``, so densities need no Jacobian).
  Edges in ``a`` may be non-uniform (geometric spacing resolves sharp lobes) and may stop short
  of 2 to zoom on a small cone; a sample outside the grid goes to an "outside" category that
  expects ``n_total`` times the pdf mass outside the grid, computed as (total - grid integral).
  ``a`` is computed as ``sin^2 / (1 + cos)`` near the axis, so it keeps its float precision.
* :class:`PlaneDomain`: points of a rectangle in the plane (densities per unit area).

Samples in a cell where the quadrature found no mass reject the sampler if the pdf is zero at
those samples (impossible points); otherwise the cell is a sliver of support between nodes and
is pooled. Usage: ``assert_chi2(samples, pdf, SphereDomain(axis=n), "label", n_total=N)``.

The tests (tests/test_warps.py, test_bsdf.py, test_lights.py, test_camera.py) assert with it;
the paper's pipeline (step ``chi2``, paper/chi2_table.py) tabulates the same statistics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

SIGNIFICANCE = 1e-3


# --- domains --------------------------------------------------------------------------------------

def _frame(axis) -> np.ndarray:
    """Rows s, t, n of an orthonormal frame with n = axis."""
    n = np.asarray(axis, np.float64)
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    s = np.cross(helper, n)
    s /= np.linalg.norm(s)
    return np.stack([s, np.cross(n, s), n])


@dataclass
class SphereDomain:
    """Directions binned by ``a = 1 - cos(theta)`` (edges ``a_edges``) and ``n_phi`` azimuths."""

    axis: tuple = (0.0, 0.0, 1.0)
    a_edges: np.ndarray | None = None
    n_phi: int = 32
    n_a: int = 32

    def __post_init__(self):
        if self.a_edges is None:
            self.a_edges = np.linspace(0.0, 2.0, self.n_a + 1)
        self.a_edges = np.asarray(self.a_edges, np.float64)
        self.b_edges = np.linspace(0.0, 2.0 * np.pi, self.n_phi + 1)
        self.frame = _frame(self.axis)

    def coords(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(a, phi) of directions d [N, 3] (renormalised in float64)."""
        d = np.asarray(d, np.float64)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        loc = d @ self.frame.T
        sin2 = loc[:, 0] ** 2 + loc[:, 1] ** 2
        a = np.where(loc[:, 2] > 0, sin2 / (1.0 + np.abs(loc[:, 2])), 1.0 - loc[:, 2])
        phi = np.mod(np.arctan2(loc[:, 1], loc[:, 0]), 2.0 * np.pi)
        return a, phi

    def points(self, a: np.ndarray, phi: np.ndarray) -> np.ndarray:
        cos = 1.0 - a
        sin = np.sqrt(np.clip(a * (2.0 - a), 0.0, None))
        loc = np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], axis=-1)
        return loc @ self.frame

    @staticmethod
    def jacobian(a, phi):
        return np.ones_like(a)


@dataclass
class PlaneDomain:
    """Points (x, y) of the rectangle [x_edges[0], x_edges[-1]] x [y_edges[0], y_edges[-1]]."""

    x_edges: np.ndarray
    y_edges: np.ndarray

    def __post_init__(self):
        self.a_edges = np.asarray(self.x_edges, np.float64)
        self.b_edges = np.asarray(self.y_edges, np.float64)

    @staticmethod
    def coords(p: np.ndarray):
        p = np.asarray(p, np.float64)
        return p[:, 0], p[:, 1]

    @staticmethod
    def points(x, y):
        return np.stack([x, y], axis=-1)

    @staticmethod
    def jacobian(x, y):
        return np.ones_like(x)


# --- quadrature and histogram --------------------------------------------------------------------

def bucket(n: int) -> int:
    """The next power of two >= n (at least 1024): sizes that jitted functions are called with,
    so that varying sample and quadrature counts reuse a handful of compilations."""
    return max(1024, 1 << int(np.ceil(np.log2(max(n, 1)))))


def _evaluate(density, pts: np.ndarray) -> np.ndarray:
    """density(pts), called on a copy padded to a :func:`bucket` size (repeating the last row)."""
    n = len(pts)
    padded = np.concatenate([pts, np.repeat(pts[-1:], bucket(n) - n, axis=0)])
    return np.asarray(density(padded), np.float64)[:n]


def _gauss_cells(density, domain, lo_a, hi_a, lo_b, hi_b, nodes):
    """(integral, some node zero, some node nonzero) per cell [lo_a, hi_a] x [lo_b, hi_b]."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    ha, hb = 0.5 * (hi_a - lo_a), 0.5 * (hi_b - lo_b)
    A = lo_a[:, None, None] + ha[:, None, None] * (x[None, :, None] + 1.0)
    B = lo_b[:, None, None] + hb[:, None, None] * (x[None, None, :] + 1.0)
    A, B = np.broadcast_arrays(A, B)
    val = _evaluate(density, domain.points(A.ravel(), B.ravel())).reshape(A.shape)
    if not np.all(np.isfinite(val)):
        raise AssertionError("the pdf is not finite at some quadrature points")
    val = val * domain.jacobian(A, B)
    out = (val * (w[:, None] * w[None, :])).sum(axis=(1, 2)) * ha * hb
    return out, np.any(val == 0, axis=(1, 2)), np.any(val != 0, axis=(1, 2))


def _refine(density, domain, lo_a, hi_a, lo_b, hi_b, refine, nodes, depth, out):
    """Replace ``out[refine]`` by the sum over 2 x 2 sub-cells, recursively. A sub-cell is split
    again if the density is zero at some of its nodes and not at others, or zero at all of them
    while a sibling is not (a thin tip of the support can fall between the nodes)."""
    i = np.flatnonzero(refine)
    if depth == 0 or len(i) == 0:
        return out
    ma, mb = 0.5 * (lo_a[i] + hi_a[i]), 0.5 * (lo_b[i] + hi_b[i])
    sla = np.concatenate([lo_a[i], ma, lo_a[i], ma])
    sha = np.concatenate([ma, hi_a[i], ma, hi_a[i]])
    slb = np.concatenate([lo_b[i], lo_b[i], mb, mb])
    shb = np.concatenate([mb, mb, hi_b[i], hi_b[i]])
    sub, zero, nonzero = _gauss_cells(density, domain, sla, sha, slb, shb, nodes)
    sibling_nonzero = np.tile(nonzero.reshape(4, -1).any(0), 4)
    again = (zero & nonzero) | (~nonzero & sibling_nonzero)
    sub = _refine(density, domain, sla, sha, slb, shb, again, nodes, depth - 1, sub)
    out = out.copy()
    out[i] = sub.reshape(4, len(i)).sum(0)
    return out


def cell_integrals(density, domain, nodes: int = 8, depth: int = 4) -> np.ndarray:
    """Integral of ``density(points [M, dim]) -> [M]`` over each cell of the domain's grid:
    tensor Gauss-Legendre, refined ``depth`` times on the support's edges (cells with zero and
    nonzero nodes, and empty cells next to nonempty ones), since the edges of a light's
    silhouette, a horizon or a cone make the density discontinuous."""
    ea, eb = domain.a_edges, domain.b_edges
    na, nb = len(ea) - 1, len(eb) - 1
    ia, ib = np.meshgrid(np.arange(na), np.arange(nb), indexing="ij")
    ia, ib = ia.ravel(), ib.ravel()
    la, ha, lb, hb = ea[ia], ea[ia + 1], eb[ib], eb[ib + 1]
    out, zero, nonzero = _gauss_cells(density, domain, la, ha, lb, hb, nodes)
    nz = np.pad(nonzero.reshape(na, nb), 1)
    near = np.zeros((na, nb), bool)
    for da in (-1, 0, 1):
        for db in (-1, 0, 1):
            near |= nz[1 + da: 1 + da + na, 1 + db: 1 + db + nb]
    refine = (zero & nonzero) | (~nonzero & near.ravel())
    out = _refine(density, domain, la, ha, lb, hb, refine, nodes, depth, out)
    return out.reshape(na, nb)


def histogram(samples, domain) -> tuple[np.ndarray, int]:
    """(counts per cell, number of samples outside the grid)."""
    a, b = domain.coords(samples)
    counts, _, _ = np.histogram2d(a, b, bins=[domain.a_edges, domain.b_edges])
    return counts, int(len(a) - counts.sum())


# --- the statistic --------------------------------------------------------------------------------

@dataclass
class Result:
    statistic: float
    dof: int
    p_value: float
    pdf_integral: float     # integral of the pdf over the grid
    cells: int              # categories after pooling
    message: str

    def ok(self, significance: float = SIGNIFICANCE) -> bool:
        return self.p_value >= significance


def pearson(observed: np.ndarray, expected: np.ndarray, min_expected: float = 5.0) -> Result:
    """Pearson's chi-square with low-expectation categories pooled (Mitsuba's rule: cells with
    expected < ``min_expected`` merge into one pool; a pool that is still too small merges into
    the smallest remaining cell)."""
    observed = np.asarray(observed, np.float64).ravel()
    expected = np.asarray(expected, np.float64).ravel()
    low = expected < min_expected
    obs = list(observed[~low])
    exp = list(expected[~low])
    pool_o, pool_e = observed[low].sum(), expected[low].sum()
    if low.any():
        if pool_e >= min_expected or not exp:
            obs.append(pool_o)
            exp.append(pool_e)
        else:
            i = int(np.argmin(exp))
            obs[i] += pool_o
            exp[i] += pool_e
    obs, exp = np.asarray(obs), np.asarray(exp)
    if len(obs) < 2:
        return Result(0.0, 0, 1.0, np.nan, len(obs), "fewer than two cells: nothing to test")
    stat = float(((obs - exp) ** 2 / exp).sum())
    dof = len(obs) - 1
    p = float(stats.chi2.sf(stat, dof))
    worst = int(np.argmax((obs - exp) ** 2 / exp))
    msg = (f"chi2 = {stat:.1f} with {dof} dof, p = {p:.3g}; worst cell observed "
           f"{obs[worst]:.0f} vs expected {exp[worst]:.1f}")
    return Result(stat, dof, p, np.nan, len(obs), msg)


def chi2_test(samples, pdf, domain, *, n_total: int | None = None, total: float | None = None,
              nodes: int = 8, min_expected: float = 5.0) -> Result:
    """Test that ``samples`` (the successful ones, [N, dim]) follow the density ``pdf``.

    ``n_total``: number of sampling attempts (default: ``len(samples)``, every attempt
    succeeded). ``total``: the pdf's total mass over the whole domain, i.e. the probability that
    an attempt succeeds (1 for a normalised density); by default the grid's integral, for grids
    that cover the whole domain. A zoomed grid expects ``n_total * (total - grid integral)``
    samples outside it; failed attempts are expected with probability ``1 - total``.
    """
    samples = np.asarray(samples)
    n_total = len(samples) if n_total is None else int(n_total)
    integrals = cell_integrals(pdf, domain, nodes)
    grid_mass = float(integrals.sum())
    total = grid_mass if total is None else float(total)
    counts, outside = histogram(samples, domain)
    # Samples in cells whose quadrature found no mass: rejected outright if the pdf is zero at
    # the samples themselves (points the pdf calls impossible); otherwise the cell holds a sliver
    # of support between the quadrature nodes (a horizon or a silhouette) and is merely pooled.
    empty = (integrals <= 0.0) & (counts > 0)
    if empty.any():
        a, b = domain.coords(samples)
        ia = np.searchsorted(domain.a_edges, a, side="right") - 1
        ib = np.searchsorted(domain.b_edges, b, side="right") - 1
        inside = (ia >= 0) & (ia < empty.shape[0]) & (ib >= 0) & (ib < empty.shape[1])
        sel = np.zeros(len(a), bool)
        sel[inside] = empty[ia[inside], ib[inside]]
        at = _evaluate(pdf, samples[sel])
        if np.any(at <= 0):
            return Result(np.inf, 0, 0.0, grid_mass, 0,
                          f"{int((at <= 0).sum())} samples where the pdf is 0, e.g. "
                          f"{samples[sel][at <= 0][:3].tolist()}")
    failures = n_total - len(samples)
    observed = np.concatenate([counts.ravel(), [outside, failures]])
    expected = np.concatenate([n_total * integrals.ravel(),
                               [n_total * max(total - grid_mass, 0.0),
                                n_total * max(1.0 - total, 0.0)]])
    r = pearson(observed, expected, min_expected)
    r.pdf_integral = grid_mass
    return r


def assert_chi2(samples, pdf, domain, label: str = "", **kw) -> Result:
    r = chi2_test(samples, pdf, domain, **kw)
    assert r.ok(), f"{label}: sampler does not follow its pdf: {r.message}"
    return r
