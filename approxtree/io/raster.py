"""GDAL rasters through rasterio: GeoTIFF, ESRI ASCII, SRTM .hgt(.zip), USGS DEM, netCDF, ...

The grid keeps the dataset's affine transform and CRS. Cells that rasterio masks (the nodata
value, NaN, an internal or alpha mask) become NaN and are never data points.
A GeoTIFF whose own keys declare a CRS that GDAL returns empty is a TerrainFormatError
(``check_crs_read``), never a grid silently without its CRS.

A raster too large to hold (more than ``WINDOWED_BYTES`` of heights, or ``windowed=True``) is
opened *windowed*: the Grid's heights are a WindowedHeights over a ``RasterSource`` that reads
rasterio windows on demand, one dataset handle per thread, through a bounded GDAL cache.
"""

from __future__ import annotations

import os
import threading
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError, TerrainFormatError
from approxtree.geometry import Grid
from approxtree.geometry.windowed import DEFAULT_CACHE_BYTES, HeightSource, WindowedHeights
from approxtree.io._common import (
    FILL_SEARCH_DISTANCE,
    as_heights,
    check_cell_size,
    check_claimed_bytes,
    check_crs,
    check_nodata_policy,
    check_origin,
    existing_file,
    fill_holes,
    make_grid,
    own_transform,
    reading,
    resolve_transform,
)
from approxtree.io.gdal import no_side_files
from approxtree.io.geokeys import declared_model

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
    # Absolute: GDAL looks a relative /vsizip/ path up from the root, not the working folder.
    return f"zip://{os.path.abspath(path)}!{rasters[0]}"


#: GDAL block cache (MB) while a band is read whole, and while a windowed raster is read.
_READ_CACHE_MB = 64

#: Rasters whose heights would take more bytes than this are opened windowed by default
#: (``windowed=None``); the environment variable APPROXTREE_WINDOWED_BYTES overrides it.
WINDOWED_BYTES = 2**30


def windowed_threshold() -> int:
    """Bytes of heights above which a raster opens windowed: APPROXTREE_WINDOWED_BYTES or 1 GiB."""
    text = os.environ.get("APPROXTREE_WINDOWED_BYTES")
    if text is None:
        return WINDOWED_BYTES
    try:
        return int(float(text))
    except ValueError:
        raise InvalidParameterError(
            f"APPROXTREE_WINDOWED_BYTES must be a number of bytes, got {text!r}."
        ) from None


def heights_dtype(band_dtype: str | np.dtype) -> np.dtype:
    """The dtype a windowed raster's heights get, decided from the band's type alone.

    float64 for float64 and for integers of 4 bytes or more (they may leave float32's exact
    range, and a windowed raster is not scanned to find out; the values are the same), float32
    otherwise (an in-memory read narrows wide integers to float32 when they all fit).
    """
    dtype = np.dtype(band_dtype)
    if dtype.kind not in "iuf":
        raise TerrainFormatError(f"Heights must be real numbers, got a band of {dtype}.")
    return np.dtype(np.float64 if _heights_itemsize(dtype) == 8 else np.float32)


def _heights_itemsize(band_dtype: str | np.dtype) -> int:
    """Bytes a cell of this band takes as heights (8 for float64 and wide integers, else 4)."""
    dtype = np.dtype(band_dtype)
    return 8 if dtype == np.float64 or (dtype.kind in "iu" and dtype.itemsize >= 4) else 4


