"""Shared pieces of the terrain readers: option checks, error wrapping, nodata policy, georeference.

Every reader turns a library's own exceptions into TerrainFormatError through ``reading`` and
checks its keyword options here, so that all readers word their messages the same way.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
from affine import Affine

from approxtree.errors import ApproxTreeError, InvalidParameterError, TerrainFormatError
from approxtree.geometry import Grid

#: Nodata policies: "mask" leaves nodata cells out, "fill" interpolates holes from their border.
NODATA_POLICIES = ("mask", "fill")

#: How far (in cells) the "fill" policy searches for valid cells; holes wider stay nodata.
FILL_SEARCH_DISTANCE = 100.0

#: Integers beyond ±2^24 are not exact in float32; such grids are stored as float64.
_FLOAT32_EXACT_LIMIT = 2**24


# -- paths and errors --------------------------------------------------------------------------


def existing_file(path: str | os.PathLike) -> Path:
    """The path as a Path, or TerrainFormatError when it is missing or not a file."""
    p = Path(path)
    if not p.exists():
        raise TerrainFormatError(f"The terrain file {p} does not exist; check the path.")
    if not p.is_file():
        raise TerrainFormatError(f"{p} is a folder, not a terrain file; give a file inside it.")
    return p


def _reason(exc: BaseException) -> str:
    """The library's message for an exception, or its type name when it has none. A message
    that only points at the exception before it (rasterio's "Read failed. See previous
    exception for details.") gives way to the innermost one in the chain (GDAL's own)."""
    while "previous exception" in str(exc) and exc.__cause__ is not None:
        exc = exc.__cause__
        while exc.__cause__ is not None:
            exc = exc.__cause__
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


@contextlib.contextmanager
def reading(path: str | os.PathLike, what: str) -> Iterator[None]:
    """Turn any library exception raised inside the block into TerrainFormatError.

    Our own ApproxTreeErrors (and MemoryError) pass through unchanged.
    """
    try:
        yield
    except (ApproxTreeError, MemoryError):
        raise
    except Exception as exc:
        raise TerrainFormatError(f"Cannot read {path} as {what}: {_reason(exc)}") from exc


def check_shapefile_length(path: str | os.PathLike) -> None:
    """TerrainFormatError when a shapefile's .shp (or its .shx) is shorter than its header
    says: GDAL reads a truncated shapefile without a word, the features past the cut with no
    geometry. Any other file is left to its reader."""
    path = Path(path)
    if path.suffix.lower() != ".shp":
        return
    index = [p for p in (path.with_suffix(".shx"), path.with_suffix(".SHX")) if p.is_file()]
    for part in [path, *index[:1]]:
        with open(part, "rb") as f:
            header = f.read(100)
        # Bytes 0-3: file code 9994; bytes 24-27: the file's length in 16-bit words (both
        # big-endian, ESRI's shapefile white paper).
        if len(header) < 100 or int.from_bytes(header[:4], "big") != 9994:
            raise TerrainFormatError(
                f"{part} is not a shapefile part (no shapefile header); restore it from a copy."
            )
        declared = int.from_bytes(header[24:28], "big") * 2
        actual = part.stat().st_size
        if actual < declared:
            raise TerrainFormatError(
                f"{part} is truncated: its header declares {declared} bytes, the file holds "
                f"{actual}. Restore it from a copy."
            )


#: Workers (processes or threads) per core at most: more only wait for a core.
MAX_WORKERS_PER_CORE = 4


def most_workers() -> int:
    """The most workers a local pool may start here: MAX_WORKERS_PER_CORE × the core count."""
    return MAX_WORKERS_PER_CORE * (os.cpu_count() or 1)


def available_memory() -> int:
    """Bytes of memory this process may still use: MemAvailable, else the physical memory."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 2**40


def check_claimed_bytes(path: Path, claimed: int, present: int | None, what: str) -> None:
    """TerrainFormatError when a header claims more bytes than the file holds or memory fits.

    Libraries allocate what a header claims before reading: a few flipped bits ask for
    hundreds of GB (MemoryError, or the system's OOM killer). present: bytes of data the file
    holds, or None for compressed data whose size says nothing.
    """
    if present is not None and claimed > present:
        raise TerrainFormatError(
            f"{path} is truncated or corrupt: its header claims {what} ({claimed} bytes), but "
            f"only {present} bytes of data follow."
        )
    memory = available_memory()
    if claimed > memory:
        raise TerrainFormatError(
            f"{path} claims {what}, {claimed / 1e9:.1f} GB, more than the {memory / 1e9:.1f} GB "
            "of memory available; crop or tile it first."
        )


# -- option checks -----------------------------------------------------------------------------


def check_nodata_policy(nodata: str) -> str:
    """The nodata policy, or InvalidParameterError naming the valid ones."""
    if not isinstance(nodata, str) or nodata not in NODATA_POLICIES:
        raise InvalidParameterError(
            f"Unknown nodata policy {nodata!r}; use 'mask' (leave nodata cells out) or "
            "'fill' (interpolate holes from their border)."
        )
    return nodata


def _finite_number(value: object, name: str) -> float:
    """A real finite number, or InvalidParameterError."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidParameterError(f"{name} must be a number, got {value!r}.")
    number = float(value)
    if not math.isfinite(number):
        raise InvalidParameterError(f"{name} must be finite, got {value!r}.")
    return number


def _number_pair(value: object, name: str) -> tuple[float, float]:
    """Two finite numbers from a 2-sequence, or InvalidParameterError."""
    try:
        items = list(value) if isinstance(value, Iterable) else []
    except TypeError:
        items = []
    if len(items) != 2:
        raise InvalidParameterError(f"{name} must be a pair of numbers (x, y), got {value!r}.")
    return (_finite_number(items[0], name), _finite_number(items[1], name))


def check_cell_size(cell_size: object) -> tuple[float, float] | None:
    """(dx, dy) from a positive number or a pair of positive numbers; None stays None."""
    if cell_size is None:
        return None
    if isinstance(cell_size, int | float | np.integer | np.floating) and not isinstance(
        cell_size, bool
    ):
        dx = dy = _finite_number(cell_size, "cell_size")
    else:
        dx, dy = _number_pair(cell_size, "cell_size")
    if dx <= 0 or dy <= 0:
        raise InvalidParameterError(f"cell_size must be positive, got {cell_size!r}.")
    return (dx, dy)


def check_origin(origin: object) -> tuple[float, float] | None:
    """(x of the left edge, y of the top edge), or None."""
    return None if origin is None else _number_pair(origin, "origin")


def check_bounds(bounds: object) -> tuple[float, float, float, float] | None:
    """(west, south, east, north) with west < east and south < north, or None."""
    if bounds is None:
        return None
    try:
        items = list(bounds) if isinstance(bounds, Iterable) else []
    except TypeError:
        items = []
    if len(items) != 4:
        raise InvalidParameterError(
            f"bounds must be four numbers (west, south, east, north), got {bounds!r}."
        )
    west, south, east, north = (_finite_number(v, "bounds") for v in items)
    if not (west < east and south < north):
        raise InvalidParameterError(
            f"bounds must satisfy west < east and south < north, got {bounds!r}."
        )
    return (west, south, east, north)


def check_crs(crs: object) -> str | None:
    """A CRS string (EPSG code, PROJ string or WKT) that pyproj understands, or None."""
    if crs is None:
        return None
    if not isinstance(crs, str) or not crs.strip():
        raise InvalidParameterError(
            f"crs must be a non-empty string such as 'EPSG:4326' or a WKT, got {crs!r}."
        )
    # A CRS no library can read would fail later, at the first display scale or reprojection.
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        CRS.from_user_input(crs.strip())
    except CRSError as exc:
        raise InvalidParameterError(
            f"crs {crs.strip()!r} is not a CRS pyproj knows ({exc}); give an EPSG code such as "
            "'EPSG:4326', a PROJ string or a WKT."
        ) from None
    return crs.strip()


def check_flag(value: object, name: str) -> bool:
    """A boolean option, or InvalidParameterError."""
    if not isinstance(value, bool | np.bool_):
        raise InvalidParameterError(f"{name} must be True or False, got {value!r}.")
    return bool(value)


def check_number(value: object, name: str, *, nonzero: bool = False) -> float:
    """A finite number (non-zero when asked), or InvalidParameterError."""
    number = _finite_number(value, name)
    if nonzero and number == 0.0:
        raise InvalidParameterError(f"{name} must not be zero.")
    return number


# -- heights and georeference ------------------------------------------------------------------


def as_heights(values: np.ndarray, reuse: bool = False) -> np.ndarray:
    """Heights as float32, or float64 when that is needed to keep the values exact.

    values: (rows, cols) real numbers or a masked array; masked and infinite cells become NaN.
    reuse: the caller gives up ``values`` (a reader's own buffer), so when its dtype already
    is the heights' the NaNs are written into it instead of into a full-size copy.
    """
    a = values
    dtype = np.dtype(a.dtype)
    if dtype.kind not in "iuf":
        raise TerrainFormatError(f"Heights must be real numbers, got an array of {dtype}.")
    wide = dtype == np.float64
    # Wide integers keep float64 only when their valid values leave float32's exact range.
    if dtype.kind in "iu" and dtype.itemsize >= 4:
        valid = a.compressed() if np.ma.isMaskedArray(a) else a.ravel()
        wide = valid.size > 0 and (
            int(valid.min()) < -_FLOAT32_EXACT_LIMIT or int(valid.max()) > _FLOAT32_EXACT_LIMIT
        )
    out_type = np.float64 if wide else np.float32
    if reuse and dtype == out_type:
        out = np.ma.getdata(a)
        # copyto skips the index arrays of a boolean assignment (mostly all False here).
        mask = np.ma.getmask(a)
        if mask is not np.ma.nomask and mask.any():
            np.copyto(out, np.nan, where=mask)
    elif np.ma.isMaskedArray(a):
        out = np.ma.filled(a.astype(out_type), np.nan)
    else:
        out = np.array(a, dtype=out_type)
    # Infinite heights are as unusable as NaN; keep one marker of nodata. Finite extremes
    # (two passes, no full-size boolean array) say when there is none to look for.
    if out.size and not (np.isfinite(out.min()) and np.isfinite(out.max())):
        np.copyto(out, np.nan, where=np.isinf(out))
    return out


def plain_transform(
    shape: tuple[int, int],
    cell_size: tuple[float, float] | None,
    origin: tuple[float, float] | None,
) -> Affine:
    """Georeference for data without one: cell size 1 and row 0 at the top unless told.

    origin is (x of the left edge, y of the top edge); by default the bottom edge lies at y = 0.
    """
    rows = shape[0]
    dx, dy = cell_size if cell_size is not None else (1.0, 1.0)
    x0, y_top = origin if origin is not None else (0.0, rows * dy)
    return Affine(dx, 0.0, x0, 0.0, -dy, y_top)


def own_transform(ds) -> Affine | None:
    """The dataset's affine transform, or None when GDAL found no georeference.

    rasterio reports a raster without georeference by the identity transform (y growing down).
    """
    if ds.transform.is_identity and ds.crs is None:
        if ds.gcps[0]:
            raise TerrainFormatError(
                f"{ds.name} is georeferenced by ground control points only; warp it to a "
                "north-up grid first (for example with gdalwarp)."
            )
        return None
    return ds.transform


def resolve_transform(
    own: Affine | None,
    shape: tuple[int, int],
    cell_size: tuple[float, float] | None,
    origin: tuple[float, float] | None,
    path: Path,
) -> Affine:
    """The file's own georeference, or one built from cell_size/origin when it has none.

    TerrainFormatError when it places the grid nowhere (a NaN, infinite or zero cell size or
    origin, or an extent beyond float range).
    """
    if own is None:
        return check_transform(plain_transform(shape, cell_size, origin), shape, path)
    if cell_size is not None or origin is not None:
        raise InvalidParameterError(
            f"{path} carries its own georeference; cell_size and origin apply only to data "
            "without one. Leave them out."
        )
    return check_transform(own, shape, path)


def check_transform(transform: Affine, shape: tuple[int, int], path: Path) -> Affine:
    """The transform if every coefficient and both grid corners are finite and cells non-empty."""
    rows, cols = shape
    corners = (transform.c + cols * transform.a, transform.f + rows * transform.e)
    if not all(math.isfinite(v) for v in (*tuple(transform)[:6], *corners)):
        raise TerrainFormatError(
            f"{path} has an unusable georeference: pixel size ({transform.a}, {transform.e}) "
            f"and origin ({transform.c}, {transform.f}) must be finite numbers and the grid's "
            "extent must stay finite. Fix the file's geotransform (for example with "
            "gdal_edit.py -a_ullr) or its world file."
        )
    if transform.a == 0.0 or transform.e == 0.0:
        raise TerrainFormatError(
            f"{path} has a pixel size of zero ({transform.a}, {transform.e}); fix the file's "
            "geotransform (for example with gdal_edit.py -a_ullr) or its world file."
        )
    return transform


def fill_holes(heights: np.ndarray) -> tuple[np.ndarray, int]:
    """Fill NaN cells from their valid neighbours with GDAL's inverse-distance fill.

    heights: (rows, cols) float32/float64 with NaN holes. Returns the filled copy (cells farther
    than FILL_SEARCH_DISTANCE from valid data stay NaN) and the number of cells filled.
    """
    from rasterio.fill import fillnodata

    valid = np.isfinite(heights)
    n_holes = int(heights.size - np.count_nonzero(valid))
    # Nothing to fill, or nothing to fill from.
    if n_holes == 0 or n_holes == heights.size:
        return heights, 0
    filled = fillnodata(
        heights.copy(), mask=valid.astype(np.uint8), max_search_distance=FILL_SEARCH_DISTANCE
    )
    return filled, n_holes - int(np.count_nonzero(np.isnan(filled)))


def make_grid(
    heights: np.ndarray,
    transform: Affine | None,
    crs: str | None,
    nodata_value: float | None,
    policy: str,
) -> Grid:
    """A Grid with the nodata policy applied and reported (transform None: Grid's default).

    The grid carries ``nodata_policy`` ("mask" or "fill") and ``filled_count`` (cells filled).
    """
    filled_count = 0
    if policy == "fill":
        heights, filled_count = fill_holes(heights)
    grid = Grid(heights, transform, crs=crs, nodata=nodata_value)
    grid.nodata_policy = policy
    grid.filled_count = filled_count
    return grid
