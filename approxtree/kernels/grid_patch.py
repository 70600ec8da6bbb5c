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

from approxtree.kernels.grid_interp import lattice_triangles


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
    # In float64 whatever the raster's dtype: a float32 difference of two corners is rounded
    # (up to 3e-5 m at 500 m), which made claimed errors fall short of the true ones.
    z00 = np.float64(z00)
    z01 = np.float64(z01)
    z10 = np.float64(z10)
    z11 = np.float64(z11)
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
    z00 = np.float64(heights[rb, cb])
    z11 = np.float64(heights[re, ce])
    # On the diagonal: triangle B (corners 00, 11, 10) holds it too.
    if dc * hr == dr * wc and not np.isnan(heights[re, cb]):
        return z00 + (dr / hr) * (z11 - z00)
    # North edge: triangle B of the block above (corners (rb−sr, cb), (rb, ce), (rb, cb)).
    if dr == 0 and kr > 0 and not np.isnan(heights[rb - sr, cb]):
        z01 = np.float64(heights[rb, ce])
        p = z00 + (dc / wc) * (z01 - z00)
        if not np.isnan(p):
            return p
    # West edge: triangle A of the block to the left (corners (rb, cb−sc), (rb, cb), (re, cb)).
    if dc == 0 and kc > 0 and not np.isnan(heights[rb, cb - sc]):
        z10 = np.float64(heights[re, cb])
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


@njit(cache=True, inline="always")
def _plain(z) -> bool:
    """A corner the branch-free rows may use: data, small enough that no difference overflows."""
    return abs(z) <= 1e37


@njit(cache=True)
def _fractions(wc):
    """dc / wc for dc = 0 .. wc, the same float64 quotients ``_block_value`` computes."""
    out = np.empty(wc + 1)
    for dc in range(wc + 1):
        out[dc] = dc / wc
    return out


@njit(cache=True)
def _block_fill(heights, p, r, c0, rb, re, cb, ce, cend, vrow, sr, sc, kr, kc, t_off, frac):
    """Fill p over one block's part of row r; returns the error of its per-point path.

    A block whose four corners hold data (and are small enough that no difference overflows)
    draws both triangles: triangle B before dc = t_off, triangle A from there on, each a
    branch-free run with the operands and order of ``_block_value``. Other blocks take the
    per-point path of ``_patch_error`` and leave NaN in p (their error is returned instead).
    """
    hr = re - rb
    wc = ce - cb
    dr = r - rb
    # float64 corners, as _block_value takes them.
    z00 = np.float64(heights[rb, cb])
    z01 = np.float64(heights[rb, ce])
    z10 = np.float64(heights[re, cb])
    z11 = np.float64(heights[re, ce])
    err = 0.0
    if not (_plain(z00) and _plain(z01) and _plain(z10) and _plain(z11)):
        for c in range(cb, cend + 1):
            p[c - c0] = np.nan
            dc = c - cb
            # Patch vertices are reproduced exactly.
            if vrow and (dc == 0 or c == ce):
                continue
            z = heights[r, c]
            v = _block_value(z00, z01, z10, z11, dr, dc, hr, wc)
            if np.isnan(v):
                v = _edge_value(heights, r, c, rb, re, cb, ce, sr, sc, kr, kc)
            err = _fold_error(err, z, not np.isnan(z), v)
        return err
    fr = dr / hr
    t = min(cb + t_off, cend + 1)
    for c in range(cb, t):
        p[c - c0] = z00 + fr * (z10 - z00) + frac[c - cb] * (z11 - z10)
    for c in range(t, cend + 1):
        p[c - c0] = z00 + frac[c - cb] * (z01 - z00) + fr * (z11 - z01)
    # Patch vertices are reproduced exactly.
    if vrow:
        p[cb - c0] = np.nan
        if cend == ce:
            p[ce - c0] = np.nan
    return err


@njit(cache=True)
def _rows_range_scalar(heights, a0, a1, c0, c1):
    """``_rows_range`` point by point (narrow patches)."""
    zmin = np.inf
    zmax = -np.inf
    count = 0
    for r in range(a0, a1 + 1):
        for c in range(c0, c1 + 1):
            z = heights[r, c]
            if z == z:
                count += 1
                if z < zmin:
                    zmin = z
                if z > zmax:
                    zmax = z
    return 0.0, zmin, zmax, count


