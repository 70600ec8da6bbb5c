"""TINPatch: greedy insertion TIN (Garland & Heckbert), on grids and on scattered points.

On a Grid the patch runs ``kernels.greedy_tin`` over the window of its rectangle: vertices are
grid points of the window (so vertices on the node border are data points of that border),
nodata stays out of the mesh (triangles never span a hole once refinement is done). On a
TIN / TINPointSet the data points are scattered: ``patches.tin_points`` runs
``kernels.greedy_points`` (per-triangle buckets of input points) over each rectangle's points.

Stored: (row, col) grid indices or point indices of the vertices, and the triangles.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from approxtree.errors import UnsupportedStrategyError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.geometry.refinement import GridRefinement
from approxtree.geometry.tin import TIN
from approxtree.kernels._jit import readonly
from approxtree.kernels.greedy_tin import greedy_tin
from approxtree.patches.base import GeometryPatch
from approxtree.patches.lattice import LatticePatch, Window, grid_window


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


class GridTINPatch(LatticePatch):
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
        return TINPatch.build_many(terrain, rects, max_points, epsilon)


class TINPatch(GeometryPatch):
    """Greedy insertion TIN: a ``GridTINPatch`` on grids, a ``PointTINPatch`` on point sets."""

    kind = "tin"
    #: Algorithm IV (data-dependent flips) instead of Delaunay; off for tree nodes.
    data_dependent = False

    @classmethod
    def build_many(
        cls,
        terrain: GeometryData,
        rects: Sequence[Rect],
        max_points: int,
        epsilon: float = 0.0,
    ) -> list[GeometryPatch]:
        if isinstance(terrain, GridRefinement):
            from approxtree.patches.refined import RefinedTINPatch

            return RefinedTINPatch.build_many(terrain, rects, max_points, epsilon)
        if isinstance(terrain, TIN):
            from approxtree.patches.tin_points import PointTINPatch

            # Scattered points: every rectangle of the level in one kernel call.
            return list(PointTINPatch.build_points(terrain, rects, max_points, epsilon))
        out: list[GeometryPatch] = []
        for rect in rects:
            if isinstance(terrain, Grid):
                win = grid_window(terrain, rect)
                result = grid_tin(
                    terrain, win, epsilon, max_points, data_dependent=cls.data_dependent
                )
                out.append(GridTINPatch.from_greedy(terrain, rect, win, result))
            else:
                raise UnsupportedStrategyError(
                    f"The tin strategy needs a Grid, TIN, TINPointSet or GridRefinement, got a "
                    f"{type(terrain).__name__}."
                )
        return out

    @classmethod
    def from_record(
        cls, terrain: GeometryData, rect: Rect, record: dict[str, np.ndarray]
    ) -> GeometryPatch:
        if isinstance(terrain, Grid):
            return GridTINPatch.from_record(terrain, rect, record)
        if isinstance(terrain, GridRefinement):
            from approxtree.patches.refined import RefinedTINPatch

            return RefinedTINPatch.from_record(terrain, rect, record)
        from approxtree.patches.tin_points import PointTINPatch

        return PointTINPatch.from_record(terrain, rect, record)


def approximate_tin(
    terrain: GeometryData,
    max_error: float | None,
    max_points: int | None,
    max_triangles: int | None,
    data_dependent: bool = False,
) -> GeometryPatch:
    """The greedy TIN of a whole terrain (see ``patches.approximate``)."""
    rect = terrain.domain
    if isinstance(terrain, Grid):
        win = grid_window(terrain, rect)
        result = grid_tin(terrain, win, max_error, max_points, max_triangles, data_dependent)
        return GridTINPatch.from_greedy(terrain, rect, win, result)
    if isinstance(terrain, TIN):
        from approxtree.patches.tin_points import PointTINPatch

        if max_triangles is not None:
            # A triangulation of v points has fewer than 2v triangles.
            max_points = max(3, max_triangles // 2)
        err = -1.0 if max_error is None else max_error
        return PointTINPatch.build_rect(terrain, rect, max_points or 0, err)
    raise UnsupportedStrategyError(
        f"The tin strategy cannot approximate a {type(terrain).__name__}."
    )
