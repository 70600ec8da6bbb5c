"""Approximation tree invariants on real and fractal DEMs, and bad build parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import data_file
from helpers import brute_force_error

import approxtree as at
from approxtree import ApproximationTree, EmptyTerrainError, Grid, InvalidParameterError, Rect
from approxtree.datasets import fractal_terrain, sample_terrain

# (file, epsilon, max_points): real DEMs of ../shared/data, with nodata in the last two.
REAL_CASES = [
    ("nc/elev_ned_30m.tif", 1.0, 17 * 17),
    ("scape/crater.stm", 10.0, 33 * 33),
    ("edge/SainteHelens.dem", 20.0, 17 * 17),
    ("edge/dtm.tif", 0.5, 9 * 9),
]


def check_invariants(tree: ApproximationTree, epsilon: float) -> None:
    """The structural invariants every tree must satisfy (see the test docstrings)."""
    terrain = tree.terrain
    for node in tree.nodes():
        patch = node.patch
        assert patch.point_count <= tree.max_points
        children = node.children
        if children:
            # Inner nodes split only because their error exceeds the threshold.
            assert node.error > epsilon
            parent = node.rect
            area = sum(c.rect.area for c in children)
            assert math.isclose(area, parent.area, rel_tol=1e-12)
            for c in children:
                assert c.rect.intersection(parent) == c.rect
                assert c.level == node.level + 1 and c.parent == node
            for i, a in enumerate(children):
                for b in children[i + 1 :]:
                    common = a.rect.intersection(b.rect)
                    assert common is None or common.area == 0.0
            union = Rect(
                min(c.rect.xmin for c in children),
                min(c.rect.ymin for c in children),
                max(c.rect.xmax for c in children),
                max(c.rect.ymax for c in children),
            )
            assert union == parent
        else:
            assert node.error <= epsilon or patch.is_full_resolution
        # B_N holds every data point of D_N.
        pts = terrain.points(node.rect)
        if len(pts):
            box = node.bbox
            assert box[2] == pts[:, 2].min() and box[5] == pts[:, 2].max()


@pytest.mark.parametrize(("relative", "epsilon", "max_points"), REAL_CASES)
def test_tree_invariants_on_real_dems(data_dir, relative, epsilon, max_points):
    """Children partition parents, leaves meet ε or are full resolution, boxes hold the data."""
    terrain = at.open_terrain(data_file(data_dir, relative))
    tree = ApproximationTree.build(terrain, epsilon=epsilon, max_points=max_points)
    assert len(tree) > 1
    check_invariants(tree, epsilon)


@pytest.mark.parametrize(("relative", "epsilon", "max_points"), REAL_CASES)
def test_stored_error_equals_brute_force_on_real_dems(data_dir, relative, epsilon, max_points):
    """Every node's ε_T(N) equals an independent recomputation with matplotlib's interpolator."""
    terrain = at.open_terrain(data_file(data_dir, relative))
    tree = ApproximationTree.build(terrain, epsilon=epsilon, max_points=max_points)
    # All nodes of the first four levels and a seeded sample of the deeper ones.
    rng = np.random.default_rng(0)
    shallow = np.flatnonzero(tree.levels < 4)
    deep = np.flatnonzero(tree.levels >= 4)
    chosen = np.concatenate([shallow, rng.choice(deep, min(len(deep), 300), replace=False)])
    for i in chosen:
        node = tree.node(int(i))
        expected = brute_force_error(terrain, node.rect, node.patch.vertices, node.patch.triangles)
        if math.isinf(expected):
            assert math.isinf(node.error)
        else:
            assert node.error == pytest.approx(expected, abs=1e-6 * (1 + abs(expected)))


def test_nodata_forces_refinement_until_represented(data_dir):
    """On Kauai (voids), no leaf has an infinite error and data next to voids are vertices."""
    terrain = at.open_terrain(data_file(data_dir, "srtm/N22W160v2.3a.hgt.zip"))
    tree = ApproximationTree.build(terrain, epsilon=5.0)
    assert np.isfinite(tree.errors[tree.leaves]).all()
    assert np.isinf(tree.errors).any()
    assert tree.stats()["max_leaf_error"] <= 5.0


def test_fractal_tree_save_load_round_trip(tmp_path):
    """save → load gives equal node arrays, parameters, terrain and patches."""
    terrain = fractal_terrain(129, 97, seed=1, relief=300.0)
    tree = ApproximationTree.build(terrain, epsilon=2.0, max_points=9 * 9, fanout=2)
    path = tmp_path / "t.zarr.zip"
    nbytes = tree.save(path)
    assert nbytes == path.stat().st_size
    back = ApproximationTree.load(path)
    for name in (
        "rects",
        "errors",
        "bboxes",
        "levels",
        "parents",
        "child_start",
        "child_count",
        "strategies",
    ):
        np.testing.assert_array_equal(getattr(back, name), getattr(tree, name))
    assert back.params == tree.params
    assert back.stats() == tree.stats()
    np.testing.assert_array_equal(back.terrain.heights, terrain.heights)
    assert back.terrain.transform == terrain.transform
    for i in range(len(tree)):
        a, b = tree.node(i).patch, back.node(i).patch
        assert a.index == b.index and a.error == b.error
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.triangles, b.triangles)


def test_kd_tree_has_two_children_per_inner_node():
    """fanout 2 builds a k-d tree; its invariants hold too."""
    tree = ApproximationTree.build(
        fractal_terrain(65, 129, seed=2), epsilon=1.0, max_points=25, fanout=2
    )
    inner = tree.child_count[tree.child_count > 0]
    assert set(inner.tolist()) == {2}
    check_invariants(tree, 1.0)


def test_odd_sized_grids_are_subdivided_exactly():
    """Grids of any size (not only 2^k+1) build trees whose leaves cover every data point."""
    terrain = fractal_terrain(50, 77, seed=5, relief=80.0)
    tree = ApproximationTree.build(terrain, epsilon=0.0, max_points=16)
    check_invariants(tree, 0.0)
    covered = np.zeros(terrain.shape, dtype=bool)
    for i in tree.leaves:
        r0, r1, c0, c1 = terrain.index_range(tree.node(int(i)).rect)
        covered[r0 : r1 + 1, c0 : c1 + 1] = True
    assert covered.all()
    assert tree.stats()["max_leaf_error"] == 0.0


def test_sample_terrain_patch_mesh_is_ccw_and_inside_its_rect():
    """Patch triangles are counter-clockwise seen from above and vertices lie in D_N."""
    tree = ApproximationTree.build(sample_terrain(), epsilon=5.0)
    for node in tree.nodes()[:50]:
        v, t = node.patch.vertices, node.patch.triangles
        e1 = v[t[:, 1], :2] - v[t[:, 0], :2]
        e2 = v[t[:, 2], :2] - v[t[:, 0], :2]
        assert (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0).all()
        assert node.rect.contains(v[:, 0], v[:, 1]).all()


def test_constant_grid_is_one_patch_with_zero_error():
    """A constant terrain is valid: a single root patch of error 0."""
    tree = ApproximationTree.build(Grid(np.full((200, 300), 42.0)), epsilon=0.0)
    assert len(tree) == 1 and tree.root.error == 0.0 and tree.root.is_leaf


@pytest.mark.parametrize("epsilon", [-1.0, float("nan"), float("inf")])
def test_bad_epsilon_is_rejected(epsilon):
    """Negative, NaN or infinite epsilon raise InvalidParameterError naming epsilon."""
    with pytest.raises(InvalidParameterError, match="epsilon"):
        ApproximationTree.build(fractal_terrain(9), epsilon=epsilon)


def test_bad_max_points_and_fanout_are_rejected():
    """max_points < 4, a fanout other than 2 or 4 and an unknown policy are clear errors."""
    with pytest.raises(InvalidParameterError, match="max_points"):
        ApproximationTree.build(fractal_terrain(9), max_points=3)
    with pytest.raises(InvalidParameterError, match="fanout"):
        ApproximationTree.build(fractal_terrain(9), fanout=3)
    with pytest.raises(InvalidParameterError, match="policy"):
        ApproximationTree.build(fractal_terrain(9), policy="magic")


def test_nan_only_and_thin_grids_are_rejected():
    """NaN-only and 1 × N height arrays cannot become terrains."""
    with pytest.raises(EmptyTerrainError):
        Grid(np.full((20, 20), np.nan))
    with pytest.raises(EmptyTerrainError):
        Grid(np.ones((1, 50)))


def test_scattered_points_refuse_the_grid_strategy():
    """The grid strategy refuses a point set with a message naming the data type."""
    pts = np.random.default_rng(0).uniform(0, 10, (50, 3))
    with pytest.raises(at.UnsupportedStrategyError, match="TINPointSet"):
        ApproximationTree.build(at.TINPointSet(pts), policy="grid")
