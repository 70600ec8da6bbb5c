"""The command line: figures as JSON, and one-line errors with exit code 2 on bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file

from approxtree import ApproximationTree
from approxtree.cli import main


def run(*args: str):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def test_info_json_on_the_nc_dem(data_dir):
    """info --json reports the facts of the NC DEM (500 × 450, EPSG:32119, 30 m, no nodata)."""
    result = run("info", str(data_file(data_dir, "nc/elev_ned_30m.tif")), "--json")
    assert result.exit_code == 0, result.output
    info = json.loads(result.output)
    assert (info["width"], info["height"]) == (500, 450)
    assert info["crs"] == "EPSG:32119"
    assert info["cell_size"] == [30.0, 30.0]
    assert info["nodata_count"] == 0
    assert round(info["z_min"], 2) == 55.17 and round(info["z_max"], 2) == 156.39


def test_info_counts_nodata_of_kauai(data_dir):
    """info reports the 4279 void cells of the Kauai SRTM tile."""
    result = run("info", str(data_file(data_dir, "srtm/N22W160v2.3a.hgt.zip")), "--json")
    assert json.loads(result.output)["nodata_count"] == 4279


def test_info_text_on_a_point_set_says_what_does_not_apply(data_dir):
    """info's text on a LAZ point set shows a dash for the grid figures (no width, height or
    cell size), never Python's None; --json keeps them null."""
    path = str(data_file(data_dir, "lidar/autzen_trim.laz"))
    result = run("info", path)
    assert result.exit_code == 0, result.output
    rows = dict(line.split(None, 1) for line in result.output.splitlines())
    assert rows["kind"] == "tinpointset" and rows["points"] == "109993"
    assert rows["width"] == rows["height"] == rows["cell_size"] == "—"
    assert "None" not in result.output
    assert json.loads(run("info", path, "--json").output)["width"] is None


def test_build_json_and_tree_file(data_dir, tmp_path):
    """build --json writes a loadable tree whose figures match the printed ones."""
    out = tmp_path / "nc.zarr.zip"
    result = run(
        "build",
        str(data_file(data_dir, "nc/elev_ned_30m.tif")),
        "--out",
        str(out),
        "--epsilon",
        "2",
        "--max-points",
        "289",
        "--json",
    )
    assert result.exit_code == 0, result.output
    figures = json.loads(result.output)
    tree = ApproximationTree.load(out)
    stats = tree.stats()
    for key in ("nodes", "levels", "leaves", "strategies", "max_leaf_error"):
        assert figures[key] == stats[key]
    assert figures["bytes"] == out.stat().st_size
    assert figures["max_leaf_error"] <= 2.0
    assert figures["seconds"] > 0


def test_demo_builds_the_sample_terrain(tmp_path):
    """demo builds the matplotlib sample DEM's tree and prints its figures."""
    out = tmp_path / "demo.zarr"
    result = run("demo", "--out", str(out), "--json")
    assert result.exit_code == 0, result.output
    figures = json.loads(result.output)
    assert (figures["width"], figures["height"]) == (403, 344)
    assert figures["max_leaf_error"] <= 1.0
    assert ApproximationTree.load(out).stats()["nodes"] == figures["nodes"]
    # The hillshade pyramid is baked next to the tree and textures the rendered overview.
    assert (tmp_path / "demo_textures" / "pyramid.json").is_file()
    assert figures["texture_patches"] >= 1 and figures["texture_switches"] >= 1


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["info", "/nonexistent/dem.tif"], "does not exist"),
        (["build", "{npy}", "--out", "{out}", "--epsilon", "-1"], "epsilon"),
        (["build", "{npy}", "--out", "{out}", "--epsilon", "nan"], "epsilon"),
        (["build", "{npy}", "--out", "{out}", "--max-points", "2"], "max_points"),
        (["build", "{npy}", "--out", "/nonexistent/dir/t.zarr.zip"], "does not exist"),
        (["build", "{nan_npy}", "--out", "{out}"], "no valid elevation"),
        (["build", "{thin_npy}", "--out", "{out}"], "2 × 2"),
        (["build", "{npy}", "--out", "{atree}"], "no longer writes the legacy .atree"),
    ],
)
def test_bad_input_gives_one_line_and_exit_2(tmp_path, args, words):
    """Bad files and parameters end with 'Error: ...' on stderr, exit 2, and no tree file."""
    np.save(tmp_path / "dem.npy", np.random.default_rng(0).random((20, 20)))
    np.save(tmp_path / "nan.npy", np.full((8, 8), np.nan))
    np.save(tmp_path / "thin.npy", np.ones((1, 30)))
    paths = {
        "npy": tmp_path / "dem.npy",
        "nan_npy": tmp_path / "nan.npy",
        "thin_npy": tmp_path / "thin.npy",
        "out": tmp_path / "t.zarr.zip",
        "atree": tmp_path / "t.atree",
    }
    argv = [a.format(**paths) for a in args]
    proc = subprocess.run(
        [sys.executable, "-m", "approxtree", *argv], capture_output=True, text=True
    )
    assert proc.returncode == 2
    assert proc.stderr.startswith("Error: ") and words in proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "t.zarr.zip").exists() and not (tmp_path / "t.atree").exists()
