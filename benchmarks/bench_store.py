"""Tree save and load: zarr tree store (folder) vs zip store, side by side (approxtree no
longer writes the legacy .atree file).

The tree: a 1025² fractal DEM, grid strategy, max_points 9, ε = 0, i.e. a full quadtree of 10
levels (349,525 nodes). For each form: save seconds, load seconds (verify on: every patch
checksum read), seconds to read 2,000 random patches lazily after a load without verify, and
bytes (also ÷ the DEM's bytes as float32 and as held). The batched record gather
(``records_many``) is timed on its own. Median of --repeats runs; JSON to
benchmarks/results/store.json.

    python benchmarks/bench_store.py [--size 1025] [--max-points 9] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def _bytes(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(path) for f in fs)


def _median(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=1025)
    parser.add_argument("--max-points", type=int, default=9)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--patches", type=int, default=2000)
    args = parser.parse_args()

    from approxtree import ApproximationTree, load_tree
    from approxtree.datasets import fractal_terrain

    grid = fractal_terrain(args.size, seed=args.size)
    t0 = time.perf_counter()
    tree = ApproximationTree.build(
        grid, epsilon=0.0, max_points=args.max_points, policy="grid", progress=False
    )
    build = time.perf_counter() - t0
    n = len(tree)
    print(f"{n} nodes built in {build:.2f} s", flush=True)
    patches = [tree.patch(i) for i in range(n)]
    gather = _median(lambda: type(patches[0]).records_many(patches), args.repeats)
    per_node = _median(lambda: [p.to_record() for p in patches], 1)
    rng = np.random.default_rng(0)
    picks = rng.integers(0, n, args.patches)
    dem_bytes = int(np.asarray(grid.heights).nbytes)
    rows = []
    with tempfile.TemporaryDirectory(dir=".") as tmp:
        for name in ("tree.zarr", "tree.zarr.zip"):
            path = Path(tmp) / name

            def save(path=path):
                if path.is_dir():
                    shutil.rmtree(path)
                tree.save(path)

            save_s = _median(save, args.repeats)
            load_s = _median(lambda path=path: load_tree(path, verify=True), args.repeats)

            def read_patches(path=path):
                t = load_tree(path, verify=False)
                for i in picks:
                    t.patch(int(i))

            patch_s = _median(read_patches, 1)
            size = _bytes(path)
            row = {
                "form": name.split(".", 1)[1],
                "save_seconds": round(save_s, 3),
                "load_seconds_verify": round(load_s, 3),
                f"read_{args.patches}_patches_seconds": round(patch_s, 3),
                "bytes": size,
                "bytes_per_dem_byte": round(size / dem_bytes, 4),
                "bytes_per_float32_dem_byte": round(size / (grid.heights.size * 4), 4),
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
    report = {
        "benchmark": "tree save/load: zarr store vs zip store",
        "tree": {
            "dem": f"fractal_terrain({args.size}), {grid.heights.dtype} heights",
            "dem_bytes": dem_bytes,
            "nodes": n,
            "levels": int(tree.levels.max()) + 1,
            "strategy": "grid",
            "max_points": args.max_points,
            "build_seconds": round(build, 3),
        },
        "records_many_seconds": round(gather, 3),
        "per_node_to_record_seconds": round(per_node, 3),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "results": rows,
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "store.json").write_text(json.dumps(report, indent=2))
    print(json.dumps({k: v for k, v in report.items() if k != "results"}))
    print(f"wrote {RESULTS / 'store.json'}")


if __name__ == "__main__":
    main()
