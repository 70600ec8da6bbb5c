"""Compact 3D Tiles in real clients (issue 28, items 1 and 2): Debian's chromium drives
3DTilesRendererJS (three.js) over Draco, meshopt and implicit tilesets of the NC tree, CesiumJS
over the meshopt and implicit ones (test_browser.py covers the default, Draco), and CesiumJS's
Cesium3DTilesTerrainProvider over ``--format 3dtiles-terrain`` with a picture draped on it.
Each view must load from 127.0.0.1 only, every tile request succeed and terrain fill the
picture; the near view must go deeper than the far one. Skips without chromium, node or
web/node_modules.
"""

from __future__ import annotations

import json
from pathlib import Path

import browser
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file

from approxtree.cli import main

pytestmark = pytest.mark.skipif(
    browser.unavailable() is not None, reason=str(browser.unavailable())
)

CRS = "EPSG:32119"
BOUNDS = (630000.0, 215000.0, 645000.0, 228500.0)
SIZE = (480, 320)
FOV = 45.0
FAR = ((637500.0, 203000.0, 5000.0), (637500.0, 221750.0, 100.0))
NEAR = ((636000.0, 214000.0, 700.0), (637000.0, 219000.0, 90.0))
#: Tilesets of the NC tree: name → `approxtree tiles` options.
TILESETS = {
    "draco": ["--compression", "draco"],
    "meshopt": ["--compression", "meshopt"],
    "implicit": ["--compression", "draco", "--implicit"],
}
#: The checkerboard draped over the 3D Tiles terrain: red and blue squares.
RED, BLUE = (220, 40, 40), (40, 60, 220)


def _cli(*args: str) -> dict:
    result = CliRunner().invoke(main, [*args, "--json"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return json.loads(result.output.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def nc(data_dir: Path, tmp_path_factory) -> dict:
    """The NC tree's tilesets (TILESETS) and its 3D Tiles terrain with a checkerboard."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    tmp = tmp_path_factory.mktemp("browser3d")
    tree = tmp / "nc.zarr"
    _cli("build", str(dem), "--out", str(tree))
    out: dict = {"tmp": tmp}
    for name, options in TILESETS.items():
        out[name] = tmp / name
        _cli("tiles", str(tree), "--out", str(out[name]), "--format", "3dtiles", *options)
    out["terrain"] = tmp / "terrain"
    _cli("tiles", str(dem), "--out", str(out["terrain"]), "--format", "3dtiles-terrain")
    from PIL import Image

    squares = (np.add.outer(np.arange(256) // 32, np.arange(256) // 32) % 2).astype(bool)
    picture = np.where(squares[..., None], BLUE, RED).astype(np.uint8)
    Image.fromarray(picture).save(tmp / "checker.png")
    return out


def _views(content: dict) -> list[dict]:
    return [
        {"name": name, "params": {**content, "sse": "1", **browser.cesium_view(*cam, FOV, CRS)}}
        for name, cam in (("far", FAR), ("near", NEAR))
    ]


def _check_loaded(shot: dict) -> None:
    """Loaded without error from 127.0.0.1 only, every tile request served, terrain drawn."""
    assert shot["error"] is None and shot["ready"], shot
    assert shot["blocked"] == [], f"the page tried to reach {shot['blocked']}"
    assert [u for u in shot["failed"] if "/tiles/" in u] == [], shot["failed"]
    assert shot["consoleErrors"] == [], shot["consoleErrors"]
    fraction = browser.terrain_mask(shot["screenshot"]).mean()
    assert fraction > 0.1, f"only {fraction:.3f} of the screenshot is terrain"


@pytest.mark.parametrize("name", sorted(TILESETS))
def test_3dtilesrenderer_draws_the_tileset(nc: dict, name: str) -> None:
    """3DTilesRendererJS (three.js, its Draco and meshopt decoders, ImplicitTilingPlugin) draws
    each tileset's meshes, and more of them (deeper) from the near camera than the far one."""
    views = _views({"tileset": "/tiles/tileset.json"})
    shots = browser.run_views(
        nc[name], views, nc["tmp"] / f"three_{name}", SIZE, page="/pages/three_tiles.html"
    )
    stats = {}
    for shot in shots:
        _check_loaded(shot)
        s = shot["stats"]
        assert s["meshes"] > 0 and s["triangles"] > 0 and s["failed"] == 0, s
        assert any(r.endswith(".glb") for r in shot["tile_requests"]), shot["tile_requests"]
        stats[shot["name"]] = s
    assert max(stats["near"]["depths"]) > max(stats["far"]["depths"]), stats


@pytest.mark.parametrize("name", ["meshopt", "implicit"])
def test_cesium_draws_the_tileset(nc: dict, name: str) -> None:
    """CesiumJS draws the meshopt and the implicit tilesets; with the implicit one it refines
    by the exact errors of the tile metadata: the far view selects the root (error < 30 m)."""
    views = _views({"tileset": "/tiles/tileset.json", "globe": "0"})
    shots = {
        s["name"]: s for s in browser.run_views(nc[name], views, nc["tmp"] / f"cesium_{name}", SIZE)
    }
    for shot in shots.values():
        _check_loaded(shot)
        assert shot["stats"]["tileset"]["selected"] > 0, shot["stats"]
    far, near = (shots[n]["stats"]["tileset"] for n in ("far", "near"))
    assert near["selected"] > far["selected"], (far, near)
    assert max(far["selectedErrors"]) < 30.0, far


def test_cesium_drapes_a_picture_on_the_3dtiles_terrain(nc: dict) -> None:
    """Cesium3DTilesTerrainProvider reads `--format 3dtiles-terrain` as the globe's terrain:
    it loads from level 0 through the subtrees down to the DEM's tiles (deeper near than far),
    and a checkerboard imagery layer is draped on it: red and blue squares cover the terrain."""
    import shutil

    from PIL import Image

    shutil.copy(nc["tmp"] / "checker.png", nc["terrain"] / "checker.png")
    rect = ",".join(f"{v:.7f}" for v in browser.lonlat_bounds(BOUNDS, CRS))
    views = _views(
        {
            "terrain": "/tiles/tileset.json",
            "image": "/tiles/checker.png",
            "rect": rect,
            "clip": rect,
        }
    )
    shots = browser.run_views(
        nc["terrain"], views, nc["tmp"] / "terrain3d", SIZE, page="/pages/cesium_terrain3d.html"
    )
    deepest = {}
    for shot in shots:
        _check_loaded(shot)
        globe = shot["stats"]["globe"]
        assert globe["tiles"] > 0 and globe["triangles"] > 0, globe
        assert any("/subtrees/" in r for r in shot["tile_requests"])
        deepest[shot["name"]] = max(globe["levels"])
        rgb = np.asarray(Image.open(shot["screenshot"]).convert("RGB")).astype(int)
        terrain = browser.terrain_mask(shot["screenshot"])
        red = (rgb[..., 0] > rgb[..., 2] + 60) & terrain
        blue = (rgb[..., 2] > rgb[..., 0] + 60) & terrain
        assert red.sum() > 0.2 * terrain.sum() and blue.sum() > 0.2 * terrain.sum()
    assert deepest["near"] > deepest["far"], deepest
