"""Scan conversion of lattice triangles over a height grid: candidates and exact errors.

A triangle's grid points are visited row by row between the exact integer bounds given by its
three edge functions (no bounding-box waste, no rounding), and the plane through its corners is
evaluated relative to corner a so that thin triangles far from the origin stay accurate. The hot
scans (``scan_candidate``, ``triangle_sse``) get those bounds by walking the left and right
edges with exact integer steps (``_edge_walk``); ``row_span`` computes one row's bounds alone.

Keys returned for the heap:

- ``>= 0``: the largest |z − plane| over the triangle's non-vertex data points (its candidate),
- ``-1``: no candidate (every point is a vertex, or a hole triangle holding only nodata),
- ``inf``: the triangle must be refined because of nodata (see ``scan_with_holes``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from approxtree.kernels._jit import njit_no_nrt

NO_CANDIDATE = -1.0


@njit(cache=True, inline="always")
def _bound(a: int, k: int, lo: int, hi: int):
    """Tighten [lo, hi] to the x with a·x + k >= 0 (exact: float guess, integer fix-up)."""
    if a > 0:
        x = math.ceil(-k / a)
        if a * (x - 1) + k >= 0:
            x -= 1
        elif a * x + k < 0:
            x += 1
        return max(lo, x), hi
    if a < 0:
        x = math.floor(k / -a)
        if a * (x + 1) + k >= 0:
            x += 1
        elif a * x + k < 0:
            x -= 1
        return lo, min(hi, x)
    if k < 0:
        return 1, 0
    return lo, hi


@njit(cache=True, inline="always")
def row_span(ax, ay, bx, by, cx, cy, y):
    """Inclusive column range (lo, hi) of lattice row y inside the closed triangle (a, b, c).

    Each edge u→v gives E(x) = (uy − vy)·x + (vx − ux)·(y − uy) + (vy − uy)·ux >= 0 inside.
    """
    lo = min(ax, min(bx, cx))
    hi = max(ax, max(bx, cx))
    lo, hi = _bound(ay - by, (bx - ax) * (y - ay) + (by - ay) * ax, lo, hi)
    lo, hi = _bound(by - cy, (cx - bx) * (y - by) + (cy - by) * bx, lo, hi)
    lo, hi = _bound(cy - ay, (ax - cx) * (y - cy) + (ay - cy) * cx, lo, hi)
    return lo, hi


@njit(cache=True, inline="always")
def plane(za, zb, zc, ax, ay, bx, by, cx, cy):
    """Gradient (gx, gy) of the plane through the corners, for z = za + gx·dx + gy·dy."""
    d = float((bx - ax) * (cy - ay) - (by - ay) * (cx - ax))
    db = zb - za
    dc = zc - za
    gx = (db * (cy - ay) - dc * (by - ay)) / d
    gy = (dc * (bx - ax) - db * (cx - ax)) / d
    return gx, gy


@njit_no_nrt(fastmath=True)
def _grid_row_max(heights: np.ndarray, r: int, start: int, n: int, base: float, gx: float):
    """``_row_max`` of heights[r, start:start + n], indexed in place (no row view to count)."""
    m = 0.0
    # Unsigned indices: numba then emits no negative-index wraparound per load.
    ur = np.uint64(r)
    us = np.uint64(start)
    for i in range(n):
        m = max(m, abs(heights[ur, us + np.uint64(i)] - (base + gx * i)))
    return m


@njit(cache=True, inline="always")
def _floor_div(num: int, d: int | np.integer):
    """(q, r) with num = q·d + r, 0 <= r < d (d > 0): a float quotient fixed up exactly
    (cheaper than an integer division; |num| < 2^53 keeps it within one of the truth)."""
    q = math.floor(num / d)
    r = num - q * d
    if r < 0:
        q -= 1
        r += d
    elif r >= d:
        q += 1
        r -= d
    return q, r


@njit(cache=True, inline="always")
def _edge_walk(x0: int, y0: int, x1: int, y1: int, y: int):
    """Walk state at row y of the edge (x0, y0)–(x1, y1), y1 > y0.

    The edge's x at row y is q + r / d exactly (0 <= r < d = y1 − y0); each next row adds
    sq + sr / d (0 <= sr < d). Returns (q, r, d, sq, sr): integers only, so the walk is exact.
    """
    d = y1 - y0
    q, r = _floor_div(x0 * d + (x1 - x0) * (y - y0), d)
    sq, sr = _floor_div(x1 - x0, d)
    return q, r, d, sq, sr


@njit(cache=True, inline="always")
def _edge_start(x0: int, y0: int, x1: int, y1: int):
    """``_edge_walk`` at the edge's first row y0 (q = x0, r = 0): one division, not two."""
    d = np.int64(y1 - y0)
    sq, sr = _floor_div(x1 - x0, d)
    # int64 like the walk's later states (the corners may come in as int32).
    return np.int64(x0), np.int64(0), d, sq, sr


