"""Kernels of the point quadtree (seed 003): Morton codes, fan errors, greedy point insertion.

Leaf meshes start from a fan around the leaf's centre through its boundary lattice points
(corners and the edge midpoints its finer neighbours need) and grow by inserting the leaf's
data points one at a time, largest error first: the point's triangle is split in three (a point
on an edge gives a flat third triangle). The insertion order and the error after every step
are recorded, so render time can replay any prefix.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def morton_codes(ix: np.ndarray, iy: np.ndarray, depth: int) -> np.ndarray:
    """(n,) int64 Z-order codes of cells (ix, iy) of a 2^depth × 2^depth lattice."""
    n = ix.shape[0]
    out = np.zeros(n, dtype=np.int64)
    for k in range(n):
        code = 0
        for b in range(depth):
            code |= ((ix[k] >> b) & 1) << (2 * b)
            code |= ((iy[k] >> b) & 1) << (2 * b + 1)
        out[k] = code
    return out


@njit(cache=True, inline="always")
def _bary(ax, ay, bx, by, cx, cy, x, y):
    det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
    if det == 0.0:
        return -1.0, -1.0, -1.0
    l1 = ((by - cy) * (x - cx) + (cx - bx) * (y - cy)) / det
    l2 = ((cy - ay) * (x - cx) + (ax - cx) * (y - cy)) / det
    return l1, l2, 1.0 - l1 - l2


@njit(cache=True)
def fan_errors(
    px: np.ndarray,
    py: np.ndarray,
    pz: np.ndarray,
    start: np.ndarray,
    stop: np.ndarray,
    squares: np.ndarray,
    ring_z: np.ndarray,
) -> np.ndarray:
    """δ(node) = max |z − fan| over the node's points, for every fan the node can be drawn as.

    A drawn node is a fan around its centre through its corners and, on each side whose drawn
    neighbour is finer, the side's midpoint. Each point lies in the sector of one side, where
    only that side's choice matters, so the largest error over all 16 fans is the largest of
    the 4-triangle fan's and the 8-triangle fan's errors at each point.

    px, py, pz: (n,) points sorted so node k owns start[k]:stop[k]; squares: (m, 3) x0, y0,
    size; ring_z: (m, 9) heights of corners SW, SE, NE, NW, the centre, then the midpoints
    of sides S, E, N, W.
    """
    m = start.shape[0]
    out = np.zeros(m)
    for k in range(m):
        x0, y0, s = squares[k, 0], squares[k, 1], squares[k, 2]
        cxs = np.array([x0, x0 + s, x0 + s, x0])
        cys = np.array([y0, y0, y0 + s, y0 + s])
        mx, my = x0 + 0.5 * s, y0 + 0.5 * s
        cz = ring_z[k, 4]
        worst = 0.0
        for p in range(start[k], stop[k]):
            best = np.inf
            for e in range(4):
                f = (e + 1) % 4
                l1, l2, l3 = _bary(mx, my, cxs[e], cys[e], cxs[f], cys[f], px[p], py[p])
                if l1 >= -1e-9 and l2 >= -1e-9 and l3 >= -1e-9:
                    h = l1 * cz + l2 * ring_z[k, e] + l3 * ring_z[k, f]
                    best = abs(pz[p] - h)
                    # The same sector split at the side's midpoint.
                    hx, hy, hz = 0.5 * (cxs[e] + cxs[f]), 0.5 * (cys[e] + cys[f]), ring_z[k, 5 + e]
                    l1, l2, l3 = _bary(mx, my, cxs[e], cys[e], hx, hy, px[p], py[p])
                    if not (l1 >= -1e-9 and l2 >= -1e-9 and l3 >= -1e-9):
                        l1, l2, l3 = _bary(mx, my, hx, hy, cxs[f], cys[f], px[p], py[p])
                        h = l1 * cz + l2 * hz + l3 * ring_z[k, f]
                    else:
                        h = l1 * cz + l2 * ring_z[k, e] + l3 * hz
                    best = max(best, abs(pz[p] - h))
                    break
            worst = max(worst, best)
        out[k] = worst
    return out


@njit(cache=True)
def insert_points(
    base: np.ndarray, pts: np.ndarray, order_in: np.ndarray, steps: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy insertion (order_in[0] < 0) or replay of a recorded order into a leaf fan.

    base: (b, 3) centre first, then the boundary lattice points counter-clockwise; pts: (n, 3)
    the leaf's data points; steps: how many points to insert (<= n).
    Returns (order (steps,) point indices, errors (steps + 1,) max |z − mesh| over the points
    after 0..steps insertions, triangles (t, 3) indices into [base; pts]).
    """
    b = base.shape[0]
    n = pts.shape[0]
    vx = np.empty(b + n)
    vy = np.empty(b + n)
    vz = np.empty(b + n)
    vx[:b], vy[:b], vz[:b] = base[:, 0], base[:, 1], base[:, 2]
    vx[b:], vy[b:], vz[b:] = pts[:, 0], pts[:, 1], pts[:, 2]
    tris = np.empty((b - 1 + 2 * n, 3), dtype=np.int64)
    nt = 0
    for i in range(1, b):
        j = i + 1 if i + 1 < b else 1
        tris[nt, 0], tris[nt, 1], tris[nt, 2] = 0, i, j
        nt += 1
    owner = np.full(n, -1, dtype=np.int64)
    err = np.zeros(n)
    done = np.zeros(n, dtype=np.bool_)

    def locate(p, t0, t1):
        for t in range(t0, t1):
            a, c, d = tris[t, 0], tris[t, 1], tris[t, 2]
            l1, l2, l3 = _bary(vx[a], vy[a], vx[c], vy[c], vx[d], vy[d], vx[b + p], vy[b + p])
            if l1 >= -1e-9 and l2 >= -1e-9 and l3 >= -1e-9:
                owner[p] = t
                err[p] = abs(vz[b + p] - (l1 * vz[a] + l2 * vz[c] + l3 * vz[d]))
                return

    for p in range(n):
        owner[p] = -1
        err[p] = np.inf
        locate(p, 0, nt)
    order = np.empty(steps, dtype=np.int64)
    errors = np.empty(steps + 1)
    for k in range(steps + 1):
        worst, arg = 0.0, -1
        for p in range(n):
            if not done[p] and err[p] >= worst:
                worst, arg = err[p], p
        errors[k] = worst if arg >= 0 else 0.0
        if k == steps:
            break
        p = order_in[k] if order_in[0] >= 0 else arg
        order[k] = p
        done[p] = True
        err[p] = 0.0
        t = owner[p]
        a, c, d = tris[t, 0], tris[t, 1], tris[t, 2]
        v = b + p
        # Split t = (a, c, d) into (a, c, v), (c, d, v), (d, a, v).
        tris[t, 0], tris[t, 1], tris[t, 2] = a, c, v
        tris[nt, 0], tris[nt, 1], tris[nt, 2] = c, d, v
        tris[nt + 1, 0], tris[nt + 1, 1], tris[nt + 1, 2] = d, a, v
        for q in range(n):
            if not done[q] and owner[q] == t:
                owner[q] = -1
                err[q] = np.inf
                locate(q, t, t + 1)
                if owner[q] < 0:
                    locate(q, nt, nt + 2)
        nt += 2
    return order, errors, tris[:nt].copy()


