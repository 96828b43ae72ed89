"""Spectra to linear sRGB, as Mitsuba 3's RGB variants and pbrt-v4's RGB film convert them.

A spectrum is given as (wavelength nm, value) pairs (inline lists, ``.spd`` files), as a
blackbody temperature, or by one of pbrt-v4's names. jgi renders in RGB, so each importer turns
a spectrum into the RGB its renderer would see:

- Mitsuba 3 (``spectrum_list_to_srgb`` in src/core/spectrum.cpp, called by its XML loader in
  RGB variants): 1000 points evenly spaced over [360, 830] nm, those inside the list's range
  weighted by the piecewise-linear spectrum, Mitsuba's 5 nm CIE 1931 table (linearly
  interpolated) and, outside emitters, its normalised D65; times 470 / 1000 / 106.75; Mitsuba's
  XYZ -> sRGB matrix; reflectances clamped to [0, 1], emission and eta / k to >= 0. A constant
  spectrum is that constant, in emitters times xyz_to_srgb(1, 1, 1) (Mitsuba's "purple-ish"
  equal-energy white). Mitsuba's RGB variants cannot render a ``blackbody``; jgi takes what its
  spectral variants write to an RGB film: the Planck radiance (W m^-2 sr^-1 nm^-1) integrated
  against the same CIE curves over [wavelength_min, wavelength_max].
- pbrt-v4 (sensor "cie1931", the default of its RGB film): XYZ = sum over 360..830 nm (1 nm)
  of the spectrum times the CIE 1931 curves, then XYZ -> linear sRGB with pbrt's matrix (from
  the sRGB primaries and the white of its D65 table). Light spectra are divided by their
  photometric integral (``SpectrumToPhotometric``: luminance 1 times the light's "scale"); a
  reflectance or other non-emitted spectrum is seen under the colour space's illuminant
  (D65, normalised to luminance 1): exact for an RGB-white light, an approximation under
  coloured light, where pbrt multiplies spectra wavelength by wavelength.

CIE 1931 2-degree colour matching functions and the standard illuminants come from
colour-science (CIE's published tables); D65 past 780 nm (which colour-science does not
tabulate) from CIE 15 (the values Mitsuba's and pbrt's tables hold).
"""

from __future__ import annotations

import functools
import math
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np

CIE_MIN, CIE_MAX = 360, 830
CIE_NM = np.arange(CIE_MIN, CIE_MAX + 1, dtype=float)          # 1 nm, pbrt's sampling
_CIE_5NM = CIE_NM[::5]                                          # Mitsuba's 95-sample table
D65_NM = np.arange(300, 831, 5, dtype=float)

# CIE D65 at 785..830 nm (5 nm): CIE 15, table T.1; colour-science's D65 stops at 780 nm
_D65_TAIL = (63.8434, 64.304, 61.8779, 59.4519, 55.7054, 51.959, 54.6998, 57.4406, 58.8765,
             60.3125)

# Mitsuba 3 (include/mitsuba/core/spectrum.h)
MITSUBA_CIE_Y_NORMALIZATION = 1.0 / 106.7502593994140625
MITSUBA_D65_NORMALIZATION = 1.0 / 98.99741751876255
MITSUBA_XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                                [-0.969256, 1.875991, 0.041556],
                                [0.055648, -0.204043, 1.057311]])
MITSUBA_BLACKBODY_STEPS = 4096   # quadrature of Planck x CIE (smooth: converged to ~1e-7)

# Physical constants as Mitsuba's blackbody.cpp and pbrt-v4's Blackbody() write them
_MITSUBA_PLANCK = (2.99792458e8, 6.62607004e-34, 1.38064852e-23)
_PBRT_PLANCK = (299792458.0, 6.62606957e-34, 1.3806488e-23)


class SpectrumError(ValueError):
    """A malformed spectrum (the importers add the file and line)."""


