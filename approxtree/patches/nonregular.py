"""NonRegularGridPatch: the non-regular grid strategy (core paper, section 3.2, figure 4).

The patch chooses rows and columns of the shared Grid inside its rectangle that are not
regularly spaced: starting from the rectangle's first and last row and column, it inserts the
row and the column of the data point of largest error until the error is at most ε, is zero, or
one more row–column pair would exceed s = rows × columns points. Only row–column
intersections are vertices, and cells are cut by the same diagonal as GridPatch, so the patch
is a grid patch with irregular steps. Stored: the chosen row and column indices (int32) and
the exact error figures; vertices are read from the grid on demand.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from approxtree.errors import UnsupportedStrategyError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.geometry.windowed import WindowedHeights
from approxtree.kernels.grid_interp import lattice_triangles
from approxtree.kernels.row_column import lattice_errors, refine_lattices
from approxtree.patches.base import GeometryPatch
from approxtree.patches.grid import lattice_world_mesh
from approxtree.patches.lattice import require_grid
from approxtree.patches.records import Batch, gather, interleave


def lattice_mesh(grid: Grid, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World vertices (n, 3) float64 and CCW triangles (m, 3) int64 of the rows × cols lattice.

    Nodata vertices are left out (with the triangles touching them).
    """
    heights = grid.heights
    if isinstance(heights, WindowedHeights):
        # A windowed grid reads only the lattice; the kernel sees it with consecutive lines.
        z = heights[rows[:, None], cols[None, :]]
        kr, kc = np.arange(len(rows)), np.arange(len(cols))
        return lattice_world_mesh(grid, rows, cols, lattice_triangles(z, kr, kc))
    return lattice_world_mesh(grid, rows, cols, lattice_triangles(heights, rows, cols))


