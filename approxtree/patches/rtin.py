"""RTINPatch: right-triangulated irregular network (Evans, Kirkpatrick & Townsend).

The window of the rectangle is embedded in the smallest (2^k + 1)² lattice that holds it; the
lattice points beyond the window get no height (no invented height is ever drawn: triangles
reaching past the window split until they no longer cover window points, and are then left
out). ``kernels.rtin`` computes true per-triangle errors once; extraction at a threshold is a
single pass. A point or triangle budget is met by the smallest threshold whose mesh fits:
triangles split in decreasing order of their (propagated) error, i.e. greedy refinement by
badness with the forced splits that keep the mesh free of cracks and T-junctions.
"""

from __future__ import annotations

from collections.abc import Sequence

import numba
import numpy as np

from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.kernels.rtin import extract, vertex_errors
from approxtree.kernels.rtin_greedy import greedy_rtin
from approxtree.patches.base import GeometryPatch
from approxtree.patches.lattice import Window, grid_window, require_grid
from approxtree.patches.tin import CompiledMeshArrays


def lattice_size(rows: int, cols: int) -> int:
    """s = 2^k: the smallest power of two with s + 1 >= rows and s + 1 >= cols."""
    s = 1
    while s + 1 < max(rows, cols):
        s *= 2
    return s


def _threshold(
    err: np.ndarray,
    grid: Grid,
    win: Window,
    max_error: float | None,
    max_points: int | None,
    max_triangles: int | None,
) -> float:
    """The smallest threshold meeting the budgets (bisection: counts fall as it grows)."""
    base = 0.0 if max_error is None else float(max_error)

    def fits(t: float) -> bool:
        z = grid.heights_array("building RTIN patches")
        nt, nv, *_ = extract(err, t, z, win.r0, win.c0, win.rows, win.cols, True)
        return (max_points is None or nv <= max_points) and (
            max_triangles is None or nt <= max_triangles
        )

    if (max_points is None and max_triangles is None) or fits(base):
        return base
    # Only stored errors matter as thresholds: bisect over their sorted distinct values.
    values = np.unique(err[np.isfinite(err) & (err > base)])
    if values.size == 0 or not fits(float(values[-1])):
        return float("inf")
    lo, hi = -1, values.size - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if fits(float(values[mid])):
            hi = mid
        else:
            lo = mid
    return float(values[hi])


#: Lattices with fewer points than this compute their errors on one thread: each of the ~60
#: parallel levels costs a thread hand-off, more than the level's work on small windows.
PARALLEL_MIN_POINTS = 2049 * 2049


def _vertex_errors(grid: Grid, win: Window, size: int, cut: float) -> np.ndarray:
    """``kernels.rtin.vertex_errors`` of the window, threaded only for large lattices.

    cut: the one threshold the table will serve (entries past it are not exact), or inf.
    """
    threads = numba.get_num_threads()
    if (size + 1) ** 2 < PARALLEL_MIN_POINTS:
        numba.set_num_threads(1)
    try:
        z = grid.heights_array("building RTIN patches")
        return vertex_errors(z, win.r0, win.c0, win.rows, win.cols, size, win.has_nan, cut)
    finally:
        numba.set_num_threads(threads)


def rtin_patch(
    grid: Grid,
    rect: Rect,
    max_error: float | None = None,
    max_points: int | None = None,
    max_triangles: int | None = None,
    greedy: bool = False,
) -> RTINPatch:
    """The RTIN of one rectangle meeting the error goal and the budgets.

    greedy: meet a point or triangle budget by greedy refinement (``kernels.rtin_greedy``)
    instead of the smallest fitting threshold of the precomputed error hierarchy.
    """
    win = grid_window(grid, rect)
    size = lattice_size(win.rows, win.cols)
    if greedy and (max_points is not None or max_triangles is not None):
        # A budget: greedy refinement by badness (worst leaf first, forced splits included).
        split = greedy_rtin(
            grid.heights_array("building RTIN patches"),
            win.r0,
            win.c0,
            win.rows,
            win.cols,
            size,
            -1.0 if max_error is None else float(max_error),
            0 if max_points is None else int(max_points),
            0 if max_triangles is None else int(max_triangles),
            win.has_nan,
        )
        return RTINPatch.from_extract(grid, rect, win, split, 0.5)
    # One threshold known beforehand (no budget): the table need only be exact up to it.
    budget = max_points is not None or max_triangles is not None
    cut = float(max_error) if max_error is not None and not budget else np.inf
    err = _vertex_errors(grid, win, size, cut)
    t = _threshold(err, grid, win, max_error, max_points, max_triangles)
    return RTINPatch.from_extract(grid, rect, win, err, t)


class RTINPatch(CompiledMeshArrays):
    """RTIN of a Grid window: stores (row, col) vertex indices and triangles."""

    kind = "rtin"

    @classmethod
    def from_extract(
        cls, grid: Grid, rect: Rect, win: Window, err: np.ndarray, threshold: float
    ) -> RTINPatch:
        """The patch of ``kernels.rtin.extract`` at threshold over the (s+1, s+1) table err.

        extract emits valid vertices and drawn triangles only, and measures the mesh as it
        goes (exact max and RMS over every valid point): the arrays are kept as they are,
        ij (n, 2) int32 grid (row, col), triangles a view of tv.
        """
        z = grid.heights_array("building RTIN patches")
        _, nv, ij, tv, vmax, sumsq, count = extract(
            err, threshold, z, win.r0, win.c0, win.rows, win.cols, False
        )
        # Every valid point is a vertex (exact) or measured once in a drawn triangle; one
        # left out (under no drawn triangle) makes both figures infinite.
        complete = count + nv >= win.count
        error = float(vmax) if complete else float("inf")
        rms = float(np.sqrt(sumsq / win.count)) if win.count else 0.0
        if not complete:
            rms = float("inf")
        return cls(grid, rect, ij, tv.reshape(-1, 3), error, rms, win.z_range, win.count)

    @classmethod
    def build_many(
        cls,
        terrain: GeometryData,
        rects: Sequence[Rect],
        max_points: int,
        epsilon: float = 0.0,
    ) -> list[GeometryPatch]:
        grid = require_grid(terrain, cls.kind)
        return [rtin_patch(grid, r, epsilon, max_points) for r in rects]

    @classmethod
    def approximate(
        cls,
        terrain: GeometryData,
        max_error: float | None,
        max_points: int | None,
        max_triangles: int | None,
        data_dependent: bool = False,
    ) -> GeometryPatch:
        return approximate_rtin(terrain, max_error, max_points, max_triangles)


def approximate_rtin(
    terrain: GeometryData,
    max_error: float | None,
    max_points: int | None,
    max_triangles: int | None,
) -> GeometryPatch:
    """The RTIN of a whole grid (see ``patches.approximate``)."""
    grid = require_grid(terrain, "rtin")
    return rtin_patch(grid, grid.domain, max_error, max_points, max_triangles, greedy=True)
