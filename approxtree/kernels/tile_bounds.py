"""Per-tile reductions of 3D Tiles content: the angles of a lattice's height bound, the
lattice coordinates themselves, and the extent of a tile's region, each in one loop.

tiles/lattice.py and tiles/tile_content.py turn these into the bound a tile's claim carries
and its bounding volume; the loops replace a dozen small numpy reductions per tile.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def lattice_cosines(faces, triangles, up, normals, per_vertex):
    """(cos α, cos θ, cos φ), each the smallest over the tile, of ``tiles.lattice.bound_factor``:
    α between a face's unit normal (``faces`` (m, 3), any length) and the vertical at its
    first vertex, θ between that vertical and its other vertices', φ between a vertex's
    vertical and the lattice's ``up`` (3,). Verticals: ``normals`` (n, 3) unit vectors when
    ``per_vertex``, else ``up`` everywhere (θ = φ = 0). triangles: (m, 3) int64."""
    cos_alpha = math.inf
    cos_theta = math.inf
    cos_phi = math.inf
    for i in range(faces.shape[0]):
        fx, fy, fz = faces[i, 0], faces[i, 1], faces[i, 2]
        length = max(math.sqrt(fx * fx + fy * fy + fz * fz), 1e-300)
        fx, fy, fz = fx / length, fy / length, fz / length
        if per_vertex:
            a = triangles[i, 0]
            nx, ny, nz = normals[a, 0], normals[a, 1], normals[a, 2]
            cos_alpha = min(cos_alpha, fx * nx + fy * ny + fz * nz)
            for k in (1, 2):
                b = triangles[i, k]
                dot = nx * normals[b, 0] + ny * normals[b, 1] + nz * normals[b, 2]
                cos_theta = min(cos_theta, dot)
        else:
            cos_alpha = min(cos_alpha, fx * up[0] + fy * up[1] + fz * up[2])
    if per_vertex:
        for v in range(normals.shape[0]):
            dot = normals[v, 0] * up[0] + normals[v, 1] * up[1] + normals[v, 2] * up[2]
            cos_phi = min(cos_phi, dot)
    else:
        cos_theta = 1.0
        cos_phi = 1.0
    return cos_alpha, cos_theta, cos_phi


@njit(cache=True)
def round_to_lattice(local, origin, step):
    """(q (n, 3) int64, largest q, largest displacement |origin + q · step − local|) of the
    positions ``local`` (n, 3) float64 rounded to the lattice of ``origin`` (3,) and ``step``
    (rounding half to even, as numpy's ``rint``)."""
    n = local.shape[0]
    q = np.empty((n, 3), dtype=np.int64)
    top = np.int64(0)
    moved = 0.0
    for i in range(n):
        d2 = 0.0
        for c in range(3):
            k = np.rint((local[i, c] - origin[c]) / step)
            q[i, c] = np.int64(k)
            top = max(top, q[i, c])
            d = origin[c] + q[i, c] * step - local[i, c]
            d2 += d * d
        moved = max(moved, math.sqrt(d2))
    return q, top, moved


@njit(cache=True)
def region_extent(geo, points, triangles):
    """(low (3,), high (3,), longest chord, largest |latitude|) of a tile: ``geo`` (n, 3)
    longitude, latitude (degrees) and height bounds (low, high), the longest edge of
    ``triangles`` (m, 3) int64 over ``points`` (n, 3) ECEF, and the largest |latitude|
    (degrees) of the vertices."""
    low = np.full(3, math.inf)
    high = np.full(3, -math.inf)
    extreme = 0.0
    for i in range(geo.shape[0]):
        for c in range(3):
            low[c] = min(low[c], geo[i, c])
            high[c] = max(high[c], geo[i, c])
        extreme = max(extreme, abs(geo[i, 1]))
    chord2 = 0.0
    for i in range(triangles.shape[0]):
        for s in range(3):
            a = triangles[i, s]
            b = triangles[i, (s + 1) % 3]
            dx = points[a, 0] - points[b, 0]
            dy = points[a, 1] - points[b, 1]
            dz = points[a, 2] - points[b, 2]
            chord2 = max(chord2, dx * dx + dy * dy + dz * dz)
    return low, high, math.sqrt(chord2), extreme


@njit(cache=True)
def column_bounds(points):
    """(low (3,), high (3,)) per column of ``points`` (n >= 1, 3), in its dtype: numpy's
    ``min(axis=0)`` and ``max(axis=0)`` take tens of microseconds on 3 columns."""
    low = points[0].copy()
    high = points[0].copy()
    for i in range(1, points.shape[0]):
        for c in range(3):
            v = points[i, c]
            if v < low[c]:
                low[c] = v
            if v > high[c]:
                high[c] = v
    return low, high
