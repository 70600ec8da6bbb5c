"""Terrain readers: ``open_terrain(path, **options)`` picks the reader from the file.

One module per format family, each delegating to the library made for the format:

    raster          GDAL rasters via rasterio (GeoTIFF, ASCII grid, SRTM, USGS DEM, netCDF, ...)
    encoded_png     Terrain-RGB, Terrarium and grayscale PNGs (rasterio)
    arrays          numpy .npy / .npz
    scape           SCAPE .stm (numpy) and PGM (Pillow)
    pointcloud      LAS / LAZ (laspy + lazrs)
    quantized_mesh  Cesium quantized-mesh .terrain (quantized_mesh_tile)
    dataarray       an xarray / rioxarray DataArray in memory (no file)

Every reader raises TerrainFormatError for a missing, unknown or corrupt file (with the path
and the library's reason), EmptyTerrainError when no usable data point is left, and
InvalidParameterError for a bad option. A new format is one reader function plus one row in
``FORMATS``.
"""

from __future__ import annotations

import inspect
import os
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from approxtree.errors import InvalidParameterError, TerrainFormatError
from approxtree.geometry import GeometryData, Grid
from approxtree.geometry.dataarray import is_dataarray
from approxtree.io._common import NODATA_POLICIES, existing_file
from approxtree.io.arrays import read_array
from approxtree.io.dataarray import check_dataarray_options, read_dataarray
from approxtree.io.encoded_png import ENCODINGS, read_png
from approxtree.io.pointcloud import read_point_cloud
from approxtree.io.quantized_mesh import read_quantized_mesh, tile_bounds
from approxtree.io.raster import is_gdal_raster, read_raster
from approxtree.io.scape import read_pgm, read_stm
from approxtree.io.unitless import warn_degrees_without_crs


@dataclass(frozen=True)
class Format:
    """A terrain file format: its name in messages, its extensions and its reader."""

    name: str
    extensions: tuple[str, ...]
    reader: Callable[..., GeometryData]

    @property
    def options(self) -> tuple[str, ...]:
        """The keyword options the reader accepts."""
        params = inspect.signature(self.reader).parameters.values()
        return tuple(p.name for p in params if p.kind is inspect.Parameter.KEYWORD_ONLY)


#: Known formats, in the order they are listed to the user.
FORMATS: dict[str, Format] = {
    f.name: f
    for f in (
        Format(
            "GDAL raster",
            (".tif", ".tiff", ".asc", ".hgt", ".hgt.zip", ".zip", ".dem", ".nc", ".img", ".vrt"),
            read_raster,
        ),
        Format("height PNG", (".png",), read_png),
        Format("numpy array", (".npy", ".npz"), read_array),
        Format("SCAPE STM", (".stm",), read_stm),
        Format("PGM image", (".pgm",), read_pgm),
        Format("LAS/LAZ point cloud", (".las", ".laz"), read_point_cloud),
        Format("quantized-mesh tile", (".terrain",), read_quantized_mesh),
    )
}

# First bytes of the formats that have a signature, for files with an unknown extension.
_MAGIC = (
    (b"\x93NUMPY", "numpy array"),
    (b"STM ", "SCAPE STM"),
    (b"P2", "PGM image"),
    (b"P5", "PGM image"),
    (b"LASF", "LAS/LAZ point cloud"),
    (b"\x89PNG", "height PNG"),
)


def supported_formats() -> str:
    """One line listing the formats and their extensions, for error messages and --help."""
    return "; ".join(f"{f.name} ({', '.join(f.extensions)})" for f in FORMATS.values())


