"""Cesium quantized-mesh terrain tiles (``.terrain``) through the quantized_mesh_tile package.

A tile stores its vertices quantized to 0..32767 within the tile's bounds, which the file does
not contain: they come from the ``bounds`` option or from the tile address in the file name.
Cesium's geographic tiling (TMS, EPSG:4326): level 0 has 2 × 1 tiles of 180°, a tile of level Z
is 180 / 2^Z degrees wide, x counts from the west (−180°), y from the SOUTH (−90°).
The TIN has x = longitude, y = latitude in degrees and z = height in metres.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from pathlib import Path

import numpy as np

from approxtree.errors import TerrainFormatError
from approxtree.geometry import TIN
from approxtree.io._common import check_bounds, existing_file, reading

#: CRS of the tile's longitudes and latitudes.
TILE_CRS = "EPSG:4326"

_GZIP_MAGIC = b"\x1f\x8b"
_FLAT_NAME = re.compile(r"^(\d+)_(\d+)_(\d+)$")


def tile_bounds(level: int, x: int, y: int) -> tuple[float, float, float, float]:
    """(west, south, east, north) in degrees of tile (level, x, y) of Cesium's geographic TMS."""
    if not (0 <= x < 2 ** (level + 1) and 0 <= y < 2**level):
        raise TerrainFormatError(
            f"Tile {level}/{x}/{y} does not exist: level {level} has x 0..{2 ** (level + 1) - 1} "
            f"and y 0..{2**level - 1}."
        )
    size = 180.0 / 2**level
    west, south = -180.0 + x * size, -90.0 + y * size
    return (west, south, west + size, south + size)


def address_from_path(path: Path) -> tuple[int, int, int] | None:
    """(level, x, y) from a name ``Z_X_Y.terrain`` or a tile-server layout ``Z/X/Y.terrain``."""
    match = _FLAT_NAME.match(path.stem)
    if match:
        return int(match.group(1)), int(match.group(2)), int(match.group(3))
    parts = [path.parent.parent.name, path.parent.name, path.stem]
    if all(part.isdigit() for part in parts):
        return int(parts[0]), int(parts[1]), int(parts[2])
    return None


def read_quantized_mesh(
    path: str | os.PathLike,
    *,
    bounds: tuple[float, float, float, float] | None = None,
) -> TIN:
    """Read a quantized-mesh tile as a TIN: vertices (n, 3) lon, lat, height; triangles (m, 3).

    bounds: (west, south, east, north) in degrees; by default taken from the tile address in
    the file name.
    """
    p = existing_file(path)
    box = check_bounds(bounds)
    if box is None:
        address = address_from_path(p)
        if address is None:
            raise TerrainFormatError(
                f"The bounds of {p} are unknown: a quantized-mesh tile does not store them. "
                "Pass bounds=(west, south, east, north) in degrees (CLI: --bounds), or name the "
                "file Z_X_Y.terrain after its tile address."
            )
        box = tile_bounds(*address)
    with reading(p, "a quantized-mesh tile"):
        import quantized_mesh_tile

        with open(p, "rb") as f:
            gzipped = f.read(2) == _GZIP_MAGIC
        # Extensions (normals, water mask, metadata) are skipped; only geometry is needed.
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Skipping unsupported terrain tile")
            tile = quantized_mesh_tile.decode(str(p), box, gzipped=gzipped)
        vertices = np.asarray(tile.getVerticesCoordinates(), dtype=np.float64).reshape(-1, 3)
        triangles = np.asarray(tile.indices, dtype=np.int64).reshape(-1, 3)
        centre = (tile.header["centerX"], tile.header["centerY"], tile.header["centerZ"])
    if bounds is None:
        _check_centre(p, box, centre)
    return TIN(vertices, triangles, crs=TILE_CRS)


def _check_centre(
    path: Path, box: tuple[float, float, float, float], centre: tuple[float, float, float]
) -> None:
    """Check that the tile's ECEF centre (from its header) lies in bounds guessed from its name.

    A mismatch means the name does not follow Cesium's geographic tiling (web-mercator tiles,
    y counted from the north); a zero centre says nothing and is accepted.
    """
    x, y, z = centre
    if x == 0.0 and y == 0.0 and z == 0.0:
        return
    lon = math.degrees(math.atan2(y, x))
    lat = math.degrees(math.atan2(z, math.hypot(x, y)))
    west, south, east, north = box
    # Geocentric latitude differs from geodetic by < 0.2°; half a degree of slack covers it.
    tol = max(east - west, north - south, 0.5)
    if not (west - tol <= lon <= east + tol and south - tol <= lat <= north + tol):
        raise TerrainFormatError(
            f"{path}: the tile's centre ({lon:.4f}°, {lat:.4f}°) lies outside the bounds "
            f"{box} derived from its name with Cesium's geographic tiling. Pass "
            "bounds=(west, south, east, north) explicitly (CLI: --bounds)."
        )
