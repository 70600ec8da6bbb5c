"""Selection without GL: hand-made trees and plain frame states, asserting which nodes are drawn."""

from __future__ import annotations

import math

import numpy as np
import pytest
from affine import Affine

from approxtree import ApproximationTree, Grid, InvalidParameterError
from approxtree.datasets import fractal_terrain
from approxtree.render import (
    Camera,
    FrameState,
    SelectionResult,
    display_scale,
    overview_camera,
    select,
    texel_sizes,
    visual_errors,
)
from approxtree.render.frustum import boxes_in_frustum

SIZE = (400, 300)


def flat_tree(errors=(2.0, 0.5, 0.5, 0.5, 0.5), z=0.0) -> ApproximationTree:
    """Root [0, 4]² with four leaf quadrants (ids 1..4: SW, SE, NW, NE) over flat ground z."""
    heights = np.full((5, 5), z)
    terrain = Grid(heights, transform=Affine(1.0, 0.0, -0.5, 0.0, -1.0, 4.5))
    rects = np.array(
        [[0, 0, 4, 4], [0, 0, 2, 2], [2, 0, 4, 2], [0, 2, 2, 4], [2, 2, 4, 4]], dtype=float
    )
    bboxes = np.column_stack([rects[:, :2], np.full(5, z), rects[:, 2:], np.full(5, z)])
    return ApproximationTree(
        terrain,
        rects=rects,
        errors=np.array(errors, dtype=float),
        bboxes=bboxes,
        levels=np.array([0, 1, 1, 1, 1], dtype=np.int32),
        parents=np.array([-1, 0, 0, 0, 0]),
        child_start=np.array([1, 0, 0, 0, 0]),
        child_count=np.array([4, 0, 0, 0, 0]),
        strategies=np.zeros(5, dtype=np.uint8),
        strategy_names=["grid"],
        params={"epsilon": 0.0, "max_points": 9, "fanout": 4, "policy": "grid"},
        patches=[None] * 5,
    )


def frame(tree, camera, size=SIZE) -> FrameState:
    return FrameState.from_camera(
        camera, size, tree.bboxes[0], tree.origin, display_scale(tree.terrain)
    )


def oblique(tree, distance: float) -> FrameState:
    """Looking at the centre (2, 2, 0) from the south-west at 45°, ``distance`` away."""
    d = distance / math.sqrt(3.0)
    return frame(tree, Camera.look_at((2 - d, 2 - d, d), (2, 2, 0), fov=60))


def test_far_camera_selects_the_root_only():
    """A camera far away sees α_root under the threshold: only the root is drawn."""
    tree = flat_tree()
    sel = select(tree, oblique(tree, 5000.0), alpha=1.0, gamma=math.inf)
    assert sel.nodes.tolist() == [0]
    assert sel.stats["nodes_visited"] == 1 and sel.stats["culled"] == 0
    assert sel.result_of(0) is SelectionResult.SELECTED
    assert sel.result_of(1) is None


def test_near_camera_refines_to_the_leaves():
    """Close up α_root exceeds alpha: the root is refined and its four leaves drawn."""
    tree = flat_tree()
    sel = select(tree, oblique(tree, 10.0), alpha=1.0, gamma=math.inf)
    assert sel.nodes.tolist() == [1, 2, 3, 4]
    assert sel.result_of(0) is SelectionResult.REFINED
    assert sel.stats["nodes_visited"] == 5
    # Leaves are drawn whatever their α.
    assert sel.stats["max_alpha"] > 1.0


def test_threshold_between_alpha_values_decides():
    """The same view selects the root or its children depending on which side alpha lies."""
    tree = flat_tree()
    fs = oblique(tree, 200.0)
    a_root = visual_errors(tree.bboxes[:1], tree.errors[:1], np.ones((1, 2)), fs)[0][0]
    assert select(tree, fs, alpha=a_root * 1.01, gamma=math.inf).nodes.tolist() == [0]
    assert select(tree, fs, alpha=a_root * 0.99, gamma=math.inf).nodes.tolist() == [1, 2, 3, 4]


def test_looking_away_culls_the_root():
    """A camera looking away from the terrain culls the root: nothing is visited below it."""
    tree = flat_tree()
    fs = frame(tree, Camera.look_at((2, -10, 5), (2, -20, 5), fov=60))
    sel = select(tree, fs, alpha=1.0)
    assert len(sel.nodes) == 0
    assert sel.stats == {
        "nodes_visited": 1,
        "culled": 1,
        "selected": 0,
        "max_alpha": 0.0,
        "max_gamma": 0.0,
    }
    assert sel.result_of(0) is SelectionResult.CULLED