def refine_windows(
    grid: Grid,
    ranges: np.ndarray,
    epsilon: float,
    max_points: int,
    max_cells: int = 0,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Chosen (rows, cols) int64 of each window of ``ranges`` (n, 4) inclusive (r0, r1, c0, c1).

    max_points: most rows × cols (0 = no limit); max_cells: most cells (0 = no limit).
    """
    ranges = np.ascontiguousarray(ranges, dtype=np.int64).reshape(-1, 4)
    if len(ranges) == 0:
        return []
    n_rows = ranges[:, 1] - ranges[:, 0] + 1
    n_cols = ranges[:, 3] - ranges[:, 2] + 1
    if (n_rows < 2).any() or (n_cols < 2).any():
        k = int(np.flatnonzero((n_rows < 2) | (n_cols < 2))[0])
        raise UnsupportedStrategyError(
            "A non-regular grid patch needs a window of at least 2 × 2 grid points, got "
            f"{n_rows[k]} × {n_cols[k]}; use a larger rectangle."
        )
    # Each side keeps >= 2 lines, so one side holds at most s / 2 of them.
    cap_r = int(n_rows.max())
    cap_c = int(n_cols.max())
    if max_points > 0:
        cap_r = min(cap_r, max(2, max_points // 2))
        cap_c = min(cap_c, max(2, max_points // 2))
    if max_cells > 0:
        cap_r = min(cap_r, max_cells + 1)
        cap_c = min(cap_c, max_cells + 1)
    rows, nrows, cols, ncols, _ = refine_lattices(
        grid.heights_array("building non-regular grid patches"),
        ranges,
        float(epsilon),
        int(max_points),
        int(max_cells),
        cap_r,
        cap_c,
    )
    return [(rows[k, : nrows[k]], cols[k, : ncols[k]]) for k in range(len(ranges))]


class NonRegularGridPatch(GeometryPatch):
    """Irregularly chosen rows and columns of a Grid.

    rows: (kr,) int32 sorted row indices of the grid (a window's own; records hold the full
    raster's), first and last = the rectangle's border rows;
    cols: (kc,) int32 likewise; error, rms_error: exact over the rectangle's data points.
    """

    kind = "nonregular"

    def __init__(
        self,
        grid: Grid,
        rect: Rect,
        rows: np.ndarray,
        cols: np.ndarray,
        error: float,
        rms_error: float,
        z_range: tuple[float, float],
        data_count: int,
    ) -> None:
        self.grid = grid
        self.rect = rect
        self.rows = np.ascontiguousarray(rows, dtype=np.int32)
        self.cols = np.ascontiguousarray(cols, dtype=np.int32)
        self.error = float(error)
        self.rms_error = float(rms_error)
        self.z_range = (float(z_range[0]), float(z_range[1]))
        self.data_count = int(data_count)
        self._mesh: tuple[np.ndarray, np.ndarray] | None = None

    @classmethod
    def from_lines(
        cls, grid: Grid, rects: Sequence[Rect], lines: Sequence[tuple[np.ndarray, np.ndarray]]
    ) -> list[NonRegularGridPatch]:
        """Measure the chosen lattices exactly (one batched kernel call) and wrap them."""
        n = len(lines)
        lr = max((len(r) for r, _ in lines), default=2)
        lc = max((len(c) for _, c in lines), default=2)
        rows = np.zeros((n, lr), dtype=np.int64)
        cols = np.zeros((n, lc), dtype=np.int64)
        nrows = np.array([len(r) for r, _ in lines], dtype=np.int64)
        ncols = np.array([len(c) for _, c in lines], dtype=np.int64)
        for k, (r, c) in enumerate(lines):
            rows[k, : len(r)] = r
            cols[k, : len(c)] = c
        error, sumsq, count, zmin, zmax = lattice_errors(
            grid.heights_array("building non-regular grid patches"), rows, nrows, cols, ncols
        )
        rms = np.sqrt(sumsq / np.maximum(count, 1))
        return [
            cls(grid, rect, r, c, error[k], rms[k], (zmin[k], zmax[k]), count[k])
            for k, (rect, (r, c)) in enumerate(zip(rects, lines, strict=True))
        ]

    @classmethod
    def build_many(
        cls,
        terrain: GeometryData,
        rects: Sequence[Rect],
        max_points: int,
        epsilon: float = 0.0,
    ) -> list[GeometryPatch]:
        grid = require_grid(terrain, cls.kind)
        ranges = np.array([grid.index_range(r) for r in rects], dtype=np.int64).reshape(-1, 4)
        lines = refine_windows(grid, ranges, epsilon, max_points)
        return list(cls.from_lines(grid, rects, lines))

    @classmethod
    def approximate(
        cls,
        terrain: GeometryData,
        max_error: float | None,
        max_points: int | None,
        max_triangles: int | None,
        data_dependent: bool = False,
    ) -> GeometryPatch:
        return approximate_nonregular(terrain, max_error, max_points, max_triangles)

    @property
    def is_full_resolution(self) -> bool:
        """True when every data line of the rectangle is chosen (the patch equals T there)."""
        return int(self.rows[-1] - self.rows[0]) + 1 == len(self.rows) and int(
            self.cols[-1] - self.cols[0]
        ) + 1 == len(self.cols)

    def _get_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        if self._mesh is None:
            self._mesh = lattice_mesh(
                self.grid, self.rows.astype(np.int64), self.cols.astype(np.int64)
            )
        return self._mesh

    @property
    def vertices(self) -> np.ndarray:
        return self._get_mesh()[0]

    @property
    def triangles(self) -> np.ndarray:
        return self._get_mesh()[1]

    @property
    def point_count(self) -> int:
        return len(self.rows) * len(self.cols)

    @property
    def nbytes(self) -> int:
        return self.rows.nbytes + self.cols.nbytes

    def to_record(self) -> dict[str, np.ndarray]:
        # One never-empty array: [kr, kc, rows..., cols...], in the full raster's indices.
        r_off, c_off = self.grid.index_offset
        rows = self.rows.astype(np.int64) + r_off
        cols = self.cols.astype(np.int64) + c_off
        lines = np.concatenate([[len(rows), len(cols)], rows, cols])
        stats = [self.error, self.rms_error, *self.z_range, self.data_count]
        return {"lines": lines.astype("<i4"), "stats": np.array(stats, dtype="<f8")}

    @classmethod
    def records_many(cls, patches: Sequence[NonRegularGridPatch]) -> Batch:
        # The to_record layout [kr, kc, rows..., cols...] assembled for all patches at once.
        ps = list(patches)
        k = len(ps)
        kr = np.fromiter((len(p.rows) for p in ps), dtype=np.int64, count=k)
        kc = np.fromiter((len(p.cols) for p in ps), dtype=np.int64, count=k)
        # Lines in the full raster's indices, as to_record writes them.
        rows = (
            np.concatenate([p.rows + p.grid.index_offset[0] for p in ps])
            if k
            else np.zeros(0, np.int32)
        )
        cols = (
            np.concatenate([p.cols + p.grid.index_offset[1] for p in ps])
            if k
            else np.zeros(0, np.int32)
        )
        head = (np.stack([kr, kc], axis=1).reshape(-1), np.full(k, 2))
        lines = interleave([head, (rows, kr), (cols, kc)], "<i4")
        stats = ((p.error, p.rms_error, *p.z_range, p.data_count) for p in ps)
        return {"lines": lines, "stats": gather(stats, k, 5, "<f8")}

    @classmethod
    def from_record(
        cls, terrain: GeometryData, rect: Rect, record: dict[str, np.ndarray]
    ) -> NonRegularGridPatch:
        grid = require_grid(terrain, cls.kind)
        lines = np.asarray(record["lines"], dtype=np.int32)
        kr, kc = int(lines[0]), int(lines[1])
        error, rms, zmin, zmax, count = (float(v) for v in record["stats"])
        r_off, c_off = grid.index_offset
        rows = lines[2 : 2 + kr] - r_off
        cols = lines[2 + kr : 2 + kr + kc] - c_off
        return cls(grid, rect, rows, cols, error, rms, (zmin, zmax), int(count))


def approximate_nonregular(
    terrain: GeometryData,
    max_error: float | None,
    max_points: int | None,
    max_triangles: int | None,
) -> NonRegularGridPatch:
    """The non-regular grid of a whole grid (see ``patches.approximate``)."""
    grid = require_grid(terrain, NonRegularGridPatch.kind)
    rect = grid.domain
    ranges = np.array([grid.index_range(rect)], dtype=np.int64)
    epsilon = 0.0 if max_error is None else float(max_error)
    # Two triangles per cell (fewer where nodata leaves some out).
    max_cells = 0 if max_triangles is None else max_triangles // 2
    lines = refine_windows(grid, ranges, epsilon, max_points or 0, max_cells)
    return NonRegularGridPatch.from_lines(grid, [rect], lines)[0]