def detect_format(path: Path, encoding: str | None = None) -> Format:
    """The format of an existing file, from its extension, else from its first bytes.

    An ``encoding`` makes any image a height PNG (Terrain-RGB tiles also come as .webp).
    """
    if encoding is not None:
        return FORMATS["height PNG"]
    name = path.name.lower()
    for fmt in FORMATS.values():
        if name.endswith(fmt.extensions):
            # A .zip of .npy files is an .npz under another name.
            if fmt.name == "GDAL raster" and name.endswith(".zip") and _is_npz(path):
                return FORMATS["numpy array"]
            return fmt
    with open(path, "rb") as f:
        head = f.read(8)
    for magic, fmt_name in _MAGIC:
        if head.startswith(magic):
            return FORMATS[fmt_name]
    if head.startswith(b"PK") and _is_npz(path):
        return FORMATS["numpy array"]
    if is_gdal_raster(path):
        return FORMATS["GDAL raster"]
    raise TerrainFormatError(
        f"{path} is not a terrain format approxtree knows (extension '{path.suffix}', and GDAL "
        f"does not recognise its content). Supported formats: {supported_formats()}."
    )


def _is_npz(path: Path) -> bool:
    """True for a zip archive holding only .npy members."""
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
    except (zipfile.BadZipFile, OSError):
        return False
    return bool(names) and all(n.endswith(".npy") for n in names)


def _check_options(fmt: Format, options: dict[str, object]) -> None:
    """InvalidParameterError for an option unknown to every reader or not used by this one."""
    known = {name for f in FORMATS.values() for name in f.options}
    for name in options:
        if name not in known:
            raise InvalidParameterError(
                f"Unknown option {name!r}; the readers accept {', '.join(sorted(known))}."
            )
        if name not in fmt.options:
            users = [f.name for f in FORMATS.values() if name in f.options]
            raise InvalidParameterError(
                f"Option {name!r} does not apply to a {fmt.name} file; it applies to: "
                f"{', '.join(users)}. This format takes {', '.join(fmt.options)}."
            )


def open_terrain(path: str | os.PathLike | Any, **options: Any) -> GeometryData:
    """Read a terrain file with the reader its extension (or content) calls for; or place an
    xarray / rioxarray DataArray given in place of the path (``io.dataarray``: its transform
    or regular x/y coordinates, CRS and nodata; options nodata, crs, windowed).

    Options (None means "not given"): nodata ("mask" | "fill"), band, encoding ("terrain-rgb" |
    "terrarium"), height_scale, height_offset, ground_only, cell_size, origin, crs, key, bounds,
    windowed (GDAL rasters: True reads by windows on demand, False into memory, None/absent
    windowed above ``approxtree.io.raster.windowed_threshold()`` bytes of heights).
    Returns a Grid for rasters, images and arrays, a TINPointSet for point clouds and a TIN for
    quantized-mesh tiles. Every option is checked by the reader that takes it.
    """
    given = {name: value for name, value in options.items() if value is not None}
    if is_dataarray(path):
        check_dataarray_options(given)
        grid = read_dataarray(path, **given)
        warn_degrees_without_crs(grid, "the DataArray")
        return grid
    if not isinstance(path, str | os.PathLike):
        raise InvalidParameterError(
            f"open_terrain takes the path of a terrain file or an xarray DataArray, got "
            f"{type(path).__name__} {path!r:.40}; for a numpy array of heights use "
            "Grid(heights, transform)."
        )
    p = existing_file(path)
    fmt = detect_format(p, encoding=given.get("encoding"))
    _check_options(fmt, given)
    terrain = fmt.reader(p, **given)
    # A grid in degrees read without its CRS would be drawn as a needle: say how to fix it.
    if isinstance(terrain, Grid):
        warn_degrees_without_crs(terrain, path)
    return terrain


def read_grid(path: str | os.PathLike, **options: object) -> Grid:
    """Like open_terrain, for callers that need a Grid (rasters, images, arrays)."""
    terrain = open_terrain(path, **options)
    if not isinstance(terrain, Grid):
        raise TerrainFormatError(
            f"{path} holds a {type(terrain).__name__}, not a regular grid; use a raster, image "
            "or array file here."
        )
    return terrain


__all__ = [
    "ENCODINGS",
    "FORMATS",
    "NODATA_POLICIES",
    "Format",
    "detect_format",
    "open_terrain",
    "read_array",
    "read_dataarray",
    "read_grid",
    "read_pgm",
    "read_png",
    "read_point_cloud",
    "read_quantized_mesh",
    "read_raster",
    "read_stm",
    "supported_formats",
    "tile_bounds",
]
