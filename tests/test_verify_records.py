"""Patch records of a tree over a Grid.window: saved in the full raster's indices by every
batched writer, so a store of such a tree reads back its own patches (``approxtree verify``
found them shifted by the window's offset)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_file

import approxtree as at


@pytest.mark.parametrize("policy", ["grid", "tin", "rtin", "nonregular"])
def test_a_tree_over_a_grid_window_loads_back_its_own_patches(data_dir, tmp_path, policy):
    """A tree built on Grid.window (indices offset in the raster) and saved as a store reads
    back the very same patch vertices (the batched records left the offset out)."""
    dem = at.open_terrain(str(data_file(data_dir, "nc/elev_ned_30m.tif")))
    terrain = dem.window(100, 219, 100, 259)
    tree = at.ApproximationTree.build(terrain, epsilon=1.0, max_points=289, policy=policy)
    tree.save(tmp_path / "w.zarr")
    loaded = at.load_tree(tmp_path / "w.zarr")
    for i in range(len(tree.errors)):
        np.testing.assert_array_equal(loaded.read_patch(i).vertices, tree.read_patch(i).vertices)
