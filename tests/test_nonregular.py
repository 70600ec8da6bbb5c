"""Non-regular grid strategy (and the uniform grid of ``approximate``): exact errors against
matplotlib, valid meshes, the incremental refinement against a from-scratch reference, budgets,
monotone vertex counts, tree files and crack-free rendering."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import data_file
from helpers import brute_force_error
from matplotlib.tri import LinearTriInterpolator, Triangulation
from test_render import gl_context, holes_in_footprint  # noqa: F401  (fixture)
from test_strategies import check_mesh, crop
from test_tree import check_invariants

import approxtree as at
from approxtree import ApproximationTree, Grid, UnsupportedStrategyError
from approxtree.datasets import fractal_terrain
from approxtree.kernels.grid_patch import grid_patch_errors
from approxtree.kernels.row_column import lattice_error
from approxtree.patches import STRATEGIES, NonRegularGridPatch
from approxtree.patches.approximate import approximate
from approxtree.patches.nonregular import lattice_mesh

REAL = ["scape/crater.stm", "nc/elev_ned_30m.tif", "srtm/N44W072.hgt"]
GRIDS = ["nonregular", "grid"]


def reference_refinement(grid: Grid, max_points: int) -> tuple[list[int], list[int]]:
    """The paper's algorithm from scratch: each step re-interpolates every data point with
    matplotlib over the whole lattice, then inserts the row and column of the worst point."""
    rows_n, cols_n = grid.shape
    rows, cols = [0, rows_n - 1], [0, cols_n - 1]
    pts = grid.points()
    while True:
        verts, tris = lattice_mesh(grid, np.array(rows), np.array(cols))
        tri = Triangulation(verts[:, 0], verts[:, 1], tris)
        h = LinearTriInterpolator(tri, verts[:, 2])(pts[:, 0], pts[:, 1])
        err = np.abs(pts[:, 2] - np.ma.filled(h, np.nan))
        k = int(np.argmax(err))
        if err[k] <= 1e-9:
            return rows, cols
        fr, fc = grid.fractional_index(pts[k, 0], pts[k, 1])
        r, c = int(np.rint(fr)), int(np.rint(fc))
        new_rows = sorted({*rows, r})
        new_cols = sorted({*cols, c})
        if len(new_rows) * len(new_cols) > max_points:
            return rows, cols
        rows, cols = new_rows, new_cols


@pytest.mark.parametrize("strategy", GRIDS)
@pytest.mark.parametrize("relative", REAL)
def test_reported_error_is_exact_and_within_request_on_real_dems(data_dir, relative, strategy):
    """Max error equals matplotlib's brute-force recomputation, is <= the request, and the
    mesh is valid (manifold, CCW, no T-junction, tiles the domain)."""
    terrain = crop(at.open_terrain(data_file(data_dir, relative)), 180, 150)
    z0, z1 = terrain.z_range
    # The uniform grid needs a coarse request to drop any line on these sharp DEMs.
    requested = (0.05 if strategy == "nonregular" else 0.25) * (z1 - z0)
    mesh = approximate(terrain, strategy, max_error=requested)
    expected = brute_force_error(terrain, terrain.domain, mesh.vertices, mesh.triangles)
    assert mesh.max_error == pytest.approx(expected, abs=1e-6 * (1 + expected))
    assert 0 < mesh.max_error <= requested
    assert len(mesh.vertices) < terrain.point_count
    check_mesh(mesh.vertices, mesh.triangles, terrain.domain)


@pytest.mark.parametrize("strategy", GRIDS)
def test_rms_error_is_exact_on_fractal_terrain(strategy):
    """The reported RMS error equals the RMS of matplotlib's per-point errors."""
    terrain = fractal_terrain(61, 83, seed=11, relief=300.0)
    mesh = approximate(terrain, strategy, max_points=600)
    pts = terrain.points()
    tri = Triangulation(mesh.vertices[:, 0], mesh.vertices[:, 1], mesh.triangles)
    h = LinearTriInterpolator(tri, mesh.vertices[:, 2])(pts[:, 0], pts[:, 1])
    err = np.abs(pts[:, 2] - h.filled(np.nan))
    assert not np.isnan(err).any()
    assert mesh.rms_error == pytest.approx(float(np.sqrt(np.mean(err**2))), rel=1e-9)
    assert mesh.max_error == pytest.approx(float(err.max()), abs=1e-9)
    check_mesh(mesh.vertices, mesh.triangles, terrain.domain)


def test_incremental_refinement_matches_the_from_scratch_algorithm():
    """Strip-wise updates choose exactly the rows and columns of the naive algorithm that
    re-evaluates every data point after each insertion."""
    terrain = fractal_terrain(29, 37, seed=12, relief=100.0)
    expected_rows, expected_cols = reference_refinement(terrain, 180)
    patch = NonRegularGridPatch.build(terrain, terrain.domain, 180, 0.0)
    assert patch.rows.tolist() == expected_rows
    assert patch.cols.tolist() == expected_cols
    assert patch.point_count <= 180 and len(expected_rows) > 4


