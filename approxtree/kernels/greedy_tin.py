"""Greedy insertion TIN over a height grid (Garland & Heckbert, Algorithms III and IV).

Start from the two triangles on the window's corners; repeatedly take the triangle whose
candidate (its grid point of largest error) is worst, insert that point, restore the mesh by
edge flips, and rescan only the triangles the insertion changed. Candidates sit in a max-heap
of triangles (``tri_heap``), so a pass costs O(log m) plus the rescanned area: O((m + n) log m)
expected in all. In a fine mesh most triangles are the smallest lattice triangles (twice the
area 1 or 2: no point but the corners, or one edge midpoint); ``tin_scan`` answers those
without walking rows, in the scans and in the final sum of squared errors.

Two flip rules:

- Delaunay (Algorithm III): flip when the far vertex lies inside the circumcircle.
- Data-dependent (Algorithm IV): flip when the other diagonal fits the data better (sum of
  the two triangles' max errors, L∞ accumulate / L1 combine as the paper found best), unless
  one split has much better shape: with q = area₁·area₂ / (diam₁·diam₂) for each diagonal, a
  ratio min(q)/max(q) <= ``QTHRESH`` = 0.5 (the paper's best threshold) decides by shape.

Stops when the worst candidate's error is <= ``max_error``, at ``max_points`` vertices, or
before the triangle count would exceed ``max_triangles``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from approxtree.kernels._jit import njit_no_nrt
from approxtree.kernels.tin_mesh import (
    flip,
    grow,
    in_circle,
    next_edge,
    orient,
    prev_edge,
    split_edge,
    split_interior,
)
from approxtree.kernels.tin_scan import (
    row_span,
    scan_candidate,
    scan_with_holes,
    triangle_error,
    triangle_sse,
)
from approxtree.kernels.tri_heap import heap_remove, heap_update

#: Shape-quality ratio under which the data-dependent rule decides by shape (paper: 0.5).
QTHRESH = 0.5


@njit(cache=True, inline="always")
def _shape(ax, ay, bx, by, cx, cy) -> float:
    """Area / longest edge of a triangle (a length: scale-consistent shape rating)."""
    area = 0.5 * abs(orient(ax, ay, bx, by, cx, cy))
    d = max(
        (bx - ax) ** 2 + (by - ay) ** 2,
        max((cx - bx) ** 2 + (cy - by) ** 2, (ax - cx) ** 2 + (ay - cy) ** 2),
    )
    return area / math.sqrt(d)


@njit_no_nrt()
def _flip_improves(heights, r0, c0, vxy, a, b, p, q, has_nan) -> bool:
    """Algorithm IV's test: is diagonal p–q better than a–b for the quadrilateral a, q, b, p?"""
    ax, ay, bx, by = vxy[2 * a], vxy[2 * a + 1], vxy[2 * b], vxy[2 * b + 1]
    px, py, qx, qy = vxy[2 * p], vxy[2 * p + 1], vxy[2 * q], vxy[2 * q + 1]
    # Only a strictly convex quadrilateral can take the other diagonal.
    if orient(ax, ay, qx, qy, px, py) <= 0 or orient(qx, qy, bx, by, px, py) <= 0:
        return False
    q_ab = _shape(ax, ay, bx, by, px, py) * _shape(bx, by, ax, ay, qx, qy)
    q_pq = _shape(ax, ay, qx, qy, px, py) * _shape(qx, qy, bx, by, px, py)
    if min(q_ab, q_pq) <= QTHRESH * max(q_ab, q_pq):
        return q_pq > q_ab
    e_ab = triangle_error(heights, r0, c0, ax, ay, bx, by, px, py, has_nan) + triangle_error(
        heights, r0, c0, bx, by, ax, ay, qx, qy, has_nan
    )
    e_pq = triangle_error(heights, r0, c0, ax, ay, qx, qy, px, py, has_nan) + triangle_error(
        heights, r0, c0, qx, qy, bx, by, px, py, has_nan
    )
    return e_pq < e_ab


#: Why ``_insert_until`` returned: the run is over, or an array must grow before it resumes.
FINISHED = 0
GROW_MESH = 1
GROW_STACK = 2
GROW_HEAP = 3