def parse_pairs(numbers, what: str = "spectrum") -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths, values) from interleaved numbers; wavelengths must increase."""
    a = np.asarray(numbers, float).reshape(-1)
    if a.size == 0 or a.size % 2:
        raise SpectrumError(f"{what}: expected (wavelength, value) pairs, got {a.size} numbers")
    wl, val = a[0::2], a[1::2]
    if np.any(np.diff(wl) <= 0):
        raise SpectrumError(f"{what}: wavelengths must increase, got {wl.tolist()}")
    if not np.all(np.isfinite(a)):
        raise SpectrumError(f"{what}: values must be finite")
    return wl, val


def read_spd(path) -> tuple[np.ndarray, np.ndarray]:
    """A ``.spd`` file: whitespace- or comma-separated (wavelength, value) pairs, '#'
    comments (the format Mitsuba's spectrum_from_file and pbrt's ReadFloatFile read)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise SpectrumError(f"cannot read spectrum file '{path}': {e}") from None
    nums = []
    for line in text.splitlines():
        line = line.split("#", 1)[0]
        for tok in re.split(r"[\s,]+", line.strip()):
            if tok:
                try:
                    nums.append(float(tok))
                except ValueError:
                    raise SpectrumError(f"spectrum file '{path}': '{tok}' is not a "
                                        "number") from None
    return parse_pairs(nums, f"spectrum file '{path.name}'")


def parse_mitsuba_value(text: str) -> tuple[np.ndarray, np.ndarray] | float:
    """Mitsuba's <spectrum value=...>: one number (a constant) or "wl:v, wl:v, ..." pairs."""
    text = text.strip()
    if ":" not in text:
        try:
            return float(text)
        except ValueError:
            raise SpectrumError(f"'{text}' is neither a number nor wavelength:value "
                                "pairs") from None
    nums = []
    for item in text.split(","):
        parts = item.split(":")
        if len(parts) != 2:
            raise SpectrumError(f"'{item.strip()}' is not a wavelength:value pair")
        try:
            nums += [float(parts[0]), float(parts[1])]
        except ValueError:
            raise SpectrumError(f"'{item.strip()}' is not a wavelength:value pair") from None
    return parse_pairs(nums)


def planck(wavelength_nm, temperature: float, constants=_MITSUBA_PLANCK) -> np.ndarray:
    """Planck's law: black-body spectral radiance in W m^-2 sr^-1 m^-1 at wavelength_nm."""
    c, h, k = constants
    lam = np.asarray(wavelength_nm, float) * 1e-9
    with np.errstate(over="ignore"):   # far below the peak exp overflows: B is 0 there
        return 2 * h * c * c / (lam ** 5 * np.expm1(h * c / (lam * k * temperature)))


def _check_temperature(temperature: float):
    if not (math.isfinite(temperature) and temperature > 0):
        raise SpectrumError(f"blackbody temperature must be > 0 kelvin, got {temperature}")


# --- Mitsuba 3 ----------------------------------------------------------------------------
def mitsuba_cie_xyz(wavelength_nm) -> np.ndarray:
    """Mitsuba's cie1931_xyz: its 5 nm table, linearly interpolated, 0 outside [360, 830]."""
    w = np.asarray(wavelength_nm, float)
    return np.stack([np.interp(w, _CIE_5NM, _cie().CIE_XYZ_5NM[:, i], left=0.0, right=0.0)
                     for i in range(3)], -1)


def mitsuba_d65(wavelength_nm) -> np.ndarray:
    """Mitsuba's cie_d65: D65 (5 nm, linear) times MI_CIE_D65_NORMALIZATION in [360, 830]."""
    w = np.asarray(wavelength_nm, float)
    inside = (w >= CIE_MIN) & (w <= CIE_MAX)
    return np.where(inside, np.interp(w, D65_NM, _cie().D65) * MITSUBA_D65_NORMALIZATION, 0.0)


