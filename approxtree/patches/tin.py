"""GridTINPatch: greedy insertion TIN (Garland & Heckbert) on grids.

The patch runs ``kernels.greedy_tin`` over the window of its rectangle: vertices are
grid points of the window (so vertices on the node border are data points of that border),
nodata stays out of the mesh (triangles never span a hole once refinement is done). Scattered
points have ``patches.tin_points``; ``patches.table`` says which class builds ``tin`` on which
data type.

Stored: (row, col) grid indices of the vertices, and the triangles.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from approxtree.errors import UnsupportedStrategyError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.kernels._jit import readonly
from approxtree.kernels.greedy_tin import greedy_tin
from approxtree.kernels.tin_mesh import grid_vertices, wide_triangles
from approxtree.patches.base import GeometryPatch
from approxtree.patches.lattice import LatticePatch, Window, grid_window, require_grid


def grid_tin(
    grid: Grid,
    win: Window,
    max_error: float | None = None,
    max_points: int | None = None,
    max_triangles: int | None = None,
    data_dependent: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float]:
    """Greedy insertion over one window: (vx, vy, tv, he, max error, sum of squared errors)
    window-local, see ``greedy_tin`` (the two figures only hold without nodata)."""
    if win.rows < 2 or win.cols < 2:
        raise UnsupportedStrategyError(
            f"A TIN needs a window of at least 2 × 2 grid points, got {win.rows} × {win.cols}."
        )
    # Read-only view: in-memory and windowed (read-only) heights share one compiled signature.
    return greedy_tin(
        readonly(grid.heights_array("building TIN patches")),
        win.r0,
        win.c0,
        win.rows,
        win.cols,
        -1.0 if max_error is None else float(max_error),
        0 if max_points is None else int(max_points),
        0 if max_triangles is None else int(max_triangles),
        bool(data_dependent),
        bool(win.has_nan),
    )


class CompiledMeshArrays(LatticePatch):
    """A LatticePatch whose world mesh arrays come from one compiled pass each (the same
    values as ``LatticePatch``'s numpy gathers, without their widened index temporaries)."""

    @property
    def vertices(self) -> np.ndarray:
        g = self.grid
        h = g.heights
        if not isinstance(h, np.ndarray):
            return super().vertices
        return grid_vertices(
            readonly(self.ij, np.int32),
            readonly(g.x_coords, np.float64),
            readonly(g.y_coords, np.float64),
            readonly(h),
        )

    @property
    def triangles(self) -> np.ndarray:
        # Index space is (col, row); a north-up transform mirrors it, so flip to stay CCW.
        flip = bool(self.grid.transform.a * self.grid.transform.e < 0)
        return wide_triangles(readonly(self.tris, np.int32), flip)


class GridTINPatch(CompiledMeshArrays):
    """The TIN of one window of a Grid (vertices are grid points)."""

    kind = "tin"

    @classmethod
    def from_greedy(
        cls,
        grid: Grid,
        rect: Rect,
        win: Window,
        result: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float],
    ) -> LatticePatch:
        """The patch of a ``grid_tin`` result.

        Without nodata the greedy run already measured its mesh exactly (every triangle's key
        is its true maximum, every point's squared error is summed once), so no second pass
        over the window is needed; with nodata the mesh is measured afresh.
        """
        vx, vy, tv, he, worst, sse = result
        if win.has_nan:
            return cls.from_window_mesh(grid, rect, win, vx, vy, tv, he)
        ij = np.empty((len(vx), 2), dtype=np.int32)
        ij[:, 0] = vy
        ij[:, 0] += win.r0
        ij[:, 1] = vx
        ij[:, 1] += win.c0
        rms = float(np.sqrt(sse / win.count))
        return cls(grid, rect, ij, tv.reshape(-1, 3), worst, rms, win.z_range, win.count)

    @classmethod
    def build_many(
        cls, terrain: GeometryData, rects: Sequence[Rect], max_points: int, epsilon: float = 0.0
    ) -> list[GeometryPatch]:
        # One greedy run per window (tree nodes use Delaunay flips, not Algorithm IV).
        grid = require_grid(terrain, cls.kind)
        out: list[GeometryPatch] = []
        for rect in rects:
            win = grid_window(grid, rect)
            result = grid_tin(grid, win, epsilon, max_points)
            out.append(cls.from_greedy(grid, rect, win, result))
        return out

    @classmethod
    def approximate(
        cls,
        terrain: GeometryData,
        max_error: float | None,
        max_points: int | None,
        max_triangles: int | None,
        data_dependent: bool = False,
    ) -> GeometryPatch:
        """The greedy TIN of a whole grid (see ``patches.approximate``)."""
        grid = require_grid(terrain, cls.kind)
        rect = grid.domain
        win = grid_window(grid, rect)
        result = grid_tin(grid, win, max_error, max_points, max_triangles, data_dependent)
        return cls.from_greedy(grid, rect, win, result)
