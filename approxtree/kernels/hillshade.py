"""Cartographic hillshade over a height grid, with gdaldem's formulas and nodata rules.

Gradients from the 3 × 3 window (cell 4 in the centre)::

    0 1 2        Horn:                 x = ((w0 + 2 w3 + w6) − (w2 + 2 w5 + w8)) / (8 Δx)
    3 4 5                              y = ((w6 + 2 w7 + w8) − (w0 + 2 w1 + w2)) / (8 Δy)
    6 7 8        Zevenbergen–Thorne:   x = (w3 − w5) / (2 Δx),  y = (w7 − w1) / (2 Δy)

Δy is the signed row step (negative for north-up grids), as in gdaldem. The shade of a cell is
1 + 254 · cos(angle between the surface normal and the light), clamped to 1 when the cell faces
away from the light; 0 marks nodata (a window touching nodata, or the outer border).
"""

from __future__ import annotations

import math
import sys

import numpy as np
from numba import njit, prange

HORN = 0
ZEVENBERGEN_THORNE = 1

STANDARD = 0
COMBINED = 1
MULTIDIRECTIONAL = 2


@njit(cache=True, inline="always")
def _gradient(z, r, c, inv_ew, inv_ns, algorithm):
    """(x, y) gradient at interior cell (r, c), unscaled by the z factor's 1/8 or 1/2."""
    if algorithm == HORN:
        x = (
            (z[r - 1, c - 1] + 2.0 * z[r, c - 1] + z[r + 1, c - 1])
            - (z[r - 1, c + 1] + 2.0 * z[r, c + 1] + z[r + 1, c + 1])
        ) * inv_ew
        y = (
            (z[r + 1, c - 1] + 2.0 * z[r + 1, c] + z[r + 1, c + 1])
            - (z[r - 1, c - 1] + 2.0 * z[r - 1, c] + z[r - 1, c + 1])
        ) * inv_ns
    else:
        x = (z[r, c - 1] - z[r, c + 1]) * inv_ew
        y = (z[r + 1, c] - z[r - 1, c]) * inv_ns
    return x, y


@njit(cache=True, inline="always")
def _shade_cell(z, r, c, inv_ew, inv_ns, algorithm, mode, consts):
    """Shade of interior cell (r, c) in [1, 255] (float64, before float32 storage), 0 = nodata.

    consts: (sin_alt, cos_alt_z, cos_az, sin_az, c225, square_z) of the light and z factor.
    """
    sin_alt, cos_alt_z, cos_az, sin_az, c225, square_z = consts
    # Any nodata in the window leaves the cell nodata, as gdaldem does. Horn's gradient
    # reads the eight neighbours, so NaN shows up in it; only the centre needs a test.
    if np.isnan(z[r, c]):
        return 0.0
    if algorithm != HORN and (
        np.isnan(z[r - 1, c - 1])
        or np.isnan(z[r - 1, c + 1])
        or np.isnan(z[r + 1, c - 1])
        or np.isnan(z[r + 1, c + 1])
    ):
        return 0.0
    x, y = _gradient(z, r, c, inv_ew, inv_ns, algorithm)
    if np.isnan(x) or np.isnan(y):
        return 0.0
    xx_yy = x * x + y * y
    if mode == STANDARD:
        v = 254.0 * (sin_alt - (y * cos_az - x * sin_az)) / math.sqrt(1.0 + square_z * xx_yy)
        return 1.0 if v <= 0.0 else 1.0 + v
    if mode == COMBINED:
        slope = xx_yy * square_z
        cang = (sin_alt - (y * cos_az - x * sin_az)) / math.sqrt(1.0 + slope)
        cang = math.acos(min(1.0, max(-1.0, cang)))
        # Steeper cells get darker: weight the angle by the slope.
        cang = 1.0 - cang * math.atan(math.sqrt(slope)) / (math.pi * math.pi / 4.0)
        return 1.0 if cang <= 0.0 else 1.0 + 254.0 * cang
    if xx_yy == 0.0:
        return 1.0 + 254.0 * sin_alt
    # Four lights (225°, 270°, 315°, 360°) weighted by the aspect (USGS OF 92-422).
    v225 = max(0.0, 127.0 * (sin_alt + (x - y) * c225))
    v270 = max(0.0, 127.0 * (sin_alt - x * cos_alt_z))
    v315 = max(0.0, 127.0 * (sin_alt + (x + y) * c225))
    v360 = max(0.0, 127.0 * (sin_alt - y * cos_alt_z))
    w225 = 0.5 * xx_yy - x * y
    w270 = x * x
    w315 = xx_yy - w225
    w360 = y * y
    v = (w225 * v225 + w270 * v270 + w315 * v315 + w360 * v360) / xx_yy
    return 1.0 + v / math.sqrt(1.0 + square_z * xx_yy)


