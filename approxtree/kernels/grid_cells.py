"""Figures of a grid patch per lattice cell, so that an edit re-measures only the cells it reaches.

A grid patch (r0, r1, c0, c1, sr, sc) samples rows r0, r0 + sr, ... and r1 (likewise columns);
its lattice cell (k, j) owns the data rows r0 + k·sr .. r0 + (k+1)·sr − 1 (the last cell down
to r1) and the columns likewise. Each point is measured by ``grid_patch.grid_patch_part``, the
very evaluation of ``_patch_error``, so the maxima, minima and counts over all cells equal the
patch's figures bit for bit (the sign of a zero extreme aside: see ``grid_patch_errors``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from approxtree.kernels.grid_patch import grid_patch_part


@njit(cache=True, parallel=True)
def grid_patch_cells(
    heights: np.ndarray,
    lattice: np.ndarray,
    r0: int,
    r1: int,
    c0: int,
    c1: int,
    sr: int,
    sc: int,
    k0: int,
    k1: int,
    j0: int,
    j1: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(error, zmin, zmax, count, zeros) of the cells k0..k1 × j0..j1 of one grid patch.

    heights: (rows, cols) the whole grid (NaN = nodata); lattice: (nbr + 1, nbc + 1) heights
    of the patch's sampled rows × columns, in the dtype of ``heights``. Returns four
    (k1 − k0 + 1, j1 − j0 + 1) arrays: float64 error, zmin (inf without data), zmax (−inf
    without data), int64 count of valid points and int64 zeros (bit 1: a +0.0, bit 2: a −0.0,
    set only where an extreme of the cell is zero).
    """
    nbr = (r1 - r0 + sr - 1) // sr
    nbc = (c1 - c0 + sc - 1) // sc
    nk = k1 - k0 + 1
    nj = j1 - j0 + 1
    err = np.empty((nk, nj))
    zmin = np.empty((nk, nj))
    zmax = np.empty((nk, nj))
    count = np.empty((nk, nj), dtype=np.int64)
    # Signed zeros: 1 where the cell holds a +0.0, 2 a −0.0 (3 both), scanned only when an
    # extreme is zero (which zero is the extreme depends on the scan order).
    zeros = np.zeros((nk, nj), dtype=np.int64)
    for t in prange(nk * nj):
        k = k0 + t // nj
        j = j0 + t % nj
        a0 = r0 + k * sr
        a1 = r1 if k == nbr - 1 else a0 + sr - 1
        b0 = c0 + j * sc
        b1 = c1 if j == nbc - 1 else b0 + sc - 1
        e, lo, hi, n = grid_patch_part(
            heights, 0, 0, a0, a1, b0, b1, lattice, 0, 0, r0, r1, c0, c1, sr, sc
        )
        err[k - k0, j - j0] = e
        zmin[k - k0, j - j0] = lo
        zmax[k - k0, j - j0] = hi
        count[k - k0, j - j0] = n
        if lo == 0.0 or hi == 0.0:
            for r in range(a0, a1 + 1):
                for c in range(b0, b1 + 1):
                    z = heights[r, c]
                    if z == 0.0:
                        zeros[k - k0, j - j0] |= 2 if np.signbit(z) else 1
    return err, zmin, zmax, count, zeros
