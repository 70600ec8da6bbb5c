"""NonRegularGrid: a grid whose rows and columns are irregularly spaced.

Heights are given on the lattice xs × ys; cells are triangulated exactly like a regular Grid
(diagonal from (r, c) to (r+1, c+1)), and h_T interpolates linearly within each triangle.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt

from approxtree.errors import EmptyTerrainError, TerrainFormatError
from approxtree.geometry.base import GeometryData, RecordArray
from approxtree.geometry.rect import Rect
from approxtree.kernels.grid_interp import grid_height_at


def _strictly_monotonic(a: npt.ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    d = np.diff(a)
    if a.ndim != 1 or not (np.all(d > 0) or np.all(d < 0)):
        raise TerrainFormatError(f"{name} must be a strictly increasing or decreasing 1-D array.")
    return a


class NonRegularGrid(GeometryData):
    """Heights on an irregular lattice.

    xs: (cols,) x of each column, strictly monotonic; ys: (rows,) y of each row, strictly
    monotonic; heights: (rows, cols) float, NaN = nodata.
    """

    def __init__(
        self, xs: npt.ArrayLike, ys: npt.ArrayLike, heights: npt.ArrayLike, crs: str | None = None
    ):
        h = np.ascontiguousarray(heights, dtype=np.float64)
        self.xs = _strictly_monotonic(xs, "xs")
        self.ys = _strictly_monotonic(ys, "ys")
        if h.shape != (len(self.ys), len(self.xs)):
            raise TerrainFormatError(
                f"heights must have shape (len(ys), len(xs)) = {(len(self.ys), len(self.xs))}, "
                f"got {h.shape}."
            )
        if h.shape[0] < 2 or h.shape[1] < 2:
            raise EmptyTerrainError(f"A grid needs at least 2 × 2 points, got {h.shape}.")
        self._n_valid = int(np.count_nonzero(np.isfinite(h)))
        if self._n_valid == 0:
            raise EmptyTerrainError("The non-regular grid has no valid elevation.")
        self.heights = h
        self.crs = crs

    @staticmethod
    def _fraction(v: np.ndarray, coords: np.ndarray) -> np.ndarray:
        """Fractional index of values v along monotonic coords; NaN outside."""
        idx = np.arange(len(coords), dtype=np.float64)
        if coords[0] > coords[-1]:
            coords, idx = coords[::-1], idx[::-1]
        return np.interp(v, coords, idx, left=np.nan, right=np.nan)

    @cached_property
    def domain(self) -> Rect:
        return Rect(
            float(self.xs.min()), float(self.ys.min()), float(self.xs.max()), float(self.ys.max())
        )

    def points(self, rect: Rect | None = None) -> np.ndarray:
        cols = (
            np.arange(len(self.xs))
            if rect is None
            else np.flatnonzero((self.xs >= rect.xmin) & (self.xs <= rect.xmax))
        )
        rows = (
            np.arange(len(self.ys))
            if rect is None
            else np.flatnonzero((self.ys >= rect.ymin) & (self.ys <= rect.ymax))
        )
        rr, cc = np.meshgrid(rows, cols, indexing="ij")
        z = self.heights[rr, cc]
        ok = np.isfinite(z)
        return np.column_stack([self.xs[cc[ok]], self.ys[rr[ok]], z[ok]])

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        shape = np.broadcast_shapes(x.shape, y.shape)
        fc = self._fraction(np.broadcast_to(x, shape).ravel(), self.xs)
        fr = self._fraction(np.broadcast_to(y, shape).ravel(), self.ys)
        return grid_height_at(self.heights, fr, fc).reshape(shape)

    @cached_property
    def z_range(self) -> tuple[float, float]:
        return (float(np.nanmin(self.heights)), float(np.nanmax(self.heights)))

    @property
    def point_count(self) -> int:
        return self._n_valid

    def to_record(self) -> tuple[dict[str, Any], dict[str, RecordArray]]:
        return {"crs": self.crs}, {"xs": self.xs, "ys": self.ys, "heights": self.heights}

    @classmethod
    def from_record(
        cls, attrs: dict[str, Any], arrays: Mapping[str, RecordArray]
    ) -> NonRegularGrid:
        return cls(arrays["xs"], arrays["ys"], arrays["heights"], attrs["crs"])

    def split_position(self, rect: Rect, axis: int) -> float | None:
        coords = self.xs if axis == 0 else self.ys
        lo, hi = (rect.xmin, rect.xmax) if axis == 0 else (rect.ymin, rect.ymax)
        inside = np.sort(coords[(coords >= lo) & (coords <= hi)])
        if len(inside) < 3:
            return None
        return float(inside[(len(inside) - 1) // 2])
