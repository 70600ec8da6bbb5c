"""The water-mask extension of a terrain tile from a land/water raster.

The raster (any CRS) says water where its value is nonzero (nodata and outside: land). Each
tile gets 256 × 256 bytes (row 0 = north, 255 = water, 0 = land; nearest raster cell at each
pixel centre), or a single byte when the tile is all land (0) or all water (255).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Literal

import numpy as np

from approxtree.errors import TerrainFormatError
from approxtree.geometry.grid import Grid

if TYPE_CHECKING:
    # pyproj is imported when a mask is first resampled; here for the annotations only.
    from pyproj import Transformer

#: Side of a water mask in pixels (fixed by the format).
MASK_SIZE = 256


class WaterMask:
    """A land/water raster ready to be resampled per tile (picklable)."""

    def __init__(self, grid: Grid) -> None:
        if not grid.crs:
            raise TerrainFormatError(
                "The water-mask raster has no CRS, so it cannot be placed on the tiles; give it "
                "one (gdal_edit.py -a_srs EPSG:...)."
            )
        self.grid = grid
        #: lon/lat → the grid's CRS: None until first needed, False when it is lon/lat already.
        self._transformer: Transformer | Literal[False] | None = None

    @classmethod
    def open(cls, path: str | os.PathLike) -> WaterMask:
        """Read a land/water raster (nonzero = water)."""
        from approxtree.io import open_terrain

        terrain = open_terrain(path)
        if not isinstance(terrain, Grid):
            raise TerrainFormatError(
                f"{path}: a water mask must be a raster (nonzero = water), got a "
                f"{type(terrain).__name__}."
            )
        return cls(terrain)

    def __getstate__(self) -> dict:
        return {"grid": self.grid}

    def __setstate__(self, state: dict) -> None:
        self.grid = state["grid"]
        self._transformer = None

    def _xy(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from pyproj import CRS, Transformer

        transformer = self._transformer
        if transformer is None:
            crs = CRS.from_user_input(self.grid.crs)
            if crs.equals(CRS.from_user_input("EPSG:4326"), ignore_axis_order=True):
                transformer = False
            else:
                transformer = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
            self._transformer = transformer
        if transformer is False:
            return lon, lat
        return transformer.transform(lon, lat)

    def tile_mask(self, bounds: tuple[float, float, float, float]) -> np.ndarray | int:
        """(256, 256) uint8 mask of the tile (row 0 north), or 0 / 255 when uniform."""
        west, south, east, north = bounds
        t = (np.arange(MASK_SIZE) + 0.5) / MASK_SIZE
        lon, lat = np.meshgrid(west + (east - west) * t, north - (north - south) * t)
        x, y = self._xy(lon, lat)
        fr, fc = self.grid.fractional_index(x, y)
        r, c = np.rint(fr), np.rint(fc)
        rows, cols = self.grid.shape
        inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
        water = np.zeros((MASK_SIZE, MASK_SIZE), dtype=bool)
        if inside.any():
            z = self.grid.heights[r[inside].astype(np.int64), c[inside].astype(np.int64)]
            water[inside] = np.isfinite(z) & (z != 0)
        if not water.any():
            return 0
        if water.all():
            return 255
        return np.where(water, 255, 0).astype(np.uint8)
