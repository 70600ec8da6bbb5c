"""Approximation strategies (tin, rtin) on real DEMs and fractal terrain: exact errors, valid
meshes, Delaunay property, monotone vertex counts, agreement with pydelatin, tree integration."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import data_file
from helpers import brute_force_error
from test_tree import check_invariants

import approxtree as at
from approxtree import ApproximationTree, Grid
from approxtree.datasets import fractal_terrain
from approxtree.patches import STRATEGIES
from approxtree.patches.approximate import approximate

REAL = ["scape/crater.stm", "nc/elev_ned_30m.tif", "srtm/N44W072.hgt"]
STRATS = ["tin", "rtin"]


def crop(terrain: Grid, rows: int, cols: int) -> Grid:
    """The north-west rows × cols corner of a grid, same georeference."""
    return Grid(terrain.heights[:rows, :cols], terrain.transform, terrain.crs)


def check_mesh(vertices: np.ndarray, triangles: np.ndarray, domain: at.Rect) -> None:
    """Edge-manifold, CCW, no T-junction, and the triangles tile the domain exactly."""
    v = vertices[:, :2]
    t = triangles
    e1 = v[t[:, 1]] - v[t[:, 0]]
    e2 = v[t[:, 2]] - v[t[:, 0]]
    area2 = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    assert (area2 > 0).all()
    assert math.isclose(area2.sum() / 2, domain.area, rel_tol=1e-9)
    directed = {}
    for tri in t:
        for k in range(3):
            a, b = int(tri[k]), int(tri[(k + 1) % 3])
            assert (a, b) not in directed  # consistent orientation: each directed edge once
            directed[(a, b)] = True
    border = [(a, b) for (a, b) in directed if (b, a) not in directed]
    for a, b in border:
        # An unpaired edge lies on the domain border (so interior edges are shared by two).
        (xa, ya), (xb, yb) = v[a], v[b]
        on_x = math.isclose(xa, xb) and (
            math.isclose(xa, domain.xmin) or math.isclose(xa, domain.xmax)
        )
        on_y = math.isclose(ya, yb) and (
            math.isclose(ya, domain.ymin) or math.isclose(ya, domain.ymax)
        )
        assert on_x or on_y
    # No T-junction: with a tiled domain, the border length equals the domain's perimeter
    # only if no vertex lies inside another edge; check vertices against edge interiors.
    edges = np.array(list(directed))
    a, b = v[edges[:, 0]], v[edges[:, 1]]
    for p in v[np.random.default_rng(0).choice(len(v), min(len(v), 300), replace=False)]:
        cross = (b[:, 0] - a[:, 0]) * (p[1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (p[0] - a[:, 0])
        dot = (p[0] - a[:, 0]) * (b[:, 0] - a[:, 0]) + (p[1] - a[:, 1]) * (b[:, 1] - a[:, 1])
        length2 = (b[:, 0] - a[:, 0]) ** 2 + (b[:, 1] - a[:, 1]) ** 2
        scale = np.sqrt(length2) * 1e-9
        inside = (np.abs(cross) <= scale * np.sqrt(length2)) & (dot > 1e-9 * length2)
        inside &= dot < length2 * (1 - 1e-9)
        assert not inside.any()


@pytest.mark.parametrize("strategy", STRATS)
@pytest.mark.parametrize("relative", REAL)
def test_reported_error_is_exact_and_within_request_on_real_dems(data_dir, relative, strategy):
    """Max error equals a brute-force recomputation, is <= the request, and the mesh is valid."""
    terrain = crop(at.open_terrain(data_file(data_dir, relative)), 300, 260)
    z0, z1 = terrain.z_range
    requested = 0.01 * (z1 - z0)
    mesh = approximate(terrain, strategy, max_error=requested)
    expected = brute_force_error(terrain, terrain.domain, mesh.vertices, mesh.triangles)
    assert mesh.max_error == pytest.approx(expected, abs=1e-6 * (1 + expected))
    assert mesh.max_error <= requested
    check_mesh(mesh.vertices, mesh.triangles, terrain.domain)


@pytest.mark.parametrize("strategy", STRATS)
def test_fractal_error_exact_and_odd_sizes_covered(strategy):
    """On an odd-sized fractal grid the mesh tiles the domain and its error is exact."""
    terrain = fractal_terrain(97, 130, seed=3, relief=400.0)
    mesh = approximate(terrain, strategy, max_error=4.0)
    expected = brute_force_error(terrain, terrain.domain, mesh.vertices, mesh.triangles)
    assert mesh.max_error == pytest.approx(expected, abs=1e-6 * (1 + expected))
    assert mesh.max_error <= 4.0
    pts = terrain.points()
    err = pts[:, 2] - terrain.height_at(pts[:, 0], pts[:, 1])
    assert mesh.rms_error <= mesh.max_error and mesh.rms_error > 0 and np.all(err == 0)
    check_mesh(mesh.vertices, mesh.triangles, terrain.domain)


def test_tin_is_delaunay():
    """The Delaunay variant has no vertex strictly inside a neighbour's circumcircle."""
    terrain = fractal_terrain(129, seed=4, relief=300.0)
    mesh = approximate(terrain, "tin", max_error=2.0)
    v = mesh.vertices[:, :2]
    t = mesh.triangles
    opposite = {}
    for tri in t:
        for k in range(3):
            opposite[(int(tri[k]), int(tri[(k + 1) % 3]))] = int(tri[(k + 2) % 3])
    for (a, b), c in opposite.items():
        d = opposite.get((b, a))
        if d is None:
            continue
        m = np.array([[*(v[i] - v[d]), np.sum((v[i] - v[d]) ** 2)] for i in (a, b, c)])
        assert np.linalg.det(m) <= 1e-6 * np.abs(m).max() ** 2


