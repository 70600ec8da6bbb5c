"""TIN and TINPointSet: terrains given by triangles, or by scattered points to triangulate.

h_T is the linear interpolation on the triangles; outside them it is NaN. Point location uses a
uniform bucket grid (``kernels.tin_locate``), built once on first use.
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
from approxtree.kernels.greedy_points import greedy_point_tin
from approxtree.kernels.point_index import bin_points, points_in_rects
from approxtree.kernels.tin_locate import build_buckets, locate_and_interpolate


class TIN(GeometryData):
    """A triangulated irregular network.

    vertices: (n, 3) float64 world x, y, z; triangles: (m, 3) integer indices into vertices.
    crs: EPSG code or WKT of x and y, or None.
    """

    def __init__(self, vertices: npt.ArrayLike, triangles: npt.ArrayLike, crs: str | None = None):
        v = np.ascontiguousarray(vertices, dtype=np.float64)
        t = np.ascontiguousarray(triangles, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise TerrainFormatError(f"TIN vertices must have shape (n, 3), got {v.shape}.")
        if t.ndim != 2 or t.shape[1] != 3:
            raise TerrainFormatError(f"TIN triangles must have shape (m, 3), got {t.shape}.")
        if len(t) == 0 or len(v) < 3:
            raise EmptyTerrainError(
                f"A TIN needs at least 3 vertices and 1 triangle, got {len(v)} and {len(t)}."
            )
        if not np.all(np.isfinite(v)):
            raise TerrainFormatError("TIN vertices contain NaN or infinite coordinates.")
        if t.min() < 0 or t.max() >= len(v):
            raise TerrainFormatError(
                f"TIN triangle indices must lie in 0..{len(v) - 1}, got {t.min()}..{t.max()}."
            )
        # Counter-clockwise seen from above (z up), so front faces point up for the renderer.
        e1 = v[t[:, 1], :2] - v[t[:, 0], :2]
        e2 = v[t[:, 2], :2] - v[t[:, 0], :2]
        clockwise = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
        if clockwise.any():
            t = t.copy()
            t[clockwise] = t[clockwise][:, [0, 2, 1]]
        self.vertices = v
        self.triangles = t
        self.crs = crs

    @cached_property
    def domain(self) -> Rect:
        lo = self.vertices[:, :2].min(axis=0)
        hi = self.vertices[:, :2].max(axis=0)
        return Rect(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))

    def points(self, rect: Rect | None = None) -> np.ndarray:
        if rect is None:
            return self.vertices.copy()
        return self.vertices[rect.contains(self.vertices[:, 0], self.vertices[:, 1])]

    @cached_property
    def _cells(self) -> tuple:
        """The vertices binned into a cell grid of about 16 points a cell (see point_index)."""
        d = self.domain
        n = len(self.vertices)
        w = max(d.width, 1e-12)
        h = max(d.height, 1e-12)
        nbx = max(1, min(4096, round(np.sqrt(n / 16 * w / h))))
        nby = max(1, min(4096, round(np.sqrt(n / 16 * h / w))))
        cw, ch = w / nbx, h / nby
        vx = np.ascontiguousarray(self.vertices[:, 0])
        vy = np.ascontiguousarray(self.vertices[:, 1])
        start, items = bin_points(vx, vy, d.xmin, d.ymin, cw, ch, nbx, nby)
        return vx, vy, start, items, d.xmin, d.ymin, cw, ch, nbx, nby

    def point_indices(self, rects: list[Rect]) -> tuple[np.ndarray, np.ndarray]:
        """Indices of the vertices inside each closed rectangle, as ``Rect.contains`` decides.

        Returns (index (Σ,) int64, starts (r + 1,) int64): rectangle k holds
        index[starts[k]:starts[k + 1]] (grouped by cell, not sorted).
        """
        vx, vy, start, items, x0, y0, cw, ch, nbx, nby = self._cells
        boxes = np.array([r.as_tuple() for r in rects], dtype=np.float64).reshape(-1, 4)
        return points_in_rects(vx, vy, start, items, x0, y0, cw, ch, nbx, nby, boxes)

    @cached_property
    def _buckets(self) -> tuple:
        d = self.domain
        m = len(self.triangles)
        # About one triangle per bucket, buckets shaped like the domain.
        w = max(d.width, 1e-12)
        h = max(d.height, 1e-12)
        nbx = max(1, round(np.sqrt(m * w / h)))
        nby = max(1, round(np.sqrt(m * h / w)))
        cw, ch = w / nbx, h / nby
        vx = np.ascontiguousarray(self.vertices[:, 0])
        vy = np.ascontiguousarray(self.vertices[:, 1])
        start, items = build_buckets(vx, vy, self.triangles, d.xmin, d.ymin, cw, ch, nbx, nby)
        return vx, vy, start, items, cw, ch, nbx, nby

    def locate(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(triangle index or -1, linear height or NaN) at the points (x, y); flat (q,) arrays."""
        vx, vy, start, items, cw, ch, nbx, nby = self._buckets
        qx = np.ascontiguousarray(np.ravel(x), dtype=np.float64)
        qy = np.ascontiguousarray(np.ravel(y), dtype=np.float64)
        d = self.domain
        return locate_and_interpolate(
            vx,
            vy,
            np.ascontiguousarray(self.vertices[:, 2]),
            self.triangles,
            start,
            items,
            d.xmin,
            d.ymin,
            cw,
            ch,
            nbx,
            nby,
            qx,
            qy,
            1e-10,
        )

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        shape = np.broadcast_shapes(x.shape, y.shape)
        _, z = self.locate(np.broadcast_to(x, shape), np.broadcast_to(y, shape))
        return z.reshape(shape)

    @cached_property
    def z_range(self) -> tuple[float, float]:
        z = self.vertices[:, 2]
        return (float(z.min()), float(z.max()))

    @property
    def point_count(self) -> int:
        return len(self.vertices)

    def to_record(self) -> tuple[dict[str, Any], dict[str, RecordArray]]:
        return {"crs": self.crs}, {"vertices": self.vertices, "triangles": self.triangles}

    @classmethod
    def from_record(cls, attrs: dict[str, Any], arrays: Mapping[str, RecordArray]) -> TIN:
        # Bypass subclass constructors (TINPointSet would re-triangulate): the stored triangles
        # are the terrain.
        tin = cls.__new__(cls)
        TIN.__init__(tin, arrays["vertices"], arrays["triangles"], attrs["crs"])
        return tin

    def split_position(self, rect: Rect, axis: int) -> float | None:
        lo, hi = (rect.xmin, rect.xmax) if axis == 0 else (rect.ymin, rect.ymax)
        if hi <= lo:
            return None
        return 0.5 * (lo + hi)


