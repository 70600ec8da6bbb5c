"""A pit excavated step by step: the tree and the frames follow each edit of the terrain.

    python examples/dynamic_terrain.py [DEM] [--steps 8] [--out dynamic_frames]

A simulation developer's loop: every step digs the pit deeper (and heaps the spoil beside
it), ``tree.update`` rebuilds only the nodes over the changed window, and the same Engine
renders the next frame — its caches keep every unchanged node's mesh. Writes one PNG per step
and prints each step's update and frame times.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from PIL import Image

import approxtree as at
from approxtree.datasets import sample_terrain
from approxtree.geometry.rect import Rect
from approxtree.render import Cut, overview_camera


def window_rect(grid: at.Grid, r0: int, c0: int, rows: int, cols: int) -> Rect:
    """The world rect of cells rows r0.., columns c0.. (their pixel corners)."""
    t = grid.transform
    xs = (t.c + c0 * t.a, t.c + (c0 + cols) * t.a)
    ys = (t.f + r0 * t.e, t.f + (r0 + rows) * t.e)
    return Rect(min(xs), min(ys), max(xs), max(ys))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dem", nargs="?", help="terrain file (default: matplotlib's sample DEM)")
    parser.add_argument("--steps", type=int, default=8, help="excavation steps")
    parser.add_argument("--out", default="dynamic_frames", help="folder of the PNG frames")
    args = parser.parse_args()

    grid = at.open_terrain(args.dem) if args.dem else sample_terrain()
    tree = at.ApproximationTree.build(grid, epsilon=1.0, max_points=17 * 17)
    print(
        f"{grid.height} × {grid.width} cells, {len(tree)} nodes, build {tree.build_seconds:.2f} s"
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    # The pit: flat-bottomed, steep-walled, in the middle third of the terrain, deepened each
    # step; its spoil heaped east of it.
    rows, cols = grid.height // 3, grid.width // 3
    r0, c0 = grid.height // 3, grid.width // 3
    yy, xx = np.mgrid[:rows, :cols]
    radius = np.hypot((yy - rows / 2) / (rows / 3), (xx - cols / 3) / (cols / 4))
    bowl = np.clip(4.0 * (1.0 - radius), 0.0, 1.0)
    heap = np.exp(-(((yy - rows / 2) / (rows / 6)) ** 2 + ((xx - 0.8 * cols) / (cols / 8)) ** 2))
    relief = grid.z_range[1] - grid.z_range[0]
    ground = np.array(grid.heights[r0 : r0 + rows, c0 : c0 + cols], dtype=np.float64)
    rect = window_rect(grid, r0, c0, rows, cols)

    with at.Engine(tree, exaggeration=4.0) as engine:
        camera = overview_camera(tree.bboxes[0], engine.scale, fov=40.0, elevation=35.0)
        cut = Cut(alpha=1.0, gamma=math.inf)
        for step in range(args.steps + 1):
            if step:
                depth = 0.15 * relief * step
                report = tree.update(rect, ground - depth * bowl + 0.5 * depth * heap)
                update_ms = report.seconds * 1e3
                changed = f"{len(report.rebuilt)} nodes rebuilt of {report.nodes_after}"
            else:
                update_ms, changed = 0.0, "the terrain as read"
            t0 = time.perf_counter()
            frame = engine.render(camera, (960, 540), cut)
            frame_ms = (time.perf_counter() - t0) * 1e3
            Image.fromarray(frame.image).save(out / f"step_{step:02d}.png")
            dropped = engine.update_figures.get("gpu_dropped", 0) if step else 0
            print(
                f"step {step}: update {update_ms:7.1f} ms ({changed}), frame {frame_ms:6.1f} ms, "
                f"{dropped} meshes dropped from the GPU"
            )
    print(f"frames in {out}/")


if __name__ == "__main__":
    main()
