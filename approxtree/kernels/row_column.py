"""Row–column insertion for non-regular grid patches, and exact errors of grid lattices.

A *lattice* is a sorted set of chosen rows and columns of a height grid; its vertices are the
row–column intersections and each cell (rows[i]..rows[i+1] × cols[j]..cols[j+1]) is cut by the
diagonal from (rows[i], cols[j]) to (rows[i+1], cols[j+1]), exactly as ``grid_patch`` cuts its
blocks: a data point (r, c) of a cell with offsets (dr, dc) and size (hr, wc) lies in

    triangle A (corners 00, 01, 11)  if dc · hr >= dr · wc,   else triangle B (00, 11, 10).

Refinement (core paper, section 3.2, figure 4): start with the window's first and last row and
column, then repeatedly insert the row *and* the column of the data point of largest error.
Every cell keeps its worst data point; inserting a row only changes the cells of the row strip
it splits, inserting a column only those of the column strip it splits, so only those strips
are re-evaluated. Cells are stored by stable strip ids (a new strip gets the next free id), so
insertion never moves stored cells; each row strip keeps its worst cell, and the global worst is
found by scanning the row strips. Ties go to the first data point in row-major order.

Nodata during refinement: a point whose triangle in its own cell has a nodata corner (and that
is not on the cell's diagonal with the other triangle drawn) counts as infinitely wrong. That is
conservative (a neighbouring cell may draw the edge the point lies on), so the refinement's
error is never below the true one; the patch's reported error is always re-measured exactly
with ``lattice_errors``, whose nodata rules are those of ``grid_patch``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True)
def _interpolate(z00, z01, z10, z11, dr, dc, hr, wc):
    """h_TN at offsets (dr, dc) of a cell of size (hr, wc); NaN when its triangle has nodata."""
    if dc * hr >= dr * wc:
        p = z00 + (dc / wc) * (z01 - z00) + (dr / hr) * (z11 - z01)
    else:
        p = z00 + (dr / hr) * (z10 - z00) + (dc / wc) * (z11 - z10)
    # On the diagonal both triangles hold the point: use the other one if this one is not drawn.
    if np.isnan(p) and dc * hr == dr * wc and not (np.isnan(z00) or np.isnan(z11)):
        p = z00 + (dr / hr) * (z11 - z00)
    return p


@njit(cache=True)
def _cell_worst(heights, ra, rb, ca, cb):
    """(error, row, col) of the worst data point of one cell, borders included, corners not.

    Returns error 0 and (−1, −1) when the cell has no data point off its corners.
    """
    hr = rb - ra
    wc = cb - ca
    z00 = np.float64(heights[ra, ca])
    z01 = np.float64(heights[ra, cb])
    z10 = np.float64(heights[rb, ca])
    z11 = np.float64(heights[rb, cb])
    best = 0.0
    br = -1
    bc = -1
    for r in range(ra, rb + 1):
        dr = r - ra
        edge_row = dr == 0 or dr == hr
        for c in range(ca, cb + 1):
            z = heights[r, c]
            dc = c - ca
            # Corners are lattice vertices: reproduced exactly.
            if edge_row and (dc == 0 or dc == wc):
                continue
            p = _interpolate(z00, z01, z10, z11, dr, dc, hr, wc)
            if np.isnan(z):
                # Nodata under a drawn triangle must become a vertex (the hole is cut out).
                if np.isnan(p):
                    continue
                e = np.inf
            else:
                e = np.inf if np.isnan(p) else abs(z - p)
            if e > best:
                best = e
                br = r
                bc = c
    return best, br, bc


@njit(cache=True)
def _insert(lines, ids, n, pos, value, new_id):
    """Insert ``value`` at position ``pos`` of the first n lines (and its strip id)."""
    for k in range(n, pos, -1):
        lines[k] = lines[k - 1]
        ids[k] = ids[k - 1]
    lines[pos] = value
    ids[pos] = new_id


@njit(cache=True)
def _worse(e1, k1, e2, k2):
    """True when point 1 (error e1, row-major index k1) is worse than point 2.

    Ties go to the first data point in row-major order, so the choice does not depend on the
    order in which cells are visited.
    """
    return e1 > e2 or (e1 == e2 and k1 < k2)


@njit(cache=True)
def _eval_cell(heights, R, C, rid, cid, i, j, E, AR, AC):
    """Evaluate cell (i, j) of the current lattice into its stable storage slot.

    Returns the cell's (error, row-major index of its worst point).
    """
    e, r, c = _cell_worst(heights, R[i], R[i + 1], C[j], C[j + 1])
    E[rid[i], cid[j]] = e
    AR[rid[i], cid[j]] = r
    AC[rid[i], cid[j]] = c
    return e, r * heights.shape[1] + c


@njit(cache=True)
def _set_strip_worst(heights, rid, cid, i, nc, E, AR, AC, strip):
    """Recompute the worst cell of row strip i from the stored cell errors.

    strip: (cap, 3) float64 per row-strip id: error, row-major point index, cell column id.
    """
    w = heights.shape[1]
    k = rid[i]
    best = -1.0
    best_key = 0
    arg = 0
    for j in range(nc - 1):
        e = E[k, cid[j]]
        key = AR[k, cid[j]] * w + AC[k, cid[j]]
        if _worse(e, key, best, best_key):
            best = e
            best_key = key
            arg = cid[j]
    strip[k, 0] = best
    strip[k, 1] = best_key
    strip[k, 2] = arg


@njit(cache=True)
def refine_lattice(heights, r0, r1, c0, c1, epsilon, max_points, max_cells, rows_out, cols_out):
    """Row–column insertion over the window r0..r1 × c0..c1 (inclusive, r1 > r0, c1 > c0).

    Stops when the worst point's error is <= epsilon (or 0), or when inserting its row and
    column would exceed max_points lattice points (rows × cols) or max_cells cells (0 = no
    limit). rows_out, cols_out: int64 buffers long enough for every row / column that can be
    chosen. Returns (number of rows, number of columns, refinement error), the sorted chosen
    lines in the buffers' first entries.
    """
    cap_r = rows_out.shape[0]
    cap_c = cols_out.shape[0]
    R = rows_out
    C = cols_out
    rid = np.empty(cap_r, dtype=np.int64)
    cid = np.empty(cap_c, dtype=np.int64)
    R[0] = r0
    R[1] = r1
    C[0] = c0
    C[1] = c1
    rid[0] = 0
    rid[1] = 1
    cid[0] = 0
    cid[1] = 1
    nr = 2
    nc = 2
    # Cell storage by stable strip ids: strip ids are never reused or moved. Every slot is
    # written when its cell is created, before it is read, so the arrays start uninitialized.
    E = np.empty((cap_r - 1, cap_c - 1))
    AR = np.empty((cap_r - 1, cap_c - 1), dtype=np.int64)
    AC = np.empty((cap_r - 1, cap_c - 1), dtype=np.int64)
    # Per row strip: its worst cell's error, point index and column id (exact in float64).
    strip = np.empty((cap_r - 1, 3))
    _eval_cell(heights, R, C, rid, cid, 0, 0, E, AR, AC)
    _set_strip_worst(heights, rid, cid, 0, nc, E, AR, AC, strip)
    while True:
        # The worst cell: scan the row strips' worst cells.
        bi = 0
        for i in range(1, nr - 1):
            a = strip[rid[i]]
            b = strip[rid[bi]]
            if _worse(a[0], a[1], b[0], b[1]):
                bi = i
        worst = strip[rid[bi], 0]
        if worst <= epsilon or worst <= 0.0:
            return nr, nc, max(worst, 0.0)
        wc_id = np.int64(strip[rid[bi], 2])
        r = AR[rid[bi], wc_id]
        c = AC[rid[bi], wc_id]
        bj = 0
        while cid[bj] != wc_id:
            bj += 1
        # The point's row (column) is new unless it lies on one of the cell's lines.
        new_r = r != R[bi] and r != R[bi + 1]
        new_c = c != C[bj] and c != C[bj + 1]
        nr2 = nr + (1 if new_r else 0)
        nc2 = nc + (1 if new_c else 0)
        if max_points > 0 and nr2 * nc2 > max_points:
            return nr, nc, worst
        if max_cells > 0 and (nr2 - 1) * (nc2 - 1) > max_cells:
            return nr, nc, worst
        if nr2 > cap_r or nc2 > cap_c:
            return nr, nc, worst
        if new_c:
            _insert(C, cid, nc, bj + 1, c, nc - 1)
            nc += 1
        if new_r:
            _insert(R, rid, nr, bi + 1, r, nr - 1)
            nr += 1
            # Both halves of the split row strip, over all (possibly new) columns.
            for i in (bi, bi + 1):
                for j in range(nc - 1):
                    _eval_cell(heights, R, C, rid, cid, i, j, E, AR, AC)
                _set_strip_worst(heights, rid, cid, i, nc, E, AR, AC, strip)
        if new_c:
            old_id = cid[bj]
            for i in range(nr - 1):
                if new_r and (i == bi or i == bi + 1):
                    continue
                e1, k1 = _eval_cell(heights, R, C, rid, cid, i, bj, E, AR, AC)
                e2, k2 = _eval_cell(heights, R, C, rid, cid, i, bj + 1, E, AR, AC)
                k = rid[i]
                if np.int64(strip[k, 2]) == old_id:
                    # The strip's worst cell was split: its maximum may have dropped.
                    _set_strip_worst(heights, rid, cid, i, nc, E, AR, AC, strip)
                    continue
                # Otherwise the old worst cell stands unless a new half beats it.
                if _worse(e1, k1, strip[k, 0], strip[k, 1]):
                    strip[k, 0] = e1
                    strip[k, 1] = k1
                    strip[k, 2] = cid[bj]
                if _worse(e2, k2, strip[k, 0], strip[k, 1]):
                    strip[k, 0] = e2
                    strip[k, 1] = k2
                    strip[k, 2] = cid[bj + 1]


@njit(cache=True, parallel=True)
def refine_lattices(heights, ranges, epsilon, max_points, max_cells, cap_r, cap_c):
    """``refine_lattice`` over many windows at once.

    ranges: (n, 4) int64 inclusive (r0, r1, c0, c1). Returns rows (n, cap_r) int64,
    nrows (n,), cols (n, cap_c) int64, ncols (n,), refinement error (n,) float64.
    """
    n = ranges.shape[0]
    rows = np.zeros((n, cap_r), dtype=np.int64)
    cols = np.zeros((n, cap_c), dtype=np.int64)
    nrows = np.zeros(n, dtype=np.int64)
    ncols = np.zeros(n, dtype=np.int64)
    err = np.zeros(n)
    for k in prange(n):
        r0, r1, c0, c1 = ranges[k, 0], ranges[k, 1], ranges[k, 2], ranges[k, 3]
        kr = min(cap_r, r1 - r0 + 1)
        kc = min(cap_c, c1 - c0 + 1)
        a, b, e = refine_lattice(
            heights, r0, r1, c0, c1, epsilon, max_points, max_cells, rows[k, :kr], cols[k, :kc]
        )
        nrows[k] = a
        ncols[k] = b
        err[k] = e
    return rows, nrows, cols, ncols, err


# -- exact measurement ------------------------------------------------------------------------


@njit(cache=True)
def _other_triangle(heights, rows, cols, i, j, r, c):
    """Height of point (r, c) of cell (i, j) from a drawn triangle other than its own, or NaN.

    Only points on an edge have another triangle: the diagonal (triangle B of the cell), the
    cell's north edge (triangle B of the cell above) or its west edge (triangle A of the cell to
    the left). Interior cells leave their south and east lines to the next cell.
    """
    rb = rows[i]
    re = rows[i + 1]
    cb = cols[j]
    ce = cols[j + 1]
    hr = re - rb
    wc = ce - cb
    dr = r - rb
    dc = c - cb
    z00 = np.float64(heights[rb, cb])
    z11 = np.float64(heights[re, ce])
    if dc * hr == dr * wc and not np.isnan(heights[re, cb]):
        return z00 + (dr / hr) * (z11 - z00)
    if dr == 0 and i > 0 and not np.isnan(heights[rows[i - 1], cb]):
        z01 = np.float64(heights[rb, ce])
        p = z00 + (dc / wc) * (z01 - z00)
        if not np.isnan(p):
            return p
    if dc == 0 and j > 0 and not np.isnan(heights[rb, cols[j - 1]]):
        z10 = np.float64(heights[re, cb])
        return z00 + (dr / hr) * (z10 - z00)
    return np.nan


@njit(cache=True)
def lattice_error(heights, rows, cols):
    """Exact (max error, sum of squared errors, valid points, z min, z max) of one lattice.

    rows: (kr,) int64 sorted chosen rows, cols: (kc,) int64 sorted chosen columns, both >= 2;
    the data points are those of the window rows[0]..rows[-1] × cols[0]..cols[-1], each
    evaluated once. A valid point in no drawn triangle gives an infinite max error (and sum); a
    nodata point in a drawn triangle (the lattice would cover a hole) an infinite max error.
    """
    return _lattice_error(heights, rows, cols, np.inf)


@njit(cache=True)
def _lattice_error(heights, rows, cols, limit):
    """``lattice_error`` that returns early, with a partial result, once the error > limit."""
    err = 0.0
    sumsq = 0.0
    zmin = np.inf
    zmax = -np.inf
    count = 0
    nbr = rows.shape[0] - 1
    nbc = cols.shape[0] - 1
    for i in range(nbr):
        rb = rows[i]
        re = rows[i + 1]
        hr = re - rb
        rend = re if i == nbr - 1 else re - 1
        for j in range(nbc):
            cb = cols[j]
            ce = cols[j + 1]
            wc = ce - cb
            cend = ce if j == nbc - 1 else ce - 1
            z00 = np.float64(heights[rb, cb])
            z01 = np.float64(heights[rb, ce])
            z10 = np.float64(heights[re, cb])
            z11 = np.float64(heights[re, ce])
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
                    if (dr == 0 or r == re) and (dc == 0 or c == ce):
                        continue
                    if dc * hr >= dr * wc:
                        p = z00 + (dc / wc) * (z01 - z00) + (dr / hr) * (z11 - z01)
                    else:
                        p = z00 + (dr / hr) * (z10 - z00) + (dc / wc) * (z11 - z10)
                    if np.isnan(p):
                        p = _other_triangle(heights, rows, cols, i, j, r, c)
                    if not valid:
                        # Nodata under a drawn triangle: the lattice would cover a hole.
                        if not np.isnan(p):
                            err = np.inf
                            if err > limit:
                                return err, sumsq, count, zmin, zmax
                        continue
                    if np.isnan(p):
                        err = np.inf
                        sumsq = np.inf
                    else:
                        e = abs(z - p)
                        sumsq += e * e
                        if e > err:
                            err = e
                    if err > limit:
                        return err, sumsq, count, zmin, zmax
    return err, sumsq, count, zmin, zmax


@njit(cache=True)
def _uniform_lines(lo, hi, step):
    """lo, lo + step, ... and hi: the lines of a regular lattice with the last one kept."""
    n = (hi - lo + step - 1) // step
    out = np.empty(n + 1, dtype=np.int64)
    for k in range(n):
        out[k] = lo + k * step
    out[n] = hi
    return out


@njit(cache=True)
def coarsest_uniform_step(heights, max_error):
    """Largest step s (same in both directions) whose whole-grid lattice has error <= max_error.

    Steps are tried from the largest down; a failing step stops at its first point beyond
    max_error, so typically only the answer is measured in full. Returns 1 if no step > 1 fits.
    """
    rows, cols = heights.shape
    for step in range(max(rows, cols) - 1, 1, -1):
        r = _uniform_lines(0, rows - 1, step)
        c = _uniform_lines(0, cols - 1, step)
        if _lattice_error(heights, r, c, max_error)[0] <= max_error:
            return step
    return 1


@njit(cache=True, parallel=True)
def lattice_errors(heights, rows, nrows, cols, ncols):
    """``lattice_error`` of many lattices: rows (n, L) with nrows (n,) used, likewise cols.

    Returns error (n,), sumsq (n,), count (n,) int64, zmin (n,), zmax (n,) (NaN without data).
    """
    n = rows.shape[0]
    error = np.empty(n)
    sumsq = np.empty(n)
    count = np.empty(n, dtype=np.int64)
    zmin = np.empty(n)
    zmax = np.empty(n)
    for k in prange(n):
        e, s, m, lo, hi = lattice_error(heights, rows[k, : nrows[k]], cols[k, : ncols[k]])
        error[k] = e
        sumsq[k] = s
        count[k] = m
        zmin[k] = lo if m > 0 else np.nan
        zmax[k] = hi if m > 0 else np.nan
    return error, sumsq, count, zmin, zmax
