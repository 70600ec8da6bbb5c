"""The greedy TIN's triangle scans against their definition, to the last bit.

``scan_candidate`` and ``triangle_sse`` answer the smallest triangles (twice the area 1 or 2,
by Pick's theorem) without walking rows; these tests recompute both figures by the plain row
scan they stand for — every lattice point of the closed triangle, the same float64 arithmetic
in the same order — and require identical values, on small triangles of every size.
"""

from __future__ import annotations

import numpy as np
import pytest

from approxtree.kernels.tin_scan import scan_candidate, triangle_sse


def _orient(ax: int, ay: int, bx: int, by: int, px: int, py: int) -> int:
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


def _plane(za: float, zb: float, zc: float, a, b, c) -> tuple[float, float]:
    (ax, ay), (bx, by), (cx, cy) = a, b, c
    d = float(_orient(ax, ay, bx, by, cx, cy))
    gx = ((zb - za) * (cy - ay) - (zc - za) * (by - ay)) / d
    gy = ((zc - za) * (bx - ax) - (zb - za) * (cx - ax)) / d
    return gx, gy


def _rows(a, b, c) -> list[tuple[int, int, int]]:
    """(y, lo, hi) of every row of the closed triangle holding a lattice point."""
    xs, ys = (a[0], b[0], c[0]), (a[1], b[1], c[1])
    out = []
    for y in range(min(ys), max(ys) + 1):
        inside = [
            x
            for x in range(min(xs), max(xs) + 1)
            if _orient(*a, *b, x, y) >= 0 and _orient(*b, *c, x, y) >= 0
            if _orient(*c, *a, x, y) >= 0
        ]
        if inside:
            out.append((y, inside[0], inside[-1]))
    return out


def reference_candidate(h: np.ndarray, a, b, c) -> tuple[float, int, int]:
    """Largest |z − plane| over the non-corner points, row by row from each row's first point."""
    za, zb, zc = (float(h[p[1], p[0]]) for p in (a, b, c))
    gx, gy = _plane(za, zb, zc, a, b, c)
    best, bx, by = -1.0, -1, -1
    for y, lo, hi in _rows(a, b, c):
        base = za + gy * (y - a[1]) + gx * (lo - a[0])
        for i in range(hi - lo + 1):
            e = abs(float(h[y, lo + i]) - (base + gx * i))
            if e > best and (lo + i, y) not in (a, b, c):
                best, bx, by = e, lo + i, y
    return best, by, bx


def reference_sse(h: np.ndarray, a, b, c, w: tuple[float, float, float]) -> float:
    """The owned sum of squared errors: each row summed from its first point, a row along a
    horizontal edge weighted as that edge, else the ends' unowned shares taken back off."""
    za, zb, zc = (float(h[p[1], p[0]]) for p in (a, b, c))
    gx, gy = _plane(za, zb, zc, a, b, c)
    edges = ((a, b), (b, c), (c, a))

    def weight(x: int, y: int) -> float:
        on = [_orient(*u, *v, x, y) == 0 for u, v in edges]
        if sum(on) >= 2:
            return 0.0
        return next((w[k] for k in range(3) if on[k]), 1.0)

    sse = 0.0
    for y, lo, hi in _rows(a, b, c):
        base = za + gy * (y - a[1]) + gx * (lo - a[0])
        s = 0.0
        for i in range(hi - lo + 1):
            e = abs(float(h[y, lo + i]) - (base + gx * i))
            s += e * e
        flat = [u[1] == v[1] == y for u, v in edges]
        if any(flat):
            s *= w[flat.index(True)]
        else:
            e = abs(float(h[y, lo]) - base)
            s -= (1.0 - weight(lo, y)) * e * e
            if hi > lo:
                e = abs(float(h[y, hi]) - (base + gx * (hi - lo)))
                s -= (1.0 - weight(hi, y)) * e * e
        sse += s
    return max(sse, 0.0)


def small_triangles(rng: np.random.Generator, n: int, size: int):
    """n counter-clockwise lattice triangles with corners in [0, size)², sorted by area."""
    out = []
    while len(out) < n:
        p = rng.integers(0, size, (3, 2))
        a, b, c = (tuple(int(v) for v in q) for q in p)
        o = _orient(*a, *b, *c)
        if o < 0:
            b, c = c, b
        if o != 0:
            out.append((a, b, c))
    return sorted(out, key=lambda t: abs(_orient(*t[0], *t[1], *t[2])))


@pytest.mark.parametrize(
    ("dtype", "integral"), [(np.float32, True), (np.float32, False), (np.float64, False)]
)
def test_scans_of_small_triangles_match_the_row_scan_bit_for_bit(dtype, integral):
    rng = np.random.default_rng(7)
    # Heights far from zero with fractions (round-off depends on where a row starts), and
    # integer heights like SRTM's (ties, planes that are exact).
    h = rng.normal(2000.0, 300.0, (12, 12))
    h = (h.round() if integral else h).astype(dtype)
    tris = small_triangles(rng, 600, 6)
    areas = {abs(_orient(*a, *b, *c)) for a, b, c in tris}
    # Twice the area 1 and 2 (the shortcuts) and larger ones (the row walks) all occur.
    assert {1, 2, 3, 4} <= areas
    for a, b, c in tris:
        got = scan_candidate(h, 0, 0, a[0], a[1], b[0], b[1], c[0], c[1])
        assert tuple(got) == reference_candidate(h, a, b, c), (a, b, c)
        for w in ((0.5, 0.5, 0.5), (1.0, 0.5, 1.0), (0.5, 1.0, 1.0)):
            sse = triangle_sse(h, 0, 0, a[0], a[1], b[0], b[1], c[0], c[1], *w)
            assert sse == reference_sse(h, a, b, c, w), (a, b, c, w)
