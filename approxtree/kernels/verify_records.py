"""Patch records of a tree store read back into triangles, for ``approxtree verify``.

Own code, not the patches' (``verify`` checks what they wrote): the layouts are those of the
store's docstring (``tree/tree_store.py``) and of each strategy's record:

- grid: ``index`` (r0, r1, c0, c1, sr, sc): rows r0, r0 + sr, ... and always r1 (columns
  alike); nonregular: ``lines`` [kr, kc, rows..., cols...]. Both are lattices whose cells are
  cut by the diagonal from (row i, col j) to (row i + 1, col j + 1): triangles (00, 01, 11)
  and (00, 11, 10); a triangle with a nodata corner is not drawn.
- tin and rtin over a grid: ``mesh`` [n, m, n × (row, col), m × 3 corners]; tin over points:
  ``mesh`` [n, m, n point indices, m × 3 corners].

Flat record data come with (k + 1,) offsets, as the store keeps them.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def grid_lines(index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows and columns of grid patches. index: (k, 6) int64 (r0, r1, c0, c1, sr, sc).

    Returns rows (R,), row_offsets (k + 1,), cols (C,), col_offsets (k + 1,) int64.
    """
    k = index.shape[0]
    row_off = np.zeros(k + 1, dtype=np.int64)
    col_off = np.zeros(k + 1, dtype=np.int64)
    for i in range(k):
        r0, r1, c0, c1, sr, sc = index[i]
        row_off[i + 1] = row_off[i] + (r1 - r0 + sr - 1) // sr + 1
        col_off[i + 1] = col_off[i] + (c1 - c0 + sc - 1) // sc + 1
    rows = np.empty(row_off[k], dtype=np.int64)
    cols = np.empty(col_off[k], dtype=np.int64)
    for i in range(k):
        r0, r1, c0, c1, sr, sc = index[i]
        for a in range(row_off[i], row_off[i + 1] - 1):
            rows[a] = r0 + (a - row_off[i]) * sr
        rows[row_off[i + 1] - 1] = r1
        for a in range(col_off[i], col_off[i + 1] - 1):
            cols[a] = c0 + (a - col_off[i]) * sc
        cols[col_off[i + 1] - 1] = c1
    return rows, row_off, cols, col_off


