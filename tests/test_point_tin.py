"""Point clouds as terrain: greedy TINs over scattered points and point-set trees.

Every stored error is recomputed independently (matplotlib's linear interpolation on the
patch's own triangles at the node's data points) and must agree to ~1e-9; every leaf is within
ε; meshes are valid (counter-clockwise, exact rational orientation) and cover every point.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from conftest import data_file
from matplotlib.tri import LinearTriInterpolator, Triangulation
from scipy.spatial import Delaunay

import approxtree as at
from approxtree import ApproximationTree
from approxtree.patches.tin_points import greedy_points


def interpolate(vertices: np.ndarray, triangles: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Linear height of the mesh at q (k, 2); inf outside every triangle (matplotlib)."""
    o = vertices[:, :2].min(axis=0)
    tri = Triangulation(vertices[:, 0] - o[0], vertices[:, 1] - o[1], triangles)
    z = LinearTriInterpolator(tri, vertices[:, 2])(q[:, 0] - o[0], q[:, 1] - o[1])
    return np.ma.filled(z.astype(np.float64), np.inf)


def true_error(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> float:
    """max |z − h_mesh| over the data points (n, 3); inf when one is not covered."""
    if len(points) == 0:
        return 0.0
    return float(np.max(np.abs(points[:, 2] - interpolate(vertices, triangles, points[:, :2]))))


def check_tree(terrain: at.TINPointSet, tree: ApproximationTree, epsilon: float) -> None:
    """Every node's stored error equals the recomputed maximum; leaves are within ε."""
    for node in tree.nodes():
        points = terrain.points(node.rect)
        patch = node.patch
        expected = true_error(points, patch.vertices, patch.triangles)
        assert node.error == pytest.approx(expected, abs=1e-9), (node.index, len(points))
        assert patch.data_count == len(points)
        assert patch.point_count <= tree.max_points or len(patch.triangles) == 0
    assert (tree.errors[tree.leaves] <= epsilon).all()


def scattered_cloud(seed: int, n: int = 500, offset: float = 6.0e5) -> np.ndarray:
    """(n + ..., 3) rough terrain far from the origin with near-coincident pairs (1e-4 apart,
    5 m higher: multiple returns) and exact duplicate positions."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 100.0, (n, 2))
    z = 10 * np.sin(xy[:, 0] / 9) * np.cos(xy[:, 1] / 13) + rng.normal(0.0, 0.3, n)
    near = xy[: n // 5] + rng.normal(0.0, 1e-4, (n // 5, 2))
    dup = xy[n // 5 : n // 5 + n // 10]
    pts = np.vstack(
        [
            np.column_stack([xy, z]),
            np.column_stack([near, z[: n // 5] + 5.0]),
            np.column_stack([dup, z[n // 5 : n // 5 + n // 10] - 2.0]),
        ]
    )
    pts[:, :2] += offset
    return pts


def exact_error(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> float:
    """max |z − h_mesh| over the points, located and interpolated in exact rational arithmetic
    (inf when a point lies in no triangle): the reference for near-degenerate meshes, where
    float interpolation of slivers is itself inexact."""
    fv = [[Fraction(float(c)) for c in row] for row in vertices]
    lo = vertices[triangles, :2].min(axis=1)
    hi = vertices[triangles, :2].max(axis=1)
    worst = Fraction(0)
    for x, y, z in points:
        near = np.flatnonzero((lo[:, 0] <= x) & (x <= hi[:, 0]) & (lo[:, 1] <= y) & (y <= hi[:, 1]))
        px, py = Fraction(float(x)), Fraction(float(y))
        for t in near:
            (ax, ay, az), (bx, by, bz), (cx, cy, cz) = (fv[i] for i in triangles[t])
            d = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
            wb = ((px - ax) * (cy - ay) - (py - ay) * (cx - ax)) / d
            wc = ((bx - ax) * (py - ay) - (by - ay) * (px - ax)) / d
            if wb >= 0 and wc >= 0 and wb + wc <= 1:
                worst = max(worst, abs(Fraction(float(z)) - (az + wb * (bz - az) + wc * (cz - az))))
                break
        else:
            return float("inf")
    return float(worst)


def ccw_exact(vertices: np.ndarray, triangles: np.ndarray) -> bool:
    """Every triangle strictly counter-clockwise, decided in exact rational arithmetic."""
    for a, b, c in triangles:
        ax, ay = (Fraction(float(v)) for v in vertices[a, :2])
        bx, by = (Fraction(float(v)) for v in vertices[b, :2])
        cx, cy = (Fraction(float(v)) for v in vertices[c, :2])
        if (bx - ax) * (cy - ay) - (by - ay) * (cx - ax) <= 0:
            return False
    return True


# -- point-set trees: stored error == true error -------------------------------------------------


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_point_set_tree_errors_are_true_errors_with_near_duplicates(seed):
    """Near-coincident points far from the origin (where Qhull dropped chosen vertices and the
    old patch called their error 0): every node's error is the true maximum."""
    terrain = at.TINPointSet(scattered_cloud(seed))
    tree = ApproximationTree.build(terrain, epsilon=0.5, max_points=64)
    assert len(tree) > 1
    check_tree(terrain, tree, 0.5)


def test_point_set_terrain_keeps_every_point_a_vertex():
    """h_T of a TINPointSet passes through every data point, near-coincident ones included."""
    terrain = at.TINPointSet(scattered_cloud(4))
    assert len(np.unique(terrain.triangles)) == terrain.point_count
    v = terrain.vertices
    np.testing.assert_allclose(terrain.height_at(v[:, 0], v[:, 1]), v[:, 2], atol=1e-9)


@pytest.mark.parametrize(("ground", "side"), [(False, 120.0), (True, 400.0), (True, 0.0)])
def test_autzen_point_set_trees_have_exact_errors(data_dir, ground, side):
    """Lidar (all returns or ground only, crops and the whole ground set): stored == true."""
    from approxtree.io.pointcloud import read_point_cloud

    cloud = read_point_cloud(data_file(data_dir, "lidar/autzen_trim.laz"), ground_only=ground)
    p = cloud.vertices
    if side > 0:
        c = np.median(p[:, :2], axis=0)
        p = p[(np.abs(p[:, :2] - c) <= side / 2).all(axis=1)]
    terrain = at.TINPointSet(p)
    for epsilon, max_points, fanout in [(1.0, 33 * 33, 4), (0.5, 25, 2)]:
        tree = ApproximationTree.build(
            terrain, epsilon=epsilon, max_points=max_points, fanout=fanout
        )
        check_tree(terrain, tree, epsilon)


# -- the greedy kernel -------------------------------------------------------------------------


def test_duplicate_positions_count_with_their_true_error():
    """Raw points with duplicate positions: one vertex per position, and the error is the true
    maximum over all points, duplicates included (so it cannot drop below their spread)."""
    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 50, (300, 2))
    z = xy[:, 0] * 0.2 + np.sin(xy[:, 1] / 5)
    pts = np.vstack([np.column_stack([xy, z]), np.column_stack([xy[:40], z[:40] + 3.0])])
    for max_error in (0.0, 0.5):
        chosen, tris, worst, sse = greedy_points(pts[:, :2], pts[:, 2], max_error, 0)
        v = pts[chosen]
        assert len(np.unique(v[:, :2], axis=0)) == len(v)
        err = np.abs(pts[:, 2] - interpolate(v, tris, pts[:, :2]))
        assert worst == pytest.approx(err.max(), abs=1e-9)
        assert sse == pytest.approx(np.sum(err**2), rel=1e-9)
        # The 40 doubled positions differ by 3: whichever is the vertex, the other is 3 off.
        assert worst == pytest.approx(3.0, abs=1e-9)