@njit(cache=True, inline="always")
def _store_state(state, nv, nt, size, sp, n_pending):
    """state[:] = (nv, nt, size, sp, n_pending), item by item: a slice assignment would compile
    numba's shape-mismatch error formatting (seconds on a cold start). Inlined: one call site
    passes a literal 0, which would compile a second signature."""
    state[0] = nv
    state[1] = nt
    state[2] = size
    state[3] = sp
    state[4] = n_pending


# Without the reference-counting runtime (it allocates nothing): every call of a scan or mesh
# operation from the loop would otherwise pay atomic reference-count updates on its arrays.
@njit_no_nrt()
def _insert_until(
    heights,
    r0,
    c0,
    cols,
    max_error,
    max_points,
    max_triangles,
    data_dependent,
    has_nan,
    vxy,
    tv,
    he,
    cand,
    hpos,
    key,
    heap,
    hkey,
    pending,
    is_pending,
    stack,
    changed,
    suspects,
    state,
) -> int:
    """Run greedy insertion on the given arrays until done or one of them is full.

    state: (5,) int64 nv, nt, heap size, stack depth, pending count, read on entry and written
    on return; the return value says which array to grow (see FINISHED, GROW_*). The run can be
    resumed from any return: it only returns at the top of the flip loop, before the rescan,
    or before an insertion. No array is reassigned in here, so the loop pays no reference
    counting (a reassigned array variable costs atomic updates at every merge of the loop).
    """
    nv, nt, size, sp, n_pending = state[0], state[1], state[2], state[3], state[4]
    done = max(max_error, 0.0)
    while True:
        # Restore the mesh: test every suspect edge, flipping until none is left.
        while sp > 0:
            if sp + 2 > stack.shape[0]:
                _store_state(state, nv, nt, size, sp, n_pending)
                return GROW_STACK
            sp -= 1
            # Unsigned indices: no negative-index wraparound per load.
            e = stack[np.uint64(sp)]
            f = he[np.uint64(e)]
            if f < 0:
                continue
            a = tv[np.uint64(e)]
            b = tv[np.uint64(next_edge(e))]
            p = tv[np.uint64(prev_edge(e))]
            q = tv[np.uint64(prev_edge(f))]
            if data_dependent:
                do_flip = _flip_improves(heights, r0, c0, vxy, a, b, p, q, has_nan)
            else:
                do_flip = in_circle(
                    vxy[np.uint64(2 * a)],
                    vxy[np.uint64(2 * a + 1)],
                    vxy[np.uint64(2 * b)],
                    vxy[np.uint64(2 * b + 1)],
                    vxy[np.uint64(2 * p)],
                    vxy[np.uint64(2 * p + 1)],
                    vxy[np.uint64(2 * q)],
                    vxy[np.uint64(2 * q + 1)],
                )
            if not do_flip:
                continue
            t = e // 3
            u = f // 3
            flip(tv, he, e)
            # Pending triangles keep their stale heap entry until rescanned (one sift, then).
            if not is_pending[np.uint64(t)]:
                is_pending[t] = True
                pending[n_pending] = t
                n_pending += 1
            if not is_pending[np.uint64(u)]:
                is_pending[u] = True
                pending[n_pending] = u
                n_pending += 1
            stack[sp] = 3 * t
            stack[sp + 1] = 3 * u
            sp += 2

        # Rescan the changed triangles and put them back in the heap.
        if size + n_pending > heap.shape[0]:
            _store_state(state, nv, nt, size, sp, n_pending)
            return GROW_HEAP
        for i in range(n_pending):
            t = pending[np.uint64(i)]
            is_pending[t] = False
            # Own names: unsigned values must not share a variable with the signed ones.
            e3 = np.uint64(3 * t)
            one = np.uint64(1)
            ia = np.uint64(2 * tv[e3])
            ib = np.uint64(2 * tv[e3 + one])
            ic = np.uint64(2 * tv[e3 + one + one])
            ax, ay, bx, by = vxy[ia], vxy[ia + one], vxy[ib], vxy[ib + one]
            cx, cy = vxy[ic], vxy[ic + one]
            if has_nan:
                k, ky, kx = scan_with_holes(heights, r0, c0, ax, ay, bx, by, cx, cy)
            else:
                k, ky, kx = scan_candidate(heights, r0, c0, ax, ay, bx, by, cx, cy)
            cand[np.uint64(t)] = ky * cols + kx
            key[np.uint64(t)] = k
            if k > done:
                size = heap_update(heap, hkey, hpos, size, t, k)
            else:
                size = heap_remove(heap, hkey, hpos, size, t)
        n_pending = 0

        # Stopping rules: the worst candidate is good enough, or a budget is spent.
        if size == 0 or hkey[0] <= done or 0 < max_points <= nv or 0 < max_triangles < nt + 2:
            _store_state(state, nv, nt, size, sp, n_pending)
            return FINISHED
        t = heap[0]

        # Room for one more vertex and two more triangles.
        if 2 * nv + 2 > vxy.shape[0] or nt + 2 > key.shape[0]:
            _store_state(state, nv, nt, size, sp, n_pending)
            return GROW_MESH

        # Insert the candidate: inside t (three triangles) or on one of its edges (four, or two
        # on the window border).
        p = nv
        px = cand[np.uint64(t)] % cols
        py = cand[np.uint64(t)] // cols
        vxy[2 * p] = px
        vxy[2 * p + 1] = py
        nv += 1
        # Not a literal -1: numba would compile split_edge for Literal[int](-1) as well.
        on_edge = np.int64(-1)
        for k3 in range(3):
            e = 3 * t + k3
            a = tv[np.uint64(e)]
            b = tv[np.uint64(next_edge(e))]
            if orient(vxy[2 * a], vxy[2 * a + 1], vxy[2 * b], vxy[2 * b + 1], px, py) == 0:
                on_edge = e
        n1 = nt
        n2 = nt + 1
        for k4 in range(4):
            changed[k4] = -1
            suspects[k4] = -1
        changed[0] = t
        changed[1] = n1
        if on_edge < 0:
            split_interior(tv, he, t, n1, n2, p)
            nt += 2
            changed[2] = n2
            suspects[0] = 3 * t
            suspects[1] = 3 * n1
            suspects[2] = 3 * n2
        else:
            u = he[on_edge] // 3 if he[on_edge] >= 0 else -1
            added = split_edge(tv, he, on_edge, n1, n2, p)
            nt += added
            suspects[0] = 3 * t + 2
            suspects[1] = 3 * n1 + 1
            if added == 2:
                changed[2] = u
                changed[3] = n2
                suspects[2] = 3 * u + 2
                suspects[3] = 3 * n2 + 1
        # Index loops, not iterators: an array iterator costs reference-count updates.
        for k4 in range(4):
            s = changed[k4]
            if s >= 0 and not is_pending[s]:
                is_pending[s] = True
                pending[n_pending] = s
                n_pending += 1
        for k4 in range(4):
            e = suspects[k4]
            if e >= 0:
                stack[sp] = e
                sp += 1


