"""A store update writes only the height chunks the window reaches; the others are hard links."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from test_update_store import same_store

from approxtree.datasets import fractal_terrain
from approxtree.geometry.grid import Grid
from approxtree.tree.approximation_tree import ApproximationTree
from approxtree.tree.store_update import update_store

PARAMS = {"epsilon": 5.0, "max_points": 33 * 33}


def chunk_inodes(store: Path) -> dict[str, int]:
    """Inode of every chunk file of the store's terrain heights, by chunk key."""
    root = store / "terrain" / "heights" / "c"
    return {str(p.relative_to(root)): os.stat(p).st_ino for p in root.rglob("*") if p.is_file()}


def test_unchanged_height_chunks_are_links_and_store_equals_fresh_build(tmp_path) -> None:
    """After an update of a 40 × 40 window across a chunk corner of a 1300 × 1100 terrain, the
    4 chunks it meets are new files, the other 5 keep their inodes, and the store holds the
    tree a fresh build of the edited terrain saves."""
    grid = fractal_terrain(1300, 1100, seed=5)
    store = tmp_path / "t.zarr"
    ApproximationTree.build(grid, **PARAMS).save(store)
    before = chunk_inodes(store)
    r0, c0 = 500, 490
    patch = np.array(grid.heights[r0 : r0 + 40, c0 : c0 + 40]) - 30.0
    patch[:3, :3] = np.nan
    t = grid.transform
    window = Grid(patch, t, grid.crs, index_offset=(r0, c0), allow_empty=True)
    update_store(store, window)
    after = chunk_inodes(store)
    assert after.keys() == before.keys() and len(after) == 9
    changed = {key for key in after if after[key] != before[key]}
    assert changed == {"0/0", "0/1", "1/0", "1/1"}
    edited = np.array(grid.heights)
    edited[r0 : r0 + 40, c0 : c0 + 40] = patch
    fresh = tmp_path / "fresh.zarr"
    ApproximationTree.build(Grid(edited, t, grid.crs, allow_empty=True), **PARAMS).save(fresh)
    same_store(store, fresh)
