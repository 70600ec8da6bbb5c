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
        r0 = 2 * i
        r1 = min(r0 + 1, rows - 1)
        for j in range(out_cols):
            c0 = 2 * j
            c1 = min(c0 + 1, cols - 1)
            a00 = np.int64(src[r0, c0, 3])
            a01 = np.int64(src[r0, c1, 3])
            a10 = np.int64(src[r1, c0, 3])
            a11 = np.int64(src[r1, c1, 3])
            wsum = a00 + a01 + a10 + a11
            for k in range(3):
                if wsum > 0:
                    num = (
                        a00 * src[r0, c0, k]
                        + a01 * src[r0, c1, k]
                        + a10 * src[r1, c0, k]
                        + a11 * src[r1, c1, k]
                    )
                    out[i, j, k] = _round_ratio(num, wsum)
                else:
                    out[i, j, k] = 0
            out[i, j, 3] = _round_ratio(wsum, 4)