@njit(cache=True)
def _light_consts(z_factor, altitude, azimuth, algorithm):
    """(sin_alt, cos_alt_z, cos_az, sin_az, c225, square_z) for ``_shade_cell``."""
    zf = z_factor / (8.0 if algorithm == HORN else 2.0)
    alt = math.radians(altitude)
    az = math.radians(azimuth)
    cos_alt_z = math.cos(alt) * zf
    return (
        math.sin(alt),
        cos_alt_z,
        math.cos(az) * cos_alt_z,
        math.sin(az) * cos_alt_z,
        math.cos(math.radians(225.0)) * cos_alt_z,
        zf * zf,
    )


@njit(cache=True, parallel=True)
def hillshade(
    z: np.ndarray,
    dx: float,
    dy: float,
    z_factor: float,
    altitude: float,
    azimuth: float,
    algorithm: int,
    mode: int,
) -> np.ndarray:
    """Shade values of a height grid.

    z: (rows, cols) float, NaN = nodata. dx: column step (> 0); dy: signed row step in the same
    horizontal units (negative when row 0 is north). altitude, azimuth in degrees.
    Returns (rows, cols) float32 in [1, 255], 0 = nodata.
    """
    rows, cols = z.shape
    out = np.zeros((rows, cols), dtype=np.float32)
    inv_ew = 1.0 / dx
    inv_ns = 1.0 / dy
    consts = _light_consts(z_factor, altitude, azimuth, algorithm)
    for r in prange(1, rows - 1):
        for c in range(1, cols - 1):
            out[r, c] = _shade_cell(z, r, c, inv_ew, inv_ns, algorithm, mode, consts)
    return out


@njit(cache=True, parallel=True)
def hillshade_grey(
    z: np.ndarray,
    dx: float,
    dy: float,
    z_factor: float,
    altitude: float,
    azimuth: float,
    algorithm: int,
    mode: int,
) -> np.ndarray:
    """``hillshade`` rounded to grey levels in the kernel: (rows, cols) uint8, 0 = nodata.

    Each value is stored as float32 and rounded half to even, as ``np.rint`` of ``hillshade``
    would, without the (rows, cols) float32 temporary.
    """
    rows, cols = z.shape
    out = np.zeros((rows, cols), dtype=np.uint8)
    inv_ew = 1.0 / dx
    inv_ns = 1.0 / dy
    consts = _light_consts(z_factor, altitude, azimuth, algorithm)
    for r in prange(1, rows - 1):
        for c in range(1, cols - 1):
            v = np.float32(_shade_cell(z, r, c, inv_ew, inv_ns, algorithm, mode, consts))
            out[r, c] = np.uint8(np.rint(v))
    return out


@njit(cache=True, parallel=True)
def slope_degrees(z: np.ndarray, dx: float, dy: float, z_factor: float, algorithm: int):
    """Slope in degrees (gdaldem slope): (rows, cols) float32, NaN = nodata or border."""
    rows, cols = z.shape
    out = np.full((rows, cols), np.nan, dtype=np.float32)
    div = 8.0 if algorithm == HORN else 2.0
    for r in prange(1, rows - 1):
        for c in range(1, cols - 1):
            x, y = _gradient(z, r, c, 1.0 / dx, 1.0 / dy, algorithm)
            if not (np.isnan(x) or np.isnan(y)):
                out[r, c] = math.degrees(math.atan(z_factor * math.sqrt(x * x + y * y) / div))
    return out


