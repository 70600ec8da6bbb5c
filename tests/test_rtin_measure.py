"""RTIN patch errors (measured by ``kernels.rtin.extract`` as it walks the hierarchy) against a
brute-force recomputation over every grid point of the window: max and RMS of |z − mesh| at
every valid point, each point once, nodata under a drawn triangle or a valid point under none
making both infinite."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_file

import approxtree as at
from approxtree.datasets import fractal_terrain
from approxtree.geometry.grid import Grid
from approxtree.patches.lattice import grid_window
from approxtree.patches.rtin import RTINPatch, rtin_patch


def brute_errors(patch: RTINPatch) -> tuple[float, float]:
    """(max, RMS) |z − mesh| over the valid points of the patch's window, by numpy per triangle."""
    z = patch.grid.heights.astype(np.float64)
    rows, cols = z.shape
    r, c = patch.ij[:, 0].astype(np.int64), patch.ij[:, 1].astype(np.int64)
    # Per-point error: nan where no triangle covers the point yet.
    perr = np.full(z.shape, np.nan)
    yy, xx = np.mgrid[0:rows, 0:cols]
    for a, b, d in patch.tris:
        (ax, ay), (bx, by), (cx, cy) = (c[a], r[a]), (c[b], r[b]), (c[d], r[d])
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        x0, x1 = min(ax, bx, cx), max(ax, bx, cx) + 1
        y0, y1 = min(ay, by, cy), max(ay, by, cy) + 1
        px, py = xx[y0:y1, x0:x1], yy[y0:y1, x0:x1]
        w_a = (bx - px) * (cy - py) - (by - py) * (cx - px)
        w_b = (cx - px) * (ay - py) - (cy - py) * (ax - px)
        w_c = (ax - px) * (by - py) - (ay - py) * (bx - px)
        inside = (w_a * area >= 0) & (w_b * area >= 0) & (w_c * area >= 0)
        mesh = (w_a * z[ay, ax] + w_b * z[by, bx] + w_c * z[cy, cx]) / area
        e = np.abs(z[y0:y1, x0:x1] - mesh)
        # Nodata under a drawn triangle: the mesh covers a hole.
        e[np.isnan(e)] = np.inf
        box = perr[y0:y1, x0:x1]
        box[inside] = np.fmax(box[inside], e[inside])
    perr[r, c] = 0.0
    # Only the points of the patch's own window count.
    win = grid_window(patch.grid, patch.rect)
    valid = np.zeros(z.shape, dtype=bool)
    valid[win.r0 : win.r1 + 1, win.c0 : win.c1 + 1] = True
    valid &= np.isfinite(z)
    if (valid & np.isnan(perr)).any():
        return float("inf"), float("inf")
    e = perr[valid]
    return float(e.max()), float(np.sqrt(np.mean(e * e)))


def check(patch: RTINPatch) -> None:
    want_max, want_rms = brute_errors(patch)
    assert patch.error == pytest.approx(want_max, rel=1e-9, abs=1e-9)
    assert patch.rms_error == pytest.approx(want_rms, rel=1e-9, abs=1e-9)


def _cases() -> list[tuple[str, np.ndarray]]:
    rng = np.random.default_rng(5)
    noise = rng.normal(0.0, 30.0, (29, 37)).astype(np.float32)
    frac = fractal_terrain(45, seed=4, relief=300.0).heights.copy()
    holed = frac.copy()
    holed[10:17, 20:26] = np.nan
    holed[0:2, 0:3] = np.nan
    holed[40:, 31] = np.nan
    return [("noise", noise), ("fractal", frac), ("holes", holed)]


@pytest.mark.parametrize("name,z", _cases(), ids=lambda v: v if isinstance(v, str) else "")
@pytest.mark.parametrize("threshold", [0.0, 0.5, 3.0, 25.0])
def test_measured_errors_equal_brute_force(name: str, z: np.ndarray, threshold: float) -> None:
    """Noise on a 29 × 37 window (padded lattice), fractal terrain, and nodata holes."""
    grid = Grid(z)
    check(rtin_patch(grid, grid.domain, max_error=threshold))


def test_measured_errors_under_budgets_equal_brute_force() -> None:
    """The bisected threshold and the greedy refinement under a triangle budget, with holes."""
    z = _cases()[2][1]
    grid = Grid(z)
    for greedy in (False, True):
        for budget in (40, 300):
            check(rtin_patch(grid, grid.domain, max_triangles=budget, greedy=greedy))


def test_measured_errors_on_a_real_dem_with_nodata(data_dir) -> None:
    """Crater Lake: a 70 × 52 window with a nodata hole, and a sub-rectangle of the grid."""
    heights = at.open_terrain(data_file(data_dir, "scape/crater.stm")).heights
    z = np.array(heights[100:170, 140:192], dtype=np.float32)
    z[30:41, 5:12] = np.nan
    grid = Grid(z)
    for threshold in (0.5, 2.0, 10.0):
        check(rtin_patch(grid, grid.domain, max_error=threshold))
    d = grid.domain
    sub = type(d)(
        d.xmin + 0.2 * (d.xmax - d.xmin),
        d.ymin + 0.1 * (d.ymax - d.ymin),
        d.xmin + 0.7 * (d.xmax - d.xmin),
        d.ymin + 0.8 * (d.ymax - d.ymin),
    )
    check(rtin_patch(grid, sub, max_error=1.0))
