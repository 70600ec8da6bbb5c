"""ApproximationTree.update: the tree after an edit equals a fresh build, node for node."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_file

from approxtree.datasets import fractal_terrain
from approxtree.errors import InvalidParameterError
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.io import read_grid
from approxtree.tree import update as update_module
from approxtree.tree import update_cells
from approxtree.tree.approximation_tree import ApproximationTree


def cell_rect(grid: Grid, r0: int, c0: int, rows: int, cols: int) -> Rect:
    """The world rect of cells rows r0.., columns c0.. (pixel corners)."""
    t = grid.transform
    xs = (t.c + c0 * t.a, t.c + (c0 + cols) * t.a)
    ys = (t.f + r0 * t.e, t.f + (r0 + rows) * t.e)
    return Rect(min(xs), min(ys), max(xs), max(ys))


def assert_same_tree(a: ApproximationTree, b: ApproximationTree) -> None:
    """Every node array equal, errors and boxes to the last bit, patches alike."""
    assert len(a) == len(b)
    for name in ("rects", "levels", "parents", "child_start", "child_count", "strategies"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.errors.tobytes() == b.errors.tobytes()
    assert a.bboxes.tobytes() == b.bboxes.tobytes()
    assert a.strategy_names == b.strategy_names
    for i in np.linspace(0, len(a) - 1, 25).astype(int).tolist():
        pa, pb = a.patch(i), b.patch(i)
        assert pa.kind == pb.kind
        np.testing.assert_array_equal(pa.vertices, pb.vertices)
        np.testing.assert_array_equal(pa.triangles, pb.triangles)


def random_edits(grid: Grid, rng: np.random.Generator, n: int, nodata: bool):
    """n random windows (rect, heights): bumps, pits, flat fills and holes of no data."""
    zlo, zhi = grid.z_range
    for _ in range(n):
        rows = int(rng.integers(1, max(2, grid.height // 3)))
        cols = int(rng.integers(1, max(2, grid.width // 3)))
        r0 = int(rng.integers(0, grid.height - rows + 1))
        c0 = int(rng.integers(0, grid.width - cols + 1))
        old = np.array(grid.heights[r0 : r0 + rows, c0 : c0 + cols], dtype=np.float64)
        kind = rng.integers(0, 3)
        if kind == 0:
            new = old + rng.normal(0, (zhi - zlo) * 0.05, old.shape)
        elif kind == 1:
            new = np.full(old.shape, zlo + (zhi - zlo) * rng.random())
        else:
            new = old - (zhi - zlo) * 0.2
        if nodata:
            new[rng.random(old.shape) < 0.2] = np.nan
        yield cell_rect(grid, r0, c0, rows, cols), new


def check_sequence(grid: Grid, seed: int, nodata: bool, **params) -> None:
    """Apply random edits one after the other, comparing with a fresh build (tree and terrain
    z range) after each."""
    rng = np.random.default_rng(seed)
    tree = ApproximationTree.build(grid, **params)
    for rect, heights in random_edits(grid, rng, 4, nodata):
        report = tree.update(rect, heights)
        fresh = ApproximationTree.build(Grid(np.array(grid.heights), grid.transform), **params)
        assert_same_tree(tree, fresh)
        assert tree.terrain.z_range == fresh.terrain.z_range
        assert len(report.rebuilt) >= 1
        kept = np.flatnonzero(report.old_to_new >= 0)
        assert len(kept) + len(report.removed) == report.nodes_before


@pytest.fixture(params=["built", "cells"])
def large_nodes(request, monkeypatch) -> str:
    """Run twice: large nodes rebuilt whole, and measured per lattice cell from 400 points
    (by the build from 2000 points, by the first update reaching them below)."""
    if request.param == "cells":
        monkeypatch.setattr(update_cells, "LARGE_POINTS", 400)
        monkeypatch.setattr(update_cells, "BUILD_POINTS", 2000)
    return request.param


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("nodata", [False, True])
def test_fractal_updates_equal_fresh_builds(seed: int, nodata: bool, large_nodes: str) -> None:
    """Random edits of a generated fractal give the fresh build's tree after each edit."""
    grid = fractal_terrain(129 + seed * 17, 150, seed=seed)
    check_sequence(grid, seed, nodata, epsilon=5.0, max_points=9 * 9)