def mitsuba_rgb(spectrum, emitter: bool = False, unbounded: bool = False) -> np.ndarray:
    """The RGB Mitsuba 3's RGB variants give a <spectrum>: ``spectrum`` is a constant or
    (wavelengths, values); ``emitter`` for emitters' radiance / intensity / irradiance,
    ``unbounded`` for values that are not reflectances (a conductor's eta and k)."""
    if not isinstance(spectrum, tuple):
        v = float(spectrum)
        return v * MITSUBA_XYZ_TO_SRGB.sum(1) if emitter else np.full(3, v)
    wl, val = (np.asarray(a, float) for a in spectrum)
    if len(wl) == 1:
        return mitsuba_rgb(float(val[0]), emitter, unbounded)
    steps = 1000
    w = CIE_MIN + np.arange(steps) / (steps - 1) * (CIE_MAX - CIE_MIN)
    w = w[(w >= wl[0]) & (w <= wl[-1])]
    v = np.interp(w, wl, val)
    weight = v if emitter else v * mitsuba_d65(w)
    xyz = (mitsuba_cie_xyz(w) * weight[:, None]).sum(0)
    xyz *= (CIE_MAX - CIE_MIN) * MITSUBA_CIE_Y_NORMALIZATION / steps
    rgb = MITSUBA_XYZ_TO_SRGB @ xyz
    return np.clip(rgb, 0.0, None if (emitter or unbounded) else 1.0)


def mitsuba_blackbody_rgb(temperature: float, wavelength_min: float = CIE_MIN,
                          wavelength_max: float = CIE_MAX) -> np.ndarray:
    """What Mitsuba 3's spectral variants write to an RGB film for a ``blackbody`` emitter
    (radiance in W m^-2 sr^-1 nm^-1, blackbody.cpp's 1e-9 factor): the integral against the
    CIE curves times MI_CIE_Y_NORMALIZATION, then Mitsuba's XYZ -> sRGB."""
    _check_temperature(temperature)
    lo, hi = max(wavelength_min, CIE_MIN), min(wavelength_max, CIE_MAX)
    if not hi > lo:
        return np.zeros(3)
    # midpoint rule on a fine grid, with the 5 nm table's kinks on it
    edges = np.linspace(lo, hi, MITSUBA_BLACKBODY_STEPS + 1)
    w = 0.5 * (edges[1:] + edges[:-1])
    radiance = 1e-9 * planck(w, temperature)
    xyz = (mitsuba_cie_xyz(w) * (radiance * np.diff(edges))[:, None]).sum(0)
    return MITSUBA_XYZ_TO_SRGB @ (xyz * MITSUBA_CIE_Y_NORMALIZATION)


# --- pbrt-v4 ------------------------------------------------------------------------------
def _xyz_from_primaries(white_xyz) -> np.ndarray:
    """pbrt-v4's RGBColorSpace: the XYZ-from-RGB matrix of the sRGB primaries scaled so that
    RGB (1, 1, 1) is the white."""
    prim = np.array([[0.64, 0.33], [0.30, 0.60], [0.15, 0.06]])
    cols = np.stack([[x / y, 1.0, (1 - x - y) / y] for x, y in prim], 1)
    return cols * np.linalg.solve(cols, white_xyz)[None, :]


def pbrt_sample(spectrum) -> np.ndarray:
    """A spectrum at pbrt's 1 nm wavelengths 360..830: (wavelengths, values) piecewise linear
    and 0 outside its range (PiecewiseLinearSpectrum), or a constant."""
    if not isinstance(spectrum, tuple):
        return np.full(CIE_NM.shape, float(spectrum))
    wl, val = (np.asarray(a, float) for a in spectrum)
    inside = (CIE_NM >= wl[0]) & (CIE_NM <= wl[-1])
    return np.where(inside, np.interp(CIE_NM, wl, val), 0.0)


PBRT_CIE_Y_INTEGRAL = 106.856895

# The CIE tables come from colour-science, whose import takes half a second: they are built on
# first use (every jgi start-up would pay otherwise), and read as module attributes
# (spectra.CIE_XYZ, spectra.D65, ...) or, inside this module, as _cie().NAME.
_LAZY = ("CIE_XYZ", "D65", "PBRT_D65", "PBRT_XYZ_FROM_SRGB", "PBRT_SRGB_FROM_XYZ")


