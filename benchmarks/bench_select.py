"""Selection time on a tree of more than 100,000 nodes (target: at most 5 ms per view).

A 4097² fractal DEM is built with max_points = 9 × 9 and ε = 0 (about 350,000 nodes: every
node splits until its patch is exact). Eight views — the oblique overview, low oblique views
from the four sides, a close-up and two from straight above — are selected REPEAT times each
at alpha = 1 px and gamma = 2 px² on a 1280 × 720 viewport, texel sizes computed once as the
Engine does. Reported: the median and the worst median over the views, and the node counts.
Results go to benchmarks/results/select.json.

    python benchmarks/bench_select.py [--size 4097] [--max-points 81] [--repeat 50]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from approxtree import ApproximationTree
from approxtree.datasets import fractal_terrain
from approxtree.render import Camera, FrameState, display_scale, overview_camera, select
from approxtree.render.visual_error import texel_sizes

RESULTS = Path(__file__).resolve().parent / "results"


def views(tree) -> dict[str, Camera]:
    """Named cameras over the tree's domain."""
    d = tree.terrain.domain
    (cx, cy), w = d.center, d.width
    z = float(tree.bboxes[0, 5])
    return {
        "overview": overview_camera(tree.bboxes[0], display_scale(tree.terrain)),
        "south_low": Camera.look_at((cx, d.ymin - 0.1 * w, z + 0.05 * w), (cx, cy, 0), 60),
        "north_low": Camera.look_at((cx, d.ymax + 0.1 * w, z + 0.05 * w), (cx, cy, 0), 60),
        "west_low": Camera.look_at((d.xmin - 0.1 * w, cy, z + 0.05 * w), (cx, cy, 0), 60),
        "east_low": Camera.look_at((d.xmax + 0.1 * w, cy, z + 0.05 * w), (cx, cy, 0), 60),
        "close_up": Camera.look_at((cx, cy - 0.05 * w, z + 0.02 * w), (cx, cy, 0), 60),
        "above": Camera.look_at((cx, cy, z + w), (cx, cy + 1, 0), 60),
        "above_low": Camera.look_at((cx, cy, z + 0.1 * w), (cx, cy + 1, 0), 60),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=4097)
    ap.add_argument("--max-points", type=int, default=9 * 9)
    ap.add_argument("--repeat", type=int, default=50)
    args = ap.parse_args()

    terrain = fractal_terrain(args.size, seed=1)
    t0 = time.perf_counter()
    tree = ApproximationTree.build(terrain, epsilon=0.0, max_points=args.max_points)
    build_s = time.perf_counter() - t0
    texels = texel_sizes(tree)
    scale = display_scale(terrain)
    rows = []
    for name, cam in views(tree).items():
        fs = FrameState.from_camera(cam, (1280, 720), tree.bboxes[0], tree.origin, scale)
        sel = select(tree, fs, 1.0, 2.0, texels)  # warm-up (numba cache load)
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            sel = select(tree, fs, 1.0, 2.0, texels)
            times.append((time.perf_counter() - t0) * 1e3)
        rows.append(
            {
                "view": name,
                "ms_median": statistics.median(times),
                "ms_min": min(times),
                **sel.stats,
            }
        )
        print(f"{name:10s} {statistics.median(times):7.3f} ms  {sel.stats}")
    medians = [r["ms_median"] for r in rows]
    result = {
        "benchmark": "selection time, 1280 × 720, alpha = 1 px, gamma = 2 px²",
        "machine": {"cpus": __import__("os").cpu_count(), "python": platform.python_version()},
        "dem": f"fractal {args.size}²",
        "max_points": args.max_points,
        "nodes": len(tree),
        "build_seconds": build_s,
        "ms_median_over_views": float(np.median(medians)),
        "ms_worst_view": max(medians),
        "target_ms": 5.0,
        "views": rows,
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "select.json").write_text(json.dumps(result, indent=2))
    print(
        f"{len(tree)} nodes: median {result['ms_median_over_views']:.3f} ms, "
        f"worst view {result['ms_worst_view']:.3f} ms (target 5 ms)"
    )


if __name__ == "__main__":
    main()
