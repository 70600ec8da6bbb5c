"""Greedy RTIN refinement under a budget: split the leaf of largest true error first.

The RTIN hierarchy of ``kernels.rtin`` on the (s + 1)² lattice: a conforming mesh is fully
described by which hypotenuse midpoints are split (``split[y, x]``); the triangles sharing a
hypotenuse (a diamond) split together, and a triangle may split only once its parent has, its
parent's midpoint being the triangle's own apex. A leaf's key is its true max error (the
``rtin._tri_error`` rules: inf while it must split because of padding or nodata). Each step pops
the worst leaf and plans its split with every forced split it needs (parents first, down the
diamonds); the plan is applied only when the drawn-triangle and vertex counts stay within the
budgets, otherwise refinement stops. ``extract(split, 0.5, ...)`` then emits the mesh.

Every leaf is pushed once when it appears; a popped entry whose midpoint is already split is
stale and skipped, so the heap needs no removals.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.kernels.rtin import _tri_error
from approxtree.kernels.tri_heap import heap_push, heap_remove


@njit(cache=True, inline="always")
def _lowbit(v: int, s: int) -> int:
    """Largest power of two dividing v (2s for v = 0)."""
    if v == 0:
        return 2 * s
    return v & -v


@njit(cache=True)
def _diamond_apexes(mx: int, my: int, s: int):
    """(count, ax0, ay0, ax1, ay1): apexes of the 1 or 2 triangles (a diamond) whose hypotenuse
    midpoint is (mx, my); lattice side s."""
    bx = _lowbit(mx, s)
    by = _lowbit(my, s)
    if bx == by:
        # Centre of an L-square (L = 2h): its diagonal's two triangles.
        h = bx
        i = (mx - h) // (2 * h)
        j = (my - h) // (2 * h)
        if (i + j) % 2 == 0:
            return 2, mx + h, my - h, mx - h, my + h
        return 2, mx - h, my - h, mx + h, my + h
    # Midpoint of an L-square side: apexes at the centres of the squares on either side.
    h = min(bx, by)
    if bx == h:
        # Horizontal side: squares above and below.
        c = 0
        ax0, ay0, ax1, ay1 = -1, -1, -1, -1
        if my + h <= s:
            ax0, ay0 = mx, my + h
            c = 1
        if my - h >= 0:
            if c == 0:
                ax0, ay0 = mx, my - h
            else:
                ax1, ay1 = mx, my - h
            c += 1
        return c, ax0, ay0, ax1, ay1
    c = 0
    ax0, ay0, ax1, ay1 = -1, -1, -1, -1
    if mx + h <= s:
        ax0, ay0 = mx + h, my
        c = 1
    if mx - h >= 0:
        if c == 0:
            ax0, ay0 = mx - h, my
        else:
            ax1, ay1 = mx - h, my
        c += 1
    return c, ax0, ay0, ax1, ay1


@njit(cache=True, inline="always")
def _drawn(heights, r0, c0, rows, cols, ax, ay, bx, by, cx, cy, has_nan) -> int:
    """1 when the triangle lies in the window with valid corners (``extract`` draws it)."""
    if max(ax, max(bx, cx)) > cols - 1 or max(ay, max(by, cy)) > rows - 1:
        return 0
    if has_nan and (
        np.isnan(heights[r0 + ay, c0 + ax])
        or np.isnan(heights[r0 + by, c0 + bx])
        or np.isnan(heights[r0 + cy, c0 + cx])
    ):
        return 0
    return 1


@njit(cache=True)
def greedy_rtin(
    heights: np.ndarray,
    r0: int,
    c0: int,
    rows: int,
    cols: int,
    size: int,
    max_error: float,
    max_points: int,
    max_triangles: int,
    has_nan: bool,
) -> np.ndarray:
    """split (size+1, size+1) uint8: the midpoints split by greedy refinement.

    Stops when the worst leaf's error is <= max_error (< 0: no error goal) or before a split
    (with its forced splits) would make more than max_triangles drawn triangles or max_points
    vertices (<= 0: no such budget). Feed the result to ``rtin.extract`` with threshold 0.5.
    """
    s = size
    split = np.zeros((s + 1, s + 1), dtype=np.uint8)
    planned = np.zeros((s + 1, s + 1), dtype=np.uint8)
    cap = 1024
    tri = np.empty((cap, 6), dtype=np.int64)
    heap = np.empty(cap, dtype=np.int32)
    hkey = np.empty(cap, dtype=np.float64)
    hpos = np.full(cap, -1, dtype=np.int32)
    n_tri = 0
    hsize = 0
    plan = np.empty(256, dtype=np.int64)
    stack = np.empty(256, dtype=np.int64)
    done = max(max_error, 0.0) if max_error >= 0 else -1.0

    # Roots (apex, l, r) on the main diagonal, and the counts of the initial mesh.
    roots = ((s, 0, 0, 0, s, s), (0, s, s, s, 0, 0))
    nt = 0
    for k in range(2):
        ax, ay, lx, ly, rx, ry = roots[k]
        for q in range(6):
            tri[n_tri, q] = roots[k][q]
        e = _tri_error(heights, r0, c0, rows, cols, ax, ay, lx, ly, rx, ry, has_nan, np.inf)
        hsize = heap_push(heap, hkey, hpos, hsize, n_tri, e)
        n_tri += 1
        nt += _drawn(heights, r0, c0, rows, cols, ax, ay, lx, ly, rx, ry, has_nan)
    nv = 0
    for cx, cy in ((0, 0), (s, 0), (0, s), (s, s)):
        if cx <= cols - 1 and cy <= rows - 1 and not np.isnan(heights[r0 + cy, c0 + cx]):
            nv += 1

    while hsize > 0:
        t = heap[0]
        worst = hkey[0]
        ax, ay, lx, ly, rx, ry = tri[t, 0], tri[t, 1], tri[t, 2], tri[t, 3], tri[t, 4], tri[t, 5]
        mx = (lx + rx) // 2
        my = (ly + ry) // 2
        if split[my, mx]:
            hsize = heap_remove(heap, hkey, hpos, hsize, t)
            continue
        if worst <= done or (lx + rx) % 2 or (ly + ry) % 2:
            # Good enough, or a unit triangle (nothing left to split): the worst leaf decides.
            if worst <= done:
                break
            hsize = heap_remove(heap, hkey, hpos, hsize, t)
            continue

        # Plan: depth-first over the midpoints this split needs, parents first.
        n_plan = 0
        sp = 0
        stack[0] = my * (s + 1) + mx
        sp = 1
        while sp > 0:
            m = stack[sp - 1]
            qx = m % (s + 1)
            qy = m // (s + 1)
            if split[qy, qx] or planned[qy, qx] == 2:
                sp -= 1
                continue
            c, a0x, a0y, a1x, a1y = _diamond_apexes(qx, qy, s)
            if planned[qy, qx] == 0 and not (qx == s // 2 and qy == s // 2):
                # First visit (not a root diamond): the apexes, its parents' midpoints, first.
                planned[qy, qx] = 1
                if sp + 2 > stack.shape[0]:
                    bigger = np.empty(2 * stack.shape[0], dtype=np.int64)
                    bigger[:sp] = stack[:sp]
                    stack = bigger
                stack[sp] = a0y * (s + 1) + a0x
                sp += 1
                if c == 2:
                    stack[sp] = a1y * (s + 1) + a1x
                    sp += 1
                continue
            planned[qy, qx] = 2
            sp -= 1
            if n_plan >= plan.shape[0]:
                bigger = np.empty(2 * plan.shape[0], dtype=np.int64)
                bigger[:n_plan] = plan
                plan = bigger
            plan[n_plan] = m
            n_plan += 1

        # Count what the plan adds: a vertex per midpoint, children minus parents per diamond.
        d_nv = 0
        d_nt = 0
        for i in range(n_plan):
            qx = plan[i] % (s + 1)
            qy = plan[i] // (s + 1)
            planned[qy, qx] = 0
            if qx <= cols - 1 and qy <= rows - 1 and not np.isnan(heights[r0 + qy, c0 + qx]):
                d_nv += 1
            c, a0x, a0y, a1x, a1y = _diamond_apexes(qx, qy, s)
            for k in range(c):
                pax = a0x if k == 0 else a1x
                pay = a0y if k == 0 else a1y
                ux = pax - qx
                uy = pay - qy
                p1x, p1y = qx - uy, qy + ux
                p2x, p2y = qx + uy, qy - ux
                d_nt -= _drawn(heights, r0, c0, rows, cols, pax, pay, p1x, p1y, p2x, p2y, has_nan)
                d_nt += _drawn(heights, r0, c0, rows, cols, qx, qy, p1x, p1y, pax, pay, has_nan)
                d_nt += _drawn(heights, r0, c0, rows, cols, qx, qy, pax, pay, p2x, p2y, has_nan)
        if (0 < max_triangles < nt + d_nt) or (0 < max_points < nv + d_nv):
            break

        # Apply: split each midpoint and push the new leaves with their true errors.
        nt += d_nt
        nv += d_nv
        hsize = heap_remove(heap, hkey, hpos, hsize, t)
        for i in range(n_plan):
            qx = plan[i] % (s + 1)
            qy = plan[i] // (s + 1)
            split[qy, qx] = 1
            c, a0x, a0y, a1x, a1y = _diamond_apexes(qx, qy, s)
            for k in range(c):
                pax = a0x if k == 0 else a1x
                pay = a0y if k == 0 else a1y
                ux = pax - qx
                uy = pay - qy
                p1x, p1y = qx - uy, qy + ux
                p2x, p2y = qx + uy, qy - ux
                if n_tri + 2 > cap:
                    cap *= 2
                    tri2 = np.empty((cap, 6), dtype=np.int64)
                    tri2[:n_tri] = tri[:n_tri]
                    tri = tri2
                    heap2 = np.empty(cap, dtype=np.int32)
                    heap2[:hsize] = heap[:hsize]
                    heap = heap2
                    hkey2 = np.empty(cap, dtype=np.float64)
                    hkey2[:hsize] = hkey[:hsize]
                    hkey = hkey2
                    hpos2 = np.full(cap, -1, dtype=np.int32)
                    hpos2[:n_tri] = hpos[:n_tri]
                    hpos = hpos2
                for child in range(2):
                    if child == 0:
                        bx, by, cx, cy = p1x, p1y, pax, pay
                    else:
                        bx, by, cx, cy = pax, pay, p2x, p2y
                    tri[n_tri, 0] = qx
                    tri[n_tri, 1] = qy
                    tri[n_tri, 2] = bx
                    tri[n_tri, 3] = by
                    tri[n_tri, 4] = cx
                    tri[n_tri, 5] = cy
                    e = _tri_error(
                        heights, r0, c0, rows, cols, qx, qy, bx, by, cx, cy, has_nan, np.inf
                    )
                    hsize = heap_push(heap, hkey, hpos, hsize, n_tri, e)
                    n_tri += 1
    return split
