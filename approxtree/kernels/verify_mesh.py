"""Errors of triangle meshes at a terrain's data points, for ``approxtree verify``.

Own code: ``verify`` must not trust the kernels of the writers it checks (greedy, RTIN, grid
patches, tin_locate), so the two ways of meeting the data points are written here again:

- ``grid_mesh_errors``: data points on a raster's lattice. Each triangle is rasterized over the
  lattice points of its bounding box, in the raster's index space (u = column, v = row), where
  the vertices of patches over the raster are integers and the edge tests are exact.
- ``point_mesh_errors``: scattered data points, sorted into buckets beforehand (numpy); each
  triangle visits the buckets of its bounding box.

Both take an *owner* per group of triangles (a node, a tile, a whole mesh): the data points
of the owner's closed rectangle are measured against the owner's triangles only.

Triangles are (t, 9) float64 rows (u0, v0, z0, u1, v1, z1, u2, v2, z2). A data point is inside
a triangle when it lies on the inner side of every edge or within ``tol`` (a distance, in the
u, v units) of it; its height there is the plane through the three corners. A point inside
several triangles (shared edges, overlaps) takes the largest |z − h| of them; the triangles
that hold it only within ``tol`` (not within ``TIGHT``) count only where none holds it
strictly (rounded border vertices), and a nodata point under a triangle counts only when the
triangle holds it strictly. A nearly vertical triangle holds no data point: seen from above,
one edge shorter than ``FLAT`` times the longest or than ``tol`` (a skirt's wall), or narrower
than ``tol`` (a near-vertical sliver of a point cloud's TIN, whose heights a tile's float32
rounding scrambles); nor does a triangle with a non-finite corner (not drawn). A row whose
three corners are one point is a *vertex* alone (a patch vertex in no triangle): it holds the
data point within ``tol`` of it, at its own height, as the writers count such points
represented.

Per owner: the largest error and where, the sum of squares and count of the points measured,
the valid points no triangle holds (``uncovered``), the nodata points a triangle holds
(``holes``: invented surface), and the z range of the valid points.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: A triangle whose shortest edge, seen from above, is below FLAT × its longest is vertical.
FLAT = 1e-4
#: Distance (u, v units) within which a point on an edge is strictly inside (round-off).
TIGHT = 1e-9


@njit(cache=True, inline="always")
def _flat(t: np.ndarray, k: int, tol: float) -> bool:
    """Whether triangle k is not drawn over the data (vertical, degenerate or non-finite):
    seen from above, an edge shorter than FLAT × the longest or than ``tol``, or narrower
    than ``tol``."""
    u0, v0, z0 = t[k, 0], t[k, 1], t[k, 2]
    u1, v1, z1 = t[k, 3], t[k, 4], t[k, 5]
    u2, v2, z2 = t[k, 6], t[k, 7], t[k, 8]
    if not (np.isfinite(z0) and np.isfinite(z1) and np.isfinite(z2)):
        return True
    a = (u1 - u0) ** 2 + (v1 - v0) ** 2
    b = (u2 - u1) ** 2 + (v2 - v1) ** 2
    c = (u0 - u2) ** 2 + (v0 - v2) ** 2
    lo = min(a, min(b, c))
    hi = max(a, max(b, c))
    area2 = (u1 - u0) * (v2 - v0) - (v1 - v0) * (u2 - u0)
    if area2 == 0.0 or not hi > 0.0 or lo < FLAT * FLAT * hi or lo < tol * tol:
        return True
    # A sliver narrower than tol (its height over the longest edge): a wall seen from above.
    return area2 * area2 < tol * tol * hi


@njit(cache=True, inline="always")
def _is_vertex(t: np.ndarray, k: int) -> bool:
    """Whether row k is a lone vertex (three equal corners of finite height)."""
    return t[k, 0] == t[k, 3] == t[k, 6] and t[k, 1] == t[k, 4] == t[k, 7] and np.isfinite(t[k, 2])


@njit(cache=True, inline="always")
def _height(t: np.ndarray, k: int, s: float, x: float, y: float, tol: float) -> tuple[float, bool]:
    """(h, strict): the plane's height of triangle k at (x, y), NaN when (x, y) is farther
    than tol outside it; strict when it is inside (within TIGHT of an edge).

    s: the triangle's orientation (+1 counter-clockwise, −1 clockwise). Each corner's weight
    is the (signed) edge function of the opposite edge, over the edge's length a distance.
    """
    u0, v0, z0 = t[k, 0], t[k, 1], t[k, 2]
    u1, v1, z1 = t[k, 3], t[k, 4], t[k, 5]
    u2, v2, z2 = t[k, 6], t[k, 7], t[k, 8]
    w0 = s * ((u2 - u1) * (y - v1) - (v2 - v1) * (x - u1))
    w1 = s * ((u0 - u2) * (y - v2) - (v0 - v2) * (x - u2))
    w2 = s * ((u1 - u0) * (y - v0) - (v1 - v0) * (x - u0))
    if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
        return (w0 * z0 + w1 * z1 + w2 * z2) / (w0 + w1 + w2), True
    d = min(
        w0 / np.sqrt((u2 - u1) ** 2 + (v2 - v1) ** 2),
        min(
            w1 / np.sqrt((u0 - u2) ** 2 + (v0 - v2) ** 2),
            w2 / np.sqrt((u1 - u0) ** 2 + (v1 - v0) ** 2),
        ),
    )
    if d < -tol:
        return np.nan, False
    return (w0 * z0 + w1 * z1 + w2 * z2) / (w0 + w1 + w2), d >= -min(tol, TIGHT)


@njit(cache=True, inline="always")
def _orientation(t: np.ndarray, k: int) -> float:
    area2 = (t[k, 3] - t[k, 0]) * (t[k, 7] - t[k, 1]) - (t[k, 4] - t[k, 1]) * (t[k, 6] - t[k, 0])
    return 1.0 if area2 > 0.0 else -1.0


@njit(cache=True, inline="always")
def _fold(buf: np.ndarray, i: int, zd: float, h: float, strict: bool) -> None:
    """Fold height h of a triangle holding data point i (height zd, NaN = nodata) into buf:
    buf[2i] for the triangles holding it strictly, buf[2i + 1] for those within tol only
    (−1 none yet, inf a nodata point under a triangle, else the largest |zd − h|)."""
    j = 2 * i if strict else 2 * i + 1
    if np.isnan(zd):
        buf[j] = np.inf
    else:
        e = abs(zd - h)
        if e > buf[j]:
            buf[j] = e


@njit(cache=True, inline="always")
def _settle(buf: np.ndarray, i: int, valid: bool) -> float:
    """The error of data point i: its strict triangles', else those within tol (a point the
    rounding of a border put just outside); −1 when none holds it, inf for a hole."""
    if buf[2 * i] >= 0.0:
        return buf[2 * i]
    return buf[2 * i + 1] if valid else -1.0


@njit(parallel=True, cache=True)
def grid_mesh_errors(
    z: np.ndarray,
    wr0: int,
    wc0: int,
    pieces: np.ndarray,
    piece_tris: np.ndarray,
    tris: np.ndarray,
    tol: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Errors of owners' triangles at the lattice points of a raster window.

    z: (h, w) float64 heights of the window, NaN = nodata; wr0, wc0: raster index of z[0, 0].
    pieces: (p, 4) int64 inclusive raster index ranges (r0, r1, c0, c1), each inside the
    window (an owner may have several pieces). piece_tris: (p, 2) int64 [start, stop) of the
    piece's owner's triangles in ``tris`` (t, 9) (u = column, v = row, raster indices).
    Returns, per piece: err (p,) float64 (−inf when no point was measured), worst (p, 2) int64
    raster (row, col) of err, sumsq (p,) float64, counts (p, 3) int64 (measured, uncovered,
    holes), zrange (p, 2) float64 of the valid points (inf, −inf when none).
    """
    p = pieces.shape[0]
    err = np.full(p, -np.inf)
    worst = np.full((p, 2), -1, dtype=np.int64)
    sumsq = np.zeros(p)
    counts = np.zeros((p, 3), dtype=np.int64)
    zrange = np.empty((p, 2))
    for q in prange(p):
        r0, r1, c0, c1 = pieces[q, 0], pieces[q, 1], pieces[q, 2], pieces[q, 3]
        zrange[q, 0], zrange[q, 1] = np.inf, -np.inf
        if r1 < r0 or c1 < c0:
            continue
        w = c1 - c0 + 1
        buf = np.full(2 * (r1 - r0 + 1) * w, -1.0)
        for k in range(piece_tris[q, 0], piece_tris[q, 1]):
            if _is_vertex(tris, k):
                r, c = int(np.rint(tris[k, 1])), int(np.rint(tris[k, 0]))
                near = abs(tris[k, 1] - r) <= tol and abs(tris[k, 0] - c) <= tol
                if near and r0 <= r <= r1 and c0 <= c <= c1:
                    _fold(buf, (r - r0) * w + (c - c0), z[r - wr0, c - wc0], tris[k, 2], True)
                continue
            if _flat(tris, k, tol):
                continue
            s = _orientation(tris, k)
            umin = min(tris[k, 0], min(tris[k, 3], tris[k, 6])) - tol
            umax = max(tris[k, 0], max(tris[k, 3], tris[k, 6])) + tol
            vmin = min(tris[k, 1], min(tris[k, 4], tris[k, 7])) - tol
            vmax = max(tris[k, 1], max(tris[k, 4], tris[k, 7])) + tol
            ra = max(r0, int(np.ceil(vmin)))
            rb = min(r1, int(np.floor(vmax)))
            ca = max(c0, int(np.ceil(umin)))
            cb = min(c1, int(np.floor(umax)))
            for r in range(ra, rb + 1):
                for c in range(ca, cb + 1):
                    h, strict = _height(tris, k, s, float(c), float(r), tol)
                    if not np.isnan(h):
                        _fold(buf, (r - r0) * w + (c - c0), z[r - wr0, c - wc0], h, strict)
        # Every point of the piece: measured, uncovered or a hole.
        for r in range(r0, r1 + 1):
            for c in range(c0, c1 + 1):
                zd = z[r - wr0, c - wc0]
                e = _settle(buf, (r - r0) * w + (c - c0), not np.isnan(zd))
                if np.isnan(zd):
                    if e == np.inf:
                        counts[q, 2] += 1
                    continue
                zrange[q, 0] = min(zrange[q, 0], zd)
                zrange[q, 1] = max(zrange[q, 1], zd)
                if e < 0.0:
                    counts[q, 1] += 1
                    continue
                counts[q, 0] += 1
                sumsq[q] += e * e
                if e > err[q]:
                    err[q] = e
                    worst[q, 0], worst[q, 1] = r, c
    return err, worst, sumsq, counts, zrange