@njit(cache=True)
def range_z_bounds(pz: np.ndarray, start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """(m, 2) min and max of pz[start[k]:stop[k]] per range k (+inf, −inf when empty)."""
    m = start.shape[0]
    out = np.empty((m, 2))
    for k in range(m):
        lo, hi = np.inf, -np.inf
        for p in range(start[k], stop[k]):
            lo = min(lo, pz[p])
            hi = max(hi, pz[p])
        out[k, 0], out[k, 1] = lo, hi
    return out


@njit(cache=True)
def first_within(
    errors: np.ndarray, start: np.ndarray, count: np.ndarray, budget: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per leaf i: the fewest insertions k whose recorded error is within budget[i].

    errors: recorded errors of all leaves, leaf i owning errors[start[i]:start[i] + count[i]]
    (error after 0..count[i] − 1 insertions). Returns (k (m,) int64, error after k (m,)); the
    last prefix when none is within.
    """
    m = start.shape[0]
    ks = np.empty(m, dtype=np.int64)
    es = np.empty(m)
    for i in range(m):
        k = count[i] - 1
        for j in range(count[i]):
            if errors[start[i] + j] <= budget[i]:
                k = j
                break
        ks[i] = k
        es[i] = errors[start[i] + k]
    return ks, es


@njit(cache=True)
def insertion_orders(
    bases: np.ndarray, base_start: np.ndarray, pts: np.ndarray, start: np.ndarray, stop: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy insertion orders of many leaves (``insert_points`` per leaf, one call in all).

    bases: (B, 3) the leaves' base rings one after the other, leaf k's at
    bases[base_start[k]:base_start[k + 1]]; pts: (n, 3) points, leaf k owning
    pts[start[k]:stop[k]]. Returns (orders (Σ n_k,) leaf-local point indices, errors
    (Σ (n_k + 1),)), leaf after leaf.
    """
    m = start.shape[0]
    total = 0
    for k in range(m):
        total += stop[k] - start[k]
    orders = np.empty(total, dtype=np.int64)
    errors = np.empty(total + m)
    o = 0
    e = 0
    none = np.full(1, -1, dtype=np.int64)
    for k in range(m):
        n = stop[k] - start[k]
        base = bases[base_start[k] : base_start[k + 1]]
        order, errs, _ = insert_points(base, pts[start[k] : stop[k]], none, n)
        orders[o : o + n] = order
        errors[e : e + n + 1] = errs
        o += n
        e += n + 1
    return orders, errors
