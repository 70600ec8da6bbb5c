"""A georeferenced xarray DataArray as the parts of a Grid: heights, transform, CRS, nodata.

``Grid(dataarray)`` and ``open_terrain(dataarray)`` place a DataArray by, in this order:

1. rioxarray's ``rio.transform()`` when its accessor is there and agrees with the x/y
   coordinates (the stored transform is exact; a stale one, left by slicing or flipping the
   array, is passed over), or its stored transform alone when the array has no coordinates;
2. else regular 1-D x/y coordinates taken as cell centres (pixel-is-area);
3. an array without any coordinate is a plain grid (cell size 1, row 0 at the top), as a
   numpy array is.

Rows are turned so that row 0 is the north edge and columns run west to east, whatever the
order of the coordinates. The CRS is ``rio.crs`` (or a ``crs`` attribute); nodata is
``rio.nodata``, else the ``_FillValue`` / ``missing_value`` of the attributes or encoding;
cells holding it, NaN or ±inf are nodata (NaN in the heights). A band (or any other
dimension) of size 1 is dropped. What cannot be placed is an InvalidParameterError saying why:
irregular or 2-D coordinates, dimensions that are neither x nor y, values that are not numbers.

A dask-backed DataArray is never computed whole: its heights are a WindowedHeights over a
``DataArraySource`` that computes the windows a computation asks for, block by block (the
array's own chunks), so a Grid over a lazily opened raster reads what it needs.

xarray and rioxarray are optional: nothing here imports xarray (an object is a DataArray only
when xarray is loaded already), and rioxarray is imported, when installed, only once a
DataArray is given.
"""

from __future__ import annotations

import importlib.util
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeGuard

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError
from approxtree.geometry.windowed import WindowedHeights

if TYPE_CHECKING:
    # Types only: xarray is optional and never imported here at run time.
    import xarray

#: Dimension names read as x (east) and y (north), lower case.
X_NAMES = ("x", "lon", "long", "longitude", "easting")
Y_NAMES = ("y", "lat", "latitude", "northing")


def is_dataarray(obj: object) -> TypeGuard[xarray.DataArray]:
    """True for an xarray.DataArray (found without importing xarray)."""
    xr = sys.modules.get("xarray")
    return xr is not None and isinstance(obj, xr.DataArray)


@dataclass(frozen=True)
class GridParts:
    """What a Grid is made of: heights (rows, cols) float32/float64 with NaN nodata, or a
    WindowedHeights of them; transform (None: no georeference); crs; the nodata value."""

    heights: np.ndarray | WindowedHeights
    transform: Affine | None
    crs: str | None
    nodata: float | None


def grid_parts(da: Any, windowed: bool | None = None) -> GridParts:
    """The Grid parts of a DataArray (see the module docstring).

    windowed: True reads by windows (a WindowedHeights), False computes the array whole, None
    (default) reads by windows exactly when the array is dask-backed.
    """
    rio = _rio(da)
    ydim, xdim = _spatial_dims(da, rio)
    da = _two_dimensional(da, ydim, xdim)
    if da.dtype.kind not in "iuf":
        raise InvalidParameterError(
            f"The DataArray holds {da.dtype} values, not heights; give it real numbers."
        )
    transform = _transform(da, ydim, xdim, rio)
    nodata, reported = _nodata(da, rio)
    # Row 0 north, columns west to east: flip the array (lazily) where the transform does not.
    if transform is not None:
        rows, cols = da.shape
        t = transform
        if t.e > 0:
            da = da.isel({ydim: slice(None, None, -1)})
            t = Affine(t.a, 0.0, t.c, 0.0, -t.e, t.f + rows * t.e)
        if t.a < 0:
            da = da.isel({xdim: slice(None, None, -1)})
            t = Affine(-t.a, 0.0, t.c + cols * t.a, 0.0, t.e, t.f)
        transform = t
    if windowed is None:
        windowed = da.chunks is not None
    source = DataArraySource(da.data, nodata)
    rows, cols = da.shape
    heights = WindowedHeights(source) if windowed else source.read(0, rows, 0, cols)
    return GridParts(heights, transform, _crs(da, rio), reported)


