"""TIN microstructures: corridors along the NC streams and the paper-scale synthetic case."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from conftest import data_file

import approxtree as at
from approxtree import EmptyTerrainError, GridRefinement, InvalidParameterError
from approxtree.datasets import case_study_terrain, fractal_terrain
from approxtree.io.microstructures import corridor_microstructures, load_microstructures, read_lines


@pytest.fixture(scope="module")
def nc(data_dir):
    """The NC DEM with one incised corridor microstructure per stream (30 m wide, 15 m samples)."""
    grid = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    streams = data_file(data_dir, "nc/streams.shp")
    lines = read_lines(streams, grid.crs)
    return grid, lines, load_microstructures(streams, grid, width=30.0, depth=2.0, spacing=15.0)


def test_nc_streams_become_non_overlapping_microstructures(nc):
    """Most of the 8,294 streams own a TIN; TIN footprints do not overlap."""
    _, lines, tins = nc
    # Six of the 8,294 features carry no geometry.
    assert len(lines) == 8288
    assert 7500 < len(tins) <= 8288
    polys = [
        shapely.union_all(shapely.polygons(t.vertices[t.triangles][..., :2])) for t in tins[:300]
    ]
    total = sum(p.area for p in polys)
    assert shapely.union_all(polys).area == pytest.approx(total, rel=1e-6)


def test_combined_surface_is_microstructure_inside_and_grid_outside(nc):
    """h_T of the GridRefinement equals the TIN inside footprints and the grid elsewhere."""
    grid, _, tins = nc
    refined = GridRefinement(grid, tins)
    rng = np.random.default_rng(1)
    t = tins[17]
    bary = rng.dirichlet(np.ones(3), len(t.triangles))
    inside = (t.vertices[t.triangles][..., :2] * bary[..., None]).sum(axis=1)
    np.testing.assert_allclose(
        refined.height_at(inside[:, 0], inside[:, 1]),
        t.height_at(inside[:, 0], inside[:, 1]),
        atol=1e-9,
    )
    d = grid.domain
    q = rng.uniform([d.xmin, d.ymin], [d.xmax, d.ymax], (2000, 2))
    located, _ = refined.combined.locate(q[:, 0], q[:, 1])
    outside = located < 0
    np.testing.assert_array_equal(
        refined.height_at(q[outside, 0], q[outside, 1]),
        grid.height_at(q[outside, 0], q[outside, 1]),
    )
    assert outside.mean() > 0.5


def test_incised_profile_deepens_towards_the_centre_line():
    """An incised corridor is depth below the grid at its centre line and meets it at its edge."""
    grid = at.Grid(np.full((41, 41), 100.0))
    line = shapely.linestrings([[5.0, 20.5], [35.0, 20.5]])
    (tin,) = corridor_microstructures(grid, [line], width=6.0, spacing=0.5, depth=2.0)
    v = tin.vertices
    on_line = np.abs(v[:, 1] - 20.5) < 1e-9
    inner = on_line & (v[:, 0] > 6) & (v[:, 0] < 34)
    np.testing.assert_allclose(v[inner, 2], 98.0)
    edge = np.abs(shapely.distance(shapely.points(v[:, :2]), line) - 3.0) < 1e-9
    np.testing.assert_allclose(v[edge, 2], 100.0)


def test_paper_scale_case_study_has_the_papers_figures():
    """641 × 321 grid, 20,652 microstructures, about 500,000 triangles in the full model."""
    grid, tins = case_study_terrain(seed=0)
    assert grid.shape == (321, 641)
    assert len(tins) == 20_652
    refined = GridRefinement(grid, tins)
    out = refined.grid_outside
    grid_triangles = 2 * int((out[:-1, :-1] & out[1:, :-1] & out[:-1, 1:] & out[1:, 1:]).sum())
    total = grid_triangles + sum(len(t.triangles) for t in tins)
    assert 450_000 <= total <= 550_000


def test_bad_corridor_requests(tmp_path):
    """Unknown profiles, zero width, lines off the grid and non-TIN files are clear errors."""
    grid = fractal_terrain(20)
    line = shapely.linestrings([[0.0, 0.0], [50.0, 50.0]])
    with pytest.raises(InvalidParameterError, match="profile"):
        corridor_microstructures(grid, [line], width=5.0, profile="wavy")
    with pytest.raises(InvalidParameterError, match="width"):
        corridor_microstructures(grid, [line], width=0.0)
    far = shapely.linestrings([[1e6, 1e6], [1e6 + 10, 1e6]])
    with pytest.raises(EmptyTerrainError, match="domain"):
        corridor_microstructures(grid, [far], width=5.0)
    np.save(tmp_path / "g.npy", np.ones((5, 5)))
    with pytest.raises(at.TerrainFormatError, match="not a TIN"):
        load_microstructures(tmp_path / "g.npy", grid)
