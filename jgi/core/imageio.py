"""Image output: OpenEXR (linear float32 RGB) and tone-mapped PNG (matplotlib's writer)."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import OpenEXR


def write_exr(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an (H, W, 3) float image as a float32 RGB OpenEXR file."""

    img = np.ascontiguousarray(np.asarray(image, np.float32))
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"{path}: expected an (H, W, 3) image, got shape {img.shape}")
    channels = {"R": img[:, :, 0].copy(), "G": img[:, :, 1].copy(), "B": img[:, :, 2].copy()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


def read_exr(path: str | os.PathLike) -> np.ndarray:
    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        if "RGB" in ch:
            return np.asarray(ch["RGB"].pixels, np.float32)
        return np.stack([np.asarray(ch[c].pixels, np.float32) for c in "RGB"], axis=-1)


def tonemap(image: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Exposure (stops), then the sRGB transfer curve, clipped to [0, 1]."""
    x = np.clip(np.nan_to_num(np.asarray(image, np.float32) * 2.0 ** exposure), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def write_png(path: str | os.PathLike, image: np.ndarray, exposure: float = 0.0) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    mpimg.imsave(str(path), tonemap(image, exposure))
