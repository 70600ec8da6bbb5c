"""LOD cut vs full resolution: triangles, draw time and measured screen error.

A 4097² fractal DEM (10 m cells, 1000 m relief) is built with ε = 0 (leaves exact) and the
default 33 × 33 max points, then drawn at 1280 × 720 from two oblique views (the overview of
the whole terrain, and a low view across it from its southern edge) on headless EGL (Mesa
llvmpipe on a CPU-only machine):

- the LOD cut at alpha = 1 px with the texture error off (gamma = inf: there are no textures
  yet), and, for reference, with gamma = 2 px² (texel = data spacing);
- the unsimplified terrain (``Cut(full_resolution=True)``).

Draw time: median over FRAMES frames of clear + draw calls + ctx.finish(), uploads done
before (each frame is drawn from the GPU cache). The screen error of the cut is measured
with the world-position buffer: for every covered surface pixel the distance in pixels
between the projections of (x, y, z) and (x, y, h_T(x, y)). Results go to
benchmarks/results/render.json.

    python benchmarks/bench_render.py [--size 4097] [--frames 5] [--full-frames 3]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from approxtree import ApproximationTree
from approxtree.datasets import fractal_terrain
from approxtree.render import Camera, Cut, Engine, overview_camera

RESULTS = Path(__file__).resolve().parent / "results"
SIZE = (1280, 720)


def measure(engine, camera, frames: int, cut: Cut) -> dict:
    """Render ``frames`` + 1 frames (the first uploads); median of the draw times."""
    first = engine.render(camera, SIZE, cut)
    draws = [engine.render(camera, SIZE, cut).stats["draw_ms"] for _ in range(frames)]
    stats = dict(first.stats)
    stats["draw_ms_median"] = statistics.median(draws)
    stats["draw_ms_all"] = draws
    stats["first_frame_draw_ms"] = first.stats["draw_ms"]
    return stats


def screen_error(engine, camera, cut: Cut) -> tuple[float, int]:
    """(largest distance in pixels, pixels checked) of ``cut`` drawn."""
    frame = engine.render(camera, SIZE, cut)
    pos = engine.world_positions(frame)
    surface = pos[..., 3] > 0.5
    p = pos[surface][:, :3]
    q = p.copy()
    q[:, 2] = engine.tree.terrain.height_at(p[:, 0], p[:, 1])
    a, _ = frame.frame_state.world_to_pixels(p)
    b, _ = frame.frame_state.world_to_pixels(q)
    d = np.hypot(*(a - b).T)
    d = d[np.isfinite(d)]
    return float(d.max()), int(d.size)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=4097)
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--full-frames", type=int, default=3)
    args = ap.parse_args()

    terrain = fractal_terrain(args.size, seed=1)
    t0 = time.perf_counter()
    tree = ApproximationTree.build(terrain, epsilon=0.0, progress=False)
    build_s = time.perf_counter() - t0
    print(f"tree: {len(tree)} nodes in {build_s:.1f} s")
    views = {}
    with Engine(tree, cache_bytes=3 << 30) as engine:
        renderer = engine.ctx.info["GL_RENDERER"]
        d = terrain.domain
        (cx, cy), zmax = d.center, float(tree.bboxes[0, 5])
        cameras = {
            # The whole terrain, seen from the south at 40°.
            "overview": overview_camera(tree.bboxes[0], engine.scale),
            # Low over the southern edge, looking north across the terrain.
            "low_oblique": Camera.look_at(
                (cx, d.ymin - 2000.0, zmax + 3000.0), (cx, cy, 0.0), fov=60.0
            ),
        }
        for name, camera in cameras.items():
            engine.cache.release()
            cut, cut_g = Cut(alpha=1.0, gamma=math.inf), Cut(alpha=1.0, gamma=2.0)
            lod = measure(engine, camera, args.frames, cut)
            lod["max_screen_error_px"], lod["pixels_checked"] = screen_error(engine, camera, cut)
            lod_g = measure(engine, camera, args.frames, cut_g)
            lod_g["max_screen_error_px"], lod_g["pixels_checked"] = screen_error(
                engine, camera, cut_g
            )
            engine.cache.release()  # the reference starts from an empty cache
            full = measure(engine, camera, args.full_frames, Cut(full_resolution=True))
            views[name] = {"lod_alpha1": lod, "lod_alpha1_gamma2": lod_g, "full_resolution": full}
            for cut in (lod, lod_g):
                cut["triangle_ratio"] = full["triangles"] / cut["triangles"]
                cut["draw_time_ratio"] = full["draw_ms_median"] / cut["draw_ms_median"]
            for key in ("lod_alpha1", "lod_alpha1_gamma2"):
                r = views[name][key]
                print(
                    f"{name} {key}: {r['triangles']} vs {full['triangles']} triangles "
                    f"({r['triangle_ratio']:.1f}×), draw {r['draw_ms_median']:.1f} vs "
                    f"{full['draw_ms_median']:.1f} ms ({r['draw_time_ratio']:.1f}×), "
                    f"max screen error {r['max_screen_error_px']:.3f} px"
                )

    result = {
        "benchmark": "LOD cut vs full resolution, oblique views, 1280 × 720, alpha = 1 px",
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "gl_renderer": renderer,
        },
        "dem": f"fractal {args.size}², 10 m cells, 1000 m relief, seed 1",
        "tree": {
            "nodes": len(tree),
            "build_seconds": build_s,
            "epsilon": 0.0,
            "max_points": tree.max_points,
        },
        "views": views,
        "targets": {"triangle_ratio": 50, "draw_time_ratio": 20, "max_screen_error_px": 1.0},
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "render.json").write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