def test_partial_view_culls_the_other_quadrants():
    """Looking straight down on the SW quadrant with a narrow view culls the three others."""
    tree = flat_tree()
    # Footprint at z = 0: half-width 10 · tan(2.5°) ≈ 0.44 around (1, 1).
    fs = frame(tree, Camera.look_at((1, 1, 10), (1, 1, 0), fov=5), size=(300, 300))
    # Seen from straight above a vertical segment projects to a point (α ≈ 0): γ refines.
    sel = select(tree, fs, alpha=1.0, gamma=1e-6)
    assert sel.nodes.tolist() == [1]
    assert [sel.result_of(i) for i in range(5)] == [
        SelectionResult.REFINED,
        SelectionResult.SELECTED,
        SelectionResult.CULLED,
        SelectionResult.CULLED,
        SelectionResult.CULLED,
    ]
    assert sel.stats["culled"] == 3


def test_gamma_refines_exact_patches():
    """With α = 0 everywhere (exact patches) the texel area γ alone decides the refinement."""
    tree = flat_tree(errors=(0.0,) * 5)
    fs = frame(tree, Camera.look_at((2, 2, 20), (2, 2, 0), fov=60))
    texels = np.array([[2.0, 2.0], [1.0, 1.0], [1.0, 1.0], [1.0, 1.0], [1.0, 1.0]])
    _, g = visual_errors(tree.bboxes, tree.errors, texels, fs)
    sel = select(tree, fs, alpha=1.0, gamma=g[0] * 1.01, texels=texels)
    assert sel.nodes.tolist() == [0]
    sel = select(tree, fs, alpha=1.0, gamma=g[0] * 0.99, texels=texels)
    assert sel.nodes.tolist() == [1, 2, 3, 4]
    assert sel.stats["max_alpha"] == 0.0


def test_alpha_is_the_projected_vertical_segment():
    """Seen horizontally from distance D on the optical axis, α = focal_px · ε / D."""
    tree = flat_tree(errors=(2.0, 0, 0, 0, 0))
    fs = frame(tree, Camera.look_at((-10, 2, 0), (0, 2, 0), fov=60))
    a, _ = visual_errors(tree.bboxes[:1], tree.errors[:1], np.ones((1, 2)), fs)
    focal = 0.5 * SIZE[1] / math.tan(math.radians(30))
    assert a[0] == pytest.approx(focal * 2.0 / 10.0, rel=1e-9)


def test_gamma_is_the_projected_texel_area():
    """Looking straight down from height D, a w × h texel covers (f·w/D)·(f·h/D) pixels²."""
    tree = flat_tree()
    fs = frame(tree, Camera.look_at((2, 2, 8), (2, 2, 0), fov=60))
    _, g = visual_errors(tree.bboxes[:1], tree.errors[:1], np.array([[0.5, 0.25]]), fs)
    focal = 0.5 * SIZE[1] / math.tan(math.radians(30))
    assert g[0] == pytest.approx((focal * 0.5 / 8) * (focal * 0.25 / 8), rel=1e-9)


def test_eye_inside_a_box_always_refines():
    """An eye inside B_N makes α_N infinite, so the node is refined even for a huge alpha."""
    tree = flat_tree()
    tree.bboxes[:, 5] = 10.0
    fs = frame(tree, Camera.look_at((1, 1, 5), (3, 3, 0), fov=60))
    sel = select(tree, fs, alpha=1e9, gamma=math.inf)
    assert sel.result_of(0) is SelectionResult.REFINED
    assert math.isinf(sel.stats["max_alpha"])


def test_eye_below_ground_selects_nothing():
    """An eye under the terrain surface gives an empty selection (an empty frame, no error)."""
    tree = flat_tree(z=100.0)
    fs = frame(tree, Camera.look_at((2, 2, 50), (2, 2, 200), fov=60))
    sel = select(tree, fs, alpha=1.0)
    assert sel.below_ground and len(sel.nodes) == 0 and sel.stats["nodes_visited"] == 0


def test_bad_thresholds_are_rejected():
    """alpha <= 0, NaN or inf and gamma <= 0 raise InvalidParameterError with the value."""
    tree = flat_tree()
    fs = oblique(tree, 10.0)
    for alpha, gamma in ((0.0, 1.0), (-1.0, 1.0), (math.nan, 1.0), (math.inf, 1.0), (1, 0)):
        with pytest.raises(InvalidParameterError, match="must be"):
            select(tree, fs, alpha=alpha, gamma=gamma)


def test_bad_cameras_and_viewports_are_rejected():
    """Non-finite camera values, eye == target, a bad fov and zero or huge sizes are errors."""
    with pytest.raises(InvalidParameterError, match="finite"):
        Camera.look_at((0, 0, math.nan), (1, 1, 1))
    with pytest.raises(InvalidParameterError, match="differ"):
        Camera.look_at((1, 1, 1), (1, 1, 1))
    with pytest.raises(InvalidParameterError, match="fov"):
        Camera.look_at((0, 0, 1), (1, 1, 1), fov=180)
    tree = flat_tree()
    cam = Camera.look_at((0, 0, 10), (2, 2, 0))
    for size in ((0, 100), (100, 0), (100000, 100), (10.5, 10)):
        with pytest.raises(InvalidParameterError, match="size"):
            frame(tree, cam, size=size)


