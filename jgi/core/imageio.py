"""Images: OpenEXR (linear float32 RGB) and tone-mapped PNG output (matplotlib's writer);
texture and environment input (EXR, Radiance RGBE, PNG, JPEG) as linear RGB."""

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


def read_hdr(path: str | os.PathLike, centred: bool = False) -> np.ndarray:
    """An [H, W, 3] float32 image from a Radiance RGBE file (.hdr / .rgbe: flat or new-style
    run-length encoded scanlines, the usual ``-Y H +X W`` layout), decoded as Mitsuba 3 and
    Walter's reference reader do: (r, g, b) 2^(e - 136), 0 where e = 0.

    ``centred``: (r, g, b) + 1/2 instead, the middle of the quantisation step, as Radiance's
    own reader decodes. Writers truncate each channel to its step, so the plain decoding is
    low by half a step on average (0.2 % to a few % of a pixel, more in the weaker channels):
    take centred values to compare another renderer's mean radiance with jgi's."""
    data = Path(path).read_bytes()
    pos, fmt = 0, None
    if not data.startswith((b"#?RADIANCE", b"#?RGBE")):
        raise OSError(f"{path}: not a Radiance RGBE file (no '#?RADIANCE' header)")
    while True:                                   # header lines, up to an empty one
        end = data.find(b"\n", pos)
        if end < 0:
            raise OSError(f"{path}: truncated header")
        line, pos = data[pos:end].strip(), end + 1
        if not line:
            break
        if line.startswith(b"FORMAT="):
            fmt = line[7:]
    if fmt not in (None, b"32-bit_rle_rgbe"):
        raise OSError(f"{path}: format {fmt.decode(errors='replace')} is not supported "
                      "(allowed: 32-bit_rle_rgbe)")
    end = data.find(b"\n", pos)
    res = data[pos:end].split()
    if len(res) != 4 or res[0] != b"-Y" or res[2] != b"+X":
        raise OSError(f"{path}: resolution line {data[pos:end]!r} is not supported (allowed: "
                      "'-Y height +X width')")
    H, W = int(res[1]), int(res[3])
    buf = np.frombuffer(data, np.uint8, offset=end + 1)
    out = np.zeros((H, W, 4), np.uint8)
    i = 0
    for y in range(H):
        if 8 <= W < 32768 and i + 4 <= len(buf) and buf[i] == 2 and buf[i + 1] == 2 \
                and (int(buf[i + 2]) << 8 | int(buf[i + 3])) == W:
            i += 4
            for c in range(4):                    # each channel run-length encoded
                x = 0
                while x < W:
                    n = int(buf[i])
                    if n > 128:
                        n -= 128
                        out[y, x:x + n, c] = buf[i + 1]
                        i += 2
                    else:
                        out[y, x:x + n, c] = buf[i + 1:i + 1 + n]
                        i += 1 + n
                    if n == 0 or x + n > W:
                        raise OSError(f"{path}: corrupt run-length data in scanline {y}")
                    x += n
        else:                                     # a flat scanline
            if i + 4 * W > len(buf):
                raise OSError(f"{path}: truncated pixel data")
            out[y] = buf[i:i + 4 * W].reshape(W, 4)
            i += 4 * W
    e = out[..., 3].astype(np.int32)
    f = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)
    return ((out[..., :3] + (0.5 if centred else 0.0)) * f[..., None]).astype(np.float32)


def srgb_decode(x) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear (IEC 61966-2-1), as Mitsuba decodes 8-bit images."""
    x = np.asarray(x, np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def read_image(path: str | os.PathLike, raw: bool = False) -> np.ndarray:
    """An [H, W, 3] float64 linear RGB image (row 0 the top) from an EXR (linear already) or a
    PNG / JPEG file (matplotlib's reader; integer images scaled to [0, 1] and, unless ``raw``,
    sRGB-decoded, as Mitsuba's bitmap texture does with raw=false). Alpha is dropped, grey is
    repeated into three channels."""
    path = Path(path)
    if not path.is_file():
        raise OSError(f"no such file '{path}'")
    if path.suffix.lower() == ".exr":
        return np.asarray(read_exr(path), np.float64)
    if path.suffix.lower() in (".hdr", ".rgbe", ".pic"):
        return np.asarray(read_hdr(path), np.float64)
    img = mpimg.imread(str(path))
    if np.issubdtype(img.dtype, np.integer):
        img = img / float(np.iinfo(img.dtype).max)
    img = np.asarray(img, np.float64)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    img = img[:, :, :3]
    return img if raw else srgb_decode(img)


def tonemap(image: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Exposure (stops), then the sRGB transfer curve, clipped to [0, 1]."""
    x = np.clip(np.nan_to_num(np.asarray(image, np.float32) * 2.0 ** exposure), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def write_png(path: str | os.PathLike, image: np.ndarray, exposure: float = 0.0) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    mpimg.imsave(str(path), tonemap(image, exposure))
