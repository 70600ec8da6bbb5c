"""Grid: a regular, georeferenced height grid — the most common terrain.

Data points sit at cell centres (rasters are pixel-is-area): the point of row r, column c is
``transform @ (c + 0.5, r + 0.5)``. Row 0 is the first row of the file (north for north-up
rasters). Nodata cells hold NaN in ``heights`` and are never data points.

``heights`` is either a numpy array or a ``WindowedHeights`` (a raster read by windows through
a bounded block cache): a *windowed* grid answers domain, points(rect), height_at, z range and
point count reading only the blocks they need; an operation that needs the whole band reads it
only when it is small (``WHOLE_BAND_LIMIT_BYTES``), else raises WholeBandError.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt
from affine import Affine

from approxtree.errors import EmptyTerrainError, InvalidParameterError, TerrainFormatError
from approxtree.geometry.base import GeometryData, RecordArray
from approxtree.geometry.dataarray import is_dataarray
from approxtree.geometry.rect import Rect
from approxtree.geometry.windowed import WindowedHeights, band_statistics, check_whole_band
from approxtree.kernels.grid_interp import cell_height_at, grid_height_at


def _as_heights(heights: npt.ArrayLike) -> np.ndarray:
    """Heights as float32 (exact for integer DEMs up to 2^24) unless they are float64 already."""
    a = np.asarray(heights)
    if a.dtype == np.float64:
        return np.ascontiguousarray(a)
    return np.ascontiguousarray(a, dtype=np.float32)


#: Largest side of the strided overview of a grid (the Engine's normal map); a tree store keeps
#: it beside the heights so opening a viewer on a huge terrain reads no more than it.
OVERVIEW_SIDE = 4096

#: Fewest float64 steps a cell must span at the grid's coordinates; below it data points on a
#: node's border fall on either side of it by round-off.
MIN_CELL_STEPS = 1e4


def _check_resolution(transform: Affine, rows: int, cols: int) -> None:
    """TerrainFormatError unless the grid's corners are finite and float64 resolves its cells."""
    t = transform
    xs, ys = (t.c, t.c + cols * t.a), (t.f, t.f + rows * t.e)
    if not np.all(np.isfinite([*tuple(t)[:6], *xs, *ys])):
        raise TerrainFormatError(
            f"The grid's georeference is not finite: transform {tuple(t)[:6]} over "
            f"{rows} × {cols} cells. Fix the file's geotransform."
        )
    magnitude = max(abs(v) for v in (*xs, *ys))
    cell = min(abs(t.a), abs(t.e))
    step = float(np.spacing(magnitude))
    if cell < MIN_CELL_STEPS * step:
        raise TerrainFormatError(
            f"Cells of {cell:g} at coordinates of {magnitude:g} are too small for float64 "
            f"(its steps there are {step:g}): shift the origin towards 0 (for example a local "
            "projected CRS or a false easting/northing) or use larger cells."
        )


def _check_not_empty(n_valid: int, shape: tuple[int, int], allow_empty: bool | None) -> None:
    """EmptyTerrainError for a grid without a valid elevation, unless it may be empty."""
    if n_valid == 0 and not allow_empty:
        rows, cols = shape
        raise EmptyTerrainError(
            f"The grid of {rows} × {cols} points has no valid elevation (all nodata or NaN). "
            "Check the nodata value of the file or choose another file."
        )


def _from_dataarray(
    da: Any, transform: Affine | None, crs: str | None, nodata: float | None
) -> tuple[np.ndarray | WindowedHeights, Affine | None, str | None, float | None]:
    """(heights, transform, crs, nodata) of an xarray DataArray given to Grid: its own
    georeference (``geometry.dataarray``). A transform given as well is refused when the
    array has one; a crs or nodata given replaces its own."""
    from approxtree.geometry.dataarray import grid_parts

    parts = grid_parts(da)
    if transform is not None and parts.transform is not None:
        raise InvalidParameterError(
            "The DataArray carries its own georeference (x/y coordinates or rioxarray's "
            "transform); leave transform out, or drop its coordinates first."
        )
    return (
        parts.heights,
        parts.transform if transform is None else transform,
        parts.crs if crs is None else crs,
        parts.nodata if nodata is None else nodata,
    )


