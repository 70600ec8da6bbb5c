"""Per-cell figures of large grid patches: made by the build, saved in the store, read by a
store update, checked by verify; a store without them still updates to the fresh build."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from test_update_store import same_store

from approxtree.cli import main
from approxtree.datasets import fractal_terrain
from approxtree.errors import StoreError
from approxtree.geometry.grid import Grid
from approxtree.tree import update_cells
from approxtree.tree.approximation_tree import ApproximationTree
from approxtree.tree.store_update import update_store
from approxtree.tree.tree_store import TreeStoreSource
from approxtree.tree.zarr_store import StoreReader

PARAMS = {"epsilon": 5.0, "max_points": 9 * 9}


@pytest.fixture
def small_large(monkeypatch) -> None:
    """Patches of 400 points and more count as large (measured per cell) on small terrains;
    the build measures those of 4000 points and more, an update the others when it reaches
    them."""
    monkeypatch.setattr(update_cells, "LARGE_POINTS", 400)
    monkeypatch.setattr(update_cells, "BUILD_POINTS", 4000)


def stored_cells(store: Path) -> dict:
    """The store's per-cell figures by patch index ({} when it has none)."""
    return TreeStoreSource(StoreReader(store)).cell_entries() or {}


def edit(grid: Grid, r0: int, c0: int, rows: int, cols: int) -> tuple[Grid, np.ndarray]:
    """A pit with a hole of no data as a patch grid, and the edited terrain's heights."""
    pit = np.array(grid.heights[r0 : r0 + rows, c0 : c0 + cols], dtype=np.float64) - 40.0
    pit[:2, :3] = np.nan
    edited = np.array(grid.heights, dtype=np.float64)
    edited[r0 : r0 + rows, c0 : c0 + cols] = pit
    patch = Grid(pit, grid.transform, grid.crs, index_offset=(r0, c0), allow_empty=True)
    return patch, edited


def fresh_store(tmp_path: Path, grid: Grid, heights: np.ndarray) -> Path:
    path = tmp_path / "fresh.zarr"
    ApproximationTree.build(Grid(heights, grid.transform, grid.crs), **PARAMS).save(path)
    return path


def same_cells(updated: dict, fresh: dict, every: bool = True) -> None:
    """The patches of both stores have the same cells, bit for bit; every: each patch of the
    fresh store has its cells in the updated one."""
    common = set(fresh) & set(updated)
    assert common
    if every:
        assert set(fresh) <= set(updated)
    for key in common:
        for a, b in zip(updated[key], fresh[key], strict=True):
            assert a.tobytes() == b.tobytes(), key


@pytest.mark.parametrize("nodata", [False, True])
def test_build_with_cells_equals_build_without(monkeypatch, nodata: bool) -> None:
    """Large patches measured per cell give the build kernel's tree, errors bit for bit."""
    grid = fractal_terrain(301, 277, seed=3)
    if nodata:
        grid.heights[40:90, 100:160] = np.nan
        grid.heights[200:203, :] = 0.0
        grid.heights[201, ::2] = -0.0
    plain = ApproximationTree.build(grid, **PARAMS)
    assert "_cell_cache" not in plain.__dict__
    monkeypatch.setattr(update_cells, "LARGE_POINTS", 400)
    monkeypatch.setattr(update_cells, "BUILD_POINTS", 400)
    cells = ApproximationTree.build(grid, **PARAMS)
    assert cells.__dict__["_cell_cache"].entries
    assert cells.errors.tobytes() == plain.errors.tobytes()
    assert cells.bboxes.tobytes() == plain.bboxes.tobytes()
    np.testing.assert_array_equal(cells.child_count, plain.child_count)


def test_store_update_reads_cells_and_equals_fresh_build(tmp_path, small_large) -> None:
    """A built store holds the cells; two store updates read and rewrite them, and the store
    equals a fresh build's, cells included; ``approxtree verify`` checks them."""
    grid = fractal_terrain(300, 280, seed=4)
    store = tmp_path / "t.zarr"
    ApproximationTree.build(grid, **PARAMS).save(store)
    assert stored_cells(store)
    for r0, c0 in ((120, 100), (10, 230)):
        patch, edited = edit(grid, r0, c0, 30, 25)
        update_store(store, patch)
        grid = Grid(edited, grid.transform, grid.crs)
        fresh = fresh_store(tmp_path, grid, edited)
        same_store(store, fresh)
        same_cells(stored_cells(store), stored_cells(fresh))
    result = CliRunner().invoke(main, ["verify", str(store)])
    assert result.exit_code == 0, result.output
    assert "cells" in result.output


def test_store_without_cells_updates_to_fresh_build(tmp_path, small_large) -> None:
    """A store written without cells (an older store) updates to the fresh build's tree, and
    the new store holds the cells its update measured."""
    grid = fractal_terrain(300, 280, seed=5)
    tree = ApproximationTree.build(grid, **PARAMS)
    tree.__dict__.pop("_cell_cache")
    store = tmp_path / "t.zarr"
    tree.save(store)
    assert not StoreReader(store).has("cells")
    patch, edited = edit(grid, 150, 60, 20, 40)
    update_store(store, patch)
    fresh = fresh_store(tmp_path, grid, edited)
    same_store(store, fresh)
    same_cells(stored_cells(store), stored_cells(fresh), every=False)


def test_cells_that_disagree_fail_load_and_verify(tmp_path, small_large) -> None:
    """A stored cell error raised above its patch's error fails a verified load and verify."""
    grid = fractal_terrain(200, 210, seed=6)
    tree = ApproximationTree.build(grid, **PARAMS)
    root = next(iter(tree.__dict__["_cell_cache"].entries.values()))
    root[0][0, 0] = root[0].max() + 1.0
    store = tmp_path / "t.zarr"
    tree.save(store)
    with pytest.raises(StoreError, match="per-cell"):
        ApproximationTree.load(store)
    result = CliRunner().invoke(main, ["verify", str(store)])
    assert result.exit_code == 1
    assert "FAIL cells" in result.output
