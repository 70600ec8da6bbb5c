"""GDAL rasters through rasterio: GeoTIFF, ESRI ASCII, SRTM .hgt(.zip), USGS DEM, netCDF, ...

The grid keeps the dataset's affine transform and CRS. Cells that rasterio masks (the nodata
value, NaN, an internal or alpha mask) become NaN and are never data points.
"""

from __future__ import annotations

import os
import warnings
import zipfile
from pathlib import Path

import numpy as np

from approxtree.errors import InvalidParameterError, TerrainFormatError
from approxtree.geometry import Grid
from approxtree.io._common import (
    as_heights,
    check_cell_size,
    check_claimed_bytes,
    check_crs,
    check_nodata_policy,
    check_origin,
    existing_file,
    make_grid,
    own_transform,
    reading,
    resolve_transform,
)

#: Extensions of rasters GDAL reads that we look for inside a .zip.
RASTER_EXTENSIONS = (".tif", ".tiff", ".asc", ".hgt", ".dem", ".nc", ".img", ".bil", ".flt", ".vrt")


def rasterio_source(path: Path) -> str:
    """The name rasterio opens: the path itself, or ``zip://path!member`` for a zipped raster."""
    if path.suffix.lower() != ".zip":
        return str(path)
    with reading(path, "a zip archive"), zipfile.ZipFile(path) as archive:
        members = [m for m in archive.namelist() if not m.endswith("/")]
    rasters = [m for m in members if m.lower().endswith(RASTER_EXTENSIONS)]
    # A zip of one file is read whatever that file is called.
    if not rasters and len(members) == 1:
        rasters = members
    if len(rasters) != 1:
        found = ", ".join(members) or "nothing"
        raise TerrainFormatError(
            f"{path} must hold exactly one raster ({', '.join(RASTER_EXTENSIONS)}); it holds "
            f"{found}. Unzip it and open the raster you want."
        )
    return f"zip://{path}!{rasters[0]}"


#: GDAL block cache (MB) while a band is read whole.
_READ_CACHE_MB = 64


def read_raster(
    path: str | os.PathLike,
    *,
    band: int = 1,
    nodata: str = "mask",
    crs: str | None = None,
    cell_size: float | tuple[float, float] | None = None,
    origin: tuple[float, float] | None = None,
) -> Grid:
    """Read one band of a GDAL raster as a Grid.

    band: 1-based band number. nodata: "mask" or "fill". crs: replaces the file's CRS.
    cell_size, origin: georeference for a raster without one (cell size 1, row 0 at the top
    otherwise). Returns a Grid with heights (rows, cols) float32 (float64 for float64 data).
    """
    p = existing_file(path)
    policy = check_nodata_policy(nodata)
    crs = check_crs(crs)
    cell = check_cell_size(cell_size)
    corner = check_origin(origin)
    if isinstance(band, bool) or not isinstance(band, int | np.integer) or band < 1:
        raise InvalidParameterError(f"band must be a band number ≥ 1, got {band!r}.")
    source = rasterio_source(p)
    with reading(p, "a GDAL raster (GeoTIFF, ASCII grid, SRTM, USGS DEM, netCDF, ...)"):
        import rasterio
        from rasterio.errors import NotGeoreferencedWarning

        # A raster without georeference is fine: it gets cell size 1 below. The band is read
        # once, so a small block cache: GDAL's default (5 % of RAM) would hold a second copy.
        with warnings.catch_warnings(), rasterio.Env(GDAL_CACHEMAX=_READ_CACHE_MB):
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(source) as ds:
                if band > ds.count:
                    raise InvalidParameterError(
                        f"band {band} does not exist: {p} has {ds.count} band(s)."
                    )
                # The band, its mask and the float heights: about 3 × 8 bytes a cell.
                cells = ds.width * ds.height
                check_claimed_bytes(p, cells * 24, None, f"{ds.width} × {ds.height} cells")
                values = ds.read(int(band), masked=True)
                own = own_transform(ds)
                file_crs = ds.crs.to_string() if ds.crs else None
                nodata_value = ds.nodata
    # The band read is ours: float32 data get their NaNs in place (no second DEM in memory).
    heights = as_heights(values, reuse=True)
    del values
    transform = resolve_transform(own, heights.shape, cell, corner, p)
    return make_grid(heights, transform, crs or file_crs, nodata_value, policy)


def is_gdal_raster(path: Path) -> bool:
    """True when GDAL recognises the file as a raster (used for unknown extensions)."""
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(rasterio_source(path)) as ds:
                return ds.count > 0
    except Exception:
        return False
