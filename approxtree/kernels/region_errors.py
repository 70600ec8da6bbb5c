"""Errors of a triangle mesh at many points that cover only a small part of it.

``mesh_errors.mesh_point_errors`` lays its bucket grid over the whole mesh, about one
triangle per bucket; when the points crowd into a corner of the mesh (a DEM a few units wide
in a tile whose edges and outside are meshed too) one bucket then holds all the triangles
there and every point scans them all. Here the grid is laid over the points' bounding box
instead, with about as many buckets as triangles meet it (and no more than there are
points); a triangle is binned into the buckets its bounding box covers inside the grid.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.kernels.tin_locate import linear_z


@njit(cache=True)
def region_point_errors(
    vx: np.ndarray,
    vy: np.ndarray,
    vz: np.ndarray,
    tris: np.ndarray,
    qx: np.ndarray,
    qy: np.ndarray,
    qz: np.ndarray,
    tol: float,
) -> np.ndarray:
    """|z − h_mesh| at each point (inf where no triangle holds it).

    vx, vy, vz: (n,) float64 mesh vertices; tris: (m, 3) int64; qx, qy, qz: (q,) float64
    points. Returns (q,) float64.
    """
    q = qx.shape[0]
    m = tris.shape[0]
    out = np.full(q, np.inf)
    if q == 0 or m == 0:
        return out
    x0, x1 = qx.min(), qx.max()
    y0, y1 = qy.min(), qy.max()
    # The triangles whose box meets the points' box.
    meets = np.zeros(m, dtype=np.bool_)
    k = 0
    for t in range(m):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        if (
            max(vx[a], max(vx[b], vx[c])) >= x0
            and min(vx[a], min(vx[b], vx[c])) <= x1
            and max(vy[a], max(vy[b], vy[c])) >= y0
            and min(vy[a], min(vy[b], vy[c])) <= y1
        ):
            meets[t] = True
            k += 1
    w = max(x1 - x0, 1e-9)
    h = max(y1 - y0, 1e-9)
    cells = max(1, min(k, q))
    nbx = max(1, int(np.sqrt(cells * w / h) + 0.5))
    nby = max(1, int(np.sqrt(cells * h / w) + 0.5))
    cw, ch = w / nbx, h / nby
    # Two passes: count per bucket, then fill.
    start = np.zeros(nbx * nby + 1, dtype=np.int64)
    items = np.empty(0, dtype=np.int64)
    fill = np.empty(0, dtype=np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            for i in range(nbx * nby):
                start[i + 1] += start[i]
            items = np.empty(start[nbx * nby], dtype=np.int64)
            fill = start[:-1].copy()
        for t in range(m):
            if not meets[t]:
                continue
            a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
            i0 = max(0, min(nbx - 1, int((min(vx[a], min(vx[b], vx[c])) - x0) / cw)))
            i1 = max(0, min(nbx - 1, int((max(vx[a], max(vx[b], vx[c])) - x0) / cw)))
            j0 = max(0, min(nby - 1, int((min(vy[a], min(vy[b], vy[c])) - y0) / ch)))
            j1 = max(0, min(nby - 1, int((max(vy[a], max(vy[b], vy[c])) - y0) / ch)))
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    if pass_ == 0:
                        start[j * nbx + i + 1] += 1
                    else:
                        items[fill[j * nbx + i]] = t
                        fill[j * nbx + i] += 1
    for p in range(q):
        x, y = qx[p], qy[p]
        i = min(max(int((x - x0) / cw), 0), nbx - 1)
        j = min(max(int((y - y0) / ch), 0), nby - 1)
        b = j * nbx + i
        for s in range(start[b], start[b + 1]):
            t = items[s]
            inside, z = linear_z(vx, vy, vz, tris[t, 0], tris[t, 1], tris[t, 2], x, y, tol)
            if inside:
                out[p] = abs(qz[p] - z)
                break
    return out
