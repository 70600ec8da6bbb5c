"""
On the web: the tree as 3D Tiles in CesiumJS
============================================

``approxtree tiles --format 3dtiles`` writes one glTF tile per node of the tree, each with
its exact geometric error, its texture patch and skirts; CesiumJS then plays the role of our
renderer, its ``maximumScreenSpaceError`` that of α. Here the North Carolina tree with its
land-use texture is written as a tileset, served on 127.0.0.1 and opened in headless
chromium by the page in ``examples/web`` (CesiumJS from ``web/node_modules``, no network, no
Ion token) — the harness of the browser tests, ``tests/browser.py``. Beside it, the same
camera drawn by approxtree's own Engine.

It needs Debian's ``chromium``, Node.js and ``npm ci --prefix web``; without them this page
shows a note instead of the screenshot.
"""

# %%
import importlib.util

import numpy as np
from _gallery import ROOT, WORK, data_file, placeholder, show
from PIL import Image

import approxtree as at
from approxtree.render import Camera
from approxtree.textures.bake import bake
from approxtree.tiles import write_3dtiles

spec = importlib.util.spec_from_file_location("browser", ROOT / "tests" / "browser.py")
browser = importlib.util.module_from_spec(spec)
spec.loader.exec_module(browser)

dem = data_file("nc/elev_ned_30m.tif")
missing = browser.unavailable()
if dem is None or missing:
    print(f"No CesiumJS screenshot: {missing or 'the North Carolina data are absent'}.")
    placeholder(f"No CesiumJS screenshot on this machine: {missing or 'NC data absent'}")
else:
    terrain = at.open_terrain(dem)
    tree = at.ApproximationTree.build(terrain, epsilon=1.0)
    baked = bake(
        terrain,
        WORK / "nc_tiles_textures",
        thematic=dem.with_name("landuse_r.tif"),
        palette="landclass96",
    )
    print(write_3dtiles(tree, WORK / "nc_3dtiles", textures=baked.pyramid))

# %%
# One camera from the south-west over the DEM (EPSG:32119, metres), in CesiumJS with a
# maximum screen-space error of 1 px, and in approxtree's Engine with α = 1 px; the same
# background colour in both.
if dem is not None and not missing:
    size, fov = (640, 400), 45.0
    eye, target = (633000.0, 209000.0, 2500.0), (638000.0, 220000.0, 80.0)
    background = "#9db8d9"
    view = {
        "name": "nc",
        "params": {
            "tileset": "/tiles/tileset.json",
            "globe": "0",
            "sse": "1",
            "bg": background,
            **browser.cesium_view(eye, target, fov, "EPSG:32119"),
        },
    }
    [shot] = browser.run_views(WORK / "nc_3dtiles", [view], WORK / "cesium_shots", size)
    print({k: shot[k] for k in ("ready", "error")}, len(shot["tile_requests"]), "tiles requested")
    with at.Engine(tree, textures=baked.pyramid) as engine:
        ours = engine.render(
            Camera.look_at(eye, target, fov=fov),
            size,
            at.Cut(alpha=1.0),
            style=at.Style(background=background),
        )
    show(
        [np.asarray(Image.open(shot["screenshot"]).convert("RGBA")), ours.image],
        ["CesiumJS (chromium, 3D Tiles)", "approxtree Engine, same camera"],
    )
