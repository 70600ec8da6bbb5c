"""RGBA texel kernels of the texture pyramid: grey levels to RGBA, and the 2 × 2 halving.

They work on uint8 in integer arithmetic and write into a caller's array, so a pyramid is
assembled strip by strip without float64 or full-size temporaries. The pyramid's strips are
in band order (4, rows, cols), the layout GDAL takes without a copy.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, parallel=True)
def grey_into_rgba(grey: np.ndarray, out: np.ndarray) -> None:
    """(rows, cols) uint8 grey levels (0 = nodata) → ``out`` (rows, cols, 4) uint8, R = G = B,
    alpha 255 where grey > 0 and 0 elsewhere."""
    rows, cols = grey.shape
    for r in prange(rows):
        for c in range(cols):
            g = grey[r, c]
            out[r, c, 0] = g
            out[r, c, 1] = g
            out[r, c, 2] = g
            out[r, c, 3] = 255 if g > 0 else 0


@njit(cache=True, inline="always")
def _round_ratio(num: int, den: int) -> int:
    """num / den rounded half to even (numpy's round), for num ≥ 0 and den > 0."""
    q = num // den
    twice = 2 * (num - q * den)
    if twice > den or (twice == den and q % 2 == 1):
        q += 1
    return q


@njit(cache=True, inline="always")
def _round_quarter(s: int) -> int:
    """s / 4 rounded half to even, for s ≥ 0, without branches: adding 1 + (⌊s/4⌋ odd)
    before the shift carries exactly the remainders 3, and 2 when ⌊s/4⌋ is odd."""
    return (s + 1 + ((s >> 2) & 1)) >> 2


@njit(cache=True, parallel=True)
def grey_into_bands(grey: np.ndarray, out: np.ndarray) -> None:
    """(rows, cols) uint8 grey levels (0 = nodata) → ``out`` (4, rows, cols) uint8 in band
    order (R, G, B, A planes, as GDAL writes them): R = G = B = grey, A = 255 where grey > 0."""
    rows, cols = grey.shape
    for r in prange(rows):
        for c in range(cols):
            g = grey[r, c]
            out[0, r, c] = g
            out[1, r, c] = g
            out[2, r, c] = g
            out[3, r, c] = 255 if g > 0 else 0


#: Pairs of columns whose alphas ``halve_bands`` tests at once.
_BLOCK = 64


@njit(cache=True, inline="always")
def _halve_texel(src, out, alpha, i, j, r0, r1, cols):
    """Texel (i, j) of ``halve_bands`` from rows r0, r1 of ``src``: the alpha-weighted mean."""
    c0 = 2 * j
    c1 = min(c0 + 1, cols - 1)
    a00 = np.int64(src[alpha, r0, c0])
    a01 = np.int64(src[alpha, r0, c1])
    a10 = np.int64(src[alpha, r1, c0])
    a11 = np.int64(src[alpha, r1, c1])
    wsum = a00 + a01 + a10 + a11
    for k in range(alpha):
        if wsum > 0:
            num = (
                a00 * src[k, r0, c0]
                + a01 * src[k, r0, c1]
                + a10 * src[k, r1, c0]
                + a11 * src[k, r1, c1]
            )
            out[k, i, j] = _round_ratio(num, wsum)
        else:
            out[k, i, j] = 0
    out[alpha, i, j] = _round_quarter(wsum)


@njit(cache=True, nogil=True)
def halve_bands(src: np.ndarray, out: np.ndarray) -> None:
    """2 × 2 alpha-weighted box filter of (bands, rows, cols) uint8 planes, alpha last (R, G,
    B, A or grey, A), into ``out`` (bands, ⌈rows/2⌉, ⌈cols/2⌉) uint8.

    Serial and without the GIL: the pyramid halves a strip on its writer thread while the
    main thread makes the next strip (a parallel kernel may be launched from one thread only).

    Colour is the alpha-weighted mean of the four texels (0 where all four are transparent),
    alpha their mean, both rounded half to even. Odd sizes repeat the last row or column, so
    every output texel has four inputs. Integer sums give exactly the values of the float64
    formula: a quotient of integers below 2^53 is rounded correctly, and a non-tie lies at
    least 1/2040 from a tie.
    """
    alpha = src.shape[0] - 1
    rows, cols = src.shape[1], src.shape[2]
    out_rows, out_cols = out.shape[1], out.shape[2]
    pairs = cols // 2
    for i in range(out_rows):
        # An odd last row or column pairs with itself.
        r0 = 2 * i
        r1 = min(r0 + 1, rows - 1)
        # Every band as if its four texels were opaque (most texels): a plain mean of four
        # in 16-bit lanes, a loop over row views that the compiler vectorizes.
        for k in range(alpha + 1):
            u = src[k, r0]
            v = src[k, r1]
            o = out[k, i]
            for j in range(pairs):
                s = (
                    np.uint16(u[2 * j])
                    + np.uint16(u[2 * j + 1])
                    + np.uint16(v[2 * j])
                    + np.uint16(v[2 * j + 1])
                )
                o[j] = np.uint8(
                    (s + np.uint16(1) + ((s >> np.uint16(2)) & np.uint16(1))) >> np.uint16(2)
                )
        # Then, with the weights, the texels that are not (a transparent or partial alpha
        # among the four): found by blocks of _BLOCK pairs, each tested at once in a
        # vectorized loop, so only a block holding one is scanned texel by texel.
        a0 = src[alpha, r0]
        a1 = src[alpha, r1]
        for b0 in range(0, pairs, _BLOCK):
            b1 = min(b0 + _BLOCK, pairs)
            opaque = np.uint8(255)
            for j in range(b0, b1):
                opaque &= a0[2 * j] & a0[2 * j + 1] & a1[2 * j] & a1[2 * j + 1]
            if opaque == 255:
                continue
            for j in range(b0, b1):
                if a0[2 * j] & a0[2 * j + 1] & a1[2 * j] & a1[2 * j + 1] != 255:
                    _halve_texel(src, out, alpha, i, j, r0, r1, cols)
        # An odd last column.
        for j in range(pairs, out_cols):
            _halve_texel(src, out, alpha, i, j, r0, r1, cols)


@njit(cache=True)
def bands_into_rgba(planes: np.ndarray, out: np.ndarray) -> None:
    """(bands, rows, cols) uint8 planes of a pyramid level, alpha last (grey and alpha, or R,
    G, B and alpha), into ``out[:rows, :cols]`` of a (≥ rows, ≥ cols, 4) uint8 RGBA array:
    grey fills R, G and B. The rest of ``out`` is left as it is. Serial: patches are read on
    a loader thread, and small ones would wait longer for a thread pool than they take."""
    bands, rows, cols = planes.shape
    for r in range(rows):
        if bands == 2:
            for c in range(cols):
                g = planes[0, r, c]
                out[r, c, 0] = g
                out[r, c, 1] = g
                out[r, c, 2] = g
                out[r, c, 3] = planes[1, r, c]
        else:
            for c in range(cols):
                for k in range(4):
                    out[r, c, k] = planes[k, r, c]


@njit(cache=True, nogil=True)
def box_halve_rgba(src: np.ndarray, out: np.ndarray) -> None:
    """2 × 2 box mean of (rows, cols, channels) uint8 texels into ``out`` (⌊rows/2⌋,
    ⌊cols/2⌋, channels) uint8, rounded half up ((sum + 2) >> 2): one mip level from the one
    above (an odd last row or column is dropped, as GL sizes mip levels).

    Serial and without the GIL: texture patches' mip chains are made on a worker thread
    while the main thread draws.
    """
    rows, cols, channels = out.shape
    for i in range(rows):
        a = src[2 * i]
        b = src[2 * i + 1]
        o = out[i]
        for j in range(cols):
            for k in range(channels):
                s = (
                    np.uint16(a[2 * j, k])
                    + np.uint16(a[2 * j + 1, k])
                    + np.uint16(b[2 * j, k])
                    + np.uint16(b[2 * j + 1, k])
                )
                o[j, k] = np.uint8((s + np.uint16(2)) >> np.uint16(2))
