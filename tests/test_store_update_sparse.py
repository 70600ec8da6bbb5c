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


def test_equal_chunks_are_links_to_the_old_arrays_files(tmp_path) -> None:
    """An array written again with one row changed and rows appended links exactly its full
    chunks whose bytes are the old ones; it reads back as the new values."""
    import zarr
    from zarr.storage import LocalStore

    from approxtree.tree.zarr_store import CHUNK_BYTES, EqualChunks, write_array

    rows = CHUNK_BYTES // 8
    old_values = np.arange(4 * rows + 10, dtype=np.float64)
    new_values = np.concatenate([old_values, np.arange(7.0)])
    new_values[rows + 3] = -1.0
    old_root = zarr.open_group(LocalStore(str(tmp_path / "old")), mode="w")
    write_array(old_root, "a", old_values)
    new_root = zarr.open_group(LocalStore(str(tmp_path / "new")), mode="w")
    reuse = EqualChunks(tmp_path / "old" / "a")
    write_array(new_root, "a", new_values, reuse=reuse)
    old, new = inodes(tmp_path / "old" / "a"), inodes(tmp_path / "new" / "a")
    # Chunks 0, 2, 3 are equal; 1 has the changed row; 4 is longer now.
    assert {k for k in new if new[k] == old.get(k)} == {"0", "2", "3"}
    assert reuse.linked == 3
    np.testing.assert_array_equal(np.asarray(new_root["a"][...]), new_values)


def inodes(folder: Path) -> dict[str, int]:
    """Inode of every chunk file under an array folder, by chunk key."""
    root = folder / "c"
    return {str(p.relative_to(root)): os.stat(p).st_ino for p in root.rglob("*") if p.is_file()}


def test_update_reads_few_chunks_links_the_rest_and_equals_fresh_build(
    tmp_path, monkeypatch
) -> None:
    """Of two updates of small windows in one quadrant of a 2600 × 2100 terrain (30 height
    chunks), the second (the large patches above it hold their per-cell figures since the
    first) reads at most a third of the chunks; both leave the tree a fresh build of the
    edited terrain makes, which verify accepts."""
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
    for r0, c0, side in ((1300, 700, 40), (1500, 300, 24)):
        patch = np.array(edited[r0 : r0 + side, c0 : c0 + side]) - 30.0
        patch[:2, :2] = np.nan
        edited[r0 : r0 + side, c0 : c0 + side] = patch
        window = Grid(patch, t, grid.crs, index_offset=(r0, c0), allow_empty=True)
        store_update.update_store(store, window)
        assert len(bands) == 1 or bands[-1].chunks_read <= bands[-1].loaded.size // 3
        fresh = tmp_path / f"fresh{side}.zarr"
        ApproximationTree.build(Grid(np.array(edited), t, grid.crs), **PARAMS).save(fresh)
        same_store(store, fresh)
    report = at.verify(store, Grid(np.array(edited), t, grid.crs))
    assert report.ok, {c.name: c.offenders for c in report.checks.values() if not c.ok}
