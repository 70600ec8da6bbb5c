"""Trees over a GridRefinement (grid + TIN microstructures): errors against the combined
surface, policies by data semantics, the store and the build command."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely
from click.testing import CliRunner
from conftest import data_file
from helpers import brute_force_error

import approxtree as at
from approxtree import ApproximationTree, GridRefinement, InvalidParameterError
from approxtree.cli import main
from approxtree.datasets import case_study_terrain, fractal_terrain
from approxtree.io.microstructures import corridor_microstructures, read_lines
from approxtree.tree.policy import SemanticPolicy


@pytest.fixture(scope="module")
def refined() -> GridRefinement:
    """A small synthetic case study: 81 × 161 grid with 600 river-bed microstructures."""
    grid, tins = case_study_terrain(seed=4, rows=81, cols=161, microstructures=600)
    return GridRefinement(grid, tins)


def check_errors_against_combined_surface(tree: ApproximationTree, every: int = 1) -> None:
    """Stored ε_T(N) equals brute force over the combined data points of D_N."""
    for i in range(0, len(tree), every):
        node = tree.node(i)
        p = node.patch
        expected = brute_force_error(tree.terrain, node.rect, p.vertices, p.triangles)
        assert node.error == pytest.approx(expected, abs=1e-6 * (1 + expected)), i
        assert p.point_count <= tree.max_points


def test_data_points_are_grid_outside_footprints_plus_microstructure_vertices(refined):
    """points(rect) = grid points outside every footprint + microstructure vertices in rect."""
    g = refined.grid
    d = refined.domain
    rect = at.Rect(d.xmin + 700, d.ymin + 400, d.xmin + 2500, d.ymin + 1300)
    pts = refined.points(rect)
    xx, yy = np.meshgrid(g.x_coords, g.y_coords)
    inside_rect = rect.contains(xx, yy)
    located, _ = refined.combined.locate(xx[inside_rect], yy[inside_rect])
    v = refined.combined.vertices
    n_micro = int(rect.contains(v[:, 0], v[:, 1]).sum())
    assert n_micro > 0 and (located >= 0).any()
    assert len(pts) == int((located < 0).sum()) + n_micro
    # h_T at the data points is their own height: microstructure inside, grid outside.
    np.testing.assert_allclose(refined.height_at(pts[:, 0], pts[:, 1]), pts[:, 2], atol=1e-9)


@pytest.mark.parametrize("policy", ["type", "tin", "auto", "grid"])
def test_every_node_error_is_exact_against_the_combined_surface(refined, policy):
    """Every node's stored error equals brute force against grid + microstructures."""
    tree = ApproximationTree.build(refined, epsilon=1.0, max_points=9 * 9, policy=policy)
    check_errors_against_combined_surface(tree, every=1 if policy != "grid" else 37)
    if policy != "grid":
        assert tree.errors[tree.leaves].max() <= 1.0
    else:
        # A regular grid cannot reproduce the microstructures: leaves stay above ε there.
        assert tree.errors[tree.leaves].max() > 1.0


def test_semantic_policy_counts_match(refined):
    """semantic:tin@2,grid: tin exactly on nodes from level 2 holding microstructure points."""
    tree = ApproximationTree.build(refined, 1.0, 9 * 9, policy="semantic:tin@2,grid")
    expected = np.array(
        [
            "tin"
            if tree.levels[i] >= 2
            and SemanticPolicy.holds_microstructure(refined, tree.node(i).rect)
            else "grid"
            for i in range(len(tree))
        ]
    )
    got = np.array([tree.node(i).strategy for i in range(len(tree))])
    np.testing.assert_array_equal(got, expected)
    assert tree.strategy_counts == {n: int((got == n).sum()) for n in ("grid", "tin")}


def test_refinement_tree_round_trips_through_the_store(refined, tmp_path):
    """save → load keeps the GridRefinement, node strategies, patches and errors."""
    tree = ApproximationTree.build(refined, 1.0, 9 * 9, policy="semantic:tin@1,grid")
    tree.save(tmp_path / "r.zarr")
    back = ApproximationTree.load(tmp_path / "r.zarr")
    assert isinstance(back.terrain, GridRefinement)
    assert back.strategy_counts == tree.strategy_counts
    np.testing.assert_array_equal(back.strategies, tree.strategies)
    for i in range(0, len(tree), 3):
        a, b = tree.node(i).patch, back.node(i).patch
        assert a.error == b.error and a.kind == b.kind
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.triangles, b.triangles)


def test_build_accepts_microstructure_tins_and_rejects_non_grids(refined):
    """build(..., microstructures=[...]) refines a Grid; other terrains are a clear error."""
    tree = ApproximationTree.build(
        refined.grid, 1.0, 9 * 9, microstructures=refined.microstructures[:50]
    )
    assert isinstance(tree.terrain, GridRefinement) and len(tree.terrain.microstructures) == 50
    pts = at.TINPointSet(np.random.default_rng(0).uniform(0, 9, (30, 3)))
    with pytest.raises(InvalidParameterError, match="Grid"):
        ApproximationTree.build(pts, microstructures=refined.microstructures[:1])


def test_cli_build_with_a_line_layer(tmp_path):
    """build --microstructures LINES.geojson builds corridors and reports both strategies."""
    grid = fractal_terrain(65, 97, seed=2, relief=100.0)
    dem = tmp_path / "g.npy"
    np.save(dem, grid.heights)
    d = at.open_terrain(dem).domain
    line = [[d.xmin + 5, d.ymin + 10], [d.xmax - 7, d.ymax - 20]]
    layer = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {},
                "geometry": {"type": "LineString", "coordinates": line},
            }
        ],
    }
    lines = tmp_path / "river.geojson"
    lines.write_text(json.dumps(layer))
    out = tmp_path / "g.zarr"
    args = ["build", str(dem), "--out", str(out), "--epsilon", "0.5", "--max-points", "81"]
    args += ["--microstructures", str(lines), "--microstructure-width", "3", "--json"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    figures = json.loads(result.output)
    tree = ApproximationTree.load(out)
    assert isinstance(tree.terrain, GridRefinement)
    assert figures["strategies"] == tree.strategy_counts
    assert set(figures["strategies"]) == {"grid", "tin"}
    bad = CliRunner().invoke(main, [*args[:6], "--microstructures", str(tmp_path / "none.shp")])
    assert bad.exit_code == 2 and "does not exist" in bad.output


def test_nc_window_with_stream_corridors(data_dir):
    """Real case: a window of the NC DEM with its streams as corridors; errors exact."""
    full = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    grid = at.Grid(full.heights[:90, :120], full.transform, full.crs)
    lines = read_lines(data_file(data_dir, "nc/streams.shp"), grid.crs)
    d = grid.domain
    lines = lines[shapely.intersects(lines, shapely.box(d.xmin, d.ymin, d.xmax, d.ymax))]
    tins = corridor_microstructures(grid, lines, width=30.0, spacing=15.0)
    tree = ApproximationTree.build(GridRefinement(grid, tins), epsilon=1.0, max_points=17 * 17)
    assert set(tree.strategy_counts) <= {"grid", "tin"} and "tin" in tree.strategy_counts
    assert tree.errors[tree.leaves].max() <= 1.0
    check_errors_against_combined_surface(tree, every=max(1, len(tree) // 40))
