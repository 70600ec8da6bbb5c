"""Every command that takes a terrain takes every kind of one, through the CLI.

render and tiles --format 3dtiles draw or tile a saved tree, or any terrain file (raster DEM,
point cloud, TIN) built into a tree in memory with the build options (--epsilon, ...); the
result equals `build FILE` followed by the same command on the store, pixel for pixel and
byte for byte. Reader options apply to a terrain file and are refused for a saved tree, as
build options are. bake, mesh and rd take a tree store's terrain.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file
from PIL import Image

from approxtree.cli import main

#: Terrains of each kind: (id, file under ../shared/data, reader options).
KINDS = [
    ("dem", "nc/elev_ned_30m.tif", ()),
    ("laz", "lidar/autzen_trim.laz", ("--ground-only",)),
    ("terrain", "tin/9_533_383.terrain", ()),
]

#: Every raster kind of ../shared/data: (file, reader options, ε of the tree built).
RASTERS = [
    ("nc/elev_ned_30m.tif", (), 2.0),
    ("srtm/N44W072.hgt", (), 50.0),
    ("srtm/N22W160v2.3a.hgt.zip", (), 50.0),
    ("edge/hugo_site.asc", (), 1.0),
    ("edge/SainteHelens.dem", (), 20.0),
    ("scape/crater.stm", ("--cell-size", "30"), 20.0),
    ("scape/crater.pgm", ("--cell-size", "30"), 20.0),
    ("edge/jacksboro_fault_dem.npz", ("--crs", "EPSG:4326"), 20.0),
]


def run(*args: object) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of the CLI run in-process."""
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def run_json(*args: object) -> dict:
    code, out, err = run(*args, "--json")
    assert code == 0, err
    return json.loads(out)


def render_png(source: object, png: Path, *options: object) -> tuple[dict, np.ndarray]:
    """(stats, RGBA image (h, w, 4)) of `render SOURCE` over a transparent background."""
    stats = run_json(
        "render", source, "--out", png, "--size", "96x72", "--background", "transparent", *options
    )
    return stats, np.asarray(Image.open(png))


