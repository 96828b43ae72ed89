"""Shared test settings: fixed seeds, small images, and helpers for statistical comparisons."""

from __future__ import annotations

import numpy as np
import pytest


def region_stats(images: np.ndarray, regions: int = 4):
    """Per-region means of each repetition -> (mean over repetitions, standard error).

    ``images``: (R, H, W, 3) independent renders (different seeds). Regions are a
    ``regions x regions`` grid; the luminance-free RGB channels are kept separate."""
    R, H, W, _ = images.shape
    h, w = H // regions, W // regions
    blocks = images[:, : h * regions, : w * regions].reshape(R, regions, h, regions, w, 3)
    per_rep = blocks.mean(axis=(2, 4))  # (R, regions, regions, 3)
    mean = per_rep.mean(0)
    se = per_rep.std(0, ddof=1) / np.sqrt(R)
    return mean, se


def assert_agree(a: np.ndarray, b: np.ndarray, regions: int = 4, z: float = 5.0, label: str = ""):
    """Two stacks of independent renders agree per region within ``z`` combined standard errors."""
    ma, sa = region_stats(a, regions)
    mb, sb = region_stats(b, regions)
    sigma = np.sqrt(sa**2 + sb**2)
    # a floor for regions that are exactly deterministic in both (sigma = 0)
    sigma = np.maximum(sigma, 1e-6 * np.maximum(np.abs(ma), 1e-3))
    zs = np.abs(ma - mb) / sigma
    worst = np.unravel_index(np.argmax(zs), zs.shape)
    assert zs.max() < z, (f"{label}: region {worst[:2]} channel {worst[2]} differs by "
                          f"{zs.max():.1f} sigma ({ma[worst]:.5f} vs {mb[worst]:.5f})")
    return zs


@pytest.fixture(scope="session")
def rng_np():
    return np.random.default_rng(12345)
