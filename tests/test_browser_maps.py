"""Imagery and raster-dem in the clients they are for, in Debian's chromium (issue 28, 3-5).

The North Carolina DEM is built into a tree store and baked (land use over shading); with
`approxtree tiles` it becomes quantized-mesh terrain, geographic imagery, a Terrarium
PMTiles archive and a Web Mercator imagery archive. CesiumJS (examples/web/index.html)
drapes the imagery over the terrain from its default view; MapLibre GL JS
(examples/web/maplibre.html) draws the archive as 3D terrain with a hillshade layer, through
its pmtiles protocol (byte ranges of one file). Skips, saying why, without chromium, node or
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
from PIL import Image

from approxtree.cli import main

pytestmark = pytest.mark.skipif(
    browser.unavailable() is not None
    or not (browser.NODE_MODULES / "maplibre-gl" / "package.json").exists(),
    reason=str(browser.unavailable() or "npm packages maplibre-gl, pmtiles missing in web/"),
)

SIZE = (480, 320)


def _cli(*args) -> dict:
    result = CliRunner().invoke(main, [*map(str, args), "--json"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return json.loads(result.output.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def nc(data_dir: Path, tmp_path_factory) -> dict:
    """The NC store's tiles in one folder: terrain/, imagery/, dem.pmtiles, img.pmtiles."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    landuse = data_file(data_dir, "nc/landuse_r.tif")
    tmp = tmp_path_factory.mktemp("maps")
    store = tmp / "nc.zarr"
    _cli("build", dem, "--out", store)
    tex = tmp / "thematic"
    _cli("bake", dem, "--thematic", landuse, "--palette", "landclass96", "--out", tex,
         "--no-gl", "--quiet")  # fmt: skip
    tiles = tmp / "tiles"
    tiles.mkdir()
    _cli("tiles", store, "--format", "quantized-mesh", "--out", tiles / "terrain")
    _cli("tiles", store, "--format", "imagery", "--textures", tex, "--out", tiles / "imagery")
    _cli("tiles", store, "--format", "terrarium", "--out", tiles / "dem.pmtiles")
    _cli("tiles", store, "--format", "imagery", "--textures", tex, "--scheme", "webmercator",
         "--out", tiles / "img.pmtiles")  # fmt: skip
    return {"tmp": tmp, "tiles": tiles, "dem": dem}


def green(png: Path | str) -> float:
    """Fraction of the picture in the land use's greens (forest), which no bare globe has."""
    rgb = np.asarray(Image.open(png).convert("RGB")).astype(int)
    return float(((rgb[..., 1] > rgb[..., 0] + 8) & (rgb[..., 1] > rgb[..., 2] + 8)).mean())


def _clean(shot: dict) -> None:
    """Loaded without error, from 127.0.0.1 only."""
    assert shot["error"] is None and shot["ready"], shot
    assert shot["blocked"] == [], f"the page tried to reach {shot['blocked']}"
    assert shot["failed"] == [] and shot["consoleErrors"] == [], shot


def test_cesium_drapes_the_imagery_over_the_terrain_from_an_oblique_view(nc: dict) -> None:
    """CesiumJS asks for terrain and imagery tiles, shows the land-use colours (green forest,
    not the bare globe's beige) over the terrain, and its default camera looks down obliquely
    (between 20° and 60°), not straight down."""
    params = {"terrain": "/tiles/terrain/", "imagery": "/tiles/imagery/tilejson.json"}
    views = [{"name": "drape", "params": params}]
    [shot] = browser.run_views(nc["tiles"], views, nc["tmp"] / "shots_drape", SIZE)
    _clean(shot)
    requests = shot["tile_requests"]
    assert any(r.startswith("terrain/") and r.endswith(".terrain") for r in requests), requests
    imagery = [r for r in requests if r.startswith("imagery/") and r.endswith(".png")]
    assert len(imagery) >= 4, requests
    rgb = np.asarray(Image.open(shot["screenshot"]).convert("RGB")).astype(int)
    terrain = browser.terrain_mask(shot["screenshot"])
    assert terrain.mean() > 0.2
    assert green(shot["screenshot"]) > 0.05, "no land-use green in the picture"
    assert rgb[terrain].std() > 10
    cam = shot["stats"]["camera"]
    up = np.asarray(cam["position"]) / np.linalg.norm(cam["position"])
    down = -np.degrees(np.arcsin(np.dot(cam["direction"], up)))
    assert 20.0 < down < 60.0, down


