"""One compiled signature per kernel: a tree opened from a file reuses the built tree's code.

numba types an array by dtype, layout and read-only flag. A tree loaded from a legacy .atree
(memory-mapped, read-only) or a store, or a grid with read-only heights, must reach the hot
kernels with the same types as a freshly built tree: otherwise the first frame of an opened
tree compiles every kernel a second time on the user's clock. The invariant is exact: after
the in-memory pass, the opened-tree pass adds no signature to any kernel already compiled.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
from atree_writer import write_atree
from numba.core.dispatcher import Dispatcher

from approxtree import ApproximationTree, Grid, load_tree
from approxtree.datasets import fractal_terrain
from approxtree.patches.approximate import approximate
from approxtree.render import display_scale, overview_camera, select
from approxtree.render.frame_state import FrameState
from approxtree.render.skirts import skirt_depths
from approxtree.render.texture_sharing import texture_nodes


def _signatures() -> dict[str, int]:
    """Number of compiled signatures of every approxtree kernel imported so far."""
    counts = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("approxtree") or module is None:
            continue
        for attr, obj in vars(module).items():
            # Each kernel once, under the module that defines it.
            if isinstance(obj, Dispatcher) and obj.py_func.__module__ == name:
                counts[f"{name}.{attr}"] = len(obj.signatures)
    return counts


def _frame_work(tree) -> list[np.ndarray]:
    """What a frame of the renderer computes on the CPU: selection, texture sharing, skirt
    depths, and the meshes of the selected patches. Returns the arrays, for comparison."""
    fs = FrameState.from_camera(
        overview_camera(tree.bboxes[0], display_scale(tree.terrain)),
        (800, 600),
        tree.bboxes[0],
        tree.origin,
        display_scale(tree.terrain),
    )
    sel = select(tree, fs, alpha=0.5, gamma=2.0)
    shared, _ = texture_nodes(tree.parents, sel, 2.0)
    rects = tree.bboxes[:, [0, 1, 3, 4]]
    depths = skirt_depths(tree.errors, tree.terrain.z_range, None, rects)
    meshes = [tree.patch(int(i)).vertices for i in sel.nodes[:8]]
    return [sel.nodes, sel.alphas, shared, depths, *meshes]


def _assert_no_new_signature(before: dict[str, int], after: dict[str, int]) -> None:
    grown = {k: (before[k], n) for k, n in after.items() if k in before and n > before[k]}
    assert not grown, f"kernels compiled again for the opened tree (before, after): {grown}"


@pytest.mark.parametrize("suffix", [".atree", ".zarr"])
def test_opened_tree_compiles_nothing_new(tmp_path, suffix):
    """Selection, texture sharing, skirts and patch meshes of a tree opened from a file
    (memory-mapped .atree or zarr store: read-only arrays) run the built tree's signatures,
    and give the same arrays."""
    terrain = fractal_terrain(129, seed=3)
    tree = ApproximationTree.build(terrain, epsilon=1.0, max_points=289)
    built = _frame_work(tree)
    before = _signatures()
    path = tmp_path / f"t{suffix}"
    if suffix == ".atree":
        # From the tests' writer: approxtree reads that format, it no longer writes it.
        write_atree(tree, path)
    else:
        tree.save(path)
    opened = load_tree(path)
    got = _frame_work(opened)
    _assert_no_new_signature(before, _signatures())
    for a, b in zip(built, got, strict=True):
        np.testing.assert_array_equal(a, b)


def test_read_only_heights_mesh_without_new_signature():
    """``approxtree mesh`` on read-only (e.g. memory-mapped) heights reuses the TIN and grid
    kernels compiled for writable heights, with the same mesh."""
    terrain = fractal_terrain(97, seed=5)
    heights = terrain.heights.copy()
    heights.flags.writeable = False
    frozen = Grid(heights, transform=terrain.transform, crs=terrain.crs)
    assert not frozen.heights.flags.writeable
    meshes = {}
    for strategy in ("tin", "grid"):
        meshes[strategy] = approximate(terrain, strategy, max_error=2.0)
    before = _signatures()
    for strategy in ("tin", "grid"):
        got = approximate(frozen, strategy, max_error=2.0)
        np.testing.assert_array_equal(got.vertices, meshes[strategy].vertices)
        np.testing.assert_array_equal(got.triangles, meshes[strategy].triangles)
    _assert_no_new_signature(before, _signatures())


def test_readonly_helper_is_a_view():
    """readonly() copies only for another dtype or layout, and never changes its argument."""
    from approxtree.kernels._jit import readonly

    a = np.arange(12.0).reshape(3, 4)
    v = readonly(a)
    assert np.shares_memory(a, v) and not v.flags.writeable and a.flags.writeable
    assert readonly(v) is v
    f = readonly(np.asfortranarray(a))
    assert f.flags.c_contiguous and not f.flags.writeable
    assert readonly(a, np.float32).dtype == np.float32
