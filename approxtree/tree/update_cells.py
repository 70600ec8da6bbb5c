"""Large grid patches of an updated tree, re-measured only in the lattice cells an edit reaches.

A node's grid patch error is a maximum over its data points; the few large nodes above an
edit (the root, its children, ...) would cost a pass over most of the terrain each. The cache
keeps, per large patch (keyed by its index (r0, r1, c0, c1, sr, sc), which does not depend
on node ids), the figures of each lattice cell (``kernels.grid_cells``); an update measures
again the cells owning edited points, and around an edited vertex the cells on both sides and
one more each way (a point on a sampled line may use the neighbouring cell's triangle), and
reduces the cells into
the patch's figures, bit for bit those of a fresh build. Entries meeting a window that an
update did not refresh (their node is gone) are forgotten, so none goes stale.

The cells are made by the build itself (``builder.build_levels`` measures a level of large
grid patches per cell, with ``grid_patch_cells_many``, instead of with the whole-patch kernel:
the same figures), kept by the tree, saved in its store (``cells/``, ``tree_store``) and read
back by the first update of a loaded tree, so neither an update in memory nor a store update
measures a large patch whole. A tree without them (a blocked build, an older store) measures
the large patches above its first edits whole, as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.kernels.grid_cells import grid_patch_cells, grid_patch_cells_many
from approxtree.patches.grid import GridPatch, GridPatchArrays
from approxtree.tree.policy import StrategyPolicy
from approxtree.tree.update_band import read_domains

#: Data points from which a node's grid patch is measured per cell (1024² and more): the cells
#: around an edit (one thread) cost less than a whole re-measure by the build's kernel.
LARGE_POINTS = 1 << 20

#: Data points from which a build measures a level's large patches per cell (2048² and
#: more: few patches of large cells, about as fast as the whole-patch kernel, and a store
#: update's first edit in an area then re-measures no 2048² patch whole); the smaller large
#: patches get their cells when an update first reaches them (then kept, and saved).
BUILD_POINTS = 1 << 22

#: Points of a re-measure below which it runs on one thread.
SERIAL_POINTS = 1 << 20

Index = tuple[int, int, int, int, int, int]

#: A window of no cells: measuring patches from their cells, nothing edited.
NO_WINDOW = (0, -1, 0, -1)


@dataclass
class CellCache:
    """Per-cell figures of large grid patches: index → (error, zmin, zmax, count, zeros)
    arrays of shape (nbr, nbc) (float64 ×3, int64 ×2; ``kernels.grid_cells``)."""

    entries: dict[Index, tuple[np.ndarray, ...]] = field(default_factory=dict)
    touched: set[Index] = field(default_factory=set)

    def eligible(
        self, grid: Grid, policy: StrategyPolicy, level: int, rects: np.ndarray, max_points: int
    ) -> np.ndarray:
        """(k,) bool: the nodes measured per cell (large, and grid patches by the policy)."""
        ranges = grid.index_ranges(rects)
        points = (ranges[:, 1] - ranges[:, 0] + 1) * (ranges[:, 3] - ranges[:, 2] + 1)
        out = points >= LARGE_POINTS
        for i in np.flatnonzero(out).tolist():
            rect = Rect(*(float(v) for v in rects[i]))
            out[i] = tuple(policy.candidates(grid, level, rect)) == ("grid",)
        return out

    def build(
        self,
        grid: Grid,
        rects: np.ndarray,
        max_points: int,
        window: tuple[int, int, int, int] = NO_WINDOW,
    ) -> GridPatchArrays:
        """The grid patches of ``rects`` (k, 4), as ``GridPatch.build_level_arrays`` makes
        them, from the cells: those of a patch not held yet measured whole (all such patches
        in one kernel call), the others measured again where the window reaches them."""
        k = math.isqrt(max_points)
        ranges = grid.index_ranges(rects)
        spans = np.column_stack([ranges[:, 1] - ranges[:, 0], ranges[:, 3] - ranges[:, 2]])
        steps = np.maximum(1, -(-spans // (k - 1))).astype(np.int64)
        index = np.column_stack([ranges, steps])
        n = len(rects)
        error, zmin, zmax = np.empty(n), np.empty(n), np.empty(n)
        count = np.empty(n, dtype=np.int64)
        heights = grid.heights_array("measuring grid patches")
        keys: list[Index] = [tuple(idx) for idx in index.tolist()]
        new = [key for key in dict.fromkeys(keys) if key not in self.entries]
        if new:
            read_domains(grid, np.array([key[:4] for key in new]))
            self._measure(heights, new)
        exact: list[int] = []
        for i, key in enumerate(keys):
            fresh = key in new
            e, lo, hi, c, zeros = (
                self.entries[key] if fresh else self._cells(grid, heights, key, window)
            )
            self.touched.add(key)
            error[i], count[i] = e.max(), c.sum()
            lo_v, hi_v = lo.min(), hi.max()
            if (lo_v == 0.0 or hi_v == 0.0) and np.bitwise_or.reduce(zeros, axis=None) == 3:
                # Which signed zero is the extreme depends on the scan order: the kernel's own.
                exact.append(i)
            zmin[i] = lo_v if count[i] > 0 else np.nan
            zmax[i] = hi_v if count[i] > 0 else np.nan
        if exact:
            read_domains(grid, index[exact, :4])
            ref = GridPatch.build_level_arrays(grid, rects[exact], max_points)
            zmin[exact], zmax[exact] = ref.zmin, ref.zmax
        return GridPatchArrays(
            grid, np.asarray(rects, dtype=np.float64), index, error, zmin, zmax, count
        )

    def _measure(self, heights: np.ndarray, keys: list[Index]) -> None:
        """Measure every cell of the patches ``keys`` (not held yet), in one kernel call."""
        lattices = [np.ravel(heights[np.ix_(*_lines(key))]) for key in keys]
        start = np.zeros(len(keys) + 1, dtype=np.int64)
        np.cumsum([len(a) for a in lattices], out=start[1:])
        flat = np.concatenate(lattices).astype(heights.dtype, copy=False)
        index = np.array(keys, dtype=np.int64).reshape(-1, 6)
        *figures, cell_start = grid_patch_cells_many(heights, flat, start, index)
        for i, key in enumerate(keys):
            rows, cols = _lines(key)
            shape = (len(rows) - 1, len(cols) - 1)
            a, b = int(cell_start[i]), int(cell_start[i + 1])
            self.entries[key] = tuple(f[a:b].reshape(shape) for f in figures)

    def _cells(
        self, grid: Grid, heights: np.ndarray, index: Index, window: tuple[int, int, int, int]
    ) -> tuple[np.ndarray, ...]:
        """The per-cell figures of one held patch, measured again where the window is."""
        r0, r1, c0, c1, sr, sc = index
        entry = self.entries[index]
        nbr, nbc = entry[0].shape
        # The cells owning edited points, and those around edited vertices (``_cell_span``).
        k0, k1 = _cell_span(window[0], window[1], r0, r1, sr, nbr)
        j0, j1 = _cell_span(window[2], window[3], c0, c1, sc, nbc)
        if k0 <= k1 and j0 <= j1:
            # The kernel reads the points of these cells and their corners' lattice heights.
            span = [r0 + k0 * sr, min(r1, r0 + (k1 + 1) * sr)]
            span += [c0 + j0 * sc, min(c1, c0 + (j1 + 1) * sc)]
            read_domains(grid, np.array([span]))
            lattice = np.ascontiguousarray(heights[np.ix_(*_lines(index))])
            # A few cells: one thread (waking a pool costs more than the work on a busy host).
            points = (min(r1, r0 + (k1 + 1) * sr) - r0 - k0 * sr + 1) * (
                min(c1, c0 + (j1 + 1) * sc) - c0 - j0 * sc + 1
            )
            threads = numba.get_num_threads()
            numba.set_num_threads(1 if points < SERIAL_POINTS else threads)
            try:
                part = grid_patch_cells(heights, lattice, *index, k0, k1, j0, j1)
            finally:
                numba.set_num_threads(threads)
            for whole, fresh in zip(entry, part, strict=True):
                whole[k0 : k1 + 1, j0 : j1 + 1] = fresh
        return entry

    def begin(self) -> None:
        """Start an update: nothing refreshed yet."""
        self.touched = set()

    def end(self, window: tuple[int, int, int, int]) -> None:
        """Forget the entries the window reaches that this update did not refresh."""
        w0, w1, v0, v1 = window
        for idx in list(self.entries):
            r0, r1, c0, c1 = idx[:4]
            if idx not in self.touched and r0 <= w1 and r1 >= w0 and c0 <= v1 and c1 >= v0:
                del self.entries[idx]


def _lines(index: Index) -> tuple[np.ndarray, np.ndarray]:
    """The sampled rows and columns of a grid patch (every step-th line, and its last)."""
    r0, r1, c0, c1, sr, sc = index
    return np.append(np.arange(r0, r1, sr), r1), np.append(np.arange(c0, c1, sc), c1)


def _cell_span(w0: int, w1: int, lo: int, hi: int, step: int, cells: int) -> tuple[int, int]:
    """First and last cell (of ``cells`` along one axis, lines lo..hi sampled every ``step``
    and at hi) to measure again after lines w0..w1 changed; empty (0, −1) when apart.

    The cells owning a changed line; and where a sampled line (a patch vertex) changed, the
    cells on both sides of it and one more each way (a point on a sampled line may be
    measured against the neighbouring cell's triangle, ``_lattice_edge_value``).
    """
    a, b = max(w0, lo), min(w1, hi)
    if a > b:
        return 0, -1
    first = min((a - lo) // step, cells - 1)
    last = min((b - lo) // step, cells - 1)
    # Vertex lines inside a..b: indices m (line lo + m·step, and ``cells`` for hi).
    m_first = -(-(a - lo) // step)
    m_last = cells if b == hi else min((b - lo) // step, cells - 1)
    if m_first <= m_last:
        first = min(first, m_first - 1)
        last = max(last, m_last + 1)
    return max(0, first), min(cells - 1, last)
