"""The terrain's data points inside each tile of the geographic tiling, in the tile's (u, v).

A tile's error is measured at the terrain's data points (valid cell centres of its grid) that
lie in the tile's closed lon/lat square: a point on a shared edge belongs to both tiles. The
grid is cut into blocks of BLOCK × BLOCK cells; ``PointBlocks`` carries each block's cell
centres through pyproj into lon/lat once and keeps the results in a cache bounded in bytes
(tiles of one level share blocks, and coarse tiles all cover the same ones). A tile finds the
blocks whose lon/lat box meets its square (``PointBlocks.meeting``), and ``TilePoints`` gives
their points inside it as quantized-mesh coordinates u, v in 0..QMAX (floats, unrounded):
all at once, stride-decimated, or chunk by chunk so that a tile holding more points than
memory allows is still measured at every one.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from approxtree.geometry.grid import Grid
from approxtree.tiles.encoding import QMAX

#: Side (cells) of the blocks whose lon/lat are computed and cached together.
BLOCK = 256
#: Bytes of block lon/lat and heights a PointBlocks keeps: 24 bytes a cell, so 256 MiB hold
#: about 11 M cells (a 3300² DEM).
LONLAT_CACHE_BYTES = 256 * 2**20
#: Cells between the points whose lon/lat bound each block's lon/lat box.
_BOX_STEP = 32

ToLonLat = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass
class PointSet:
    """Data points of a tile: u, v (n,) float64 in 0..QMAX (from west, from south; not
    rounded), z (n,) float64 heights, cell (n,) int64 their cells (row · cols + col), and
    ou, ov (n,) float64 the (u, v) step from a point on the grid's outer edge half a cell
    outward (0 for the others: rounding an edge point outward keeps it off the drop beyond)."""

    u: np.ndarray
    v: np.ndarray
    z: np.ndarray
    cell: np.ndarray
    ou: np.ndarray
    ov: np.ndarray

    FIELDS = ("u", "v", "z", "cell", "ou", "ov")

    @classmethod
    def empty(cls) -> PointSet:
        e = np.empty(0)
        return cls(e, e, e, np.empty(0, dtype=np.int64), e, e)

    @classmethod
    def concat(cls, parts: list[PointSet]) -> PointSet:
        if not parts:
            return cls.empty()
        if len(parts) == 1:
            return parts[0]
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in cls.FIELDS))

    def take(self, idx: np.ndarray) -> PointSet:
        return PointSet(*(getattr(self, f)[idx] for f in self.FIELDS))

    def __len__(self) -> int:
        return len(self.z)


@dataclass
class _Block:
    """One block's cells from row r0, column c0: lon, lat, z (rows, cols) float64 (NaN where
    the cell has no data); edge (k,) int64 the flat indices (sorted) of its valid cells on the
    grid's outer edge, edge_lon, edge_lat (k,) their points half a cell outward."""

    r0: int
    c0: int
    lon: np.ndarray
    lat: np.ndarray
    z: np.ndarray
    edge: np.ndarray
    edge_lon: np.ndarray
    edge_lat: np.ndarray

    @property
    def nbytes(self) -> int:
        return self.lon.nbytes + self.lat.nbytes + self.z.nbytes + 3 * self.edge.nbytes