def test_grid_lattice_error_agrees_with_the_grid_patch_kernel():
    """The lattice kernel measures a regular lattice exactly as GridPatch's kernel does."""
    terrain = fractal_terrain(70, 91, seed=13, relief=250.0)
    full = np.array([[0, 69, 0, 90]], dtype=np.int64)
    for step in (1, 2, 3, 7, 20):
        expected, _, _, _ = grid_patch_errors(terrain.heights, full, np.array([[step, step]]))
        rows = np.append(np.arange(0, 69, step), 69).astype(np.int64)
        cols = np.append(np.arange(0, 90, step), 90).astype(np.int64)
        assert lattice_error(terrain.heights, rows, cols)[0] == pytest.approx(expected[0])
    # A budget holding every data point gives the exact terrain.
    assert approximate(terrain, "grid", max_points=10_000).max_error == 0.0


def test_grid_error_goal_picks_the_largest_step_that_meets_it(data_dir):
    """For an error goal the uniform grid takes the largest step whose measured error meets
    it (errors are not monotone in the step, so every step is checked)."""
    terrain = crop(at.open_terrain(data_file(data_dir, "scape/crater.stm")), 120, 100)
    steps = np.arange(1, 120, dtype=np.int64)
    full = np.repeat(np.array([[0, 119, 0, 99]], dtype=np.int64), len(steps), axis=0)
    errors, _, _, _ = grid_patch_errors(terrain.heights, full, np.column_stack([steps, steps]))
    for goal in (10.0, 30.0, 60.0, 100.0, 200.0):
        mesh = approximate(terrain, "grid", max_error=goal)
        assert mesh.patch.steps[0] == steps[errors <= goal].max()
        assert mesh.max_error == errors[steps == mesh.patch.steps[0]][0] <= goal


@pytest.mark.parametrize("strategy", GRIDS)
def test_vertex_counts_fall_as_error_grows(data_dir, strategy):
    """Vertex counts are monotonically non-increasing in the requested error."""
    terrain = crop(at.open_terrain(data_file(data_dir, "scape/crater.stm")), 200, 180)
    counts = [
        len(approximate(terrain, strategy, max_error=e).vertices) for e in (1, 2, 5, 10, 20, 50)
    ]
    assert counts == sorted(counts, reverse=True) and counts[0] > counts[-1]


@pytest.mark.parametrize("goal", [{"max_points": 500}, {"max_triangles": 700}])
@pytest.mark.parametrize("strategy", GRIDS)
def test_budgets_are_respected(strategy, goal):
    """A point or triangle budget is never exceeded, and the error is finite."""
    mesh = approximate(fractal_terrain(120, 90, seed=7), strategy, **goal)
    if "max_points" in goal:
        assert 4 <= len(mesh.vertices) <= goal["max_points"]
        assert mesh.patch.point_count <= goal["max_points"]
    else:
        assert 2 <= len(mesh.triangles) <= goal["max_triangles"]
    assert math.isfinite(mesh.max_error) and mesh.max_error > 0


def test_patch_keeps_border_lines_and_only_stores_line_indices():
    """Rows and columns are sorted, start and end on the rectangle's border lines; the patch
    stores 4 bytes per chosen line and its vertices are the row–column intersections."""
    terrain = fractal_terrain(80, 64, seed=14, relief=200.0)
    rect = terrain.rect_of(10, 70, 5, 50)
    patch = NonRegularGridPatch.build(terrain, rect, 17 * 17, 1.0)
    assert patch.rows[0] == 10 and patch.rows[-1] == 70
    assert patch.cols[0] == 5 and patch.cols[-1] == 50
    assert (np.diff(patch.rows) > 0).all() and (np.diff(patch.cols) > 0).all()
    assert patch.nbytes == 4 * (len(patch.rows) + len(patch.cols))
    assert len(patch.vertices) == patch.point_count == len(patch.rows) * len(patch.cols) <= 289
    xs = set(terrain.x_coords[patch.cols].tolist())
    ys = set(terrain.y_coords[patch.rows].tolist())
    assert set(patch.vertices[:, 0].tolist()) == xs and set(patch.vertices[:, 1].tolist()) == ys
    expected = brute_force_error(terrain, rect, patch.vertices, patch.triangles)
    assert patch.error == pytest.approx(expected, abs=1e-6 * (1 + expected))


