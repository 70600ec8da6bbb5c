"""Linear interpolation on a triangulated regular grid, in index space.

Every grid cell (r, c)–(r+1, c+1) is cut by the diagonal from (r, c) to (r+1, c+1); the same
convention is used by h_T, by the error of grid patches and by the triangles sent to the GPU, so
the measured error is the error of what is drawn:

    (r, c) ●───────● (r, c+1)        triangle A: fc >= fr  (corners 00, 01, 11)
           │ ╲   A │                 triangle B: fc <  fr  (corners 00, 11, 10)
           │  B ╲  │
  (r+1, c) ●───────● (r+1, c+1)
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, inline="always")
def interpolate_cell(z00: float, z01: float, z10: float, z11: float, fr: float, fc: float):
    """Height at fractional position (fr, fc) in [0, 1]² of a cell with the given corners."""
    # In float64 whatever the raster's dtype (a float32 difference of two corners is rounded).
    z00 = np.float64(z00)
    z01 = np.float64(z01)
    z10 = np.float64(z10)
    z11 = np.float64(z11)
    if fc >= fr:
        return z00 + fc * (z01 - z00) + fr * (z11 - z01)
    return z00 + fr * (z10 - z00) + fc * (z11 - z10)


@njit(cache=True, parallel=True)
def grid_height_at(heights: np.ndarray, fr: np.ndarray, fc: np.ndarray) -> np.ndarray:
    """h_T at fractional row/column indices.

    heights: (rows, cols) float, NaN = nodata; fr, fc: (n,) float64 fractional indices.
    Returns (n,) float64, NaN outside the grid or in a triangle touching nodata.
    """
    rows, cols = heights.shape
    n = fr.shape[0]
    out = np.empty(n, dtype=np.float64)
    for i in prange(n):
        r = fr[i]
        c = fc[i]
        if not (r >= 0.0 and r <= rows - 1 and c >= 0.0 and c <= cols - 1):
            out[i] = np.nan
            continue
        r0 = min(int(r), rows - 2) if rows > 1 else 0
        c0 = min(int(c), cols - 2) if cols > 1 else 0
        r1 = min(r0 + 1, rows - 1)
        c1 = min(c0 + 1, cols - 1)
        out[i] = interpolate_cell(
            heights[r0, c0], heights[r0, c1], heights[r1, c0], heights[r1, c1], r - r0, c - c0
        )
    return out


@njit(cache=True, parallel=True)
def cell_height_at(
    z00: np.ndarray,
    z01: np.ndarray,
    z10: np.ndarray,
    z11: np.ndarray,
    dr: np.ndarray,
    dc: np.ndarray,
) -> np.ndarray:
    """h_T from the corners of each point's cell (for heights read by windows).

    z00, z01, z10, z11: (n,) corner heights (r, c), (r, c+1), (r+1, c), (r+1, c+1); dr, dc: (n,)
    float64 offsets in the cell. Returns (n,) float64, equal bit for bit to grid_height_at.
    """
    n = dr.shape[0]
    out = np.empty(n, dtype=np.float64)
    for i in prange(n):
        out[i] = interpolate_cell(z00[i], z01[i], z10[i], z11[i], dr[i], dc[i])
    return out


@njit(cache=True)
def lattice_triangles(heights: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(m, 3) int64 triangles of the lattice ``rows`` (kr,) × ``cols`` (kc,) of ``heights``,
    indexing its kr × kc vertices row-major.

    Every lattice cell is cut by the diagonal of the picture above, triangle A then B,
    counter-clockwise in (col, row) index space; a triangle with a nodata corner is left out.
    Grid patches (``grid_patch_mesh``) and nonregular lattices triangulate with this one.
    """
    nbr = rows.shape[0] - 1
    nbc = cols.shape[0] - 1
    kc = nbc + 1
    tris = np.empty((2 * nbr * nbc, 3), dtype=np.int64)
    m = 0
    for i in range(nbr):
        for j in range(nbc):
            a = i * kc + j  # (r, c)
            b = a + 1  # (r, c+1)
            c = a + kc  # (r+1, c)
            d = c + 1  # (r+1, c+1)
            za = heights[rows[i], cols[j]]
            zb = heights[rows[i], cols[j + 1]]
            zc = heights[rows[i + 1], cols[j]]
            zd = heights[rows[i + 1], cols[j + 1]]
            # Triangle A (fc >= fr): corners 00, 01, 11.
            if not (np.isnan(za) or np.isnan(zb) or np.isnan(zd)):
                tris[m, 0] = a
                tris[m, 1] = b
                tris[m, 2] = d
                m += 1
            # Triangle B (fc < fr): corners 00, 11, 10.
            if not (np.isnan(za) or np.isnan(zd) or np.isnan(zc)):
                tris[m, 0] = a
                tris[m, 1] = d
                tris[m, 2] = c
                m += 1
    return tris[:m]