@njit_no_nrt()
def _mesh_figures(heights, r0, c0, vx, vy, tv, he, key, nt, has_nan):
    """(max error, sum of squared errors) of the final mesh's nt triangles.

    Loops, not key[:nt].max() / a summed array: the same values (a sequential sum in triangle
    order, like numba's array sum), without compiling numba's reductions on a cold start; and
    a kernel without the reference-counting runtime, so the call per triangle pays no atomic
    reference-count updates on ``heights``.
    """
    worst = 0.0
    for t in range(nt):
        worst = max(worst, key[t])
    # The squared errors are summed once over the final mesh, not at every rescan: the same
    # per-triangle figures (a triangle's edges keep their border or shared status while it
    # lives), for a fraction of the work.
    total = 0.0
    if not has_nan:
        for t in range(nt):
            a, b, c = tv[3 * t], tv[3 * t + 1], tv[3 * t + 2]
            # An edge point is half this triangle's when the edge is shared.
            total += triangle_sse(
                heights,
                r0,
                c0,
                vx[a],
                vy[a],
                vx[b],
                vy[b],
                vx[c],
                vy[c],
                0.5 if he[3 * t] >= 0 else 1.0,
                0.5 if he[3 * t + 1] >= 0 else 1.0,
                0.5 if he[3 * t + 2] >= 0 else 1.0,
            )
    return worst, total


