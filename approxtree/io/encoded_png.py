"""Heights stored in PNG pixels: Terrain-RGB, Terrarium and grayscale (8- or 16-bit) PNGs.

Pixels are read with rasterio, which also picks up a world file (.pgw) or .aux.xml for the
georeference; without one the cell size is 1 and row 0 is the top row (or cell_size/origin).

Encodings (R, G, B are 0..255):
    terrain-rgb (Mapbox):  h = -10000 + (R * 256 * 256 + G * 256 + B) * 0.1
    terrarium (Mapzen):    h = R * 256 + G + B / 256 - 32768
    grayscale:             h = raw * height_scale + height_offset
Pixels with alpha 0 are nodata.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from approxtree.errors import InvalidParameterError, TerrainDataWarning, TerrainFormatError
from approxtree.geometry import Grid
from approxtree.io._common import (
    check_cell_size,
    check_claimed_bytes,
    check_crs,
    check_nodata_policy,
    check_number,
    check_origin,
    existing_file,
    make_grid,
    own_transform,
    reading,
    resolve_transform,
)
from approxtree.io.gdal import no_side_files

#: Known RGB height encodings.
ENCODINGS = ("terrain-rgb", "terrarium")

#: Heights (m) an Earth terrain can have: the Challenger Deep (−10,935 m) to Everest (8,849 m)
#: with a margin. Decoded heights beyond them mean the image is not height-encoded.
EARTH_HEIGHTS = (-12_000.0, 9_000.0)


def decode_terrain_rgb(rgb: np.ndarray) -> np.ndarray:
    """Mapbox Terrain-RGB: rgb (3, rows, cols) uint8 → heights (rows, cols) float32, 0.1 m steps."""
    r, g, b = (c.astype(np.int64) for c in rgb)
    return (-10000.0 + (r * 65536 + g * 256 + b) * 0.1).astype(np.float32)


def decode_terrarium(rgb: np.ndarray) -> np.ndarray:
    """Mapzen Terrarium: rgb (3, rows, cols) uint8 → heights (rows, cols) float32, 1/256 m steps."""
    r, g, b = (c.astype(np.float64) for c in rgb)
    return (r * 256.0 + g + b / 256.0 - 32768.0).astype(np.float32)


_DECODERS = {"terrain-rgb": decode_terrain_rgb, "terrarium": decode_terrarium}


def check_encoding(encoding: object) -> str | None:
    """The encoding name, or InvalidParameterError naming the known ones."""
    if encoding is None:
        return None
    if not isinstance(encoding, str) or encoding.lower() not in ENCODINGS:
        raise InvalidParameterError(
            f"Unknown height encoding {encoding!r}; use 'terrain-rgb' (Mapbox) or 'terrarium' "
            "(Mapzen), or leave it out for a grayscale PNG."
        )
    return encoding.lower()


def _split_bands(ds) -> tuple[list[int], np.ndarray]:
    """(1-based colour band numbers, (rows, cols) bool valid mask from alpha/nodata)."""
    from rasterio.enums import ColorInterp

    colour = [i + 1 for i, ci in enumerate(ds.colorinterp) if ci != ColorInterp.alpha]
    valid = ds.dataset_mask() > 0
    return colour, valid


def read_png(
    path: str | os.PathLike,
    *,
    encoding: str | None = None,
    height_scale: float | None = None,
    height_offset: float | None = None,
    nodata: str = "mask",
    crs: str | None = None,
    cell_size: float | tuple[float, float] | None = None,
    origin: tuple[float, float] | None = None,
) -> Grid:
    """Read a height-encoding PNG (or any raster of RGB pixels) as a Grid.

    encoding: "terrain-rgb", "terrarium", or None for a one-band grayscale image whose heights
    are raw * height_scale + height_offset (defaults 1 and 0). Returns heights (rows, cols).
    """
    p = existing_file(path)
    encoding = check_encoding(encoding)
    policy = check_nodata_policy(nodata)
    crs = check_crs(crs)
    cell = check_cell_size(cell_size)
    corner = check_origin(origin)
    if encoding is not None and (height_scale is not None or height_offset is not None):
        raise InvalidParameterError(
            f"height_scale and height_offset apply to grayscale PNGs only; the {encoding} "
            "encoding fixes the scale. Leave them out."
        )
    scale = (
        1.0 if height_scale is None else check_number(height_scale, "height_scale", nonzero=True)
    )
    offset = 0.0 if height_offset is None else check_number(height_offset, "height_offset")

    with reading(p, "a height PNG"):
        import rasterio
        from rasterio.enums import ColorInterp
        from rasterio.errors import NotGeoreferencedWarning

        # Plain PNGs have no georeference; they get cell size 1 below.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with no_side_files(), rasterio.open(p) as ds:
                # Every band, the mask and the float heights: about (count + 3) × 8 bytes a cell.
                cells = ds.width * ds.height
                need = cells * 8 * (ds.count + 3)
                check_claimed_bytes(p, need, None, f"{ds.width} × {ds.height} pixels")
                colour, valid = _split_bands(ds)
                dtype = np.dtype(ds.dtypes[0])
                palette = ds.colorinterp[0] == ColorInterp.palette
                pixels = ds.read(colour)
                own = own_transform(ds)
                file_crs = ds.crs.to_string() if ds.crs else None

    if encoding is None:
        heights = _grayscale(p, pixels, dtype, palette, scale, offset)
    else:
        if len(colour) < 3 or dtype != np.uint8:
            raise TerrainFormatError(
                f"{p} must be an 8-bit RGB(A) image for the {encoding} encoding; it has "
                f"{len(colour)} colour band(s) of {dtype}."
            )
        heights = _DECODERS[encoding](pixels[:3])
    heights[~valid] = np.nan
    if encoding is not None:
        _warn_unearthly(p, heights, encoding)
    transform = resolve_transform(own, heights.shape, cell, corner, p)
    return make_grid(heights, transform, crs or file_crs, None, policy)


def _warn_unearthly(path: os.PathLike, heights: np.ndarray, encoding: str) -> None:
    """TerrainDataWarning when decoded heights (rows, cols) leave EARTH_HEIGHTS.

    Any RGB image decodes to some height (a photo read as Terrain-RGB reaches 1,667 km), so a
    range no terrain has is the sign of an image that does not encode heights.
    """
    valid = heights[np.isfinite(heights)]
    if valid.size == 0:
        return
    lo, hi = float(valid.min()), float(valid.max())
    if lo < EARTH_HEIGHTS[0] or hi > EARTH_HEIGHTS[1]:
        warnings.warn(
            f"{path} decoded as {encoding} has heights {lo:,.1f} .. {hi:,.1f} m, beyond any "
            f"terrain on Earth ({EARTH_HEIGHTS[0]:,.0f} .. {EARTH_HEIGHTS[1]:,.0f} m): check "
            "that the image really is a "
            f"{encoding} height tile (and the encoding is the right one).",
            TerrainDataWarning,
            stacklevel=3,
        )


def _grayscale(
    path: os.PathLike,
    pixels: np.ndarray,
    dtype: np.dtype,
    palette: bool,
    scale: float,
    offset: float,
) -> np.ndarray:
    """Heights (rows, cols) float32 from one gray band (1, rows, cols): raw * scale + offset."""
    if len(pixels) >= 3:
        raise TerrainFormatError(
            f"{path} is a colour ({len(pixels)}-band) image: pass encoding='terrain-rgb' or "
            "encoding='terrarium' (CLI: --encoding) to say how its pixels encode heights."
        )
    if palette:
        raise TerrainFormatError(
            f"{path} is a palette image, not a height field: convert it to grayscale, or pass "
            "encoding='terrain-rgb' or 'terrarium' (CLI: --encoding) for RGB-encoded heights."
        )
    if dtype.kind not in "iuf":
        raise TerrainFormatError(f"{path} has pixels of {dtype}, not heights.")
    return (pixels[0].astype(np.float64) * scale + offset).astype(np.float32)