@njit(cache=True, inline="always")
def _step(w):
    """The walk state of the next row."""
    q, r, d, sq, sr = w
    q += sq
    r += sr
    if r >= d:
        r -= d
        q += 1
    return q, r, d, sq, sr


# Inlined (a call per triangle costs ~3% of a TIN run), at two call sites only: numba types an
# inlined body again at each one.
@njit(cache=True, inline="always")
def _scan_rows(
    heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy, ya, yb, left, right, best, bestx, besty
):
    """Candidate search over rows ya..yb between a left and a right edge walk.

    left, right: ``_edge_walk`` states at row ya of the edges bounding the rows from the left
    (ceiling) and the right (floor). Points are visited in the order of a ``row_span`` scan,
    with the same arithmetic, so ties and values are those of a row-span scan. Returns the
    best so far and both walks at row yb + 1.
    """
    for y in range(ya, yb + 1):
        lo = left[0] + (left[1] > 0)
        hi = right[0]
        left = _step(left)
        right = _step(right)
        if lo > hi:
            continue
        n = hi - lo + 1
        base = za + gy * (y - ay) + gx * (lo - ax)
        r = r0 + y
        start = c0 + lo
        # Long rows: a vectorized maximum first (with slack for its fused arithmetic), the
        # position searched only when it may beat the best so far.
        if n >= 16 and _grid_row_max(heights, r, start, n, base, gx) + 1e-9 <= best:
            continue
        # Unsigned indices: no negative-index wraparound per load (see ``_grid_row_max``).
        ur = np.uint64(r)
        us = np.uint64(start)
        # The offset as a float counted alongside (exact: small integers), not converted
        # from i at every point: the same values.
        fi = 0.0
        for i in range(n):
            e = abs(heights[ur, us + np.uint64(i)] - (base + gx * fi))
            fi += 1.0
            if e > best:
                x = lo + i
                # Corners are reproduced exactly; round-off must not make them candidates.
                if (x == ax and y == ay) or (x == bx and y == by) or (x == cx and y == cy):
                    continue
                best = e
                bestx = x
                besty = y
    return best, bestx, besty, left, right


@njit(cache=True, inline="always")
def _by_rows(ax, ay, bx, by, cx, cy):
    """The corners sorted by row (top, middle, bottom), and whether the middle one lies left
    of the top–bottom edge."""
    tx, ty, mx, my, lx, ly = ax, ay, bx, by, cx, cy
    if my < ty:
        tx, ty, mx, my = mx, my, tx, ty
    if ly < my:
        mx, my, lx, ly = lx, ly, mx, my
        if my < ty:
            tx, ty, mx, my = mx, my, tx, ty
    # The middle corner against the long edge's x at its row (cross-multiplied, exact).
    mid_left = mx * (ly - ty) < tx * (ly - ty) + (lx - tx) * (my - ty)
    return tx, ty, mx, my, lx, ly, mid_left