@pytest.mark.parametrize("strategy", STRATS)
def test_vertex_counts_fall_as_error_grows(strategy):
    """Vertex counts are monotonically non-increasing in the requested error."""
    terrain = fractal_terrain(129, seed=5, relief=500.0)
    counts = [len(approximate(terrain, strategy, max_error=e).vertices) for e in (1, 3, 10, 30)]
    assert counts == sorted(counts, reverse=True) and counts[0] > counts[-1]


@pytest.mark.parametrize("max_error", [1.0, 5.0, 10.0, 30.0])
def test_tin_vertex_count_within_two_percent_of_pydelatin(max_error):
    """Same greedy algorithm as pydelatin: vertex counts within 2% at the same max error."""
    pydelatin = pytest.importorskip("pydelatin")
    terrain = fractal_terrain(257, seed=6, relief=1000.0)
    ours = approximate(terrain, "tin", max_error=max_error)
    theirs = pydelatin.Delatin(terrain.heights, max_error=max_error)
    assert abs(len(ours.vertices) / len(theirs.vertices) - 1) <= 0.02


@pytest.mark.parametrize("goal", [{"max_points": 500}, {"max_triangles": 700}])
@pytest.mark.parametrize("strategy", STRATS)
def test_budgets_are_respected(strategy, goal):
    """A point or triangle budget is never exceeded."""
    mesh = approximate(fractal_terrain(120, 90, seed=7), strategy, **goal)
    if "max_points" in goal:
        assert 4 <= len(mesh.vertices) <= goal["max_points"]
    else:
        assert 2 <= len(mesh.triangles) <= goal["max_triangles"]
    assert math.isfinite(mesh.max_error)


def test_data_dependent_tin_meets_error(data_dir):
    """Algorithm IV meets the request with an exact error on Crater Lake."""
    terrain = crop(at.open_terrain(data_file(data_dir, "scape/crater.stm")), 200, 200)
    mesh = approximate(terrain, "tin", max_error=10.0, data_dependent=True)
    expected = brute_force_error(terrain, terrain.domain, mesh.vertices, mesh.triangles)
    assert mesh.max_error == pytest.approx(expected, abs=1e-6 * (1 + expected))
    assert mesh.max_error <= 10.0
    check_mesh(mesh.vertices, mesh.triangles, terrain.domain)


@pytest.mark.parametrize("strategy", STRATS)
def test_nodata_holes_stay_out_of_the_mesh(data_dir, strategy):
    """On Mount St Helens (nodata) no drawn triangle covers a hole and the error is exact."""
    terrain = at.open_terrain(data_file(data_dir, "edge/SainteHelens.dem"))
    terrain = crop(terrain, 200, 200)
    assert terrain.nodata_count > 0
    mesh = approximate(terrain, strategy, max_error=20.0)
    assert np.isfinite(mesh.vertices[:, 2]).all()
    expected = brute_force_error(terrain, terrain.domain, mesh.vertices, mesh.triangles)
    assert mesh.max_error == pytest.approx(expected, abs=1e-6 * (1 + expected))
    assert mesh.max_error <= 20.0
    # Nodata cells lie in no drawn triangle: their centres interpolate to nothing.
    from matplotlib.tri import Triangulation

    rr, cc = np.nonzero(np.isnan(terrain.heights))
    x, y = terrain.x_coords[cc], terrain.y_coords[rr]
    finder = Triangulation(mesh.vertices[:, 0], mesh.vertices[:, 1], mesh.triangles)
    assert (finder.get_trifinder()(x, y) == -1).all()


