"""Dynamic terrain: the cost of ``ApproximationTree.update`` against a full build.

A fractal terrain of --size² cells is built once (the full build's time); then square windows
of each edit size (64² … 2048² by default) are edited at random places (a pit dug 20 m deep)
and the tree updated, --repeats times each (median); the ratio update / full build is the
issue's figure (target ≤ 5 % for a 256² edit of an 8192² terrain). The first update compiles
nothing new (the build's kernels), so every update is timed. Results in
benchmarks/results/update_<size>.json and .png (cost against edit size).

    python benchmarks/bench_update.py [--size 8192] [--edits 64 128 256 512 1024 2048]
        [--repeats 3] [--epsilon 1.0]
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
    args = parser.parse_args()

    from approxtree.datasets import fractal_terrain
    from approxtree.tree.approximation_tree import ApproximationTree

    grid = fractal_terrain(args.size, args.size, seed=1)
    # Warm-up: compile the build's kernels on a small grid first.
    ApproximationTree.build(fractal_terrain(257, 257, seed=2), epsilon=args.epsilon)
    t0 = time.perf_counter()
    tree = ApproximationTree.build(grid, epsilon=args.epsilon)
    build_s = time.perf_counter() - t0
    print(f"full build {args.size}²: {build_s:.2f} s, {len(tree)} nodes", flush=True)
    rng = np.random.default_rng(0)
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
