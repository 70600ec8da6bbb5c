"""Viewer frame rate over recorded fly-overs, bounded uploads side by side with unbounded.

Two terrains: the NC case study DEM (../shared/data/nc/elev_ned_30m.tif, 500 × 450, 30 m)
and a 4097² fractal DEM (10 m cells, 1000 m relief), each built at ε = 1 m. For each, a
fly-over is recorded into benchmarks/results/viewer_path_<case>.json: a flight along the
domain's southern edge, just outside it, at 1/15 of the diagonal above the highest point,
looking over the terrain (SEGMENTS keyframes of FRAMES frames each), and a path of JUMPS
abrupt camera cuts to oblique views from all around, each held HOLD frames (the worst case
for uploads: a whole new cut wanted at once). The viewer replays it in a
real 1280 × 720 window under Xvfb (Mesa llvmpipe on this CPU-only machine), one fresh process
per run, at alpha = 1 and 4 px (γ off: no texture pyramid), with an upload budget of
32 meshes per frame and, side by side, without a budget (every wanted mesh uploaded in the
frame that wants it). Frame time is the wall time of the whole frame (events, selection,
uploads, draw, overlay, swap).

    python benchmarks/bench_viewer.py [--frames 20] [--segments 4] [--jumps 8] [--hold 6]
        [--cases nc,fractal]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from approxtree import ApproximationTree
from approxtree.datasets import fractal_terrain
from approxtree.io import open_terrain
from approxtree.viewer.xvfb import virtual_display

RESULTS = Path(__file__).resolve().parent / "results"
DATA = Path(os.environ.get("APPROXTREE_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
SIZE = "1280x720"


def flyover(tree, segments: int, frames: int) -> list[dict]:
    """Keyframes (world coordinates) of a flight along the domain's southern edge, just
    outside it, looking north-east over the terrain, then turning to look north-west.

    The eye stays outside the root box: over the box, the selection's α of a node right
    below the eye is that of a vertical segment seen end-on (≈ 0 px), so a flight over the
    domain would draw little more than the root (see the notes of the viewer branch).
    """
    b = np.asarray(tree.bboxes[0], dtype=np.float64)
    lo, hi = b[:3], b[3:]
    size = hi[:2] - lo[:2]
    diag = float(np.linalg.norm(size))
    height = hi[2] + diag / 15.0
    y = lo[1] - 0.03 * diag
    path = []
    for k in range(segments + 1):
        t = k / segments
        x = lo[0] + (0.05 + 0.9 * t) * size[0]
        look = lo[0] + (0.3 + 0.4 * (1.0 - t)) * size[0]
        path.append(
            {
                "eye": [float(x), float(y), float(height)],
                "target": [float(look), float(lo[1] + 0.45 * size[1]), float(lo[2])],
                "frames": 1 if k == 0 else frames,
            }
        )
    return path


def jumps(tree, count: int, hold: int) -> list[dict]:
    """Keyframes of abrupt cuts: every ``hold`` frames the camera jumps to another oblique
    view from outside the domain (around it, nearer each time), the worst case for uploads."""
    b = np.asarray(tree.bboxes[0], dtype=np.float64)
    lo, hi = b[:3], b[3:]
    centre = 0.5 * (lo + hi)
    diag = float(np.linalg.norm(hi[:2] - lo[:2]))
    path = []
    for k in range(count):
        angle = 2.0 * math.pi * (0.37 * k) - math.pi / 2
        reach = 0.75 - 0.2 * (k % 3)
        eye = centre[:2] + reach * diag * np.array([math.cos(angle), math.sin(angle)])
        look = centre[:2] + 0.2 * diag * np.array([math.cos(angle), math.sin(angle)])
        view = {
            "eye": [float(eye[0]), float(eye[1]), float(hi[2] + diag / 12.0)],
            "target": [float(look[0]), float(look[1]), float(lo[2])],
        }
        # Each jump: one frame to cut there, then held.
        path.append({**view, "frames": 1})
        path.append({**view, "frames": hold - 1})
    return path


def run(display: str, tree_path: Path, script: Path, alpha: float, uploads: int) -> dict:
    """Replay ``script`` in a fresh viewer process; figures of its stats lines."""
    stats_path = script.with_suffix(f".a{alpha:g}.u{uploads}.jsonl")
    cmd = [
        sys.executable, "-m", "approxtree", "view", str(tree_path), "--script", str(script),
        "--stats", str(stats_path), "--size", SIZE, "--alpha", str(alpha), "--gamma", "inf",
        "--max-uploads", str(uploads),
    ]  # fmt: skip
    t0 = time.perf_counter()
    subprocess.run(cmd, env=dict(os.environ, DISPLAY=display), check=True, capture_output=True)
    wall = time.perf_counter() - t0
    lines = [json.loads(s) for s in stats_path.read_text().splitlines()]
    ms = [s["frame_ms"] for s in lines]
    # The first frame also loads the compiled kernels; report it apart.
    rest = ms[1:]
    return {
        "alpha": alpha,
        "max_uploads": uploads,
        "frames": len(ms),
        "fps": round(len(rest) / (sum(rest) / 1e3), 2),
        "frame_ms_median": round(statistics.median(rest), 2),
        "frame_ms_p95": round(float(np.percentile(rest, 95)), 2),
        "frame_ms_max": round(max(rest), 2),
        "first_frame_ms": round(ms[0], 2),
        "triangles_median": int(statistics.median(s["triangles"] for s in lines)),
        "patches_median": int(statistics.median(s["patches"] for s in lines)),
        "paged_uploads_max": max(s["paged_uploads"] for s in lines),
        "upload_ms_max": max(s["upload_ms"] for s in lines),
        "frames_with_stand_ins": sum(1 for s in lines if s["pending"] > 0),
        "max_alpha_max": max(s["max_alpha"] for s in lines),
        "process_seconds": round(wall, 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20, help="frames per fly-over segment")
    ap.add_argument("--segments", type=int, default=4)
    ap.add_argument("--jumps", type=int, default=8, help="camera cuts of the jump path")
    ap.add_argument("--hold", type=int, default=6, help="frames held after each cut")
    ap.add_argument("--cases", default="nc,fractal")
    args = ap.parse_args()
    RESULTS.mkdir(exist_ok=True)
    cases = []
    for name in args.cases.split(","):
        if name == "nc":
            dem = DATA / "nc" / "elev_ned_30m.tif"
            if not dem.exists():
                print(f"skipping nc: {dem} is absent")
                continue
            terrain = open_terrain(dem)
            label = "NC elev_ned_30m 500x450"
        else:
            terrain = fractal_terrain(4097, seed=1)
            label = "fractal 4097x4097"
        t0 = time.perf_counter()
        tree = ApproximationTree.build(terrain, epsilon=1.0, progress=False)
        build_s = time.perf_counter() - t0
        tree_path = RESULTS / f"viewer_{name}.zarr"
        tree.save(tree_path)
        for kind in ("flyover", "jumps"):
            if kind == "flyover":
                path = flyover(tree, args.segments, args.frames)
            else:
                path = jumps(tree, args.jumps, args.hold)
            script = RESULTS / f"viewer_{kind}_{name}.json"
            script.write_text(json.dumps(path, indent=1))
            cases.append((name, kind, label, tree, tree_path, script, build_s))
    out = {
        "machine": platform.platform(),
        "size": SIZE,
        "gamma": None,
        "cases": [],
    }
    with virtual_display() as display:
        for name, kind, label, tree, tree_path, script, build_s in cases:
            runs = []
            for alpha in (1.0, 4.0):
                for uploads in (32, 0):
                    r = run(display, tree_path, script, alpha, uploads)
                    runs.append(r)
                    print(name, kind, json.dumps(r))
            out["cases"].append(
                {
                    "case": name,
                    "path_kind": kind,
                    "terrain": label,
                    "nodes": len(tree),
                    "build_seconds": round(build_s, 2),
                    "path": str(script),
                    "runs": runs,
                }
            )
    for case in out["cases"]:
        for r in case["runs"]:
            r["max_alpha_max"] = r["max_alpha_max"] if math.isfinite(r["max_alpha_max"]) else None
    (RESULTS / "viewer.json").write_text(json.dumps(out, indent=2))
    print(f"wrote {RESULTS / 'viewer.json'}")


if __name__ == "__main__":
    main()
