"""The terrain's heights on each tile's regular lon/lat sample grid.

A tile of the geographic tiling is sampled at ``samples`` × ``samples`` points, its corners
included: point (i, j) at lon = west + i·d, lat = south + j·d with d = tile width /
(samples − 1), so neighbouring tiles sample their shared edge at the same points. Heights are
the terrain's h_T (bilinear on the grid) at the point carried into the terrain's CRS by pyproj.

Where h_T has no value: outside the terrain's domain the sample gets ``FILL_HEIGHT`` (0 m, the
ellipsoid, where CesiumJS shows no terrain either); inside it (nodata holes) the nearest valid
sample of the same tile, or ``FILL_HEIGHT`` when the tile has none.
"""

from __future__ import annotations

from functools import cached_property

import numba
import numpy as np

from approxtree.errors import EmptyTerrainError, TerrainFormatError, UnsupportedStrategyError
from approxtree.geometry.grid import Grid
from approxtree.kernels.grid_interp import grid_height_at

#: Height of samples outside the terrain's domain, metres.
FILL_HEIGHT = 0.0
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

    def sample(
        self, bounds: tuple[float, float, float, float], samples: int
    ) -> tuple[np.ndarray, int]:
        """Heights (samples, samples) float64 of the tile ``bounds`` (west, south, east, north),
        row 0 = south, column 0 = west, holes filled (see the module); and the count of samples
        that had a value of h_T (0: the tile lies outside the data)."""
        west, south, east, north = bounds
        t = np.arange(samples, dtype=np.float64) / (samples - 1)
        lon = west + (east - west) * t
        lat = south + (north - south) * t
        lon2, lat2 = np.meshgrid(lon, lat)
        if self._to_terrain is None:
            x, y = lon2, lat2
        else:
            x, y = self._to_terrain.transform(lon2, lat2)
        g = self.terrain
        fr, fc = g.fractional_index(x, y)
        rows, cols = g.shape
        # Samples on the domain's border (a tile edge along the last data row) count as inside
        # despite round-off in the projection: 1e-6 cells of slack, then clamped onto it.
        tol = 1e-6
        inside = (fr >= -tol) & (fr <= rows - 1 + tol) & (fc >= -tol) & (fc <= cols - 1 + tol)
        h = np.full((samples, samples), FILL_HEIGHT)
        if inside.any():
            fr_in = np.clip(fr[inside], 0.0, rows - 1)
            fc_in = np.clip(fc[inside], 0.0, cols - 1)
            # h_T at fractional indices, as Grid.height_at computes it after its own mapping;
            # on one thread: a tile's samples are too few to share (tiles run in parallel
            # instead), and on a busy machine the kernel's threads cost 100× the work.
            threads = numba.get_num_threads()
            numba.set_num_threads(1)
            try:
                if g.is_windowed:
                    h[inside] = g._windowed_height_at(fr_in, fc_in)
                else:
                    h[inside] = grid_height_at(g.heights, fr_in, fc_in)
            finally:
                numba.set_num_threads(threads)
        valid = np.isfinite(h) & inside
        holes = inside & ~valid
        n_valid = int(np.count_nonzero(valid))
        if holes.any():
            if n_valid == 0:
                h[holes] = FILL_HEIGHT
            else:
                from scipy.ndimage import distance_transform_edt

                _, (ri, ci) = distance_transform_edt(~valid, return_indices=True)
                h[holes] = h[ri[holes], ci[holes]]
        return h, n_valid


#: What a nodata-only terrain is told.
NO_DATA = "The terrain holds no valid height (nodata only): no tiles written."


def check_has_data(sampler: TileSampler) -> None:
    """EmptyTerrainError when an in-memory terrain has no valid height at all (its count is
    known). A windowed terrain is not scanned for it (a whole read of a band that may be
    bigger than memory): the tile writer counts only when no tile sampled any height."""
    if not sampler.terrain.is_windowed and sampler.terrain.point_count == 0:
        raise EmptyTerrainError(NO_DATA)
