"""Patches over a GridRefinement: a grid with TIN microstructures (core paper, section 7).

The data points of a node are the grid points outside every footprint plus the microstructure
vertices inside D_N, and h_T is the combined surface. Two strategies build such nodes:

- ``grid``: the GridPatch of the base grid (rows and columns of the grid), its error re-measured
  against the combined data points — exact, and large wherever a microstructure is finer than
  the grid;
- ``tin``: ``RefinedTINPatch``, greedy insertion over the scattered data points of D_N,
  starting from the rectangle's corners (heights h_T there) so that the patch covers D_N.

Greedy insertion here inserts, per pass, the worst point of every triangle whose error exceeds
ε (the multiple-insertion variant of Garland & Heckbert), largest errors first when the point
budget runs out: a pass costs one Delaunay triangulation (scipy's Qhull) and one point location,
so a patch of k points takes O(log k) passes rather than k. Errors are measured at every data
point of the node after the last pass.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from approxtree.geometry.base import GeometryData
from approxtree.geometry.rect import Rect
from approxtree.geometry.refinement import GridRefinement
from approxtree.kernels.mesh_errors import mesh_point_errors
from approxtree.patches.base import GeometryPatch, ccw_triangles


def locate_errors(
    vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(triangle of each point or −1, |z − h_TN| with inf outside) for points (k, 3)."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    p = np.ascontiguousarray(points, dtype=np.float64)
    return mesh_point_errors(
        np.ascontiguousarray(v[:, 0]),
        np.ascontiguousarray(v[:, 1]),
        np.ascontiguousarray(v[:, 2]),
        np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3),
        np.ascontiguousarray(p[:, 0]),
        np.ascontiguousarray(p[:, 1]),
        np.ascontiguousarray(p[:, 2]),
        1e-10,
    )


def mesh_errors(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """|z − h_TN| at ``points`` (k, 3) for the mesh (n, 3) / (m, 3); inf outside the mesh."""
    return locate_errors(vertices, triangles, points)[1]


def _delaunay_errors(
    vxy: np.ndarray, vz: np.ndarray, xy: np.ndarray, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(triangles (m, 3), simplex of each point (−1 outside), |z − h| (inf outside))."""
    from scipy.spatial import Delaunay, QhullError

    try:
        tri = Delaunay(vxy)
    except (QhullError, ValueError):
        return np.empty((0, 3), np.int64), np.full(len(xy), -1), np.full(len(xy), np.inf)
    simplices = tri.simplices.astype(np.int64)
    s, err = locate_errors(np.column_stack([vxy, vz]), simplices, np.column_stack([xy, z]))
    return simplices, s, err


def greedy_multi(
    start: np.ndarray, points: np.ndarray, max_error: float, max_points: int
) -> tuple[np.ndarray, np.ndarray]:
    """Multiple-insertion greedy TIN.

    start: (a, 3) initial vertices (rectangle corners); points: (n, 3) data points;
    returns (vertices (k, 3) with k <= max(max_points, a), triangles (m, 3)).
    """
    xy, z = points[:, :2], points[:, 2]
    chosen = np.zeros(len(points), dtype=bool)
    verts = start
    while True:
        tris, simplex, err = _delaunay_errors(verts[:, :2], verts[:, 2], xy, z)
        err[chosen] = 0.0
        budget = max_points - len(verts)
        bad = np.flatnonzero(err > max_error)
        if budget <= 0 or len(bad) == 0:
            return verts, tris
        # Worst point of each triangle (points outside the mesh group under −1).
        order = bad[np.lexsort((-err[bad], simplex[bad]))]
        first = np.ones(len(order), dtype=bool)
        first[1:] = simplex[order[1:]] != simplex[order[:-1]]
        pick = order[first]
        outside = order[simplex[order] < 0]
        if len(outside):
            # Points the mesh does not reach: take them all (the hull must grow to them).
            pick = np.union1d(pick[simplex[pick] >= 0], outside)
        pick = pick[np.argsort(-err[pick], kind="stable")][:budget]
        chosen[pick] = True
        verts = np.concatenate([verts, points[pick]])


