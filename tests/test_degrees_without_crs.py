"""Grids in degrees read without a CRS: the reader warns and says how to give it (--crs, crs=).

Without a CRS x, y and z share one unit, so a DEM exported in longitude/latitude (a .npz, PGM or
PNG) is a needle thousands of times taller than wide that no view shows. These tests check the
warning fires on such grids only, that ``--crs`` reaches every reader that takes a CRS, and that
with it the fitted view draws the terrain.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from approxtree import ApproximationTree
from approxtree.cli import main
from approxtree.errors import InvalidParameterError, TerrainDataWarning
from approxtree.io import open_terrain


def run(*args: object) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of the CLI run in-process."""
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def write_npz(path: Path, cell: float, x0: float, y0: float, relief: float) -> Path:
    """A 40 × 50 hill of ``relief`` z units above 200 with ``cell``-sized cells from (x0, y0)."""
    y, x = np.mgrid[0:40, 0:50]
    z = 200.0 + relief * np.exp(-((x - 25.0) ** 2 + (y - 20.0) ** 2) / 200.0)
    np.savez(
        path,
        elevation=z.astype(np.float32),
        xmin=x0,
        xmax=x0 + 50 * cell,
        ymin=y0,
        ymax=y0 + 40 * cell,
    )
    return path


@pytest.fixture
def degrees(tmp_path: Path) -> Path:
    """A grid of 3″ cells near Jacksboro, 800 m of relief: 0.04° wide."""
    return write_npz(tmp_path / "degrees.npz", 1 / 1200, -84.4, 36.4, 800.0)


def no_warnings(**options: object):
    """open_terrain with every warning turned into an error."""

    def read(path: Path):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            return open_terrain(path, **options)

    return read


def test_degree_grid_without_crs_warns_with_the_fix(degrees):
    """The warning names the file, the aspect it would have and the option that fixes it."""
    with pytest.warns(TerrainDataWarning, match=r"--crs EPSG:4326") as record:
        grid = open_terrain(degrees)
    message = str(record[0].message)
    assert str(degrees) in message and "taller than wide" in message
    assert grid.crs is None
    assert no_warnings(crs="EPSG:4326")(degrees).crs == "EPSG:4326"


@pytest.mark.parametrize(
    "cell, x0, y0, relief",
    [
        (30.0, 500_000.0, 4_000_000.0, 800.0),  # projected metres
        (1 / 1200, -84.4, 36.4, 0.3),  # degree-sized cells, flat: heights not far beyond width
        (1.0, 0.0, 0.0, 5.0),  # unit cells near the origin (synthetic arrays)
        (0.05, 179.0, 10.0, 800.0),  # within longitudes on the west but beyond 180 on the east
    ],
)
def test_grids_that_do_not_look_like_degrees_read_silently(tmp_path, cell, x0, y0, relief):
    """Metre grids, flat degree grids and grids past ±180 read without a warning."""
    path = write_npz(tmp_path / "g.npz", cell, x0, y0, relief)
    assert no_warnings()(path).crs is None


def test_a_crs_pyproj_cannot_read_is_refused(degrees):
    with pytest.raises(InvalidParameterError, match="not a CRS pyproj knows"):
        open_terrain(degrees, crs="EPSG:99999999")


def test_cli_warns_then_crs_draws_the_terrain(degrees, tmp_path):
    """build warns without --crs; with it the tree is geographic and the fitted view (transparent
    background) is mostly terrain, where the needle read in one unit covers almost nothing."""
    needle, tree = tmp_path / "needle.zarr", tmp_path / "tree.zarr"
    code, _, err = run("build", degrees, "--epsilon", 2, "--out", needle)
    assert code == 0 and err.startswith("Warning: ") and "--crs EPSG:4326" in err
    code, _, err = run(
        "build", degrees, "--crs", "EPSG:4326", "--epsilon", 2, "--out", tree, "--json"
    )
    assert code == 0 and "Warning" not in err, err
    assert ApproximationTree.load(tree).terrain.crs == "EPSG:4326"
    drawn = {}
    for name, path in (("needle", needle), ("tree", tree)):
        png = tmp_path / f"{name}.png"
        code, _, err = run(
            "render", path, "--size", "160x120", "--background", "transparent", "--out", png
        )
        assert code == 0, err
        drawn[name] = (np.asarray(Image.open(png))[..., 3] > 0).mean()
    assert drawn["tree"] > 0.2
    assert drawn["needle"] < 0.02


def test_cli_crs_errors_are_one_line(degrees, tmp_path):
    """A bad --crs, --crs on a format without a CRS option, --crs with a saved tree: Error."""
    tile = tmp_path / "t.terrain"
    tile.write_bytes(b"")  # detected by extension; refused before it is read
    tree = tmp_path / "t.zarr"
    assert run("build", degrees, "--crs", "EPSG:4326", "--epsilon", 5, "--out", tree)[0] == 0
    cases = [
        (["info", degrees, "--crs", "not a crs"], "is not a CRS pyproj knows"),
        (["info", tile, "--crs", "EPSG:4326"], "--crs does not apply"),
        (["info", tree, "--crs", "EPSG:4326"], "saved tree"),
    ]
    for args, words in cases:
        code, _, err = run(*args)
        assert code == 2, args
        assert err.startswith("Error: ") and words in err and err.count("\n") == 1, err


def test_info_reports_the_given_crs(degrees):
    code, out, _ = run("info", degrees, "--crs", "EPSG:4326", "--json")
    assert code == 0 and json.loads(out)["crs"] == "EPSG:4326"
