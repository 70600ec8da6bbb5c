"""3D Tiles writing speed and size: tiles per second, serial vs dask workers, bytes per tile.

Trees: the NC DEM of ../shared/data (ε = 1 m) and a fractal DEM (4097² by default, ε = 1 m,
10 m cells, placed with no CRS: local ENU frame). Each tree is built, saved as a store and
loaded lazily (verify off, as `approxtree tiles` does), then its tileset is written
``--repeats`` times in this process (1 worker) and as dask tasks on a LocalCluster of
``--workers`` processes (its start included, as a user's run has it), interleaved (serial,
parallel, serial, ...) so both meet the same machine load; medians are reported. Bytes per
tile are the GLB sizes (skirts and normals included, untextured); for reference,
cesium-terrain-builder's heightmap-1.0 tiles have a fixed size of 65 × 65 × 2 + 2 = 8452 bytes
before gzip (the format's size, not a measurement). Results go to benchmarks/results/tiles.json.

    python benchmarks/bench_tiles.py [--fractal-size 4097] [--workers 2] [--repeats 3]
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

RESULTS = Path(__file__).resolve().parent / "results"
DATA = Path(
    os.environ.get("APPROXTREE_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")
)
CTB_HEIGHTMAP_BYTES = 65 * 65 * 2 + 2


def _tree(name: str, terrain, epsilon: float, folder: Path):
    import approxtree as at
    from approxtree.tree.tree_store import save_tree

    t0 = time.perf_counter()
    tree = at.ApproximationTree.build(terrain, epsilon=epsilon)
    build = time.perf_counter() - t0
    path = folder / f"{name}.zarr"
    save_tree(tree, path)
    return at.load_tree(path, verify=False), build


def _bench(name: str, tree, workers: int, repeats: int, folder: Path) -> dict:
    from approxtree.tiles import write_3dtiles

    runs: dict[str, list[dict]] = {"serial": [], "workers": []}
    for _ in range(repeats):
        for kind, n in (("serial", 1), ("workers", workers)):
            out = folder / f"{name}-{kind}"
            figures = write_3dtiles(tree, out, workers=n)
            runs[kind].append(figures)
            shutil.rmtree(out)
    serial = statistics.median(f["seconds"] for f in runs["serial"])
    parallel = statistics.median(f["seconds"] for f in runs["workers"])
    first = runs["serial"][0]
    return {
        "tree": name,
        "nodes": len(tree.errors),
        "tiles": first["tiles"],
        "bytes": first["bytes"],
        "bytes_per_tile": first["bytes_per_tile"],
        "serial_seconds": serial,
        "serial_tiles_per_second": first["tiles"] / serial,
        "workers": workers,
        "workers_seconds": parallel,
        "workers_tiles_per_second": first["tiles"] / parallel,
        "speedup": serial / parallel,
        "runs": {k: [f["seconds"] for f in v] for k, v in runs.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fractal-size", type=int, default=4097)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=RESULTS / "tiles.json")
    args = parser.parse_args()

    import approxtree as at
    from approxtree.datasets import fractal_terrain

    results = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        trees = []
        nc = DATA / "nc" / "elev_ned_30m.tif"
        if nc.is_file():
            trees.append(("nc", at.open_terrain(str(nc))))
        else:
            print(f"skipping NC: {nc} is absent")
        n = args.fractal_size
        trees.append((f"fractal{n}", fractal_terrain(n, seed=1, relief=1000.0, cell_size=10.0)))
        for name, terrain in trees:
            tree, build = _tree(name, terrain, 1.0, folder)
            row = _bench(name, tree, args.workers, args.repeats, folder)
            row["build_seconds"] = build
            row["ctb_heightmap_bytes"] = CTB_HEIGHTMAP_BYTES
            results.append(row)
            print(json.dumps({k: v for k, v in row.items() if k != "runs"}))
    report = {
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        "load": os.getloadavg(),
        "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