#: Largest |x|, |y|, |z| of scattered points (see TINPointSet): the in-circle predicate's
#: fourth-degree products of coordinate differences stay finite in float64 below it.
MAX_POINT_COORDINATE = 1e60


class TINPointSet(TIN):
    """Scattered data points, Delaunay-triangulated (``kernels.greedy_points``, every point).

    points: (n, 3) float64 x, y, z. Points sharing the same (x, y) are merged into one data point
    at their mean height, since a height field has one height per position.
    """

    def __init__(self, points: np.ndarray, crs: str | None = None):
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise TerrainFormatError(f"Scattered points must have shape (n, 3), got {p.shape}.")
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p) < 3:
            raise EmptyTerrainError(
                f"A point set needs at least 3 finite points to triangulate, got {len(p)}."
            )
        # The exact predicates multiply coordinate differences up to the fourth power (in-circle):
        # beyond ±1e60 they overflow to inf and the triangulation's walks run off its arrays.
        # Such coordinates only come from corrupt scales or offsets (real ones are < 1e8).
        if np.abs(p).max() > MAX_POINT_COORDINATE:
            raise TerrainFormatError(
                f"Point coordinates reach {np.abs(p).max():.3g}, beyond ±{MAX_POINT_COORDINATE:g}: "
                "the file's scale factors or offsets are probably corrupt. Check them (e.g. with "
                "`pdal info` or lasinfo) and rewrite the file."
            )
        xy, inverse, counts = np.unique(p[:, :2], axis=0, return_inverse=True, return_counts=True)
        z = np.bincount(inverse.ravel(), weights=p[:, 2]) / counts
        merged = np.column_stack([xy, z])
        # Full insertion with exact orientation keeps every point a vertex (Qhull dropped
        # near-coincident points far from the origin, so h_T missed their heights).
        verts, tv, _, _ = greedy_point_tin(
            np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]), z, -1.0, 0
        )
        if len(tv) == 0:
            raise EmptyTerrainError(
                "The points cannot be triangulated (all on one line or one position)."
            )
        #: Input points dropped because another point had the same (x, y).
        self.duplicates_merged = int(len(p) - len(merged))
        super().__init__(merged, verts[tv.reshape(-1, 3)], crs=crs)


#: Lattice steps along the longer side of a point cloud's rectangle in ``gap_fill_points``.
GAP_FILL_CELLS = 64


def gap_fill_points(points: np.ndarray, cells: int = GAP_FILL_CELLS, k: int = 4) -> np.ndarray:
    """Points that fill a point cloud's gaps, the way the point quadtree's interpolation points
    do: a square lattice over the points' bounding rectangle, ``cells`` steps along its longer
    side (both edges included); each lattice point with no data point within one step gets
    the mean height of its ``k`` nearest data points. The cloud and these points together
    triangulate into a surface over the whole rectangle, without holes wider than a step.

    points: (n, 3) float64 x, y, z (n >= 1). Returns (m, 3) float64, m >= 0 (none where the
    cloud is dense everywhere).
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)
    lo, hi = p[:, :2].min(axis=0), p[:, :2].max(axis=0)
    step = float((hi - lo).max()) / max(int(cells), 1)
    if not step > 0.0:
        return np.empty((0, 3))
    # Lattice along each side, its last line on the rectangle's far edge.
    axes = [
        np.linspace(a, b, max(2, int(np.ceil((b - a) / step)) + 1))
        for a, b in zip(lo, hi, strict=True)
    ]
    gx, gy = np.meshgrid(*axes)
    lattice = np.column_stack([gx.ravel(), gy.ravel()])
    index = cKDTree(p[:, :2])
    nearest, _ = index.query(lattice, k=1)
    empty = lattice[nearest > step]
    if len(empty) == 0:
        return np.empty((0, 3))
    k = min(k, len(p))
    _, near = index.query(empty, k=k)
    z = p[np.asarray(near).reshape(len(empty), k), 2].mean(axis=1)
    return np.column_stack([empty, z])
