"""Robust geometric predicates on float64 coordinates (Shewchuk's filters, exact fallback).

``orient2d`` returns a value whose sign is always the exact sign of the orientation
determinant: a float evaluation is trusted when it exceeds its rounding-error bound, otherwise
the determinant is evaluated exactly as a floating-point expansion (two-sum / two-product,
Dekker's splitter). ``in_circle_sure`` answers "certainly inside" from the filtered float
evaluation only: a near-cocircular quadruple answers False, which keeps an edge instead of
flipping it (the mesh stays valid and the flip loop terminates; it is Delaunay except where
both diagonals are Delaunay within rounding).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_EPS = 2.0**-53
#: Error bound factors of the float evaluations (Shewchuk 1997, Table 1).
_CCW_BOUND = (3.0 + 16.0 * _EPS) * _EPS
_ICC_BOUND = (10.0 + 96.0 * _EPS) * _EPS
#: Dekker's splitter 2^27 + 1 for float64.
_SPLITTER = 134217729.0


@njit(cache=True, inline="always")
def _two_sum(a: float, b: float) -> tuple[float, float]:
    x = a + b
    bv = x - a
    av = x - bv
    return x, (a - av) + (b - bv)


@njit(cache=True, inline="always")
def _two_diff(a: float, b: float) -> tuple[float, float]:
    x = a - b
    bv = a - x
    av = x + bv
    return x, (a - av) + (bv - b)


@njit(cache=True, inline="always")
def _split(a: float) -> tuple[float, float]:
    c = _SPLITTER * a
    big = c - a
    hi = c - big
    return hi, a - hi


@njit(cache=True, inline="always")
def _two_product(a: float, b: float) -> tuple[float, float]:
    x = a * b
    ahi, alo = _split(a)
    bhi, blo = _split(b)
    err = x - ahi * bhi - alo * bhi - ahi * blo
    return x, alo * blo - err


@njit(cache=True)
def orient2d_exact(ax, ay, bx, by, px, py) -> float:
    """(bx − ax)(py − ay) − (by − ay)(px − ax) evaluated exactly as an expansion; returns its
    largest component: the exact sign, and the value to about one ulp."""
    terms = np.empty(16)
    u1, u0 = _two_diff(bx, ax)
    v1, v0 = _two_diff(py, ay)
    s1, s0 = _two_diff(by, ay)
    w1, w0 = _two_diff(px, ax)
    k = 0
    # Products of two 2-term expansions: four exact two-products each, the second negated.
    for a in (u1, u0):
        for b in (v1, v0):
            hi, lo = _two_product(a, b)
            terms[k] = hi
            terms[k + 1] = lo
            k += 2
    for a in (s1, s0):
        for b in (w1, w0):
            hi, lo = _two_product(a, b)
            terms[k] = -hi
            terms[k + 1] = -lo
            k += 2
    # Grow a nonoverlapping expansion term by term; its largest nonzero component has the sign
    # of the exact sum.
    h = np.zeros(16)
    m = 0
    for i in range(16):
        q = terms[i]
        for j in range(m):
            q, h[j] = _two_sum(q, h[j])
        h[m] = q
        m += 1
    for j in range(m - 1, -1, -1):
        if h[j] != 0.0:
            return h[j]
    return 0.0


@njit(cache=True, inline="always")
def orient2d(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> float:
    """Twice the signed area of (a, b, p), with the exact sign: > 0 when p is left of a→b."""
    left = (bx - ax) * (py - ay)
    right = (by - ay) * (px - ax)
    det = left - right
    bound = _CCW_BOUND * (abs(left) + abs(right))
    if det > bound or -det > bound:
        return det
    return orient2d_exact(ax, ay, bx, by, px, py)


@njit(cache=True, inline="always")
def in_circle_sure(ax, ay, bx, by, cx, cy, dx, dy) -> bool:
    """True when d certainly lies strictly inside the circumcircle of (a, b, c), which must be
    counter-clockwise; False when it lies outside, on, or too near the circle to tell."""
    adx = ax - dx
    ady = ay - dy
    bdx = bx - dx
    bdy = by - dy
    cdx = cx - dx
    cdy = cy - dy
    bc = bdx * cdy - cdx * bdy
    ca = cdx * ady - adx * cdy
    ab = adx * bdy - bdx * ady
    alift = adx * adx + ady * ady
    blift = bdx * bdx + bdy * bdy
    clift = cdx * cdx + cdy * cdy
    det = alift * bc + blift * ca + clift * ab
    permanent = (
        (abs(bdx * cdy) + abs(cdx * bdy)) * alift
        + (abs(cdx * ady) + abs(adx * cdy)) * blift
        + (abs(adx * bdy) + abs(bdx * ady)) * clift
    )
    # The bound covers the rounding of the differences too (Shewchuk's errbound A); an
    # uncertain answer keeps the edge.
    return det > _ICC_BOUND * permanent
