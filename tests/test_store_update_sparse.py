"""A store update reads only the height chunks it needs and links every unchanged chunk."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from test_update_store import same_store

import approxtree as at
from approxtree.datasets import fractal_terrain
from approxtree.geometry.grid import Grid
from approxtree.tree import store_update
from approxtree.tree.approximation_tree import ApproximationTree
from approxtree.tree.update_band import SparseBand

PARAMS = {"epsilon": 5.0, "max_points": 33 * 33}


def inodes(folder: Path) -> dict[str, int]:
    """Inode of every chunk file under an array folder, by chunk key."""
    root = folder / "c"
    return {str(p.relative_to(root)): os.stat(p).st_ino for p in root.rglob("*") if p.is_file()}


def test_update_reads_few_chunks_links_the_rest_and_equals_fresh_build(
    tmp_path, monkeypatch
) -> None:
    """Two updates of small windows of a 2600 × 2100 terrain (30 height chunks) read at most
    a third of its chunks, keep the inodes of the node and patch chunks they leave equal, and
    leave the tree a fresh build of the edited terrain makes, which verify accepts."""
    grid = fractal_terrain(2600, 2100, seed=7)
    store = tmp_path / "t.zarr"
    ApproximationTree.build(grid, **PARAMS).save(store)
    bands: list[SparseBand] = []
    made = store_update.SparseBand

    def spy(source: object) -> SparseBand:
        bands.append(made(source))  # type: ignore[arg-type]
        return bands[-1]

    monkeypatch.setattr(store_update, "SparseBand", spy)
    t = grid.transform
    edited = np.array(grid.heights)
    for r0, c0, side in ((1300, 700, 40), (90, 1900, 24)):
        before = {name: inodes(store / "nodes" / name) for name in ("levels", "rects")}
        patch = np.array(edited[r0 : r0 + side, c0 : c0 + side]) - 30.0
        patch[:2, :2] = np.nan
        edited[r0 : r0 + side, c0 : c0 + side] = patch
        window = Grid(patch, t, grid.crs, index_offset=(r0, c0), allow_empty=True)
        store_update.update_store(store, window)
        assert bands and bands[-1].chunks_read <= bands[-1].loaded.size // 3
        # Node arrays keep their chunk files where the update left their bytes equal.
        after = {name: inodes(store / "nodes" / name) for name in ("levels", "rects")}
        shared = sum(after[n].get(k) == v for n in before for k, v in before[n].items())
        assert shared > 0
        fresh = tmp_path / f"fresh{side}.zarr"
        ApproximationTree.build(Grid(np.array(edited), t, grid.crs), **PARAMS).save(fresh)
        same_store(store, fresh)
    report = at.verify(store, Grid(np.array(edited), t, grid.crs))
    assert report.ok, {c.name: c.offenders for c in report.checks.values() if not c.ok}
