"""A store's terrain band held in memory only where an update reads it.

A store update (``store_update``) edits a window of a terrain it does not read whole: its
grid's band is an ordinary (rows, cols) numpy array (the kernels need one) allocated but left
unread, with the store's chunks read into it on demand (``SparseBand.read``) — the window's,
the domains of the nodes being rebuilt, the cells around the window of the large patches
(``update_cells``). Code of the update that reads a domain of the grid first
calls ``read_domains(grid, ranges)``, which does nothing for a grid held whole; anything it
did not announce holds no defined value, so the update's result is compared with fresh builds
by the tests (tests/test_store_update*.py).
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Protocol

import numpy as np


class BandSource(Protocol):
    """What SparseBand reads from (``zarr_store.ZarrHeightSource``)."""

    shape: tuple[int, int]
    dtype: np.dtype
    block_shape: tuple[int, int]

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray: ...


class SparseBand:
    """A (rows, cols) band whose source chunks are read once each, when first needed.

    band: the (rows, cols) array (source dtype); only the chunks read (``loaded``, one flag
    per source chunk) hold the terrain's heights.
    """

    def __init__(self, source: BandSource) -> None:
        self.source = source
        rows, cols = source.shape
        # np.empty maps pages lazily: the chunks never read cost no memory traffic.
        self.band = np.empty((rows, cols), dtype=source.dtype)
        self.chunk = (int(source.block_shape[0]), int(source.block_shape[1]))
        h, w = self.chunk
        self.loaded = np.zeros((-(-rows // h), -(-cols // w)), dtype=bool)
        self._lock = threading.Lock()
        #: Chunks read so far (a figure for benchmarks).
        self.chunks_read = 0

    def read(self, ranges: np.ndarray) -> None:
        """Read the chunks of the (k, 4) int inclusive (r0, r1, c0, c1) index ranges that are
        not read yet (each a run of chunks along a row read with one call, runs in parallel)."""
        ranges = np.asarray(ranges, dtype=np.int64).reshape(-1, 4)
        if not len(ranges):
            return
        h, w = self.chunk
        want = np.zeros_like(self.loaded)
        for r0, r1, c0, c1 in ranges.tolist():
            if r1 >= r0 and c1 >= c0:
                want[r0 // h : r1 // h + 1, c0 // w : c1 // w + 1] = True
        with self._lock:
            want &= ~self.loaded
            if not want.any():
                return
            runs = _runs(want)
            threads = max(1, min(os.cpu_count() or 1, len(runs)))
            if threads == 1:
                for run in runs:
                    self._read_run(*run)
            else:
                with ThreadPoolExecutor(threads, thread_name_prefix="band-read") as pool:
                    list(pool.map(lambda run: self._read_run(*run), runs))
            self.loaded |= want
            self.chunks_read += int(want.sum())

    def _read_run(self, i: int, j0: int, j1: int) -> None:
        """Chunks j0..j1 of chunk row i, in one read."""
        h, w = self.chunk
        rows, cols = self.band.shape
        r0, r1 = i * h, min(rows, (i + 1) * h)
        c0, c1 = j0 * w, min(cols, (j1 + 1) * w)
        self.band[r0:r1, c0:c1] = self.source.read(r0, r1, c0, c1)

    def read_all(self) -> None:
        """Every chunk (a question only the whole band answers)."""
        rows, cols = self.band.shape
        self.read(np.array([[0, rows - 1, 0, cols - 1]]))


def _runs(want: np.ndarray) -> list[tuple[int, int, int]]:
    """(chunk row, first, last) of each run of wanted chunks along a chunk row."""
    out: list[tuple[int, int, int]] = []
    for i in np.flatnonzero(want.any(axis=1)).tolist():
        js = np.flatnonzero(want[i])
        breaks = np.flatnonzero(np.diff(js) > 1)
        starts = np.concatenate([[0], breaks + 1])
        ends = np.concatenate([breaks, [len(js) - 1]])
        out.extend((i, int(js[a]), int(js[b])) for a, b in zip(starts, ends, strict=True))
    return out


def read_domains(grid: Any, ranges: np.ndarray) -> None:
    """Before reading the grid's points in the (k, 4) inclusive index ranges: have a sparse
    band read them (nothing to do for a grid held whole)."""
    band = grid.__dict__.get("_sparse_band")
    if band is not None:
        band.read(ranges)


def read_whole(grid: Any) -> None:
    """Before a pass over the whole grid: have a sparse band read every chunk."""
    band = grid.__dict__.get("_sparse_band")
    if band is not None:
        band.read_all()


__all__ = ["SparseBand", "read_domains", "read_whole"]
