"""GeometryData subclasses: domains, data points, h_T and z ranges on small exact cases."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine

from approxtree import (
    TIN,
    EmptyTerrainError,
    Grid,
    GridRefinement,
    NonRegularGrid,
    Rect,
    TerrainFormatError,
    TINPointSet,
)
from approxtree.datasets import fractal_terrain, sample_terrain


def plane(x, y):
    return 3.0 + 0.5 * x - 0.25 * y


def test_grid_points_sit_at_cell_centres():
    """Data points of a north-up grid are the cell centres, row 0 at the top."""
    g = Grid(np.arange(6.0).reshape(2, 3), Affine(10, 0, 100, 0, -10, 500))
    assert g.domain == Rect(105, 485, 125, 495)
    p = g.points()
    assert p[0].tolist() == [105, 495, 0]
    assert p[-1].tolist() == [125, 485, 5]


def test_grid_height_at_reproduces_planes_exactly():
    """Linear interpolation on the triangulated grid is exact on a plane."""
    xs, ys = np.meshgrid(np.arange(7.0) + 0.5, 5.0 - np.arange(5.0) - 0.5)
    g = Grid(plane(xs, ys), Affine(1, 0, 0, 0, -1, 5))
    rng = np.random.default_rng(1)
    qx, qy = rng.uniform(0.5, 6.5, 500), rng.uniform(0.5, 4.5, 500)
    np.testing.assert_allclose(g.height_at(qx, qy), plane(qx, qy), atol=1e-5)


def test_grid_height_at_uses_the_nw_se_diagonal():
    """A cell with one raised corner interpolates along the (r, c)–(r+1, c+1) diagonal."""
    z = np.zeros((2, 2))
    z[0, 1] = 4.0  # north-east corner
    g = Grid(z, Affine(1, 0, 0, 0, -1, 2))
    # Centre of the cell lies on the diagonal NW–SE, whose ends are both 0.
    assert g.height_at(np.array(1.0), np.array(1.0)) == 0.0
    # Midway along the north edge: half the raised corner.
    assert g.height_at(np.array(1.0), np.array(1.5)) == pytest.approx(2.0)


def test_grid_nodata_is_never_a_data_point():
    """NaN cells are left out of points() and make h_T NaN in the triangles they touch."""
    z = np.ones((3, 3))
    z[1, 1] = np.nan
    g = Grid(z)
    assert g.point_count == 8 and g.nodata_count == 1
    assert not np.isnan(g.points()[:, 2]).any()
    assert np.isnan(g.height_at(np.array(1.5), np.array(1.5)))


def test_grid_rejects_degenerate_input():
    """1 × N, all-NaN and rotated grids raise specific errors."""
    with pytest.raises(EmptyTerrainError, match="2 × 2"):
        Grid(np.ones((1, 10)))
    with pytest.raises(EmptyTerrainError, match="no valid elevation"):
        Grid(np.full((4, 4), np.nan))
    with pytest.raises(TerrainFormatError, match="Rotated"):
        Grid(np.ones((3, 3)), Affine(1, 0.1, 0, 0, -1, 3))


def test_grid_index_range_includes_border_points():
    """index_range of a rect spanned by data points includes the points on its border."""
    g = fractal_terrain(65, 33, seed=3)
    rect = g.rect_of(10, 20, 5, 30)
    assert g.index_range(rect) == (10, 20, 5, 30)
    assert len(g.points(rect)) == 11 * 26


def test_nonregular_grid_interpolates_planes():
    """NonRegularGrid h_T is exact on a plane with irregular rows and columns."""
    xs = np.array([0.0, 0.3, 1.7, 2.0, 5.0])
    ys = np.array([4.0, 2.5, 1.0, 0.0])
    xx, yy = np.meshgrid(xs, ys)
    g = NonRegularGrid(xs, ys, plane(xx, yy))
    rng = np.random.default_rng(2)
    qx, qy = rng.uniform(0, 5, 300), rng.uniform(0, 4, 300)
    np.testing.assert_allclose(g.height_at(qx, qy), plane(qx, qy), atol=1e-12)
    assert g.domain == Rect(0, 0, 5, 4)
    assert np.isnan(g.height_at(np.array(6.0), np.array(1.0)))


def test_tin_interpolates_and_is_nan_outside():
    """TIN h_T is linear in each triangle and NaN outside the triangles."""
    v = np.array([[0, 0, 0], [2, 0, 2], [0, 2, 4], [2, 2, 6]], dtype=float)
    t = TIN(v, np.array([[0, 1, 3], [0, 3, 2]]))
    assert t.height_at(np.array(1.0), np.array(1.0)) == pytest.approx(3.0)
    assert t.height_at(np.array(2.0), np.array(0.0)) == pytest.approx(2.0)
    assert np.isnan(t.height_at(np.array(3.0), np.array(1.0)))


def test_tin_rejects_bad_indices():
    """Triangle indices out of range are a TerrainFormatError."""
    with pytest.raises(TerrainFormatError, match="indices"):
        TIN(np.zeros((3, 3)), np.array([[0, 1, 5]]))


def test_tinpointset_matches_scipy_interpolation():
    """TINPointSet's h_T equals scipy's LinearNDInterpolator on the same Delaunay TIN."""
    from scipy.interpolate import LinearNDInterpolator

    rng = np.random.default_rng(4)
    p = rng.uniform(0, 100, (2000, 3))
    s = TINPointSet(p)
    q = rng.uniform(0, 100, (1000, 2))
    ref = LinearNDInterpolator(p[:, :2], p[:, 2])(q)
    np.testing.assert_allclose(s.height_at(q[:, 0], q[:, 1]), ref, atol=1e-9, equal_nan=True)


def test_tinpointset_merges_duplicate_positions():
    """Points sharing (x, y) become one data point at their mean height."""
    p = np.array([[0, 0, 1], [0, 0, 3], [1, 0, 0], [0, 1, 0]], dtype=float)
    s = TINPointSet(p)
    assert s.point_count == 3 and s.duplicates_merged == 1
    assert s.height_at(np.array(0.0), np.array(0.0)) == pytest.approx(2.0)


def test_grid_refinement_uses_microstructure_inside_its_footprint():
    """GridRefinement h_T is the TIN inside the footprint and the grid elsewhere."""
    g = Grid(np.zeros((11, 11)), Affine(1, 0, 0, 0, -1, 11))
    v = np.array([[2, 2, -5], [6, 2, -5], [2, 6, -5], [6, 6, -5]], dtype=float)
    micro = TIN(v, np.array([[0, 1, 3], [0, 3, 2]]))
    r = GridRefinement(g, [micro])
    assert r.height_at(np.array(4.0), np.array(4.0)) == -5.0
    assert r.height_at(np.array(8.5), np.array(8.5)) == 0.0
    # Grid points inside the footprint give way to the microstructure vertices.
    inside = (g.x_coords[None, :] >= 2) & (g.x_coords[None, :] <= 6)
    inside = inside & (g.y_coords[:, None] >= 2) & (g.y_coords[:, None] <= 6)
    assert r.point_count == 121 - int(inside.sum()) + 4
    assert r.z_range == (-5.0, 0.0)


def test_sample_terrain_is_north_up_jacksboro():
    """The bundled sample DEM is 344 × 403, 3″ cells, north-up despite its swapped bounds."""
    g = sample_terrain()
    assert g.shape == (344, 403)
    assert g.cell_size == pytest.approx((1 / 1200, 1 / 1200))
    assert g.y_coords[0] > g.y_coords[-1]
    assert g.domain.ymin == pytest.approx(36.44625 + 1 / 2400)
    assert g.crs == "EPSG:4326"


def test_fractal_terrain_is_seeded_and_any_size():
    """Same seed → same heights; any size; heights span [0, relief]."""
    a = fractal_terrain(37, 51, seed=7, relief=250.0)
    b = fractal_terrain(37, 51, seed=7, relief=250.0)
    c = fractal_terrain(37, 51, seed=8, relief=250.0)
    assert a.shape == (37, 51)
    np.testing.assert_array_equal(a.heights, b.heights)
    assert not np.array_equal(a.heights, c.heights)
    assert a.z_range == pytest.approx((0.0, 250.0), abs=1e-3)
