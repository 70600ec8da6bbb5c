"""BinTree: the embedded right-triangle binary tree of a (2^k + 1)² grid (see kernels.bintree_rd).

Holds the heights, the mate of every node and the distortion d of every node (measured once,
O(n log n) over all levels). Splitting and merging domains are answered for the full tree.
"""

from __future__ import annotations

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.geometry.grid import Grid
from approxtree.geometry.windowed import check_whole_band
from approxtree.kernels import bintree_rd as kr


def lattice_heights(terrain: Grid | np.ndarray, size: int | None = None) -> np.ndarray:
    """The centred (size × size) window of a grid's heights, size = 2^k + 1, as float64.

    size None: the largest 2^k + 1 that fits. Raises InvalidParameterError when size is not
    2^k + 1, does not fit, or the window holds nodata.
    """
    # A windowed grid is read only in the window (below), never whole.
    h = terrain.heights if isinstance(terrain, Grid) else np.asarray(terrain, dtype=np.float64)
    if h.ndim != 2:
        raise InvalidParameterError(f"Expected a 2-D height array, got shape {h.shape}.")
    rows, cols = h.shape
    if size is None:
        size = 2
        while 2 * (size - 1) + 1 <= min(rows, cols):
            size = 2 * (size - 1) + 1
    k = (size - 1).bit_length() - 1
    if size < 3 or (1 << k) + 1 != size:
        raise InvalidParameterError(f"Expected a lattice size 2^k + 1 >= 3, got {size}.")
    if size > min(rows, cols):
        raise InvalidParameterError(
            f"A {size} × {size} window does not fit the {rows} × {cols} grid; choose a smaller "
            "size or resample the raster."
        )
    r0 = (rows - size) // 2
    c0 = (cols - size) // 2
    if isinstance(terrain, Grid) and terrain.is_windowed:
        check_whole_band((size, size), np.dtype(np.float64), "the binary tree (rd)")
    win = np.ascontiguousarray(h[r0 : r0 + size, c0 : c0 + size], dtype=np.float64)
    if not np.isfinite(win).all():
        raise InvalidParameterError(
            f"The {size} × {size} window at row {r0}, column {c0} holds nodata; the binary tree "
            "needs a complete grid: fill the holes (--nodata fill) or choose another window."
        )
    return win


class BinTree:
    """The binary tree of triangles over heights (2^k + 1, 2^k + 1).

    mate: (2^(2k+2),) int32; d: (2^(2k+2),) float64 distortion of every node; gain:
    (2^(2k+1),) float64 d(u) − d(2u) − d(2u + 1).
    """

    def __init__(self, heights: np.ndarray) -> None:
        h = np.ascontiguousarray(heights, dtype=np.float64)
        rows, cols = h.shape
        k = (rows - 1).bit_length() - 1
        if rows != cols or rows < 3 or (1 << k) + 1 != rows:
            raise InvalidParameterError(
                f"Expected a (2^k + 1) × (2^k + 1) grid, got {rows} × {cols}; crop it with "
                "lattice_heights()."
            )
        if not np.isfinite(h).all():
            raise InvalidParameterError("The grid holds nodata; fill the holes first.")
        self.heights = h
        self.k = k
        self.mate = kr.tree_mates(k)
        self.d = kr.tree_distortions(h, k)
        self.gain = kr.tree_gains(self.d, k)

    @property
    def size(self) -> int:
        """Grid points per side, 2^k + 1."""
        return self.heights.shape[0]

    @property
    def root_distortion(self) -> float:
        """Distortion of the two-triangle mesh (e_max of the SNR)."""
        return float(self.d[2] + self.d[3])

    def corners(self, u: int) -> tuple[int, int, int, int, int, int]:
        """(apex x, y, left x, y, right x, y) of node u in lattice (column, row)."""
        return kr.node_corners(int(u), self.k)

    def splitting_domain(self, u: int) -> np.ndarray:
        """Forced splits when u splits in the coarsest conforming mesh holding it as a leaf."""
        self._check(u)
        before = set(kr.split_closure(u >> 1, self.mate).tolist()) if u >= 4 else set()
        closure = kr.split_closure(u, self.mate)
        return np.array([x for x in closure if x not in before and x != u], dtype=np.int64)

    def merging_domain(self, u: int) -> np.ndarray:
        """Roots of the other subtrees that merge with u's in the full tree (u excluded)."""
        self._check(u)
        alive = np.zeros(1 << (2 * self.k + 2), dtype=np.bool_)
        alive[1 : 1 << (2 * self.k + 1)] = True
        mark = np.zeros(len(alive), dtype=np.int64)
        roots, n = kr.merge_roots(u, self.mate, alive, mark, 1, np.empty(64, dtype=np.int64))
        return np.array([r for r in roots[:n] if r != u], dtype=np.int64)

    def _check(self, u: int) -> None:
        if not 2 <= u < 1 << (2 * self.k + 1):
            raise InvalidParameterError(
                f"Node {u} is not a splittable triangle of this tree (2 <= u < "
                f"{1 << (2 * self.k + 1)})."
            )
