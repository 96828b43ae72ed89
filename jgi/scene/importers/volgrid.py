"""Mitsuba's binary volume grids (``.vol``), the files of its ``gridvolume`` plugin.

Layout (little-endian; Mitsuba 3's ``VolumeGrid``):

    bytes 0-2   'VOL'
    byte  3     version: 3
    int32       encoding: 1 = float32 (the only one Mitsuba 3 reads; jgi too)
    int32 x3    xres, yres, zres
    int32       channels
    float32 x6  bounding box: xmin, ymin, zmin, xmax, ymax, zmax
    float32     data[((z * yres + y) * xres + x) * channels + c]   (x fastest)

:func:`read_vol` returns the grid as [nz, ny, nx, channels] with its box; every malformed
file is a :class:`VolError` naming the file and what was expected.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

HEADER = struct.Struct("<3sBi4i6f")   # magic, version, encoding, xres, yres, zres, channels, bbox


class VolError(ValueError):
    """A malformed .vol file (the message names it)."""


def read_vol(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(data [nz, ny, nx, channels] float32, bbox_min, bbox_max) of Mitsuba's .vol file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise VolError(f"{path}: cannot read the volume grid ({e.strerror or e})") from None
    if len(raw) < HEADER.size:
        raise VolError(f"{path}: {len(raw)} bytes, shorter than a .vol header ({HEADER.size} "
                       "bytes)")
    magic, version, encoding, nx, ny, nz, channels, *box = HEADER.unpack_from(raw)
    if magic != b"VOL":
        raise VolError(f"{path}: not a Mitsuba volume grid (starts with {magic!r}, expected "
                       "b'VOL')")
    if version != 3:
        raise VolError(f"{path}: .vol version {version}; supported: 3")
    if encoding != 1:
        raise VolError(f"{path}: .vol encoding {encoding}; supported: 1 (float32)")
    if min(nx, ny, nz, channels) < 1:
        raise VolError(f"{path}: resolution {nx} x {ny} x {nz} with {channels} channels; each "
                       "must be >= 1")
    count = nx * ny * nz * channels
    if len(raw) != HEADER.size + 4 * count:
        raise VolError(f"{path}: {len(raw) - HEADER.size} bytes of data, expected {4 * count} "
                       f"({nx} x {ny} x {nz} voxels x {channels} channels x 4 bytes)")
    data = np.frombuffer(raw, "<f4", count, HEADER.size).reshape(nz, ny, nx, channels)
    return (data.astype(np.float32), np.array(box[:3], np.float64),
            np.array(box[3:], np.float64))


def write_vol(path, data, bbox_min=(0.0, 0.0, 0.0), bbox_max=(1.0, 1.0, 1.0)) -> None:
    """Write ``data`` ([nz, ny, nx] or [nz, ny, nx, channels]) as a float32 .vol file."""
    a = np.asarray(data, np.float32)
    if a.ndim == 3:
        a = a[..., None]
    if a.ndim != 4:
        raise ValueError(f"write_vol: data of shape {a.shape}; expected [nz, ny, nx(, c)]")
    nz, ny, nx, channels = a.shape
    head = HEADER.pack(b"VOL", 3, 1, nx, ny, nz, channels,
                       *(float(v) for v in (*bbox_min, *bbox_max)))
    Path(path).write_bytes(head + a.astype("<f4").tobytes())
