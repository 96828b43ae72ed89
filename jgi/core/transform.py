"""4x4 affine transforms built on the host with numpy (scene construction, not hot paths)."""

from __future__ import annotations

import numpy as np


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = np.asarray(v, float)
    return m


def scale(s) -> np.ndarray:
    s = np.broadcast_to(np.asarray(s, float), (3,))
    return np.diag([s[0], s[1], s[2], 1.0])


def rotate(axis, degrees: float) -> np.ndarray:
    """Right-handed rotation about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, float)
    n = np.linalg.norm(a)
    if n == 0:
        raise ValueError("rotation axis must be non-zero")
    x, y, z = a / n
    t = np.radians(degrees)
    c, s = np.cos(t), np.sin(t)
    C = 1 - c
    m = np.eye(4)
    m[:3, :3] = [
        [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
        [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
        [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
    ]
    return m


def look_at(origin, target, up) -> np.ndarray:
    """Camera-to-world with the camera looking down +z (Mitsuba/pbrt convention), x left."""
    o, t, u = (np.asarray(v, float) for v in (origin, target, up))
    d = t - o
    d = d / np.linalg.norm(d)
    left = np.cross(u, d)
    left = left / np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, o
    return m


def apply_point(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    p = np.asarray(p, float)
    return p @ m[:3, :3].T + m[:3, 3]


def apply_vector(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.asarray(v, float) @ m[:3, :3].T