def test_full_insertion_is_the_delaunay_triangulation():
    """max_error < 0 inserts every point; Delaunay by flips gives scipy's (unique) Delaunay."""
    rng = np.random.default_rng(5)
    pts = rng.uniform(0, 1000, (3000, 3)) + np.array([6.0e5, 8.0e5, 0.0])
    chosen, tris, worst, _ = greedy_points(pts[:, :2], pts[:, 2], -1.0, 0)
    assert len(chosen) == 3000 and worst == 0.0
    ours = {tuple(sorted(t)) for t in chosen[tris].tolist()}
    theirs = {tuple(sorted(t)) for t in Delaunay(pts[:, :2]).simplices.tolist()}
    assert ours == theirs


@pytest.mark.parametrize("case", ["collinear", "near-collinear", "lattice", "two-lines"])
def test_degenerate_inputs_give_valid_meshes_and_exact_errors(case):
    """Collinear, nearly collinear, cocircular (lattice) input: a valid counter-clockwise mesh
    (exact arithmetic) covering every point, with the true maximum error."""
    rng = np.random.default_rng(6)
    if case == "collinear":
        # Exactly collinear (every coordinate representable), in random order.
        k = rng.permutation(200).astype(np.float64)
        pts = np.column_stack([6.0e5 + 1.5 * k, 8.0e5 + k, rng.normal(0, 1, 200)])
    elif case == "near-collinear":
        t = np.sort(rng.uniform(0, 1, 200))
        pts = np.column_stack([6.0e5 + t, 8.0e5 + t, rng.normal(0, 1, 200)])
        pts[::7, 1] += 1e-9
    elif case == "lattice":
        g = np.arange(25.0)
        x, y = np.meshgrid(g, g)
        pts = np.column_stack([x.ravel(), y.ravel(), np.hypot(x - 12, y - 12).ravel() ** 1.5])
    else:
        t = rng.uniform(0, 100, 150)
        pts = np.vstack(
            [np.column_stack([t, 0.5 * t, np.sin(t)]), np.column_stack([t, 0.5 * t + 1e-7, t])]
        )
    for max_error in (-1.0, 0.0, 0.3):
        chosen, tris, worst, _ = greedy_points(pts[:, :2], pts[:, 2], max_error, 0)
        v = pts[chosen]
        if case == "collinear":
            # No area to triangulate: every point is a vertex, nothing is approximated.
            assert len(tris) == 0 and len(chosen) == len(pts) and worst == 0.0
            continue
        assert len(tris) > 0 and ccw_exact(v, tris)
        assert worst == pytest.approx(exact_error(pts, v, tris), abs=1e-9)
        assert worst <= max(max_error, 0.0) + 1e-12


