"""
Dynamic terrain: a pit dug, then a flood rising over North Carolina
===================================================================

A simulation changes the ground and the water, and the tree, the texture pyramid and the
frames follow each step without a rebuild: ``tree.update`` rebuilds only the nodes over the
dug window, ``rebake`` re-bakes only the pyramid tiles the edit (or the shore line of a new
water level) reaches, and the same Engine draws the next frame. The water is a thematic
layer of the pyramid: texels below the level in the water colour, shaded like the ground.
The same as, for each step::

    approxtree update nc.zarr pit_step.tif --textures nc_tex --json

and, for the flood (baked with ``approxtree bake … --water-level 58``), for each level::

    approxtree update nc.zarr --textures nc_tex --water-level 66 --json
"""

# %%
import time

import numpy as np
from _gallery import WORK, data_file, placeholder, show

import approxtree as at
from approxtree.geometry.rect import Rect
from approxtree.render import framing_camera
from approxtree.textures.bake import bake
from approxtree.textures.rebake import rebake

dem = data_file("nc/elev_ned_30m.tif")
if dem is None:
    placeholder("North Carolina data absent (shared/data/nc): no picture")
else:
    terrain = at.open_terrain(dem)
    tree = at.ApproximationTree.build(terrain, epsilon=1.0, max_points=17 * 17)
    # A pond in the lowest valley to begin with (3 m above the lowest ground).
    low, high = terrain.z_range
    pyramid = bake(
        terrain, WORK / "nc_dynamic", gl=False, texel_size=10.0, water_level=low + 3.0
    ).pyramid
    print(
        f"{len(tree)} nodes; pyramid level 0: {pyramid.levels[0].width} × "
        f"{pyramid.levels[0].height} texels"
    )

# %%
# The pit: 60 × 80 cells in the south-west of the sheet, a bowl dug 20 m deeper each step.
# Each step prints the update of the tree, the re-bake (tiles written of all) and the frame.
frames, titles = [], []
if dem is not None:
    r0, c0, rows, cols = 280, 120, 60, 80
    t = terrain.transform
    rect = Rect(t.c + c0 * t.a, t.f + (r0 + rows) * t.e, t.c + (c0 + cols) * t.a, t.f + r0 * t.e)
    yy, xx = np.mgrid[:rows, :cols]
    bowl = np.clip(
        3.0 * (1.0 - np.hypot((yy - rows / 2) / (rows / 2), (xx - cols / 2) / (cols / 2))), 0, 1
    )
    ground = np.array(terrain.heights[r0 : r0 + rows, c0 : c0 + cols], dtype=np.float64)
    size = (640, 360)
    cut = at.Cut(alpha=1.0, gamma=2.0)
    with at.Engine(tree, textures=pyramid, exaggeration=5.0) as engine:
        camera = framing_camera(tree.bboxes[0], engine.scale, size, elevation=40.0)

        def draw(title: str, update_ms: float, rebake_result) -> None:
            """Render a frame with the current pyramid, keep it, print the step's times."""
            engine.set_textures(rebake_result.pyramid if rebake_result else pyramid)
            t0 = time.perf_counter()
            image = engine.render(camera, size, cut, style=at.Style(background="sky")).image
            frame_ms = (time.perf_counter() - t0) * 1e3
            tiles = (
                f"{sum(rebake_result.tiles)} of {sum(rebake_result.tiles_total)} tiles "
                f"in {rebake_result.seconds * 1e3:.0f} ms"
                if rebake_result
                else "-"
            )
            print(
                f"{title:>16}: update {update_ms:6.1f} ms, re-bake {tiles}, frame {frame_ms:.0f} ms"
            )
            frames.append(image)
            titles.append(title)

        draw("as read", 0.0, None)
        for step in (1, 2, 3):
            report = tree.update(rect, ground - 20.0 * step * bowl)
            done = rebake(pyramid.folder, tree.terrain, rect)
            draw(f"pit, step {step}", report.seconds * 1e3, done)
        # The flood: the level rises over the pit's floor and up the valleys.
        for level in np.linspace(low + 10.0, low + 0.3 * (high - low), 4):
            done = rebake(pyramid.folder, tree.terrain, water_level=float(level))
            draw(f"water at {level:.0f} m", 0.0, done)

# %%
# The eight frames: the pit deepens, then the water fills it and spreads along the streams.
if frames:
    show(frames[:4], titles[:4], width=12.0)
    show(frames[4:], titles[4:], width=12.0)
