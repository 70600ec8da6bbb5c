"""True errors of owners' triangles (nodes, tiles, meshes) at the source terrain's data points.

An *owner* is a closed rectangle of the terrain's domain (world coordinates) and the triangles
that claim to approximate the terrain there, given in world coordinates (x, y, z) by a
callback ``triangles_of(owners) -> (soup (t, 9), owner (t,))`` so that big outputs are decoded
a batch at a time. Two sources of data points:

- ``GridMeasure``: a raster, read window by window (``TILE`` × ``TILE`` lattice points): each
  owner's index range is cut at multiples of TILE into pieces, each window's pieces are
  measured together (``kernels.verify_mesh.grid_mesh_errors``), so every data point is read
  once and memory is bounded by a window plus one batch of triangles. Triangles are taken
  into the raster's index space; with ``snap`` (a tree store's patches, whose vertices are
  lattice points), vertices within ``SNAP`` of a lattice point are put on it, so the edge
  tests are exact. Files with rounded coordinates are measured as they are.
- ``PointMeasure``: scattered points (point clouds, TINs), held in memory as their terrain
  holds them, sorted into buckets once (``point_mesh_errors``).
"""

from __future__ import annotations

import itertools
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.kernels._jit import readonly
from approxtree.kernels.verify_mesh import bucket_points, grid_mesh_errors, point_mesh_errors

#: Lattice points of a window side.
TILE = 512
#: Vertices this close to a lattice point (in cells) are on it.
SNAP = 1e-6
#: Owners decoded per batch of a point source.
_POINT_BATCH = 2048
#: Bytes of index-space triangles kept for owners spanning several windows.
_CACHE_BYTES = 64 << 20

TrianglesOf = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass
class OwnerErrors:
    """Per owner (k,): err (largest |z − h|, −inf when no point was measured, inf never),
    worst (k, 2) world x, y of it, sumsq and measured (points measured), uncovered (valid
    points of the rectangle no triangle holds), holes (nodata points under a triangle),
    zmin/zmax of the valid points (inf/−inf when none)."""

    err: np.ndarray
    worst: np.ndarray
    sumsq: np.ndarray
    measured: np.ndarray
    uncovered: np.ndarray
    holes: np.ndarray
    zmin: np.ndarray
    zmax: np.ndarray

    @classmethod
    def empty(cls, k: int) -> OwnerErrors:
        return cls(
            np.full(k, -np.inf),
            np.full((k, 2), np.nan),
            np.zeros(k),
            np.zeros(k, dtype=np.int64),
            np.zeros(k, dtype=np.int64),
            np.zeros(k, dtype=np.int64),
            np.full(k, np.inf),
            np.full(k, -np.inf),
        )

    @property
    def rms(self) -> np.ndarray:
        """(k,) RMS of |z − h| over the measured points (NaN when none)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.sqrt(self.sumsq / self.measured)

    def fold(self, at: np.ndarray, err, worst, sumsq, counts, zrange) -> None:
        """Fold the results of pieces ``at`` (owner per piece) into the owners' figures."""
        better = np.full(len(self.err), -1, dtype=np.int64)
        # The worst piece of each owner: its position wins where its error is the largest.
        order = np.lexsort((err, at))
        last = np.r_[at[order][1:] != at[order][:-1], True]
        best = order[last]
        owners = at[best]
        improve = err[best] > self.err[owners]
        better[owners[improve]] = best[improve]
        self.err[owners[improve]] = err[best[improve]]
        has = better >= 0
        self.worst[has] = worst[better[has]]
        np.add.at(self.sumsq, at, sumsq)
        np.add.at(self.measured, at, counts[:, 0])
        np.add.at(self.uncovered, at, counts[:, 1])
        np.add.at(self.holes, at, counts[:, 2])
        np.minimum.at(self.zmin, at, zrange[:, 0])
        np.maximum.at(self.zmax, at, zrange[:, 1])


def grid_index_ranges(grid, rects: np.ndarray) -> np.ndarray:
    """(k, 4) int64 inclusive (r0, r1, c0, c1) of the raster's lattice points inside the
    closed rectangles (k, 4) (xmin, ymin, xmax, ymax), 1e-9 cells of slack; empty: r1 < r0."""
    fr_a, fc_a = world_to_index(grid, rects[:, 0], rects[:, 1])
    fr_b, fc_b = world_to_index(grid, rects[:, 2], rects[:, 3])
    rows, cols = grid.shape
    out = np.empty((len(rects), 4), dtype=np.int64)
    with np.errstate(invalid="ignore"):
        out[:, 0] = np.maximum(np.ceil(np.minimum(fr_a, fr_b) - 1e-9), 0)
        out[:, 1] = np.minimum(np.floor(np.maximum(fr_a, fr_b) + 1e-9), rows - 1)
        out[:, 2] = np.maximum(np.ceil(np.minimum(fc_a, fc_b) - 1e-9), 0)
        out[:, 3] = np.minimum(np.floor(np.maximum(fc_a, fc_b) + 1e-9), cols - 1)
    return out


