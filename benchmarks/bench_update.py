"""Dynamic terrain: the cost of ``ApproximationTree.update`` against a full build.

A fractal terrain of --size² cells is built once (the full build's time); then square windows
of each edit size (64² … 2048² by default) are edited at random places (a pit dug 20 m deep)
and the tree updated, --repeats times each (median); the ratio update / full build is the
issue's figure (target ≤ 5 % for a 256² edit of an 8192² terrain). Kernels are compiled on
a small grid first; the first update of the large tree (which measures the cells of the
large nodes above it that the build did not, see tree/update_cells.py) and --warmup 256² edits
at random places (after which every large node holds its per-cell figures) are reported on
their own. Results in
benchmarks/results/update_<size>.json and .png (cost against edit size).

--pyramid measures the texture pyramid instead (``textures.rebake``): for each terrain side of
--sizes a fractal's hillshade pyramid is baked whole (numpy), then square windows of each edit
size are edited at random places and the pyramid re-baked (only the tiles the edit reaches, on
every level, into delta files committed by replacing pyramid.json), --repeats times each,
each re-bake right after a full bake of the same terrain into another folder (interleaved, so
both see the same load of a shared machine); the ratio re-bake / full bake is the median of
the pairs' ratios, the issue's figure (target ≤ 5 % for a 256² edit of an 8192² terrain).
The load average is recorded. Results in benchmarks/results/rebake.json and .png (cost
against edit size, one line per terrain size).

    python benchmarks/bench_update.py [--size 8192] [--edits 64 128 256 512 1024 2048]
        [--repeats 3] [--epsilon 1.0] [--warmup 96]
    python benchmarks/bench_update.py --pyramid [--sizes 2048 4096 8192] [--edits ...]
    python benchmarks/bench_update.py --store [--sizes 4096 8192] [--edits 64 256 1024]

--store times ``approxtree update``'s work on a folder store (``store_update.update_store``:
load, read the chunks it needs, update, write the new store linking unchanged chunks, swap):
for each terrain side of --sizes (or --size), --repeats times a full build + save of a
fractal, each followed by one update of each edit size (--edits) at a random place, so each
update is compared with the build + save next to it on a shared host; the ratio is
update / (build + save), medians reported per edit size with the load average. Results in
benchmarks/results/update_store_<size>.json and .png.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def cell_rect(grid, r0: int, c0: int, rows: int, cols: int):
    """The world rect of cells rows r0.., columns c0.. (pixel corners)."""
    from approxtree.geometry.rect import Rect

    t = grid.transform
    xs = (t.c + c0 * t.a, t.c + (c0 + cols) * t.a)
    ys = (t.f + r0 * t.e, t.f + (r0 + rows) * t.e)
    return Rect(min(xs), min(ys), max(xs), max(ys))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=8192)
    parser.add_argument("--edits", type=int, nargs="+", default=[64, 128, 256, 512, 1024, 2048])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--epsilon", type=float, default=1.0)
    parser.add_argument("--warmup", type=int, default=96, help="untimed 256² edits first")
    parser.add_argument("--pyramid", action="store_true", help="time pyramid re-bakes instead")
    parser.add_argument("--sizes", type=int, nargs="+", default=[2048, 4096, 8192])
    parser.add_argument("--work", type=Path, default=None, help="folder for the pyramids")
    parser.add_argument("--store", action="store_true", help="time store updates instead")
    args = parser.parse_args()
    if args.pyramid:
        pyramid_main(args)
        return
    if args.store:
        store_main(args)
        return

    from approxtree.datasets import fractal_terrain
    from approxtree.tree.approximation_tree import ApproximationTree

    grid = fractal_terrain(args.size, args.size, seed=1)
    # Warm-up: compile the build's and the update's kernels on a small grid first.
    small = fractal_terrain(1025, 1025, seed=2)
    warm = ApproximationTree.build(small, epsilon=args.epsilon)
    warm.update(cell_rect(small, 5, 5, 4, 4), np.zeros((4, 4)))
    builds = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        tree = ApproximationTree.build(grid, epsilon=args.epsilon)
        builds.append(time.perf_counter() - t0)
    build_s = statistics.median(builds)
    print(f"full build {args.size}²: {build_s:.2f} s (median), {len(tree)} nodes", flush=True)
    rng = np.random.default_rng(0)
    # The first update measures the large nodes above it whole (their per-cell figures are
    # kept for the next updates): reported on its own.
    c = args.size // 2
    first = tree.update(
        cell_rect(grid, c, c, 256, 256), np.array(grid.heights[c : c + 256, c : c + 256]) - 20.0
    )
    print(f"first update (256², per-cell figures made): {first.seconds * 1e3:.1f} ms", flush=True)
    # Warm-up edits all over the terrain: every large node gets its per-cell figures once
    # (a simulation editing the same terrain for long pays this once); reported too.
    warmup = []
    for _ in range(args.warmup):
        r0, c0 = (int(v) for v in rng.integers(0, args.size - 256 + 1, 2))
        pit = np.array(grid.heights[r0 : r0 + 256, c0 : c0 + 256]) - 1.0
        warmup.append(tree.update(cell_rect(grid, r0, c0, 256, 256), pit).seconds)
    if warmup:
        print(f"{len(warmup)} warm-up updates: {sum(warmup):.2f} s in all", flush=True)
    rows = []
    for edit in args.edits:
        if edit > args.size:
            continue
        times, rebuilt = [], []
        for _ in range(args.repeats):
            r0, c0 = (int(v) for v in rng.integers(0, args.size - edit + 1, 2))
            pit = np.array(grid.heights[r0 : r0 + edit, c0 : c0 + edit]) - 20.0
            report = tree.update(cell_rect(grid, r0, c0, edit, edit), pit)
            times.append(report.seconds)
            rebuilt.append(len(report.rebuilt))
        median = statistics.median(times)
        rows.append(
            {
                "edit": edit,
                "seconds": median,
                "all_seconds": times,
                "ratio": median / build_s,
                "rebuilt_nodes": int(statistics.median(rebuilt)),
            }
        )
        print(
            f"edit {edit}²: {median * 1e3:.1f} ms ({100 * median / build_s:.2f} % of the build), "
            f"{rows[-1]['rebuilt_nodes']} nodes rebuilt",
            flush=True,
        )
    out = {
        "size": args.size,
        "epsilon": args.epsilon,
        "nodes": len(tree),
        "build_seconds": build_s,
        "build_all_seconds": builds,
        "first_update_seconds": first.seconds,
        "warmup_update_seconds": warmup,
        "edits": rows,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"update_{args.size}.json"
    path.write_text(json.dumps(out, indent=2))
    plot(out, path.with_suffix(".png"))
    print(f"wrote {path}")


def pyramid_main(args: argparse.Namespace) -> None:
    """Full bake against re-bakes of each edit size, for each terrain size (module doc)."""
    import tempfile

    from approxtree.datasets import fractal_terrain
    from approxtree.textures.bake import bake
    from approxtree.textures.rebake import rebake

    work = Path(tempfile.mkdtemp(dir=args.work))
    # Warm-up: compile the shading and halving kernels on a small terrain first.
    small = fractal_terrain(1025, 1025, seed=2)
    bake(small, work / "warm", gl=False)
    rebake(work / "warm", small, cell_rect(small, 5, 5, 4, 4))
    rng = np.random.default_rng(0)
    terrains = []
    load = [os.getloadavg()]
    for size in args.sizes:
        grid = fractal_terrain(size, size, seed=1)
        folder = work / f"pyramid{size}"
        bake(grid, folder, gl=False)
        z = grid.heights
        rows, bakes = [], []
        for edit in args.edits:
            if edit > size:
                continue
            times, ratios, tiles = [], [], []
            for _ in range(args.repeats):
                # A full bake of the terrain as it is (another folder), then the re-bake.
                t0 = time.perf_counter()
                bake(grid, work / "reference", gl=False)
                bakes.append(time.perf_counter() - t0)
                r0, c0 = (int(v) for v in rng.integers(0, size - edit + 1, 2))
                z[r0 : r0 + edit, c0 : c0 + edit] -= 20.0
                result = rebake(folder, grid, cell_rect(grid, r0, c0, edit, edit))
                times.append(result.seconds)
                ratios.append(result.seconds / bakes[-1])
                tiles.append(sum(result.tiles))
            median = statistics.median(times)
            rows.append(
                {
                    "edit": edit,
                    "seconds": median,
                    "all_seconds": times,
                    "ratio": statistics.median(ratios),
                    "all_ratios": ratios,
                    "tiles": int(statistics.median(tiles)),
                    "tiles_total": sum(result.tiles_total),
                }
            )
            print(
                f"  {size}², edit {edit}²: {median * 1e3:.1f} ms ({100 * rows[-1]['ratio']:.2f} % "
                f"of the bake beside it), {rows[-1]['tiles']} of {rows[-1]['tiles_total']} tiles",
                flush=True,
            )
        bake_s = statistics.median(bakes)
        print(f"full bake {size}²: {bake_s:.2f} s (median of {len(bakes)})", flush=True)
        terrains.append(
            {"size": size, "bake_seconds": bake_s, "bake_all_seconds": bakes, "edits": rows}
        )
        load.append(os.getloadavg())
    out = {"shading": "topographic (numpy)", "load_average": load, "terrains": terrains}
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / "rebake.json"
    path.write_text(json.dumps(out, indent=2))
    plot_rebake(out, path.with_suffix(".png"))
    print(f"wrote {path}")


def store_main(args: argparse.Namespace) -> None:
    """Store updates against a full build + save, per terrain size (module doc)."""
    import tempfile

    from approxtree.datasets import fractal_terrain
    from approxtree.geometry.grid import Grid
    from approxtree.tree import store_update
    from approxtree.tree.approximation_tree import ApproximationTree

    work = Path(tempfile.mkdtemp(dir=args.work))
    # Warm-up: compile the build's, the update's and the store's kernels on a small grid.
    small = fractal_terrain(1025, 1025, seed=2)
    ApproximationTree.build(small, epsilon=args.epsilon).save(work / "warm.zarr")
    warm = Grid(np.zeros((4, 4)), small.transform, index_offset=(5, 5), allow_empty=True)
    store_update.update_store(work / "warm.zarr", warm, verify=False)
    sizes = args.sizes if args.sizes != [2048, 4096, 8192] else [args.size]
    # The store write inside each update is timed on its own.
    writes: list[float] = []
    plain_save = store_update.save_tree

    def timed_save(*a: object) -> int:
        t = time.perf_counter()
        try:
            return plain_save(*a)  # type: ignore[arg-type]
        finally:
            writes.append(time.perf_counter() - t)

    rng = np.random.default_rng(0)
    for size in sizes:
        grid = fractal_terrain(size, size, seed=1)
        store = work / f"store_{size}.zarr"
        builds: list[float] = []
        saves: list[float] = []
        rows = []
        for repeat in range(args.repeats):
            # A full build + save, then one update of each edit size (interleaved: the host
            # is shared, so each update is compared with the build + save next to it).
            t0 = time.perf_counter()
            tree = ApproximationTree.build(grid, epsilon=args.epsilon)
            builds.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            tree.save(store)
            saves.append(time.perf_counter() - t0)
            full = builds[-1] + saves[-1]
            for edit in args.edits:
                if edit > size:
                    continue
                r0, c0 = (int(v) for v in rng.integers(0, size - edit + 1, 2))
                pit = np.array(grid.heights[r0 : r0 + edit, c0 : c0 + edit]) - 20.0
                window = Grid(pit, grid.transform, index_offset=(r0, c0), allow_empty=True)
                store_update.save_tree = timed_save  # type: ignore[assignment]
                try:
                    t0 = time.perf_counter()
                    report = store_update.update_store(store, window, verify=False)
                    seconds = time.perf_counter() - t0
                finally:
                    store_update.save_tree = plain_save
                row = {
                    "repeat": repeat,
                    "edit": edit,
                    "seconds": seconds,
                    "tree_update_seconds": report.seconds,
                    "write_seconds": writes[-1],
                    "load_seconds": seconds - report.seconds - writes[-1],
                    "build_save_seconds": full,
                    "ratio": seconds / full,
                    "rebuilt": len(report.rebuilt),
                }
                rows.append(row)
                print(
                    f"{size}² store, {edit}² edit: {seconds:.3f} s = load + read "
                    f"{row['load_seconds']:.3f} + tree update {report.seconds:.3f} + write "
                    f"{writes[-1]:.3f} s; {100 * row['ratio']:.2f} % of build + save "
                    f"{full:.2f} s",
                    flush=True,
                )
        medians = {}
        for edit in sorted({r["edit"] for r in rows}):
            mine = [r for r in rows if r["edit"] == edit]
            keys = ("seconds", "load_seconds", "tree_update_seconds", "write_seconds", "ratio")
            m = {key: statistics.median(r[key] for r in mine) for key in keys}
            medians[str(edit)] = m
            print(
                f"median {size}², {edit}²: {m['seconds']:.3f} s ({100 * m['ratio']:.2f} %): "
                f"load + read {m['load_seconds']:.3f}, tree update "
                f"{m['tree_update_seconds']:.3f}, write {m['write_seconds']:.3f}",
                flush=True,
            )
        out = {
            "size": size,
            "epsilon": args.epsilon,
            "build_seconds": statistics.median(builds),
            "build_all_seconds": builds,
            "save_seconds": statistics.median(saves),
            "save_all_seconds": saves,
            "load_average": list(os.getloadavg()),
            "updates": rows,
            "medians": medians,
        }
        RESULTS.mkdir(parents=True, exist_ok=True)
        path = RESULTS / f"update_store_{size}.json"
        path.write_text(json.dumps(out, indent=2))
        plot_store(out, path.with_suffix(".png"))
        print(f"wrote {path}", flush=True)


def plot_store(out: dict, path: Path) -> None:
    """Store update time as a share of build + save against edit side (medians)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    edits = sorted(int(e) for e in out["medians"])
    shares = [100 * out["medians"][str(e)]["ratio"] for e in edits]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(edits, shares, "o-", label="approxtree update (store)")
    ax.axhline(5.0, color="r", ls=":", label="5 % of build + save")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("edit side (cells)")
    ax.set_ylabel("store update / (build + save) (%)")
    ax.set_title(f"store update on a {out['size']}² fractal (ε = {out['epsilon']})")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_rebake(out: dict, path: Path) -> None:
    """Re-bake time as a share of the full bake against edit side, one line per terrain."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for terrain in out["terrains"]:
        edits = [r["edit"] for r in terrain["edits"]]
        shares = [100 * r["ratio"] for r in terrain["edits"]]
        ax.loglog(edits, shares, "o-", label=f"{terrain['size']}² terrain")
    ax.axhline(5.0, color="r", ls=":", label="5 % of a full bake")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("edit side (cells)")
    ax.set_ylabel("re-bake / full bake (%)")
    ax.set_title("pyramid re-bake of the tiles an edit reaches")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot(out: dict, path: Path) -> None:
    """Update time against edit side, with the full build and its 5 % as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    edits = [r["edit"] for r in out["edits"]]
    secs = [r["seconds"] for r in out["edits"]]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(edits, secs, "o-", label="update")
    ax.axhline(out["build_seconds"], color="k", ls="--", label="full build")
    ax.axhline(0.05 * out["build_seconds"], color="r", ls=":", label="5 % of full build")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("edit side (cells)")
    ax.set_ylabel("seconds")
    ax.set_title(f"tree update on a {out['size']}² fractal (ε = {out['epsilon']})")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
