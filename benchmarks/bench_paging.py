"""Paging renderer over a fly-over: frame time, stand-ins and RSS with caches of a given size.

A tree (``--tree PATH``, or one built from a seeded fractal of ``--dem-size``² at ε = 1 m and
saved, so patches are read from the store on demand) is flown over along a loop of ``--frames``
frames at ``--size``: the eye circles the domain centre at 0.35 of its width, 1/15 of the
diagonal above the highest point, looking ahead and down. Each frame is one interactive
``Engine.render(..., paging=Paging(wait=False))`` on headless EGL (Mesa llvmpipe on a CPU-only
machine) with CPU and GPU caches of ``--cache-mb`` each and at most ``--max-uploads`` uploads
per frame: the provider loads in the background, stand-ins are drawn meanwhile. Per frame:
wall time of the render call, whether it drew a stand-in, the process RSS (sampled after the
frame). Each
cache size given runs in its own process (peers side by side: RSS must follow the caches, not
the terrain seen).

    python benchmarks/bench_paging.py [--tree PATH] [--frames 600] [--size 1280x720]
        [--alpha 1] [--cache-mb 512] [--peer-cache-mb 64] [--dem-size 2049] [--max-uploads 32]
        [--out benchmarks/results/paging.json]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

RESULTS = Path(__file__).resolve().parent / "results"


def loop_cameras(tree, frames: int, scale) -> list:
    """Cameras of a loop over the domain (see the module docstring)."""
    from approxtree.render import Camera

    b = np.asarray(tree.bboxes[0], dtype=np.float64)
    lo, hi = b[:3], b[3:]
    centre = 0.5 * (lo[:2] + hi[:2])
    width = float(min(hi[:2] - lo[:2]))
    diag = float(np.linalg.norm(hi[:2] - lo[:2]))
    height = hi[2] + diag / 15.0
    cams = []
    for k in range(frames):
        t = 2.0 * math.pi * k / frames
        eye = (*(centre + 0.35 * width * np.array([math.cos(t), math.sin(t)])), height)
        ahead = t + 0.6
        look = (*(centre + 0.2 * width * np.array([math.cos(ahead), math.sin(ahead)])), lo[2])
        cams.append(Camera.look_at(eye, look, fov=60))
    return cams


def rss_parts() -> tuple[int, int]:
    """(anonymous, file-backed) resident bytes of this process (Linux /proc; file-backed
    pages are mapped files such as a memory-mapped tree store: the kernel reclaims them)."""
    parts = {"RssAnon:": 0, "RssFile:": 0}
    with open("/proc/self/status") as f:
        for line in f:
            key = line.split(maxsplit=1)[0]
            if key in parts:
                parts[key] = int(line.split()[1]) * 1024
    return parts["RssAnon:"], parts["RssFile:"]


def run_one(args: argparse.Namespace) -> dict:
    """One fly-over in this process; returns its figures."""
    from approxtree import load_tree
    from approxtree.render import Cut, Engine, Paging

    proc = psutil.Process()
    rss0 = proc.memory_info().rss
    tree = load_tree(args.tree)
    w, h = (int(v) for v in args.size.lower().split("x"))
    cache = int(args.cache_mb * (1 << 20))
    rows = []
    with Engine(tree, cache_bytes=cache, cpu_cache_bytes=cache) as eng:
        cams = loop_cameras(tree, args.frames, eng.scale)
        rss_open = proc.memory_info().rss
        for cam in cams:
            t0 = time.perf_counter()
            frame = eng.render(
                cam, (w, h), Cut(args.alpha, math.inf), paging=Paging(False, args.max_uploads)
            )
            ms = (time.perf_counter() - t0) * 1e3
            rows.append(
                {
                    "ms": ms,
                    "stand_ins": frame.stats["stand_ins"],
                    "pending": frame.stats["pending"],
                    "patches": frame.stats["patches"],
                    "triangles": frame.stats["triangles"],
                    "gpu_bytes": frame.stats["gpu_bytes"],
                    "cpu_bytes": frame.stats["cpu_bytes"],
                    "rss": proc.memory_info().rss,
                    "rss_anon": rss_parts()[0],
                    "rss_file": rss_parts()[1],
                }
            )
        provider = eng.provider.figures()
    ms = np.array([r["ms"] for r in rows])
    rss = np.array([r["rss"] for r in rows]) / 2**20
    anon = np.array([r["rss_anon"] for r in rows]) / 2**20
    file_backed = np.array([r["rss_file"] for r in rows]) / 2**20
    warm = max(1, len(rows) // 10)
    mb = 1 << 20
    return {
        "cache_mb": args.cache_mb,
        "frames": len(rows),
        "frame_ms_median": round(float(np.median(ms)), 2),
        "frame_ms_p95": round(float(np.percentile(ms, 95)), 2),
        "frames_with_stand_ins": int(sum(r["stand_ins"] > 0 for r in rows)),
        "frames_pending": int(sum(r["pending"] > 0 for r in rows)),
        "stand_ins_median": float(np.median([r["stand_ins"] for r in rows])),
        "pending_median": float(np.median([r["pending"] for r in rows])),
        "patches_median": int(np.median([r["patches"] for r in rows])),
        "triangles_median": int(np.median([r["triangles"] for r in rows])),
        "gpu_mb_max": round(max(r["gpu_bytes"] for r in rows) / mb, 1),
        "cpu_mb_max": round(max(r["cpu_bytes"] for r in rows) / mb, 1),
        "rss_mb_before_tree": round(rss0 / mb, 1),
        "rss_mb_engine_open": round(rss_open / mb, 1),
        "rss_mb_peak": round(float(rss.max()), 1),
        # Flat after warm-up: the peak of the first tenth against the peak of the rest.
        "rss_mb_peak_warmup": round(float(rss[:warm].max()), 1),
        "rss_mb_peak_after_warmup": round(float(rss[warm:].max()), 1) if len(rss) > warm else None,
        "rss_mb_by_decile": _deciles(rss),
        # RSS split: anonymous memory (caches, arrays, driver buffers) and mapped files.
        "rss_anon_mb_peak_warmup": round(float(anon[:warm].max()), 1),
        "rss_anon_mb_peak_after_warmup": round(float(anon[warm:].max()), 1)
        if len(anon) > warm
        else None,
        "rss_anon_mb_by_decile": _deciles(anon),
        "rss_file_mb_by_decile": _deciles(file_backed),
        # Cache fill: RSS must follow it, then stay flat.
        "caches_mb_by_decile": _deciles(
            np.array([r["cpu_bytes"] + r["gpu_bytes"] for r in rows]) / mb
        ),
        "provider": provider,
    }


def _deciles(values: np.ndarray) -> list[float]:
    """values at frames 0, 10 %, ..., 100 % of the run."""
    n = len(values)
    return [round(float(values[min(n - 1, k * n // 10)]), 1) for k in range(11)]


def build_tree(size: int, folder: Path) -> Path:
    """A fractal of size² at ε = 1 m, saved to ``folder``; returns its path."""
    from approxtree import ApproximationTree
    from approxtree.datasets import fractal_terrain

    terrain = fractal_terrain(size, seed=7, relief=1000.0)
    tree = ApproximationTree.build(terrain, epsilon=1.0, progress=False)
    path = folder / f"fractal_{size}.zarr"
    tree.save(path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", help="tree store (default: build a fractal)")
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--alpha", type=float, default=1.0)
    parser.add_argument("--cache-mb", type=float, default=512.0)
    parser.add_argument("--peer-cache-mb", type=float, action="append", default=None)
    parser.add_argument("--dem-size", type=int, default=2049)
    parser.add_argument("--max-uploads", type=int, default=32)
    parser.add_argument("--out", default=str(RESULTS / "paging.json"))
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args)))
        return
    with tempfile.TemporaryDirectory() as tmp:
        built = None
        if args.tree is None:
            t0 = time.perf_counter()
            args.tree = str(build_tree(args.dem_size, Path(tmp)))
            built = {"dem_size": args.dem_size, "build_and_save_s": time.perf_counter() - t0}
        peers = args.peer_cache_mb if args.peer_cache_mb is not None else [args.cache_mb / 8]
        runs = []
        for cache_mb in [args.cache_mb, *peers]:
            cmd = [
                *(sys.executable, __file__, "--one", "--tree", args.tree),
                *("--frames", str(args.frames), "--size", args.size, "--alpha", str(args.alpha)),
                *("--cache-mb", str(cache_mb), "--max-uploads", str(args.max_uploads)),
            ]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            runs.append(json.loads(out.strip().splitlines()[-1]))
            print(json.dumps({k: v for k, v in runs[-1].items() if k != "provider"}), flush=True)
        tree_bytes = (
            sum(p.stat().st_size for p in Path(args.tree).rglob("*"))
            if Path(args.tree).is_dir()
            else Path(args.tree).stat().st_size
        )
    result = {
        "tree": args.tree if built is None else f"(built) fractal {args.dem_size}²",
        "tree_bytes": tree_bytes,
        "built": built,
        "frames": args.frames,
        "size": args.size,
        "alpha": args.alpha,
        "max_uploads": args.max_uploads,
        "machine": {"platform": platform.platform(), "cpus": psutil.cpu_count()},
        "runs": runs,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