@njit(cache=True, inline="always")
def _midpoint(ax, ay, bx, by, cx, cy):
    """The one non-corner point of a triangle of twice the area 2: the midpoint of the edge
    whose steps are both even (Pick's theorem: 4 border points, none inside)."""
    if (bx - ax) % 2 == 0 and (by - ay) % 2 == 0:
        return np.int64((ax + bx) // 2), np.int64((ay + by) // 2)
    if (cx - bx) % 2 == 0 and (cy - by) % 2 == 0:
        return np.int64((bx + cx) // 2), np.int64((by + cy) // 2)
    return np.int64((cx + ax) // 2), np.int64((cy + ay) // 2)


@njit(cache=True, inline="always")
def _midpoint_candidate(heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy):
    """``scan_candidate`` of a triangle of twice the area 2: its one non-corner point is the
    midpoint of the edge whose steps are both even. The error is evaluated as the row scan
    would (from the first point of the point's row), so it is the same to the last bit."""
    mx, my = _midpoint(ax, ay, bx, by, cx, cy)
    # The row's first point: the midpoint or a corner on its row left of it.
    lo = mx
    if ay == my:
        lo = min(lo, ax)
    if by == my:
        lo = min(lo, bx)
    if cy == my:
        lo = min(lo, cx)
    base = za + gy * (my - ay) + gx * (lo - ax)
    e = abs(heights[np.uint64(r0 + my), np.uint64(c0 + mx)] - (base + gx * (mx - lo)))
    return e, np.int64(my), np.int64(mx)


@njit_no_nrt()
def scan_candidate(heights, r0, c0, ax, ay, bx, by, cx, cy):
    """(key, candidate y, candidate x) of a triangle on a grid without nodata.

    Rows are bounded by walking the triangle's left and right edges with integer steps (the
    exact spans of ``row_span`` without its divisions per row); the grid is indexed in place
    and the kernel compiled without the reference-counting runtime: row views, or reference
    counts on the arguments, would cost atomic updates per row and per call, which dominate
    on the small triangles of a fine mesh.
    """
    # The smallest triangles of a fine mesh, by Pick's theorem (2·area = 2·interior + border
    # points − 2): twice the area 1 holds no point but its corners, 2 exactly one, the midpoint
    # of its one edge with even steps. Answered without the row walks, with the same result.
    o = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    if o == 1:
        return NO_CANDIDATE, np.int64(-1), np.int64(-1)
    # Unsigned indices: no negative-index wraparound per load.
    za = np.float64(heights[np.uint64(r0 + ay), np.uint64(c0 + ax)])
    zb = np.float64(heights[np.uint64(r0 + by), np.uint64(c0 + bx)])
    zc = np.float64(heights[np.uint64(r0 + cy), np.uint64(c0 + cx)])
    gx, gy = plane(za, zb, zc, ax, ay, bx, by, cx, cy)
    if o == 2:
        return _midpoint_candidate(heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy)
    best = NO_CANDIDATE
    # int64 throughout (no literal −1, no int32 row): every ``_scan_rows`` call below is then
    # one compiled signature.
    best_x = np.int64(-1)
    best_y = np.int64(-1)
    tx, ty, mx, my, lx, ly, mid_left = _by_rows(ax, ay, bx, by, cx, cy)
    # The long edge bounds every row on one side; the top–middle edge, then the middle–bottom
    # one, on the other.
    long_w = _edge_start(tx, ty, lx, ly)
    ya = np.int64(ty)
    # The walks are swapped into (left, right) order rather than calling ``_scan_rows`` in
    # each order: half the inlined copies to compile, the same arithmetic.
    if my > ty:
        short = _edge_start(tx, ty, mx, my)
        left, right = (short, long_w) if mid_left else (long_w, short)
        best, best_x, best_y, left, right = _scan_rows(
            heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy, ya, my, left, right,
            best, best_x, best_y,
        )  # fmt: skip
        long_w = right if mid_left else left
        ya = my + 1
    if ly >= ya and ly > my:
        # The lower edge starts at the middle row, or one below it after the upper rows.
        short = _edge_start(mx, my, lx, ly)
        if ya > my:
            short = _step(short)
        left, right = (short, long_w) if mid_left else (long_w, short)
        best, best_x, best_y, left, right = _scan_rows(
            heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy, ya, ly, left, right,
            best, best_x, best_y,
        )  # fmt: skip
    return best, best_y, best_x


@njit_no_nrt(fastmath=True)
def _row_max_sse(row: np.ndarray, start: int, n: int, base: float, gx: float):
    """(max, sum of squares) of |row[start + i] − (base + gx·i)| for i < n (SIMD, no nodata)."""
    m = 0.0
    s = 0.0
    # Unsigned indices: no negative-index wraparound per load (see ``_grid_row_max``).
    us = np.uint64(start)
    for i in range(n):
        e = abs(row[us + np.uint64(i)] - (base + gx * i))
        m = max(m, e)
        s += e * e
    return m, s


@njit(cache=True, inline="always")
def _edge_weight(ax, ay, bx, by, cx, cy, x, y, wab, wbc, wca) -> float:
    """Share of point (x, y) of the closed triangle that the triangle owns.

    1 inside, the edge's weight on an edge (½ shared with a neighbour, 1 on the border), 0 at a
    corner (corners are exact vertices, counted apart).
    """
    on_ab = orient_i(ax, ay, bx, by, x, y) == 0
    on_bc = orient_i(bx, by, cx, cy, x, y) == 0
    on_ca = orient_i(cx, cy, ax, ay, x, y) == 0
    if on_ab + on_bc + on_ca >= 2:
        return 0.0
    if on_ab:
        return wab
    if on_bc:
        return wbc
    if on_ca:
        return wca
    return 1.0


# Inlined into its two callers (``_sse_rows``'s row loop and ``_small_sse``): one copy of the
# arithmetic, so both sum every row exactly alike.
@njit(cache=True, inline="always")
def _row_sse(heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy, wab, wbc, wca, y, lo, hi):
    """The owned squared errors of row y, columns lo..hi (lo <= hi), of the triangle whose plane
    through corner a is ``za + gx·(x − ax) + gy·(y − ay)`` (see ``triangle_sse``)."""
    n = hi - lo + 1
    base = za + gy * (y - ay) + gx * (lo - ax)
    r = r0 + y
    start = c0 + lo
    # Long rows: a vectorized sum; short rows: a plain one.
    if n >= 16:
        s = _row_max_sse(heights[r], start, n, base, gx)[1]
    else:
        s = 0.0
        ur = np.uint64(r)
        us = np.uint64(start)
        fi = 0.0
        for i in range(n):
            e = abs(float(heights[ur, us + np.uint64(i)]) - (base + gx * fi))
            fi += 1.0
            s += e * e
    # Edge points are shared: a row along a horizontal edge lies wholly on it, otherwise only
    # the row's two ends can touch an edge.
    if ay == by == y:
        s *= wab
    elif by == cy == y:
        s *= wbc
    elif cy == ay == y:
        s *= wca
    else:
        e = abs(float(heights[r, start]) - base)
        s -= (1.0 - _edge_weight(ax, ay, bx, by, cx, cy, lo, y, wab, wbc, wca)) * e * e
        if hi > lo:
            e = abs(float(heights[r, c0 + hi]) - (base + gx * (n - 1)))
            w = _edge_weight(ax, ay, bx, by, cx, cy, hi, y, wab, wbc, wca)
            s -= (1.0 - w) * e * e
    return s


# A plain call, not inlined (see ``_scan_rows``).
@njit_no_nrt()
def _sse_rows(
    heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy, wab, wbc, wca, ya, yb, left, right, sse
):
    """``sse`` plus the owned squared errors over rows ya..yb between a left and a right
    edge walk (see ``_scan_rows``, ``triangle_sse``), added row by row in row order."""
    lq, lr, ld, lsq, lsr = _edge_walk(left[0], left[1], left[2], left[3], ya)
    rq, rr, rd, rsq, rsr = _edge_walk(right[0], right[1], right[2], right[3], ya)
    for y in range(ya, yb + 1):
        lo = lq + (lr > 0)
        hi = rq
        lq += lsq
        lr += lsr
        if lr >= ld:
            lr -= ld
            lq += 1
        rq += rsq
        rr += rsr
        if rr >= rd:
            rr -= rd
            rq += 1
        if lo > hi:
            continue
        sse += _row_sse(
            heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy, wab, wbc, wca, y, lo, hi
        )
    return sse


@njit(cache=True, inline="always")
def _small_sse(heights, r0, c0, ax, ay, bx, by, cx, cy, wab, wbc, wca, o) -> float:
    """``triangle_sse`` of a triangle of twice the area o <= 2 (its corners and at most one
    edge midpoint, see ``scan_candidate``). A row holding a lone corner adds exactly zero (the
    corner's error is taken back off), so only two rows can count: a horizontal edge's (its
    corners, and the midpoint if it lies on that edge, weighted as the edge) and the
    midpoint's. They are summed as ``_sse_rows`` sums them, in row order: the same value.
    """
    hy = np.int64(-1)
    hlo = np.int64(0)
    hhi = np.int64(0)
    if ay == by:
        hy, hlo, hhi = np.int64(ay), np.int64(min(ax, bx)), np.int64(max(ax, bx))
    elif by == cy:
        hy, hlo, hhi = np.int64(by), np.int64(min(bx, cx)), np.int64(max(bx, cx))
    elif cy == ay:
        hy, hlo, hhi = np.int64(cy), np.int64(min(cx, ax)), np.int64(max(cx, ax))
    my = np.int64(-1)
    mlo = np.int64(0)
    mhi = np.int64(0)
    if o == 2:
        mx, my = _midpoint(ax, ay, bx, by, cx, cy)
        if my == hy:
            my = np.int64(-1)
        else:
            # The midpoint's row: the midpoint and a corner on that row, if any.
            mlo = mx
            mhi = mx
            if ay == my:
                mlo, mhi = min(mlo, ax), max(mhi, ax)
            if by == my:
                mlo, mhi = min(mlo, bx), max(mhi, bx)
            if cy == my:
                mlo, mhi = min(mlo, cx), max(mhi, cx)
    if hy < 0 and my < 0:
        return 0.0
    za = np.float64(heights[r0 + ay, c0 + ax])
    zb = np.float64(heights[r0 + by, c0 + bx])
    zc = np.float64(heights[r0 + cy, c0 + cx])
    gx, gy = plane(za, zb, zc, ax, ay, bx, by, cx, cy)
    sse = 0.0
    # In row order (the sum's order): the edge's row first when it lies above.
    if hy >= 0 and (my < 0 or hy < my):
        sse += _row_sse(
            heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy, wab, wbc, wca, hy, hlo, hhi
        )
    if my >= 0:
        sse += _row_sse(
            heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy, wab, wbc, wca, my, mlo, mhi
        )
        if 0 <= hy and my < hy:
            sse += _row_sse(
                heights, r0, c0, za, gx, gy, ax, ay, bx, by, cx, cy, wab, wbc, wca, hy, hlo, hhi
            )
    return max(sse, 0.0)


@njit_no_nrt()
def triangle_sse(heights, r0, c0, ax, ay, bx, by, cx, cy, wab, wbc, wca) -> float:
    """The triangle's owned sum of squared errors on a grid without nodata.

    wab, wbc, wca: the share of a point on edge ab, bc, ca this triangle owns (½ when the edge
    is shared with a neighbour, 1 on the border), so the sums over a mesh's triangles count
    every non-vertex point once (up to round-off: both neighbours interpolate the same line).
    Rows are walked as in ``scan_candidate``; the sum runs in row order.
    """
    # The smallest triangles of a fine mesh without the row walks (same value).
    o = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    if o <= 2:
        return _small_sse(heights, r0, c0, ax, ay, bx, by, cx, cy, wab, wbc, wca, o)
    za = np.float64(heights[r0 + ay, c0 + ax])
    zb = np.float64(heights[r0 + by, c0 + bx])
    zc = np.float64(heights[r0 + cy, c0 + cx])
    gx, gy = plane(za, zb, zc, ax, ay, bx, by, cx, cy)
    sse = 0.0
    tx, ty, mx, my, lx, ly, mid_left = _by_rows(ax, ay, bx, by, cx, cy)
    long_edge = (tx, ty, lx, ly)
    if my > ty:
        upper = (tx, ty, mx, my)
        left, right = (upper, long_edge) if mid_left else (long_edge, upper)
        sse = _sse_rows(
            heights,
            r0,
            c0,
            za,
            gx,
            gy,
            ax,
            ay,
            bx,
            by,
            cx,
            cy,
            wab,
            wbc,
            wca,
            np.int64(ty),
            my,
            left,
            right,
            sse,
        )
    if ly > my:
        lower = (mx, my, lx, ly)
        left, right = (lower, long_edge) if mid_left else (long_edge, lower)
        ya = np.int64(my + 1 if my > ty else ty)
        sse = _sse_rows(
            heights,
            r0,
            c0,
            za,
            gx,
            gy,
            ax,
            ay,
            bx,
            by,
            cx,
            cy,
            wab,
            wbc,
            wca,
            ya,
            ly,
            left,
            right,
            sse,
        )
    return max(sse, 0.0)


@njit_no_nrt()
def scan_with_holes(heights, r0, c0, ax, ay, bx, by, cx, cy):
    """(key, candidate y, candidate x) of a triangle on a grid with nodata (NaN).

    A triangle with a nodata corner is a hole triangle (never drawn): while it still holds a
    valid non-corner point it gets key inf and that point (the most interior one) as candidate,
    so the valid data around holes end up in drawn triangles. A triangle with valid corners that
    holds nodata gets key inf and its most interior nodata point as candidate, so holes are cut
    out of the mesh. Otherwise the key is the ordinary largest error.
    """
    za = np.float64(heights[r0 + ay, c0 + ax])
    zb = np.float64(heights[r0 + by, c0 + bx])
    zc = np.float64(heights[r0 + cy, c0 + cx])
    hole = np.isnan(za) or np.isnan(zb) or np.isnan(zc)
    gx, gy = (0.0, 0.0) if hole else plane(za, zb, zc, ax, ay, bx, by, cx, cy)
    best = NO_CANDIDATE
    best_x = -1
    best_y = -1
    odd_depth = -1
    odd_x = -1
    odd_y = -1
    y0 = min(ay, min(by, cy))
    y1 = max(ay, max(by, cy))
    for y in range(y0, y1 + 1):
        lo, hi = row_span(ax, ay, bx, by, cx, cy, y)
        if lo > hi:
            continue
        for x in range(lo, hi + 1):
            if (x == ax and y == ay) or (x == bx and y == by) or (x == cx and y == cy):
                continue
            z = heights[r0 + y, c0 + x]
            # Points that force refinement: valid ones in a hole triangle, nodata otherwise.
            if hole != np.isnan(z):
                depth = min(
                    orient_i(bx, by, cx, cy, x, y),
                    min(orient_i(cx, cy, ax, ay, x, y), orient_i(ax, ay, bx, by, x, y)),
                )
                if depth > odd_depth:
                    odd_depth = depth
                    odd_x = x
                    odd_y = y
                continue
            if hole:
                continue
            e = abs(z - (za + gx * (x - ax) + gy * (y - ay)))
            if e > best:
                best = e
                best_x = x
                best_y = y
    if odd_depth >= 0:
        return np.inf, odd_y, odd_x
    return best, best_y, best_x


@njit(cache=True, inline="always")
def orient_i(ax, ay, bx, by, px, py):
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@njit_no_nrt()
def triangle_error(heights, r0, c0, ax, ay, bx, by, cx, cy, has_nan) -> float:
    """Largest |z − plane| over the triangle's data points (inf when nodata forces a split)."""
    if has_nan:
        k, _, _ = scan_with_holes(heights, r0, c0, ax, ay, bx, by, cx, cy)
    else:
        k, _, _ = scan_candidate(heights, r0, c0, ax, ay, bx, by, cx, cy)
    return max(k, 0.0)
