"""RTIN (Evans, Kirkpatrick & Townsend): right-triangle binary hierarchy with true error bounds.

The hierarchy lives on a padded (2^k + 1)² lattice of side s = 2^k. A triangle (apex, l, r)
with hypotenuse l–r splits at the midpoint m of l–r into (m, l, apex) and (m, apex, r). Two
kinds of levels alternate, for square sizes L = s, s/2, ..., 2:

- A(L): each L-square is cut by one diagonal (main where (i + j) is even, else the other); the
  hypotenuse midpoint is the square's centre.
- D(L): the children of A(L): four triangles per square, apex at the centre, hypotenuse on a
  side; the midpoint is the side's midpoint, shared with the neighbouring square.

``vertex_errors`` stores at each midpoint m the true max error of the (one or two) triangles
whose hypotenuse midpoint is m, maxed with the errors stored at their children's midpoints.
Splitting every triangle whose E[m] > ε then yields a mesh without cracks or T-junctions (the
two triangles sharing a hypotenuse split together; a child never splits without its parent)
whose leaves all have true error <= ε.

Padding: lattice points beyond the window (x > cols − 1 or y > rows − 1) have no height. A
triangle reaching past the window must split while it still covers window points off its own
border (E = inf); triangles entirely outside are never drawn. Nodata inside the window follows
the TIN rules (``tin_scan.scan_with_holes``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from approxtree.kernels.tin_mesh import orient
from approxtree.kernels.tin_scan import plane, row_span, scan_with_holes

#: Hierarchy triangles whose hypotenuse spans at most this many lattice steps are measured
#: point by point (``_small_error``), larger ones row by row (``_scan_right``).
SMALL_SPAN = 16


@njit(cache=True, inline="always")
def _mid_error(heights, r0, c0, ux, uy, vx, vy) -> float:
    """|z − linear interpolation| at the midpoint of edge u–v (0 when it is no lattice point)."""
    if (ux + vx) % 2 or (uy + vy) % 2:
        return 0.0
    zu = np.float64(heights[r0 + uy, c0 + ux])
    zv = np.float64(heights[r0 + vy, c0 + vx])
    zm = np.float64(heights[r0 + (uy + vy) // 2, c0 + (ux + vx) // 2])
    return abs(zm - 0.5 * (zu + zv))


@njit(cache=True, inline="always")
def _axis_frame(ax, ay, lx, ly, rx, ry, span):
    """A triangle whose hypotenuse l–r spans ``span`` steps along an axis: (h, dx, dy, mx,
    my, nx, ny) — h = span / 2 rows k = 0 (the hypotenuse) to h − 1 towards the apex a, row k
    centred at m + k·n with h − k points either side, d the unit step along the hypotenuse."""
    h = span // 2
    mx = (lx + rx) // 2
    my = (ly + ry) // 2
    return h, (rx - lx) // span, (ry - ly) // span, mx, my, (ax - mx) // h, (ay - my) // h


@njit(cache=True, inline="always")
def _diagonal_frame(ax, ay, lx, ly, rx, ry, span):
    """A triangle whose hypotenuse l–r is diagonal: (ux, uy, vx, vy), the points
    l + i·u + j·v for 0 <= j <= i <= span, u = (a − l)/span, v = (r − a)/span."""
    return (ax - lx) // span, (ay - ly) // span, (rx - ax) // span, (ry - ay) // span


@njit(cache=True)
def _small_error(heights, r0, c0, ax, ay, lx, ly, rx, ry, span) -> float:
    """Exact max |z − plane| over the non-corner points of a small hierarchy triangle, its
    hypotenuse l–r spanning span (a power of two) lattice steps in x or y, apex a: point by
    point, the plane's value at each from the corners' heights by its barycentric weights
    (multiples of 1/span: no divisions, no row set-up)."""
    za = np.float64(heights[r0 + ay, c0 + ax])
    zl = np.float64(heights[r0 + ly, c0 + lx])
    zr = np.float64(heights[r0 + ry, c0 + rx])
    inv = 1.0 / span
    best = 0.0
    if lx == rx or ly == ry:
        # Hypotenuse along an axis (legs diagonal): rows k = 0 (the hypotenuse) to h − 1
        # towards the apex, row k centred at m + k·n with h − k points either side (d the unit
        # step along the hypotenuse, n towards the apex).
        h, dx, dy, mx, my, nx, ny = _axis_frame(ax, ay, lx, ly, rx, ry, span)
        zm = (zl + zr) * 0.5
        g = (zr - zl) * inv
        rise = (za - zm) * (2.0 * inv)
        for k in range(h):
            centre = zm + rise * k
            for t in range(k - h, h - k + 1):
                if k == 0 and (t == -h or t == h):
                    continue
                z = np.float64(heights[r0 + my + k * ny + t * dy, c0 + mx + k * nx + t * dx])
                best = max(best, abs(z - (centre + g * t)))
        return best
    # Hypotenuse diagonal (legs along the axes): p = l + i·u + j·v, u = (a − l)/span,
    # v = (r − a)/span, 0 <= j <= i <= span, the plane zl + i·(za − zl)/span + j·(zr − za)/span.
    ux, uy, vx, vy = _diagonal_frame(ax, ay, lx, ly, rx, ry, span)
    gu = (za - zl) * inv
    gv = (zr - za) * inv
    for i in range(1, span + 1):
        for j in range(0, i + 1):
            if i == span and (j == 0 or j == span):
                continue
            z = np.float64(heights[r0 + ly + i * uy + j * vy, c0 + lx + i * ux + j * vx])
            best = max(best, abs(z - (zl + gu * i + gv * j)))
    return best


@njit(cache=True)
def _tri_error(heights, r0, c0, rows, cols, ax, ay, bx, by, cx, cy, has_nan, cut) -> float:
    """True error of one hierarchy triangle (inf: it must split), see the module docstring.

    cut: once the error is known to exceed cut, any value > cut may come back (the scan stops
    early); inf for the exact error.
    """
    if orient(ax, ay, bx, by, cx, cy) < 0:
        bx, by, cx, cy = cx, cy, bx, by
    w1 = cols - 1
    h1 = rows - 1
    if max(ax, max(bx, cx)) <= w1 and max(ay, max(by, cy)) <= h1:
        if not has_nan and max(abs(bx - cx), abs(by - cy)) <= 2:
            # The finest levels (most of the triangles): the only non-corner points are the
            # midpoints of the edges with even extents.
            return max(
                _mid_error(heights, r0, c0, ax, ay, bx, by),
                max(
                    _mid_error(heights, r0, c0, bx, by, cx, cy),
                    _mid_error(heights, r0, c0, cx, cy, ax, ay),
                ),
            )
        span = max(abs(bx - cx), abs(by - cy))
        if not has_nan and span <= SMALL_SPAN:
            # The next levels (most of the rest): their few points one by one.
            return _small_error(heights, r0, c0, ax, ay, bx, by, cx, cy, span)
        if has_nan:
            k, _, _ = scan_with_holes(heights, r0, c0, ax, ay, bx, by, cx, cy)
            return max(k, 0.0)
        return _scan_right(heights, r0, c0, ax, ay, bx, by, cx, cy, cut)
    # Partly or wholly outside the window: split while it reaches window points other than
    # those on its own edges along the window's far border.
    y0 = min(ay, min(by, cy))
    y1 = min(max(ay, max(by, cy)), h1)
    for y in range(y0, y1 + 1):
        lo, hi = row_span(ax, ay, bx, by, cx, cy, y)
        hi = min(hi, w1)
        if lo > hi:
            continue
        if y < h1 and lo < w1:
            return np.inf
        # Far-border points: fine as corners, or on an edge running along that border (the
        # triangle on the window side of that edge draws them); otherwise split.
        for x in range(lo, hi + 1):
            if (x == ax and y == ay) or (x == bx and y == by) or (x == cx and y == cy):
                continue
            # The far corner can only be drawn as a corner of a triangle inside the window.
            if x == w1 and y == h1:
                return np.inf
            if orient(ax, ay, bx, by, x, y) == 0:
                if _along_border(ax, ay, bx, by, x, y, w1, h1):
                    continue
            elif orient(bx, by, cx, cy, x, y) == 0:
                if _along_border(bx, by, cx, cy, x, y, w1, h1):
                    continue
            elif orient(cx, cy, ax, ay, x, y) == 0:
                if _along_border(cx, cy, ax, ay, x, y, w1, h1):
                    continue
            return np.inf
    return 0.0


@njit(cache=True, inline="always")
def _edge_x(ux, uy, vx, vy, y, lo, hi):
    """Widen [lo, hi] by the columns of edge u–v on row y (edges are axis-parallel or 45°)."""
    if y < min(uy, vy) or y > max(uy, vy):
        return lo, hi
    if uy == vy:
        return min(lo, min(ux, vx)), max(hi, max(ux, vx))
    x = ux
    if vx != ux:
        x = ux + (y - uy) if (vx > ux) == (vy > uy) else ux - (y - uy)
    return min(lo, x), max(hi, x)


@njit(cache=True)
def _row_max(heights: np.ndarray, r: int, start: int, n: int, base: float, gx: float) -> float:
    """max |heights[r, start + i] − (base + gx·i)| for i < n, no nodata, in plain arithmetic.

    Four running maxima: one would chain every step on the latency of the previous max.
    """
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    m3 = 0.0
    # Unsigned indices: no wrap-around test per element.
    ur = np.uint64(r)
    us = np.uint64(start)
    i = 0
    while i + 4 <= n:
        u = us + np.uint64(i)
        m0 = max(m0, abs(heights[ur, u] - (base + gx * i)))
        m1 = max(m1, abs(heights[ur, u + np.uint64(1)] - (base + gx * (i + 1))))
        m2 = max(m2, abs(heights[ur, u + np.uint64(2)] - (base + gx * (i + 2))))
        m3 = max(m3, abs(heights[ur, u + np.uint64(3)] - (base + gx * (i + 3))))
        i += 4
    while i < n:
        m0 = max(m0, abs(heights[ur, us + np.uint64(i)] - (base + gx * i)))
        i += 1
    return max(max(m0, m1), max(m2, m3))


@njit(cache=True)
def _scan_right(heights, r0, c0, ax, ay, bx, by, cx, cy, cut) -> float:
    """Exact max |z − plane| over the non-corner points of a hierarchy triangle, no nodata.

    Stops after the first row that takes the maximum past cut (the value returned is then
    only known to exceed cut).

    The same arithmetic as ``tin_scan.scan_candidate`` (so the same value to the last bit), but
    row spans come from the edges directly, which are axis-parallel or diagonal: no divisions.
    """
    za = np.float64(heights[r0 + ay, c0 + ax])
    zb = np.float64(heights[r0 + by, c0 + bx])
    zc = np.float64(heights[r0 + cy, c0 + cx])
    gx, gy = plane(za, zb, zc, ax, ay, bx, by, cx, cy)
    best = 0.0
    big = max(ax, max(bx, cx)) + 1
    for y in range(min(ay, min(by, cy)), max(ay, max(by, cy)) + 1):
        lo, hi = _edge_x(ax, ay, bx, by, y, big, -1)
        lo, hi = _edge_x(bx, by, cx, cy, y, lo, hi)
        lo, hi = _edge_x(cx, cy, ax, ay, y, lo, hi)
        base = za + gy * (y - ay) + gx * (lo - ax)
        n = hi - lo + 1
        # Rows through a corner: the corner's round-off must not count. Other rows: one
        # vectorized, exact maximum.
        if y != ay and y != by and y != cy:
            best = max(best, _row_max(heights, r0 + y, c0 + lo, n, base, gx))
            if best > cut:
                return best
            continue
        for i in range(n):
            x = lo + i
            e = abs(heights[r0 + y, c0 + x] - (base + gx * i))
            if e > best:
                if (x == ax and y == ay) or (x == bx and y == by) or (x == cx and y == cy):
                    continue
                best = e
    return best


@njit(cache=True, inline="always")
def _along_border(ux, uy, vx, vy, x, y, w1, h1) -> bool:
    """True when edge u–v lies on the far border line (x = w1 or y = h1) through (x, y)."""
    return (ux == vx == x == w1) or (uy == vy == y == h1)


@njit(cache=True, inline="always")
def _store(e: float) -> np.float32:
    """float32 of e rounded up, so stored errors stay upper bounds."""
    v = np.float32(e)
    if v < e:
        v = np.float32(e + abs(e) * 2.4e-7)
    return v


@njit(cache=True, inline="always")
def _decide(e: float, dm: float, cut: float, margin: float) -> float:
    """An entry's value without a scan, or −1 when its triangles must be scanned.

    e: the maximum stored at its children's midpoints (<= cut), dm: the error at the midpoint
    itself. Past cut by more than round-off: dm (the full table's entry exceeds cut too). Else
    the bound e + dm (a point of a child with plane P1 is off the parent's plane by its error
    to P1 plus dm times its barycentric weight at the midpoint, <= 1), widened past round-off,
    when its float32 stays <= cut (the full table's entry is then <= cut as well).
    """
    if dm - margin > cut:
        return dm
    v = _store((e + dm) * (1.0 + 2e-6) + margin)
    if v <= cut:
        return float(v)
    return -1.0


@njit(cache=True, parallel=True)
def vertex_errors(
    heights: np.ndarray,
    r0: int,
    c0: int,
    rows: int,
    cols: int,
    size: int,
    has_nan: bool,
    cut: float,
) -> np.ndarray:
    """E (size+1, size+1) float32 over the window heights[r0:r0+rows, c0:c0+cols].

    size: s = 2^k >= max(rows, cols) − 1. Entries that are no midpoint stay 0.
    cut: inf for the exact hierarchy. A finite cut serves one extraction at threshold cut:
    every entry is on the same side of cut as the exact table's (E > cut: split), but not
    exact: past cut, any value > cut (a triangle with a child past cut is not scanned, nor one
    whose midpoint alone is past it, a scan stops once past it); at or below, an upper bound of
    the true error (children's bound plus the midpoint's error, ``_decide``, scanned only when
    that bound reaches cut). So ``extract(E, cut, ...)`` draws the exact table's mesh.
    """
    n = size + 1
    err = np.zeros((n, n), dtype=np.float32)
    big = size
    w1 = cols - 1
    h1 = rows - 1
    # L = 2 inside the window without nodata (fast): every triangle's only non-corner points
    # are edge midpoints, so D(2) stores its side's midpoint error and A(2) the diagonal's,
    # maxed with its sides (the same values as the generic path: max is exact).
    fine = not has_nan
    # Bounds need finite heights, and a margin above the round-off of a plane's value at a
    # point (a few ulps of the heights' magnitude).
    bound = fine and cut < np.inf
    zmax = 0.0
    if bound:
        for r in range(rows):
            for c in range(cols):
                zmax = max(zmax, abs(np.float64(heights[r0 + r, c0 + c])))
    margin = 1e-9 * (zmax + 1.0)
    # A value within float32 round-off below cut whose stored float32 is past it: the exact
    # table's entry depends on exact children values a bound replaced; then start over exact.
    dirty = np.zeros(1, dtype=np.int64)
    for attempt in range(2):
        if attempt == 1:
            if dirty[0] == 0:
                break
            bound = False
            cut = np.inf
            err[:] = 0
        L = 2
        while L <= big:
            h = L // 2
            q = h // 2
            m = big // L
            # D(L), horizontal sides y = j·L: triangles of the squares above and below.
            # Children first: past cut, the triangles need no scan.
            for j in prange(m + 1):
                y = j * L
                for i in range(m):
                    x0 = i * L
                    if L == 2 and fine and x0 + 2 <= w1 and min(y + 1, big) <= h1:
                        err[y, x0 + 1] = _store(_mid_error(heights, r0, c0, x0, y, x0 + 2, y))
                        continue
                    e = 0.0
                    if q > 0:
                        if j < m:
                            e = max(e, err[y + q, x0 + q], err[y + q, x0 + h + q])
                        if j > 0:
                            e = max(e, err[y - q, x0 + q], err[y - q, x0 + h + q])
                    if bound and q > 0 and e <= cut and x0 + L <= w1 and min(y + h, big) <= h1:
                        v = _decide(e, _mid_error(heights, r0, c0, x0, y, x0 + L, y), cut, margin)
                        if v >= 0.0:
                            err[y, x0 + h] = _store(v)
                            continue
                    if j < m and e <= cut:
                        e = max(
                            e,
                            _tri_error(
                                heights, r0, c0, rows, cols, x0 + h, y + h, x0, y, x0 + L, y,
                                has_nan, cut,
                            ),
                        )  # fmt: skip
                    if j > 0 and e <= cut:
                        e = max(
                            e,
                            _tri_error(
                                heights, r0, c0, rows, cols, x0 + h, y - h, x0 + L, y, x0, y,
                                has_nan, cut,
                            ),
                        )  # fmt: skip
                    if e <= cut < _store(e):
                        dirty[0] = 1
                    err[y, x0 + h] = _store(e)
            # D(L), vertical sides x = i·L.
            for i in prange(m + 1):
                x = i * L
                for j in range(m):
                    y0 = j * L
                    if L == 2 and fine and y0 + 2 <= h1 and min(x + 1, big) <= w1:
                        err[y0 + 1, x] = _store(_mid_error(heights, r0, c0, x, y0, x, y0 + 2))
                        continue
                    e = 0.0
                    if q > 0:
                        if i < m:
                            e = max(e, err[y0 + q, x + q], err[y0 + h + q, x + q])
                        if i > 0:
                            e = max(e, err[y0 + q, x - q], err[y0 + h + q, x - q])
                    if bound and q > 0 and e <= cut and y0 + L <= h1 and min(x + h, big) <= w1:
                        v = _decide(e, _mid_error(heights, r0, c0, x, y0, x, y0 + L), cut, margin)
                        if v >= 0.0:
                            err[y0 + h, x] = _store(v)
                            continue
                    if i < m and e <= cut:
                        e = max(
                            e,
                            _tri_error(
                                heights, r0, c0, rows, cols, x + h, y0 + h, x, y0 + L, x, y0,
                                has_nan, cut,
                            ),
                        )  # fmt: skip
                    if i > 0 and e <= cut:
                        e = max(
                            e,
                            _tri_error(
                                heights, r0, c0, rows, cols, x - h, y0 + h, x, y0, x, y0 + L,
                                has_nan, cut,
                            ),
                        )  # fmt: skip
                    if e <= cut < _store(e):
                        dirty[0] = 1
                    err[y0 + h, x] = _store(e)
            # A(L): both triangles of each square's diagonal, and the four side midpoints.
            for j in prange(m):
                y0 = j * L
                for i in range(m):
                    x0 = i * L
                    if L == 2 and fine and x0 + 2 <= w1 and y0 + 2 <= h1:
                        if (i + j) % 2 == 0:
                            e = _mid_error(heights, r0, c0, x0, y0, x0 + 2, y0 + 2)
                        else:
                            e = _mid_error(heights, r0, c0, x0 + 2, y0, x0, y0 + 2)
                        e = max(e, err[y0, x0 + 1], err[y0 + 2, x0 + 1])
                        e = max(e, err[y0 + 1, x0], err[y0 + 1, x0 + 2])
                        err[y0 + 1, x0 + 1] = _store(e)
                        continue
                    e = max(np.float64(err[y0, x0 + h]), np.float64(err[y0 + L, x0 + h]))
                    e = max(e, np.float64(err[y0 + h, x0]), np.float64(err[y0 + h, x0 + L]))
                    if bound and e <= cut and x0 + L <= w1 and y0 + L <= h1:
                        if (i + j) % 2 == 0:
                            dm = _mid_error(heights, r0, c0, x0, y0, x0 + L, y0 + L)
                        else:
                            dm = _mid_error(heights, r0, c0, x0 + L, y0, x0, y0 + L)
                        v = _decide(e, dm, cut, margin)
                        if v >= 0.0:
                            err[y0 + h, x0 + h] = _store(v)
                            continue
                    if (i + j) % 2 == 0:
                        if e <= cut:
                            e = max(
                                e,
                                _tri_error(
                                    heights, r0, c0, rows, cols, x0 + L, y0, x0, y0, x0 + L,
                                    y0 + L, has_nan, cut,
                                ),
                            )  # fmt: skip
                        if e <= cut:
                            e = max(
                                e,
                                _tri_error(
                                    heights, r0, c0, rows, cols, x0, y0 + L, x0 + L, y0 + L,
                                    x0, y0, has_nan, cut,
                                ),
                            )  # fmt: skip
                    else:
                        if e <= cut:
                            e = max(
                                e,
                                _tri_error(
                                    heights, r0, c0, rows, cols, x0, y0, x0, y0 + L, x0 + L,
                                    y0, has_nan, cut,
                                ),
                            )  # fmt: skip
                        if e <= cut:
                            e = max(
                                e,
                                _tri_error(
                                    heights, r0, c0, rows, cols, x0 + L, y0 + L, x0 + L, y0,
                                    x0, y0 + L, has_nan, cut,
                                ),
                            )  # fmt: skip
                    if e <= cut < _store(e):
                        dirty[0] = 1
                    err[y0 + h, x0 + h] = _store(e)
            L *= 2
    return err


@njit(cache=True)
def _walk(
    err: np.ndarray,
    threshold: float,
    heights: np.ndarray,
    r0: int,
    c0: int,
    rows: int,
    cols: int,
    mark: np.ndarray,
    ij: np.ndarray,
    tv: np.ndarray,
    store: bool,
):
    """(triangles, vertices, max error, sum of squared errors, points measured) of the mesh at
    threshold; with store, fills ij (grid row, column) and tv, and measures every drawn leaf.

    mark: (rows·cols,) int64, −1 where no vertex yet; on return the index of each vertex, −2
    at the non-corner points on drawn edges (measured once: a conforming mesh has no vertex
    inside an edge).
    Written without helpers taking arrays and without reassigning arrays: either costs
    reference counting per leaf, several times the work of the leaf itself.
    """
    size = err.shape[0] - 1
    # Depth-first, a stack of (apex, l, r); every split pops one and pushes two, so the depth
    # stays under two entries per level (64 levels hold any lattice).
    stack = np.empty((130, 6), dtype=np.int64)
    stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3], stack[0, 4], stack[0, 5] = (
        size, 0, 0, 0, size, size,
    )  # fmt: skip
    stack[1, 0], stack[1, 1], stack[1, 2], stack[1, 3], stack[1, 4], stack[1, 5] = (
        0, size, size, size, 0, 0,
    )  # fmt: skip
    sp = 2
    nt = 0
    nv = 0
    vmax = 0.0
    sumsq = 0.0
    count = 0
    w1 = cols - 1
    h1 = rows - 1
    while sp > 0:
        sp -= 1
        ax = stack[sp, 0]
        ay = stack[sp, 1]
        lx = stack[sp, 2]
        ly = stack[sp, 3]
        rx = stack[sp, 4]
        ry = stack[sp, 5]
        sx = lx + rx
        sy = ly + ry
        if (sx | sy) & 1 == 0:
            mx = sx >> 1
            my = sy >> 1
            if err[my, mx] > threshold:
                # Children (m, l, apex) below (m, apex, r): the latter is visited first.
                stack[sp, 0] = mx
                stack[sp, 1] = my
                stack[sp, 2] = lx
                stack[sp, 3] = ly
                stack[sp, 4] = ax
                stack[sp, 5] = ay
                stack[sp + 1, 0] = mx
                stack[sp + 1, 1] = my
                stack[sp + 1, 2] = ax
                stack[sp + 1, 3] = ay
                stack[sp + 1, 4] = rx
                stack[sp + 1, 5] = ry
                sp += 2
                continue
        # A leaf: drawn when inside the window with valid corners.
        if max(ax, max(lx, rx)) > w1 or max(ay, max(ly, ry)) > h1:
            continue
        if orient(ax, ay, lx, ly, rx, ry) < 0:
            lx, ly, rx, ry = rx, ry, lx, ly
        # A leaf with a nodata corner is not drawn, but its valid corners are vertices.
        hole = False
        for k in range(3):
            if k == 0:
                px, py = ax, ay
            elif k == 1:
                px, py = lx, ly
            else:
                px, py = rx, ry
            key = py * cols + px
            if np.isnan(heights[r0 + py, c0 + px]):
                hole = True
            elif mark[key] < 0:
                mark[key] = nv
                if store:
                    ij[nv, 0] = r0 + py
                    ij[nv, 1] = c0 + px
                nv += 1
        if hole:
            continue
        nt += 1
        if not store:
            continue
        tv[3 * nt - 3] = mark[ay * cols + ax]
        tv[3 * nt - 2] = mark[ly * cols + lx]
        tv[3 * nt - 1] = mark[ry * cols + rx]
        # Unit right triangles (most leaves of a fine mesh) have no point but their corners.
        if abs(lx - rx) == 1 and abs(ly - ry) == 1:
            continue
        # Measure the leaf: every non-corner point, the plane's value at each from the
        # corners' heights by its barycentric weights (multiples of 1/span, as
        # ``_small_error``: no divisions, no row set-up); interior points belong to this leaf
        # alone, edge points count once, marked −2 in mark (corners are vertices: skipped).
        za = np.float64(heights[r0 + ay, c0 + ax])
        zl = np.float64(heights[r0 + ly, c0 + lx])
        zr = np.float64(heights[r0 + ry, c0 + rx])
        span = max(abs(rx - lx), abs(ry - ly))
        inv = 1.0 / span
        if lx == rx or ly == ry:
            # Hypotenuse along an axis: rows k = 0 (the hypotenuse) to h − 1 towards the
            # apex, centred at m + k·n, h − k points either side (the outer two on the legs).
            h, dx, dy, mx, my, nx, ny = _axis_frame(ax, ay, lx, ly, rx, ry, span)
            zm = (zl + zr) * 0.5
            g = (zr - zl) * inv
            rise = (za - zm) * (2.0 * inv)
            for k in range(h):
                centre = zm + rise * k
                w = h - k
                px0 = mx + k * nx
                py0 = my + k * ny
                for t in range(-w, w + 1):
                    px = px0 + t * dx
                    py = py0 + t * dy
                    if k == 0 or t == -w or t == w:
                        if mark[py * cols + px] != -1:
                            continue
                        mark[py * cols + px] = -2
                    z = heights[r0 + py, c0 + px]
                    if np.isnan(z):
                        # Nodata under a drawn triangle: the mesh would cover a hole.
                        vmax = np.inf
                        continue
                    e = abs(z - (centre + g * t))
                    count += 1
                    sumsq += e * e
                    if e > vmax:
                        vmax = e
            continue
        # Hypotenuse diagonal: p = l + i·u + j·v, u = (a − l)/span, v = (r − a)/span,
        # 0 <= j <= i <= span (j = 0, j = i and i = span on the edges).
        ux, uy, vx, vy = _diagonal_frame(ax, ay, lx, ly, rx, ry, span)
        gu = (za - zl) * inv
        gv = (zr - za) * inv
        for i in range(1, span + 1):
            base = zl + gu * i
            px0 = lx + i * ux
            py0 = ly + i * uy
            for j in range(i + 1):
                px = px0 + j * vx
                py = py0 + j * vy
                if j == 0 or j == i or i == span:
                    if mark[py * cols + px] != -1:
                        continue
                    mark[py * cols + px] = -2
                z = heights[r0 + py, c0 + px]
                if np.isnan(z):
                    vmax = np.inf
                    continue
                e = abs(z - (base + gv * j))
                count += 1
                sumsq += e * e
                if e > vmax:
                    vmax = e
    return nt, nv, vmax, sumsq, count


@njit(cache=True)
def extract(
    err: np.ndarray,
    threshold: float,
    heights: np.ndarray,
    r0: int,
    c0: int,
    rows: int,
    cols: int,
    count_only: bool,
):
    """One pass over the hierarchy: split every triangle whose E[midpoint] > threshold.

    Emits the triangles inside the window without nodata corners, orient > 0 in (column, row);
    the valid corners of leaves with a nodata corner are vertices too (exact, not drawn).
    Returns (triangle count, vertex count, ij (n, 2) int32 grid (row, column) of the vertices
    (window offsets r0, c0 added), tv (3m,) int32 window-local triangles, max error,
    sum of squared errors, points measured): the exact error of the mesh over the window's
    non-vertex points (inf where a drawn triangle covers nodata; a point no drawn triangle
    covers is not measured: the caller compares the count). With count_only the arrays are
    empty and nothing is measured.
    """
    mark = np.full(rows * cols, -1, dtype=np.int64)
    if count_only:
        ij = np.empty((0, 2), dtype=np.int32)
        tv = np.empty(0, dtype=np.int32)
        nt, nv, vmax, sumsq, count = _walk(
            err, threshold, heights, r0, c0, rows, cols, mark, ij, tv, False
        )
        return nt, nv, ij, tv, vmax, sumsq, count
    # Room for the finest mesh (drawn triangles have area >= 1/2 and do not overlap): pages
    # are touched only as far as they are filled, and the result is copied out compact.
    ij = np.empty((rows * cols, 2), dtype=np.int32)
    tv = np.empty(6 * max(rows - 1, 0) * max(cols - 1, 0), dtype=np.int32)
    nt, nv, vmax, sumsq, count = _walk(
        err, threshold, heights, r0, c0, rows, cols, mark, ij, tv, True
    )
    return nt, nv, ij[:nv].copy(), tv[: 3 * nt].copy(), vmax, sumsq, count
