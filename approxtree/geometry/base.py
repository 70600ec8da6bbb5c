"""GeometryData: the abstract terrain T = (P, h_T) every strategy and reader speaks.

A terrain is a set of data points P in the xy-plane with elevations, plus an elevation function
h_T that interpolates them linearly (on the triangulated grid, or on the TIN). Subclassing
contract: a new data type implements ``domain``, ``points``, ``height_at``, ``z_range``,
``point_count`` and ``split_position``; nothing else in the engine needs to change.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, TypeAlias

import numpy as np

from approxtree.geometry.rect import Rect
from approxtree.geometry.windowed import WindowedHeights

#: One named array of a terrain record: a numpy array, or the heights of a windowed grid as
#: their WindowedHeights (read by windows; ``np.asarray`` reads the band whole).
RecordArray: TypeAlias = np.ndarray | WindowedHeights


class GeometryData(ABC):
    """A terrain: data points P, elevation function h_T, domain D(T) and its CRS."""

    #: Coordinate reference system of x and y as a string (EPSG code or WKT), None if unknown.
    crs: str | None = None

    @property
    @abstractmethod
    def domain(self) -> Rect:
        """D(T): the axis-parallel bounding box of the data points, in world units."""

    @abstractmethod
    def points(self, rect: Rect | None = None) -> np.ndarray:
        """The data points inside the closed ``rect`` (all when None): (n, 3) float64 x, y, z.

        Nodata is never a data point: masked cells are left out.
        """

    @abstractmethod
    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """h_T at the points (x, y): arrays of any equal shape in, float64 of that shape out.

        NaN outside the domain and inside holes (triangles touching nodata).
        """

    @property
    @abstractmethod
    def z_range(self) -> tuple[float, float]:
        """(z_min, z_max) over the valid data points."""

    @property
    @abstractmethod
    def point_count(self) -> int:
        """``|P|``: the number of valid data points."""

    @abstractmethod
    def split_position(self, rect: Rect, axis: int) -> float | None:
        """Where a subdivision may cut ``rect`` across ``axis`` (0 = x, 1 = y), or None.

        Grids cut on a data line so that neighbouring patches share their border points.
        """

    def split_positions(self, rects: np.ndarray, axis: int) -> np.ndarray:
        """(k,) float64 ``split_position`` of (k, 4) rectangles (xmin, ymin, xmax, ymax), NaN
        where a rectangle cannot be cut; grids override it with one array pass."""
        out = np.full(len(rects), np.nan)
        for i, box in enumerate(np.asarray(rects, dtype=np.float64).reshape(-1, 4).tolist()):
            at = self.split_position(Rect(*box), axis)
            if at is not None:
                out[i] = at
        return out

    @abstractmethod
    def to_record(self) -> tuple[dict[str, Any], dict[str, RecordArray]]:
        """(JSON-able attributes, named arrays) that ``from_record`` turns back into the terrain."""

    @classmethod
    @abstractmethod
    def from_record(cls, attrs: dict[str, Any], arrays: Mapping[str, RecordArray]) -> GeometryData:
        """Rebuild the terrain from ``to_record``'s output (arrays may be read-only views)."""

    @property
    def kind(self) -> str:
        """Short lower-case name of the data type, as stored in tree files."""
        return type(self).__name__.lower()

    def __repr__(self) -> str:
        d = self.domain
        return (
            f"{type(self).__name__}(points={self.point_count}, "
            f"domain=({d.xmin:g}, {d.ymin:g}, {d.xmax:g}, {d.ymax:g}), crs={self.crs!r})"
        )
