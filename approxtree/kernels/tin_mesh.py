"""Half-edge triangle arrays for incremental TIN insertion on a lattice (integer coordinates).

A triangle t owns the half-edges 3t, 3t+1, 3t+2; half-edge e runs from ``tv[e]`` to
``tv[next(e)]`` and ``he[e]`` is its twin in the neighbouring triangle (−1 on the border).
Vertices are integer lattice points (column x, row y), so orientation and in-circle tests are
exact in int64 for grids up to about 2^15 points a side. Every triangle has orient(a, b, c) > 0.
The mesh operations allocate nothing and are compiled without numba's reference-counting
runtime (``_nrt=False``): a call then costs no atomic reference-count updates on its arrays,
which would outweigh the operation itself.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.kernels._jit import njit_no_nrt


@njit(cache=True, inline="always")
def next_edge(e: int) -> int:
    return e - 2 if e % 3 == 2 else e + 1


@njit(cache=True, inline="always")
def prev_edge(e: int) -> int:
    return e + 2 if e % 3 == 0 else e - 1


@njit(cache=True, inline="always")
def orient(ax: int, ay: int, bx: int, by: int, px: int, py: int) -> int:
    """Twice the signed area of (a, b, p): > 0 when p lies left of a→b (inside for our tris)."""
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@njit(cache=True, inline="always")
def in_circle(ax, ay, bx, by, cx, cy, dx, dy) -> bool:
    """True when d lies strictly inside the circumcircle of (a, b, c), orient(a, b, c) > 0."""
    adx = ax - dx
    ady = ay - dy
    bdx = bx - dx
    bdy = by - dy
    cdx = cx - dx
    cdy = cy - dy
    ad = adx * adx + ady * ady
    bd = bdx * bdx + bdy * bdy
    cd = cdx * cdx + cdy * cdy
    det = adx * (bdy * cd - bd * cdy) - ady * (bdx * cd - bd * cdx) + ad * (bdx * cdy - bdy * cdx)
    return det > 0


# Loads and stores index as unsigned (np.uint64): numba then emits no negative-index
# wraparound (a compare and select per access on the hot paths). Written out, not a helper:
# an inlined helper is typed again at each of its call sites (cold compile time).


# Inlined: its callers pass int32 and int64 values (and literal -1) in many combinations, each
# of which would be a separate compile of a kernel a handful of instructions long.
@njit(cache=True, inline="always")
def set_triangle(tv, he, t, a, b, c, hab, hbc, hca) -> None:
    """Write triangle t = (a, b, c) and link its three half-edges with their twins."""
    e = 3 * t
    # Unsigned indices: numba then emits no negative-index wraparound per store.
    u = np.uint64(e)
    tv[u] = a
    tv[u + np.uint64(1)] = b
    tv[u + np.uint64(2)] = c
    he[u] = hab
    he[u + np.uint64(1)] = hbc
    he[u + np.uint64(2)] = hca
    if hab >= 0:
        he[np.uint64(hab)] = e
    if hbc >= 0:
        he[np.uint64(hbc)] = e + 1
    if hca >= 0:
        he[np.uint64(hca)] = e + 2


@njit_no_nrt()
def split_interior(tv, he, t, n1, n2, p) -> None:
    """Split triangle t = (a, b, c) at interior vertex p into (a,b,p), (b,c,p) = n1, (c,a,p) = n2.

    The edges opposite p (ab, bc, ca) are the half-edges 3t, 3n1, 3n2.
    """
    e = np.uint64(3 * t)
    e1 = e + np.uint64(1)
    e2 = e + np.uint64(2)
    a, b, c = tv[e], tv[e1], tv[e2]
    hab, hbc, hca = he[e], he[e1], he[e2]
    set_triangle(tv, he, t, a, b, p, hab, 3 * n1 + 2, 3 * n2 + 1)
    set_triangle(tv, he, n1, b, c, p, hbc, 3 * n2 + 2, 3 * t + 1)
    set_triangle(tv, he, n2, c, a, p, hca, 3 * t + 2, 3 * n1 + 1)


@njit_no_nrt()
def split_edge(tv, he, e, n1, n2, p) -> int:
    """Split half-edge e = a→b (and its twin b→a, if any) at vertex p lying on it.

    t = (a, b, c) becomes (a, p, c) and n1 = (p, b, c); the twin's triangle u = (b, a, d)
    becomes (b, p, d) and n2 = (p, a, d). Returns the number of new triangles (1 or 2); the
    edges opposite p are 3t+2, 3n1+1 and, with a twin, 3u+2, 3n2+1.
    """
    t = e // 3
    ea = e
    eb = next_edge(ea)
    ec = next_edge(eb)
    a, b, c = tv[np.uint64(ea)], tv[np.uint64(eb)], tv[np.uint64(ec)]
    hab, hbc, hca = he[np.uint64(ea)], he[np.uint64(eb)], he[np.uint64(ec)]
    if hab < 0:
        set_triangle(tv, he, t, a, p, c, -1, 3 * n1 + 2, hca)
        set_triangle(tv, he, n1, p, b, c, -1, hbc, 3 * t + 1)
        return 1
    f = hab
    u = f // 3
    fa = next_edge(f)
    fd = next_edge(fa)
    d = tv[np.uint64(fd)]
    had, hdb = he[np.uint64(fa)], he[np.uint64(fd)]
    set_triangle(tv, he, t, a, p, c, 3 * n2, 3 * n1 + 2, hca)
    set_triangle(tv, he, n1, p, b, c, 3 * u, hbc, 3 * t + 1)
    set_triangle(tv, he, u, b, p, d, 3 * n1, 3 * n2 + 2, hdb)
    set_triangle(tv, he, n2, p, a, d, 3 * t, had, 3 * u + 1)
    return 2


@njit_no_nrt()
def flip(tv, he, e) -> None:
    """Swap the diagonal of the quadrilateral around half-edge e (p is opposite e in t).

    ::

              p                       p
             / \\                     /|\\
            /   \\                   / | \\
           /  t  \\                 /  |  \\
          a-------b      ─▶       a t'|u' b
           \\  u  /                 \\  |  /
            \\   /                   \\ | /
             \\ /                     \\|/
              q                       q

    t = (a, b, p), u = (b, a, q) become t = (a, q, p) and u = (q, b, p). The edges now
    opposite p, a→q (3t) and q→b (3u), are the ones to test next.
    """
    t = e // 3
    f = he[np.uint64(e)]
    u = f // 3
    eb = next_edge(e)
    ep = next_edge(eb)
    fa = next_edge(f)
    fq = next_edge(fa)
    a, b, p = tv[np.uint64(e)], tv[np.uint64(eb)], tv[np.uint64(ep)]
    q = tv[np.uint64(fq)]
    hbp, hpa = he[np.uint64(eb)], he[np.uint64(ep)]
    haq, hqb = he[np.uint64(fa)], he[np.uint64(fq)]
    set_triangle(tv, he, t, a, q, p, haq, 3 * u + 2, hpa)
    set_triangle(tv, he, u, q, b, p, hqb, hbp, 3 * t + 1)


@njit(cache=True)
def grow(a: np.ndarray, size: int, fill) -> np.ndarray:
    """A copy of ``a`` with room for ``size`` items, new slots set to ``fill``."""
    out = np.empty(size, dtype=a.dtype)
    # Loops, not out[:n] = a: slice assignment compiles numba's shape-error formatting. Each
    # slot is written once (np.full would write the copied ones twice).
    n = min(a.shape[0], size)
    for k in range(n):
        out[k] = a[k]
    for k in range(n, size):
        out[k] = fill
    return out


@njit(cache=True)
def half_edge_twins(tv: np.ndarray, n_vertices: int) -> np.ndarray:
    """(3m,) int32 twin of each half-edge of the triangles tv (3m,), −1 on the border.

    Half-edge 3t + k runs from tv[3t + k] to tv[3t + (k + 1) % 3]. Half-edges are bucketed by
    their lower vertex (counting sort, O(m)); a twin is the bucket mate with the same other end.
    """
    ne = tv.shape[0]
    out = np.full(ne, -1, dtype=np.int32)
    start = np.zeros(n_vertices + 1, dtype=np.int64)
    for e in range(ne):
        start[min(tv[e], tv[next_edge(e)]) + 1] += 1
    for v in range(n_vertices):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    bucket = np.empty(ne, dtype=np.int32)
    for e in range(ne):
        lo = min(tv[e], tv[next_edge(e)])
        bucket[fill[lo]] = e
        fill[lo] += 1
    # Buckets hold a vertex's few edges: pair them by their other end.
    for v in range(n_vertices):
        for i in range(start[v], start[v + 1]):
            e = bucket[i]
            if out[e] >= 0:
                continue
            hi = max(tv[e], tv[next_edge(e)])
            for j in range(i + 1, start[v + 1]):
                f = bucket[j]
                if max(tv[f], tv[next_edge(f)]) == hi:
                    out[e] = f
                    out[f] = e
                    break
    return out


@njit(cache=True)
def grid_vertices(
    ij: np.ndarray, x_coords: np.ndarray, y_coords: np.ndarray, heights: np.ndarray
) -> np.ndarray:
    """(n, 3) float64 world (x, y, z) of the grid points ij (n, 2) int32 (row, column).

    One pass writing each row whole: no index widening, no per-column gathers.
    """
    n = ij.shape[0]
    out = np.empty((n, 3), dtype=np.float64)
    for k in range(n):
        r = ij[k, 0]
        c = ij[k, 1]
        out[k, 0] = x_coords[c]
        out[k, 1] = y_coords[r]
        out[k, 2] = heights[r, c]
    return out


@njit(cache=True)
def wide_triangles(tris: np.ndarray, flip: bool) -> np.ndarray:
    """(m, 3) int64 copy of tris (m, 3) int32, corners 1 and 2 swapped with flip."""
    m = tris.shape[0]
    out = np.empty((m, 3), dtype=np.int64)
    b, c = (2, 1) if flip else (1, 2)
    for t in range(m):
        out[t, 0] = tris[t, 0]
        out[t, 1] = tris[t, b]
        out[t, 2] = tris[t, c]
    return out