@njit(cache=True)
def greedy_tin(
    heights: np.ndarray,
    r0: int,
    c0: int,
    rows: int,
    cols: int,
    max_error: float,
    max_points: int,
    max_triangles: int,
    data_dependent: bool,
    has_nan: bool,
):
    """Greedy insertion over the window heights[r0:r0+rows, c0:c0+cols] (rows, cols >= 2).

    heights: (R, C) float32/float64, NaN = nodata. max_error < 0, max_points <= 0 or
    max_triangles <= 0 disable that stopping rule (at least one must be active, or the run
    goes to full resolution).
    Returns vx, vy (n,) int32 window-local column/row of the vertices, tv (3m,) int32,
    he (3m,) int32 the triangles (orient > 0 in (column, row) space) and their twins, and the
    mesh's exact max error and sum of squared errors over the window's points (both only
    meaningful without nodata: every triangle's candidate key is the true maximum over its
    points, and each point is owned once, see ``triangle_sse``).
    """
    cap_v = 64
    cap_t = 128
    # Column and row of vertex v at 2v, 2v + 1: one cache line holds both (the flip tests and
    # rescans load the coordinates of scattered vertices).
    vxy = np.empty(2 * cap_v, dtype=np.int32)
    tv = np.empty(3 * cap_t, dtype=np.int32)
    he = np.full(3 * cap_t, -1, dtype=np.int32)
    # Candidate as y·cols + x: int32 holds it on every lattice the exact predicates allow.
    cand = np.full(cap_t, -1, dtype=np.int32)
    hpos = np.full(cap_t, -1, dtype=np.int32)
    key = np.zeros(cap_t, dtype=np.float64)
    # Only triangles still worse than the goal are in the heap (sized on its own): the others
    # are never popped, and the final maximum is taken from ``key``.
    cap_h = 128
    heap = np.empty(cap_h, dtype=np.int32)
    hkey = np.empty(cap_h, dtype=np.float64)
    pending = np.empty(cap_t, dtype=np.int32)
    is_pending = np.zeros(cap_t, dtype=np.bool_)
    stack = np.empty(64, dtype=np.int32)
    changed = np.empty(4, dtype=np.int64)
    suspects = np.empty(4, dtype=np.int64)

    # The window's corners and its two triangles, cut along the (0, 0)–(cols−1, rows−1)
    # diagonal like the grid's own cells.
    w = cols - 1
    h = rows - 1
    vxy[0], vxy[1] = 0, 0
    vxy[2], vxy[3] = w, 0
    vxy[4], vxy[5] = w, h
    vxy[6], vxy[7] = 0, h
    nv = 4
    tv[0], tv[1], tv[2] = 0, 1, 2
    tv[3], tv[4], tv[5] = 0, 2, 3
    he[2] = 3
    he[3] = 2
    nt = 2
    n_pending = 2
    pending[0] = 0
    pending[1] = 1
    is_pending[0] = True
    is_pending[1] = True
    size = 0
    sp = 0
    if data_dependent:
        stack[0] = 2
        sp = 1

    state = np.array([nv, nt, size, sp, n_pending], dtype=np.int64)
    # Run until finished, growing whichever array is full (by half, amortized O(1)). Fill values
    # are typed, not literals: ``grow`` then compiles once per array dtype.
    while True:
        status = _insert_until(
            heights,
            r0,
            c0,
            cols,
            max_error,
            max_points,
            max_triangles,
            data_dependent,
            has_nan,
            vxy,
            tv,
            he,
            cand,
            hpos,
            key,
            heap,
            hkey,
            pending,
            is_pending,
            stack,
            changed,
            suspects,
            state,
        )
        if status == FINISHED:
            break
        if status == GROW_STACK:
            stack = grow(stack, 2 * stack.shape[0], np.int32(0))
        elif status == GROW_HEAP:
            cap_h = max(cap_h + cap_h // 2, int(state[2] + state[4]))
            heap = grow(heap, cap_h, np.int32(0))
            hkey = grow(hkey, cap_h, 0.0)
        else:
            if state[0] + 1 > cap_v:
                cap_v += cap_v // 2
                vxy = grow(vxy, 2 * cap_v, np.int32(0))
            if state[1] + 2 > cap_t:
                cap_t += cap_t // 2
                tv = grow(tv, 3 * cap_t, np.int32(0))
                he = grow(he, 3 * cap_t, np.int32(-1))
                key = grow(key, cap_t, 0.0)
                cand = grow(cand, cap_t, np.int32(-1))
                hpos = grow(hpos, cap_t, np.int32(-1))
                is_pending = grow(is_pending, cap_t, np.bool_(False))
                # At most every triangle is pending at once.
                pending = grow(pending, cap_t, np.int32(0))
    nv = int(state[0])
    nt = int(state[1])
    vx = np.empty(nv, dtype=np.int32)
    vy = np.empty(nv, dtype=np.int32)
    for v in range(nv):
        vx[v] = vxy[2 * v]
        vy[v] = vxy[2 * v + 1]

    worst, total = _mesh_figures(heights, r0, c0, vx, vy, tv, he, key, nt, has_nan)
    # Views, not copies: the work arrays are freed on return, so the peak stays lower.
    return (
        vx,
        vy,
        tv[: 3 * nt],
        he[: 3 * nt],
        worst,
        total,
    )


@njit(cache=True)
def mesh_error(heights, r0, c0, rows, cols, vx, vy, tv, he):
    """Exact error of a lattice mesh over the valid data points of its window.

    Triangles with a nodata corner are not drawn. Every data point is counted once: a point on
    an edge shared by two drawn triangles belongs to the lower-numbered one, corners are exact.
    A nodata point inside (or on an edge of) a drawn triangle makes the max error infinite: the
    mesh would cover a hole.
    Returns (max error, sum of squared errors, points represented, drawn (m,) bool); the
    caller compares the count with the window's valid points (missing ones: infinite error).
    """
    nt = tv.shape[0] // 3
    drawn = np.empty(nt, dtype=np.bool_)
    for t in range(nt):
        ok = True
        for k in range(3):
            v = tv[3 * t + k]
            if np.isnan(heights[r0 + vy[v], c0 + vx[v]]):
                ok = False
        drawn[t] = ok
    vmax = 0.0
    sumsq = 0.0
    count = 0
    for t in range(nt):
        if not drawn[t]:
            continue
        a, b, c = tv[3 * t], tv[3 * t + 1], tv[3 * t + 2]
        ax, ay, bx, by, cx, cy = vx[a], vy[a], vx[b], vy[b], vx[c], vy[c]
        za = np.float64(heights[r0 + ay, c0 + ax])
        zb = np.float64(heights[r0 + by, c0 + bx])
        zc = np.float64(heights[r0 + cy, c0 + cx])
        d = float(orient(ax, ay, bx, by, cx, cy))
        gx = ((zb - za) * (cy - ay) - (zc - za) * (by - ay)) / d
        gy = ((zc - za) * (bx - ax) - (zb - za) * (cx - ax)) / d
        # A point on edge k is skipped when the drawn twin triangle with a lower id owns it.
        f0, f1, f2 = he[3 * t], he[3 * t + 1], he[3 * t + 2]
        skip0 = f0 >= 0 and drawn[f0 // 3] and f0 // 3 < t
        skip1 = f1 >= 0 and drawn[f1 // 3] and f1 // 3 < t
        skip2 = f2 >= 0 and drawn[f2 // 3] and f2 // 3 < t
        y0 = min(ay, min(by, cy))
        y1 = max(ay, max(by, cy))
        for y in range(y0, y1 + 1):
            lo, hi = row_span(ax, ay, bx, by, cx, cy, y)
            # Only the ends of a row, or a whole row along a horizontal edge, touch an edge.
            flat = (ay == by == y) or (by == cy == y) or (cy == ay == y)
            for x in range(lo, hi + 1):
                if flat or x == lo or x == hi:
                    wab = orient(ax, ay, bx, by, x, y)
                    wbc = orient(bx, by, cx, cy, x, y)
                    wca = orient(cx, cy, ax, ay, x, y)
                    zeros = (wab == 0) + (wbc == 0) + (wca == 0)
                    if zeros >= 2:
                        continue
                    if (wab == 0 and skip0) or (wbc == 0 and skip1) or (wca == 0 and skip2):
                        continue
                z = heights[r0 + y, c0 + x]
                if np.isnan(z):
                    # Nodata under a drawn triangle: the mesh would cover a hole.
                    vmax = np.inf
                    continue
                err = abs(z - (za + gx * (x - ax) + gy * (y - ay)))
                count += 1
                sumsq += err * err
                if err > vmax:
                    vmax = err
    return vmax, sumsq, count, drawn
