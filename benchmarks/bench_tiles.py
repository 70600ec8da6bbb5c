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
a fresh subprocess instead, the baseline's (its own code on PYTHONPATH, writing
``--baseline-compression``: ``none``, its float32 content, by default; ``default`` for a
checkout older than the option) and ours per compression taking turns, repeat after repeat:
the tiles/s ratios compare writes that met the same load. Results go to
benchmarks/results/tiles.json; ``--plot`` draws tiles/s and bytes per tile of each variant.

    python benchmarks/bench_tiles.py [--fractal-size 4097] [--workers 2] [--repeats 3]
        [--compressions meshopt,draco,none] [--baseline /tmp/base-checkout]
        [--baseline-compression none] [--plot]
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
variant = sys.argv[3]
kwargs = {"compression": sys.argv[4] if variant == "baseline" else variant}
if kwargs["compression"] == "default":
    kwargs = {}
t0 = time.perf_counter()
figures = write_3dtiles(tree, sys.argv[2], **kwargs)
print(json.dumps({"seconds": time.perf_counter() - t0, "tiles": figures["tiles"],
                  "bytes": figures["bytes"]}))
"""


def _against(
    name: str, store: Path, baseline: Path, base_compression: str, compressions, repeats, folder
) -> dict:
    """Serial writes in subprocesses, baseline and ours per compression taking turns; the
    baseline writes ``base_compression`` (``default``: its default, for a checkout older than
    the ``compression`` argument)."""
    variants = ["baseline", *compressions]
    runs: dict[str, list[dict]] = {v: [] for v in variants}
    for _ in range(repeats):
        for variant in variants:
            out = folder / f"{name}-{variant}-sub"
            env = dict(os.environ, PYTHONPATH=str(baseline if variant == "baseline" else REPO))
            # cwd: not the repository, whose approxtree would shadow the baseline's.
            done = subprocess.run(
                [sys.executable, "-c", _WORKER, str(store), str(out), variant, base_compression],
                env=env,
                cwd=folder,
                capture_output=True,
                text=True,
                check=True,
            )
            runs[variant].append(json.loads(done.stdout.strip().splitlines()[-1]))
            shutil.rmtree(out)
    row: dict = {
        "tree": name,
        "baseline_compression": base_compression,
        "runs": {v: [r["seconds"] for r in rs] for v, rs in runs.items()},
    }
    base = statistics.median(r["seconds"] for r in runs["baseline"])
    for variant, rs in runs.items():
        seconds = statistics.median(r["seconds"] for r in rs)
        row[variant] = {
            "tiles_per_second": rs[0]["tiles"] / seconds,
            "bytes_per_tile": rs[0]["bytes"] / rs[0]["tiles"],
            "tiles_per_second_vs_baseline": base / seconds,
        }
    return row


def plot(report: dict, out: Path) -> None:
    """Per tree of a ``--baseline`` run: tiles/s (median, and each run as a dot) and bytes per
    tile of the baseline and of each compression."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in report["results"] if "baseline_compression" in r]
    fig, axes = plt.subplots(2, len(rows), figsize=(5.0 * len(rows), 6.5), squeeze=False)
    for j, row in enumerate(rows):
        variants = list(row["runs"])
        labels = [
            f"main ({row['baseline_compression']})" if v == "baseline" else v for v in variants
        ]
        x = range(len(variants))
        tps = [row[v]["tiles_per_second"] for v in variants]
        axes[0, j].bar(x, tps, color=["grey"] + ["C0"] * (len(variants) - 1))
        for k, v in enumerate(variants):
            tiles = row[v]["tiles_per_second"] * statistics.median(row["runs"][v])
            axes[0, j].plot([k] * len(row["runs"][v]), [tiles / s for s in row["runs"][v]], "k.")
            axes[0, j].annotate(
                f"{row[v]['tiles_per_second_vs_baseline']:.2f}×",
                (k, max(tps[k], tiles / min(row["runs"][v]))),
                xytext=(0, 4),
                textcoords="offset points",
                ha="center",
            )
        axes[0, j].set(title=row["tree"], ylabel="tiles/s (serial, median)", xticks=list(x))
        axes[0, j].set_xticklabels(labels)
        axes[1, j].bar(x, [row[v]["bytes_per_tile"] for v in variants], color="C1")
        axes[1, j].set(ylabel="bytes per tile (GLB)", yscale="log", xticks=list(x))
        axes[1, j].set_xticklabels(labels)
    fig.suptitle(f"3D Tiles writes, {report['machine']['cpus']} CPUs, load {report['load'][0]:.1f}")
    fig.tight_layout()
    fig.savefig(out, dpi=100)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fractal-size", type=int, default=4097)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--compressions", default="meshopt,draco,none")
    parser.add_argument("--baseline", type=Path, default=None)
    parser.add_argument("--baseline-compression", default="none")
    parser.add_argument("--out", type=Path, default=RESULTS / "tiles.json")
    parser.add_argument("--plot", action="store_true", help="also write the JSON's .png")
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
                row = _against(
                    name,
                    store,
                    args.baseline,
                    args.baseline_compression,
                    compressions,
                    args.repeats,
                    folder,
                )
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
        "baseline_compression": args.baseline_compression if args.baseline else None,
        "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(f"wrote {args.out}")
    if args.plot and args.baseline is not None:
        plot(report, args.out.with_suffix(".png"))
        print(f"wrote {args.out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