def test_geographic_terrain_is_scaled_to_metres():
    """A terrain in EPSG:4326 is displayed in metres: 1° of latitude ≈ 111.2 km."""
    terrain = Grid(np.zeros((3, 3)), Affine(0.1, 0, 10.0, 0, -0.1, 60.3), crs="EPSG:4326")
    sx, sy, sz = display_scale(terrain)
    assert sy == pytest.approx(111_195, rel=1e-4)
    assert sx == pytest.approx(sy * math.cos(math.radians(60.15)), rel=1e-6)
    assert sz == 1.0


def _finer_below(tree, texels, node) -> bool:
    """Whether some descendant of ``node`` has a smaller texel area, walked plainly."""
    area = texels[node, 0] * texels[node, 1]
    stack = list(range(tree.child_start[node], tree.child_start[node] + tree.child_count[node]))
    while stack:
        c = stack.pop()
        if texels[c, 0] * texels[c, 1] < area:
            return True
        stack += range(tree.child_start[c], tree.child_start[c] + tree.child_count[c])
    return False


def _reference_select(tree, fs, alpha, gamma, texels, node=0, out=None):
    """The recursion of section 4.2 written plainly, node by node (γ refines only where a
    descendant's texel is finer: refining cannot make texels finer elsewhere)."""
    out = [] if out is None else out
    if not boxes_in_frustum(tree.bboxes[node : node + 1], fs.planes)[0]:
        return out
    a, g = visual_errors(
        tree.bboxes[node : node + 1], tree.errors[node : node + 1], texels[node : node + 1], fs
    )
    over_gamma = g[0] > gamma and _finer_below(tree, texels, node)
    if tree.child_count[node] > 0 and (a[0] > alpha or over_gamma):
        for c in range(tree.child_start[node], tree.child_start[node] + tree.child_count[node]):
            _reference_select(tree, fs, alpha, gamma, texels, int(c), out)
    else:
        out.append(node)
    return out


@pytest.mark.parametrize("alpha, gamma", [(1.0, 2.0), (4.0, math.inf), (0.5, 8.0)])
def test_matches_the_recursive_definition(alpha, gamma):
    """On a fractal tree and three views, the vectorized traversal selects exactly the nodes
    of the plain recursion of section 4.2."""
    terrain = fractal_terrain(257, seed=7)
    tree = ApproximationTree.build(terrain, epsilon=0.5, max_points=9 * 9, progress=False)
    texels = texel_sizes(tree)
    scale = display_scale(terrain)
    views = [
        overview_camera(tree.bboxes[0], scale),
        Camera.look_at((500, 300, 1500), (1500, 1500, 400), fov=50),
        Camera.look_at((1280, 1280, 3000), (1280, 1281, 0), fov=30),
    ]
    for cam in views:
        fs = frame(tree, cam, size=(640, 360))
        sel = select(tree, fs, alpha, gamma, texels)
        expected = _reference_select(tree, fs, alpha, gamma, texels)
        assert sorted(sel.nodes.tolist()) == sorted(expected)
        assert len(sel.nodes) > 0


def test_selected_nodes_partition_the_visible_domain():
    """No selected node is an ancestor of another: the cut never draws a region twice."""
    terrain = fractal_terrain(257, seed=2)
    tree = ApproximationTree.build(terrain, epsilon=0.5, max_points=9 * 9, progress=False)
    fs = frame(tree, overview_camera(tree.bboxes[0], display_scale(terrain)), (800, 600))
    chosen = set(select(tree, fs, alpha=1.0, gamma=2.0).nodes.tolist())
    for i in chosen:
        p = int(tree.parents[i])
        while p >= 0:
            assert p not in chosen
            p = int(tree.parents[p])
    # From the overview the whole domain is visible, so the cut covers its full area.
    area = sum(
        (tree.rects[i, 2] - tree.rects[i, 0]) * (tree.rects[i, 3] - tree.rects[i, 1])
        for i in chosen
    )
    assert area == pytest.approx(terrain.domain.area, rel=1e-9)


def test_texel_size_is_the_data_spacing():
    """A grid node's texel is its sample spacing: rect extent over its sampled intervals."""
    terrain = fractal_terrain(65, seed=1, cell_size=10.0)
    tree = ApproximationTree.build(terrain, epsilon=0.0, max_points=9 * 9, progress=False)
    texels = texel_sizes(tree)
    # Root: 65 lines at most 9 per side → step 8, 8 intervals over 640 m.
    assert texels[0].tolist() == [80.0, 80.0]
    leaves = tree.leaves
    # Leaves at full resolution sample every data line.
    assert np.allclose(texels[leaves], 10.0)
    for i in range(len(tree)):
        patch = tree.patch(i)
        sr, sc = patch.steps
        assert texels[i, 0] <= sc * 10.0 + 1e-9 and texels[i, 1] <= sr * 10.0 + 1e-9
