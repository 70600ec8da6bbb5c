"""The terrain's heights on each tile's regular lon/lat sample grid (and, through
``data_points``, its data points in each tile).

A tile of the geographic tiling is sampled at ``samples`` × ``samples`` points, its corners
included: point (i, j) at lon = west + i·d, lat = south + j·d with d = tile width /
(samples − 1), so neighbouring tiles sample their shared edge at the same points. Heights are
the terrain's h_T (bilinear on the grid) at the point carried into the terrain's CRS by pyproj.

Where h_T has no value: outside the terrain's domain the sample gets ``FILL_HEIGHT`` (0 m, the
ellipsoid, where CesiumJS shows no terrain either), except within ``edge_band`` of the domain
(1.5 sample spacings, at least 2 cells), where it gets h_T at the domain's nearest edge point
(the terrain's edge carried outward, the same in every tile); where that has no data (nodata
holes, or an edge point without data) the nearest valid sample near the terrain: along the
tile's edge on an edge (so the neighbour agrees), the nearest data point at a corner or on an
edge without any, else in the tile, or ``FILL_HEIGHT`` when the tile has none.
"""

from __future__ import annotations

from functools import cached_property

import numba
import numpy as np

from approxtree.errors import EmptyTerrainError, TerrainFormatError, UnsupportedStrategyError
from approxtree.geometry.grid import Grid
from approxtree.geometry.windowed import WindowedHeights
from approxtree.kernels.grid_interp import grid_height_at
from approxtree.tiles.data_points import PointBlocks, TilePoints

#: Height of samples outside the terrain's domain, metres.
FILL_HEIGHT = 0.0
#: Samples outside the domain but within EDGE_BAND_SPACINGS sample spacings (and at least
#: EDGE_BAND_CELLS cells) of it take the height of the domain's nearest edge point instead of
#: FILL_HEIGHT (``edge_band``): the drop to FILL_HEIGHT then lies a sample spacing or more
#: beyond every data point, with edge samples between, so that no data point sits on a cliff
#: that a quantized (integer) vertex position cannot follow (``tile_tin``).
EDGE_BAND_SPACINGS = 1.5
EDGE_BAND_CELLS = 2.0
#: Cells searched around a tile edge or corner without data for the nearest data point.
NEAREST_REACH = 64
#: The tile's lon/lat CRS.
LONLAT = "EPSG:4326"