def test_maplibre_draws_the_pmtiles_dem_as_terrain_with_hillshade(nc: dict) -> None:
    """MapLibre reads the Terrarium archive by byte ranges through the pmtiles protocol, draws
    it as 3D terrain under a hillshade layer and the imagery archive, and its terrain at the
    centre lies within the DEM's heights around it (MapLibre draws a mesh of its own, a few
    hundred metres a cell at this zoom: the heights within 300 m, 0.5 m of slack)."""
    from pyproj import Transformer

    from approxtree.io import open_terrain

    params = {"dem": "/tiles/dem.pmtiles", "imagery": "/tiles/img.pmtiles", "pitch": "60"}
    views = [{"name": "maplibre", "params": params}]
    [shot] = browser.run_views(
        nc["tiles"], views, nc["tmp"] / "shots_maplibre", SIZE, page="maplibre.html"
    )
    _clean(shot)
    requests = shot["tile_requests"]
    assert "dem.pmtiles" in requests and "img.pmtiles" in requests, requests
    stats = shot["stats"]
    assert stats["terrain"]["source"] == "terrain"
    assert "hillshade" in stats["layers"] and "imagery" in stats["layers"]
    terrain = open_terrain(nc["dem"])
    lon, lat = stats["center"]
    x, y = Transformer.from_crs("EPSG:4326", terrain.crs, always_xy=True).transform(lon, lat)
    dx, dy = np.meshgrid(np.linspace(-300, 300, 41), np.linspace(-300, 300, 41))
    around = terrain.height_at(x + dx, y + dy)
    drawn = stats["elevation"] / stats["exaggeration"]
    assert np.nanmin(around) - 0.5 <= drawn <= np.nanmax(around) + 0.5, (drawn, around)
    rgb = np.asarray(Image.open(shot["screenshot"]).convert("RGB")).astype(int)
    assert rgb.std() > 10


def test_cesium_opens_the_live_server_page(nc: dict) -> None:
    """approxtree serve's page at / (CesiumJS from the server, terrain and imagery made on
    request) loads in chromium without error, asking the server for terrain and imagery."""
    import subprocess
    import threading

    import uvicorn

    from approxtree.tiles.serve import create_app
    from approxtree.tiles.serve.runner import bind

    layers = nc["tmp"] / "layers"
    layers.mkdir(exist_ok=True)
    if not (layers / "thematic").exists():
        (layers / "thematic").symlink_to(nc["tmp"] / "thematic")
    app = create_app(str(nc["tmp"] / "nc.zarr"), str(layers))
    sock = bind("127.0.0.1", 0)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]})
    thread.start()
    out = nc["tmp"] / "shots_live"
    out.mkdir(exist_ok=True)
    job = {
        "node_modules": str(browser.NODE_MODULES),
        "chromium": browser.chromium_path(),
        "width": SIZE[0],
        "height": SIZE[1],
        "timeout_ms": 240_000,
        "views": [
            {
                "url": f"http://127.0.0.1:{sock.getsockname()[1]}/",
                "screenshot": str(out / "live.png"),
            }
        ],
    }
    (out / "job.json").write_text(json.dumps(job))
    try:
        proc = subprocess.run(
            ["node", str(browser.SHOT_SCRIPT), str(out / "job.json")],
            capture_output=True, text=True, timeout=400,
        )  # fmt: skip
    finally:
        server.should_exit = True
        thread.join(timeout=60)
        sock.close()
    [shot] = json.loads(proc.stdout)["views"]
    _clean(shot)
    paths = [r.split("/", 3)[-1] for r in shot["requests"]]
    assert any(p.startswith("terrain/") and p.endswith(".terrain") for p in paths), paths
    assert any(p.startswith("imagery/thematic/") and p.endswith(".png") for p in paths), paths
    assert green(out / "live.png") > 0.05
