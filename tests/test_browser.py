"""The web tiles in a real client: CesiumJS in Debian's chromium (issue 16, item 4).

The North Carolina DEM is built into a tree, written with `approxtree tiles` as a 3D Tiles
tileset and as quantized-mesh terrain, and shown by the viewer page (examples/web) from a
server on 127.0.0.1. Each format is looked at from a far and a near camera: the screenshots
must show terrain, the near view must request finer levels than the far one, and the far view
must have the silhouette of `approxtree render` of the same camera. Skips, saying why, without
chromium, node or web/node_modules (CI installs them: .ci/run).
"""

from __future__ import annotations

import json
from pathlib import Path

import browser
import pytest
from click.testing import CliRunner
from conftest import data_file

from approxtree.cli import main

pytestmark = pytest.mark.skipif(
    browser.unavailable() is not None, reason=str(browser.unavailable())
)

CRS = "EPSG:32119"
#: The DEM's bounds, map units (x 630000..645000, y 215000..228500).
BOUNDS = (630000.0, 215000.0, 645000.0, 228500.0)
SIZE = (480, 320)
FOV = 45.0
#: Far: the whole DEM from the south, obliquely. Near: low over its southern part.
FAR = ((637500.0, 203000.0, 5000.0), (637500.0, 221750.0, 100.0))
NEAR = ((636000.0, 214000.0, 700.0), (637000.0, 219000.0, 90.0))
SSE = "1"


def _cli(*args: str) -> dict:
    result = CliRunner().invoke(main, [*args, "--json"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return json.loads(result.output.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def nc(data_dir: Path, tmp_path_factory) -> dict:
    """The NC tree, its tiles in both formats and `approxtree render` of the far camera."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    tmp = tmp_path_factory.mktemp("browser")
    tree = tmp / "nc.zarr"
    _cli("build", str(dem), "--out", str(tree))
    out = {"tmp": tmp, "tree": tree}
    for fmt in ("3dtiles", "quantized-mesh"):
        out[fmt] = tmp / fmt
        _cli("tiles", str(tree), "--out", str(out[fmt]), "--format", fmt)
    eye, target = FAR
    # Alpha 0 where no terrain is drawn: the silhouette (render's default background is sky).
    out["render"] = tmp / "render.png"
    _cli(
        "render", str(tree), "--eye", ",".join(map(str, eye)), "--target",
        ",".join(map(str, target)), "--fov", str(FOV), "--size", f"{SIZE[0]}x{SIZE[1]}",
        "--out", str(out["render"]), "--background", "transparent",
    )  # fmt: skip
    return out


def _views(content: dict) -> list[dict]:
    return [
        {"name": name, "params": {**content, "sse": SSE, **browser.cesium_view(*cam, FOV, CRS)}}
        for name, cam in (("far", FAR), ("near", NEAR))
    ]


@pytest.fixture(scope="module")
def tileset_shots(nc: dict) -> dict:
    views = _views({"tileset": "/tiles/tileset.json", "globe": "0"})
    results = browser.run_views(nc["3dtiles"], views, nc["tmp"] / "shots_3dtiles", SIZE)
    return {r["name"]: r for r in results}


@pytest.fixture(scope="module")
def terrain_shots(nc: dict) -> dict:
    # The globe drawn only over the DEM, so that its silhouette can be compared.
    clip = ",".join(f"{v:.7f}" for v in browser.lonlat_bounds(BOUNDS, CRS))
    views = _views({"terrain": "/tiles/", "clip": clip})
    results = browser.run_views(nc["quantized-mesh"], views, nc["tmp"] / "shots_qm", SIZE)
    return {r["name"]: r for r in results}


def _check_loaded(shot: dict) -> None:
    """Loaded without error, from 127.0.0.1 only, with terrain in the picture."""
    assert shot["error"] is None and shot["ready"], shot
    assert shot["blocked"] == [], f"the page tried to reach {shot['blocked']}"
    assert shot["failed"] == [] and shot["consoleErrors"] == [], shot
    fraction = browser.terrain_mask(shot["screenshot"]).mean()
    assert fraction > 0.1, f"only {fraction:.3f} of the screenshot is terrain"


def test_tileset_loads_in_cesium(tileset_shots: dict) -> None:
    for shot in tileset_shots.values():
        _check_loaded(shot)
        stats = shot["stats"]["tileset"]
        assert stats["selected"] > 0 and stats["triangles"] > 0, stats
        assert any(r.endswith(".glb") for r in shot["tile_requests"]), shot["tile_requests"]


def test_terrain_loads_in_cesium(terrain_shots: dict) -> None:
    for shot in terrain_shots.values():
        _check_loaded(shot)
        stats = shot["stats"]["globe"]
        assert stats["tiles"] > 0 and stats["triangles"] > 0, stats
        assert browser.terrain_levels(shot["tile_requests"]), shot["tile_requests"]


def test_tileset_requests_finer_levels_nearer(nc: dict, tileset_shots: dict) -> None:
    depths = browser.tileset_depths(nc["3dtiles"] / "tileset.json")
    deepest = {
        name: max(depths[r] for r in shot["tile_requests"] if r in depths)
        for name, shot in tileset_shots.items()
    }
    assert deepest["near"] > deepest["far"], deepest


def test_terrain_requests_finer_levels_nearer(terrain_shots: dict) -> None:
    deepest = {
        name: max(browser.terrain_levels(shot["tile_requests"]))
        for name, shot in terrain_shots.items()
    }
    assert deepest["near"] > deepest["far"], deepest


# Bounds on the 99th percentile of the pixel distances. The terrain's are looser: its globe is
# clipped to the lon/lat rectangle around the projected DEM, a few pixels larger at the edges.
@pytest.mark.parametrize("shots, p99", [("tileset_shots", 4.0), ("terrain_shots", 6.0)])
def test_silhouette_matches_render(nc: dict, shots: str, p99: float, request) -> None:
    """CesiumJS and `approxtree render` draw the terrain over the same pixels, within a few."""
    shot = request.getfixturevalue(shots)["far"]
    cesium = browser.terrain_mask(shot["screenshot"])
    ours = browser.terrain_mask(nc["render"], background=None)
    d = browser.silhouette_distance(cesium, ours)
    assert d["b_fraction"] > 0.1, d
    assert d["p99_px"] <= p99 and d["max_px"] <= 8.0, d
    assert d["xor_fraction"] < 0.02, d