class PointBlocks:
    """The terrain's cell centres in lon/lat, block by block, through a bounded cache.

    terrain: a Grid (in memory or windowed); to_lonlat: terrain x, y → lon, lat (pyproj);
    cache_bytes: the most bytes of blocks kept (least recently used dropped first). Not
    pickled: each process makes its own (``TileSampler.blocks``).
    """

    def __init__(
        self, terrain: Grid, to_lonlat: ToLonLat, cache_bytes: int = LONLAT_CACHE_BYTES
    ) -> None:
        self.terrain = terrain
        self.to_lonlat = to_lonlat
        self.cache_bytes = int(cache_bytes)
        rows, cols = terrain.shape
        self.rows, self.cols = rows, cols
        self.shape = (-(-rows // BLOCK), -(-cols // BLOCK))
        self._cache: OrderedDict[tuple[int, int], _Block] = OrderedDict()
        self._cached = 0
        self._lock = threading.Lock()

    @cached_property
    def boxes(self) -> np.ndarray:
        """(block rows, block cols, 4) float64 lon/lat box (west, south, east, north) of each
        block's cell centres, padded by 1 % of its size against the curvature of its edges
        between the points it is computed from (every _BOX_STEP cells and each block's last
        line)."""
        nbr, nbc = self.shape

        def lines(n: int) -> np.ndarray:
            last = np.minimum(np.arange(1, -(-n // BLOCK) + 1) * BLOCK, n) - 1
            return np.union1d(np.arange(0, n, _BOX_STEP), last)

        rr, cc = lines(self.rows), lines(self.cols)
        g = self.terrain
        x, y = np.meshgrid(g.x_coords[cc], g.y_coords[rr])
        lon, lat = (np.asarray(a, dtype=np.float64) for a in self.to_lonlat(x, y))
        rs = np.searchsorted(rr, np.arange(nbr) * BLOCK)
        cs = np.searchsorted(cc, np.arange(nbc) * BLOCK)

        # Each block's lines are those from its first line up to the next block's first: the
        # extremes of a smooth map of a rectangle lie on its edges, which these points sample.
        def reduce(a: np.ndarray, fn: np.ufunc) -> np.ndarray:
            return fn.reduceat(fn.reduceat(a, rs, axis=0), cs, axis=1)

        west, east = reduce(lon, np.minimum), reduce(lon, np.maximum)
        south, north = reduce(lat, np.minimum), reduce(lat, np.maximum)
        pad_x = 0.01 * (east - west) + 1e-9
        pad_y = 0.01 * (north - south) + 1e-9
        boxes = np.stack([west - pad_x, south - pad_y, east + pad_x, north + pad_y], axis=-1)
        # A block the CRS cannot carry to lon/lat (outside its area) meets every tile.
        bad = ~np.isfinite(boxes).all(axis=-1)
        boxes[bad] = (-np.inf, -np.inf, np.inf, np.inf)
        return boxes

    def meeting(self, bounds: tuple[float, float, float, float]) -> list[tuple[int, int]]:
        """(bi, bj) of the blocks whose lon/lat box meets the closed square ``bounds``
        (west, south, east, north), row-major."""
        west, south, east, north = bounds
        b = self.boxes
        hit = (b[..., 0] <= east) & (b[..., 2] >= west)
        hit &= (b[..., 1] <= north) & (b[..., 3] >= south)
        return [(int(i), int(j)) for i, j in np.argwhere(hit)]

    def _compute(self, bi: int, bj: int) -> _Block:
        """Block (bi, bj) read and carried to lon/lat (only its valid cells through pyproj)."""
        r0, c0 = bi * BLOCK, bj * BLOCK
        r1, c1 = min(r0 + BLOCK, self.rows), min(c0 + BLOCK, self.cols)
        g = self.terrain
        z = np.asarray(g.heights[r0:r1, c0:c1], dtype=np.float64)
        valid = np.isfinite(z)
        lon = np.full(z.shape, np.nan)
        lat = np.full(z.shape, np.nan)
        if valid.any():
            rr, cc = np.nonzero(valid)
            lo, la = self.to_lonlat(g.x_coords[c0 + cc], g.y_coords[r0 + rr])
            lon[valid], lat[valid] = lo, la
        # Cells on the grid's outer edge: the point half a cell outward (a corner diagonally).
        rows = np.arange(r0, r1)[:, None]
        cols = np.arange(c0, c1)[None, :]
        dr = np.where(rows == 0, -0.5, 0.0) + np.where(rows == self.rows - 1, 0.5, 0.0)
        dc = np.where(cols == 0, -0.5, 0.0) + np.where(cols == self.cols - 1, 0.5, 0.0)
        dr, dc = np.broadcast_arrays(dr, dc)
        edge = np.flatnonzero((valid & ((dr != 0) | (dc != 0))).ravel())
        er, ec = np.divmod(edge, c1 - c0)
        t = g.transform
        ex = g.x_coords[c0 + ec] + dc.ravel()[edge] * t.a
        ey = g.y_coords[r0 + er] + dr.ravel()[edge] * t.e
        edge_lon, edge_lat = (np.asarray(a, dtype=np.float64) for a in self.to_lonlat(ex, ey))
        return _Block(r0, c0, lon, lat, z, edge, edge_lon.ravel(), edge_lat.ravel())

    def blocks(self, keys: list[tuple[int, int]]) -> Iterator[_Block]:
        """The blocks of ``keys``: cached ones first, then the others, computed. When they
        would not all fit in the cache, those computed are not kept: a scan larger than the
        cache would otherwise evict every block before its next use."""
        with self._lock:
            hits = [k for k in keys if k in self._cache]
        cached = set(hits)
        misses = [k for k in keys if k not in cached]
        need = len(keys) * BLOCK * BLOCK * 24
        keep = need <= self.cache_bytes
        for k in hits:
            with self._lock:
                block = self._cache.get(k)
                if block is not None:
                    self._cache.move_to_end(k)
            yield block if block is not None else self._compute(*k)
        for k in misses:
            block = self._compute(*k)
            if keep:
                with self._lock:
                    if k not in self._cache:
                        self._cache[k] = block
                        self._cached += block.nbytes
                    while self._cached > self.cache_bytes and len(self._cache) > 1:
                        _, old = self._cache.popitem(last=False)
                        self._cached -= old.nbytes
            yield block


class TilePoints:
    """The data points inside one tile's closed square, read from PointBlocks.

    blocks: the terrain's PointBlocks; bounds: (west, south, east, north) degrees.
    """

    def __init__(self, blocks: PointBlocks, bounds: tuple[float, float, float, float]) -> None:
        self.blocks = blocks
        west, south, east, north = bounds
        self.bounds = (float(west), float(south), float(east), float(north))
        self.keys = blocks.meeting(self.bounds)

    def estimate(self) -> int:
        """About how many cells lie in the tile: each meeting block's cells times the share of
        its lon/lat box inside the square (an upper bound's estimate, for choosing a stride)."""
        if not self.keys:
            return 0
        west, south, east, north = self.bounds
        b = self.blocks.boxes[tuple(np.array(self.keys).T)]
        w = np.clip(np.minimum(b[:, 2], east) - np.maximum(b[:, 0], west), 0, None)
        h = np.clip(np.minimum(b[:, 3], north) - np.maximum(b[:, 1], south), 0, None)
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.nan_to_num((w * h) / ((b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])), nan=1.0)
        return int(np.ceil((np.clip(share, 0, 1) * BLOCK * BLOCK).sum()))

    def _inside(self, block: _Block, stride: int) -> PointSet:
        """The block's points in the square, on rows and columns that are multiples of
        ``stride`` (1: all)."""
        i0 = (-block.r0) % stride
        j0 = (-block.c0) % stride
        lon = block.lon[i0::stride, j0::stride]
        lat = block.lat[i0::stride, j0::stride]
        west, south, east, north = self.bounds
        # NaN (no data) compares False: left out.
        ii, jj = np.nonzero((lon >= west) & (lon <= east) & (lat >= south) & (lat <= north))
        lo, la = lon[ii, jj], lat[ii, jj]
        u = np.clip((lo - west) / (east - west) * QMAX, 0.0, QMAX)
        v = np.clip((la - south) / (north - south) * QMAX, 0.0, QMAX)
        li = i0 + ii * stride
        lj = j0 + jj * stride
        z = block.z[i0::stride, j0::stride][ii, jj]
        cell = (block.r0 + li).astype(np.int64) * self.blocks.cols + block.c0 + lj
        # The outward step of the points on the grid's outer edge.
        ou, ov = np.zeros(len(u)), np.zeros(len(u))
        if len(block.edge) and len(u):
            flat = li.astype(np.int64) * block.z.shape[1] + lj
            at = np.minimum(np.searchsorted(block.edge, flat), len(block.edge) - 1)
            hit = np.flatnonzero(block.edge[at] == flat)
            ou[hit] = (block.edge_lon[at[hit]] - west) / (east - west) * QMAX - u[hit]
            ov[hit] = (block.edge_lat[at[hit]] - south) / (north - south) * QMAX - v[hit]
        return PointSet(u, v, z, cell, ou, ov)

    def gather(self, stride: int = 1) -> PointSet:
        """Every point of the tile on rows and columns that are multiples of ``stride``."""
        return PointSet.concat([self._inside(b, stride) for b in self.blocks.blocks(self.keys)])

    def chunks(self, size: int) -> Iterator[PointSet]:
        """Every point of the tile, in chunks of about ``size`` points (a block at least)."""
        parts: list[PointSet] = []
        n = 0
        for block in self.blocks.blocks(self.keys):
            part = self._inside(block, 1)
            if len(part):
                parts.append(part)
                n += len(part)
            if n >= size:
                yield PointSet.concat(parts)
                parts, n = [], 0
        if parts:
            yield PointSet.concat(parts)