def world_to_index(grid, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fractional (row, col) of the raster's lattice (data points at integers) of world x, y."""
    t = grid.transform
    if t.b or t.d:
        raise InvalidParameterError(
            "The source raster is rotated (its transform has shear terms); verify needs a "
            "north-up raster: warp it with gdalwarp first."
        )
    r_off, c_off = getattr(grid, "index_offset", (0, 0))
    fc = (np.asarray(x, dtype=np.float64) - t.c) / t.a - 0.5 - c_off
    fr = (np.asarray(y, dtype=np.float64) - t.f) / t.e - 0.5 - r_off
    return fr, fc


def index_to_world(grid, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World x, y of fractional lattice (row, col) of the raster."""
    t = grid.transform
    r_off, c_off = getattr(grid, "index_offset", (0, 0))
    return t.c + (np.asarray(cols) + c_off + 0.5) * t.a, t.f + (
        np.asarray(rows) + r_off + 0.5
    ) * t.e


def _snap(a: np.ndarray) -> np.ndarray:
    near = np.rint(a)
    return np.where(np.abs(a - near) <= SNAP, near, a)


class GridMeasure:
    """Owners measured against a raster's data points, window by window (module docstring)."""

    def __init__(self, grid, snap: bool = False) -> None:
        self.grid = grid
        self.snap = snap

    def to_index(self, soup: np.ndarray) -> np.ndarray:
        """(t, 9) world triangles → (t, 9) (col, row, z) in the raster's index space (vertices
        near lattice points snapped onto them when ``snap``)."""
        out = np.empty_like(soup, dtype=np.float64)
        snap = _snap if self.snap else (lambda a: a)
        for c in range(3):
            fr, fc = world_to_index(self.grid, soup[:, 3 * c], soup[:, 3 * c + 1])
            out[:, 3 * c] = snap(fc)
            out[:, 3 * c + 1] = snap(fr)
            out[:, 3 * c + 2] = soup[:, 3 * c + 2]
        return out

    def errors(self, rects: np.ndarray, triangles_of: TrianglesOf, tol: float) -> OwnerErrors:
        """Figures of k owners: rects (k, 4) world; tol: inside slack in cells."""
        rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
        k = len(rects)
        result = OwnerErrors.empty(k)
        ranges = grid_index_ranges(self.grid, rects)
        keep = np.flatnonzero((ranges[:, 1] >= ranges[:, 0]) & (ranges[:, 3] >= ranges[:, 2]))
        if not len(keep):
            return result
        owner, pieces = _pieces(ranges[keep], TILE)
        owner = keep[owner]
        # Window of each piece (its top-left lattice point's), windows row-major.
        key = (pieces[:, 0] // TILE) * (1 << 32) + pieces[:, 2] // TILE
        order = np.lexsort((owner, key))
        owner, pieces, key = owner[order], pieces[order], key[order]
        spans = np.bincount(owner, minlength=k)
        cache: OrderedDict[int, np.ndarray] = OrderedDict()
        bounds = np.flatnonzero(np.r_[True, key[1:] != key[:-1], True])
        for a, b in itertools.pairwise(bounds.tolist()):
            self._window(pieces[a:b], owner[a:b], triangles_of, tol, spans, cache, result)
        return result

    def _window(self, pieces, owner, triangles_of, tol, spans, cache, result) -> None:
        """Measure one window's pieces (all inside one TILE × TILE window)."""
        owners = np.unique(owner)
        # Owners decoded for an earlier window first (decoding the others may evict them).
        held = [o for o in owners.tolist() if o in cache]
        soups = [(o, cache[o]) for o in held]
        for o in held:
            cache.move_to_end(o)
        fresh = np.setdiff1d(owners, np.array(held, dtype=np.int64))
        if len(fresh):
            soup, which = triangles_of(fresh)
            soup = self.to_index(np.asarray(soup, dtype=np.float64).reshape(-1, 9))
            which = np.asarray(which, dtype=np.int64)
            part = np.argsort(which, kind="stable")
            soup, which = soup[part], which[part]
            cuts = np.searchsorted(which, fresh, side="left")
            ends = np.searchsorted(which, fresh, side="right")
            for o, s, e in zip(fresh.tolist(), cuts.tolist(), ends.tolist(), strict=True):
                tri = soup[s:e]
                if spans[o] > 1:
                    _remember(cache, o, tri)
                soups.append((o, tri))
        soups.sort(key=lambda item: item[0])
        counts = np.array([len(t) for _, t in soups], dtype=np.int64)
        tris = np.concatenate([t for _, t in soups]) if soups else np.zeros((0, 9))
        start = np.r_[0, np.cumsum(counts)]
        at = np.searchsorted(owners, owner)
        piece_tris = np.column_stack([start[at], start[at + 1]]).astype(np.int64)
        r0, r1 = int(pieces[:, 0].min()), int(pieces[:, 1].max())
        c0, c1 = int(pieces[:, 2].min()), int(pieces[:, 3].max())
        z = np.asarray(self.grid.heights[r0 : r1 + 1, c0 : c1 + 1], dtype=np.float64)
        err, worst, sumsq, cnt, zr = grid_mesh_errors(
            readonly(z), r0, c0, readonly(pieces), readonly(piece_tris), readonly(tris), tol
        )
        wx, wy = index_to_world(self.grid, worst[:, 0], worst[:, 1])
        xy = np.where(worst[:, :1] >= 0, np.column_stack([wx, wy]), np.nan)
        result.fold(owner, err, xy, sumsq, cnt, zr)


def _remember(cache: OrderedDict, key: int, tri: np.ndarray) -> None:
    cache[key] = tri
    while len(cache) > 1 and sum(t.nbytes for t in cache.values()) > _CACHE_BYTES:
        cache.popitem(last=False)


def _pieces(ranges: np.ndarray, tile: int) -> tuple[np.ndarray, np.ndarray]:
    """Cut inclusive ranges (k, 4) at multiples of ``tile``: (owner (p,), pieces (p, 4))."""
    rb0, rb1 = ranges[:, 0] // tile, ranges[:, 1] // tile
    cb0, cb1 = ranges[:, 2] // tile, ranges[:, 3] // tile
    nr, nc = rb1 - rb0 + 1, cb1 - cb0 + 1
    per = nr * nc
    owner = np.repeat(np.arange(len(ranges)), per)
    # Position of each piece inside its owner's nr × nc blocks.
    first = np.repeat(np.cumsum(per) - per, per)
    pos = np.arange(per.sum()) - first
    i = pos // nc[owner] + rb0[owner]
    j = pos % nc[owner] + cb0[owner]
    pieces = np.column_stack(
        [
            np.maximum(i * tile, ranges[owner, 0]),
            np.minimum((i + 1) * tile - 1, ranges[owner, 1]),
            np.maximum(j * tile, ranges[owner, 2]),
            np.minimum((j + 1) * tile - 1, ranges[owner, 3]),
        ]
    ).astype(np.int64)
    return owner, pieces


class PointMeasure:
    """Owners measured against scattered data points (n, 3) held in memory."""

    def __init__(self, points: np.ndarray) -> None:
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        self.x = np.ascontiguousarray(p[:, 0])
        self.y = np.ascontiguousarray(p[:, 1])
        self.z = np.ascontiguousarray(p[:, 2])
        self.start, self.items, self.grid = bucket_points(self.x, self.y)

    def errors(self, rects: np.ndarray, triangles_of: TrianglesOf, tol: float) -> OwnerErrors:
        """Figures of k owners: rects (k, 4) world; tol: inside slack in world units."""
        rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
        k = len(rects)
        result = OwnerErrors.empty(k)
        for a in range(0, k, _POINT_BATCH):
            owners = np.arange(a, min(k, a + _POINT_BATCH))
            soup, which = triangles_of(owners)
            soup = np.asarray(soup, dtype=np.float64).reshape(-1, 9)
            which = np.asarray(which, dtype=np.int64)
            part = np.argsort(which, kind="stable")
            soup, which = soup[part], which[part]
            owner_tris = np.column_stack(
                [np.searchsorted(which, owners), np.searchsorted(which, owners, side="right")]
            ).astype(np.int64)
            err, worst, sumsq, cnt, zr = point_mesh_errors(
                self.x,
                self.y,
                self.z,
                self.start,
                self.items,
                self.grid,
                readonly(rects[owners]),
                readonly(owner_tris),
                readonly(soup),
                tol,
            )
            xy = np.where(
                worst[:, None] >= 0,
                np.column_stack([self.x[np.maximum(worst, 0)], self.y[np.maximum(worst, 0)]]),
                np.nan,
            )
            result.fold(owners, err, xy, sumsq, cnt, zr)
        return result


def measure_for(terrain, snap: bool = False):
    """The measure of a source terrain: GridMeasure for a raster (``snap``: see
    GridMeasure), PointMeasure otherwise."""
    from approxtree.geometry.grid import Grid

    if isinstance(terrain, Grid):
        return GridMeasure(terrain, snap)
    return PointMeasure(terrain.points())
