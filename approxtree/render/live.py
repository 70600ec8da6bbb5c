"""Live: an Engine follows a tree store and texture pyramids that another process updates.

``approxtree update STORE PATCH.tif [--textures DIR]`` swaps in a new store folder (and a
re-baked pyramid) atomically; a viewer or widget drawing the store keeps running.
``LiveFollower.poll()`` (every frame: one ``stat`` of the store's ``zarr.json`` and of each
pyramid's ``pyramid.json``) notices the swap and hands the Engine the change:

- **Tree.** The new store is loaded, and its nodes are matched to the old ones by identity:
  same level and same domain rectangle (a fresh load numbers nodes anew). A matched node keeps
  its cached payloads when none of its data points (the closed rectangle's cells, as
  ``tree.update`` counts them) lies in a changed block of cells. Changed blocks come from
  ``HeightDigests``: two 64-bit digests per BLOCK × BLOCK cells (a weighted sum of the
  heights' bits with odd weights: a single changed cell always changes both; several cells
  collide with probability 2⁻¹²⁸), taken when the tree is loaded and again from the new store,
  so the old heights need not be kept (16 bytes per 64 cells) — the store's own files are
  gone once swapped. Why not a node map written by the update: the update's old→new map is
  exact too, but it would have to live in the store (another format promise) and it names
  the nodes of the previous version only, while a viewer may have missed several updates;
  identity plus digests compares any two versions. The cost: the heights are read whole
  once per update (and at start, on a thread of their own).
- **Textures.** The re-baked pyramid is opened again; ``Engine.set_textures`` drops only the
  texture patches meeting a tile whose checksum changed (render/texture_follow.py).

Between the swap and the next poll, a background load reads the new store with the old
tree's node numbers. ``LiveFollower`` guards the source (``payload_check``): a patch read
after the store's stamp moved raises ``StoreChangedError`` and is never cached; the frame
that meets it polls and draws again (``LiveFollower.render``). A texture patch read from a
re-baked tile fails its old checksum (a StoreError), handled the same way.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import StoreError
from approxtree.geometry.grid import Grid
from approxtree.textures.pyramid import TexturePyramid

#: Side (cells) of the blocks of ``HeightDigests``.
BLOCK = 8
#: Rows of heights read at once by ``HeightDigests`` (a multiple of BLOCK).
STRIP_ROWS = 512
# Two sets of odd 64-bit weights, one per cell of a block (fixed: digests of two loads of the
# same heights are equal).
_WEIGHTS = np.random.default_rng(20291).integers(
    0, 2**63, size=(2, BLOCK * BLOCK), dtype=np.uint64
) * np.uint64(2) + np.uint64(1)


class StoreChangedError(StoreError):
    """The store was swapped while a payload was read from it (the payload is stale)."""


def stamp(path: Path) -> tuple[int, int, int] | None:
    """(inode, mtime ns, bytes) of a metadata file, or None when it is missing (mid-swap)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


