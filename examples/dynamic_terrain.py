"""A pit excavated step by step, then a rising flood: the tree, the textures and the frames
follow each change of the terrain and of the water.

    python examples/dynamic_terrain.py [DEM] [--steps 8] [--flood 6] [--out dynamic_frames]
    python examples/dynamic_terrain.py ../shared/data/nc/elev_ned_30m.tif
    python examples/dynamic_terrain.py ../shared/data/nc/elev_ned_30m.tif --live

A simulation developer's loop: every step digs the pit deeper (and heaps the spoil beside
it), ``tree.update`` rebuilds only the nodes over the changed window, ``rebake`` re-bakes only
the texture pyramid tiles the edit reaches, and the same Engine renders the next frame — its
caches keep every unchanged node's mesh. Then the water rises: the pyramid's water layer (a
thematic layer, texels below the level in the water colour) is re-baked where the shore line
moved. Writes one PNG per step and prints each step's update, re-bake and frame times.

``--live`` shows the same steps in the viewer's window as they happen (``--frames`` frames
per step; close the window to stop): the viewer's Engine follows each update and re-bake
without being recreated, and each step prints its update, re-bake and mean frame times.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from PIL import Image

import approxtree as at
from approxtree.datasets import sample_terrain
from approxtree.geometry.rect import Rect
from approxtree.render import Cut, overview_camera
from approxtree.textures.bake import bake
from approxtree.textures.rebake import Rebake, rebake


def window_rect(grid: at.Grid, r0: int, c0: int, rows: int, cols: int) -> Rect:
    """The world rect of cells rows r0.., columns c0.. (their pixel corners)."""
    t = grid.transform
    xs = (t.c + c0 * t.a, t.c + (c0 + cols) * t.a)
    ys = (t.f + r0 * t.e, t.f + (r0 + rows) * t.e)
    return Rect(min(xs), min(ys), max(xs), max(ys))


def simulation(
    grid: at.Grid, tree: at.ApproximationTree, pyramid, steps: int, flood: int, level: float
) -> Iterator[tuple[str, str, Rebake]]:
    """Apply the pit's steps, then the flood's, to ``tree`` and ``pyramid``; yields each
    step's (name, what the update did, the re-bake) once it is applied."""
    # The pit: flat-bottomed, steep-walled, in the middle third of the terrain, deepened each
    # step; its spoil heaped east of it.
    rows, cols = grid.height // 3, grid.width // 3
    r0, c0 = grid.height // 3, grid.width // 3
    yy, xx = np.mgrid[:rows, :cols]
    radius = np.hypot((yy - rows / 2) / (rows / 3), (xx - cols / 3) / (cols / 4))
    bowl = np.clip(4.0 * (1.0 - radius), 0.0, 1.0)
    heap = np.exp(-(((yy - rows / 2) / (rows / 6)) ** 2 + ((xx - 0.8 * cols) / (cols / 8)) ** 2))
    low, high = grid.z_range
    relief = high - low
    ground = np.array(grid.heights[r0 : r0 + rows, c0 : c0 + cols], dtype=np.float64)
    rect = window_rect(grid, r0, c0, rows, cols)
    for step in range(1, steps + 1):
        depth = 0.15 * relief * step
        report = tree.update(rect, ground - depth * bowl + 0.5 * depth * heap)
        changed = f"{len(report.rebuilt)} nodes rebuilt of {report.nodes_after}"
        update = f"update {report.seconds * 1e3:7.1f} ms ({changed})"
        yield f"step_{step:02d}", update, rebake(pyramid.folder, tree.terrain, rect)
    # The flood: the water rises to a third of the relief, step by step.
    rising = np.linspace(level, low + relief / 3, flood + 1)[1:]
    for step, height in enumerate(rising, start=1):
        textures = rebake(pyramid.folder, tree.terrain, water_level=float(height))
        yield f"flood_{step:02d}", f"water at {height:.1f}", textures


