"""Windowed heights: a read-only 2-D array-like that reads only the blocks a computation needs.

A ``HeightSource`` reads half-open windows of a height band (a GDAL raster, a zarr array, an
in-memory array for tests). ``WindowedHeights`` puts a block cache bounded in bytes in front
of it and answers numpy indexing (basic slices, strided slices, integer index arrays with
broadcasting) by reading only the blocks the indices touch, so a Grid over a raster far larger
than memory answers points(rect), height_at and z range with memory bounded by the cache.

Both pickle by their source's arguments, never by the data read, so dask can ship a windowed
Grid to workers that then read their own windows.
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Protocol, runtime_checkable

import numpy as np

from approxtree.errors import WholeBandError

#: Bytes of decoded blocks a WindowedHeights keeps by default.
DEFAULT_CACHE_BYTES = 128 * 2**20

#: Side (cells) of a cache block; the blocks are whole tiles or strips of the source.
BLOCK_SIDE = 512

#: Block (rows, cols) used when the source has no usable natural block shape.
DEFAULT_BLOCK_SHAPE = (BLOCK_SIDE, BLOCK_SIDE)

#: Largest band (bytes of heights) an operation that needs the whole band reads on a windowed
#: terrain; beyond it the operation raises WholeBandError.
WHOLE_BAND_LIMIT_BYTES = 256 * 2**20


@runtime_checkable
class HeightSource(Protocol):
    """A height band read by windows.

    shape: (rows, cols). dtype: float32 or float64. ``read(r0, r1, c0, c1)`` returns the
    HALF-OPEN window rows [r0, r1), columns [c0, c1) as a (r1 − r0, c1 − c0) array of ``dtype``
    with NaN for nodata. It is called from several threads at once. A source may also have
    ``block_shape`` (rows, cols): the blocks it reads cheaply (a GeoTIFF's tiles).
    Sources pickle by their arguments (a path, a band), never by their data.
    """

    @property
    def shape(self) -> tuple[int, int]: ...

    @property
    def dtype(self) -> np.dtype: ...

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray: ...


class ArraySource:
    """A HeightSource over an in-memory (rows, cols) float array (for tests and small data)."""

    def __init__(self, heights: np.ndarray, block_shape: tuple[int, int] | None = None) -> None:
        a = np.asarray(heights)
        if a.ndim != 2 or a.dtype not in (np.float32, np.float64):
            raise TypeError(
                f"ArraySource needs a 2-D float32/float64 array, got {a.dtype} {a.shape}"
            )
        self.array = a
        self.shape = (int(a.shape[0]), int(a.shape[1]))
        self.dtype = a.dtype
        self.block_shape = block_shape
        #: Windows read so far (rows × cols summed), so tests can check what was read.
        self.cells_read = 0
        self._count_lock = threading.Lock()

    def __reduce__(self):
        return (ArraySource, (self.array, self.block_shape))

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        with self._count_lock:
            self.cells_read += (r1 - r0) * (c1 - c0)
        return np.array(self.array[r0:r1, c0:c1], copy=True)


def _axis_selection(key: Any, n: int) -> tuple[np.ndarray | slice, bool]:
    """One axis of a key → (non-negative index array or normalised slice, axis dropped)."""
    if isinstance(key, slice):
        return slice(*key.indices(n)), False
    if isinstance(key, int | np.integer):
        i = int(key)
        if not -n <= i < n:
            raise IndexError(f"index {i} is out of bounds for axis of size {n}")
        i %= n
        return slice(i, i + 1, 1), True
    a = np.asarray(key)
    if a.dtype.kind not in "iu":
        raise IndexError(f"WindowedHeights takes slices and integer indices, got {a.dtype}")
    a = a.astype(np.int64)
    if a.size and (a.min() < -n or a.max() >= n):
        raise IndexError(f"index out of bounds for axis of size {n}")
    return np.where(a < 0, a + n, a), False


class WindowedHeights:
    """A read-only (rows, cols) array-like over a HeightSource, read through a block cache.

    source: the HeightSource. cache_bytes: the most bytes of decoded blocks kept (least
    recently used evicted first; the blocks one request needs are read even when they exceed
    it, but not kept). block_shape: (rows, cols) of a block; by default the source's own when
    it has one (whole tiles or strips), else DEFAULT_BLOCK_SHAPE. Thread-safe.

    Indexing follows numpy: ``h[r0:r1, c0:c1]`` and strided slices return a (copied) array
    of the selection; ``h[rr, cc]`` with integer arrays (broadcast together) returns the values
    at those indices, reading only the blocks they fall in. Nothing else is supported.
    """

    def __init__(
        self,
        source: HeightSource,
        cache_bytes: int = DEFAULT_CACHE_BYTES,
        block_shape: tuple[int, int] | None = None,
    ) -> None:
        self.source = source
        self.shape = (int(source.shape[0]), int(source.shape[1]))
        self.dtype = np.dtype(source.dtype)
        self.cache_bytes = int(cache_bytes)
        self.block_shape = self._choose_block_shape(block_shape)
        self._cache: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()
        self._cached_bytes = 0
        self._lock = threading.Lock()

    def _choose_block_shape(self, block_shape: tuple[int, int] | None) -> tuple[int, int]:
        """The block shape: the given one, else one fitted to the source's own blocks.

        Tiles (16..4096 a side, a GeoTIFF's or a VRT's) are grouped into blocks of about
        BLOCK_SIDE a side, whole tiles each; strips (rows spanning the width) into blocks of
        whole strips of about BLOCK_SIDE² cells; anything else gets DEFAULT_BLOCK_SHAPE.
        """
        rows, cols = self.shape
        if block_shape is None:
            block_shape = DEFAULT_BLOCK_SHAPE
            natural = getattr(self.source, "block_shape", None)
            if natural is not None:
                br, bc = (max(1, int(b)) for b in natural)
                if 16 <= br <= 4096 and 16 <= bc <= 4096:
                    block_shape = (br * max(1, BLOCK_SIDE // br), bc * max(1, BLOCK_SIDE // bc))
                elif bc >= cols and cols <= 16 * BLOCK_SIDE:
                    strip_rows = -(-(BLOCK_SIDE * BLOCK_SIDE) // cols)
                    block_shape = (br * max(1, -(-strip_rows // br)), cols)
        br, bc = (max(1, int(b)) for b in block_shape)
        return (min(br, rows), min(bc, cols))

    # -- array-like attributes ------------------------------------------------------------------

    ndim = 2

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]

    @property
    def nbytes(self) -> int:
        return self.size * self.dtype.itemsize

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return (
            f"WindowedHeights(shape={self.shape}, dtype={self.dtype}, block={self.block_shape}, "
            f"cache={self.cache_bytes / 2**20:.0f} MB, source={self.source!r})"
        )

    def __reduce__(self):
        # By the source's arguments: never the cached blocks.
        return (WindowedHeights, (self.source, self.cache_bytes, self.block_shape))

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        """The whole band, if it is at most WHOLE_BAND_LIMIT_BYTES; else WholeBandError."""
        check_whole_band(self.shape, self.dtype, "converting windowed heights to an array")
        out = self[:, :]
        return out if dtype is None else out.astype(dtype, copy=False)

    # -- the block cache ------------------------------------------------------------------------

    def block_count(self) -> tuple[int, int]:
        """(block rows, block cols) covering the band."""
        br, bc = self.block_shape
        return (-(-self.shape[0] // br), -(-self.shape[1] // bc))

    def block_bounds(self, bi: int, bj: int) -> tuple[int, int, int, int]:
        """Half-open (r0, r1, c0, c1) of block (bi, bj)."""
        br, bc = self.block_shape
        return (
            bi * br,
            min((bi + 1) * br, self.shape[0]),
            bj * bc,
            min((bj + 1) * bc, self.shape[1]),
        )

    def block(self, bi: int, bj: int) -> np.ndarray:
        """Block (bi, bj) as a read-only array, from the cache or read (and cached)."""
        key = (bi, bj)
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        # Read outside the lock so that threads read different blocks at once; two threads
        # asking for the same block may both read it (harmless, one copy stays).
        r0, r1, c0, c1 = self.block_bounds(bi, bj)
        data = np.asarray(self.source.read(r0, r1, c0, c1), dtype=self.dtype)
        data.flags.writeable = False
        with self._lock:
            if key not in self._cache and data.nbytes <= self.cache_bytes:
                self._cache[key] = data
                self._cached_bytes += data.nbytes
                while self._cached_bytes > self.cache_bytes:
                    _, old = self._cache.popitem(last=False)
                    self._cached_bytes -= old.nbytes
        return data

    def clear_cache(self) -> None:
        """Drop every cached block."""
        with self._lock:
            self._cache.clear()
            self._cached_bytes = 0

    @property
    def cached_bytes(self) -> int:
        """Bytes of blocks held in the cache now."""
        return self._cached_bytes

    def iter_blocks(self) -> Iterator[tuple[int, int, int, int, np.ndarray]]:
        """(r0, r1, c0, c1, block) over every block, row-major; half-open bounds.

        Blocks are read straight from the source (not kept), so a scan of the whole band leaves
        the cache as it was. This is how a store writes a windowed terrain chunk by chunk.
        """
        nbr, nbc = self.block_count()
        for bi in range(nbr):
            for bj in range(nbc):
                r0, r1, c0, c1 = self.block_bounds(bi, bj)
                data = np.asarray(self.source.read(r0, r1, c0, c1), dtype=self.dtype)
                yield r0, r1, c0, c1, data

    # -- indexing -------------------------------------------------------------------------------

    def __getitem__(self, key: Any) -> np.ndarray:
        if not isinstance(key, tuple):
            key = (key, slice(None))
        if len(key) != 2 or any(k is Ellipsis or k is None for k in key):
            raise IndexError("WindowedHeights takes exactly two indices (rows, cols)")
        sel_r, dr = _axis_selection(key[0], self.shape[0])
        sel_c, dc = _axis_selection(key[1], self.shape[1])
        # Integer arrays: numpy's rule (a slice next to an array becomes a trailing/leading axis).
        if isinstance(sel_r, slice):
            if isinstance(sel_c, slice):
                out = self._read_slices(sel_r, sel_c)
                if dr and dc:
                    return out[0, 0]
                return out[0] if dr else (out[:, 0] if dc else out)
            rows = np.arange(sel_r.start, sel_r.stop, sel_r.step)
            rr = rows.reshape((-1,) + (1,) * sel_c.ndim) if not dr else rows[0]
            return self._read_points(*np.broadcast_arrays(rr, sel_c))
        if isinstance(sel_c, slice):
            cols = np.arange(sel_c.start, sel_c.stop, sel_c.step)
            cc = cols if not dc else cols[0]
            return self._read_points(
                *np.broadcast_arrays(sel_r[..., None] if not dc else sel_r, cc)
            )
        return self._read_points(*np.broadcast_arrays(sel_r, sel_c))

    def _read_slices(self, sr: slice, sc: slice) -> np.ndarray:
        """The (len(rows), len(cols)) selection of two normalised slices."""
        rows = range(sr.start, sr.stop, sr.step)
        cols = range(sc.start, sc.stop, sc.step)
        if len(rows) == 0 or len(cols) == 0:
            return np.empty((len(rows), len(cols)), dtype=self.dtype)
        # A large contiguous window is read straight from the source: going through the cache
        # would only evict what smaller requests keep there.
        nbytes = len(rows) * len(cols) * self.dtype.itemsize
        if sr.step == 1 and sc.step == 1 and nbytes > self.cache_bytes // 4:
            data = self.source.read(rows[0], rows[-1] + 1, cols[0], cols[-1] + 1)
            return np.asarray(data, dtype=self.dtype)
        out = np.empty((len(rows), len(cols)), dtype=self.dtype)
        for bi, out_r, in_r in self._axis_runs(rows, 0):
            for bj, out_c, in_c in self._axis_runs(cols, 1):
                block = self.block(bi, bj)
                if isinstance(in_r, slice) and isinstance(in_c, slice):
                    out[out_r, out_c] = block[in_r, in_c]
                else:
                    out[out_r, out_c] = block[np.ix_(_as_index(in_r), _as_index(in_c))]
        return out

    def _axis_runs(self, idx: range, axis: int) -> Iterator[tuple[int, slice, slice | np.ndarray]]:
        """(block, positions in idx, indices in the block) for the blocks a range touches."""
        b = self.block_shape[axis]
        a = np.arange(idx.start, idx.stop, idx.step)
        blocks = a // b
        # A range is monotonic, so each block's positions form one run.
        cuts = np.flatnonzero(np.diff(blocks)) + 1
        starts = np.concatenate([[0], cuts])
        ends = np.concatenate([cuts, [a.size]])
        for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
            blk = int(blocks[s])
            local = a[s:e] - blk * b
            if idx.step == 1:
                yield blk, slice(s, e), slice(int(local[0]), int(local[-1]) + 1)
            else:
                yield blk, slice(s, e), local

    def _read_points(self, rr: np.ndarray, cc: np.ndarray) -> np.ndarray:
        """Values at broadcast integer indices (any shape), grouped by block."""
        shape = rr.shape
        r = rr.ravel()
        c = cc.ravel()
        out = np.empty(r.size, dtype=self.dtype)
        if r.size == 0:
            return out.reshape(shape)
        br, bc = self.block_shape
        nbc = self.block_count()[1]
        ids = (r // br) * nbc + c // bc
        order = np.argsort(ids, kind="stable")
        sorted_ids = ids[order]
        cuts = np.flatnonzero(np.diff(sorted_ids)) + 1
        starts = np.concatenate([[0], cuts])
        ends = np.concatenate([cuts, [order.size]])
        # One block read per block touched, never per point.
        for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
            sel = order[s:e]
            bi, bj = divmod(int(sorted_ids[s]), nbc)
            block = self.block(bi, bj)
            out[sel] = block[r[sel] - bi * br, c[sel] - bj * bc]
        return out.reshape(shape)


def _as_index(sel: slice | np.ndarray) -> np.ndarray:
    return np.arange(sel.start, sel.stop) if isinstance(sel, slice) else sel


def check_whole_band(shape: tuple[int, int], dtype: np.dtype, operation: str) -> None:
    """WholeBandError when a band of this shape exceeds WHOLE_BAND_LIMIT_BYTES."""
    nbytes = int(shape[0]) * int(shape[1]) * np.dtype(dtype).itemsize
    if nbytes > WHOLE_BAND_LIMIT_BYTES:
        raise WholeBandError(
            f"{operation} needs the whole height band of this windowed terrain "
            f"({shape[0]} × {shape[1]} cells, {nbytes / 2**20:.0f} MB as {np.dtype(dtype)}), "
            f"more than the {WHOLE_BAND_LIMIT_BYTES / 2**20:.0f} MB read whole on a windowed "
            "terrain. Work on a part of it (Grid.window(r0, r1, c0, c1), or crop the raster "
            "with gdal_translate -srcwin), or open it in memory (read_raster(..., "
            "windowed=False), --windowed off) on a machine with the memory."
        )


def band_statistics(
    heights: WindowedHeights, workers: int | None = None
) -> tuple[int, float, float]:
    """(valid count, z min, z max) of a windowed band, read block by block (none kept).

    Rows of blocks are reduced by ``workers`` threads (default: the CPU count; sources are
    thread-safe and reads release the GIL). Peak memory: one block per thread. z min/max are
    NaN when no cell is valid.
    """
    nbr, nbc = heights.block_count()

    def reduce_row(bi: int) -> tuple[int, float, float]:
        count, lo, hi = 0, np.inf, -np.inf
        for bj in range(nbc):
            r0, r1, c0, c1 = heights.block_bounds(bi, bj)
            block = np.asarray(heights.source.read(r0, r1, c0, c1), dtype=heights.dtype)
            finite = np.isfinite(block)
            n = int(np.count_nonzero(finite))
            if n:
                count += n
                lo = min(lo, float(np.min(block, where=finite, initial=np.inf)))
                hi = max(hi, float(np.max(block, where=finite, initial=-np.inf)))
        return count, lo, hi

    n_workers = max(1, min(workers or os.cpu_count() or 1, nbr))
    with ThreadPoolExecutor(n_workers) as pool:
        rows = list(pool.map(reduce_row, range(nbr)))
    count = sum(r[0] for r in rows)
    if count == 0:
        return 0, float("nan"), float("nan")
    return count, min(r[1] for r in rows), max(r[2] for r in rows)
