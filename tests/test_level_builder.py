"""The level-wise builder against a straightforward per-node reference, and the strategy table.

The reference below re-derives every node the way the builder worked before levels became
arrays: one rectangle at a time, index ranges with Python floats, one kernel call per node, the
children cut and ordered as ``subdivision`` documents. Any off-by-one in the array cuts (odd
sizes, k-d cuts of the longer side, nodata, a window with an index offset) changes a node.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import data_file

import approxtree as at
from approxtree import ApproximationTree, Grid
from approxtree.datasets import fractal_terrain
from approxtree.errors import ApproxTreeError, InvalidParameterError, UnsupportedStrategyError
from approxtree.geometry import TERRAIN_TYPES
from approxtree.kernels.grid_patch import grid_patch_errors
from approxtree.patches import STRATEGIES, patch_class
from approxtree.patches.grid import GridPatch
from approxtree.patches.refined import RefinedTINPatch
from approxtree.patches.tin import GridTINPatch
from approxtree.patches.tin_points import PointTINPatch


def _index_range(grid: Grid, box: tuple[float, float, float, float]) -> tuple[int, ...]:
    """Grid.index_range of one rectangle, in Python floats."""
    t = grid.transform
    r_off, c_off = grid.index_offset
    xmin, ymin, xmax, ymax = box
    fc = [(x - t.c) / t.a - 0.5 - c_off for x in (xmin, xmax)]
    fr = [(y - t.f) / t.e - 0.5 - r_off for y in (ymin, ymax)]
    ulp = math.ulp(max(abs(v) for v in box))
    eps = max(1e-9, 16.0 * ulp / min(abs(t.a), abs(t.e)))
    return (
        max(math.ceil(min(fr) - eps), 0),
        min(math.floor(max(fr) + eps), grid.height - 1),
        max(math.ceil(min(fc) - eps), 0),
        min(math.floor(max(fc) + eps), grid.width - 1),
    )


def _children(grid: Grid, box: tuple[float, ...], fanout: int) -> list[tuple[float, ...]]:
    """The children of one rectangle: cut on the middle data line of each axis that has one."""
    r0, r1, c0, c1 = _index_range(grid, box)
    xmin, ymin, xmax, ymax = box
    cx = float(grid.x_coords[(c0 + c1) // 2]) if c1 - c0 >= 2 else None
    cy = float(grid.y_coords[(r0 + r1) // 2]) if r1 - r0 >= 2 else None
    if fanout == 2:
        axes = ("x", "y") if xmax - xmin >= ymax - ymin else ("y", "x")
        for axis in axes:
            if axis == "x" and cx is not None:
                return [(xmin, ymin, cx, ymax), (cx, ymin, xmax, ymax)]
            if axis == "y" and cy is not None:
                return [(xmin, ymin, xmax, cy), (xmin, cy, xmax, ymax)]
        return []
    bands = [(xmin, ymin, xmax, cy), (xmin, cy, xmax, ymax)] if cy is not None else [box]
    out = []
    for b in bands:
        out += [(b[0], b[1], cx, b[3]), (cx, b[1], b[2], b[3])] if cx is not None else [b]
    return out if len(out) > 1 else []


def _reference(grid: Grid, epsilon: float, max_points: int, fanout: int) -> dict:
    """Nodes breadth-first, one at a time: rects, parents, child ranges, patch index, error."""
    k = math.isqrt(max_points)
    heights = grid.heights_array("reference")
    rects, parents, index, errors, child_start, child_count = [], [], [], [], [], []
    frontier = [(grid.domain.as_tuple(), -1)]
    while frontier:
        first, next_frontier = len(rects), []
        for i, (box, parent) in enumerate(frontier):
            r0, r1, c0, c1 = _index_range(grid, box)
            sr = max(1, math.ceil((r1 - r0) / (k - 1)))
            sc = max(1, math.ceil((c1 - c0) / (k - 1)))
            err = grid_patch_errors(
                heights,
                np.array([[r0, r1, c0, c1]], dtype=np.int64),
                np.array([[sr, sc]], dtype=np.int64),
            )[0][0]
            kids = _children(grid, box, fanout) if err > epsilon else []
            rects.append(box)
            parents.append(parent)
            index.append((r0, r1, c0, c1, sr, sc))
            errors.append(err)
            child_start.append(first + len(frontier) + len(next_frontier) if kids else 0)
            child_count.append(len(kids))
            next_frontier += [(kid, first + i) for kid in kids]
        frontier = next_frontier
    return {
        "rects": np.array(rects),
        "parents": np.array(parents),
        "index": np.array(index),
        "errors": np.array(errors),
        "child_start": np.array(child_start),
        "child_count": np.array(child_count),
    }


def _assert_same_as_reference(grid: Grid, epsilon: float, max_points: int, fanout: int) -> None:
    tree = ApproximationTree.build(
        grid, epsilon=epsilon, max_points=max_points, fanout=fanout, progress=False
    )
    ref = _reference(grid, epsilon, max_points, fanout)
    assert len(tree) == len(ref["rects"]) > 1
    np.testing.assert_array_equal(tree.rects, ref["rects"])
    np.testing.assert_array_equal(tree.parents, ref["parents"])
    np.testing.assert_array_equal(tree.child_start, ref["child_start"])
    np.testing.assert_array_equal(tree.child_count, ref["child_count"])
    np.testing.assert_array_equal(tree.errors, ref["errors"])
    np.testing.assert_array_equal([tree.patch(i).index for i in range(len(tree))], ref["index"])


@pytest.mark.parametrize("fanout", [2, 4])
@pytest.mark.parametrize(("rows", "cols", "max_points"), [(37, 23, 16), (64, 65, 25), (9, 130, 9)])
def test_level_builder_matches_per_node_reference(rows, cols, max_points, fanout):
    """Odd, even and very unequal sizes, quadtree and k-d: every node equals the reference."""
    _assert_same_as_reference(fractal_terrain(rows, cols, seed=rows), 0.0, max_points, fanout)


@pytest.mark.parametrize("fanout", [2, 4])
def test_level_builder_matches_reference_with_nodata_and_offset(fanout):
    """Nodata holes and a window (index offset, world coordinates of the parent grid)."""
    grid = fractal_terrain(81, 77, seed=4)
    z = grid.heights.copy()
    z[10:30, 5:20] = np.nan
    z[60:, 70:] = np.nan
    holed = Grid(z, transform=grid.transform)
    _assert_same_as_reference(holed, 1.0, 25, fanout)
    _assert_same_as_reference(holed.window(3, 70, 11, 76), 0.5, 16, fanout)


def test_level_builder_matches_reference_on_a_real_dem(data_dir):
    """Mount St. Helens (nodata border), k-d tree at 2 m."""
    grid = at.open_terrain(str(data_file(data_dir, "edge/SainteHelens.dem")))
    _assert_same_as_reference(grid.window(0, 150, 0, 170), 2.0, 81, 2)


# -- the strategy table ------------------------------------------------------------------------


def test_strategy_table_picks_the_class_per_data_type():
    grid = fractal_terrain(17, seed=0)
    points = at.TINPointSet(grid.points())
    assert patch_class(grid, "grid") is GridPatch
    assert patch_class(grid, "tin") is GridTINPatch
    assert patch_class(points, "tin") is PointTINPatch
    assert patch_class(at.GridRefinement, "tin") is RefinedTINPatch
    # Every name × data type either has a class of that strategy or a clear ApproxTreeError.
    for terrain_type in TERRAIN_TYPES.values():
        for name in STRATEGIES:
            try:
                cls = patch_class(terrain_type, name)
            except ApproxTreeError as exc:
                assert name in str(exc) and terrain_type.__name__ in str(exc)
            else:
                assert cls.kind == name


def test_strategy_table_refuses_unknown_combinations():
    points = at.TINPointSet(np.random.default_rng(0).uniform(0, 10, (30, 3)))
    with pytest.raises(UnsupportedStrategyError, match="rtin strategy needs a regular Grid"):
        patch_class(points, "rtin")
    with pytest.raises(UnsupportedStrategyError, match="got a TINPointSet"):
        ApproximationTree.build(points, policy="nonregular", progress=False)
    with pytest.raises(InvalidParameterError, match="Unknown strategy 'delaunay'"):
        patch_class(fractal_terrain(9, seed=0), "delaunay")


def test_tin_modules_do_not_import_each_other():
    """patches/tin.py and patches/tin_points.py: no import cycle (not even inside functions)."""
    root = Path(at.__file__).parent / "patches"
    for name, other in (("tin", "tin_points"), ("tin_points", "tin")):
        tree = ast.parse((root / f"{name}.py").read_text())
        imported = {
            node.module
            for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module is not None
        }
        assert f"approxtree.patches.{other}" not in imported


def test_a_policy_choosing_per_rectangle_is_asked_per_node():
    """A StrategyPolicy subclass overriding ``candidates`` gets each node's own rectangle."""
    from approxtree.tree.policy import StrategyPolicy

    grid = fractal_terrain(65, 65, seed=2)
    middle = grid.domain.center[0]

    class WestTin(StrategyPolicy):
        def candidates(self, terrain, level, rect):
            return ("tin",) if rect.xmax <= middle else ("grid",)

    tree = ApproximationTree.build(
        grid, epsilon=1.0, max_points=25, policy=WestTin(), progress=False
    )
    kinds = np.array([tree.node(i).strategy for i in range(len(tree))])
    expected = np.where(tree.rects[:, 2] <= middle, "tin", "grid")
    np.testing.assert_array_equal(kinds, expected)
    assert set(kinds) == {"tin", "grid"}


