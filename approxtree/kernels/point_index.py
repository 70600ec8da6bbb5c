"""Which scattered points lie in which rectangles: a uniform cell grid over the points.

Points are binned once into cells (counting sort, O(n)); a rectangle query visits only the
cells it overlaps and tests the points there, so a whole tree level costs O(points in its
rectangles + cells visited) instead of O(n) per node.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _cell(v: float, v0: float, size: float, count: int) -> int:
    return min(max(int(np.floor((v - v0) / size)), 0), count - 1)


@njit(cache=True)
def bin_points(
    x: np.ndarray, y: np.ndarray, x0: float, y0: float, cw: float, ch: float, nbx: int, nby: int
) -> tuple[np.ndarray, np.ndarray]:
    """Points of each cell: (start (nbx·nby + 1,) int64, items (n,) int64), the points of
    cell j·nbx + i being items[start[c]:start[c + 1]] in increasing index order."""
    n = x.shape[0]
    cell = np.empty(n, dtype=np.int64)
    start = np.zeros(nbx * nby + 1, dtype=np.int64)
    for k in range(n):
        c = _cell(y[k], y0, ch, nby) * nbx + _cell(x[k], x0, cw, nbx)
        cell[k] = c
        start[c + 1] += 1
    for c in range(nbx * nby):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    items = np.empty(n, dtype=np.int64)
    for k in range(n):
        items[fill[cell[k]]] = k
        fill[cell[k]] += 1
    return start, items


@njit(cache=True)
def points_in_rects(
    x: np.ndarray,
    y: np.ndarray,
    start: np.ndarray,
    items: np.ndarray,
    x0: float,
    y0: float,
    cw: float,
    ch: float,
    nbx: int,
    nby: int,
    rects: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The points inside each closed rectangle (xmin, ymin, xmax, ymax) of rects (r, 4).

    Returns (index (Σ,) int64, starts (r + 1,) int64): rectangle k holds
    index[starts[k]:starts[k + 1]].
    """
    r = rects.shape[0]
    starts = np.zeros(r + 1, dtype=np.int64)
    out = np.empty(max(1024, x.shape[0] // 4), dtype=np.int64)
    m = 0
    for k in range(r):
        xmin, ymin, xmax, ymax = rects[k, 0], rects[k, 1], rects[k, 2], rects[k, 3]
        if xmax >= xmin and ymax >= ymin:
            i0, i1 = _cell(xmin, x0, cw, nbx), _cell(xmax, x0, cw, nbx)
            j0, j1 = _cell(ymin, y0, ch, nby), _cell(ymax, y0, ch, nby)
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    c = j * nbx + i
                    need = m + start[c + 1] - start[c]
                    if need > out.shape[0]:
                        bigger = np.empty(2 * need, dtype=np.int64)
                        bigger[:m] = out[:m]
                        out = bigger
                    for s in range(start[c], start[c + 1]):
                        p = items[s]
                        if x[p] >= xmin and x[p] <= xmax and y[p] >= ymin and y[p] <= ymax:
                            out[m] = p
                            m += 1
        starts[k + 1] = m
    return out[:m].copy(), starts