def baked_line(textures: Rebake, dropped: int) -> str:
    """A re-bake's figures: tiles re-baked, time, texture patches the Engine dropped."""
    return (
        f"{sum(textures.tiles)}/{sum(textures.tiles_total)} tiles re-baked in "
        f"{textures.seconds * 1e3:.0f} ms, {dropped} texture patches dropped"
    )


def image_sequence(tree, pyramid, changes, out: Path) -> None:
    """Render each step to a PNG with one Engine (its caches keep unchanged payloads)."""
    with at.Engine(tree, textures=pyramid, exaggeration=4.0) as engine:
        camera = overview_camera(tree.bboxes[0], engine.scale, fov=40.0, elevation=35.0)
        cut = Cut(alpha=1.0, gamma=2.0)

        def frame(name: str, update: str, baked: str) -> None:
            """Draw, write the PNG, print the step's times."""
            t0 = time.perf_counter()
            image = engine.render(camera, (960, 540), cut).image
            frame_ms = (time.perf_counter() - t0) * 1e3
            Image.fromarray(image).save(out / f"{name}.png")
            print(f"{name}: {update}, {baked}, frame {frame_ms:6.1f} ms")

        frame("step_00", "the terrain as read", "textures as baked")
        for name, update, textures in changes:
            # Only the texture patches meeting a re-baked tile leave the caches.
            engine.set_textures(textures.pyramid)
            baked = baked_line(textures, engine.update_figures["texture_gpu_dropped"])
            frame(name, update, baked)
            if name.startswith("step"):
                print(
                    f"         {engine.update_figures['gpu_dropped']} meshes dropped from the GPU"
                )


def live(tree, pyramid, changes, frames: int) -> None:
    """Show each step in the viewer's window as it happens, ``frames`` frames a step."""
    from approxtree.viewer.app import Viewer

    with Viewer(tree, textures=[pyramid], exaggeration=4.0, title="dynamic terrain") as viewer:
        viewer.run(max_frames=frames)
        for name, update, textures in changes:
            if viewer.window.closing:
                break
            # The viewer's Engine: the tree's update is followed at the next frame, the
            # re-baked pyramid now (only the patches of re-baked tiles dropped).
            viewer.pyramids = [textures.pyramid]
            viewer.apply_textures()
            engine = viewer.driver.engine
            baked = baked_line(textures, engine.update_figures["texture_gpu_dropped"])
            t0 = time.perf_counter()
            drawn = viewer.run(max_frames=frames)
            frame_ms = (time.perf_counter() - t0) * 1e3 / max(drawn, 1)
            print(f"{name}: {update}, {baked}, mean frame {frame_ms:6.1f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dem", nargs="?", help="terrain file (default: matplotlib's sample DEM)")
    parser.add_argument("--steps", type=int, default=8, help="excavation steps")
    parser.add_argument("--flood", type=int, default=6, help="steps of the rising water")
    parser.add_argument("--out", default="dynamic_frames", help="folder of the PNG frames")
    parser.add_argument("--live", action="store_true", help="show the steps in the viewer")
    parser.add_argument("--frames", type=int, default=45, help="--live: frames per step")
    args = parser.parse_args()

    grid = at.open_terrain(args.dem) if args.dem else sample_terrain()
    tree = at.ApproximationTree.build(grid, epsilon=1.0, max_points=17 * 17)
    print(
        f"{grid.height} × {grid.width} cells, {len(tree)} nodes, build {tree.build_seconds:.2f} s"
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # The textures: a hillshade over a water layer, a pond 2 % of the relief deep at first.
    low, high = grid.z_range
    level = low + 0.02 * (high - low)
    t0 = time.perf_counter()
    pyramid = bake(grid, out / "textures", gl=False, water_level=level).pyramid
    print(f"bake {time.perf_counter() - t0:.2f} s, {len(pyramid)} levels")
    changes = simulation(grid, tree, pyramid, args.steps, args.flood, level)
    if args.live:
        live(tree, pyramid, changes, args.frames)
    else:
        image_sequence(tree, pyramid, changes, out)
        print(f"frames in {out}/")


if __name__ == "__main__":
    main()
