"""PointTINPatch: greedy insertion over scattered data points (TIN and TINPointSet terrains).

The patch of a rectangle is the greedy insertion TIN of the data points inside it
(``kernels.greedy_points``: Garland & Heckbert with per-triangle buckets, a heap of candidates
and Delaunay flips, exact orientation tests). All rectangles of a tree level are found with
the terrain's point cell grid and built in one kernel call. The stored error is the true
maximum of |z − h_TN| over every data point of the rectangle (vertices, bucket points and
points sharing a vertex's position), so ε_T(N) is exact.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from approxtree.errors import UnsupportedStrategyError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.rect import Rect
from approxtree.geometry.tin import TIN
from approxtree.kernels.greedy_points import greedy_point_tin, greedy_point_tins
from approxtree.patches.base import GeometryPatch, ccw_triangles
from approxtree.patches.records import Batch, gather, interleave


def greedy_points(
    xy: np.ndarray, z: np.ndarray, max_error: float, max_points: int
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Greedy insertion over points xy (n, 2), z (n,); duplicate positions allowed.

    max_error < 0 inserts every point (full Delaunay triangulation when positions are
    distinct); max_points <= 0 sets no budget. Returns (chosen (k,) int64 point indices,
    triangles (m, 3) int64 into chosen, max error and sum of squared errors over all n points).
    """
    x = np.ascontiguousarray(xy[:, 0], dtype=np.float64)
    y = np.ascontiguousarray(xy[:, 1], dtype=np.float64)
    verts, tv, worst, sse = greedy_point_tin(
        x, y, np.ascontiguousarray(z, dtype=np.float64), float(max_error), int(max_points)
    )
    return verts, tv.reshape(-1, 3).astype(np.int64), float(worst), float(sse)