def test_nodata_holes_stay_out_and_error_is_exact(data_dir):
    """On Mount St Helens (nodata) drawn triangles avoid holes and errors are exact, for the
    whole-terrain mesh and for the nodes of a tree."""
    terrain = crop(at.open_terrain(data_file(data_dir, "edge/SainteHelens.dem")), 200, 200)
    assert terrain.nodata_count > 0
    mesh = approximate(terrain, "nonregular", max_error=20.0)
    assert np.isfinite(mesh.vertices[:, 2]).all()
    expected = brute_force_error(terrain, terrain.domain, mesh.vertices, mesh.triangles)
    assert mesh.max_error == pytest.approx(expected, abs=1e-6 * (1 + expected))
    assert mesh.max_error <= 20.0
    rr, cc = np.nonzero(np.isnan(terrain.heights))
    finder = Triangulation(mesh.vertices[:, 0], mesh.vertices[:, 1], mesh.triangles)
    assert (finder.get_trifinder()(terrain.x_coords[cc], terrain.y_coords[rr]) == -1).all()
    # In a tree, nodes split until every leaf represents its data points: finite errors.
    tree = ApproximationTree.build(terrain, epsilon=5.0, max_points=17 * 17, policy="nonregular")
    assert np.isfinite(tree.errors[tree.leaves]).all() and tree.errors.max() > 5.0
    for i in range(0, len(tree), max(1, len(tree) // 20)):
        node = tree.node(i)
        expected = brute_force_error(terrain, node.rect, node.patch.vertices, node.patch.triangles)
        assert node.error == pytest.approx(expected, abs=1e-6 * (1 + expected))


def test_tree_with_nonregular_policy_satisfies_invariants(data_dir, tmp_path):
    """A nonregular tree keeps the tree invariants, its node errors equal brute force, every
    patch holds at most s points, and save → load gives identical patches."""
    terrain = crop(at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif")), 200, 240)
    tree = ApproximationTree.build(terrain, epsilon=1.0, max_points=17 * 17, policy="nonregular")
    assert len(tree) > 1 and tree.strategy_names == ["nonregular"]
    check_invariants(tree, 1.0)
    for i in range(0, len(tree), max(1, len(tree) // 40)):
        node = tree.node(i)
        assert node.patch.point_count <= 17 * 17
        expected = brute_force_error(terrain, node.rect, node.patch.vertices, node.patch.triangles)
        assert node.error == pytest.approx(expected, abs=1e-6 * (1 + expected))
        assert node.rect.contains(node.patch.vertices[:, 0], node.patch.vertices[:, 1]).all()
    tree.save(tmp_path / "t.zarr")
    back = ApproximationTree.load(tmp_path / "t.zarr")
    for i in range(len(tree)):
        a, b = tree.node(i).patch, back.node(i).patch
        assert a.error == b.error and a.rms_error == b.rms_error and b.kind == "nonregular"
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.triangles, b.triangles)


def test_nonregular_tree_needs_fewer_nodes_than_grid(data_dir):
    """Adaptive rows and columns stop earlier than the regular grid at the same ε and s."""
    terrain = crop(at.open_terrain(data_file(data_dir, "scape/crater.stm")), 200, 200)
    sizes = {
        p: len(ApproximationTree.build(terrain, epsilon=2.0, max_points=17 * 17, policy=p))
        for p in GRIDS
    }
    assert sizes["nonregular"] < sizes["grid"]


def test_cli_builds_a_nonregular_tree(tmp_path):
    """``approxtree build --policy nonregular`` writes a tree that loads with that strategy."""
    from click.testing import CliRunner

    from approxtree.cli import main

    terrain = fractal_terrain(65, 70, seed=15, relief=150.0)
    np.save(tmp_path / "dem.npy", terrain.heights)
    out = tmp_path / "dem.zarr"
    result = CliRunner().invoke(
        main, ["build", str(tmp_path / "dem.npy"), "--out", str(out), "--policy", "nonregular"]
    )
    assert result.exit_code == 0, result.output
    assert ApproximationTree.load(out).strategy_names == ["nonregular"]


def test_scattered_points_are_refused():
    """The strategy needs a grid; a point set gets a clear UnsupportedStrategyError."""
    rng = np.random.default_rng(16)
    pts = at.TINPointSet(np.column_stack([rng.uniform(0, 9, (50, 2)), rng.uniform(0, 1, 50)]))
    with pytest.raises(UnsupportedStrategyError, match="nonregular strategy needs a regular Grid"):
        approximate(pts, "nonregular", max_error=1.0)
    assert "nonregular" in STRATEGIES


def test_no_cracks_between_nonregular_patches(gl_context):  # noqa: F811
    """With skirts, a nonregular tree cut at several levels shows no background pixel inside
    the terrain's footprint."""
    terrain = fractal_terrain(257, seed=5, relief=300.0)
    tree = ApproximationTree.build(
        terrain, epsilon=0.0, max_points=17 * 17, policy="nonregular", progress=False
    )
    holes, footprint, levels = holes_in_footprint(gl_context, tree, skirts=True)
    assert levels >= 2 and footprint > 50_000
    assert holes == 0