class DataArraySource:
    """A HeightSource over a 2-D array (numpy, or dask: computed window by window).

    array: (rows, cols) numbers, row 0 north; nodata: the value that marks nodata (NaN and
    ±inf are nodata too), or None. dtype: float64 for float64 data and integers of 4 bytes or
    more (exact), float32 otherwise. block_shape: a dask array's first chunk. Windows of a dask
    array are computed with dask's synchronous scheduler (reads run on the WindowedHeights'
    threads, or on a dask worker holding a pickled Grid). Pickles by (array, nodata).
    """

    def __init__(self, array: Any, nodata: float | None) -> None:
        self.array = array
        self.nodata = nodata
        self.shape = (int(array.shape[0]), int(array.shape[1]))
        kind, size = np.dtype(array.dtype).kind, np.dtype(array.dtype).itemsize
        wide = np.dtype(array.dtype) == np.float64 or (kind in "iu" and size >= 4)
        self.dtype = np.dtype(np.float64 if wide else np.float32)
        chunks = getattr(array, "chunks", None)
        self.block_shape = (chunks[0][0], chunks[1][0]) if chunks else None

    def __reduce__(self):
        return (DataArraySource, (self.array, self.nodata))

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Rows [r0, r1), columns [c0, c1) as (r1 − r0, c1 − c0) heights, NaN for nodata."""
        window = self.array[r0:r1, c0:c1]
        if hasattr(window, "compute"):
            window = window.compute(scheduler="synchronous")
        raw = np.asarray(window)
        out = raw.astype(self.dtype, copy=True)
        if self.nodata is not None and not np.isnan(self.nodata):
            np.copyto(out, np.nan, where=raw == self.nodata)
        # Infinite heights are nodata too; looked for only when an extreme is not finite.
        if out.size and not (np.isfinite(out.min()) and np.isfinite(out.max())):
            np.copyto(out, np.nan, where=np.isinf(out))
        return out


# -- the pieces --------------------------------------------------------------------------------


def _rio(da: Any) -> Any:
    """The DataArray's rioxarray accessor, or None (rioxarray imported here when installed)."""
    if "rioxarray" not in sys.modules and importlib.util.find_spec("rioxarray") is None:
        return None
    import rioxarray  # noqa: F401  (registers the accessor)

    return getattr(da, "rio", None)


def _spatial_dims(da: Any, rio: Any) -> tuple[str | None, str | None]:
    """(y dim, x dim): rioxarray's, else by name; (None, None) for an array without any
    coordinate whose two dims are then rows and columns."""
    if rio is not None:
        try:
            return str(rio.y_dim), str(rio.x_dim)
        except Exception:
            pass
    names = {str(d).lower(): d for d in da.dims}
    ys = [names[n] for n in Y_NAMES if n in names]
    xs = [names[n] for n in X_NAMES if n in names]
    if len(ys) == 1 and len(xs) == 1:
        return ys[0], xs[0]
    if not da.coords:
        return None, None
    _no_curvilinear(da)
    dims = ", ".join(f"{d}: {da.sizes[d]}" for d in da.dims)
    raise InvalidParameterError(
        f"Cannot tell x (east) from y (north) in a DataArray of dims ({dims}): name them y and x "
        "(da.rename(...)) or set them with rioxarray's da.rio.set_spatial_dims(...)."
    )


def _two_dimensional(da: Any, ydim: str | None, xdim: str | None) -> Any:
    """The (y, x) DataArray: other dims of size 1 (a band) dropped, y first."""
    if ydim is None:
        # No coordinates at all: the dims of size > 1 are rows and columns, in their order.
        flat = da.squeeze(drop=True) if da.ndim > 2 else da
        if flat.ndim == 2:
            return flat
    else:
        others = [d for d in da.dims if d not in (ydim, xdim)]
        if all(da.sizes[d] == 1 for d in others):
            return da.isel({d: 0 for d in others}, drop=True).transpose(ydim, xdim)
    dims = ", ".join(f"{d}: {da.sizes[d]}" for d in da.dims)
    raise InvalidParameterError(
        f"A grid is 2-D (y, x); the DataArray has dims ({dims}). Select one band or time "
        "first, e.g. da.isel(band=0)."
    )