# -- grid levels as arrays ---------------------------------------------------------------------


def test_grid_levels_make_patch_objects_only_when_asked():
    """A grid build keeps each level's patches as arrays; a node's GridPatch, made on first
    access, equals the one the constructor makes from the same figures (mesh included)."""
    from approxtree.tree.patch_table import PatchTable

    grid = fractal_terrain(70, 66, seed=5)
    z = grid.heights.copy()
    z[20:31, 8:40] = np.nan
    grid = Grid(z, transform=grid.transform)
    tree = ApproximationTree.build(grid, epsilon=0.5, max_points=25, progress=False)
    table = tree._patches
    assert isinstance(table, PatchTable) and table.held == 0 and len(tree) > 50
    ref = GridPatch.build_many(grid, [at.Rect(*(float(v) for v in r)) for r in tree.rects], 25, 0.5)
    for i, q in enumerate(ref):
        p = tree.patch(i)
        assert type(p) is GridPatch and p.grid is grid
        assert p.index == q.index and type(p.data_count) is int
        np.testing.assert_array_equal(
            [p.error, *p.z_range, p.data_count], [q.error, *q.z_range, q.data_count]
        )
        assert p.rect == q.rect and tree.patch(i) is p
        np.testing.assert_array_equal(p.vertices, q.vertices)
        np.testing.assert_array_equal(p.triangles, q.triangles)
    assert table.held == len(tree)
    again = ApproximationTree.build(grid, epsilon=0.5, max_points=25, progress=False)
    listed = list(again._patches)  # every object made in one batch
    assert again._patches.held == len(tree)
    assert [p.index for p in listed] == [q.index for q in ref]
    assert [p.rect for p in listed] == [q.rect for q in ref]
    np.testing.assert_array_equal(tree.errors, [q.error for q in ref])
    np.testing.assert_array_equal(tree.bboxes[:, 2], [q.z_range[0] for q in ref])
    np.testing.assert_array_equal(tree.bboxes[:, 5], [q.z_range[1] for q in ref])