@njit(cache=True, parallel=True)
def profile_curvature(z: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """Second derivative of height across the grid (Laplacian): (rows, cols) float32.

    Positive in hollows and valleys, negative on ridges and crests; NaN at nodata and borders.
    """
    rows, cols = z.shape
    out = np.full((rows, cols), np.nan, dtype=np.float32)
    for r in prange(1, rows - 1):
        for c in range(1, cols - 1):
            zxx = (z[r, c - 1] - 2.0 * z[r, c] + z[r, c + 1]) / (dx * dx)
            zyy = (z[r - 1, c] - 2.0 * z[r, c] + z[r + 1, c]) / (dy * dy)
            v = zxx + zyy
            if not np.isnan(v):
                out[r, c] = v
    return out


#: Shifts of grey and alpha in a uint16 texel whose bytes are (grey, alpha) in memory.
_GREY_SHIFT = 0 if sys.byteorder == "little" else 8
_ALPHA_SHIFT = 8 - _GREY_SHIFT


@njit(cache=True, inline="always")
def _texel(g: np.uint8) -> np.uint16:
    """The uint16 texel of grey g: bytes (grey, alpha) in memory, alpha 255 where g > 0."""
    a = np.uint16(255) if g > 0 else np.uint16(0)
    return (np.uint16(g) << np.uint16(_GREY_SHIFT)) | (a << np.uint16(_ALPHA_SHIFT))


@njit(cache=True, nogil=True, parallel=True)
def hillshade_grey_alpha_rows(
    z: np.ndarray,
    row0: int,
    out: np.ndarray,
    dx: float,
    dy: float,
    z_factor: float,
    altitude: float,
    azimuth: float,
    algorithm: int,
    mode: int,
) -> None:
    """Rows ``row0 .. row0 + n`` of ``hillshade_grey`` as a strip of grey and alpha texels.

    z: (rows, cols) float heights, the whole grid or a window of whole rows holding the strip
    and one row past each of its ends (the 3 × 3 window): z's first and last rows count as the
    grid's border. out: (n, cols) uint16, the view of an (n, cols, 2) uint8 array of
    interleaved texels (how the pyramid stores them), filled with the grey levels (0 = nodata
    and the border) and alpha (255 where grey > 0, else 0): the texels of ``hillshade_grey``
    of the grid. One uint16 store per texel keeps the loop vectorized (two interleaved byte
    stores run 5× slower). Without the GIL: a strip is shaded while other threads read the
    next and write the one before (GDAL; numba kernels are called from one thread only).
    """
    rows, cols = z.shape
    n = out.shape[0]
    inv_ew = 1.0 / dx
    inv_ns = 1.0 / dy
    consts = _light_consts(z_factor, altitude, azimuth, algorithm)
    for i in prange(n):
        r = row0 + i
        out[i, 0] = 0
        out[i, cols - 1] = 0
        if r < 1 or r >= rows - 1:
            for c in range(cols):
                out[i, c] = 0
            continue
        # gdaldem's default (Horn, standard) with both as constants: the compiler drops the
        # other algorithms' and modes' branches from the inner loop.
        if algorithm == HORN and mode == STANDARD:
            for c in range(1, cols - 1):
                v = np.float32(_shade_cell(z, r, c, inv_ew, inv_ns, HORN, STANDARD, consts))
                out[i, c] = _texel(np.uint8(np.rint(v)))
            continue
        for c in range(1, cols - 1):
            v = np.float32(_shade_cell(z, r, c, inv_ew, inv_ns, algorithm, mode, consts))
            out[i, c] = _texel(np.uint8(np.rint(v)))