class Grid(GeometryData):
    """A regular grid of heights with an affine georeference.

    heights: (rows, cols) float32 or float64, NaN where there is no data; or a WindowedHeights
        (float32/float64 source), which makes a windowed grid read by blocks and never scanned
        at construction (point count and z range are computed blockwise when first asked); or
        an xarray DataArray, placed by its own georeference (``geometry.dataarray``: rioxarray's
        transform and CRS, or regular x/y coordinates; dask-backed ones read by windows).

    transform: affine map from (col, row) pixel-corner coordinates to world (x, y); rotation and
        shear are not supported. Defaults to cell size 1 with row 0 at the top (y = rows).

    crs: EPSG code or WKT of x and y, or None.
    nodata: the original nodata value of the source (kept for reporting; cells are NaN already).
    """

    def __init__(
        self,
        heights: npt.ArrayLike | WindowedHeights,
        transform: Affine | None = None,
        crs: str | None = None,
        nodata: float | None = None,
        index_offset: tuple[int, int] = (0, 0),
        allow_empty: bool = False,
    ) -> None:
        if is_dataarray(heights):
            heights, transform, crs, nodata = _from_dataarray(heights, transform, crs, nodata)
        windowed = isinstance(heights, WindowedHeights)
        h = heights if isinstance(heights, WindowedHeights) else _as_heights(heights)
        if windowed and h.dtype not in (np.float32, np.float64):
            raise TerrainFormatError(f"Windowed heights must be float32 or float64, got {h.dtype}.")
        if h.ndim != 2:
            raise TerrainFormatError(f"A grid needs a 2-D height array, got shape {h.shape}.")
        rows, cols = h.shape
        if rows < 2 or cols < 2:
            raise EmptyTerrainError(
                f"A grid needs at least 2 × 2 points to form a surface, got {rows} × {cols} "
                "(rows × columns). Use a larger raster or read it as scattered points."
            )
        # A windowed grid is not scanned here (a 64k² raster opens at once): its point count
        # and emptiness are found blockwise by the first question that needs them.
        self._allow_empty = allow_empty
        if not windowed:
            n_valid = int(np.count_nonzero(np.isfinite(h)))
            _check_not_empty(n_valid, h.shape, allow_empty)
            self._n_valid = n_valid
        if transform is None:
            transform = Affine(1.0, 0.0, 0.0, 0.0, -1.0, float(rows))
        if transform.b != 0.0 or transform.d != 0.0:
            raise TerrainFormatError(
                "Rotated or sheared grids are not supported; warp the raster to a north-up grid "
                "first (for example with gdalwarp)."
            )
        if transform.a == 0.0 or transform.e == 0.0:
            raise TerrainFormatError(f"The grid's cell size is zero: transform {tuple(transform)}.")
        _check_resolution(transform, rows, cols)
        self.heights: np.ndarray | WindowedHeights = h
        self.transform = transform
        #: How the reader treated nodata: "mask" (holes stay NaN) or "fill" (interpolated).
        self.nodata_policy = "mask"
        #: Cells the fill policy gave an interpolated height (None: not known, a windowed fill).
        self.filled_count: int | None = 0
        self.crs = crs
        self.nodata = nodata
        #: (row, col) in the full raster of this grid's row 0, column 0: a window of a larger
        #: raster keeps the full raster's transform and numbers its own rows and columns from 0,
        #: so its data points have bit-identical coordinates to the same points of the full grid.
        self.index_offset = (int(index_offset[0]), int(index_offset[1]))

    def __getattr__(self, name: str) -> Any:
        # The valid count of a windowed grid: one blockwise scan, the first time it is needed.
        heights = self.__dict__.get("heights")
        if name == "_n_valid" and isinstance(heights, WindowedHeights):
            n_valid, zmin, zmax = band_statistics(heights)
            _check_not_empty(n_valid, heights.shape, self.__dict__.get("_allow_empty"))
            self.__dict__["_n_valid"] = n_valid
            self.__dict__["_z_range_blockwise"] = (zmin, zmax)
            return n_valid
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __getstate__(self) -> dict[str, Any]:
        # A windowed grid pickles by its source's arguments: drop the coordinate vectors and
        # any band read whole (they are rebuilt on demand).
        state = dict(self.__dict__)
        if self.is_windowed:
            for key in ("x_coords", "y_coords", "_whole_heights"):
                state.pop(key, None)
        return state

    def __repr__(self) -> str:
        if self.is_windowed and "_n_valid" not in self.__dict__:
            d = self.domain
            return (
                f"Grid(windowed {self.height} × {self.width}, "
                f"domain=({d.xmin:g}, {d.ymin:g}, {d.xmax:g}, {d.ymax:g}), crs={self.crs!r})"
            )
        return super().__repr__()

    # -- windowed or in memory ---------------------------------------------------------------

    @property
    def is_windowed(self) -> bool:
        """True when the heights are read by windows (a WindowedHeights), not held in memory."""
        return isinstance(self.heights, WindowedHeights)

    def overview_steps(self, side: int | None = None) -> tuple[int, int]:
        """(row step, column step) of the strided overview of at most ``side`` cells a side, in
        the order that makes its rows run south to north and its columns west to east (a
        negative step walks the grid backwards from its last line); side: OVERVIEW_SIDE."""
        side = OVERVIEW_SIDE if side is None else side
        stride = max(1, -(-max(self.shape) // side))
        t = self.transform
        return (stride if t.e > 0 else -stride, -stride if t.a < 0 else stride)

    def strided_heights(self, row_step: int, col_step: int) -> np.ndarray:
        """``heights[::row_step, ::col_step]`` as an array: from the overview a tree store keeps
        beside the heights when it is that one (no read of the band), else read (a windowed
        grid reads every block the lines cross)."""
        stored = self.__dict__.get("_overviews", {}).get((row_step, col_step))
        if stored is not None:
            return np.asarray(stored())
        return np.asarray(self.heights[::row_step, ::col_step])

    def heights_array(self, operation: str) -> np.ndarray:
        """The whole (rows, cols) height band as a numpy array, for ``operation``.

        In memory: ``heights`` itself. Windowed: read whole (and kept) when the band is at most
        WHOLE_BAND_LIMIT_BYTES; else WholeBandError naming the operation and what to do.
        """
        if not isinstance(self.heights, WindowedHeights):
            return self.heights
        whole = self.__dict__.get("_whole_heights")
        if whole is None:
            check_whole_band(self.shape, self.heights.dtype, operation)
            whole = self.heights[:, :]
            whole.flags.writeable = False
            self.__dict__["_whole_heights"] = whole
        return whole

    # -- shape and coordinates ---------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        rows, cols = self.heights.shape
        return (rows, cols)

    @property
    def width(self) -> int:
        return self.heights.shape[1]

    @property
    def height(self) -> int:
        return self.heights.shape[0]

    @property
    def cell_size(self) -> tuple[float, float]:
        """(dx, dy) cell size in world units, both positive."""
        return (abs(self.transform.a), abs(self.transform.e))

    @cached_property
    def x_coords(self) -> np.ndarray:
        """(cols,) float64 x of the data points of each column."""
        t = self.transform
        return t.c + (np.arange(self.width) + self.index_offset[1] + 0.5) * t.a

    @cached_property
    def y_coords(self) -> np.ndarray:
        """(rows,) float64 y of the data points of each row."""
        t = self.transform
        return t.f + (np.arange(self.height) + self.index_offset[0] + 0.5) * t.e

    @property
    def valid(self) -> np.ndarray:
        """(rows, cols) bool, True where the cell holds a data point."""
        return np.isfinite(self.heights_array("Grid.valid (the mask of every cell)"))

    @property
    def nodata_count(self) -> int:
        return self.heights.size - self._n_valid

    def fractional_index(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (x, y) → fractional (row, col) of the data-point lattice; arrays of one shape."""
        t = self.transform
        fc = (np.asarray(x, dtype=np.float64) - t.c) / t.a - 0.5
        fr = (np.asarray(y, dtype=np.float64) - t.f) / t.e - 0.5
        r_off, c_off = self.index_offset
        if r_off or c_off:
            fr, fc = fr - r_off, fc - c_off
        return fr, fc

    def index_range(self, rect: Rect) -> tuple[int, int, int, int]:
        """(r0, r1, c0, c1): inclusive index ranges of the data points inside the closed rect.

        Empty ranges come back with r1 < r0 or c1 < c0.
        """
        r0, r1, c0, c1 = self.index_ranges(np.array([rect.as_tuple()], dtype=np.float64))[0]
        return int(r0), int(r1), int(c0), int(c1)

    def index_ranges(self, rects: np.ndarray) -> np.ndarray:
        """(k, 4) int64 (r0, r1, c0, c1) of ``index_range`` for (k, 4) float64 rectangles
        (xmin, ymin, xmax, ymax), in one array pass (a level of a tree at once)."""
        rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
        fr_a, fc_a = self.fractional_index(rects[:, 0], rects[:, 1])
        fr_b, fc_b = self.fractional_index(rects[:, 2], rects[:, 3])
        # A tolerance keeps points on the rectangle's border inside it despite round-off in
        # world coordinates: 1e-9 cells, or a few units in the last place of the coordinates
        # where they are large against the cell size (an origin of 1e9 and 1 cm cells).
        t = self.transform
        ulp = np.spacing(np.abs(rects).max(axis=1))
        eps = np.maximum(1e-9, 16.0 * ulp / min(abs(t.a), abs(t.e)))
        out = np.empty((len(rects), 4), dtype=np.int64)
        out[:, 0] = np.maximum(np.ceil(np.minimum(fr_a, fr_b) - eps), 0)
        out[:, 1] = np.minimum(np.floor(np.maximum(fr_a, fr_b) + eps), self.height - 1)
        out[:, 2] = np.maximum(np.ceil(np.minimum(fc_a, fc_b) - eps), 0)
        out[:, 3] = np.minimum(np.floor(np.maximum(fc_a, fc_b) + eps), self.width - 1)
        return out

    def window(self, r0: int, r1: int, c0: int, c1: int) -> Grid:
        """The sub-grid of the inclusive index range rows r0..r1, columns c0..c1.

        Its heights are (r1 − r0 + 1, c1 − c0 + 1), a copy; its data points have the very same
        world coordinates (bit for bit) as in this grid, so a tree built on a window equals the
        same part of a tree built on the whole. Indices of the window are its own (row 0 is
        row r0 here); ``index_offset`` maps them back. A window of nodata only is allowed.
        """
        if not (0 <= r0 <= r1 < self.height and 0 <= c0 <= c1 < self.width):
            raise InvalidParameterError(
                f"Window rows {r0}..{r1}, columns {c0}..{c1} is not inside the grid of "
                f"{self.height} × {self.width} points."
            )
        block = self.heights[r0 : r1 + 1, c0 : c1 + 1]
        # A windowed read is a fresh array already; a slice of an in-memory band is a view.
        heights = block if self.is_windowed else np.array(block, copy=True)
        r_off, c_off = self.index_offset
        sub = Grid(
            heights,
            self.transform,
            self.crs,
            self.nodata,
            index_offset=(r_off + r0, c_off + c0),
            allow_empty=True,
        )
        sub.nodata_policy = self.nodata_policy
        return sub

    def rect_of(self, r0: int, r1: int, c0: int, c1: int) -> Rect:
        """The world rectangle spanned by the data points of an inclusive index range."""
        xs = self.x_coords[[c0, c1]]
        ys = self.y_coords[[r0, r1]]
        return Rect(float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max()))

    # -- GeometryData ------------------------------------------------------------------------

    @cached_property
    def domain(self) -> Rect:
        return self.rect_of(0, self.height - 1, 0, self.width - 1)

    def points(self, rect: Rect | None = None) -> np.ndarray:
        if rect is None:
            r0, r1, c0, c1 = 0, self.height - 1, 0, self.width - 1
            if self.is_windowed:
                check_whole_band(self.shape, self.heights.dtype, "Grid.points() of every cell")
        else:
            r0, r1, c0, c1 = self.index_range(rect)
            if r1 < r0 or c1 < c0:
                return np.empty((0, 3))
        z = self.heights[r0 : r1 + 1, c0 : c1 + 1]
        rr, cc = np.nonzero(np.isfinite(z))
        return np.column_stack(
            [self.x_coords[c0 + cc], self.y_coords[r0 + rr], z[rr, cc].astype(np.float64)]
        )

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        shape = np.broadcast_shapes(x.shape, y.shape)
        fr, fc = self.fractional_index(np.broadcast_to(x, shape), np.broadcast_to(y, shape))
        fr, fc = fr.ravel().copy(), fc.ravel().copy()
        if isinstance(self.heights, WindowedHeights):
            return self._windowed_height_at(fr, fc).reshape(shape)
        return grid_height_at(self.heights, fr, fc).reshape(shape)

    def _windowed_height_at(self, fr: np.ndarray, fc: np.ndarray) -> np.ndarray:
        """h_T at (n,) fractional indices on a windowed grid, reading only the blocks touched.

        The four corners of each point's cell are read in one grouped-by-block index read
        and interpolated by the kernel grid_height_at uses, so the values equal the in-memory
        ones bit for bit (integer cell indices subtract exactly). Peak memory: the points
        and the cached blocks, never the bounding box of the points.
        """
        rows, cols = self.shape
        out = np.full(fr.shape, np.nan)
        inside = np.flatnonzero((fr >= 0.0) & (fr <= rows - 1) & (fc >= 0.0) & (fc <= cols - 1))
        if inside.size == 0:
            return out
        # The cell of each point as the kernel picks it: the last line belongs to the cell
        # before it.
        fr_in, fc_in = fr[inside], fc[inside]
        cr = np.minimum(fr_in.astype(np.int64), rows - 2)
        cc = np.minimum(fc_in.astype(np.int64), cols - 2)
        z00, z01, z10, z11 = self.heights[
            np.concatenate([cr, cr, cr + 1, cr + 1]), np.concatenate([cc, cc + 1, cc, cc + 1])
        ].reshape(4, -1)
        out[inside] = cell_height_at(z00, z01, z10, z11, fr_in - cr, fc_in - cc)
        return out

    @property
    def z_range(self) -> tuple[float, float]:
        cached = self.__dict__.get("_z_range")
        if cached is not None:
            return cached
        if self.is_windowed:
            # One blockwise scan gives count and range together.
            _ = self._n_valid
            result = self.__dict__["_z_range_blockwise"]
        elif self._n_valid == 0:
            # A window of nodata only (allow_empty) has no range.
            result = (float("nan"), float("nan"))
        else:
            result = (float(np.nanmin(self.heights)), float(np.nanmax(self.heights)))
        self.__dict__["_z_range"] = result
        return result

    @property
    def point_count(self) -> int:
        return self._n_valid

    def to_record(self) -> tuple[dict[str, Any], dict[str, RecordArray]]:
        """(attrs, {"heights": heights}).

        On a windowed grid ``heights`` is the WindowedHeights itself, never the band read
        whole: a store writes it block by block with ``heights.iter_blocks()`` (yields half-open
        (r0, r1, c0, c1, block)) or slices ``heights[r0:r1, c0:c1]``; ``heights.source`` is the
        HeightSource (picklable by its arguments) for a store that references rather than
        copies. ``np.asarray`` of it reads the band only under WHOLE_BAND_LIMIT_BYTES, else
        raises WholeBandError. ``attrs["windowed"]`` is True then.
        """
        attrs: dict[str, Any] = {
            "transform": list(self.transform)[:6],
            "crs": self.crs,
            "nodata": self.nodata,
        }
        if self.index_offset != (0, 0):
            attrs["index_offset"] = list(self.index_offset)
        if self.is_windowed:
            attrs["windowed"] = True
        # The band's figures travel with it, so a store opened windowed never scans the band.
        attrs["stats"] = {"points": int(self._n_valid), "z_range": list(self.z_range)}
        return attrs, {"heights": self.heights}

    @classmethod
    def from_record(cls, attrs: dict[str, Any], arrays: Mapping[str, RecordArray]) -> Grid:
        r_off, c_off = attrs.get("index_offset", (0, 0))
        grid = cls(
            arrays["heights"],
            Affine(*attrs["transform"]),
            attrs["crs"],
            attrs["nodata"],
            index_offset=(r_off, c_off),
        )
        stats = attrs.get("stats")
        if stats and grid.is_windowed:
            grid.__dict__["_n_valid"] = int(stats["points"])
            zmin, zmax = stats["z_range"]
            grid.__dict__["_z_range"] = (float(zmin), float(zmax))
        return grid

    def split_position(self, rect: Rect, axis: int) -> float | None:
        at = float(self.split_positions(np.array([rect.as_tuple()], dtype=np.float64), axis)[0])
        return None if np.isnan(at) else at

    def split_positions(self, rects: np.ndarray, axis: int) -> np.ndarray:
        ranges = self.index_ranges(rects)
        lo, hi = (ranges[:, 2], ranges[:, 3]) if axis == 0 else (ranges[:, 0], ranges[:, 1])
        coords = self.x_coords if axis == 0 else self.y_coords
        # A single cell (two data lines) cannot be cut further.
        out = np.full(len(ranges), np.nan)
        ok = hi - lo >= 2
        out[ok] = coords[(lo[ok] + hi[ok]) // 2]
        return out
