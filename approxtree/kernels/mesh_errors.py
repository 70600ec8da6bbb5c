"""Errors of a small triangle mesh at many data points, serially (one patch at a time).

``tin_locate.locate_and_interpolate`` runs in parallel threads, which pays off for one big
query but costs more than the work for the thousands of small queries of patch building; this
kernel builds the same bucket grid and locates serially.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.kernels.tin_locate import build_buckets, linear_z


@njit(cache=True)
def mesh_point_errors(
    vx: np.ndarray,
    vy: np.ndarray,
    vz: np.ndarray,
    tris: np.ndarray,
    qx: np.ndarray,
    qy: np.ndarray,
    qz: np.ndarray,
    tol: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Triangle holding each data point and |z − h_mesh| there.

    vx, vy, vz: (n,) float64 mesh vertices; tris: (m, 3) int64; qx, qy, qz: (q,) data points.
    Returns (tri (q,) int64, −1 outside the mesh; err (q,) float64, inf outside).
    """
    q = qx.shape[0]
    m = tris.shape[0]
    tri_out = np.full(q, -1, dtype=np.int64)
    err_out = np.full(q, np.inf)
    if m == 0 or q == 0:
        return tri_out, err_out
    xmin, xmax = vx.min(), vx.max()
    ymin, ymax = vy.min(), vy.max()
    w = max(xmax - xmin, 1e-12)
    h = max(ymax - ymin, 1e-12)
    # About one triangle per bucket, buckets shaped like the mesh's box.
    nbx = max(1, int(np.sqrt(m * w / h) + 0.5))
    nby = max(1, int(np.sqrt(m * h / w) + 0.5))
    cw, ch = w / nbx, h / nby
    start, items = build_buckets(vx, vy, tris, xmin, ymin, cw, ch, nbx, nby)
    for k in range(q):
        x, y = qx[k], qy[k]
        i = min(max(int(np.floor((x - xmin) / cw)), 0), nbx - 1)
        j = min(max(int(np.floor((y - ymin) / ch)), 0), nby - 1)
        b = j * nbx + i
        for s in range(start[b], start[b + 1]):
            t = items[s]
            inside, z = linear_z(vx, vy, vz, tris[t, 0], tris[t, 1], tris[t, 2], x, y, tol)
            if inside:
                tri_out[k] = t
                err_out[k] = abs(qz[k] - z)
                break
    return tri_out, err_out
