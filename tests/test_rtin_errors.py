"""RTIN error hierarchy (kernels.rtin.vertex_errors) against a brute-force recomputation: every
stored error is the exact max |z − plane| over every grid point of the triangle (not only its
hypotenuse midpoint), maxed over its descendants, rounded up to float32."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_file

import approxtree as at
from approxtree.kernels.rtin import vertex_errors


def brute_hierarchy(z: np.ndarray) -> np.ndarray:
    """E (n, n) float64 of the (n = 2^k + 1)² lattice z by recursion over every triangle."""
    n = z.shape[0]
    s = n - 1
    yy, xx = np.mgrid[0:n, 0:n]
    out = np.zeros((n, n))

    def own(a, b, c) -> float:
        # The plane through the corners, evaluated at every point of the closed triangle.
        (ax, ay), (bx, by), (cx, cy) = a, b, c
        d = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if d < 0:
            (bx, by), (cx, cy) = (cx, cy), (bx, by)
            d = -d
        x0, x1 = min(ax, bx, cx), max(ax, bx, cx) + 1
        y0, y1 = min(ay, by, cy), max(ay, by, cy) + 1
        px, py = xx[y0:y1, x0:x1], yy[y0:y1, x0:x1]
        w_a = (bx - px) * (cy - py) - (by - py) * (cx - px)
        w_b = (cx - px) * (ay - py) - (cy - py) * (ax - px)
        w_c = (ax - px) * (by - py) - (ay - py) * (bx - px)
        inside = (w_a >= 0) & (w_b >= 0) & (w_c >= 0)
        corner = (w_a == d) | (w_b == d) | (w_c == d)
        za, zb, zc = z[ay, ax], z[by, bx], z[cy, cx]
        plane = (w_a * za + w_b * zb + w_c * zc) / d
        e = np.abs(z[y0:y1, x0:x1] - plane)[inside & ~corner]
        return float(e.max()) if e.size else 0.0

    # Every triangle with a lattice hypotenuse midpoint m: (m, own error, children's midpoints).
    tris = []

    def visit(a, left, right) -> None:
        m = _mid(left, right)
        if m is None:
            return
        kids = [k for k in (_mid(left, a), _mid(a, right)) if k is not None]
        tris.append((m, own(a, left, right), kids))
        visit(m, left, a)
        visit(m, a, right)

    visit((s, 0), (0, 0), (s, s))
    visit((0, s), (s, s), (0, 0))
    # E[m]: max of the own errors of both triangles on m and of E at their children's
    # midpoints (which hold their neighbours too), up to a fixed point.
    changed = True
    while changed:
        changed = False
        for m, e, kids in tris:
            v = max([e] + [out[k[1], k[0]] for k in kids])
            if v > out[m[1], m[0]]:
                out[m[1], m[0]] = v
                changed = True
    return out


def _mid(u, v):
    """The lattice midpoint of u–v, or None."""
    if (u[0] + v[0]) % 2 or (u[1] + v[1]) % 2:
        return None
    return ((u[0] + v[0]) // 2, (u[1] + v[1]) // 2)


def check_against_brute(z: np.ndarray) -> None:
    n = z.shape[0]
    err = vertex_errors(z, 0, 0, n, n, n - 1, False, np.inf)
    want = brute_hierarchy(z.astype(np.float64))
    scale = 1e-9 * max(1.0, float(np.abs(z).max()))
    # Upper bounds (rounded up to float32), and tight: within float32 rounding of the truth.
    assert (err >= want - scale).all()
    assert (err <= want * (1 + 3e-7) + scale).all()


@pytest.mark.parametrize("n", [9, 17, 33])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_errors_equal_brute_force_on_random_lattices(n: int, seed: int) -> None:
    """White noise: the worst point of a triangle is almost never its hypotenuse midpoint."""
    z = np.random.default_rng(seed).normal(0.0, 50.0, (n, n)).astype(np.float32)
    check_against_brute(z)


def test_errors_equal_brute_force_on_a_real_dem(data_dir) -> None:
    """Crater Lake: a 65² corner and a 65² window inside it."""
    heights = at.open_terrain(data_file(data_dir, "scape/crater.stm")).heights
    for r0, c0 in ((0, 0), (100, 140)):
        check_against_brute(np.ascontiguousarray(heights[r0 : r0 + 65, c0 : c0 + 65]))


@pytest.mark.parametrize("n", [17, 33, 65])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cut_table_splits_as_the_exact_table(n: int, seed: int) -> None:
    """A table for one threshold puts every entry on the exact table's side of it, bounds the
    brute-force error below it, and extracts the same mesh with the same measured error."""
    from approxtree.kernels.rtin import extract

    rng = np.random.default_rng(seed)
    # Smooth relief plus noise: bounds decide some entries, scans others.
    yy, xx = np.mgrid[0:n, 0:n] / (n - 1)
    z = (300 * np.sin(3 * xx + seed) * np.cos(2 * yy) + rng.normal(0.0, 2.0, (n, n))).astype(
        np.float32
    )
    exact = vertex_errors(z, 0, 0, n, n, n - 1, False, np.inf)
    want = brute_hierarchy(z.astype(np.float64))
    for cut in [0.5, 2.0, 5.0, 20.0, *np.quantile(exact[exact > 0], [0.3, 0.7, 0.95])]:
        cut = float(cut)
        err = vertex_errors(z, 0, 0, n, n, n - 1, False, cut)
        assert np.array_equal(err > cut, exact > cut)
        below = err <= cut
        assert (err[below] >= want[below] - 1e-9 * float(np.abs(z).max())).all()
        got = extract(err, cut, z, 0, 0, n, n, False)
        ref = extract(exact, cut, z, 0, 0, n, n, False)
        for a, b in zip(got, ref, strict=True):
            assert np.array_equal(a, b)
