"""The true errors of decoded quantized-mesh tiles at a terrain's data points, recomputed here.

Independent of approxtree.tiles: the terrain's valid cell centres are carried to lon/lat by
pyproj here, the tiles' (u, v) are found from their bounds, and each decoded TIN (as
CesiumJS decodes it: quantized u, v and heights lerp(min, max, h / 32767)) is interpolated
linearly in (u, v) with matplotlib's triangle finder (a brute-force barycentric search for
the few points it misses on the tile's border).
"""

from __future__ import annotations

import numpy as np

QMAX = 32767


class DataPoints:
    """Every valid cell centre of a Grid in lon/lat: lon, lat, z (n,) float64."""

    def __init__(self, terrain) -> None:
        from pyproj import CRS, Transformer

        z = np.asarray(terrain.heights[:, :], dtype=np.float64)
        rr, cc = np.nonzero(np.isfinite(z))
        x, y = terrain.x_coords[cc], terrain.y_coords[rr]
        crs = CRS.from_user_input(terrain.crs)
        if crs.equals(CRS.from_epsg(4326), ignore_axis_order=True):
            self.lon, self.lat = x, y
        else:
            to = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
            self.lon, self.lat = (np.asarray(a) for a in to.transform(x, y))
        self.z = z[rr, cc]

    def in_tile(self, bounds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(u, v, z) of the points in the tile's closed lon/lat square."""
        west, south, east, north = bounds
        sel = (self.lon >= west) & (self.lon <= east) & (self.lat >= south) & (self.lat <= north)
        u = (self.lon[sel] - west) / (east - west) * QMAX
        v = (self.lat[sel] - south) / (north - south) * QMAX
        return u, v, self.z[sel]


def tin_at(u_vert, v_vert, h_vert, tri, u, v) -> np.ndarray:
    """The TIN (vertices u_vert, v_vert, h_vert (n,), triangles (m, 3)) at points u, v (q,),
    linear in (u, v); NaN where no triangle holds a point."""
    import matplotlib.tri as mtri

    t = mtri.Triangulation(u_vert.astype(float), v_vert.astype(float), tri)
    out = np.asarray(mtri.LinearTriInterpolator(t, h_vert)(u, v).filled(np.nan), dtype=float)
    missed = np.flatnonzero(~np.isfinite(out))
    if len(missed):
        a, b, c = (np.column_stack([u_vert, v_vert])[tri[:, k]].astype(float) for k in range(3))
        det = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
        for i in missed:
            x, y = u[i], v[i]
            l1 = ((b[:, 1] - c[:, 1]) * (x - c[:, 0]) + (c[:, 0] - b[:, 0]) * (y - c[:, 1])) / det
            l2 = ((c[:, 1] - a[:, 1]) * (x - c[:, 0]) + (a[:, 0] - c[:, 0]) * (y - c[:, 1])) / det
            l3 = 1.0 - l1 - l2
            hit = np.flatnonzero((l1 >= -1e-9) & (l2 >= -1e-9) & (l3 >= -1e-9))
            if len(hit):
                k = hit[0]
                a0, a1, a2 = tri[k]
                out[i] = l1[k] * h_vert[a0] + l2[k] * h_vert[a1] + l3[k] * h_vert[a2]
    return out


def cell_degrees(terrain) -> float:
    """The terrain's cell at its domain's centre in degrees (the smaller of its lon and lat
    extents), recomputed with pyproj."""
    from pyproj import CRS, Transformer

    d = terrain.domain
    cx, cy = 0.5 * (d.xmin + d.xmax), 0.5 * (d.ymin + d.ymax)
    dx, dy = terrain.cell_size
    crs = CRS.from_user_input(terrain.crs)
    if crs.equals(CRS.from_epsg(4326), ignore_axis_order=True):
        return float(min(dx, dy))
    to = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = to.transform(np.array([cx, cx + dx, cx]), np.array([cy, cy, cy + dy]))
    return float(
        min(np.hypot(lon[1] - lon[0], lat[1] - lat[0]), np.hypot(lon[2] - lon[0], lat[2] - lat[0]))
    )