def test_point_budget_and_hull():
    """max_points bounds the vertices (the hull is always in); the mesh covers every point."""
    rng = np.random.default_rng(7)
    pts = rng.uniform(0, 100, (2000, 3))
    chosen, tris, worst, _ = greedy_points(pts[:, :2], pts[:, 2], 0.0, 50)
    assert len(chosen) == 50
    err = np.abs(pts[:, 2] - interpolate(pts[chosen], tris, pts[:, :2]))
    assert worst == pytest.approx(err.max(), abs=1e-9)


def test_random_degenerate_inputs_stay_valid_and_exact():
    """Small random inputs full of duplicates, collinear runs and tiny spreads far from the
    origin, with every stopping rule: valid meshes, exact errors, budgets kept."""
    rng = np.random.default_rng(123)
    for case in range(80):
        n = int(rng.integers(1, 40))
        kind = case % 4
        if kind == 0:
            xy = rng.integers(0, 5, (n, 2)).astype(np.float64)
        elif kind == 1:
            xy = rng.uniform(0, 1, (n, 2)) * 1e-6 + 6.0e5
        elif kind == 2:
            t = rng.uniform(0, 1, n)
            xy = np.column_stack([t, 0.5 * t]) + rng.normal(0, 1e-12, (n, 2))
        else:
            xy = rng.uniform(-1, 1, (n, 2))
            xy[: n // 2] = xy[0]
        pts = np.column_stack([xy, rng.normal(0, 1, n)])
        max_error = float(rng.choice([-1.0, 0.0, 0.5]))
        max_points = int(rng.choice([0, 4, 10]))
        chosen, tris, worst, _ = greedy_points(xy, pts[:, 2], max_error, max_points)
        if max_points:
            assert len(chosen) <= max_points or len(tris) == 0
        if len(tris) == 0:
            continue
        v = pts[chosen]
        assert ccw_exact(v, tris)
        expected = exact_error(pts, v, tris)
        assert worst == expected or worst == pytest.approx(expected, abs=1e-9)


def test_points_at_absurd_coordinates_are_refused_not_triangulated():
    """Coordinates near 1e293 (a corrupt LAS scale) overflowed the in-circle predicate: the
    triangulation ran off its arrays (IndexError under bounds checks, an abort without)."""
    from approxtree.errors import TerrainFormatError
    from approxtree.geometry.tin import TINPointSet

    rng = np.random.default_rng(3)
    points = rng.uniform(-1.7e293, 1.7e293, size=(200, 3))
    with pytest.raises(TerrainFormatError, match="scale factors or offsets"):
        TINPointSet(points)


def test_gap_fill_points_fill_holes_and_corners_only():
    """gap_fill_points: a cloud with a square hole and a missing corner gets lattice points in
    them (at the mean height of their 4 nearest points), none where the cloud is dense, and
    the cloud with them covers its whole bounding rectangle."""
    from approxtree.geometry.tin import gap_fill_points

    rng = np.random.default_rng(0)
    xy = rng.uniform(0.0, 100.0, (20000, 2))
    hole = (np.abs(xy - 50.0) < 15.0).all(axis=1) | ((xy[:, 0] > 85) & (xy[:, 1] > 85))
    xy = xy[~hole]
    points = np.column_stack([xy, 0.1 * xy[:, 0]])
    filled = gap_fill_points(points, cells=32)
    assert len(filled) > 0
    in_hole = (np.abs(filled[:, :2] - 50.0) < 15.0).all(axis=1)
    in_corner = (filled[:, 0] > 85) & (filled[:, 1] > 85)
    assert (in_hole | in_corner).all()
    assert in_hole.sum() >= 9 and in_corner.any()
    # Heights come from the nearest data points: within the plane's range nearby.
    assert np.abs(filled[:, 2] - 0.1 * filled[:, 0]).max() < 3.0
    assert len(gap_fill_points(points, cells=1)) == 0
