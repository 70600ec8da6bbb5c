"""Dynamic terrain: the cost of ``ApproximationTree.update`` against a full build.

A fractal terrain of --size² cells is built once (the full build's time); then square windows
of each edit size (64² … 2048² by default) are edited at random places (a pit dug 20 m deep)
and the tree updated, --repeats times each (median); the ratio update / full build is the
issue's figure (target ≤ 5 % for a 256² edit of an 8192² terrain). Kernels are compiled on
a small grid first; the first update of the large tree (which measures the large nodes above
it whole, see tree/update_cells.py) and --warmup 256² edits at random places (after which
every large node holds its per-cell figures) are reported on their own. Results in
benchmarks/results/update_<size>.json and .png (cost against edit size).

    python benchmarks/bench_update.py [--size 8192] [--edits 64 128 256 512 1024 2048]
        [--repeats 3] [--epsilon 1.0] [--warmup 96]
"""

from __future__ import annotations

import argparse
import json
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
    args = parser.parse_args()

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
