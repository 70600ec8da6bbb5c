"""Independent re-computations used by the tests (matplotlib's triangulation, not our kernels)."""

from __future__ import annotations

import numpy as np
from matplotlib.tri import LinearTriInterpolator, Triangulation

from approxtree.geometry.base import GeometryData
from approxtree.geometry.rect import Rect


def brute_force_error(
    terrain: GeometryData, rect: Rect, vertices: np.ndarray, triangles: np.ndarray
) -> float:
    """max |z(p) − h_TN(p)| over the data points p in rect, h_TN from matplotlib's interpolator.

    Points that are patch vertices count as exact; other points outside every patch triangle
    count as infinitely wrong (the patch does not represent them), and so does a nodata point
    of a lattice terrain inside a patch triangle (the patch would cover a hole).
    """
    pts = terrain.points(rect)
    if len(pts) == 0:
        return 0.0
    holes = nodata_points(terrain, rect)
    if len(holes) and len(triangles):
        tri = Triangulation(vertices[:, 0], vertices[:, 1], triangles)
        covered = tri.get_trifinder()(holes[:, 0], holes[:, 1]) >= 0
        if covered.any():
            return float("inf")
    if len(triangles):
        tri = Triangulation(vertices[:, 0], vertices[:, 1], triangles)
        h = LinearTriInterpolator(tri, vertices[:, 2])(pts[:, 0], pts[:, 1])
    else:
        h = np.ma.masked_all(len(pts))
    err = np.abs(pts[:, 2] - np.ma.filled(h, np.nan))
    outside = np.ma.getmaskarray(h)
    if outside.any():
        vset = {(x, y) for x, y in vertices[:, :2]}
        is_vertex = np.array([(x, y) in vset for x, y in pts[outside, :2]])
        err[np.flatnonzero(outside)[is_vertex]] = 0.0
        err[np.flatnonzero(outside)[~is_vertex]] = np.inf
    return float(err.max())


def nodata_points(terrain: GeometryData, rect: Rect) -> np.ndarray:
    """(k, 2) x, y of the nodata lattice points of a (regular or non-regular) grid in rect."""
    xs = getattr(terrain, "x_coords", getattr(terrain, "xs", None))
    ys = getattr(terrain, "y_coords", getattr(terrain, "ys", None))
    heights = getattr(terrain, "heights", None)
    if xs is None or ys is None or heights is None:
        return np.empty((0, 2))
    cols = np.flatnonzero((xs >= rect.xmin) & (xs <= rect.xmax))
    rows = np.flatnonzero((ys >= rect.ymin) & (ys <= rect.ymax))
    r, c = np.nonzero(~np.isfinite(heights[np.ix_(rows, cols)]))
    return np.column_stack([xs[cols[c]], ys[rows[r]]]).astype(np.float64)
