"""An xarray / rioxarray DataArray in memory as a terrain: ``open_terrain(dataarray)``.

The georeference, orientation and nodata are read by ``geometry.dataarray`` (the same rules as
``Grid(dataarray)``); this reader adds the options ``open_terrain`` takes for files: the nodata
policy, a CRS that replaces the array's, and windowed reading.
"""

from __future__ import annotations

from typing import Any

from approxtree.errors import InvalidParameterError
from approxtree.geometry import Grid, WindowedHeights
from approxtree.geometry.dataarray import grid_parts
from approxtree.io._common import check_crs, check_nodata_policy, make_grid

#: The options of ``open_terrain`` that apply to a DataArray.
DATAARRAY_OPTIONS = ("nodata", "crs", "windowed")


def check_dataarray_options(options: dict[str, object]) -> None:
    """InvalidParameterError for an ``open_terrain`` option a DataArray does not take."""
    for name in options:
        if name not in DATAARRAY_OPTIONS:
            raise InvalidParameterError(
                f"Option {name!r} does not apply to a DataArray, which carries its own cells "
                f"and georeference; it takes {', '.join(DATAARRAY_OPTIONS)}."
            )


def read_dataarray(
    da: Any,
    *,
    nodata: str = "mask",
    crs: str | None = None,
    windowed: bool | None = None,
) -> Grid:
    """A Grid of a georeferenced DataArray (``geometry.dataarray`` says how it is placed).

    nodata: "mask" or "fill" (holes filled by interpolation; windowed, each window from a halo
    around it). crs: replaces the array's CRS. windowed: True reads by windows on demand, False
    computes the array whole, None (default) reads by windows exactly when it is dask-backed
    (a dask array is then never computed whole). Returns heights (rows, cols), row 0 north.
    """
    policy = check_nodata_policy(nodata)
    crs = check_crs(crs)
    if windowed is not None and not isinstance(windowed, bool):
        raise InvalidParameterError(f"windowed must be True, False or None, got {windowed!r}.")
    parts = grid_parts(da, windowed=windowed)
    if isinstance(parts.heights, WindowedHeights):
        from approxtree.io.raster import FilledSource

        heights = parts.heights
        if policy == "fill":
            heights = WindowedHeights(FilledSource(heights.source))
        grid = Grid(heights, parts.transform, crs=crs or parts.crs, nodata=parts.nodata)
        grid.nodata_policy = policy
        # How many cells a windowed fill filled is not known without a scan of the band.
        grid.filled_count = None if policy == "fill" else 0
        return grid
    # Without a georeference the Grid gets cell size 1, row 0 at the top (as a numpy array).
    return make_grid(parts.heights, parts.transform, crs or parts.crs, parts.nodata, policy)