@njit(cache=True)
def _rows_range(heights, a0, a1, c0, c1):
    """(0, zmin, zmax, count) of rows a0 .. a1 × columns c0 .. c1 (a patch of step 1).

    Per-column minima, maxima and counts in the raster's dtype, element-wise (so the row loop
    vectorises), reduced at the end.
    """
    w = c1 - c0 + 1
    if w < 32:
        # Narrow: the per-column set-up costs more than it saves.
        return _rows_range_scalar(heights, a0, a1, c0, c1)
    lo = np.full(w, np.inf, dtype=heights.dtype)
    hi = np.full(w, -np.inf, dtype=heights.dtype)
    n = np.zeros(w, dtype=np.int64)
    for r in range(a0, a1 + 1):
        # A row view indexed from 0: no negative-index wrap test, so the loop vectorises.
        zrow = heights[r, c0 : c0 + w]
        for j in range(w):
            z = zrow[j]
            lo[j] = z if z < lo[j] else lo[j]
            hi[j] = z if z > hi[j] else hi[j]
            n[j] += z == z
    zmin = np.inf
    zmax = -np.inf
    count = 0
    for j in range(w):
        zmin = min(zmin, lo[j])
        zmax = max(zmax, hi[j])
        count += n[j]
    return 0.0, zmin, zmax, count


# Block width from which a row's heights are filled block by block (else offset by offset).
_WIDE = 16