class RefinedTINPatch(GeometryPatch):
    """Greedy TIN over the combined data points of a GridRefinement node: stores its vertices."""

    kind = "tin"

    def __init__(
        self,
        terrain: GridRefinement,
        rect: Rect,
        vertices: np.ndarray,
        tris: np.ndarray,
        error: float,
        z_range: tuple[float, float],
        data_count: int,
    ) -> None:
        self.terrain = terrain
        self.rect = rect
        self._vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
        self.tris = np.ascontiguousarray(tris, dtype=np.int32).reshape(-1, 3)
        self.error = float(error)
        self.z_range = (float(z_range[0]), float(z_range[1]))
        self.data_count = int(data_count)

    @staticmethod
    def corners(terrain: GridRefinement, rects: Sequence[Rect]) -> np.ndarray:
        """(len(rects), 4, 3) corners of each rectangle at h_T (NaN where h_T is undefined).

        The corners make the mesh cover D_N; they are data points where the grid has one
        outside every footprint, interpolated points otherwise.
        """
        r = np.array([q.as_tuple() for q in rects], dtype=np.float64).reshape(-1, 4)
        cx = r[:, [0, 2, 2, 0]]
        cy = r[:, [1, 1, 3, 3]]
        return np.stack([cx, cy, terrain.height_at(cx, cy)], axis=-1)

    @classmethod
    def build_rect(
        cls,
        terrain: GridRefinement,
        rect: Rect,
        max_points: int,
        epsilon: float = 0.0,
        corners: np.ndarray | None = None,
    ) -> RefinedTINPatch:
        pts = terrain.points(rect)
        if len(pts) == 0:
            nan = float("nan")
            return cls(terrain, rect, np.empty((0, 3)), np.empty((0, 3)), 0.0, (nan, nan), 0)
        if corners is None:
            corners = cls.corners(terrain, [rect])[0]
        corners = corners[np.isfinite(corners[:, 2])]
        verts, tris = greedy_multi(corners, pts, max(epsilon, 0.0), max(max_points, 4))
        err = mesh_errors(verts, tris, pts)
        return cls(
            terrain,
            rect,
            verts,
            tris,
            float(err.max()),
            (float(pts[:, 2].min()), float(pts[:, 2].max())),
            len(pts),
        )

    @classmethod
    def build_many(
        cls, terrain, rects: Sequence[Rect], max_points: int, epsilon: float = 0.0
    ) -> list[GeometryPatch]:
        # Corner heights of the whole batch in one query.
        corners = cls.corners(terrain, rects)
        return [
            cls.build_rect(terrain, r, max_points, epsilon, c)
            for r, c in zip(rects, corners, strict=True)
        ]

    @property
    def vertices(self) -> np.ndarray:
        return self._vertices

    @property
    def triangles(self) -> np.ndarray:
        return ccw_triangles(self._vertices, self.tris)

    @property
    def point_count(self) -> int:
        return len(self._vertices)

    @property
    def is_full_resolution(self) -> bool:
        return self.error == 0.0

    @property
    def nbytes(self) -> int:
        return self._vertices.nbytes + self.tris.nbytes + 4 * 8

    def to_record(self) -> dict[str, np.ndarray]:
        stats = [self.error, *self.z_range, self.data_count]
        return {
            "vertices": self._vertices.astype("<f8"),
            "triangles": self.tris.astype("<i4"),
            "stats": np.array(stats, dtype="<f8"),
        }

    @classmethod
    def from_record(cls, terrain, rect: Rect, record: dict[str, np.ndarray]) -> RefinedTINPatch:
        error, zmin, zmax, count = (float(v) for v in record["stats"])
        return cls(
            terrain,
            rect,
            np.asarray(record["vertices"]).reshape(-1, 3),
            np.asarray(record["triangles"]).reshape(-1, 3),
            error,
            (zmin, zmax),
            int(count),
        )


def refine_grid_patches(terrain: GeometryData, patches: Sequence[GeometryPatch]) -> None:
    """Re-measure grid patches of a base grid against the terrain's data points (a
    GridRefinement's combined ones), in place."""
    for p in patches:
        pts = terrain.points(p.rect)
        p.data_count = len(pts)
        if len(pts) == 0:
            p.error, p.z_range = 0.0, (float("nan"), float("nan"))
            continue
        p.error = float(mesh_errors(p.vertices, p.triangles, pts).max())
        p.z_range = (float(pts[:, 2].min()), float(pts[:, 2].max()))