def test_patch_table_mixes_objects_and_grid_arrays():
    """Levels held as objects and levels held as arrays: figures and strategy codes per node
    equal those read from the objects, names in order of first use."""
    from approxtree.tree.patch_table import PatchTable

    grid = fractal_terrain(40, seed=6)
    boxes = np.array([[0.0, 0.0, 200.0, 200.0], [150.0, 120.0, 390.0, 390.0]])
    tins = GridTINPatch.build_level(grid, boxes, 25, 0.5)
    arrays = GridPatch.build_level_arrays(grid, boxes[::-1], 25)
    table = PatchTable([tins, arrays, tins[:1]])
    objects = [*tins, *arrays.patches(), tins[0]]
    assert len(table) == 5 and table.held == 3
    names, codes = table.strategies()
    assert names == ["tin", "grid"]
    np.testing.assert_array_equal(codes, [0, 0, 1, 1, 0])
    np.testing.assert_array_equal(table.errors(), [p.error for p in objects])
    lo, hi = table.z_ranges()
    np.testing.assert_array_equal(lo, [p.z_range[0] for p in objects])
    np.testing.assert_array_equal(hi, [p.z_range[1] for p in objects])
    assert table[2].index == objects[2].index and table[0] is tins[0]
    assert table.records(np.array([2, 3])) is not None and table.records(np.array([1, 2])) is None
