"""Lattice meshes: patches whose vertices are grid points, shared by the TIN and RTIN strategies.

A lattice mesh lives in a window of the grid, the index range (r0, r1, c0, c1) of a rectangle.
Its vertices are (row, column) grid indices and its triangles have orient > 0 in (column, row)
space; world coordinates and counter-clockwise order (seen from above) are made on demand.
Errors are measured exactly with ``kernels.greedy_tin.mesh_error``: every valid data point of
the window once, a point outside every drawn triangle as an infinite error, and nodata inside a
drawn triangle as an infinite error too (the mesh would cover a hole).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from approxtree.errors import UnsupportedStrategyError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.kernels.greedy_tin import mesh_error
from approxtree.kernels.tin_mesh import half_edge_twins
from approxtree.patches.base import GeometryPatch
from approxtree.patches.records import Batch, gather, interleave


def require_grid(terrain: GeometryData, strategy: str) -> Grid:
    """The terrain as a Grid, or a clear error naming the strategy and the data type."""
    if not isinstance(terrain, Grid):
        raise UnsupportedStrategyError(
            f"The {strategy} strategy needs a regular Grid, got a {type(terrain).__name__}; "
            "choose a strategy made for this data type (tin for scattered points)."
        )
    return terrain


@dataclass
class Window:
    """The grid points of a rectangle: inclusive index ranges and their statistics."""

    r0: int
    r1: int
    c0: int
    c1: int
    #: Valid data points in the window.
    count: int
    z_range: tuple[float, float]
    has_nan: bool

    @property
    def rows(self) -> int:
        return self.r1 - self.r0 + 1

    @property
    def cols(self) -> int:
        return self.c1 - self.c0 + 1


def grid_window(grid: Grid, rect: Rect) -> Window:
    """The window of ``rect`` with its count of valid data points and their z range."""
    r0, r1, c0, c1 = grid.index_range(rect)
    # Lattice builds read the whole band (checked once on a windowed grid, never a huge read).
    z = grid.heights_array("building lattice (TIN, RTIN) patches")[r0 : r1 + 1, c0 : c1 + 1]
    # Two reductions settle a window without nodata (NaN or ±inf propagate into them): no mask
    # and no masked copies, a fixed cost of every TIN and RTIN build.
    if z.size:
        lo, hi = z.min(), z.max()
        if np.isfinite(lo) and np.isfinite(hi):
            return Window(r0, r1, c0, c1, z.size, (float(lo), float(hi)), False)
    valid = np.isfinite(z)
    count = int(np.count_nonzero(valid))
    if count:
        z_range = (float(z[valid].min()), float(z[valid].max()))
    else:
        z_range = (float("nan"), float("nan"))
    return Window(r0, r1, c0, c1, count, z_range, count < z.size)


def twins(tris: np.ndarray) -> np.ndarray:
    """(3m,) int32 twin half-edge of each half-edge of ``tris`` (m, 3), −1 on the border.

    Half-edge 3t + k runs from tris[t, k] to tris[t, (k + 1) % 3].
    """
    if len(tris) == 0:
        return np.empty(0, dtype=np.int32)
    tv = np.ascontiguousarray(tris, dtype=np.int64).reshape(-1)
    return half_edge_twins(tv, int(tv.max()) + 1)


@dataclass
class Measured:
    """Exact error figures of a lattice mesh over its window's valid data points."""

    error: float
    rms: float
    #: (m,) bool: triangles drawn (no nodata corner).
    drawn: np.ndarray


def measure(
    grid: Grid, win: Window, vx: np.ndarray, vy: np.ndarray, tv: np.ndarray, he: np.ndarray
) -> Measured:
    """Exact max and RMS error of a window-local lattice mesh (see the module docstring).

    vx, vy: (n,) int64 window-local column and row; tv, he: (3m,) int32 triangles and twins.
    """
    vmax, sumsq, count, drawn = mesh_error(
        grid.heights_array("measuring lattice patch errors"),
        win.r0,
        win.c0,
        win.rows,
        win.cols,
        vx,
        vy,
        tv,
        he,
    )
    valid_vertices = int(np.count_nonzero(np.isfinite(grid.heights[win.r0 + vy, win.c0 + vx])))
    # Every valid point is either a vertex (exact) or counted once in a drawn triangle.
    represented = count + valid_vertices
    error = float(vmax) if represented >= win.count else float("inf")
    rms = float(np.sqrt(sumsq / win.count)) if win.count else 0.0
    if represented < win.count:
        rms = float("inf")
    return Measured(error, rms, drawn)