def test_tin_on_scattered_points_measures_error_at_the_points():
    """On a TINPointSet the reported error equals the error at the input points."""
    rng = np.random.default_rng(8)
    xy = rng.uniform(0, 100, (400, 2))
    z = np.sin(xy[:, 0] / 15) * 20 + xy[:, 1] * 0.3
    terrain = at.TINPointSet(np.column_stack([xy, z]))
    mesh = approximate(terrain, "tin", max_error=0.5)
    expected = brute_force_error(terrain, terrain.domain, mesh.vertices, mesh.triangles)
    assert mesh.max_error == pytest.approx(expected, abs=1e-9)
    assert mesh.max_error <= 0.5 and len(mesh.vertices) < 400


@pytest.mark.parametrize("policy", ["tin", "rtin"])
def test_trees_with_each_policy_satisfy_invariants_and_exact_errors(data_dir, policy):
    """Trees built with each strategy keep the tree invariants; stored errors equal brute force."""
    terrain = crop(at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif")), 200, 240)
    tree = ApproximationTree.build(terrain, epsilon=1.0, max_points=17 * 17, policy=policy)
    assert len(tree) > 1 and set(tree.strategy_names) == {policy}
    check_invariants(tree, 1.0)
    for i in range(0, len(tree), max(1, len(tree) // 60)):
        node = tree.node(i)
        expected = brute_force_error(terrain, node.rect, node.patch.vertices, node.patch.triangles)
        assert node.error == pytest.approx(expected, abs=1e-6 * (1 + expected))
        # Border vertices are data points of the node's rectangle.
        assert node.rect.contains(node.patch.vertices[:, 0], node.patch.vertices[:, 1]).all()


def test_auto_policy_picks_tin_for_point_sets():
    """policy='auto' builds point-set trees with the tin strategy (grid for grids)."""
    rng = np.random.default_rng(9)
    pts = np.column_stack([rng.uniform(0, 50, (300, 2)), rng.uniform(0, 5, 300)])
    tree = ApproximationTree.build(at.TINPointSet(pts), epsilon=0.5, max_points=64)
    assert tree.strategy_names == ["tin"]
    assert np.isfinite(tree.errors[tree.leaves]).all()


@pytest.mark.parametrize("policy", ["tin", "rtin"])
def test_patch_records_round_trip_exactly(tmp_path, policy):
    """save → load gives identical patch vertices, triangles and errors."""
    terrain = fractal_terrain(65, 80, seed=10, relief=200.0)
    tree = ApproximationTree.build(terrain, epsilon=2.0, max_points=81, policy=policy)
    tree.save(tmp_path / "t.zarr")
    back = ApproximationTree.load(tmp_path / "t.zarr")
    for i in range(len(tree)):
        a, b = tree.node(i).patch, back.node(i).patch
        assert a.error == b.error and a.kind == b.kind == policy
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.triangles, b.triangles)


def test_registry_lists_every_strategy():
    """The tree knows the strategies by the names the CLI uses."""
    assert {"grid", "tin", "rtin"} <= set(STRATEGIES)


def _has_t_junction(vertices: np.ndarray, triangles: np.ndarray) -> bool:
    """True when some vertex lies inside an edge (exact, on the integer lattice of a grid)."""
    v = vertices[:, :2]
    edges = np.unique(
        np.sort(np.concatenate([triangles[:, [k, (k + 1) % 3]] for k in range(3)]), axis=1), axis=0
    )
    a, b = v[edges[:, 0]], v[edges[:, 1]]
    for p in v:
        cross = (b[:, 0] - a[:, 0]) * (p[1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (p[0] - a[:, 0])
        dot = (p[0] - a[:, 0]) * (b[:, 0] - a[:, 0]) + (p[1] - a[:, 1]) * (b[:, 1] - a[:, 1])
        length2 = (b[:, 0] - a[:, 0]) ** 2 + (b[:, 1] - a[:, 1]) ** 2
        if ((np.abs(cross) < 1e-9 * length2) & (dot > 0) & (dot < length2)).any():
            return True
    return False


@pytest.mark.parametrize("shape", [(129, 129), (120, 90)])
def test_rtin_triangle_budget_greedy_refinement(shape):
    """Greedy RTIN under a triangle budget: never over budget, conforming, exact error, and
    the error never grows with the budget (each mesh refines the previous one)."""
    terrain = fractal_terrain(*shape, seed=11, relief=300.0)
    errors = []
    for budget in (800, 1500, 3000, 6000):
        mesh = approximate(terrain, "rtin", max_triangles=budget)
        assert len(mesh.triangles) <= budget
        # The budget is used: one more forced split chain would not have fitted.
        assert len(mesh.triangles) >= budget - 40
        expected = brute_force_error(terrain, terrain.domain, mesh.vertices, mesh.triangles)
        assert mesh.max_error == pytest.approx(expected, abs=1e-6 * (1 + expected))
        check_mesh(mesh.vertices, mesh.triangles, terrain.domain)
        # Unit cells: vertices are grid points, so any T-junction is found exactly.
        ij = mesh.patch.ij[:, ::-1].astype(np.float64)
        assert not _has_t_junction(ij, mesh.patch.tris.astype(np.int64))
        errors.append(mesh.max_error)
    assert np.all(np.diff(errors) <= 0) and errors[-1] < errors[0]


def test_rtin_greedy_budget_beats_the_threshold_mesh_it_matches():
    """At the true error the greedy mesh reaches, a threshold extraction needs no fewer
    triangles (refinement by badness spends the budget where the error is)."""
    terrain = fractal_terrain(257, seed=12, relief=500.0)
    greedy = approximate(terrain, "rtin", max_triangles=5000)
    by_error = approximate(terrain, "rtin", max_error=greedy.max_error)
    assert by_error.max_error <= greedy.max_error
    assert len(greedy.triangles) <= len(by_error.triangles)


def test_tin_on_lidar_points_error_is_exact_at_the_input_points(data_dir):
    """Greedy insertion on a LAS point cloud (Autzen, 40 m × 40 m around its median point):
    the reported error is the brute-force max error over the input points, within request."""
    cloud = at.open_terrain(data_file(data_dir, "lidar/autzen_trim.laz"))
    pts = cloud.points()
    x0, y0 = np.median(pts[:, 0]), np.median(pts[:, 1])
    keep = (np.abs(pts[:, 0] - x0) < 20) & (np.abs(pts[:, 1] - y0) < 20)
    terrain = at.TINPointSet(pts[keep])
    assert 300 < len(terrain.points()) < 5000
    mesh = approximate(terrain, "tin", max_error=1.0)
    expected = brute_force_error(terrain, terrain.domain, mesh.vertices, mesh.triangles)
    assert mesh.max_error == pytest.approx(expected, abs=1e-9)
    assert mesh.max_error <= 1.0 and len(mesh.vertices) < len(terrain.points())


def test_tin_delaunay_matches_scipy_on_a_real_dem(data_dir):
    """The Delaunay variant on Crater Lake: every interior edge passes an independent
    in-circle test (exact integers on grid indices), and its error is exact."""
    terrain = crop(at.open_terrain(data_file(data_dir, "scape/crater.stm")), 150, 170)
    mesh = approximate(terrain, "tin", max_error=5.0)
    ij = mesh.patch.ij.astype(np.int64)
    v = np.column_stack([ij[:, 1], ij[:, 0]])
    t = mesh.patch.tris.astype(np.int64)
    opposite = {}
    for tri in t:
        for k in range(3):
            opposite[(int(tri[k]), int(tri[(k + 1) % 3]))] = int(tri[(k + 2) % 3])
    checked = 0
    for (a, b), c in opposite.items():
        d = opposite.get((b, a))
        if d is None:
            continue
        rows = [[*(v[i] - v[d]), int(((v[i] - v[d]) ** 2).sum())] for i in (a, b, c)]
        (p, q, r), (s, u, w), (x, y, z) = rows
        det = p * (u * z - w * y) - q * (s * z - w * x) + r * (s * y - u * x)
        assert det <= 0  # d is not strictly inside the circumcircle of (a, b, c)
        checked += 1
    assert checked > 100
    expected = brute_force_error(terrain, terrain.domain, mesh.vertices, mesh.triangles)
    assert mesh.max_error == pytest.approx(expected, abs=1e-6 * (1 + expected))
