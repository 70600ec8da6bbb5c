"""``approxtree update STORE PATCH.tif``: the store equals a fresh build's, and survives a kill."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from click.testing import CliRunner
from conftest import data_file

from approxtree.cli import main
from approxtree.geometry.grid import Grid
from approxtree.io import read_grid
from approxtree.tree.approximation_tree import ApproximationTree

PARAMS = {"epsilon": 1.0, "max_points": 17 * 17}


def write_patch(path: Path, grid: Grid, r0: int, c0: int, heights: np.ndarray, crs=None) -> None:
    """A GeoTIFF of ``heights`` on the grid's cells from row r0, column c0 (NaN: nodata)."""
    transform = grid.transform @ Affine.translation(c0, r0)
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=heights.shape[1],
        height=heights.shape[0],
        count=1,
        dtype="float32",
        crs=crs if crs is not None else grid.crs,
        transform=transform,
        nodata=-9999.0,
    ) as ds:
        ds.write(np.where(np.isnan(heights), -9999.0, heights).astype("float32"), 1)


def same_store(a: Path, b: Path) -> None:
    """Two stores hold the same tree: node arrays, terrain and every patch's mesh."""
    ta, tb = ApproximationTree.load(a), ApproximationTree.load(b)
    for name in ("rects", "errors", "bboxes", "levels", "parents", "child_start", "child_count"):
        assert getattr(ta, name).tobytes() == getattr(tb, name).tobytes(), name
    np.testing.assert_array_equal(
        ta.terrain.heights_array("test"), tb.terrain.heights_array("test")
    )
    for i in range(0, len(ta), max(1, len(ta) // 40)):
        np.testing.assert_array_equal(ta.patch(i).vertices, tb.patch(i).vertices)


@pytest.fixture
def dem(data_dir, tmp_path):
    """The NC DEM, its tree saved as a store, and a pit-and-hole patch written as GeoTIFF."""
    grid = read_grid(data_file(data_dir, "nc/elev_ned_30m.tif"))
    store = tmp_path / "dem.zarr"
    ApproximationTree.build(grid, **PARAMS).save(store)
    r0, c0 = 100, 150
    pit = np.array(grid.heights[r0 : r0 + 60, c0 : c0 + 80], dtype=np.float64) - 25.0
    pit[:5, :7] = np.nan
    patch = tmp_path / "pit.tif"
    write_patch(patch, grid, r0, c0, pit)
    edited = np.array(grid.heights)
    edited[r0 : r0 + 60, c0 : c0 + 80] = pit
    expected = tmp_path / "expected.zarr"
    fresh = Grid(edited, grid.transform, grid.crs, grid.nodata)
    ApproximationTree.build(fresh, **PARAMS).save(expected)
    before = tmp_path / "before.zarr"
    ApproximationTree.build(grid, **PARAMS).save(before)
    return store, patch, expected, before, grid


def test_cli_update_equals_fresh_build(dem) -> None:
    """The updated store holds the tree a fresh build of the edited DEM saves."""
    store, patch, expected, _, _ = dem
    result = CliRunner().invoke(main, ["update", str(store), str(patch), "--json"])
    assert result.exit_code == 0, result.output
    figures = json.loads(result.output)
    assert figures["window"] == {"row": 100, "col": 150, "rows": 60, "cols": 80}
    assert 0 < figures["rebuilt"] < figures["nodes_after"]
    same_store(store, expected)


def test_misaligned_or_foreign_patch_is_one_error_line(dem, tmp_path) -> None:
    """A patch off the cell edges, or in another CRS, is one Error: line with exit code 2."""
    store, _, _, before, grid = dem
    shifted = tmp_path / "shifted.tif"
    write_patch(shifted, grid, 10, 10, np.zeros((4, 4)))
    with rasterio.open(shifted, "r+") as ds:
        ds.transform = ds.transform @ Affine.translation(0.5, 0)
    foreign = tmp_path / "foreign.tif"
    write_patch(foreign, grid, 10, 10, np.zeros((4, 4)), crs="EPSG:4326")
    for path in (shifted, foreign):
        result = CliRunner().invoke(main, ["update", str(store), str(path)])
        assert result.exit_code == 2
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("Error:"), result.output
    same_store(store, before)


KILL_MID_WRITE = """
import os, signal, sys
from approxtree.tree import tree_store
calls = [0]
original = tree_store.write_array
def write_array(*args, **kwargs):
    calls[0] += 1
    if calls[0] == 3:
        os.kill(os.getpid(), signal.SIGKILL)
    return original(*args, **kwargs)
tree_store.write_array = write_array
from approxtree.cli import main
main(sys.argv[1:])
"""


@pytest.mark.parametrize("stage", ["updated", "mid-write", "saved"])
def test_killed_update_leaves_old_or_new_store(dem, stage: str) -> None:
    """SIGKILL before, in the middle of, or after the write leaves a store that opens and
    holds the old tree (or the new one once the swap is done)."""
    store, patch, expected, before, _ = dem
    env = dict(os.environ, APPROXTREE_UPDATE_KILL=stage)
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    code = KILL_MID_WRITE if stage == "mid-write" else "from approxtree.cli import main; main()"
    proc = subprocess.run(
        [sys.executable, "-c", code, "update", str(store), str(patch)],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    same_store(store, expected if stage == "saved" else before)
    # The next update finishes the job (and removes the killed writer's temp folder).
    result = CliRunner().invoke(main, ["update", str(store), str(patch)])
    assert result.exit_code == 0, result.output
    same_store(store, expected)
    assert not [p for p in store.parent.iterdir() if p.name.startswith(".dem.zarr.")]