class LatticePatch(GeometryPatch):
    """A patch of grid-point vertices: stores (row, col) indices and triangles, int32.

    ``ij``: (n, 2) int32 (row, col) of the vertices in the grid's own indices (all valid data
    points; a window's are its own, records hold the full raster's, see ``to_record``);
    ``tris``: (m, 3) int32 triangles, orient > 0 in (column, row) index space.
    """

    def __init__(
        self,
        grid: Grid,
        rect: Rect,
        ij: np.ndarray,
        tris: np.ndarray,
        error: float,
        rms_error: float,
        z_range: tuple[float, float],
        data_count: int,
    ) -> None:
        self.grid = grid
        self.rect = rect
        self.ij = np.ascontiguousarray(ij, dtype=np.int32).reshape(-1, 2)
        self.tris = np.ascontiguousarray(tris, dtype=np.int32).reshape(-1, 3)
        self.error = float(error)
        self.rms_error = float(rms_error)
        self.z_range = (float(z_range[0]), float(z_range[1]))
        self.data_count = int(data_count)

    @classmethod
    def from_window_mesh(
        cls,
        grid: Grid,
        rect: Rect,
        win: Window,
        vx: np.ndarray,
        vy: np.ndarray,
        tv: np.ndarray,
        he: np.ndarray,
    ) -> LatticePatch:
        """Measure a window-local mesh, keep drawn triangles and valid vertices only."""
        m = measure(grid, win, vx, vy, tv, he)
        tris = tv.reshape(-1, 3)[m.drawn]
        rows = win.r0 + vy
        cols = win.c0 + vx
        keep = np.isfinite(grid.heights[rows, cols])
        if not keep.all():
            new_index = np.cumsum(keep) - 1
            tris = new_index[tris]
            rows, cols = rows[keep], cols[keep]
        ij = np.column_stack([rows, cols])
        return cls(grid, rect, ij, tris, m.error, m.rms, win.z_range, win.count)

    @property
    def vertices(self) -> np.ndarray:
        g = self.grid
        # Contiguous native indices and flat takes: about half the time of fancy indexing with
        # strided int32 columns.
        r = self.ij[:, 0].astype(np.intp)
        c = self.ij[:, 1].astype(np.intp)
        # Filled column by column: no (n, 3) temporaries on million-vertex meshes.
        out = np.empty((len(self.ij), 3), dtype=np.float64)
        out[:, 0] = g.x_coords.take(c)
        out[:, 1] = g.y_coords.take(r)
        h = g.heights
        out[:, 2] = h.take(r * h.shape[1] + c) if isinstance(h, np.ndarray) else h[r, c]
        return out

    @property
    def triangles(self) -> np.ndarray:
        # Index space is (col, row); a north-up transform mirrors it, so flip to stay CCW.
        order = (0, 2, 1) if self.grid.transform.a * self.grid.transform.e < 0 else (0, 1, 2)
        # One gather in the stored dtype, then one widening pass (faster than three strided
        # column copies).
        return self.tris[:, order].astype(np.int64)

    @property
    def point_count(self) -> int:
        return len(self.ij)

    @property
    def is_full_resolution(self) -> bool:
        """True when every valid data point of the window is a vertex."""
        return self.point_count >= self.data_count

    @property
    def nbytes(self) -> int:
        return self.ij.nbytes + self.tris.nbytes + 5 * 8

    def to_record(self) -> dict[str, np.ndarray]:
        # One never-empty array: [n, m, n × (row, col), m × 3 corners], (row, col) in the full
        # raster's indices.
        ij = self.ij + np.array(self.grid.index_offset, dtype=np.int32)
        mesh = np.concatenate([[len(ij), len(self.tris)], ij.ravel(), self.tris.ravel()]).astype(
            "<i4"
        )
        stats = [self.error, self.rms_error, *self.z_range, self.data_count]
        return {"mesh": mesh, "stats": np.array(stats, dtype="<f8")}

    @classmethod
    def records_many(cls, patches: Sequence[LatticePatch]) -> Batch:
        # The to_record layout [n, m, ij..., tris...] assembled for all patches at once.
        ps = list(patches)
        k = len(ps)
        ns = np.fromiter((len(p.ij) for p in ps), dtype=np.int64, count=k)
        ms = np.fromiter((len(p.tris) for p in ps), dtype=np.int64, count=k)
        # (row, col) in the full raster's indices, as to_record writes them.
        ij = (
            np.concatenate(
                [(p.ij + np.array(p.grid.index_offset, np.int32)).reshape(-1) for p in ps]
            )
            if k
            else np.zeros(0, np.int32)
        )
        tris = np.concatenate([p.tris.reshape(-1) for p in ps]) if k else np.zeros(0, np.int32)
        head = (np.stack([ns, ms], axis=1).reshape(-1), np.full(k, 2))
        mesh = interleave([head, (ij, 2 * ns), (tris, 3 * ms)], "<i4")
        stats = ((p.error, p.rms_error, *p.z_range, p.data_count) for p in ps)
        return {"mesh": mesh, "stats": gather(stats, k, 5, "<f8")}

    @classmethod
    def from_record(
        cls, terrain: GeometryData, rect: Rect, record: dict[str, np.ndarray]
    ) -> LatticePatch:
        grid = require_grid(terrain, cls.kind)
        error, rms, zmin, zmax, count = (float(v) for v in record["stats"])
        mesh = np.asarray(record["mesh"], dtype=np.int32)
        n, m = int(mesh[0]), int(mesh[1])
        ij = mesh[2 : 2 + 2 * n].reshape(-1, 2) - np.array(grid.index_offset, dtype=np.int32)
        tris = mesh[2 + 2 * n : 2 + 2 * n + 3 * m]
        return cls(grid, rect, ij, tris, error, rms, (zmin, zmax), int(count))
