"""Exact errors of regular-grid patches, batched over the nodes of one tree level.

A grid patch samples the rows r0, r0+sr, r0+2sr, ... and always its last row r1 (likewise for
columns), so the last block may be narrower than the step. Every grid point of the node is
evaluated once against the triangulated patch (same diagonal as ``grid_interp``):

    error = max |z(p) − h_TN(p)| over the valid data points p of the node.

Triangles with a nodata corner are not drawn. A data point that lies in no drawn triangle (its
triangles all touch nodata) is not represented by the patch: its error is infinite, which forces
the node to split until such points become patch vertices. A point on an edge is represented
when any drawn triangle holds that edge, including the triangle of the neighbouring block.
Likewise a nodata point that a drawn triangle holds (edges included) would be covered by
invented surface: its error is infinite too, so holes stay holes (the node splits until the
hole's points are vertices, whose triangles are not drawn).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True)
def _block_count(lo: int, hi: int, step: int) -> int:
    """Number of blocks between sampled lines lo .. hi with the given step (last one shorter)."""
    return (hi - lo + step - 1) // step


@njit(cache=True, inline="always")
def _block_value(z00, z01, z10, z11, dr, dc, hr, wc):
    """h_TN at offset (dr, dc) of a block hr × wc with corners z00 .. z11 (NaN: not drawn).

    Integer comparison picks the triangle exactly, as the GPU sees it; the whole-patch kernel
    and the per-block part of a blocked build share this arithmetic, so their errors agree bit
    for bit.
    """
    if dc * hr >= dr * wc:
        return z00 + (dc / wc) * (z01 - z00) + (dr / hr) * (z11 - z01)
    return z00 + (dr / hr) * (z10 - z00) + (dc / wc) * (z11 - z10)


@njit(cache=True, inline="always")
def _fold_error(err, z, valid, p):
    """The running error after data point z (or nodata) against the patch's height p there."""
    if not valid:
        # Nodata under a drawn triangle: the patch would cover a hole.
        return np.inf if not np.isnan(p) else err
    if np.isnan(p):
        # A data point no drawn triangle holds is not represented.
        return np.inf
    e = abs(z - p)
    return e if e > err else err


@njit(cache=True)
def _edge_value(heights, r, c, rb, re, cb, ce, sr, sc, kr, kc):
    """Height of point (r, c) from a drawn triangle other than its primary one, or NaN.

    Only points on an edge can have another triangle: the diagonal (shared with triangle B of
    the block), or the block's north or west edge (shared with the block above or to the left,
    whose height or width is the full step).
    """
    hr = re - rb
    wc = ce - cb
    dr = r - rb
    dc = c - cb
    z00 = heights[rb, cb]
    z11 = heights[re, ce]
    # On the diagonal: triangle B (corners 00, 11, 10) holds it too.
    if dc * hr == dr * wc and not np.isnan(heights[re, cb]):
        return z00 + (dr / hr) * (z11 - z00)
    # North edge: triangle B of the block above (corners (rb−sr, cb), (rb, ce), (rb, cb)).
    if dr == 0 and kr > 0 and not np.isnan(heights[rb - sr, cb]):
        z01 = heights[rb, ce]
        p = z00 + (dc / wc) * (z01 - z00)
        if not np.isnan(p):
            return p
    # West edge: triangle A of the block to the left (corners (rb, cb−sc), (rb, cb), (re, cb)).
    if dc == 0 and kc > 0 and not np.isnan(heights[rb, cb - sc]):
        z10 = heights[re, cb]
        return z00 + (dr / hr) * (z10 - z00)
    return np.nan


@njit(cache=True)
def _patch_error(heights, r0, r1, c0, c1, sr, sc):
    """(error, zmin, zmax, count) of one grid patch; see the module docstring."""
    err = 0.0
    zmin = np.inf
    zmax = -np.inf
    count = 0
    nbr = _block_count(r0, r1, sr)
    nbc = _block_count(c0, c1, sc)
    for kr in range(nbr):
        rb = r0 + kr * sr
        re = min(rb + sr, r1)
        hr = re - rb
        # Interior blocks leave their last row to the next block; the last block keeps it.
        rend = re if kr == nbr - 1 else re - 1
        for kc in range(nbc):
            cb = c0 + kc * sc
            ce = min(cb + sc, c1)
            wc = ce - cb
            cend = ce if kc == nbc - 1 else ce - 1
            z00 = heights[rb, cb]
            z01 = heights[rb, ce]
            z10 = heights[re, cb]
            z11 = heights[re, ce]
            for r in range(rb, rend + 1):
                dr = r - rb
                for c in range(cb, cend + 1):
                    z = heights[r, c]
                    valid = not np.isnan(z)
                    if valid:
                        count += 1
                        if z < zmin:
                            zmin = z
                        if z > zmax:
                            zmax = z
                    dc = c - cb
                    # Patch vertices are reproduced exactly.
                    if (dr == 0 or r == re) and (dc == 0 or c == ce):
                        continue
                    p = _block_value(z00, z01, z10, z11, dr, dc, hr, wc)
                    if np.isnan(p):
                        p = _edge_value(heights, r, c, rb, re, cb, ce, sr, sc, kr, kc)
                    err = _fold_error(err, z, valid, p)
    return err, zmin, zmax, count