class PointTINPatch(GeometryPatch):
    """Greedy TIN over the scattered data points of a rectangle: stores point indices."""

    kind = "tin"

    def __init__(
        self,
        terrain: TIN,
        rect: Rect,
        index: np.ndarray,
        tris: np.ndarray,
        error: float,
        rms_error: float,
        z_range: tuple[float, float],
        data_count: int,
    ) -> None:
        self.terrain = terrain
        self.rect = rect
        self.index = np.ascontiguousarray(index, dtype=np.int64)
        self.tris = np.ascontiguousarray(tris, dtype=np.int32).reshape(-1, 3)
        self.error = float(error)
        self.rms_error = float(rms_error)
        self.z_range = (float(z_range[0]), float(z_range[1]))
        self.data_count = int(data_count)

    @staticmethod
    def _require_tin(terrain: GeometryData) -> TIN:
        if not isinstance(terrain, TIN):
            raise UnsupportedStrategyError(
                f"This tin strategy needs a TIN or TINPointSet, got a {type(terrain).__name__}; "
                "choose a strategy made for this data type."
            )
        return terrain

    @classmethod
    def build_rect(
        cls, terrain: TIN, rect: Rect, max_points: int, epsilon: float = 0.0
    ) -> PointTINPatch:
        """The patch of one rectangle (see ``build_points``)."""
        return cls.build_points(terrain, [rect], max_points, epsilon)[0]

    @classmethod
    def build_points(
        cls, terrain: TIN, rects: Sequence[Rect], max_points: int, epsilon: float = 0.0
    ) -> list[PointTINPatch]:
        """The greedy TIN of the data points in each rectangle, all rectangles in one batch.

        epsilon < 0 inserts every point (up to ``max_points``; 0 or less: no budget).
        """
        rects = list(rects)
        if not rects:
            return []
        index, starts = terrain.point_indices(rects)
        v = terrain.vertices
        x = np.ascontiguousarray(v[:, 0])
        y = np.ascontiguousarray(v[:, 1])
        z = np.ascontiguousarray(v[:, 2])
        verts, vstart, tv, tstart, errors, sse = greedy_point_tins(
            x, y, z, index, starts, float(epsilon), int(max_points)
        )
        # z range of each rectangle's data points (NaN when it has none).
        counts = np.diff(starts)
        zs = z[index]
        full = counts > 0
        zmin = np.full(len(rects), np.nan)
        zmax = np.full(len(rects), np.nan)
        if full.any():
            zmin[full] = np.minimum.reduceat(zs, starts[:-1][full])
            zmax[full] = np.maximum.reduceat(zs, starts[:-1][full])
        rms = np.sqrt(sse / np.maximum(counts, 1))
        return [
            cls(
                terrain,
                rect,
                verts[vstart[k] : vstart[k + 1]],
                tv[tstart[k] : tstart[k + 1]],
                errors[k],
                rms[k],
                (zmin[k], zmax[k]),
                counts[k],
            )
            for k, rect in enumerate(rects)
        ]

    @classmethod
    def build_many(
        cls, terrain: GeometryData, rects: Sequence[Rect], max_points: int, epsilon: float = 0.0
    ) -> list[PointTINPatch]:
        # Scattered points: every rectangle of the level in one kernel call.
        return cls.build_points(cls._require_tin(terrain), rects, max_points, epsilon)

    @classmethod
    def approximate(
        cls,
        terrain: GeometryData,
        max_error: float | None,
        max_points: int | None,
        max_triangles: int | None,
        data_dependent: bool = False,
    ) -> GeometryPatch:
        """The greedy TIN of all the data points (see ``patches.approximate``)."""
        if max_triangles is not None:
            # A triangulation of v points has fewer than 2v triangles.
            max_points = max(3, max_triangles // 2)
        err = -1.0 if max_error is None else max_error
        tin = cls._require_tin(terrain)
        return cls.build_rect(tin, tin.domain, max_points or 0, err)

    @property
    def vertices(self) -> np.ndarray:
        return self.terrain.vertices[self.index]

    @property
    def triangles(self) -> np.ndarray:
        return ccw_triangles(self.vertices, self.tris)

    @property
    def point_count(self) -> int:
        return len(self.index)

    @property
    def is_full_resolution(self) -> bool:
        return self.point_count >= self.data_count

    @property
    def nbytes(self) -> int:
        return self.index.nbytes + self.tris.nbytes + 5 * 8

    def to_record(self) -> dict[str, np.ndarray]:
        # One never-empty array: [n, m, n point indices, m × 3 corners].
        mesh = np.concatenate(
            [[len(self.index), len(self.tris)], self.index, self.tris.ravel()]
        ).astype("<i8")
        stats = [self.error, self.rms_error, *self.z_range, self.data_count]
        return {"mesh": mesh, "stats": np.array(stats, dtype="<f8")}

    @classmethod
    def records_many(cls, patches: Sequence[PointTINPatch]) -> Batch:
        # The to_record layout [n, m, index..., tris...] assembled for all patches at once.
        ps = list(patches)
        k = len(ps)
        ns = np.fromiter((len(p.index) for p in ps), dtype=np.int64, count=k)
        ms = np.fromiter((len(p.tris) for p in ps), dtype=np.int64, count=k)
        index = np.concatenate([p.index for p in ps]) if k else np.zeros(0, np.int64)
        tris = np.concatenate([p.tris.reshape(-1) for p in ps]) if k else np.zeros(0, np.int64)
        head = (np.stack([ns, ms], axis=1).reshape(-1), np.full(k, 2))
        mesh = interleave([head, (index, ns), (tris, 3 * ms)], "<i8")
        stats = ((p.error, p.rms_error, *p.z_range, p.data_count) for p in ps)
        return {"mesh": mesh, "stats": gather(stats, k, 5, "<f8")}

    @classmethod
    def from_record(
        cls, terrain: GeometryData, rect: Rect, record: dict[str, np.ndarray]
    ) -> PointTINPatch:
        error, rms, zmin, zmax, count = (float(v) for v in record["stats"])
        mesh = np.asarray(record["mesh"], dtype=np.int64)
        n, m = int(mesh[0]), int(mesh[1])
        index = mesh[2 : 2 + n]
        tris = mesh[2 + n : 2 + n + 3 * m]
        tin = cls._require_tin(terrain)
        return cls(tin, rect, index, tris, error, rms, (zmin, zmax), int(count))
