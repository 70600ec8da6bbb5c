"""Terrain heights written into a tree store by the block tasks of a build, as zarr regions.

The ``build`` command knows its store before it builds. ``height_regions(out, grid)`` opens a
scratch folder beside the target (named like the store's own temp folders, so a killed
build's leftover goes with the next write to the target) holding an empty ``terrain/heights``
array with the store's metadata. Each block task writes the height chunks it owns
(``HeightRegions.owned``: the chunks whose first row and column fall in the block's half-open
index range, so no two tasks write one chunk and every chunk is written whole, in one write)
and hands back only its lines of the overview. ``save_tree(..., regions=...)`` then moves the
chunk folder into the store's temp folder in one rename: the client neither reads nor
compresses the band. Chunk bytes depend only on their values and codecs, so the store is the
one the client's copy writes, byte for byte; it is still committed all or nothing.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.tree.zarr_store import HEIGHT_CHUNK, is_url, new_array

#: Path of the heights array, in the scratch folder as in the store.
HEIGHTS = "terrain/heights"


@dataclass
class OverviewPart:
    """A task's lines of the overview: rows (m,) and cols (p,) int64 full-raster indices on
    the overview's steps, values (m, p) the heights there."""

    rows: np.ndarray
    cols: np.ndarray
    values: np.ndarray


def _owned(lo: int, hi: int, n: int, chunk: int) -> tuple[int, int]:
    """Half-open lines of the chunks a block of inclusive lines lo..hi owns: those starting in
    [lo, hi), or in [lo, n) for the last block (neighbours share their border line)."""
    start = -(-lo // chunk) * chunk
    stop = n if hi >= n - 1 else -(-hi // chunk) * chunk
    return min(start, n), min(stop, n)


def _on_steps(lo: int, hi: int, n: int, step: int) -> np.ndarray:
    """(m,) int64 lines of [lo, hi) that ``np.arange(n)[::step]`` holds (step may be < 0)."""
    lines = np.arange(lo, hi, dtype=np.int64)
    first = 0 if step > 0 else n - 1
    return lines[(lines - first) % abs(step) == 0]


@dataclass
class HeightRegions:
    """Where block tasks write the heights (picklable: the folder by path, no data).

    folder: the scratch store; shape, dtype: the heights'; steps: the overview's (row, col)
    steps, None when the grid is its own overview. ``complete``: every block wrote its chunks
    (set by the build); ``parts``: their overview lines (client side, not pickled).
    """

    folder: str
    shape: tuple[int, int]
    dtype: str
    steps: tuple[int, int] | None
    chunk: int = HEIGHT_CHUNK
    complete: bool = False
    parts: list[OverviewPart] = field(default_factory=list, repr=False)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["parts"] = []
        return state

    def owned(self, index: tuple[int, int, int, int]) -> tuple[int, int, int, int]:
        """(R0, R1, C0, C1) half-open: the chunks block ``index`` (r0, r1, c0, c1 inclusive)
        writes; empty when no chunk starts in it."""
        r0, r1, c0, c1 = index
        rows, cols = self.shape
        return (*_owned(r0, r1, rows, self.chunk), *_owned(c0, c1, cols, self.chunk))

    def write(self, heights: Any, index: tuple[int, int, int, int]) -> OverviewPart | None:
        """Read the chunks block ``index`` owns from ``heights`` (the full raster, an array or
        a WindowedHeights), write them into the scratch store, return their overview lines
        (a task's body; None when the block owns no chunk)."""
        import zarr
        from zarr.storage import LocalStore

        r0, r1, c0, c1 = self.owned(index)
        if r0 >= r1 or c0 >= c1:
            return None
        values = np.asarray(heights[r0:r1, c0:c1])
        arr = zarr.open_array(LocalStore(self.folder), path=HEIGHTS, mode="r+")
        arr[r0:r1, c0:c1] = values
        if self.steps is None:
            return None
        rows = _on_steps(r0, r1, self.shape[0], self.steps[0])
        cols = _on_steps(c0, c1, self.shape[1], self.steps[1])
        part = values[np.ix_(rows - r0, cols - c0)] if len(rows) and len(cols) else None
        return None if part is None else OverviewPart(rows, cols, np.ascontiguousarray(part))

    def collect(self, parts: Iterable[OverviewPart | None]) -> None:
        """Keep the blocks' overview lines; every block has written its chunks."""
        self.parts = [p for p in parts if p is not None]
        self.complete = True

    def overview(self, tap: Any) -> np.ndarray:
        """The overview array of ``tap`` (``tree_store._OverviewTap``) filled from the parts."""
        for p in self.parts:
            tap.values[np.ix_(tap.row_at[p.rows], tap.col_at[p.cols])] = p.values
        return tap.values

    def move_into(self, group: Any, name: str = "heights") -> Any:
        """Create ``group/name`` as the store's heights and move the written chunks into it
        (one rename of the chunk folder; the store's temp folder is on the same disk)."""
        arr = new_array(group, name, self.shape, np.dtype(self.dtype), (self.chunk, self.chunk))
        target = Path(group.store.root) / arr.path / "c"
        source = Path(self.folder) / HEIGHTS / "c"
        if source.is_dir():
            os.rename(source, target)
        return arr


def regions_possible(out: str | os.PathLike, grid: Any, scheduler: str | None) -> bool:
    """Whether block tasks can write the heights of ``grid`` for a store at ``out``: a windowed
    grid (tasks read their own chunks), a local folder or zip store (a URL has no temp folder
    beside it) and no remote cluster (whose workers may not see this disk)."""
    return bool(getattr(grid, "is_windowed", False)) and not is_url(out) and scheduler is None


@contextlib.contextmanager
def height_regions(out: str | os.PathLike, grid: Any) -> Iterator[HeightRegions]:
    """The HeightRegions of a scratch folder beside ``out`` holding the empty heights array of
    ``grid`` (a windowed Grid), removed at the end, whatever happens (SIGTERM included)."""
    import zarr
    from zarr.storage import LocalStore

    from approxtree.io.atomic import _registered, _sigterm_unwinds, _temp_path
    from approxtree.tree.tree_store import _OverviewTap

    folder = _temp_path(Path(out))
    with _sigterm_unwinds(), _registered(folder):
        try:
            os.mkdir(folder)
            shape = (int(grid.shape[0]), int(grid.shape[1]))
            dtype = np.dtype(grid.heights.dtype).newbyteorder("<")
            group = zarr.open_group(LocalStore(str(folder)), mode="w").create_group("terrain")
            new_array(group, "heights", shape, dtype, (HEIGHT_CHUNK, HEIGHT_CHUNK))
            steps = _OverviewTap.steps_of(grid)
            yield HeightRegions(str(folder), shape, dtype.str, steps)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