def folder_bytes(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` by its relative path."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def store(data_dir, tmp_path_factory) -> Path:
    """A tree store of the North Carolina DEM (`approxtree build`)."""
    out = tmp_path_factory.mktemp("store") / "nc.zarr"
    run_json("build", data_file(data_dir, "nc/elev_ned_30m.tif"), "--out", out, "-q")
    return out


@pytest.mark.parametrize(("kind", "name", "options"), KINDS, ids=[k[0] for k in KINDS])
def test_render_draws_a_terrain_file_of_each_kind(data_dir, tmp_path, kind, name, options):
    """render takes a DEM, a point cloud and a TIN file, not only a tree store."""
    stats, image = render_png(data_file(data_dir, name), tmp_path / "f.png", *options)
    assert stats["triangles"] > 0 and stats["empty"] is False
    assert (image[..., 3] > 0).mean() > 0.05


@pytest.mark.parametrize(("name", "options", "epsilon"), RASTERS, ids=[r[0] for r in RASTERS])
def test_render_draws_every_raster_kind(data_dir, tmp_path, name, options, epsilon):
    """render draws every raster format of the shared data, read and built in memory."""
    stats, image = render_png(
        data_file(data_dir, name), tmp_path / "f.png", *options, "--epsilon", epsilon
    )
    assert stats["empty"] is False
    assert (image[..., 3] > 0).mean() > 0.05


def test_render_of_a_dem_equals_build_then_render(data_dir, tmp_path):
    """`render DEM` with build options draws the very image of `build DEM` + `render STORE`
    with the same options, and the options reach the build (the default tree differs)."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    options = ("--epsilon", "2", "--max-points", "289", "--fanout", "2", "--policy", "grid")
    out = tmp_path / "nc.zarr"
    run_json("build", dem, *options, "--out", out, "-q")
    from_store, stored = render_png(out, tmp_path / "store.png")
    from_file, direct = render_png(dem, tmp_path / "file.png", *options)
    assert np.array_equal(direct, stored)
    assert from_file["triangles"] == from_store["triangles"]
    default, _ = render_png(dem, tmp_path / "default.png")
    assert default["triangles"] != from_file["triangles"]


@pytest.mark.parametrize(("kind", "name", "options"), KINDS, ids=[k[0] for k in KINDS])
def test_3dtiles_of_a_terrain_file_equal_those_of_its_store(
    data_dir, tmp_path, kind, name, options
):
    """tiles --format 3dtiles takes a DEM, a point cloud and a TIN file and writes the same
    tileset, byte for byte, as `build FILE` + `tiles STORE` with the same options."""
    source = data_file(data_dir, name)
    build = (*options, "--epsilon", "2")
    direct = run_json("tiles", source, *build, "--out", tmp_path / "a", "--format", "3dtiles")
    run_json("build", source, *build, "--out", tmp_path / "t.zarr", "-q")
    stored = run_json("tiles", tmp_path / "t.zarr", "--out", tmp_path / "b", "--format", "3dtiles")
    assert direct["tiles"] == stored["tiles"] >= 1
    assert folder_bytes(tmp_path / "a") == folder_bytes(tmp_path / "b")


def test_reader_options_apply_to_a_file_and_are_refused_for_a_store(data_dir, store, tmp_path):
    """--nodata reaches the reader of a DEM given to render (fill closes the holes the mask
    leaves: more terrain drawn), and render or tiles of a tree store refuse it in one line."""
    asc = data_file(data_dir, "edge/hugo_site.asc")
    _, masked = render_png(asc, tmp_path / "m.png")
    _, filled = render_png(asc, tmp_path / "f.png", "--nodata", "fill")
    assert (filled[..., 3] > 0).sum() > (masked[..., 3] > 0).sum()
    for command in (
        ("render", store, "--out", tmp_path / "x.png", "--nodata", "fill"),
        ("tiles", store, "--out", tmp_path / "t", "--format", "3dtiles", "--nodata", "fill"),
    ):
        code, out, err = run(*command)
        assert code == 2 and out == ""
        assert err.startswith("Error: --nodata") and "saved tree" in err
        assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "command",
    [
        ("render", "--out", "x.png"),
        ("tiles", "--out", "t", "--format", "3dtiles"),
        ("tiles", "--out", "t", "--format", "quantized-mesh"),
        ("view", "--frames", "1"),
    ],
    ids=["render", "3dtiles", "quantized-mesh", "view"],
)
def test_build_options_are_refused_where_no_tree_is_built(store, tmp_path, command):
    """--epsilon with a saved tree (already built), or with quantized-mesh tiles (no tree),
    is one Error line naming the flag, and nothing is written."""
    name, *rest = command
    rest = [str(tmp_path / r) if r in ("x.png", "t") else r for r in rest]
    code, out, err = run(name, store, *rest, "--epsilon", "3")
    assert code == 2 and out == ""
    assert err.startswith("Error: --epsilon") and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "t").exists()


def test_build_option_defaults_are_those_of_build():
    """render, tiles and view build a terrain file with the defaults of `approxtree build`."""
    from approxtree.cli.options import BUILD_OPTIONS

    def defaults(name: str) -> dict[str, object]:
        command = main.get_command(None, name)
        return {p.name: p.default for p in command.params if p.name in BUILD_OPTIONS}

    expected = defaults("build")
    assert set(expected) == set(BUILD_OPTIONS)
    for name in ("render", "tiles", "view"):
        assert defaults(name) == expected, name


def test_mesh_and_rd_take_a_tree_store_terrain(data_dir, store):
    """mesh and rd of a tree store work on its stored terrain: the figures of the DEM's."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    goal = ("--max-error", "5")
    of_store, of_dem = run_json("mesh", store, *goal), run_json("mesh", dem, *goal)
    for key in ("vertices", "triangles", "max_error", "rms_error"):
        assert of_store[key] == of_dem[key]
    rd = ("--methods", "uniform", "--rates", "512", "-q")
    rows = [run_json("rd", source, *rd)["methods"]["uniform"]["rows"] for source in (store, dem)]
    assert rows[0] == rows[1] and rows[0][0]["triangles"] > 0


def test_bake_takes_a_point_quadtree_store(data_dir, tmp_path):
    """bake shades the terrain of a point-quadtree store (it used to ask for an
    approximation tree)."""
    laz = data_file(data_dir, "lidar/autzen_trim.laz")
    out = tmp_path / "pq.zarr"
    run_json("build", laz, "--ground-only", "--kind", "point-quadtree", "--out", out, "-q")
    figures = run_json("bake", out, "--no-gl", "--out", tmp_path / "pyramid", "-q")
    assert figures["levels"] >= 1 and (tmp_path / "pyramid" / "pyramid.json").exists()
