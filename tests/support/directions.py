"""Directions for BSDF tests, built in float64 in a frame independent of jgi's."""

from __future__ import annotations

import numpy as np

NORMAL = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])


def direction(theta_deg, phi_deg=30.0, n=NORMAL) -> np.ndarray:
    """Unit vector at angle theta from n (a frame independent of jgi's)."""
    n = np.asarray(n, float)
    s = np.cross([1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0], n)
    s /= np.linalg.norm(s)
    t = np.cross(n, s)
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    return np.sin(th) * (np.cos(ph) * s + np.sin(ph) * t) + np.cos(th) * n


def reflect_np(w, n):
    return 2.0 * np.dot(w, n) * n - w