class TileSampler:
    """Samples a georeferenced Grid on lon/lat tile grids (picklable: worker processes get one).

    terrain: a Grid with a CRS (in memory or windowed).
    """

    def __init__(self, terrain: Grid) -> None:
        if not isinstance(terrain, Grid):
            raise UnsupportedStrategyError(
                f"Quantized-mesh tiles are made from a height grid; got a "
                f"{type(terrain).__name__}. Rasterize it first (approxtree build on a DEM)."
            )
        if not terrain.crs:
            raise TerrainFormatError(
                "The terrain has no CRS, so it cannot be placed on the globe for Cesium's "
                "geographic tiles. Give the raster a CRS (gdal_edit.py -a_srs EPSG:...) and "
                "build again."
            )
        self.terrain = terrain

    def __getstate__(self) -> dict:
        return {"terrain": self.terrain}

    def __setstate__(self, state: dict) -> None:
        self.terrain = state["terrain"]

    @cached_property
    def _to_terrain(self):
        """pyproj Transformer lon/lat → terrain x, y (None when the terrain is lon/lat)."""
        from pyproj import CRS, Transformer
        from pyproj.exceptions import CRSError

        try:
            crs = CRS.from_user_input(self.terrain.crs)
        except CRSError as exc:
            raise TerrainFormatError(
                f"The terrain's CRS {self.terrain.crs!r} is not understood by PROJ ({exc})."
            ) from exc
        if crs.equals(CRS.from_user_input(LONLAT), ignore_axis_order=True):
            return None
        return Transformer.from_crs(LONLAT, crs, always_xy=True)

    @cached_property
    def footprint(self):
        """The terrain's domain in lon/lat degrees: a shapely Polygon (edges densified)."""
        from shapely import Polygon

        d = self.terrain.domain
        t = np.linspace(0.0, 1.0, 65)
        x = np.concatenate(
            [
                d.xmin + (d.xmax - d.xmin) * t,
                np.full(65, d.xmax),
                d.xmax - (d.xmax - d.xmin) * t,
                np.full(65, d.xmin),
            ]
        )
        y = np.concatenate(
            [
                np.full(65, d.ymin),
                d.ymin + (d.ymax - d.ymin) * t,
                np.full(65, d.ymax),
                d.ymax - (d.ymax - d.ymin) * t,
            ]
        )
        lon, lat = self._to_lonlat(x, y)
        if not (np.all(np.isfinite(lon)) and np.all(np.isfinite(lat))):
            raise TerrainFormatError(
                f"The terrain's domain {d} does not map to longitude/latitude through its CRS "
                f"{self.terrain.crs!r}; check the CRS."
            )
        return Polygon(np.column_stack([lon, lat]))

    @cached_property
    def blocks(self) -> PointBlocks:
        """The terrain's cell centres in lon/lat by blocks (``data_points.PointBlocks``), made
        in the process that asks (its cache is not pickled)."""
        from approxtree.tiles.data_points import PointBlocks

        return PointBlocks(self.terrain, self._to_lonlat)

    def points(self, bounds: tuple[float, float, float, float]) -> TilePoints:
        """The terrain's data points in the tile ``bounds`` (``data_points.TilePoints``)."""
        return TilePoints(self.blocks, bounds)

    def _to_lonlat(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self._to_terrain is None:
            return x, y
        return self._to_terrain.transform(x, y, direction="INVERSE")

    @cached_property
    def cell_degrees(self) -> float:
        """The terrain's cell at the domain's centre in degrees (the smaller of its lon and lat
        extents): the finest sample spacing worth a level."""
        d = self.terrain.domain
        cx, cy = 0.5 * (d.xmin + d.xmax), 0.5 * (d.ymin + d.ymax)
        dx, dy = self.terrain.cell_size
        lon, lat = self._to_lonlat(
            np.array([cx, cx + abs(dx), cx]), np.array([cy, cy, cy + abs(dy)])
        )
        span = np.hypot(np.diff(lon[[0, 1]]), np.diff(lat[[0, 1]]))[0]
        span2 = np.hypot(np.diff(lon[[0, 2]]), np.diff(lat[[0, 2]]))[0]
        return float(min(span, span2))

    def edge_band(self, spacing: float) -> float:
        """How far (cells) outside the domain a lattice of ``spacing`` degrees carries the
        domain's edge heights: EDGE_BAND_SPACINGS spacings over the terrain's cell in degrees
        (its smaller extent, so the band is at least that wide along both axes), at least
        EDGE_BAND_CELLS. The same for every tile of a level."""
        return max(EDGE_BAND_CELLS, EDGE_BAND_SPACINGS * spacing / self.cell_degrees)

    def sample(
        self, bounds: tuple[float, float, float, float], samples: int
    ) -> tuple[np.ndarray, int]:
        """Heights (samples, samples) float64 of the tile ``bounds`` (west, south, east, north),
        row 0 = south, column 0 = west, holes filled (see the module); and the count of samples
        that had a value of h_T (0: the tile lies outside the data)."""
        h, measured = self.lattice(bounds, samples)
        return h, int(np.count_nonzero(measured))

    def lattice(
        self, bounds: tuple[float, float, float, float], samples: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """``sample``'s heights (samples, samples) and where they are h_T inside the domain
        ((samples, samples) bool; elsewhere they are filled, carried from the edge or
        FILL_HEIGHT)."""
        west, south, east, north = bounds
        t = np.arange(samples, dtype=np.float64) / (samples - 1)
        lon2, lat2 = np.meshgrid(west + (east - west) * t, south + (north - south) * t)
        h, inside, near = self.heights_at(lon2, lat2, (east - west) / (samples - 1))
        measured = np.isfinite(h) & inside
        holes = near & np.isnan(h)
        if holes.any():
            # Nodata (inside, or at the edge point a band sample takes), filled from the valid
            # samples near the terrain (never from FILL_HEIGHT beyond it). On the tile's edges
            # the nearest one along the edge, which the neighbour shares (a corner: the
            # nearest data point, as all four tiles there decide alike); inside the tile the
            # nearest one, or FILL_HEIGHT when the tile has none.
            near_h = np.where(near, h, np.nan)
            for side in (np.s_[0, 1:-1], np.s_[-1, 1:-1], np.s_[1:-1, 0], np.s_[1:-1, -1]):
                edge = near_h[side]
                _fill_along(edge)
                # An edge without a valid sample near the terrain: the nearest data points.
                left = np.flatnonzero(np.isnan(edge) & near[side])
                if len(left):
                    edge[left] = self.nearest_data(lon2[side][left], lat2[side][left])
            for corner in ((0, 0), (0, -1), (-1, 0), (-1, -1)):
                if np.isnan(near_h[corner]):
                    near_h[corner] = self.nearest_data(lon2[corner], lat2[corner])[0]
            gaps = np.isnan(near_h)
            if gaps.all() or not gaps.any():
                near_h[gaps] = FILL_HEIGHT
            else:
                from scipy.ndimage import distance_transform_edt

                _, (ri, ci) = distance_transform_edt(gaps, return_indices=True)
                near_h[gaps] = near_h[ri[gaps], ci[gaps]]
            h = np.where(near, near_h, h)
        return h, measured

    def nearest_data(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """(n,) heights of the data points nearest (in cells, from each position's nearest
        cell) to (n,) lon/lat positions among those within NEAREST_REACH cells, else
        FILL_HEIGHT: a function of the positions alone, read in one window around them."""
        lon, lat = np.atleast_1d(lon), np.atleast_1d(lat)
        if self._to_terrain is None:
            x, y = lon, lat
        else:
            x, y = self._to_terrain.transform(lon, lat)
        rows, cols = self.terrain.shape
        fr, fc = self.terrain.fractional_index(x, y)
        ri = np.clip(np.rint(fr), 0, rows - 1).astype(np.int64)
        ci = np.clip(np.rint(fc), 0, cols - 1).astype(np.int64)
        r0, r1 = max(int(ri.min()) - NEAREST_REACH, 0), min(int(ri.max()) + NEAREST_REACH, rows - 1)
        c0, c1 = max(int(ci.min()) - NEAREST_REACH, 0), min(int(ci.max()) + NEAREST_REACH, cols - 1)
        z = np.asarray(self.terrain.heights[r0 : r1 + 1, c0 : c1 + 1], dtype=np.float64)
        valid = np.isfinite(z)
        if not valid.any():
            return np.full(len(lon), FILL_HEIGHT)
        from scipy.ndimage import distance_transform_edt

        dist, (nr, nc) = distance_transform_edt(~valid, return_indices=True)
        at = (ri - r0, ci - c0)
        # Off the grid (a band sample's corner) the distance from the grid's edge counts too.
        off = np.hypot(fr - np.clip(fr, 0, rows - 1), fc - np.clip(fc, 0, cols - 1))
        out = z[nr[at], nc[at]]
        return np.where(dist[at] + off <= NEAREST_REACH, out, FILL_HEIGHT)

    def heights_at(
        self, lon: np.ndarray, lat: np.ndarray, spacing: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(h, inside, near) at lon/lat points (any one shape) of a lattice of ``spacing``
        degrees: h_T inside the domain, h_T at the nearest edge point within ``edge_band`` of
        it, FILL_HEIGHT beyond, NaN where that point has no data; inside, near: bool, the first
        case and the first two. A function of the position alone, so tiles sharing an edge
        agree on it."""
        if self._to_terrain is None:
            x, y = lon, lat
        else:
            x, y = self._to_terrain.transform(lon, lat)
        g = self.terrain
        fr, fc = g.fractional_index(x, y)
        rows, cols = g.shape
        # Samples on the domain's border (a tile edge along the last data row) count as inside
        # despite round-off in the projection: 1e-6 cells of slack, then clamped onto it.
        tol = 1e-6
        inside = (fr >= -tol) & (fr <= rows - 1 + tol) & (fc >= -tol) & (fc <= cols - 1 + tol)
        cr, cc = np.clip(fr, 0.0, rows - 1), np.clip(fc, 0.0, cols - 1)
        near = inside | (np.hypot(fr - cr, fc - cc) <= self.edge_band(spacing))
        h = np.full(np.shape(fr), FILL_HEIGHT)
        if near.any():
            # h_T at fractional indices, as Grid.height_at computes it after its own mapping;
            # on one thread: a tile's samples are too few to share (tiles run in parallel
            # instead), and on a busy machine the kernel's threads cost 100× the work.
            threads = numba.get_num_threads()
            numba.set_num_threads(1)
            try:
                if isinstance(g.heights, WindowedHeights):
                    h[near] = g._windowed_height_at(cr[near], cc[near])
                else:
                    h[near] = grid_height_at(g.heights, cr[near], cc[near])
            finally:
                numba.set_num_threads(threads)
        return h, inside, near


def _fill_along(line: np.ndarray) -> None:
    """Fill the NaNs of a (n,) view in place from its nearest valid value (the lower index on
    a tie); nothing when it has no valid value."""
    ok = np.flatnonzero(np.isfinite(line))
    gaps = np.flatnonzero(np.isnan(line))
    if not len(ok) or not len(gaps):
        return
    at = (
        np.clip(np.searchsorted(ok, gaps), 1, len(ok) - 1)
        if len(ok) > 1
        else np.zeros(len(gaps), dtype=np.int64)
    )
    lo, hi = ok[at - 1] if len(ok) > 1 else ok[at], ok[at]
    nearest = np.where(gaps - lo <= hi - gaps, lo, hi)
    line[gaps] = line[nearest]


#: What a nodata-only terrain is told.
NO_DATA = "The terrain holds no valid height (nodata only): no tiles written."


def check_has_data(sampler: TileSampler) -> None:
    """EmptyTerrainError when an in-memory terrain has no valid height at all (its count is
    known). A windowed terrain is not scanned for it (a whole read of a band that may be
    bigger than memory): the tile writer counts only when no tile sampled any height."""
    if not sampler.terrain.is_windowed and sampler.terrain.point_count == 0:
        raise EmptyTerrainError(NO_DATA)