@njit(cache=True)
def _patch_rows_error(heights, r0, r1, c0, c1, sr, sc, k_lo, k_hi):
    """(error, zmin, zmax, count) of the rows of block rows k_lo .. k_hi − 1 of one grid patch.

    Every point gets the same float value as in ``_patch_error`` (same operands, same order),
    so the maxima are bit for bit the same; only the scan order differs. Along one row of a
    block the triangle changes once, at dc = ceil(dr·wc / hr), and all full-width blocks of a
    row share that threshold: the patch heights of a row are filled offset by offset, each a
    branch-free loop over the blocks (corners gathered once per block row). A second pass
    folds the row into per-column maxima, minima and counts (element-wise, so it vectorises);
    the columns are reduced at the end. The last (narrower) block and blocks with a nodata
    corner are filled block by block (``_block_fill``).
    """
    err = 0.0
    w = c1 - c0 + 1
    nbr = _block_count(r0, r1, sr)
    nbc = _block_count(c0, c1, sc)
    # A patch of step 1 holds every data point as a vertex: nothing to measure but its range.
    vertices_only = sr == 1 and sc == 1
    if vertices_only:
        return _rows_range(heights, r0 + k_lo, r0 + k_hi - 1 if k_hi < nbr else r1, c0, c1)
    if w < 32 and k_lo == 0 and k_hi == nbr:
        # Narrow patches: setting up the rows costs more than the per-point path.
        return _patch_error(heights, r0, r1, c0, c1, sr, sc)
    wl = c1 - (c0 + (nbc - 1) * sc)
    f_full = _fractions(sc)
    f_last = _fractions(wl)
    # Full-width blocks go through the row fill; a narrower last block goes block by block.
    nfull = nbc if wl == sc else nbc - 1
    # Corners of the block row (top and bottom sampled lines), in float64 as _block_value
    # takes them.
    top = np.empty(nbc + 1)
    bot = np.empty(nbc + 1)
    plain = np.empty(nbc, dtype=np.bool_)
    # Per full block: the row's constant terms of _block_value (aB, cA) and its corner
    # differences (dB, dA), so a point costs one multiply and one or two adds.
    a_b = np.empty(max(nfull, 1))
    d_b = np.empty(max(nfull, 1))
    z_a = np.empty(max(nfull, 1))
    d_a = np.empty(max(nfull, 1))
    c_a = np.empty(max(nfull, 1))
    # p: the patch's height along the row, NaN where the point is not measured here.
    p = np.empty(w)
    col_err = np.zeros(w)
    col_min = np.full(w, np.inf)
    col_max = np.full(w, -np.inf)
    col_count = np.zeros(w, dtype=np.int64)
    for kr in range(k_lo, k_hi):
        rb = r0 + kr * sr
        re = min(rb + sr, r1)
        hr = re - rb
        # Interior blocks leave their last row to the next block; the last block keeps it.
        rend = re if kr == nbr - 1 else re - 1
        rough = False
        for kc in range(nbc + 1):
            col = min(c0 + kc * sc, c1)
            top[kc] = heights[rb, col]
            bot[kc] = heights[re, col]
        for kc in range(nbc):
            plain[kc] = (
                _plain(top[kc]) and _plain(top[kc + 1]) and _plain(bot[kc]) and _plain(bot[kc + 1])
            )
            rough |= not plain[kc]
        for kc in range(nfull):
            # Differences in float64, as _block_value takes them.
            d_b[kc] = bot[kc + 1] - bot[kc]
            d_a[kc] = top[kc + 1] - top[kc]
            z_a[kc] = top[kc]
        for r in range(rb, rend + 1):
            dr = r - rb
            vrow = dr == 0 or r == re
            fr = dr / hr
            # Triangle B (00, 11, 10) before offset t, triangle A (00, 01, 11) from t on.
            t_full = (dr * sc + hr - 1) // hr
            t_last = (dr * wl + hr - 1) // hr
            for kc in range(nfull):
                # _block_value's operands and order: B = (z00 + fr·(z10 − z00)) + f·(z11 − z10),
                # A = (z00 + f·(z01 − z00)) + fr·(z11 − z01).
                z00 = top[kc]
                a_b[kc] = z00 + fr * (bot[kc] - z00)
                c_a[kc] = fr * (bot[kc + 1] - top[kc + 1])
            if sc >= _WIDE:
                # Wide blocks: contiguous runs per block.
                for kc in range(nfull):
                    base = kc * sc
                    a = a_b[kc]
                    d = d_b[kc]
                    for dc in range(t_full):
                        p[base + dc] = a + f_full[dc] * d
                    z = z_a[kc]
                    d = d_a[kc]
                    c = c_a[kc]
                    for dc in range(t_full, sc):
                        p[base + dc] = z + f_full[dc] * d + c
            else:
                # Narrow blocks: offset by offset, a loop over the blocks each.
                for dc in range(sc):
                    f = f_full[dc]
                    if dc < t_full:
                        for kc in range(nfull):
                            p[kc * sc + dc] = a_b[kc] + f * d_b[kc]
                    else:
                        for kc in range(nfull):
                            p[kc * sc + dc] = z_a[kc] + f * d_a[kc] + c_a[kc]
            if nfull == nbc:
                # The last column (offset sc of the last block, which keeps it): triangle A.
                p[w - 1] = z_a[nbc - 1] + f_full[sc] * d_a[nbc - 1] + c_a[nbc - 1]
            if vrow:
                # Patch vertices are reproduced exactly.
                for kc in range(nfull):
                    p[kc * sc] = np.nan
                p[w - 1] = np.nan
            if rough:
                for kc in range(nfull):
                    if not plain[kc]:
                        cb = c0 + kc * sc
                        last = kc == nbc - 1
                        e = _block_fill(
                            heights,
                            p,
                            r,
                            c0,
                            rb,
                            re,
                            cb,
                            c1 if last else cb + sc,
                            c1 if last else cb + sc - 1,
                            vrow,
                            sr,
                            sc,
                            kr,
                            kc,
                            t_full,
                            f_full,
                        )
                        err = max(err, e)
            if nfull < nbc:
                cb = c0 + nfull * sc
                e = _block_fill(
                    heights, p, r, c0, rb, re, cb, c1, c1, vrow, sr, sc, kr, nfull, t_last, f_last
                )
                err = max(err, e)
            _fold_row(heights, r, c0, p, col_err, col_min, col_max, col_count)
    zmin = np.inf
    zmax = -np.inf
    count = 0
    for j in range(w):
        err = max(err, col_err[j])
        zmin = min(zmin, col_min[j])
        zmax = max(zmax, col_max[j])
        count += col_count[j]
    return err, zmin, zmax, count


@njit(cache=True)
def _fold_row(heights, r, c0, p, col_err, col_min, col_max, col_count):
    """Fold row r (columns c0 ..) against the patch heights p into the per-column figures.

    A measured point (p not NaN) adds |z − p|, or infinity when z is nodata (the patch would
    cover a hole); every point adds to the z range and count. Element-wise selects only.
    """
    # A row view indexed from 0: no negative-index wrap test, so the loop vectorises.
    zrow = heights[r, c0 : c0 + p.shape[0]]
    for j in range(p.shape[0]):
        z = zrow[j]
        pj = p[j]
        valid = z == z
        e = abs(z - pj)
        e = e if e == e else (np.inf if pj == pj else 0.0)
        col_err[j] = e if e > col_err[j] else col_err[j]
        col_min[j] = z if z < col_min[j] else col_min[j]
        col_max[j] = z if z > col_max[j] else col_max[j]
        col_count[j] += valid


