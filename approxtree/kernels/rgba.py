"""RGBA texel kernels of the texture pyramid: grey levels to RGBA, and the 2 × 2 halving.

Both work on uint8 in integer arithmetic and write into a caller's array, so a pyramid is
assembled strip by strip without float64 or full-size temporaries.
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
def halve_rgba(src: np.ndarray, out: np.ndarray) -> None:
    """2 × 2 alpha-weighted box filter of (rows, cols, 4) uint8 into ``out``
    (⌈rows/2⌉, ⌈cols/2⌉, 4) uint8.

    Colour is the alpha-weighted mean of the four texels (0 where all four are transparent),
    alpha their mean, both rounded half to even. Odd sizes repeat the last row or column, so
    every output texel has four inputs. Integer sums give exactly the values of the float64
    formula: a quotient of integers below 2^53 is rounded correctly, and a non-tie lies at
    least 1/2040 from a tie.
    """
    rows, cols = src.shape[0], src.shape[1]
    out_rows, out_cols = out.shape[0], out.shape[1]
    for i in prange(out_rows):
        # Rows as flat bytes: texel c of a row starts at byte 4 c. An odd last row or column
        # pairs with itself.
        top = src[2 * i].reshape(4 * cols)
        bottom = src[min(2 * i + 1, rows - 1)].reshape(4 * cols)
        dst = out[i].reshape(4 * out_cols)
        for j in range(out_cols):
            p0 = 8 * j
            p1 = p0 + 4 if 2 * j + 1 < cols else p0
            q = 4 * j
            a00 = np.int64(top[p0 + 3])
            a01 = np.int64(top[p1 + 3])
            a10 = np.int64(bottom[p0 + 3])
            a11 = np.int64(bottom[p1 + 3])
            wsum = a00 + a01 + a10 + a11
            if wsum == 1020:
                # All four opaque (most texels): equal weights, a plain mean of four.
                for k in range(3):
                    total = (
                        np.int64(top[p0 + k])
                        + np.int64(top[p1 + k])
                        + np.int64(bottom[p0 + k])
                        + np.int64(bottom[p1 + k])
                    )
                    dst[q + k] = _round_quarter(total)
                dst[q + 3] = 255
                continue
            for k in range(3):
                if wsum > 0:
                    num = (
                        a00 * top[p0 + k]
                        + a01 * top[p1 + k]
                        + a10 * bottom[p0 + k]
                        + a11 * bottom[p1 + k]
                    )
                    dst[q + k] = _round_ratio(num, wsum)
                else:
                    dst[q + k] = 0
            dst[q + 3] = _round_quarter(wsum)