@njit(cache=True, parallel=True)
def grid_patch_errors(
    heights: np.ndarray, ranges: np.ndarray, steps: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact error and z range of many grid patches.

    heights: (rows, cols) float32/float64, NaN = nodata.
    ranges: (n, 4) int64 inclusive index ranges (r0, r1, c0, c1), r1 > r0 and c1 > c0.
    steps: (n, 2) int64 row and column steps (sr, sc) >= 1.
    Returns error (n,), zmin (n,), zmax (n,) float64 (NaN z for a node without data) and
    count (n,) int64 of valid data points per node.
    """
    n = ranges.shape[0]
    error = np.empty(n)
    zmin = np.empty(n)
    zmax = np.empty(n)
    count = np.empty(n, dtype=np.int64)
    for i in prange(n):
        e, lo, hi, k = _patch_error(
            heights,
            ranges[i, 0],
            ranges[i, 1],
            ranges[i, 2],
            ranges[i, 3],
            steps[i, 0],
            steps[i, 1],
        )
        error[i] = e
        zmin[i] = lo if k > 0 else np.nan
        zmax[i] = hi if k > 0 else np.nan
        count[i] = k
    return error, zmin, zmax, count


@njit(cache=True)
def grid_patch_mesh(
    heights: np.ndarray, r0: int, r1: int, c0: int, c1: int, sr: int, sc: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sampled lattice and triangles of one grid patch, in index space.

    Returns rows (kr,) int64 and cols (kc,) int64 of the sampled lines, and triangles (m, 3)
    int64 indexing the kr × kc lattice row-major, counter-clockwise in (col, row) index space;
    triangles with a nodata corner are left out.
    """
    nbr = _block_count(r0, r1, sr)
    nbc = _block_count(c0, c1, sc)
    rows = np.empty(nbr + 1, dtype=np.int64)
    cols = np.empty(nbc + 1, dtype=np.int64)
    for k in range(nbr):
        rows[k] = r0 + k * sr
    rows[nbr] = r1
    for k in range(nbc):
        cols[k] = c0 + k * sc
    cols[nbc] = c1
    kc = nbc + 1
    tris = np.empty((2 * nbr * nbc, 3), dtype=np.int64)
    m = 0
    for i in range(nbr):
        for j in range(nbc):
            a = i * kc + j  # (rb, cb)
            b = a + 1  # (rb, ce)
            c = a + kc  # (re, cb)
            d = c + 1  # (re, ce)
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
    return rows, cols, tris[:m]


@njit(cache=True)
def _lattice_edge_value(lattice, i, j, dr, dc, hr, wc, kr, kc):
    """``_edge_value`` with the patch's vertices read from a lattice (see grid_patch_part)."""
    z00 = lattice[i, j]
    z11 = lattice[i + 1, j + 1]
    if dc * hr == dr * wc and not np.isnan(lattice[i + 1, j]):
        return z00 + (dr / hr) * (z11 - z00)
    if dr == 0 and kr > 0 and not np.isnan(lattice[i - 1, j]):
        z01 = lattice[i, j + 1]
        p = z00 + (dc / wc) * (z01 - z00)
        if not np.isnan(p):
            return p
    if dc == 0 and kc > 0 and not np.isnan(lattice[i, j - 1]):
        z10 = lattice[i + 1, j]
        return z00 + (dr / hr) * (z10 - z00)
    return np.nan


@njit(cache=True)
def grid_patch_part(
    heights: np.ndarray,
    wr0: int,
    wc0: int,
    a0: int,
    a1: int,
    b0: int,
    b1: int,
    lattice: np.ndarray,
    k_lo: int,
    j_lo: int,
    r0: int,
    r1: int,
    c0: int,
    c1: int,
    sr: int,
    sc: int,
) -> tuple[float, float, float, int]:
    """(error, zmin, zmax, count) of one grid patch over a part of its points only.

    The patch is (r0, r1, c0, c1, sr, sc) in global indices, as in ``_patch_error``; the part is
    the global rows a0..a1 × columns b0..b1 (inclusive, inside the patch), whose heights are
    ``heights`` (a window whose row 0, column 0 is global (wr0, wc0)). The patch's vertices
    come from ``lattice``: the heights of the sampled rows k_lo.. × sampled columns j_lo.. (k-th
    sampled row r0 + k·sr, the last one r1), one beyond the part's cells on each side where
    they exist, in the dtype of ``heights``. Each point is evaluated exactly as
    ``_patch_error`` does, so the maxima and sums over parts that tile the patch equal the
    patch's figures bit for bit (a block of a blocked build measures its ancestors this way).
    """
    err = 0.0
    zmin = np.inf
    zmax = -np.inf
    count = 0
    nbr = _block_count(r0, r1, sr)
    nbc = _block_count(c0, c1, sc)
    for r in range(a0, a1 + 1):
        # Interior blocks leave their last row to the next block, as in _patch_error.
        kr = min((r - r0) // sr, nbr - 1)
        rb = r0 + kr * sr
        re = min(rb + sr, r1)
        hr = re - rb
        dr = r - rb
        i = kr - k_lo
        for c in range(b0, b1 + 1):
            kc = min((c - c0) // sc, nbc - 1)
            cb = c0 + kc * sc
            ce = min(cb + sc, c1)
            wc = ce - cb
            dc = c - cb
            j = kc - j_lo
            z = heights[r - wr0, c - wc0]
            valid = not np.isnan(z)
            if valid:
                count += 1
                if z < zmin:
                    zmin = z
                if z > zmax:
                    zmax = z
            if (dr == 0 or r == re) and (dc == 0 or c == ce):
                continue
            z00 = lattice[i, j]
            z01 = lattice[i, j + 1]
            z10 = lattice[i + 1, j]
            z11 = lattice[i + 1, j + 1]
            p = _block_value(z00, z01, z10, z11, dr, dc, hr, wc)
            if np.isnan(p):
                p = _lattice_edge_value(lattice, i, j, dr, dc, hr, wc, kr, kc)
            err = _fold_error(err, z, valid, p)
    return err, zmin, zmax, count
