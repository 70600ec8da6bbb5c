"""GridRefinement: a terrain grid refined by TIN microstructures (river beds, dams, ...).

h_T is the microstructure inside its footprint (the union of its triangles) and the grid
elsewhere; the data points are the grid points outside every footprint plus the vertices of the
microstructures. All microstructures are merged into one TIN so that point location is one
bucket-grid query however many there are.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import cached_property
from typing import Any

import numpy as np

from approxtree.errors import TerrainFormatError
from approxtree.geometry.base import GeometryData, RecordArray
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.geometry.tin import TIN


def merge_tins(tins: Sequence[TIN]) -> TIN:
    """One TIN holding the vertices and triangles of all ``tins`` (indices shifted)."""
    offsets = np.cumsum([0] + [len(t.vertices) for t in tins[:-1]])
    vertices = np.concatenate([t.vertices for t in tins])
    triangles = np.concatenate([t.triangles + o for t, o in zip(tins, offsets, strict=True)])
    return TIN(vertices, triangles, crs=tins[0].crs)


class GridRefinement(GeometryData):
    """A Grid plus TIN microstructures that replace it inside their footprints.

    grid: the base terrain grid; microstructures: TINs in the grid's world coordinates.
    """

    def __init__(self, grid: Grid, microstructures: Sequence[TIN]):
        if not microstructures:
            raise TerrainFormatError("GridRefinement needs at least one microstructure TIN.")
        self.grid = grid
        self.microstructures = list(microstructures)
        self.combined = merge_tins(self.microstructures)
        self.crs = grid.crs

    @cached_property
    def grid_outside(self) -> np.ndarray:
        """(rows, cols) bool: valid grid points that lie outside every footprint."""
        g = self.grid
        r0, r1, c0, c1 = g.index_range(self.combined.domain)
        outside = g.valid.copy()
        if r1 >= r0 and c1 >= c0:
            xx, yy = np.meshgrid(g.x_coords[c0 : c1 + 1], g.y_coords[r0 : r1 + 1])
            tri, _ = self.combined.locate(xx, yy)
            outside[r0 : r1 + 1, c0 : c1 + 1] &= (tri < 0).reshape(xx.shape)
        return outside

    @cached_property
    def domain(self) -> Rect:
        a, b = self.grid.domain, self.combined.domain
        return Rect(
            min(a.xmin, b.xmin), min(a.ymin, b.ymin), max(a.xmax, b.xmax), max(a.ymax, b.ymax)
        )

    @cached_property
    def _micro_by_x(self) -> tuple[np.ndarray, np.ndarray]:
        """(order, sorted x) of the microstructure vertices, for window queries."""
        x = self.combined.vertices[:, 0]
        order = np.argsort(x, kind="stable")
        return order, x[order]

    def micro_index(self, rect: Rect) -> np.ndarray:
        """(k,) int64 ascending indices of the microstructure vertices inside the closed rect."""
        order, xs = self._micro_by_x
        lo = np.searchsorted(xs, rect.xmin, side="left")
        hi = np.searchsorted(xs, rect.xmax, side="right")
        cand = order[lo:hi]
        v = self.combined.vertices[cand]
        return np.sort(cand[rect.contains(v[:, 0], v[:, 1])])

    def points(self, rect: Rect | None = None) -> np.ndarray:
        g = self.grid
        if rect is None:
            rr, cc = np.nonzero(self.grid_outside)
            micro = self.combined.vertices
        else:
            # Only the grid window of the rectangle and the vertices in its x range are read.
            r0, r1, c0, c1 = g.index_range(rect)
            rr, cc = np.nonzero(self.grid_outside[r0 : r1 + 1, c0 : c1 + 1])
            rr, cc = rr + r0, cc + c0
            micro = self.combined.vertices[self.micro_index(rect)]
        pts = np.column_stack([g.x_coords[cc], g.y_coords[rr], g.heights[rr, cc]])
        pts = np.concatenate([pts, micro])
        if rect is not None:
            pts = pts[rect.contains(pts[:, 0], pts[:, 1])]
        return pts

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        shape = np.broadcast_shapes(x.shape, y.shape)
        xb, yb = np.broadcast_to(x, shape), np.broadcast_to(y, shape)
        tri, z = self.combined.locate(xb, yb)
        outside = tri < 0
        z[outside] = self.grid.height_at(xb.ravel()[outside], yb.ravel()[outside])
        return z.reshape(shape)

    @cached_property
    def z_range(self) -> tuple[float, float]:
        gz = self.grid.heights_array("GridRefinement.z_range")[self.grid_outside]
        tz = self.combined.z_range
        lo = min(float(gz.min()) if gz.size else np.inf, tz[0])
        hi = max(float(gz.max()) if gz.size else -np.inf, tz[1])
        return (lo, hi)

    @property
    def point_count(self) -> int:
        return int(np.count_nonzero(self.grid_outside)) + self.combined.point_count

    def to_record(self) -> tuple[dict[str, Any], dict[str, RecordArray]]:
        attrs, arrays = self.grid.to_record()
        arrays = dict(arrays)
        arrays["vertices"] = self.combined.vertices
        arrays["triangles"] = self.combined.triangles
        arrays["vertex_counts"] = np.array([len(t.vertices) for t in self.microstructures])
        arrays["triangle_counts"] = np.array([len(t.triangles) for t in self.microstructures])
        return attrs, arrays

    @classmethod
    def from_record(
        cls, attrs: dict[str, Any], arrays: Mapping[str, RecordArray]
    ) -> GridRefinement:
        grid = Grid.from_record(attrs, arrays)
        v_end = np.cumsum(arrays["vertex_counts"])
        t_end = np.cumsum(arrays["triangle_counts"])
        vertices, triangles = np.asarray(arrays["vertices"]), np.asarray(arrays["triangles"])
        tins = []
        for i in range(len(v_end)):
            v0 = v_end[i - 1] if i else 0
            t0 = t_end[i - 1] if i else 0
            tins.append(TIN(vertices[v0 : v_end[i]], triangles[t0 : t_end[i]] - v0, grid.crs))
        return cls(grid, tins)

    def split_position(self, rect: Rect, axis: int) -> float | None:
        return self.grid.split_position(rect, axis)

    def split_positions(self, rects: np.ndarray, axis: int) -> np.ndarray:
        return self.grid.split_positions(rects, axis)
