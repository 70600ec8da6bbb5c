"""Figures of a grid patch per lattice cell, so that an edit re-measures only the cells it reaches.

A grid patch (r0, r1, c0, c1, sr, sc) samples rows r0, r0 + sr, ... and r1 (likewise columns);
its lattice cell (k, j) owns the data rows r0 + k·sr .. r0 + (k+1)·sr − 1 (the last cell down
to r1) and the columns likewise. Each point gets the very value ``_patch_error`` gives it: a
cell whose four corners hold data by ``_plain_cell`` (the block's triangles without a division
per point, as fast as the build's own kernel), any other by ``grid_patch.grid_patch_part``; so
the maxima, minima and counts over all cells equal the patch's figures bit for bit (the sign
of a zero extreme aside: see ``grid_patch_errors``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from approxtree.kernels.grid_patch import _plain, grid_patch_part


@njit(cache=True)
def _plain_cell(
    heights: np.ndarray,
    lattice: np.ndarray,
    k: int,
    j: int,
    a0: int,
    a1: int,
    b0: int,
    b1: int,
    rb: int,
    re: int,
    cb: int,
    ce: int,
    frac: np.ndarray,
) -> tuple[float, float, float, int]:
    """(error, zmin, zmax, count) of the cell (k, j), block rows rb..re × columns cb..ce,
    owning rows a0..a1 × columns b0..b1, whose four corners hold data (``_plain``); frac:
    (ce − cb + 1,) the quotients dc / (ce − cb) (``_fractions``), made once per patch.

    Each point gets ``_block_value``'s float64 value (same operands, same order: the
    quotients dr / hr and dc / wc, then the triangle's two terms), without its per-point
    divisions; the triangle changes once along a row, at dc = ceil(dr·wc / hr).
    """
    z00 = np.float64(lattice[k, j])
    z01 = np.float64(lattice[k, j + 1])
    z10 = np.float64(lattice[k + 1, j])
    z11 = np.float64(lattice[k + 1, j + 1])
    hr = re - rb
    wc = ce - cb
    err = 0.0
    zmin = np.inf
    zmax = -np.inf
    count = 0
    d_a = z01 - z00
    d_b = z11 - z10
    for r in range(a0, a1 + 1):
        dr = r - rb
        fr = dr / hr
        zrow = heights[r]
        # The z range and count: NaN (no data) fails every comparison, so no branch on it.
        for c in range(b0, b1 + 1):
            z = zrow[c]
            count += z == z
            zmin = z if z < zmin else zmin
            zmax = z if z > zmax else zmax
        # Patch vertices are reproduced exactly: the sampled row's first and last points
        # (the cell's own corner, and the block's far corner when the cell ends on it).
        lo = b0
        hi = b1
        if dr == 0 or r == re:
            lo = b0 + 1
            if b1 == ce:
                hi = b1 - 1
        # Triangle B (00, 11, 10) before offset t, triangle A (00, 01, 11) from t on.
        mid = cb + (dr * wc + hr - 1) // hr
        b_base = z00 + fr * (z10 - z00)
        a_add = fr * (z11 - z01)
        for c in range(lo, min(mid, hi + 1)):
            e = abs(zrow[c] - (b_base + frac[c - cb] * d_b))
            # Nodata under a drawn triangle (NaN here): the patch would cover a hole.
            e = e if e == e else np.inf
            err = e if e > err else err
        for c in range(max(mid, lo), hi + 1):
            e = abs(zrow[c] - (z00 + frac[c - cb] * d_a + a_add))
            e = e if e == e else np.inf
            err = e if e > err else err
    return err, zmin, zmax, count


@njit(cache=True)
def _patch_fractions(c0: int, c1: int, sc: int) -> np.ndarray:
    """dc / sc for dc = 0 .. sc, then dc / wl for dc = 0 .. wl (wl: the width of the patch's
    last column of cells): the quotients ``_block_value`` computes, made once per patch."""
    nbc = (c1 - c0 + sc - 1) // sc
    wl = c1 - (c0 + (nbc - 1) * sc)
    out = np.empty(sc + wl + 2)
    for dc in range(sc + 1):
        out[dc] = dc / sc
    for dc in range(wl + 1):
        out[sc + 1 + dc] = dc / wl
    return out


@njit(cache=True)
def _cell(
    heights: np.ndarray,
    lattice: np.ndarray,
    r0: int,
    r1: int,
    c0: int,
    c1: int,
    sr: int,
    sc: int,
    k: int,
    j: int,
    fractions: np.ndarray,
) -> tuple[float, float, float, int, int]:
    """(error, zmin, zmax, count, zeros) of lattice cell (k, j) of one grid patch (see
    ``grid_patch_cells``); fractions: the patch's ``_patch_fractions``."""
    nbr = (r1 - r0 + sr - 1) // sr
    nbc = (c1 - c0 + sc - 1) // sc
    a0 = r0 + k * sr
    a1 = r1 if k == nbr - 1 else a0 + sr - 1
    b0 = c0 + j * sc
    b1 = c1 if j == nbc - 1 else b0 + sc - 1
    re = min(a0 + sr, r1)
    ce = min(b0 + sc, c1)
    if (
        _plain(lattice[k, j])
        and _plain(lattice[k, j + 1])
        and _plain(lattice[k + 1, j])
        and _plain(lattice[k + 1, j + 1])
    ):
        # The last column of cells may be narrower: its quotients follow the full ones.
        frac = fractions[sc + 1 :] if j == nbc - 1 else fractions[: sc + 1]
        e, lo, hi, n = _plain_cell(heights, lattice, k, j, a0, a1, b0, b1, a0, re, b0, ce, frac)
    else:
        # A corner without data: the per-point path (edge values, holes).
        e, lo, hi, n = grid_patch_part(
            heights, 0, 0, a0, a1, b0, b1, lattice, 0, 0, r0, r1, c0, c1, sr, sc
        )
    # Signed zeros: 1 where the cell holds a +0.0, 2 a −0.0 (3 both), scanned only when an
    # extreme is zero (which zero is the extreme depends on the scan order).
    zeros = 0
    if lo == 0.0 or hi == 0.0:
        for r in range(a0, a1 + 1):
            for c in range(b0, b1 + 1):
                z = heights[r, c]
                if z == 0.0:
                    zeros |= 2 if np.signbit(z) else 1
    return e, lo, hi, n, zeros


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
    nk = k1 - k0 + 1
    nj = j1 - j0 + 1
    err = np.empty((nk, nj))
    zmin = np.empty((nk, nj))
    zmax = np.empty((nk, nj))
    count = np.empty((nk, nj), dtype=np.int64)
    zeros = np.empty((nk, nj), dtype=np.int64)
    fractions = _patch_fractions(c0, c1, sc)
    for t in prange(nk * nj):
        k = k0 + t // nj
        j = j0 + t % nj
        e, lo, hi, n, zz = _cell(heights, lattice, r0, r1, c0, c1, sr, sc, k, j, fractions)
        err[k - k0, j - j0] = e
        zmin[k - k0, j - j0] = lo
        zmax[k - k0, j - j0] = hi
        count[k - k0, j - j0] = n
        zeros[k - k0, j - j0] = zz
    return err, zmin, zmax, count, zeros


