"""GeometryPatch: the approximating terrain T_N of one node, built by one strategy.

Subclassing contract: a strategy sets ``kind`` and implements ``build_many`` (build patches for
many rectangles at once, so kernels can batch), ``vertices``, ``triangles``, ``to_record`` and
``from_record``. Every patch reports its exact error ε_T(N): the true maximum of
|h_T(p) − h_TN(p)| over the data points p of its rectangle, never an estimate.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import ClassVar, TypeVar

import numpy as np

from approxtree.geometry.base import GeometryData
from approxtree.geometry.rect import Rect
from approxtree.patches.mesh_objects import MeshConversions
from approxtree.patches.records import Batch, concat_records

_Patch = TypeVar("_Patch", bound="GeometryPatch")


def ccw_triangles(vertices: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(m, 3) int64 copy of ``tris`` with every triangle counter-clockwise seen from above.

    vertices: (n, 3) world coordinates; tris: (m, 3) vertex indices of any orientation.
    """
    t = np.asarray(tris).astype(np.int64)
    if len(t) == 0:
        return t.reshape(0, 3)
    e1 = vertices[t[:, 1], :2] - vertices[t[:, 0], :2]
    e2 = vertices[t[:, 2], :2] - vertices[t[:, 0], :2]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    t[cw] = t[cw][:, [0, 2, 1]]
    return t


class GeometryPatch(MeshConversions, ABC):
    """T_N: up to s data points approximating the terrain on a rectangle D_N.

    ``to_trimesh()`` and ``to_pyvista()`` give it as a trimesh or pyvista mesh (same vertices
    and triangles, height z as point data; ``patches.mesh_objects``).
    """

    #: Strategy name, as used by policies, the CLI and tree files.
    kind: ClassVar[str]

    rect: Rect
    #: ε_T(N) over the data points of ``rect`` (inf if some data point is not represented, or
    #: if a drawn triangle covers nodata: holes stay holes).
    error: float
    #: (z_min, z_max) of the terrain's data points inside ``rect`` (NaN when it has none).
    z_range: tuple[float, float]
    #: Valid data points of the terrain inside ``rect``.
    data_count: int

    @classmethod
    @abstractmethod
    def build_many(
        cls,
        terrain: GeometryData,
        rects: Sequence[Rect],
        max_points: int,
        epsilon: float = 0.0,
    ) -> Sequence[GeometryPatch]:
        """Build one patch of at most ``max_points`` points per rectangle.

        Adaptive strategies may stop early, with fewer points, once the patch's error is at
        most ``epsilon``; the reported error is exact either way.
        """

    @classmethod
    def build_level(
        cls,
        terrain: GeometryData,
        rects: np.ndarray,
        max_points: int,
        epsilon: float = 0.0,
    ) -> Sequence[GeometryPatch]:
        """``build_many`` of a level's (k, 4) float64 rectangles (xmin, ymin, xmax, ymax);
        strategies whose kernels take arrays override it and make no Rect per node."""
        boxes = np.asarray(rects, dtype=np.float64).reshape(-1, 4).tolist()
        return cls.build_many(terrain, [Rect(*b) for b in boxes], max_points, epsilon)

    @classmethod
    def build_level_table(
        cls,
        terrain: GeometryData,
        rects: np.ndarray,
        max_points: int,
        epsilon: float = 0.0,
    ) -> Sequence[GeometryPatch]:
        """``build_level``, or the level's patches as a table of arrays where the strategy has
        one (``GridPatchArrays``: a tree makes the objects on first access)."""
        return cls.build_level(terrain, rects, max_points, epsilon)

    @classmethod
    def build(
        cls, terrain: GeometryData, rect: Rect, max_points: int, epsilon: float = 0.0
    ) -> GeometryPatch:
        """Build the patch of a single rectangle."""
        return cls.build_many(terrain, [rect], max_points, epsilon)[0]

    @classmethod
    def approximate(
        cls,
        terrain: GeometryData,
        max_error: float | None,
        max_points: int | None,
        max_triangles: int | None,
        data_dependent: bool = False,
    ) -> GeometryPatch:
        """The patch of the whole terrain meeting one goal (see ``patches.approximate``);
        strategies that approximate whole terrains override it."""
        from approxtree.errors import UnsupportedStrategyError

        raise UnsupportedStrategyError(
            f"The {cls.kind} strategy cannot approximate a {type(terrain).__name__}."
        )

    @property
    @abstractmethod
    def vertices(self) -> np.ndarray:
        """(n, 3) float64 world coordinates of the patch's points P_N."""

    @property
    @abstractmethod
    def triangles(self) -> np.ndarray:
        """(m, 3) int64 indices into ``vertices``, counter-clockwise seen from above."""

    @property
    @abstractmethod
    def point_count(self) -> int:
        """``|P_N| <= s``: the number of data points the patch selects."""

    @property
    @abstractmethod
    def nbytes(self) -> int:
        """Bytes the patch itself stores (shared terrain data not counted)."""

    @property
    def is_empty(self) -> bool:
        """True when the rectangle holds no valid data point (all nodata)."""
        return self.data_count == 0

    @abstractmethod
    def to_record(self) -> dict[str, np.ndarray]:
        """The patch as named little-endian arrays, for the tree file."""

    @classmethod
    def records_many(cls: type[_Patch], patches: Sequence[_Patch]) -> Batch:
        """The records of many patches of this class as flat arrays plus (k + 1,) offsets (see
        ``patches.records``); record i equals ``patches[i].to_record()`` raveled. Strategies
        override it with a gather of their attributes (no per-patch ``to_record``)."""
        return concat_records([p.to_record() for p in patches])

    @classmethod
    @abstractmethod
    def from_record(
        cls, terrain: GeometryData, rect: Rect, record: dict[str, np.ndarray]
    ) -> GeometryPatch:
        """Rebuild a patch from ``to_record``'s arrays (or their raveled copies, as
        ``records_many`` stores them), referencing the shared terrain."""