@njit(cache=True)
def _both_zeros(heights, r0, r1, c0, c1) -> bool:
    """Whether rows r0 .. r1 × columns c0 .. c1 hold both +0.0 and −0.0."""
    pos = False
    neg = False
    for r in range(r0, r1 + 1):
        for c in range(c0, c1 + 1):
            z = heights[r, c]
            if z == 0.0:
                if np.copysign(1.0, z) < 0.0:
                    neg = True
                else:
                    pos = True
        if pos and neg:
            return True
    return False


# Work items a level is cut into at least (bands of block rows of its few coarse nodes).
_ITEMS = 64


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
    # Work items: a few nodes of a coarse level are cut into bands of block rows, so that
    # every thread has work; maxima, minima and counts of the bands combine exactly.
    parts = np.empty(n, dtype=np.int64)
    first = np.empty(n + 1, dtype=np.int64)
    first[0] = 0
    want = max(1, (_ITEMS + n - 1) // n)
    for i in range(n):
        parts[i] = min(want, _block_count(ranges[i, 0], ranges[i, 1], steps[i, 0]))
        first[i + 1] = first[i] + parts[i]
    m = first[n]
    item_node = np.empty(m, dtype=np.int64)
    item_lo = np.empty(m, dtype=np.int64)
    item_hi = np.empty(m, dtype=np.int64)
    for i in range(n):
        nbr = _block_count(ranges[i, 0], ranges[i, 1], steps[i, 0])
        for j in range(parts[i]):
            item_node[first[i] + j] = i
            item_lo[first[i] + j] = nbr * j // parts[i]
            item_hi[first[i] + j] = nbr * (j + 1) // parts[i]
    e_item = np.empty(m)
    lo_item = np.empty(m)
    hi_item = np.empty(m)
    k_item = np.empty(m, dtype=np.int64)
    for t in prange(m):
        i = item_node[t]
        e, lo, hi, k = _patch_rows_error(
            heights,
            ranges[i, 0],
            ranges[i, 1],
            ranges[i, 2],
            ranges[i, 3],
            steps[i, 0],
            steps[i, 1],
            item_lo[t],
            item_hi[t],
        )
        e_item[t] = e
        lo_item[t] = lo
        hi_item[t] = hi
        k_item[t] = k
    error = np.empty(n)
    zmin = np.empty(n)
    zmax = np.empty(n)
    count = np.empty(n, dtype=np.int64)
    for i in range(n):
        e = 0.0
        lo = np.inf
        hi = -np.inf
        k = 0
        for t in range(first[i], first[i + 1]):
            e = max(e, e_item[t])
            lo = min(lo, lo_item[t])
            hi = max(hi, hi_item[t])
            k += k_item[t]
        if (lo == 0.0 or hi == 0.0) and _both_zeros(
            heights, ranges[i, 0], ranges[i, 1], ranges[i, 2], ranges[i, 3]
        ):
            # Which zero (+0 or −0) is the extreme depends on the scan order: take the reference
            # order's, so results stay identical bit for bit.
            _, lo, hi, _ = _patch_error(
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
    triangles with a nodata corner are left out (``grid_interp.lattice_triangles``).
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
    return rows, cols, lattice_triangles(heights, rows, cols)


@njit(cache=True)
def _lattice_edge_value(lattice, i, j, dr, dc, hr, wc, kr, kc):
    """``_edge_value`` with the patch's vertices read from a lattice (see grid_patch_part)."""
    z00 = np.float64(lattice[i, j])
    z11 = np.float64(lattice[i + 1, j + 1])
    if dc * hr == dr * wc and not np.isnan(lattice[i + 1, j]):
        return z00 + (dr / hr) * (z11 - z00)
    if dr == 0 and kr > 0 and not np.isnan(lattice[i - 1, j]):
        z01 = np.float64(lattice[i, j + 1])
        p = z00 + (dc / wc) * (z01 - z00)
        if not np.isnan(p):
            return p
    if dc == 0 and kc > 0 and not np.isnan(lattice[i, j - 1]):
        z10 = np.float64(lattice[i + 1, j])
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
