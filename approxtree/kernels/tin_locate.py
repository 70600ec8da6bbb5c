"""Point location and linear interpolation in an arbitrary triangulation (TINs).

Triangles are binned into a uniform bucket grid over their bounding boxes (about one triangle
per bucket); a query visits only the triangles of its bucket. Building is O(m + Σ bucket
overlaps), a query is O(triangles per bucket).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, inline="always")
def linear_z(vx, vy, vz, a, b, c, x, y, tol):
    """(inside, z): whether (x, y) lies in triangle a, b, c (barycentric coordinates >= −tol)
    and the triangle's linear height there. Degenerate triangles contain nothing."""
    det = (vy[b] - vy[c]) * (vx[a] - vx[c]) + (vx[c] - vx[b]) * (vy[a] - vy[c])
    if det == 0.0:
        return False, 0.0
    l1 = ((vy[b] - vy[c]) * (x - vx[c]) + (vx[c] - vx[b]) * (y - vy[c])) / det
    l2 = ((vy[c] - vy[a]) * (x - vx[c]) + (vx[a] - vx[c]) * (y - vy[c])) / det
    l3 = 1.0 - l1 - l2
    if l1 >= -tol and l2 >= -tol and l3 >= -tol:
        return True, l1 * vz[a] + l2 * vz[b] + l3 * vz[c]
    return False, 0.0


@njit(cache=True)
def build_buckets(
    vx: np.ndarray,
    vy: np.ndarray,
    tris: np.ndarray,
    xmin: float,
    ymin: float,
    cw: float,
    ch: float,
    nbx: int,
    nby: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Bin triangles by bounding box.

    vx, vy: (n,) float64 vertex coordinates; tris: (m, 3) int64.
    Returns (start (nbx*nby + 1,) int64, items (k,) int64): triangles of bucket b are
    items[start[b]:start[b + 1]].
    """
    m = tris.shape[0]
    counts = np.zeros(nbx * nby + 1, dtype=np.int64)
    # Two passes: count per bucket, then fill, so the item array is allocated once.
    for pass_ in range(2):
        if pass_ == 1:
            for b in range(nbx * nby):
                counts[b + 1] += counts[b]
            items = np.empty(counts[nbx * nby], dtype=np.int64)
            fill = counts[:-1].copy()
        for t in range(m):
            a, b_, c = tris[t, 0], tris[t, 1], tris[t, 2]
            x0 = min(vx[a], min(vx[b_], vx[c]))
            x1 = max(vx[a], max(vx[b_], vx[c]))
            y0 = min(vy[a], min(vy[b_], vy[c]))
            y1 = max(vy[a], max(vy[b_], vy[c]))
            i0 = max(0, min(nbx - 1, int((x0 - xmin) / cw)))
            i1 = max(0, min(nbx - 1, int((x1 - xmin) / cw)))
            j0 = max(0, min(nby - 1, int((y0 - ymin) / ch)))
            j1 = max(0, min(nby - 1, int((y1 - ymin) / ch)))
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    if pass_ == 0:
                        counts[j * nbx + i + 1] += 1
                    else:
                        items[fill[j * nbx + i]] = t
                        fill[j * nbx + i] += 1
    return counts, items


@njit(cache=True, parallel=True)
def locate_and_interpolate(
    vx: np.ndarray,
    vy: np.ndarray,
    vz: np.ndarray,
    tris: np.ndarray,
    start: np.ndarray,
    items: np.ndarray,
    xmin: float,
    ymin: float,
    cw: float,
    ch: float,
    nbx: int,
    nby: int,
    qx: np.ndarray,
    qy: np.ndarray,
    tol: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Triangle containing each query point and the linear height there.

    qx, qy: (q,) float64. tol: barycentric slack so points on shared edges are found.
    Returns (tri (q,) int64, -1 when outside every triangle; z (q,) float64, NaN outside).
    """
    q = qx.shape[0]
    tri_out = np.full(q, -1, dtype=np.int64)
    z_out = np.full(q, np.nan)
    for k in prange(q):
        x = qx[k]
        y = qy[k]
        i = int(np.floor((x - xmin) / cw))
        j = int(np.floor((y - ymin) / ch))
        if i < 0 or j < 0 or i >= nbx or j >= nby:
            # Points on the far border fall just outside the last bucket.
            if i == nbx and x <= xmin + nbx * cw * (1 + 1e-12):
                i = nbx - 1
            if j == nby and y <= ymin + nby * ch * (1 + 1e-12):
                j = nby - 1
            if i < 0 or j < 0 or i >= nbx or j >= nby:
                continue
        b = j * nbx + i
        for s in range(start[b], start[b + 1]):
            t = items[s]
            inside, z = linear_z(vx, vy, vz, tris[t, 0], tris[t, 1], tris[t, 2], x, y, tol)
            if inside:
                tri_out[k] = t
                z_out[k] = z
                break
    return tri_out, z_out
