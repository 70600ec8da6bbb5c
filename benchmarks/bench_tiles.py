"""3D Tiles writing speed and size: tiles per second, serial vs dask workers, bytes per tile,
for each content compression (draco, meshopt, none), optionally against a baseline checkout.

Trees: the NC DEM of ../shared/data (ε = 1 m) and a fractal DEM (4097² by default, ε = 1 m,
10 m cells, placed with no CRS: local ENU frame). Each tree is built, saved as a store and
loaded lazily (verify off, as `approxtree tiles` does), then its tileset is written
``--repeats`` times per compression in this process (1 worker) and as dask tasks on a
LocalCluster of ``--workers`` threads (its start included, as a user's run has it),
interleaved (serial, parallel, serial, ...) so all meet the same machine load; medians are
reported. Bytes per tile are the GLB sizes (skirts and normals included, untextured) and
their gzip -6 sizes (what a server sends); the largest bound a tile's lattice adds to its
claim is reported too. For reference, cesium-terrain-builder's heightmap-1.0 tiles have a
fixed size of 65 × 65 × 2 + 2 = 8452 bytes before gzip (the format's size, not a
measurement).

With ``--baseline CHECKOUT`` (a git worktree of an earlier commit) each serial write runs in
a fresh subprocess instead, the baseline's (its own code on PYTHONPATH, float32 content) and
ours per compression taking turns, repeat after repeat: the tiles/s ratios compare writes
that met the same load. Results go to benchmarks/results/tiles.json.

    python benchmarks/bench_tiles.py [--fractal-size 4097] [--workers 2] [--repeats 3]
        [--compressions draco,meshopt,none] [--baseline /tmp/base-checkout]
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parents[1]
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
    return at.load_tree(path, verify=False), build, path


def _gzip_bytes(folder: Path) -> int:
    return sum(len(gzip.compress(p.read_bytes(), 6)) for p in folder.rglob("*.glb"))


def _bench(name: str, tree, compression: str, workers: int, repeats: int, folder: Path) -> dict:
    from approxtree.tiles import write_3dtiles

    runs: dict[str, list[dict]] = {"serial": [], "workers": []}
    gz = 0
    for _ in range(repeats):
        for kind, n in (("serial", 1), ("workers", workers)):
            out = folder / f"{name}-{compression}-{kind}"
            figures = write_3dtiles(tree, out, workers=n, compression=compression)
            runs[kind].append(figures)
            gz = gz or _gzip_bytes(out)
            shutil.rmtree(out)
    serial = statistics.median(f["seconds"] for f in runs["serial"])
    parallel = statistics.median(f["seconds"] for f in runs["workers"])
    first = runs["serial"][0]
    return {
        "tree": name,
        "compression": compression,
        "nodes": len(tree.errors),
        "tiles": first["tiles"],
        "bytes": first["bytes"],
        "bytes_per_tile": first["bytes_per_tile"],
        "gzip_bytes_per_tile": gz / max(first["tiles"], 1),
        "largest_quantization_bound": first["quantization"],
        "serial_seconds": serial,
        "serial_tiles_per_second": first["tiles"] / serial,
        "workers": workers,
        "workers_seconds": parallel,
        "workers_tiles_per_second": first["tiles"] / parallel,
        "speedup": serial / parallel,
        "runs": {k: [f["seconds"] for f in v] for k, v in runs.items()},
    }


#: A serial write in a fresh process (ours or the baseline's, by PYTHONPATH); prints seconds.
_WORKER = """
import json, sys, time
import approxtree as at
from approxtree.tiles import write_3dtiles
tree = at.load_tree(sys.argv[1], verify=False)
kwargs = {} if sys.argv[3] == "baseline" else {"compression": sys.argv[3]}
t0 = time.perf_counter()
figures = write_3dtiles(tree, sys.argv[2], **kwargs)
print(json.dumps({"seconds": time.perf_counter() - t0, "tiles": figures["tiles"],
                  "bytes": figures["bytes"]}))
"""


def _against(name: str, store: Path, baseline: Path, compressions, repeats, folder) -> dict:
    """Serial writes in subprocesses, baseline and ours per compression taking turns."""
    variants = ["baseline", *compressions]
    runs: dict[str, list[dict]] = {v: [] for v in variants}
    for _ in range(repeats):
        for variant in variants:
            out = folder / f"{name}-{variant}-sub"
            env = dict(os.environ, PYTHONPATH=str(baseline if variant == "baseline" else REPO))
            # cwd: not the repository, whose approxtree would shadow the baseline's.
            done = subprocess.run(
                [sys.executable, "-c", _WORKER, str(store), str(out), variant],
                env=env,
                cwd=folder,
                capture_output=True,
                text=True,
                check=True,
            )
            runs[variant].append(json.loads(done.stdout.strip().splitlines()[-1]))
            shutil.rmtree(out)
    row: dict = {"tree": name, "runs": {v: [r["seconds"] for r in rs] for v, rs in runs.items()}}
    base = statistics.median(r["seconds"] for r in runs["baseline"])
    for variant, rs in runs.items():
        seconds = statistics.median(r["seconds"] for r in rs)
        row[variant] = {
            "tiles_per_second": rs[0]["tiles"] / seconds,
            "bytes_per_tile": rs[0]["bytes"] / rs[0]["tiles"],
            "tiles_per_second_vs_baseline": base / seconds,
        }
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fractal-size", type=int, default=4097)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--compressions", default="draco,meshopt,none")
    parser.add_argument("--baseline", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=RESULTS / "tiles.json")
    args = parser.parse_args()
    compressions = args.compressions.split(",")

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
            tree, build, store = _tree(name, terrain, 1.0, folder)
            if args.baseline is not None:
                row = _against(name, store, args.baseline, compressions, args.repeats, folder)
                results.append(row)
                print(json.dumps({k: v for k, v in row.items() if k != "runs"}))
                continue
            for compression in compressions:
                row = _bench(name, tree, compression, args.workers, args.repeats, folder)
                row["build_seconds"] = build
                row["ctb_heightmap_bytes"] = CTB_HEIGHTMAP_BYTES
                results.append(row)
                print(json.dumps({k: v for k, v in row.items() if k != "runs"}))
    report = {
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        "load": os.getloadavg(),
        "baseline": str(args.baseline) if args.baseline else None,
        "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