def _transform(da: Any, ydim: str | None, xdim: str | None, rio: Any) -> Affine | None:
    """The affine transform placing the (y, x) array, from rioxarray or the coordinates."""
    # _spatial_dims gives both dims or neither.
    if ydim is None or xdim is None:
        _no_curvilinear(da)
        return None
    has = [d in da.coords for d in (ydim, xdim)]
    if not any(has):
        _no_curvilinear(da)
        # No coordinates: rioxarray's stored transform, when it has one.
        if rio is not None and (rio.crs is not None or not rio.transform().is_identity):
            return rio.transform()
        return None
    if not all(has):
        missing = xdim if has[0] else ydim
        raise InvalidParameterError(
            f"The DataArray has coordinates along one dim but none along {missing!r}: give "
            "both x and y coordinates (cell centres) or neither."
        )
    ys = np.asarray(da.coords[ydim].values)
    xs = np.asarray(da.coords[xdim].values)
    if ys.size < 2 or xs.size < 2:
        # Too small for a surface: the Grid says so.
        return None
    y0, dy = _regular(ys, ydim)
    x0, dx = _regular(xs, xdim)
    from_coords = Affine(dx, 0.0, x0 - dx / 2, 0.0, dy, y0 - dy / 2)
    if rio is not None:
        # rioxarray's stored transform is exact where the coordinates agree with it.
        try:
            stored = rio.transform(recalc=False)
        except Exception:
            stored = None
        if stored is not None and _agrees(stored, xs, ys):
            return stored
    return from_coords


def _regular(values: np.ndarray, dim: str) -> tuple[float, float]:
    """(first centre, step) of regular 1-D coordinates, or InvalidParameterError."""
    if values.dtype.kind not in "iuf":
        raise InvalidParameterError(
            f"The {dim!r} coordinates are {values.dtype}, not numbers in map units; a Grid needs "
            "numeric cell-centre coordinates."
        )
    v = values.astype(np.float64)
    step = (v[-1] - v[0]) / (len(v) - 1)
    if not (np.isfinite(v).all() and step != 0.0):
        raise InvalidParameterError(
            f"The {dim!r} coordinates do not advance (from {v[0]} to {v[-1]}); a Grid needs "
            "regular cell-centre coordinates."
        )
    off = float(np.abs(v - (v[0] + step * np.arange(len(v)))).max())
    if off > _tolerance(values, step):
        raise InvalidParameterError(
            f"The {dim!r} coordinates are irregular (off a regular step of {abs(step):g} by up to "
            f"{off:g}); a Grid needs regular cell centres: resample it first (e.g. rioxarray's "
            "rio.reproject or xarray's interp)."
        )
    return float(v[0]), float(step)


def _tolerance(values: np.ndarray, step: float) -> float:
    """How far a coordinate may stray from its regular position: a millionth of a cell, or a
    few steps of its own float type at its magnitude (float32 coordinates)."""
    dtype = values.dtype if values.dtype.kind == "f" else np.dtype(np.float64)
    ulp = float(np.spacing(dtype.type(np.abs(values).max())))
    return max(1e-6 * abs(step), 4.0 * ulp)


def _agrees(t: Affine, xs: np.ndarray, ys: np.ndarray) -> bool:
    """True when transform ``t`` puts the cell centres at the coordinates xs, ys."""
    if t.b != 0.0 or t.d != 0.0 or t.a == 0.0 or t.e == 0.0:
        return False
    cx = t.c + (np.arange(len(xs)) + 0.5) * t.a
    cy = t.f + (np.arange(len(ys)) + 0.5) * t.e
    return bool(
        np.abs(cx - xs).max() <= _tolerance(xs, t.a)
        and np.abs(cy - ys).max() <= _tolerance(ys, t.e)
    )


def _no_curvilinear(da: Any) -> None:
    """InvalidParameterError for coordinates of 2 dims or more (a curvilinear grid)."""
    for name, coord in da.coords.items():
        if coord.ndim >= 2:
            raise InvalidParameterError(
                f"The DataArray is placed by 2-D coordinates ({name}{tuple(coord.dims)}), a "
                "curvilinear grid; a Grid needs regular 1-D x and y coordinates: regrid it "
                "first (e.g. rioxarray's rio.reproject)."
            )


def _nodata(da: Any, rio: Any) -> tuple[float | None, float | None]:
    """(value marking nodata in the data, nodata value to report) of a DataArray."""
    value = None
    if rio is not None:
        value = rio.nodata
    if value is None:
        for where in (da.attrs, da.encoding):
            for key in ("_FillValue", "missing_value", "nodata"):
                if where.get(key) is not None and np.ndim(where[key]) == 0:
                    value = where[key]
                    break
            if value is not None:
                break
    value = None if value is None else float(value)
    # The file's own value when the data were masked on reading (rioxarray's masked=True).
    encoded = getattr(rio, "encoded_nodata", None) if rio is not None else None
    reported = float(encoded) if encoded is not None else value
    return value, reported


def _crs(da: Any, rio: Any) -> str | None:
    """The DataArray's CRS as a string (EPSG code or WKT), or None."""
    crs = rio.crs if rio is not None else None
    if crs is not None:
        return crs.to_string()
    text = da.attrs.get("crs")
    return text if isinstance(text, str) and text.strip() else None