@pytest.mark.parametrize("fanout", [2, 4])
def test_real_dem_updates_equal_fresh_builds(data_dir, fanout: int, large_nodes: str) -> None:
    """Random edits of the NC DEM (with holes of no data) give the fresh build's tree."""
    grid = read_grid(data_file(data_dir, "nc/elev_ned_30m.tif"))
    check_sequence(grid, 7 + fanout, True, epsilon=1.0, max_points=17 * 17, fanout=fanout)


def test_signed_zero_extremes_follow_the_build(monkeypatch) -> None:
    """A terrain whose lowest heights are +0.0 and −0.0 gets the build's z range bit for bit."""
    monkeypatch.setattr(update_cells, "LARGE_POINTS", 400)
    grid = fractal_terrain(97, 97, seed=4)
    z = np.array(grid.heights)
    z -= np.nanmin(z)
    z[::7, ::5] = -0.0
    grid = Grid(z, grid.transform)
    check_sequence(grid, 4, False, epsilon=5.0, max_points=9 * 9)


def test_hybrid_policy_updates_equal_fresh_builds() -> None:
    """A tree of several strategies (auto policy) follows the edit as a fresh build does."""
    grid = fractal_terrain(65, 70, seed=3)
    check_sequence(grid, 3, False, epsilon=4.0, max_points=9 * 9, policy="auto")


def test_edit_that_flattens_merges_subtrees() -> None:
    """Flattening a rough window drops its subtrees; roughening it grows them back."""
    grid = fractal_terrain(129, 129, seed=5)
    tree = ApproximationTree.build(grid, epsilon=2.0, max_points=9 * 9)
    n0 = len(tree)
    rect = cell_rect(grid, 0, 0, 129, 64)
    old = np.array(grid.heights[:, :64])
    tree.update(rect, np.zeros_like(old))
    assert len(tree) < n0
    tree.update(rect, old)
    fresh = ApproximationTree.build(fractal_terrain(129, 129, seed=5), epsilon=2.0, max_points=81)
    assert_same_tree(tree, fresh)


def test_unchanged_nodes_keep_their_ids_map() -> None:
    """old_to_new maps every kept node to a node with the same rect and error."""
    grid = fractal_terrain(129, 129, seed=6)
    tree = ApproximationTree.build(grid, epsilon=3.0, max_points=9 * 9)
    rects, errors = tree.rects.copy(), tree.errors.copy()
    report = tree.update(cell_rect(grid, 10, 10, 8, 8), np.full((8, 8), 500.0))
    kept = np.flatnonzero(report.old_to_new >= 0)
    new = report.old_to_new[kept]
    np.testing.assert_array_equal(tree.rects[new], rects[kept])
    np.testing.assert_array_equal(tree.errors[new], errors[kept])
    assert not np.isin(new, report.rebuilt).any()


def test_misaligned_window_is_refused() -> None:
    """A window off the cell edges, of the wrong shape or outside the grid is refused."""
    grid = fractal_terrain(33, 33, seed=1)
    tree = ApproximationTree.build(grid, epsilon=3.0, max_points=25)
    rect = cell_rect(grid, 2, 2, 4, 4)
    with pytest.raises(InvalidParameterError, match="cell edges"):
        tree.update(Rect(rect.xmin + 1.0, rect.ymin, rect.xmax + 1.0, rect.ymax), np.zeros((4, 4)))
    with pytest.raises(InvalidParameterError, match="heights are"):
        tree.update(rect, np.zeros((3, 4)))
    with pytest.raises(InvalidParameterError, match="not inside"):
        tree.update(cell_rect(grid, 30, 30, 4, 4), np.zeros((4, 4)))


def test_failed_update_leaves_terrain_and_tree(monkeypatch) -> None:
    """An update that fails in the middle leaves the terrain's heights and the tree as before."""
    grid = fractal_terrain(65, 65, seed=2)
    tree = ApproximationTree.build(grid, epsilon=3.0, max_points=25)
    heights, errors = np.array(grid.heights), tree.errors.copy()

    def broken(*args, **kwargs):
        raise MemoryError("out of memory in the middle of the walk")

    monkeypatch.setattr(update_module, "update_levels", broken)
    with pytest.raises(MemoryError):
        tree.update(cell_rect(grid, 4, 4, 8, 8), np.zeros((8, 8)))
    np.testing.assert_array_equal(grid.heights, heights)
    assert grid.point_count == heights.size
    assert tree.errors.tobytes() == errors.tobytes() and tree.version == 0