class HeightDigests:
    """Digests of a grid's heights, two uint64 per BLOCK × BLOCK block of cells.

    digests: (ceil(rows / BLOCK), ceil(cols / BLOCK), 2) uint64. Read strip by strip
    (STRIP_ROWS rows), so a store's heights are never whole in memory.
    """

    def __init__(self, grid: Any) -> None:
        rows, cols = grid.height, grid.width
        self.shape = (rows, cols)
        self.transform = grid.transform
        br, bc = -(-rows // BLOCK), -(-cols // BLOCK)
        self.digests = np.empty((br, bc, 2), dtype=np.uint64)
        for r0 in range(0, rows, STRIP_ROWS):
            r1 = min(r0 + STRIP_ROWS, rows)
            z = np.asarray(grid.heights[r0:r1, :], dtype=np.float64)
            # One NaN for every no-data cell; the strip padded to whole blocks.
            padded = np.full((-(-(r1 - r0) // BLOCK) * BLOCK, bc * BLOCK), np.nan)
            padded[: r1 - r0, :cols] = np.where(np.isnan(z), np.nan, z)
            bits = padded.view(np.uint64).reshape(-1, BLOCK, bc, BLOCK)
            blocks = bits.transpose(0, 2, 1, 3).reshape(-1, bc, BLOCK * BLOCK)
            for k in range(2):
                # uint64 products and sums wrap: a weighted sum modulo 2⁶⁴.
                self.digests[r0 // BLOCK : -(-r1 // BLOCK), :, k] = (blocks * _WEIGHTS[k]).sum(
                    axis=-1, dtype=np.uint64
                )

    def changed(self, other: HeightDigests) -> np.ndarray | None:
        """(blocks rows, blocks cols) bool: blocks whose digests differ; None when the grids'
        lattices differ (everything changed)."""
        if self.shape != other.shape or not self.transform.almost_equals(other.transform):
            return None
        return (self.digests != other.digests).any(axis=-1)


def follow_map(old_tree: Any, new_tree: Any, changed: np.ndarray | None) -> np.ndarray | None:
    """(n_old,) int64 the id in ``new_tree`` of each node of ``old_tree`` with the same level
    and domain whose data points meet no ``changed`` block (``HeightDigests.changed``); −1
    elsewhere. None when ``changed`` is None (every node changed)."""
    if changed is None:
        return None
    # Node identity: level and domain rectangle (a fresh build makes them bit for bit).
    new_rects = np.asarray(new_tree.rects, dtype=np.float64).tolist()
    new_levels = np.asarray(new_tree.levels).tolist()
    new_ids = {
        (lv, *rect): j for j, (lv, rect) in enumerate(zip(new_levels, new_rects, strict=True))
    }
    old_rects = np.asarray(old_tree.rects, dtype=np.float64)
    old_levels = np.asarray(old_tree.levels).tolist()
    same = np.array(
        [
            new_ids.get((lv, *rect), -1)
            for lv, rect in zip(old_levels, old_rects.tolist(), strict=True)
        ],
        dtype=np.int64,
    )
    # Whether each node's cells (closed rectangle) meet a changed block: a summed-area table.
    r = new_tree.terrain.index_ranges(old_rects) // BLOCK
    table = np.zeros((changed.shape[0] + 1, changed.shape[1] + 1), dtype=np.int64)
    table[1:, 1:] = changed.cumsum(axis=0).cumsum(axis=1)
    hits = (
        table[r[:, 1] + 1, r[:, 3] + 1]
        - table[r[:, 0], r[:, 3] + 1]
        - table[r[:, 1] + 1, r[:, 2]]
        + table[r[:, 0], r[:, 2]]
    )
    return np.where(hits == 0, same, -1)


@dataclass
class LiveChange:
    """What one poll followed. tree: the new tree (None: unchanged); kept: (n_old,) its map
    (None: nothing kept); pyramids: the re-opened pyramid of each changed folder."""

    tree: Any = None
    kept: np.ndarray | None = None
    pyramids: dict[Path, Any] = field(default_factory=dict)

    def __bool__(self) -> bool:
        return self.tree is not None or bool(self.pyramids)


class LiveFollower:
    """Keeps ``engine`` up to date with the store at ``store`` (a folder on disk, or None)
    and the texture pyramids in ``pyramids`` (folders) that another process updates (see the
    module docstring). ``loader(path)`` loads a tree (``ApproximationTree.load``). A store
    whose tree is not an approximation tree over a Grid (the only kind ``update`` changes)
    is not followed.
    """

    def __init__(self, engine: Any, store: Any, pyramids: Any, loader: Any) -> None:
        self.engine = engine
        self.loader = loader
        # Only a tree over a regular Grid is updated (tree.update): other stores stay as read.
        updatable = type(engine.tree.terrain) is Grid and hasattr(engine.source, "replace_tree")
        self.store = None if store is None or not updatable else Path(store)
        self.pyramids = [Path(p) for p in pyramids]
        self._store_stamp = None if self.store is None else stamp(self.store / "zarr.json")
        self._pyramid_stamps = {p: stamp(p / "pyramid.json") for p in self.pyramids}
        # The first digests on a thread (the heights read whole: seconds for a large store),
        # so the first frames do not wait; a poll that needs them waits.
        self._digests: HeightDigests | None = None
        self._first: threading.Thread | None = None
        if self.store is not None:
            self._first = threading.Thread(
                target=self._first_digests, args=(engine.tree,), daemon=True
            )
            self._first.start()
        #: What the polls followed since the caller last took it (``take``).
        self.changes: list[LiveChange] = []
        if self.store is not None:
            engine.source.payload_check = self._check_store

    def _first_digests(self, tree: Any) -> None:
        """Digest the drawn tree's heights; none when the store was swapped meanwhile (then
        the next update keeps nothing) or could not be read. A store swapped between the
        drawn tree's load and this follower (its node table differs from a load now) is
        followed at the next poll, keeping nothing."""
        if self.store is None:
            return
        try:
            now = self.loader(self.store)
            same = all(
                np.array_equal(getattr(now, name), getattr(tree, name), equal_nan=True)
                for name in ("levels", "rects", "errors")
            )
            digests = HeightDigests(tree.terrain)
        except StoreError:
            return
        if not same:
            self._store_stamp = None
        elif stamp(self.store / "zarr.json") == self._store_stamp:
            self._digests = digests

    def settle(self) -> None:
        """Wait for the first digests (scripted replays and tests: the next poll is then
        the same on any machine)."""
        if self._first is not None:
            self._first.join()
            self._first = None

    def _check_store(self) -> None:
        """StoreChangedError when the store was swapped since the drawn tree was loaded."""
        if self.store is not None and stamp(self.store / "zarr.json") != self._store_stamp:
            raise StoreChangedError(f"{self.store} was updated while a patch was read.")

    def take(self) -> list[LiveChange]:
        """The changes followed since the last call (oldest first)."""
        changes, self.changes = self.changes, []
        return changes

    def poll(self) -> LiveChange:
        """Follow what changed since the last poll (the store first, then the pyramids)."""
        change = LiveChange()
        if self.store is not None:
            now = stamp(self.store / "zarr.json")
            if now is not None and now != self._store_stamp:
                self._follow_store(now, change)
        for folder in self.pyramids:
            now = stamp(folder / "pyramid.json")
            if now is not None and now != self._pyramid_stamps[folder]:
                self._follow_pyramid(folder, now, change)
        if change:
            self.changes.append(change)
        return change

    def _follow_store(self, now: tuple[int, int, int], change: LiveChange) -> None:
        """Load the new store and hand the Engine the nodes it keeps; a store swapped again
        during the load (or unreadable mid-swap) is left to the next poll."""
        if self.store is None:
            return
        self.settle()
        try:
            tree = self.loader(self.store)
            digests = HeightDigests(tree.terrain)
        except StoreError:
            return
        if stamp(self.store / "zarr.json") != now:
            return
        changed = None if self._digests is None else self._digests.changed(digests)
        kept = follow_map(self.engine.tree, tree, changed)
        self._store_stamp, self._digests = now, digests
        self.engine.replace_tree(tree, kept)
        change.tree, change.kept = tree, kept

    def _follow_pyramid(self, folder: Path, now: tuple[int, int, int], change: LiveChange) -> None:
        """Open the re-baked pyramid; the Engine drops the patches of changed tiles when it
        draws this pyramid now."""
        try:
            pyramid = TexturePyramid(folder)
        except StoreError:
            return
        if stamp(folder / "pyramid.json") != now:
            return
        self._pyramid_stamps[folder] = now
        binding = self.engine.source.binding
        if binding is not None and binding.detail is None:
            if binding.pyramid.folder.resolve() == folder.resolve():
                self.engine.set_textures(pyramid)
        change.pyramids[folder] = pyramid

    def render(self, *args: Any, **kwargs: Any) -> Any:
        """``engine.render(...)`` after a poll; a frame that met a store swapped under it
        (a StoreError) polls and draws again once."""
        self.poll()
        try:
            return self.engine.render(*args, **kwargs)
        except StoreError:
            if not self.poll():
                raise
            return self.engine.render(*args, **kwargs)


__all__ = [
    "BLOCK",
    "HeightDigests",
    "LiveChange",
    "LiveFollower",
    "StoreChangedError",
    "follow_map",
    "stamp",
]