@njit(cache=True)
def nonregular_lines(
    flat: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows and columns of nonregular records [kr, kc, rows..., cols...] (flat int64 data,
    (k + 1,) offsets); returns like ``grid_lines``. A malformed record gives no line."""
    k = offsets.shape[0] - 1
    row_off = np.zeros(k + 1, dtype=np.int64)
    col_off = np.zeros(k + 1, dtype=np.int64)
    for i in range(k):
        a = offsets[i]
        ok = offsets[i + 1] - a >= 2 and offsets[i + 1] - a == 2 + flat[a] + flat[a + 1]
        row_off[i + 1] = row_off[i] + (flat[a] if ok else 0)
        col_off[i + 1] = col_off[i] + (flat[a + 1] if ok else 0)
    rows = np.empty(row_off[k], dtype=np.int64)
    cols = np.empty(col_off[k], dtype=np.int64)
    for i in range(k):
        a = offsets[i] + 2
        kr = row_off[i + 1] - row_off[i]
        kc = col_off[i + 1] - col_off[i]
        for j in range(kr):
            rows[row_off[i] + j] = flat[a + j]
        for j in range(kc):
            cols[col_off[i] + j] = flat[a + kr + j]
    return rows, row_off, cols, col_off


@njit(cache=True)
def lattice_points(
    rows: np.ndarray, row_off: np.ndarray, cols: np.ndarray, col_off: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every lattice vertex of each patch, row-major: (row (P,), col (P,), offsets (k + 1,))."""
    k = row_off.shape[0] - 1
    off = np.zeros(k + 1, dtype=np.int64)
    for i in range(k):
        off[i + 1] = off[i] + (row_off[i + 1] - row_off[i]) * (col_off[i + 1] - col_off[i])
    rr = np.empty(off[k], dtype=np.int64)
    cc = np.empty(off[k], dtype=np.int64)
    for i in range(k):
        at = off[i]
        for a in range(row_off[i], row_off[i + 1]):
            for b in range(col_off[i], col_off[i + 1]):
                rr[at] = rows[a]
                cc[at] = cols[b]
                at += 1
    return rr, cc, off


@njit(cache=True)
def lattice_soup(
    rows: np.ndarray,
    row_off: np.ndarray,
    cols: np.ndarray,
    col_off: np.ndarray,
    z: np.ndarray,
    z_off: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (t, 9) (u = col, v = row, z per corner) of lattice patches and the patch of
    each (t,) int64, patch by patch; z: the row-major lattice heights (``lattice_points``'
    order), z_off (k + 1,). Cells with a nodata corner drop the triangles touching it; a
    valid vertex left in no triangle comes as a lone vertex (three equal corners)."""
    k = row_off.shape[0] - 1
    total = 0
    for i in range(k):
        kr = row_off[i + 1] - row_off[i]
        kc = col_off[i + 1] - col_off[i]
        total += 2 * max(kr - 1, 0) * max(kc - 1, 0) + kr * kc
    out = np.empty((total, 9))
    owner = np.empty(total, dtype=np.int64)
    m = 0
    for i in range(k):
        kr = row_off[i + 1] - row_off[i]
        kc = col_off[i + 1] - col_off[i]
        base = z_off[i]
        used = np.zeros(kr * kc, dtype=np.bool_)
        for a in range(kr - 1):
            ra, rb = float(rows[row_off[i] + a]), float(rows[row_off[i] + a + 1])
            for b in range(kc - 1):
                ca, cb = float(cols[col_off[i] + b]), float(cols[col_off[i] + b + 1])
                i00 = a * kc + b
                i01, i10, i11 = i00 + 1, i00 + kc, i00 + kc + 1
                z00, z01, z10, z11 = z[base + i00], z[base + i01], z[base + i10], z[base + i11]
                if not (np.isnan(z00) or np.isnan(z01) or np.isnan(z11)):
                    out[m, 0], out[m, 1], out[m, 2] = ca, ra, z00
                    out[m, 3], out[m, 4], out[m, 5] = cb, ra, z01
                    out[m, 6], out[m, 7], out[m, 8] = cb, rb, z11
                    owner[m] = i
                    used[i00] = used[i01] = used[i11] = True
                    m += 1
                if not (np.isnan(z00) or np.isnan(z11) or np.isnan(z10)):
                    out[m, 0], out[m, 1], out[m, 2] = ca, ra, z00
                    out[m, 3], out[m, 4], out[m, 5] = cb, rb, z11
                    out[m, 6], out[m, 7], out[m, 8] = ca, rb, z10
                    owner[m] = i
                    used[i00] = used[i11] = used[i10] = True
                    m += 1
        for a in range(kr):
            for b in range(kc):
                zv = z[base + a * kc + b]
                if used[a * kc + b] or np.isnan(zv):
                    continue
                u, v = float(cols[col_off[i] + b]), float(rows[row_off[i] + a])
                for c in range(3):
                    out[m, 3 * c], out[m, 3 * c + 1], out[m, 3 * c + 2] = u, v, zv
                owner[m] = i
                m += 1
    return out[:m], owner[:m]


@njit(cache=True)
def index_meshes(
    flat: np.ndarray, offsets: np.ndarray, width: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vertices and triangles of mesh records [n, m, n × width values, m × 3 corners].

    flat: int64 record data, offsets (k + 1,). Returns verts (N, width) int64, vert_off (k + 1,),
    tris (T, 3) int64 into ``verts`` (global), owner (T,) int64, bad (k,) bool: records whose
    lengths or corners do not add up (they give no triangle).
    """
    k = offsets.shape[0] - 1
    bad = np.zeros(k, dtype=np.bool_)
    vert_off = np.zeros(k + 1, dtype=np.int64)
    tri_count = 0
    for i in range(k):
        a, e = offsets[i], offsets[i + 1]
        n = flat[a] if e - a >= 2 else -1
        m = flat[a + 1] if e - a >= 2 else -1
        if n < 0 or m < 0 or e - a != 2 + width * n + 3 * m:
            bad[i] = True
            vert_off[i + 1] = vert_off[i]
            continue
        for j in range(3 * m):
            c = flat[a + 2 + width * n + j]
            if c < 0 or c >= n:
                bad[i] = True
        vert_off[i + 1] = vert_off[i] + (0 if bad[i] else n)
        tri_count += 0 if bad[i] else m
    verts = np.empty((vert_off[k], width), dtype=np.int64)
    tris = np.empty((tri_count, 3), dtype=np.int64)
    owner = np.empty(tri_count, dtype=np.int64)
    t = 0
    for i in range(k):
        if bad[i]:
            continue
        a = offsets[i]
        n, m = flat[a], flat[a + 1]
        for j in range(n):
            for w in range(width):
                verts[vert_off[i] + j, w] = flat[a + 2 + width * j + w]
        for j in range(m):
            for c in range(3):
                tris[t, c] = vert_off[i] + flat[a + 2 + width * n + 3 * j + c]
            owner[t] = i
            t += 1
    return verts, vert_off, tris, owner, bad
