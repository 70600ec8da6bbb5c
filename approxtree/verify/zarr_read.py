"""Reading a tree store with zarr alone (not the store's own reader, which verify checks).

``StoreFiles``: the store's zarr group and the keys actually on disk (a folder's files, a
zip's entries), so that a missing chunk, which zarr reads silently as the fill value, is found
by comparing the keys with each array's chunk grid (``expected_chunk_keys``).
``ChunkReader``: rows of an array gathered through a small cache of decoded chunks, so that a
batch of scattered rows (patch records, lattice heights) decodes each chunk once.
"""

from __future__ import annotations

import itertools
import os
import zipfile
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import StoreError

#: Decoded chunks a ChunkReader keeps (bytes).
CACHE_BYTES = 64 << 20


class StoreFiles:
    """A zarr v3 store (folder or zip) opened read-only, with the keys on disk."""

    def __init__(self, path: str | os.PathLike) -> None:
        import zarr
        from zarr.abc.store import Store
        from zarr.storage import LocalStore, ZipStore

        self.path = Path(path)
        self.store: Store
        try:
            if self.path.is_dir():
                self.store = LocalStore(str(self.path), read_only=True)
                self.keys = {
                    (Path(d) / f).relative_to(self.path).as_posix()
                    for d, _, files in os.walk(self.path)
                    for f in files
                }
            else:
                with zipfile.ZipFile(self.path) as z:
                    self.keys = {n for n in z.namelist() if not n.endswith("/")}
                self.store = ZipStore(str(self.path), mode="r")
            self.root = zarr.open_group(self.store, mode="r")
            #: The root's attributes as stored (JSON: checked, never trusted).
            self.attrs: dict[str, Any] = dict(self.root.attrs)
        except Exception as exc:  # zarr and zipfile raise many kinds
            raise StoreError(f"Cannot read {self.path} as a zarr store: {exc}.") from exc

    def members(self) -> dict[str, Any]:
        """Every group and array below the root by path (a damaged zarr.json is left out)."""
        try:
            return dict(self.root.members(max_depth=None))
        except Exception:
            return self._members_one_by_one()

    def _members_one_by_one(self) -> dict[str, Any]:
        out = {}
        for key in sorted(self.keys):
            if key.endswith("/zarr.json"):
                path = key[: -len("/zarr.json")]
                try:
                    out[path] = self.root[path]
                except Exception:
                    continue
        return out

    def close(self) -> None:
        try:
            self.store.close()
        except Exception:
            pass


def read_whole(root: Any, path: str) -> np.ndarray:
    """The whole array at ``path`` below the zarr group ``root``; StoreError for a group."""
    import zarr

    node = root[path]
    if not isinstance(node, zarr.Array):
        raise StoreError(f"{path} is a group, not an array.")
    return np.asarray(node[...])


def expected_chunk_keys(path: str, array: Any) -> list[tuple[str, tuple[int, ...]]]:
    """(key, chunk coordinates) of every chunk of ``array`` (at ``path``) its chunk grid holds."""
    grid = tuple(int(n) for n in array.cdata_shape)
    encode = array.metadata.encode_chunk_key
    return [(f"{path}/{encode(c)}", c) for c in itertools.product(*(range(n) for n in grid))]


def chunk_selection(array: Any, coords: tuple[int, ...]) -> tuple[slice, ...]:
    """The selection of one chunk of ``array``."""
    return tuple(
        slice(c * s, min((c + 1) * s, n))
        for c, s, n in zip(coords, array.chunks, array.shape, strict=True)
    )


class ChunkReader:
    """Rows (axis 0) of a zarr array, gathered through a cache of decoded chunks."""

    def __init__(self, array: Any) -> None:
        self.array = array
        self.rows = int(array.chunks[0]) if array.ndim else 1
        self._cache: OrderedDict[tuple[int, ...], np.ndarray] = OrderedDict()
        self._bytes = 0

    def _chunk(self, key: tuple[int, ...]) -> np.ndarray:
        got = self._cache.get(key)
        if got is not None:
            self._cache.move_to_end(key)
            return got
        got = np.asarray(self.array[chunk_selection(self.array, key)])
        self._cache[key] = got
        self._bytes += got.nbytes
        while self._bytes > CACHE_BYTES and len(self._cache) > 1:
            _, old = self._cache.popitem(last=False)
            self._bytes -= old.nbytes
        return got

    def take(self, index: np.ndarray) -> np.ndarray:
        """array[index] for an (m,) int64 index of axis 0 (rows of a 1-D or row-chunked
        array)."""
        index = np.asarray(index, dtype=np.int64)
        tail = tuple(self.array.shape[1:])
        out = np.empty((len(index), *tail), dtype=self.array.dtype)
        if not len(index):
            return out
        chunk = index // self.rows
        for c in np.unique(chunk).tolist():
            at = np.flatnonzero(chunk == c)
            block = self._chunk((c, *([0] * len(tail))))
            out[at] = block[index[at] - c * self.rows]
        return out

    def ranges(self, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
        """The rows of every [start, stop) range, one range after the other."""
        lengths = np.maximum(np.asarray(stops) - np.asarray(starts), 0)
        first = np.repeat(
            np.asarray(starts, dtype=np.int64) - np.r_[0, np.cumsum(lengths)[:-1]], lengths
        )
        return self.take(first + np.arange(int(lengths.sum())))

    def take2d(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """array[rows, cols] of a 2-D array for (m,) int64 rows and cols, chunk by chunk."""
        rows = np.asarray(rows, dtype=np.int64)
        cols = np.asarray(cols, dtype=np.int64)
        out = np.empty(len(rows), dtype=self.array.dtype)
        if not len(rows):
            return out
        cr, cc = int(self.array.chunks[0]), int(self.array.chunks[1])
        key = (rows // cr) * (1 << 32) + cols // cc
        order = np.argsort(key, kind="stable")
        cuts = np.flatnonzero(np.r_[True, key[order][1:] != key[order][:-1], True])
        for a, b in itertools.pairwise(cuts.tolist()):
            at = order[a:b]
            i, j = int(rows[at[0]] // cr), int(cols[at[0]] // cc)
            block = self._chunk((i, j))
            out[at] = block[rows[at] - i * cr, cols[at] - j * cc]
        return out
