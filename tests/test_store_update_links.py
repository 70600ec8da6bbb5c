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


def overview_of(store: Path) -> tuple[np.ndarray, dict[str, int]]:
    """The store's terrain overview and the inode of each of its chunk files, by chunk key."""
    import zarr

    values = np.asarray(zarr.open_array(store / "terrain" / "overview", mode="r")[...])
    root = store / "terrain" / "overview" / "c"
    inodes = {str(p.relative_to(root)): os.stat(p).st_ino for p in root.rglob("*") if p.is_file()}
    return values, inodes


def test_unchanged_overview_chunks_are_links_and_overview_equals_fresh_build(
    tmp_path, monkeypatch
) -> None:
    """The heights' overview (every 3rd line of a 3000 × 1100 terrain: 2 × 1 chunks) keeps the
    inodes of the chunks an update misses, and equals a fresh build's overview, whether the
    window crosses an overview line or not."""
    monkeypatch.setattr("approxtree.geometry.grid.OVERVIEW_SIDE", 1000)
    grid = fractal_terrain(3000, 1100, seed=6)
    # North-up: the overview's rows are 2999, 2996, ... (row r at (2999 − r) / 3).
    assert grid.overview_steps() == (-3, 3)
    store = tmp_path / "t.zarr"
    ApproximationTree.build(grid, **PARAMS).save(store)
    t = grid.transform
    edited = np.array(grid.heights)
    # A 40 × 40 window (overview rows 520..533: chunk 1/0), then 2 × 2 cells on no overview row.
    for r0, c0, side, expect in ((1400, 100, 40, {"1/0"}), (1401, 101, 2, set())):
        _, before = overview_of(store)
        patch = np.array(edited[r0 : r0 + side, c0 : c0 + side]) - 30.0
        edited[r0 : r0 + side, c0 : c0 + side] = patch
        update_store(store, Grid(patch, t, grid.crs, index_offset=(r0, c0), allow_empty=True))
        values, after = overview_of(store)
        assert after.keys() == before.keys() and len(after) == 2
        assert {key for key in after if after[key] != before[key]} == expect
        fresh = tmp_path / f"fresh{side}.zarr"
        ApproximationTree.build(Grid(np.array(edited), t, grid.crs), **PARAMS).save(fresh)
        np.testing.assert_array_equal(values, overview_of(fresh)[0])
