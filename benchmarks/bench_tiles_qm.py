"""Cesium terrain tiles (``tiles --format quantized-mesh``): tiles per second and bytes per tile.

Cases: the NC DEM of ../shared/data (500 × 450, 30 m, EPSG:32119) and a seeded fractal DEM
(default 4097², 10 m cells, placed in UTM 18N). Each case is written serially (``workers=1``)
and as dask tasks on a LocalCluster of ``--workers`` processes, alternating run by run
(``--repeats``) so both see the same machine load; the figures are medians and their ratio.
Worker runs include starting the cluster (each worker process imports approxtree and loads its
numba cache), as a user's run does. The deepest level is made to ``--leaf-error`` metres.

Bytes per tile are set against a peer measured in the same run: the same tiles as
cesium-terrain-builder's default output, heightmap-1.0 (65 × 65 uint16 heights + child mask +
water-mask byte = 8452 bytes, then gzip as ctb-tile writes them), sampled from the same terrain
the same way. No published per-tile size of ctb-tile's quantized-mesh (``-f Mesh``) output was
found (the one public comparison, tum-gis/cesium-terrain-builder-docker#1, reports equal folder
sizes for both formats on one dataset, 34 MB each): it is reported as unknown.

    python benchmarks/bench_tiles_qm.py [--repeats 3] [--workers 2] [--fractal-size 4097]
        [--fractal-maxzoom N] [--data-dir DIR]

Results: benchmarks/results/tiles_qm.json.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def fractal_grid(size: int):
    """A size² fractal Grid, 10 m cells, north-west corner at UTM 18N (500 000, 4 900 000)."""
    from affine import Affine

    from approxtree.datasets import fractal_heights
    from approxtree.geometry import Grid

    z = fractal_heights(size, seed=1, relief=1000.0)
    return Grid(z, Affine(10.0, 0.0, 500000.0, 0.0, -10.0, 4900000.0), crs="EPSG:32618")


def heightmap_peer(
    terrain, tiles: list[tuple[int, int, int]], samples: int
) -> tuple[list[int], list[float]]:
    """gzip bytes of each tile as heightmap-1.0 (65 × 65 uint16 (h + 1000) · 5, row 0 north,
    child mask byte, water mask byte), sampled like our tiles; and that heightmap's max error
    (bilinear between its posts) over our tile's samples ÷ the level's error."""
    from scipy.interpolate import RegularGridInterpolator

    from approxtree.tiles.geographic import level_error, tile_bounds
    from approxtree.tiles.sampling import TileSampler

    sampler = TileSampler(terrain)
    sizes, ratios = [], []
    t65 = np.linspace(0.0, 1.0, 65)
    ts = np.linspace(0.0, 1.0, samples)
    pts = np.stack(np.meshgrid(ts, ts, indexing="ij"), axis=-1).reshape(-1, 2)
    for level, x, y in tiles:
        bounds = tile_bounds(level, x, y)
        h, _ = sampler.sample(bounds, 65)
        q = np.clip(np.rint((h[::-1] + 1000.0) * 5.0), 0, 65535).astype("<u2")
        raw = q.tobytes() + b"\x0f" + b"\x00"
        sizes.append(len(gzip.compress(raw, compresslevel=6, mtime=0)))
        fine, _ = sampler.sample(bounds, samples)
        approx = RegularGridInterpolator((t65, t65), q[::-1] / 5.0 - 1000.0)(pts)
        err = np.abs(approx.reshape(samples, samples) - fine).max()
        ratios.append(float(err / level_error(level)))
    return sizes, ratios


def run_case(
    name: str, terrain, workers: int, repeats: int, maxzoom: int | None, leaf_error: float = 1.0
) -> dict:
    from approxtree.tiles import write_quantized_mesh

    times: dict[int, list[float]] = {1: [], workers: []}
    result = None
    with tempfile.TemporaryDirectory(prefix="bench-qm-") as tmp:
        for _ in range(repeats):
            for w in (1, workers):
                out = Path(tmp, f"w{w}")
                t0 = time.perf_counter()
                result = write_quantized_mesh(
                    terrain, out, maxzoom=maxzoom, workers=w, leaf_error=leaf_error
                )
                times[w].append(time.perf_counter() - t0)
                shutil.rmtree(out)
    assert result is not None
    rows = result["results"]
    n = len(rows)
    sizes = [r["bytes"] for r in rows]
    deepest = max(r["level"] for r in rows)
    deep = [r for r in rows if r["level"] == deepest]
    peer, peer_ratio = heightmap_peer(
        terrain, [(r["level"], r["x"], r["y"]) for r in rows], result["samples"]
    )
    serial = statistics.median(times[1])
    parallel = statistics.median(times[workers])
    return {
        "case": name,
        "tiles": n,
        "levels": result["levels"],
        "samples": result["samples"],
        "seconds_serial": [round(t, 3) for t in times[1]],
        f"seconds_workers_{workers}": [round(t, 3) for t in times[workers]],
        "tiles_per_second_serial": round(n / serial, 2),
        f"tiles_per_second_workers_{workers}": round(n / parallel, 2),
        "speedup": round(serial / parallel, 3),
        "bytes_per_tile_mean": round(statistics.mean(sizes), 1),
        "bytes_per_tile_median": statistics.median(sizes),
        "bytes_per_tile_deepest_level_median": statistics.median(r["bytes"] for r in deep),
        "vertices_per_tile_deepest_level_median": statistics.median(r["vertices"] for r in deep),
        "worst_error_ratio": round(result["worst_error_ratio"], 6),
        "leaf_error": leaf_error,
        "leaf_max_error": round(result["leaf_max_error"], 4),
        "peer_heightmap_1_0_gzip_bytes_per_tile_mean": round(statistics.mean(peer), 1),
        "peer_heightmap_1_0_gzip_bytes_per_tile_median": statistics.median(peer),
        "bytes_ratio_ours_to_heightmap": round(sum(sizes) / sum(peer), 3),
        "peer_heightmap_error_ratio_median": round(statistics.median(peer_ratio), 3),
        "peer_heightmap_error_ratio_max": round(max(peer_ratio), 3),
        "peer_heightmap_tiles_over_level_error": sum(r > 1.0 for r in peer_ratio),
        "ctb_quantized_mesh_bytes_per_tile": "unknown (no published figure found)",
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--fractal-size", type=int, default=4097)
    ap.add_argument("--fractal-maxzoom", type=int, default=None)
    ap.add_argument("--fractal-repeats", type=int, default=1)
    ap.add_argument("--data-dir", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--leaf-error", type=float, default=1.0)
    args = ap.parse_args()

    from approxtree.io import open_terrain

    cases = []
    nc = args.data_dir / "nc" / "elev_ned_30m.tif"
    if nc.exists():
        cases.append(
            run_case("nc", open_terrain(nc), args.workers, args.repeats, None, args.leaf_error)
        )
        print(json.dumps(cases[-1]), flush=True)
    else:
        print(f"skipping NC: {nc} is absent", file=sys.stderr)
    grid = fractal_grid(args.fractal_size)
    cases.append(
        run_case(
            f"fractal_{args.fractal_size}",
            grid,
            args.workers,
            args.fractal_repeats,
            args.fractal_maxzoom,
            args.leaf_error,
        )
    )
    print(json.dumps(cases[-1]), flush=True)
    RESULTS.mkdir(exist_ok=True)
    report = {
        "benchmark": "tiles_qm",
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
        "args": {k: str(v) for k, v in vars(args).items()},
        "cases": cases,
    }
    (RESULTS / "tiles_qm.json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