@njit(parallel=True, cache=True)
def point_mesh_errors(
    px: np.ndarray,
    py: np.ndarray,
    pz: np.ndarray,
    bucket_start: np.ndarray,
    bucket_items: np.ndarray,
    grid: np.ndarray,
    rects: np.ndarray,
    owner_tris: np.ndarray,
    tris: np.ndarray,
    tol: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Errors of owners' triangles at scattered data points.

    px, py, pz: (n,) float64 data points (no nodata); bucket_start (nb + 1,), bucket_items (n,)
    int64: the points of bucket b are bucket_items[bucket_start[b]:bucket_start[b + 1]], bucket
    b = j · nbx + i of cells ``grid`` = (x0, y0, cell width, cell height, nbx, nby) (float64).
    rects: (k, 4) float64 closed rectangles (xmin, ymin, xmax, ymax) of the owners (the points
    within tol of it are measured); owner_tris: (k, 2) int64 [start, stop) of each owner's
    triangles in ``tris`` (t, 9) (u = x, v = y).
    Returns, per owner: err (k,) (−inf when no point was measured), worst (k,) int64 point
    index, sumsq (k,), counts (k, 3) int64 (measured, uncovered, 0), zrange (k, 2).
    """
    k_owners = rects.shape[0]
    x0, y0, cw, ch = grid[0], grid[1], grid[2], grid[3]
    nbx, nby = int(grid[4]), int(grid[5])
    err = np.full(k_owners, -np.inf)
    worst = np.full(k_owners, -1, dtype=np.int64)
    sumsq = np.zeros(k_owners)
    counts = np.zeros((k_owners, 3), dtype=np.int64)
    zrange = np.empty((k_owners, 2))
    for o in prange(k_owners):
        zrange[o, 0], zrange[o, 1] = np.inf, -np.inf
        xa, ya = rects[o, 0] - tol, rects[o, 1] - tol
        xb, yb = rects[o, 2] + tol, rects[o, 3] + tol
        ia = min(max(int(np.floor((xa - x0) / cw)), 0), nbx - 1)
        ib = min(max(int(np.floor((xb - x0) / cw)), 0), nbx - 1)
        ja = min(max(int(np.floor((ya - y0) / ch)), 0), nby - 1)
        jb = min(max(int(np.floor((yb - y0) / ch)), 0), nby - 1)
        # The owner's points: counted, then gathered.
        n = 0
        for j in range(ja, jb + 1):
            for i in range(ia, ib + 1):
                b = j * nbx + i
                for slot in range(bucket_start[b], bucket_start[b + 1]):
                    t = bucket_items[slot]
                    if xa <= px[t] <= xb and ya <= py[t] <= yb:
                        n += 1
        if n == 0:
            continue
        ids = np.empty(n, dtype=np.int64)
        n = 0
        for j in range(ja, jb + 1):
            for i in range(ia, ib + 1):
                b = j * nbx + i
                for slot in range(bucket_start[b], bucket_start[b + 1]):
                    t = bucket_items[slot]
                    if xa <= px[t] <= xb and ya <= py[t] <= yb:
                        ids[n] = t
                        n += 1
        # Local buckets over the owner's rectangle (about two points each), counting sort.
        lw = max(xb - xa, 1e-300)
        lh = max(yb - ya, 1e-300)
        side = max(1, int(np.sqrt(n / 2.0)))
        lnx = max(1, min(side * 4, int(side * np.sqrt(lw / lh)) + 1))
        lny = max(1, min(side * 4, int(side * np.sqrt(lh / lw)) + 1))
        lcw, lch = lw / lnx, lh / lny
        cell = np.empty(n, dtype=np.int64)
        start = np.zeros(lnx * lny + 1, dtype=np.int64)
        for a in range(n):
            i = min(int((px[ids[a]] - xa) / lcw), lnx - 1)
            j = min(int((py[ids[a]] - ya) / lch), lny - 1)
            cell[a] = j * lnx + i
            start[cell[a] + 1] += 1
        for b in range(lnx * lny):
            start[b + 1] += start[b]
        fill = start[:-1].copy()
        local = np.empty(n, dtype=np.int64)
        for a in range(n):
            local[fill[cell[a]]] = a
            fill[cell[a]] += 1
        buf = np.full(2 * n, -1.0)
        for k in range(owner_tris[o, 0], owner_tris[o, 1]):
            vertex = _is_vertex(tris, k)
            if not vertex and _flat(tris, k, tol):
                continue
            s = _orientation(tris, k)
            umin = min(tris[k, 0], min(tris[k, 3], tris[k, 6])) - tol
            umax = max(tris[k, 0], max(tris[k, 3], tris[k, 6])) + tol
            vmin = min(tris[k, 1], min(tris[k, 4], tris[k, 7])) - tol
            vmax = max(tris[k, 1], max(tris[k, 4], tris[k, 7])) + tol
            if umax < xa or umin > xb or vmax < ya or vmin > yb:
                continue
            ia2 = min(max(int(np.floor((umin - xa) / lcw)), 0), lnx - 1)
            ib2 = min(max(int(np.floor((umax - xa) / lcw)), 0), lnx - 1)
            ja2 = min(max(int(np.floor((vmin - ya) / lch)), 0), lny - 1)
            jb2 = min(max(int(np.floor((vmax - ya) / lch)), 0), lny - 1)
            for j in range(ja2, jb2 + 1):
                for i in range(ia2, ib2 + 1):
                    b = j * lnx + i
                    for s2 in range(start[b], start[b + 1]):
                        a = local[s2]
                        t = ids[a]
                        if vertex:
                            if abs(px[t] - tris[k, 0]) <= tol and abs(py[t] - tris[k, 1]) <= tol:
                                _fold(buf, a, pz[t], tris[k, 2], True)
                            continue
                        h, strict = _height(tris, k, s, px[t], py[t], tol)
                        if not np.isnan(h):
                            _fold(buf, a, pz[t], h, strict)
        for a in range(n):
            t = ids[a]
            zrange[o, 0] = min(zrange[o, 0], pz[t])
            zrange[o, 1] = max(zrange[o, 1], pz[t])
            e = _settle(buf, a, True)
            if e < 0.0:
                counts[o, 1] += 1
                continue
            counts[o, 0] += 1
            sumsq[o] += e * e
            if e > err[o]:
                err[o] = e
                worst[o] = t
    return err, worst, sumsq, counts, zrange


def bucket_points(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Buckets of scattered points for ``point_mesh_errors``: (start, items, grid), about two
    points a bucket over the points' bounding box. x, y: (n,) float64."""
    n = len(x)
    if n == 0:
        return (
            np.zeros(2, dtype=np.int64),
            np.zeros(0, dtype=np.int64),
            np.array([0, 0, 1, 1, 1, 1.0]),
        )
    x0, x1 = float(x.min()), float(x.max())
    y0, y1 = float(y.min()), float(y.max())
    w = max(x1 - x0, 1e-300)
    h = max(y1 - y0, 1e-300)
    side = max(1.0, np.sqrt(n / 2.0))
    nbx = int(max(1, min(4 * side, side * np.sqrt(w / h) + 1)))
    nby = int(max(1, min(4 * side, side * np.sqrt(h / w) + 1)))
    cw, ch = w / nbx * (1 + 1e-12), h / nby * (1 + 1e-12)
    i = np.minimum(((x - x0) / cw).astype(np.int64), nbx - 1)
    j = np.minimum(((y - y0) / ch).astype(np.int64), nby - 1)
    b = j * nbx + i
    items = np.argsort(b, kind="stable").astype(np.int64)
    start = np.zeros(nbx * nby + 1, dtype=np.int64)
    np.cumsum(np.bincount(b, minlength=nbx * nby), out=start[1:])
    return start, items, np.array([x0, y0, cw, ch, nbx, nby], dtype=np.float64)
