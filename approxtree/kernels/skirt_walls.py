"""A patch's border edges and the skirt walls hung from them, in one pass over its triangles.

The per-tile work of ``patches.skirts.add_skirts`` (called once per node by the renderer's
loads and by every 3D Tiles writer): the directed edges used by one triangle only (an
open-addressing table of undirected edge keys instead of numpy's sort-based ``unique``),
those on the node's rectangle, those on the domain's border, then the wall vertices and
triangles; and ``merge_bottoms``' grouping of coincident wall bottoms. Results are the same
arrays, in the same order, as the numpy versions these replaced.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Fibonacci hashing's multiplier (2^64 / golden ratio).
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


@njit(cache=True)
def border_edges(triangles):
    """(k, 2) int64 directed edges of ``triangles`` (m, 3) int64 used by exactly one triangle,
    in the order of the directed edges (0, 1) of every triangle, then (1, 2), then (2, 0)."""
    m = triangles.shape[0]
    n = np.int64(0)
    for i in range(m):
        for s in range(3):
            if triangles[i, s] + 1 > n:
                n = triangles[i, s] + 1
    # Undirected key lo · n + hi, counted in a table at most half full.
    bits = 1
    while (1 << bits) < 6 * m + 2:
        bits += 1
    size = 1 << bits
    mask = size - 1
    shift = np.uint64(64 - bits)
    keys = np.full(size, -1, dtype=np.int64)
    counts = np.zeros(size, dtype=np.int32)
    slots = np.empty(3 * m, dtype=np.int64)
    for s in range(3):
        for i in range(m):
            a = triangles[i, s]
            b = triangles[i, (s + 1) % 3]
            key = min(a, b) * n + max(a, b)
            h = np.int64((np.uint64(key) * _GOLDEN) >> shift)
            while keys[h] != -1 and keys[h] != key:
                h = (h + 1) & mask
            keys[h] = key
            counts[h] += 1
            slots[s * m + i] = h
    k = 0
    for e in range(3 * m):
        if counts[slots[e]] == 1:
            k += 1
    out = np.empty((k, 2), dtype=np.int64)
    j = 0
    for s in range(3):
        for i in range(m):
            if counts[slots[s * m + i]] == 1:
                out[j, 0] = triangles[i, s]
                out[j, 1] = triangles[i, (s + 1) % 3]
                j += 1
    return out


@njit(cache=True)
def on_rect(vertices, edges, rect):
    """(k,) bool: edges (k, 2) of ``vertices`` (n, 3) float64 whose two ends lie on one side
    of ``rect`` (4,) float64 (xmin, ymin, xmax, ymax), within 1e-9 of its larger side."""
    xmin, ymin, xmax, ymax = rect[0], rect[1], rect[2], rect[3]
    tol = 1e-9 * max(xmax - xmin, ymax - ymin, 1e-300)
    out = np.zeros(edges.shape[0], dtype=np.bool_)
    for e in range(edges.shape[0]):
        a = edges[e, 0]
        b = edges[e, 1]
        ax, ay, bx, by = vertices[a, 0], vertices[a, 1], vertices[b, 0], vertices[b, 1]
        out[e] = (
            (abs(ax - xmin) <= tol and abs(bx - xmin) <= tol)
            or (abs(ax - xmax) <= tol and abs(bx - xmax) <= tol)
            or (abs(ay - ymin) <= tol and abs(by - ymin) <= tol)
            or (abs(ay - ymax) <= tol and abs(by - ymax) <= tol)
        )
    return out


@njit(cache=True)
def hang_walls(vertices, triangles, edges, outer, depth, base):
    """(vertices (n + 2k, 3), triangles (m + 2k, 3), flags (n + 2k,) float32) of the patch
    ``vertices`` (n, 3) float64, ``triangles`` (m, 3) int64 with a wall below each of the
    directed ``edges`` (k, 2): bottoms a' (k of them) then b' (k), at ``base`` for ``outer``
    (k,) bool edges, else at max(z − depth, base); walls (a', b', b) (k) then (a', b, a) (k)."""
    n = vertices.shape[0]
    m = triangles.shape[0]
    k = edges.shape[0]
    v = np.empty((n + 2 * k, 3), dtype=np.float64)
    for i in range(n):
        for c in range(3):
            v[i, c] = vertices[i, c]
    for e in range(k):
        for half in range(2):
            top = edges[e, half]
            row = n + half * k + e
            v[row, 0] = vertices[top, 0]
            v[row, 1] = vertices[top, 1]
            v[row, 2] = base if outer[e] else max(vertices[top, 2] - depth, base)
    t = np.empty((m + 2 * k, 3), dtype=np.int64)
    for i in range(m):
        for c in range(3):
            t[i, c] = triangles[i, c]
    for e in range(k):
        a2 = n + e
        b2 = a2 + k
        t[m + e, 0], t[m + e, 1], t[m + e, 2] = a2, b2, edges[e, 1]
        t[m + k + e, 0], t[m + k + e, 1], t[m + k + e, 2] = a2, edges[e, 1], edges[e, 0]
    flags = np.zeros(n + 2 * k, dtype=np.float32)
    for i in range(n, n + 2 * k):
        flags[i] = 1.0
    return v, t, flags


@njit(cache=True)
def merge_bottoms(heights, tops, top_count):
    """(keep (j,) int64, owner (k,) int64) of k wall bottoms of ``heights`` (k,) float64
    hanging from patch vertices ``tops`` (k,) int64 < ``top_count``: the first bottom of each
    group of equal (top, height), in order, and each bottom's group as an index into keep."""
    k = tops.shape[0]
    # Bottoms kept so far per top vertex, as linked lists (a vertex has a few walls).
    head = np.full(top_count, -1, dtype=np.int64)
    nxt = np.full(k, -1, dtype=np.int64)
    owner = np.empty(k, dtype=np.int64)
    keep = np.empty(k, dtype=np.int64)
    count = 0
    for j in range(k):
        t = tops[j]
        found = -1
        c = head[t]
        while c != -1:
            if heights[keep[c]] == heights[j]:
                found = c
                break
            c = nxt[c]
        if found == -1:
            keep[count] = j
            nxt[count] = head[t]
            head[t] = count
            found = count
            count += 1
        owner[j] = found
    return keep[:count].copy(), owner


@njit(cache=True)
def skirt_mesh(vertices, triangles, rect, domain, depth, base):
    """``hang_walls`` of the border edges of ``triangles`` (m, 3) int64 that lie on ``rect``
    (4,) float64 (all of them when rect is empty), those on ``domain`` (4,) (none when empty)
    being outer: at ``base``, or left without a wall when base is infinite. vertices: (n, 3)
    float64. One call for ``patches.skirts.add_skirts``."""
    edges = border_edges(triangles)
    if rect.shape[0] == 4 and edges.shape[0]:
        edges = edges[on_rect(vertices, edges, rect)]
    outer = np.zeros(edges.shape[0], dtype=np.bool_)
    if domain.shape[0] == 4 and edges.shape[0]:
        outer = on_rect(vertices, edges, domain)
        if not np.isfinite(base):
            inner = ~outer
            edges = edges[inner]
            outer = outer[inner]
    return hang_walls(vertices, triangles, edges, outer, depth, base)


@njit(cache=True)
def merge_mesh(vertices, triangles, tops):
    """(vertices (n', 3), triangles (m, 3), tops (k',)) of a patch with wall bottoms (the last
    k of ``vertices`` (n, 3) float64, hanging from patch vertices ``tops`` (k,) int64) whose
    bottoms of equal top and height are made one (``merge_bottoms``; the kept ones in
    order). triangles: (m, 3) int64."""
    k = tops.shape[0]
    top = vertices.shape[0] - k
    keep, owner = merge_bottoms(vertices[top:, 2].copy(), tops, top)
    out = np.empty((top + keep.shape[0], 3), dtype=np.float64)
    for i in range(top):
        for c in range(3):
            out[i, c] = vertices[i, c]
    for j in range(keep.shape[0]):
        for c in range(3):
            out[top + j, c] = vertices[top + keep[j], c]
    tris = np.empty_like(triangles)
    for i in range(triangles.shape[0]):
        for c in range(3):
            v = triangles[i, c]
            tris[i, c] = v if v < top else top + owner[v - top]
    new_tops = np.empty(keep.shape[0], dtype=np.int64)
    for j in range(keep.shape[0]):
        new_tops[j] = tops[keep[j]]
    return out, tris, new_tops
