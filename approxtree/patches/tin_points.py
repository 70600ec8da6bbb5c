"""PointTINPatch: greedy insertion over scattered data points (TIN and TINPointSet terrains).

The patch starts from the convex hull of the rectangle's data points and inserts, one at a
time, the input point of largest error |z − h_TN| (measured at the input points), keeping a
Delaunay triangulation (scipy's incremental Qhull). Each pass re-evaluates every point, so this
is the straightforward O(m·n) form of greedy insertion, meant for patch-sized point sets; grids
use the O((m + n) log m) kernel.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from approxtree.geometry.base import GeometryData
from approxtree.geometry.rect import Rect
from approxtree.geometry.tin import TIN
from approxtree.patches.base import GeometryPatch, ccw_triangles


def _errors(xy: np.ndarray, z: np.ndarray, chosen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(|z − h_TN| at every point (inf outside the mesh, 0 at vertices), triangles (m, 3))."""
    from scipy.spatial import Delaunay, QhullError

    err = np.full(len(xy), np.inf)
    err[chosen] = 0.0
    try:
        tri = Delaunay(xy[chosen])
    except (QhullError, ValueError):
        return err, np.empty((0, 3), dtype=np.int64)
    s = tri.find_simplex(xy)
    inside = s >= 0
    t = tri.transform[s[inside]]
    bary2 = np.einsum("nij,nj->ni", t[:, :2], xy[inside] - t[:, 2])
    bary = np.column_stack([bary2, 1.0 - bary2.sum(axis=1)])
    zc = z[chosen][tri.simplices[s[inside]]]
    err[inside] = np.abs(z[inside] - (bary * zc).sum(axis=1))
    err[chosen] = 0.0
    return err, tri.simplices.astype(np.int64)


def greedy_points(
    xy: np.ndarray, z: np.ndarray, max_error: float, max_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy insertion over points xy (n, 2), z (n,).

    Returns (chosen (k,) int64 point indices, triangles (m, 3) into chosen, errors (n,)).
    """
    from scipy.spatial import ConvexHull, QhullError

    n = len(xy)
    limit = n if max_points <= 0 else min(n, max_points)
    try:
        chosen = ConvexHull(xy).vertices.astype(np.int64)
    except (QhullError, ValueError):
        chosen = np.arange(n, dtype=np.int64)
    chosen = chosen[:limit]
    while True:
        err, tris = _errors(xy, z, chosen)
        worst = int(np.argmax(err))
        if err[worst] <= max(max_error, 0.0) or len(chosen) >= limit:
            return chosen, tris, err
        chosen = np.append(chosen, worst)


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

    @classmethod
    def build_rect(
        cls, terrain: TIN, rect: Rect, max_points: int, epsilon: float = 0.0
    ) -> PointTINPatch:
        v = terrain.vertices
        inside = np.flatnonzero(rect.contains(v[:, 0], v[:, 1]))
        if len(inside) == 0:
            nan = float("nan")
            return cls(terrain, rect, inside, np.empty((0, 3)), 0.0, 0.0, (nan, nan), 0)
        chosen, tris, err = greedy_points(v[inside, :2], v[inside, 2], epsilon, max_points)
        z = v[inside, 2]
        rms = float(np.sqrt(np.mean(err**2)))
        return cls(
            terrain,
            rect,
            inside[chosen],
            tris,
            float(err.max()),
            rms,
            (float(z.min()), float(z.max())),
            len(inside),
        )

    @classmethod
    def build_many(
        cls, terrain: GeometryData, rects: Sequence[Rect], max_points: int, epsilon: float = 0.0
    ) -> list[GeometryPatch]:
        from approxtree.patches.tin import TINPatch

        return TINPatch.build_many(terrain, rects, max_points, epsilon)

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
    def from_record(
        cls, terrain: GeometryData, rect: Rect, record: dict[str, np.ndarray]
    ) -> PointTINPatch:
        error, rms, zmin, zmax, count = (float(v) for v in record["stats"])
        mesh = np.asarray(record["mesh"], dtype=np.int64)
        n, m = int(mesh[0]), int(mesh[1])
        index = mesh[2 : 2 + n]
        tris = mesh[2 + n : 2 + n + 3 * m]
        return cls(terrain, rect, index, tris, error, rms, (zmin, zmax), int(count))  # type: ignore[arg-type]