@functools.cache
def _cie() -> SimpleNamespace:
    import colour  # imported here: see above

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    t = SimpleNamespace(colour=colour)
    t.CIE_XYZ = np.asarray(cmfs[CIE_NM], float)                      # [471, 3]
    t.CIE_XYZ_5NM = t.CIE_XYZ[::5]
    d65 = colour.SDS_ILLUMINANTS["D65"]
    t.D65 = np.concatenate([np.asarray(d65[np.arange(300, 781, 5)], float), _D65_TAIL])
    t.PBRT_D65 = pbrt_sample((D65_NM, t.D65))
    white = (t.CIE_XYZ * t.PBRT_D65[:, None]).sum(0) / (t.CIE_XYZ[:, 1] * t.PBRT_D65).sum()
    t.PBRT_XYZ_FROM_SRGB = _xyz_from_primaries(white)
    t.PBRT_SRGB_FROM_XYZ = np.linalg.inv(t.PBRT_XYZ_FROM_SRGB)
    return t


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(_cie(), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def pbrt_rgb(spectrum, illuminant: bool) -> np.ndarray:
    """The linear sRGB pbrt-v4's RGB film (sensor "cie1931") sees of a spectrum (see the
    module docstring): an ``illuminant`` divided by its photometric integral (luminance 1), any
    other spectrum under the colour space's D65 white (a constant c gives c (1, 1, 1) up to
    the tables' rounding). ``spectrum`` is a constant, (wavelengths, values) or sampled
    values at 360..830 nm."""
    s = spectrum if isinstance(spectrum, np.ndarray) else pbrt_sample(spectrum)
    cie = _cie()
    if illuminant:
        y = float((s * cie.CIE_XYZ[:, 1]).sum())
        if not y > 0:
            raise SpectrumError("an emission spectrum must have a positive luminance "
                                "(pbrt divides it by its photometric integral)")
        xyz = (cie.CIE_XYZ * s[:, None]).sum(0) / y
    else:
        xyz = ((cie.CIE_XYZ * (s * cie.PBRT_D65)[:, None]).sum(0)
               / (cie.CIE_XYZ[:, 1] * cie.PBRT_D65).sum())
    return cie.PBRT_SRGB_FROM_XYZ @ xyz


def pbrt_blackbody(temperature: float) -> np.ndarray:
    """pbrt-v4's BlackbodySpectrum at 360..830 nm: Planck's law normalised to 1 at Wien's
    peak (lambda_max = 2.8977721e-3 m K / T)."""
    _check_temperature(temperature)
    peak = planck(2.8977721e-3 / temperature * 1e9, temperature, _PBRT_PLANCK)
    return planck(CIE_NM, temperature, _PBRT_PLANCK) / peak


# pbrt-v4's named spectra jgi converts: CIE standard illuminants (util/spectrum.cpp's
# "stdillum-*", each normalised there to a photometric integral of CIE_Y_integral). D65 and
# F1..F12 (380..780 nm) from the tables above, A from its defining formula (Planck's law at
# 2848 K with c2 = 1.435e-2 m K, 100 at 560 nm); pbrt's D50 table (to 830 nm) is not carried
_PBRT_ILLUMINANTS = {f"stdillum-F{i}": f"FL{i}" for i in range(1, 13)}


def cie_illuminant_a(wavelength_nm) -> np.ndarray:
    """CIE standard illuminant A (CIE 15), relative to 100 at 560 nm."""
    w = np.asarray(wavelength_nm, float)
    c2 = 1.435e7   # nm K
    return 100 * (560 / w) ** 5 * np.expm1(c2 / (2848 * 560)) / np.expm1(c2 / (2848 * w))


def pbrt_named(name: str) -> np.ndarray | None:
    """pbrt-v4's named illuminant spectrum ``name`` at 360..830 nm (luminance 1: pbrt's
    normalisation), or None if jgi does not carry it."""
    if name == "stdillum-D65":
        s = _cie().PBRT_D65
    elif name == "stdillum-A":
        s = cie_illuminant_a(CIE_NM)
    elif name in _PBRT_ILLUMINANTS:
        sd = _cie().colour.SDS_ILLUMINANTS[_PBRT_ILLUMINANTS[name]]
        lo, hi = sd.shape.start, sd.shape.end
        wl = np.arange(lo, hi + 1e-9, sd.shape.interval)
        s = pbrt_sample((wl, np.asarray(sd[wl], float)))
    else:
        return None
    return s * PBRT_CIE_Y_INTEGRAL / float((s * _cie().CIE_XYZ[:, 1]).sum())


def pbrt_named_illuminants() -> tuple[str, ...]:
    return ("stdillum-D65", "stdillum-A") + tuple(_PBRT_ILLUMINANTS)