class RasterSource:
    """A HeightSource over one band of a GDAL raster, read by rasterio windows.

    name: what rasterio opens (a path, ``zip://...!member``, a VRT, ``NETCDF:file:var``).
    band: 1-based band. cache_mb: GDAL's block cache while reading (GDAL_CACHEMAX).
    Each thread opens its own dataset handle (GDAL handles are not thread-safe). Cells that
    rasterio masks (nodata, NaN, internal or alpha masks) and infinite values read as NaN,
    exactly as ``read_raster`` reads them in memory. Pickles by (name, band, cache_mb).
    """

    def __init__(self, name: str, band: int = 1, cache_mb: int = _READ_CACHE_MB) -> None:
        self.name = str(name)
        self.band = int(band)
        self.cache_mb = int(cache_mb)
        self._local = threading.local()
        ds = self._dataset()
        if self.band > ds.count:
            raise InvalidParameterError(
                f"band {self.band} does not exist: {self.name} has {ds.count} band(s)."
            )
        self.shape = (int(ds.height), int(ds.width))
        self.band_dtype = np.dtype(ds.dtypes[self.band - 1])
        self.dtype = heights_dtype(self.band_dtype)
        self.block_shape = tuple(int(b) for b in ds.block_shapes[self.band - 1])
        self.nodata = ds.nodata
        self.crs = crs_text(ds)
        self.own_transform = own_transform(ds)

    def __reduce__(self):
        return (RasterSource, (self.name, self.band, self.cache_mb))

    def __repr__(self) -> str:
        return f"RasterSource({self.name!r}, band={self.band})"

    def _dataset(self):
        """This thread's open dataset (opened on first use)."""
        ds = getattr(self._local, "dataset", None)
        if ds is None:
            import rasterio
            from rasterio.errors import NotGeoreferencedWarning

            with (
                reading(self.name, "a GDAL raster"),
                warnings.catch_warnings(),
                rasterio.Env(GDAL_CACHEMAX=self.cache_mb << 20),
                no_side_files(),
            ):
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                ds = rasterio.open(self.name)
            self._local.dataset = ds
        return ds

    def close(self) -> None:
        """Close this thread's dataset handle (reopened on the next read)."""
        ds = getattr(self._local, "dataset", None)
        if ds is not None:
            ds.close()
            self._local.dataset = None

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Rows [r0, r1), columns [c0, c1) as (r1 − r0, c1 − c0) heights, NaN for nodata."""
        return self.read_into(r0, r1, c0, c1, None)

    def read_into(self, r0: int, r1: int, c0: int, c1: int, out: np.ndarray | None) -> np.ndarray:
        """``read`` into ``out``, a C-contiguous (r1 − r0, c1 − c0) array of ``dtype``
        (a new one when None), and return it: a stream of windows reuses its buffers instead
        of faulting in fresh memory for each."""
        import rasterio
        from rasterio.windows import Window

        ds = self._dataset()
        window = Window(c0, r0, c1 - c0, r1 - r0)
        flags = ds.mask_flag_enums[self.band - 1]
        if out is None:
            out = np.empty((r1 - r0, c1 - c0), dtype=self.dtype)
        # Without a mask band (every cell valid, or nodata alone) the window is read straight
        # into the heights' dtype and nodata found by comparison: no masked array, no copies.
        plain = all(f.name in ("all_valid", "nodata") for f in flags)
        with reading(self.name, "a GDAL raster"), rasterio.Env(GDAL_CACHEMAX=self.cache_mb << 20):
            if plain:
                ds.read(self.band, window=window, out=out)
            else:
                values = ds.read(self.band, window=window, masked=True)
        if plain:
            nodata = self.nodata
            if any(f.name == "nodata" for f in flags) and nodata is not None:
                if not np.isnan(nodata):
                    np.copyto(out, np.nan, where=out == out.dtype.type(nodata))
        else:
            np.copyto(out, np.ma.getdata(values), casting="unsafe")
            np.copyto(out, np.nan, where=np.ma.getmaskarray(values))
        # Infinities are nodata too; looked for only when an extreme is not finite.
        if out.size and not (np.isfinite(out.min()) and np.isfinite(out.max())):
            np.copyto(out, np.nan, where=np.isinf(out))
        return out


def crs_text(ds: Any) -> str | None:
    """The CRS of an open rasterio dataset as text (an authority code such as "EPSG:32119",
    else its WKT), or None when GDAL reports none."""
    crs = ds.crs
    if not crs:
        return None
    # Truthy means the CRS has a WKT: the text is never empty.
    return str(crs.to_string() or crs.wkt)


def check_crs_read(crs: str | None, path: Path, source: str) -> None:
    """TerrainFormatError when GDAL read no CRS (``crs`` None) from a GeoTIFF whose own GeoKeys
    declare one (``geokeys.declared_model``).

    GDAL reports a CRS it could not build from the keys as none at all, the very answer it
    gives for a file without one: read so, the grid would silently lose its place on the
    Earth (and a tree store built from it would keep it lost). ``source`` is the name rasterio
    opened (``zip://…!member`` for a zipped raster).
    """
    if crs is not None:
        return
    member = source.split("!", 1)[1] if source.startswith("zip://") else None
    model = declared_model(path, member)
    if model is not None:
        raise TerrainFormatError(
            f"GDAL read no CRS from {path}, but its GeoTIFF keys declare a {model} one "
            "(GTModelTypeGeoKey): GDAL could not build it from them. Check the file with "
            "gdalinfo, or give its CRS (--crs EPSG:... on the command line, crs= to "
            "open_terrain)."
        )


def read_raster(
    path: str | os.PathLike,
    *,
    band: int = 1,
    nodata: str = "mask",
    crs: str | None = None,
    cell_size: float | tuple[float, float] | None = None,
    origin: tuple[float, float] | None = None,
    windowed: bool | None = None,
) -> Grid:
    """Read one band of a GDAL raster as a Grid.

    band: 1-based band number. nodata: "mask" or "fill". crs: replaces the file's CRS.
    cell_size, origin: georeference for a raster without one (cell size 1, row 0 at the top
    otherwise). windowed: True opens it windowed (heights read by windows on demand, nothing
    read now), False reads the band into memory, None (default) opens windowed when the heights
    would exceed ``windowed_threshold()`` bytes. Returns a Grid with heights (rows, cols)
    float32 (float64 for float64 data) or, windowed, a WindowedHeights of them.
    """
    p = existing_file(path)
    policy = check_nodata_policy(nodata)
    crs = check_crs(crs)
    cell = check_cell_size(cell_size)
    corner = check_origin(origin)
    if isinstance(band, bool) or not isinstance(band, int | np.integer) or band < 1:
        raise InvalidParameterError(f"band must be a band number ≥ 1, got {band!r}.")
    if windowed is not None and not isinstance(windowed, bool | np.bool_):
        raise InvalidParameterError(f"windowed must be True, False or None, got {windowed!r}.")
    source = rasterio_source(p)
    if windowed:
        return _open_windowed(p, source, int(band), policy, crs, cell, corner)
    with reading(p, "a GDAL raster (GeoTIFF, ASCII grid, SRTM, USGS DEM, netCDF, ...)"):
        import rasterio
        from rasterio.errors import NotGeoreferencedWarning

        # A raster without georeference is fine: it gets cell size 1 below. The band is read
        # once, so a small block cache: GDAL's default (5 % of RAM) would hold a second copy.
        with (
            warnings.catch_warnings(),
            rasterio.Env(GDAL_CACHEMAX=_READ_CACHE_MB << 20),
            no_side_files(),
        ):
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(source) as ds:
                if band > ds.count:
                    raise InvalidParameterError(
                        f"band {band} does not exist: {p} has {ds.count} band(s)."
                    )
                # By default a band whose heights exceed the threshold is read by windows.
                cells = ds.width * ds.height
                itemsize = _heights_itemsize(ds.dtypes[int(band) - 1])
                if windowed is None and cells * itemsize > windowed_threshold():
                    windowed = True
                else:
                    # A CRS the file declares but GDAL did not build fails before the read.
                    file_crs = crs_text(ds)
                    if crs is None:
                        check_crs_read(file_crs, p, source)
                    # The band, its mask and the float heights: about 3 × 8 bytes a cell.
                    check_claimed_bytes(p, cells * 24, None, f"{ds.width} × {ds.height} cells")
                    values = ds.read(int(band), masked=True)
                    own = own_transform(ds)
                    nodata_value = ds.nodata
    if windowed:
        return _open_windowed(p, source, int(band), policy, crs, cell, corner)
    # The band read is ours: float32 data get their NaNs in place (no second DEM in memory).
    heights = as_heights(values, reuse=True)
    del values
    transform = resolve_transform(own, heights.shape, cell, corner, p)
    return make_grid(heights, transform, crs or file_crs, nodata_value, policy)


class FilledSource:
    """A HeightSource whose holes are filled as ``nodata="fill"`` fills a band read whole.

    GDAL's fill (inverse distance, no smoothing) looks at most FILL_SEARCH_DISTANCE cells
    away, so each window is filled from itself plus a halo of twice that distance and gives
    the very values a fill of the whole band gives (tests compare them on real DEMs).
    """

    #: Cells read around each window (the fill's reach, with a margin for its diagonals).
    HALO = 2 * int(FILL_SEARCH_DISTANCE) + 2

    def __init__(self, source: HeightSource) -> None:
        self.source = source
        self.shape = source.shape
        self.dtype = source.dtype
        self.block_shape: tuple[int, ...] | None = getattr(source, "block_shape", None)

    def __reduce__(self):
        return (FilledSource, (self.source,))

    def __repr__(self) -> str:
        return f"FilledSource({self.source!r})"

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Rows [r0, r1), columns [c0, c1), holes within reach of data filled."""
        rows, cols = self.shape
        a0, a1 = max(0, r0 - self.HALO), min(rows, r1 + self.HALO)
        b0, b1 = max(0, c0 - self.HALO), min(cols, c1 + self.HALO)
        filled, _ = fill_holes(self.source.read(a0, a1, b0, b1))
        return np.array(filled[r0 - a0 : r1 - a0, c0 - b0 : c1 - b0], copy=True)


def _open_windowed(
    p: Path,
    source: str,
    band: int,
    policy: str,
    crs: str | None,
    cell: tuple[float, float] | None,
    corner: tuple[float, float] | None,
) -> Grid:
    """A windowed Grid over the raster: nothing of the band is read here."""
    what = "a GDAL raster (GeoTIFF, ASCII grid, SRTM, USGS DEM, netCDF, ...)"
    with reading(p, what):
        heights = RasterSource(source, band)
    if crs is None:
        check_crs_read(heights.crs, p, source)
    transform = resolve_transform(heights.own_transform, heights.shape, cell, corner, p)
    # The fill policy fills each window from a halo around it (as a whole-band fill would).
    read_from: HeightSource = FilledSource(heights) if policy == "fill" else heights
    windowed = WindowedHeights(read_from, cache_bytes=DEFAULT_CACHE_BYTES)
    # One block read now (kept in the cache): a header claiming more cells than the file
    # holds fails here, as it fails an in-memory read, not in the middle of a computation.
    last = windowed.block_count()
    try:
        windowed.block(last[0] - 1, last[1] - 1)
    except TerrainFormatError as exc:
        rows, cols = heights.shape
        raise TerrainFormatError(
            f"{p} is truncated or corrupt: its header claims {cols} × {rows} cells, but its last "
            f"block cannot be read. {exc}"
        ) from exc
    grid = Grid(
        windowed,
        transform,
        crs=crs or heights.crs,
        nodata=heights.nodata,
    )
    grid.nodata_policy = policy
    # How many cells a windowed fill filled is not known without a scan of the band.
    grid.filled_count = None if policy == "fill" else 0
    return grid


def is_gdal_raster(path: Path) -> bool:
    """True when GDAL recognises the file as a raster (used for unknown extensions)."""
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with no_side_files(), rasterio.open(rasterio_source(path)) as ds:
                return ds.count > 0
    except Exception:
        return False