@njit(cache=True)
def _cell_row(
    heights: np.ndarray,
    lattice: np.ndarray,
    r0: int,
    r1: int,
    c0: int,
    c1: int,
    sr: int,
    sc: int,
    k: int,
    fractions: np.ndarray,
    err: np.ndarray,
    zmin: np.ndarray,
    zmax: np.ndarray,
    count: np.ndarray,
    zeros: np.ndarray,
) -> None:
    """The figures of the whole row k of cells of one grid patch into the (nbc,) outputs.

    As the build's kernel (``grid_patch._patch_rows_error``): each data row's patch heights
    are filled cell by cell (NaN at vertices and in cells with a corner without data), then
    folded into per-column figures element-wise (so the folds vectorise); the columns are
    reduced per cell at the end. Cells with a corner without data are measured again by
    ``_cell`` (edge values, holes). The same values per point as ``_cell``: the same figures.
    """
    nbr = (r1 - r0 + sr - 1) // sr
    nbc = (c1 - c0 + sc - 1) // sc
    a0 = r0 + k * sr
    a1 = r1 if k == nbr - 1 else a0 + sr - 1
    re = min(a0 + sr, r1)
    hr = re - a0
    w = c1 - c0 + 1
    plain = np.empty(nbc, dtype=np.bool_)
    for j in range(nbc):
        plain[j] = (
            _plain(lattice[k, j])
            and _plain(lattice[k, j + 1])
            and _plain(lattice[k + 1, j])
            and _plain(lattice[k + 1, j + 1])
        )
    p = np.empty(w)
    col_err = np.zeros(w)
    col_min = np.full(w, np.inf)
    col_max = np.full(w, -np.inf)
    col_count = np.zeros(w, dtype=np.int64)
    for r in range(a0, a1 + 1):
        dr = r - a0
        fr = dr / hr
        vrow = dr == 0 or r == re
        for j in range(nbc):
            cb = c0 + j * sc
            ce = min(cb + sc, c1)
            wc = ce - cb
            last = j == nbc - 1
            b1 = c1 if last else cb + sc - 1
            if not plain[j]:
                for c in range(cb, b1 + 1):
                    p[c - c0] = np.nan
                continue
            frac = fractions[sc + 1 :] if last else fractions[: sc + 1]
            z00 = np.float64(lattice[k, j])
            z01 = np.float64(lattice[k, j + 1])
            z10 = np.float64(lattice[k + 1, j])
            z11 = np.float64(lattice[k + 1, j + 1])
            d_a = z01 - z00
            d_b = z11 - z10
            # Triangle B (00, 11, 10) before offset t, triangle A (00, 01, 11) from t on.
            mid = min(cb + (dr * wc + hr - 1) // hr, b1 + 1)
            b_base = z00 + fr * (z10 - z00)
            a_add = fr * (z11 - z01)
            for c in range(cb, mid):
                p[c - c0] = b_base + frac[c - cb] * d_b
            for c in range(mid, b1 + 1):
                p[c - c0] = z00 + frac[c - cb] * d_a + a_add
            if vrow:
                # Patch vertices are reproduced exactly.
                p[cb - c0] = np.nan
                if last:
                    p[ce - c0] = np.nan
        zrow = heights[r, c0 : c1 + 1]
        for x in range(w):
            z = zrow[x]
            pj = p[x]
            e = abs(z - pj)
            # NaN: no data under a drawn triangle (a hole covered) or an unmeasured point.
            e = e if e == e else (np.inf if pj == pj else 0.0)
            col_err[x] = e if e > col_err[x] else col_err[x]
            col_min[x] = z if z < col_min[x] else col_min[x]
            col_max[x] = z if z > col_max[x] else col_max[x]
            col_count[x] += z == z
    for j in range(nbc):
        if not plain[j]:
            e, lo, hi, n, zz = _cell(heights, lattice, r0, r1, c0, c1, sr, sc, k, j, fractions)
            err[j], zmin[j], zmax[j], count[j], zeros[j] = e, lo, hi, n, zz
            continue
        x0 = j * sc
        x1 = w - 1 if j == nbc - 1 else x0 + sc - 1
        e = 0.0
        lo = np.inf
        hi = -np.inf
        n = 0
        for x in range(x0, x1 + 1):
            e = max(e, col_err[x])
            lo = min(lo, col_min[x])
            hi = max(hi, col_max[x])
            n += col_count[x]
        err[j], zmin[j], zmax[j], count[j] = e, lo, hi, n
        # Signed zeros, as ``_cell`` scans them (only where an extreme is zero).
        zz = 0
        if lo == 0.0 or hi == 0.0:
            for r in range(a0, a1 + 1):
                for c in range(c0 + x0, c0 + x1 + 1):
                    if heights[r, c] == 0.0:
                        zz |= 2 if np.signbit(heights[r, c]) else 1
        zeros[j] = zz


@njit(cache=True, parallel=True)
def grid_patch_cells_many(
    heights: np.ndarray, lattices: np.ndarray, lattice_start: np.ndarray, index: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The figures of every cell of n grid patches at once (one thread pool for all).

    lattices: the patches' lattices raveled one after the other, patch i's (nbr + 1) × (nbc + 1)
    heights from lattice_start[i] ((n + 1,) int64); index: (n, 6) int64 (r0, r1, c0, c1, sr,
    sc). Returns (error, zmin, zmax, count, zeros) raveled as one (cells,) array each, patch
    i's nbr × nbc cells (row-major) from cell_start[i], and cell_start (n + 1,) int64.
    """
    n = index.shape[0]
    cell_start = np.zeros(n + 1, dtype=np.int64)
    for i in range(n):
        nbr = (index[i, 1] - index[i, 0] + index[i, 4] - 1) // index[i, 4]
        nbc = (index[i, 3] - index[i, 2] + index[i, 5] - 1) // index[i, 5]
        cell_start[i + 1] = cell_start[i] + nbr * nbc
    m = cell_start[n]
    # The quotients of every patch, made once (not per cell: an allocation per cell would
    # serialise the threads on the allocator).
    frac_start = np.zeros(n + 1, dtype=np.int64)
    for i in range(n):
        sc = index[i, 5]
        nbc = (index[i, 3] - index[i, 2] + sc - 1) // sc
        frac_start[i + 1] = frac_start[i] + sc + (index[i, 3] - index[i, 2] - (nbc - 1) * sc) + 2
    fractions = np.empty(frac_start[n])
    for i in range(n):
        fractions[frac_start[i] : frac_start[i + 1]] = _patch_fractions(
            index[i, 2], index[i, 3], index[i, 5]
        )
    err = np.empty(m)
    zmin = np.empty(m)
    zmax = np.empty(m)
    count = np.empty(m, dtype=np.int64)
    zeros = np.empty(m, dtype=np.int64)
    # One work item per row of cells of a patch: its column folds run along whole rows.
    row_start = np.zeros(n + 1, dtype=np.int64)
    for i in range(n):
        row_start[i + 1] = (
            row_start[i] + (index[i, 1] - index[i, 0] + index[i, 4] - 1) // index[i, 4]
        )
    for t in prange(row_start[n]):
        i = int(np.searchsorted(row_start, t, side="right")) - 1
        r0, r1, c0, c1 = index[i, 0], index[i, 1], index[i, 2], index[i, 3]
        sr, sc = index[i, 4], index[i, 5]
        nbc = (c1 - c0 + sc - 1) // sc
        nbr = (r1 - r0 + sr - 1) // sr
        lattice = lattices[lattice_start[i] : lattice_start[i + 1]].reshape(nbr + 1, nbc + 1)
        frac = fractions[frac_start[i] : frac_start[i + 1]]
        k = t - row_start[i]
        a = cell_start[i] + k * nbc
        _cell_row(
            heights,
            lattice,
            r0,
            r1,
            c0,
            c1,
            sr,
            sc,
            k,
            frac,
            err[a : a + nbc],
            zmin[a : a + nbc],
            zmax[a : a + nbc],
            count[a : a + nbc],
            zeros[a : a + nbc],
        )
    return err, zmin, zmax, count, zeros, cell_start
