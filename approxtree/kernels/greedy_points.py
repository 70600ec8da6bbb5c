"""Greedy insertion TIN over scattered points (Garland & Heckbert, Algorithm III, point form).

The mesh starts as the convex hull of the points (a fan, made Delaunay by flips). Every
triangle owns the *bucket* of input points it covers (a linked list through ``nxt``); its
candidate is the bucket point of largest error |z − h_mesh|, and a max-heap of triangles keyed
by that error (``tri_heap``, shared with the grid kernel) gives the next point to insert. An
insertion splits its triangle (or the edge it lies on), Delaunay is restored by edge flips
(``tin_mesh``, shared with the grid kernel), and only the buckets of the changed triangles are
redistributed and rescanned: O((m + n) log m) expected.

Robustness: point-in-triangle, hull and convexity decisions use ``orient2d`` with the exact
sign, so every triangle stays strictly counter-clockwise and every input point is always in
exactly one bucket or a vertex: the error is the true maximum over all points. In-circle
tests flip only when certain (near-cocircular quads keep their edge).

Duplicate positions: the first point of a position that insertion picks becomes the vertex;
the other points of that position are never inserted and keep their true error
|z − z_vertex| (counted in the maximum; they bound how low the error can go).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.kernels.predicates import in_circle_sure, orient2d, orient2d_exact
from approxtree.kernels.tin_mesh import (
    flip,
    grow,
    next_edge,
    prev_edge,
    split_edge,
    split_interior,
)
from approxtree.kernels.tri_heap import heap_remove, heap_update


@njit(cache=True, inline="always")
def _plane(x, y, z, a, b, c):
    """(x_a, y_a, z_a, ∂z/∂x, ∂z/∂y) of the plane through the triangle (a, b, c)."""
    ax, ay, za = x[a], y[a], z[a]
    bx, by = x[b] - ax, y[b] - ay
    cx, cy = x[c] - ax, y[c] - ay
    d = orient2d(ax, ay, x[b], y[b], x[c], y[c])
    dzb = z[b] - za
    dzc = z[c] - za
    gx = (dzb * cy - dzc * by) / d
    gy = (dzc * bx - dzb * cx) / d
    return ax, ay, za, gx, gy


@njit(cache=True)
def _scan(t, tv, x, y, z, head, nxt):
    """(max error, its point or −1, sum of squared errors) over the bucket of triangle t."""
    a, b, c = tv[3 * t], tv[3 * t + 1], tv[3 * t + 2]
    ax, ay, za, gx, gy = _plane(x, y, z, a, b, c)
    bx, by = x[b] - ax, y[b] - ay
    cx, cy = x[c] - ax, y[c] - ay
    # A sliver's gradient is ill-conditioned: interpolate it by barycentric weights from
    # exactly evaluated areas instead (accurate to a few ulps of the height differences).
    d = bx * cy - by * cx
    sliver = abs(d) < 1e-3 * (abs(bx * cy) + abs(by * cx))
    if sliver:
        d = orient2d_exact(ax, ay, x[b], y[b], x[c], y[c])
    dzb = z[b] - za
    dzc = z[c] - za
    best = -1.0
    arg = -1
    s = 0.0
    i = head[t]
    while i >= 0:
        if sliver:
            wb = orient2d_exact(ax, ay, x[i], y[i], x[c], y[c]) / d
            wc = orient2d_exact(ax, ay, x[b], y[b], x[i], y[i]) / d
            h = za + wb * dzb + wc * dzc
        else:
            h = za + gx * (x[i] - ax) + gy * (y[i] - ay)
        e = abs(z[i] - h)
        s += e * e
        if e > best:
            best = e
            arg = i
        i = nxt[i]
    return best, arg, s


@njit(cache=True, inline="always")
def _push(t, i, head, nxt) -> None:
    nxt[i] = head[t]
    head[t] = i


@njit(cache=True, inline="always")
def _mark(t, pending, n_pending, is_pending) -> int:
    """Queue triangle t for rescanning (once); returns the new queue length."""
    if not is_pending[t]:
        is_pending[t] = True
        pending[n_pending] = t
        n_pending += 1
    return n_pending


@njit(cache=True)
def _take(t, head, nxt, buf, nb, skip):
    """Move the bucket of t (except point ``skip``) to buf[nb:]; returns the new nb."""
    i = head[t]
    head[t] = -1
    while i >= 0:
        if i != skip:
            buf[nb] = i
            nb += 1
        i = nxt[i]
    return nb


@njit(cache=True)
def _hull(x, y):
    """Strictly convex hull, counter-clockwise (Andrew's monotone chain, exact orientation).

    Returns (h,) int64 point indices; fewer than 3 when all points lie on one line.
    """
    n = x.shape[0]
    order = np.argsort(x, kind="mergesort")
    # Ties in x are ordered by y, so the order is lexicographic.
    i = 0
    while i < n:
        j = i + 1
        while j < n and x[order[j]] == x[order[i]]:
            j += 1
        if j - i > 1:
            run = order[i:j].copy()
            order[i:j] = run[np.argsort(y[run], kind="mergesort")]
        i = j
    hull = np.empty(2 * n + 1, dtype=np.int64)
    k = 0
    for i in range(n):
        p = order[i]
        while k >= 2 and (
            orient2d(x[hull[k - 2]], y[hull[k - 2]], x[hull[k - 1]], y[hull[k - 1]], x[p], y[p])
            <= 0.0
        ):
            k -= 1
        hull[k] = p
        k += 1
    lower = k + 1
    for i in range(n - 2, -1, -1):
        p = order[i]
        while k >= lower and (
            orient2d(x[hull[k - 2]], y[hull[k - 2]], x[hull[k - 1]], y[hull[k - 1]], x[p], y[p])
            <= 0.0
        ):
            k -= 1
        hull[k] = p
        k += 1
    # The chain ends where it started.
    k = max(k - 1, 1)
    return hull[:k].copy()


@njit(cache=True)
def _legalize(tv, he, x, y, head, nxt, buf, stack, sp, pending, n_pending, is_pending, outer):
    """Flip suspect edges on the stack until none is illegal, moving bucket points along.

    outer: also push the two edges at the apex (a general Lawson pass, not after an
    insertion). Returns (stack, sp, n_pending).
    """
    while sp > 0:
        sp -= 1
        e = stack[sp]
        f = he[e]
        if f < 0:
            continue
        a = tv[e]
        b = tv[next_edge(e)]
        p = tv[prev_edge(e)]
        q = tv[prev_edge(f)]
        if not in_circle_sure(x[a], y[a], x[b], y[b], x[p], y[p], x[q], y[q]):
            continue
        # Only a strictly convex quadrilateral can take the other diagonal.
        if orient2d(x[a], y[a], x[q], y[q], x[p], y[p]) <= 0.0:
            continue
        if orient2d(x[q], y[q], x[b], y[b], x[p], y[p]) <= 0.0:
            continue
        t = int(e // 3)
        u = int(f // 3)
        nb = _take(t, head, nxt, buf, 0, -1)
        nb = _take(u, head, nxt, buf, nb, -1)
        flip(tv, he, e)
        # Now t = (a, q, p) and u = (q, b, p): the diagonal q→p separates them.
        for k in range(nb):
            i = buf[k]
            if orient2d(x[q], y[q], x[p], y[p], x[i], y[i]) >= 0.0:
                _push(t, i, head, nxt)
            else:
                _push(u, i, head, nxt)
        n_pending = _mark(t, pending, n_pending, is_pending)
        n_pending = _mark(u, pending, n_pending, is_pending)
        if sp + 4 > stack.shape[0]:
            stack = grow(stack, 2 * stack.shape[0], 0)
        stack[sp] = 3 * t
        stack[sp + 1] = 3 * u
        sp += 2
        if outer:
            stack[sp] = 3 * u + 1
            stack[sp + 1] = 3 * t + 2
            sp += 2
    return stack, sp, n_pending


@njit(cache=True)
def _morton_order(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(n,) int64 permutation visiting the points along a Z-order curve (16 bits an axis)."""
    n = x.shape[0]
    x0, y0 = x.min(), y.min()
    w = max(x.max() - x0, y.max() - y0, 1e-300)
    s = 65535.0 / w
    code = np.empty(n, dtype=np.int64)
    for i in range(n):
        cx = np.int64((x[i] - x0) * s)
        cy = np.int64((y[i] - y0) * s)
        c = np.int64(0)
        for b in range(16):
            c |= ((cx >> b) & 1) << (2 * b)
            c |= ((cy >> b) & 1) << (2 * b + 1)
        code[i] = c
    return np.argsort(code)


@njit(cache=True)
def greedy_point_tin(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, max_error: float, max_points: int
):
    """Greedy insertion over scattered points x, y, z (n,) float64; see ``_greedy``.

    The points are first put in Z-order so that a triangle's bucket lies close in memory.
    """
    n = x.shape[0]
    if n < 64:
        return _greedy(x, y, z, max_error, max_points)
    order = _morton_order(x, y)
    verts, tv, worst, sse = _greedy(x[order], y[order], z[order], max_error, max_points)
    return order[verts], tv, worst, sse


@njit(cache=True)
def _greedy(x: np.ndarray, y: np.ndarray, z: np.ndarray, max_error: float, max_points: int):
    """Greedy insertion over scattered points x, y, z (n,) float64 (any order, duplicates ok).

    max_error < 0 inserts every point (up to ``max_points``, if > 0): with distinct positions
    that is the full Delaunay triangulation; max_error >= 0 stops once every point is within
    it. The mesh starts from the convex hull; a hull of more than ``max_points`` vertices is
    thinned to ``max_points`` and the points left outside make the error infinite.
    Returns (verts (k,) int64 point indices in insertion order, tv (3m,) int32 triangles as
    indices into verts, counter-clockwise, max error and sum of squared errors over all n
    points). When the points are all on one line there are no triangles: every point is a
    vertex and the error is 0.
    """
    n = x.shape[0]
    if n == 0:
        return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int32), 0.0, 0.0
    hull = _hull(x, y)
    nh = hull.shape[0]
    if nh < 3:
        return np.arange(n, dtype=np.int64), np.empty(0, dtype=np.int32), 0.0, 0.0
    reduced = 0 < max_points < nh
    if reduced:
        # A hull larger than the budget: keep evenly spread hull vertices (still strictly
        # convex); the points left outside are not represented (infinite error).
        keep = max(max_points, 3)
        hull = hull[(np.arange(keep) * nh) // keep]
        nh = keep
    uncovered = 0

    cap_t = 2 * n
    tv = np.empty(3 * cap_t, dtype=np.int32)
    he = np.full(3 * cap_t, -1, dtype=np.int32)
    head = np.full(cap_t, -1, dtype=np.int64)
    nxt = np.full(n, -1, dtype=np.int64)
    key = np.full(cap_t, -1.0)
    cand = np.full(cap_t, -1, dtype=np.int64)
    tsse = np.zeros(cap_t)
    hpos = np.full(cap_t, -1, dtype=np.int32)
    heap = np.empty(cap_t, dtype=np.int32)
    hkey = np.empty(cap_t, dtype=np.float64)
    pending = np.empty(cap_t, dtype=np.int32)
    is_pending = np.zeros(cap_t, dtype=np.bool_)
    stack = np.empty(64, dtype=np.int64)
    buf = np.empty(n, dtype=np.int64)
    is_vertex = np.zeros(n, dtype=np.bool_)
    verts = np.empty(n, dtype=np.int64)
    # Points that coincide with a vertex (duplicate positions) and that vertex.
    dup_pt = np.empty(n, dtype=np.int64)
    dup_v = np.empty(n, dtype=np.int64)
    n_dup = 0

    # The hull as a fan from hull[0]: triangle k = (h0, h[k+1], h[k+2]).
    for k in range(nh):
        verts[k] = hull[k]
        is_vertex[hull[k]] = True
    nv = nh
    h0 = hull[0]
    nt = nh - 2
    for k in range(nt):
        tv[3 * k] = h0
        tv[3 * k + 1] = hull[k + 1]
        tv[3 * k + 2] = hull[k + 2]
        if k + 1 < nt:
            he[3 * k + 2] = 3 * (k + 1)
            he[3 * (k + 1)] = 3 * k + 2
    # Every other point into its fan triangle: the last spoke h0→h[j] it is not right of.
    for i in range(n):
        if is_vertex[i]:
            continue
        lo = 1
        hi = nh - 1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if orient2d(x[h0], y[h0], x[hull[mid]], y[hull[mid]], x[i], y[i]) >= 0.0:
                lo = mid
            else:
                hi = mid - 1
        k = min(lo - 1, nt - 1)
        # Outside a reduced hull: beyond the first or last spoke, or past the hull edge.
        if reduced and (
            orient2d(x[h0], y[h0], x[hull[1]], y[hull[1]], x[i], y[i]) < 0.0
            or orient2d(x[h0], y[h0], x[hull[nh - 1]], y[hull[nh - 1]], x[i], y[i]) > 0.0
            or orient2d(x[hull[k + 1]], y[hull[k + 1]], x[hull[k + 2]], y[hull[k + 2]], x[i], y[i])
            < 0.0
        ):
            uncovered += 1
            continue
        _push(k, i, head, nxt)

    # Make the fan Delaunay (a general Lawson pass), then scan every triangle.
    n_pending = 0
    sp = 0
    for k in range(nt - 1):
        if sp + 1 > stack.shape[0]:
            stack = grow(stack, 2 * stack.shape[0], 0)
        stack[sp] = 3 * k + 2
        sp += 1
    stack, sp, n_pending = _legalize(
        tv, he, x, y, head, nxt, buf, stack, sp, pending, n_pending, is_pending, True
    )
    n_pending = 0
    for t in range(nt):
        is_pending[t] = True
        pending[n_pending] = t
        n_pending += 1

    # A negative goal inserts every point, exactly represented or not (full triangulation).
    done = -1.0 if max_error < 0 else max_error
    size = 0
    while True:
        # Rescan the changed triangles and put them back in the heap.
        for k in range(n_pending):
            t = pending[k]
            is_pending[t] = False
            kk, arg, s = _scan(t, tv, x, y, z, head, nxt)
            key[t] = kk
            cand[t] = arg
            tsse[t] = s
            if kk > done:
                size = heap_update(heap, hkey, hpos, size, t, kk)
            else:
                size = heap_remove(heap, hkey, hpos, size, t)
        n_pending = 0

        # Stopping rules: the worst candidate is good enough, or the budget is spent.
        if size == 0:
            break
        if 0 < max_points <= nv:
            break
        t = int(heap[0])
        p = int(cand[t])
        a, b, c = int(tv[3 * t]), int(tv[3 * t + 1]), int(tv[3 * t + 2])

        # A point at a vertex's position cannot be inserted: it keeps its error.
        same = -1
        if x[a] == x[p] and y[a] == y[p]:
            same = a
        elif x[b] == x[p] and y[b] == y[p]:
            same = b
        elif x[c] == x[p] and y[c] == y[p]:
            same = c
        if same >= 0:
            nb = _take(t, head, nxt, buf, 0, p)
            for k in range(nb):
                _push(t, buf[k], head, nxt)
            dup_pt[n_dup] = p
            dup_v[n_dup] = same
            n_dup += 1
            n_pending = _mark(t, pending, 0, is_pending)
            continue

        # Insert p: inside t (three triangles) or on one of its edges (four, or two on the hull).
        is_vertex[p] = True
        verts[nv] = p
        nv += 1
        on_edge = -1
        for k3 in range(3):
            e = 3 * t + k3
            if (
                orient2d(x[tv[e]], y[tv[e]], x[tv[next_edge(e)]], y[tv[next_edge(e)]], x[p], y[p])
                == 0.0
            ):
                on_edge = e
        n1 = nt
        n2 = nt + 1
        if sp + 4 > stack.shape[0]:
            stack = grow(stack, 2 * stack.shape[0], 0)
        if on_edge < 0:
            nb = _take(t, head, nxt, buf, 0, p)
            split_interior(tv, he, t, n1, n2, p)
            nt += 2
            # t = (a, b, p), n1 = (b, c, p), n2 = (c, a, p): decide by the spokes a–p, b–p, c–p.
            for k in range(nb):
                i = buf[k]
                sa = orient2d(x[a], y[a], x[p], y[p], x[i], y[i])
                sb = orient2d(x[b], y[b], x[p], y[p], x[i], y[i])
                if sb >= 0.0 and sa <= 0.0:
                    _push(t, i, head, nxt)
                elif sb <= 0.0 and orient2d(x[c], y[c], x[p], y[p], x[i], y[i]) >= 0.0:
                    _push(n1, i, head, nxt)
                else:
                    _push(n2, i, head, nxt)
            n_pending = _mark(t, pending, n_pending, is_pending)
            n_pending = _mark(n1, pending, n_pending, is_pending)
            n_pending = _mark(n2, pending, n_pending, is_pending)
            stack[sp] = 3 * t
            stack[sp + 1] = 3 * n1
            stack[sp + 2] = 3 * n2
            sp += 3
        else:
            f = int(he[on_edge])
            u = f // 3 if f >= 0 else -1
            c = int(tv[prev_edge(on_edge)])
            d = int(tv[prev_edge(f)]) if f >= 0 else -1
            nb = _take(t, head, nxt, buf, 0, p)
            nbt = nb
            if u >= 0:
                nb = _take(u, head, nxt, buf, nb, p)
            added = split_edge(tv, he, on_edge, n1, n2, p)
            nt += added
            # t = (a, p, c) | n1 = (p, b, c) across p–c; u = (b, p, d) | n2 = (p, a, d) across p–d.
            for k in range(nbt):
                i = buf[k]
                if orient2d(x[p], y[p], x[c], y[c], x[i], y[i]) >= 0.0:
                    _push(t, i, head, nxt)
                else:
                    _push(n1, i, head, nxt)
            for k in range(nbt, nb):
                i = buf[k]
                if orient2d(x[p], y[p], x[d], y[d], x[i], y[i]) >= 0.0:
                    _push(u, i, head, nxt)
                else:
                    _push(n2, i, head, nxt)
            n_pending = _mark(t, pending, n_pending, is_pending)
            n_pending = _mark(n1, pending, n_pending, is_pending)
            stack[sp] = 3 * t + 2
            stack[sp + 1] = 3 * n1 + 1
            sp += 2
            if added == 2:
                n_pending = _mark(u, pending, n_pending, is_pending)
                n_pending = _mark(n2, pending, n_pending, is_pending)
                stack[sp] = 3 * u + 2
                stack[sp + 1] = 3 * n2 + 1
                sp += 2
        stack, sp, n_pending = _legalize(
            tv, he, x, y, head, nxt, buf, stack, sp, pending, n_pending, is_pending, False
        )

    # The exact error over all points: bucket points by their triangle's plane, duplicates
    # against their vertex, vertices exact.
    worst = 0.0
    sse = 0.0
    for t in range(nt):
        if head[t] >= 0:
            kk = key[t]
            if kk > worst:
                worst = kk
            sse += tsse[t]
    for k in range(n_dup):
        e = abs(z[dup_pt[k]] - z[dup_v[k]])
        if e > worst:
            worst = e
        sse += e * e
    if uncovered > 0:
        worst = np.inf
        sse = np.inf
    # Triangles as indices into verts (insertion order).
    slot = np.empty(n, dtype=np.int32)
    for k in range(nv):
        slot[verts[k]] = k
    out = np.empty(3 * nt, dtype=np.int32)
    for e in range(3 * nt):
        out[e] = slot[tv[e]]
    return verts[:nv].copy(), out, worst, sse


@njit(cache=True)
def greedy_point_tins(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    index: np.ndarray,
    starts: np.ndarray,
    max_error: float,
    max_points: int,
):
    """``greedy_point_tin`` for many point subsets at once (one per tree node).

    x, y, z: (n,) float64 all data points; subset r is index[starts[r]:starts[r+1]].
    Returns (verts (Σk,) int64 indices into x, vstart (r+1,) int64, tv (Σ3m,) int32 into each
    subset's own verts, tstart (r+1,) int64, errors (r,), sse (r,)).
    """
    r = starts.shape[0] - 1
    errors = np.zeros(r)
    sses = np.zeros(r)
    vstart = np.zeros(r + 1, dtype=np.int64)
    tstart = np.zeros(r + 1, dtype=np.int64)
    vout = np.empty(1024, dtype=np.int64)
    tout = np.empty(3072, dtype=np.int32)
    nvo = 0
    nto = 0
    for k in range(r):
        idx = index[starts[k] : starts[k + 1]]
        verts, tv, err, s = greedy_point_tin(x[idx], y[idx], z[idx], max_error, max_points)
        if nvo + verts.shape[0] > vout.shape[0]:
            vout = grow(vout, 2 * (nvo + verts.shape[0]), 0)
        if nto + tv.shape[0] > tout.shape[0]:
            tout = grow(tout, 2 * (nto + tv.shape[0]), 0)
        for i in range(verts.shape[0]):
            vout[nvo + i] = idx[verts[i]]
        tout[nto : nto + tv.shape[0]] = tv
        nvo += verts.shape[0]
        nto += tv.shape[0]
        vstart[k + 1] = nvo
        tstart[k + 1] = nto
        errors[k] = err
        sses[k] = s
    return vout[:nvo], vstart, tout[:nto], tstart, errors, sses
