"""Error vs vertex count and error vs memory of the four strategies on Crater Lake.

As in Evans, Kirkpatrick & Townsend (figs 8–11) and Garland & Heckbert (figs 17–20): every
strategy (grid, nonregular, rtin, tin) approximates the whole crater.stm terrain over a sweep of
max_error goals and of max_points budgets; each run records the vertex and triangle counts, the
exact max and RMS errors over all data points, the seconds, and the bytes the patch stores:

    grid        index range and steps (6 × int64), vertices implicit in the shared grid
    nonregular  chosen row and column indices (int32 each)
    tin, rtin   vertex (row, col) indices and triangles (int32) plus 5 float64 statistics

(for rtin the run also records the size of the implicit bintree encoding, one bit per node of
the right-triangle tree, which approxtree does not store). A side measurement times the
non-regular refinement against a from-scratch variant that re-evaluates every cell after each
insertion, checking both choose the same lines; another builds a tree with each strategy at the
same ε and s (nodes, leaf vertices, patch bytes). Results: benchmarks/results/curves.json,
curves_vertices.png and curves_memory.png.

    python benchmarks/bench_curves.py [--dem ../shared/data/scape/crater.stm]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import time
from pathlib import Path

import numpy as np
from numba import njit

from approxtree.kernels.row_column import _cell_worst, _worse

RESULTS = Path(__file__).resolve().parent / "results"
DEFAULT_DEM = Path(__file__).resolve().parents[2] / "shared" / "data" / "scape" / "crater.stm"
STRATEGIES = ["grid", "nonregular", "rtin", "tin"]
ERRORS = [1.0, 2.0, 5.0, 10.0, 20.0, 50.0]
POINTS = [500, 1000, 2000, 5000, 10_000, 20_000, 50_000]


def run_case(terrain, strategy: str, goal: str, value: float) -> dict:
    """One approximation of the whole terrain and its figures."""
    from approxtree.patches.approximate import approximate

    kwargs = {goal: value if goal == "max_error" else int(value)}
    mesh = approximate(terrain, strategy, **kwargs)
    row = {
        "strategy": strategy,
        "goal": goal,
        "value": value,
        "vertices": len(mesh.vertices),
        "triangles": len(mesh.triangles),
        "max_error": mesh.max_error,
        "rms_error": mesh.rms_error,
        "bytes": int(mesh.patch.nbytes),
        "seconds": mesh.seconds,
    }
    if strategy == "rtin":
        # A bintree with T leaves has 2T − 1 nodes: one bit each says leaf or split.
        row["bintree_bytes"] = math.ceil((2 * len(mesh.triangles) - 1) / 8)
    return row


@njit(cache=True)
def _naive_refine(heights, rows_n, cols_n, epsilon):
    """Row–column insertion that re-evaluates every cell after each insertion (reference)."""
    rows = [0, rows_n - 1]
    cols = [0, cols_n - 1]
    while True:
        best = -1.0
        br = -1
        bc = -1
        for i in range(len(rows) - 1):
            for j in range(len(cols) - 1):
                e, r, c = _cell_worst(heights, rows[i], rows[i + 1], cols[j], cols[j + 1])
                # Same rule as the kernel: ties go to the first point in row-major order.
                if _worse(e, r * cols_n + c, best, br * cols_n + bc):
                    best, br, bc = e, r, c
        if best <= epsilon or best <= 0.0:
            return np.array(rows), np.array(cols)
        if br not in rows:
            rows.append(br)
            rows.sort()
        if bc not in cols:
            cols.append(bc)
            cols.sort()


def refinement_speed(terrain, errors: list[float], repeats: int = 3) -> list[dict]:
    """Median seconds of the strip-wise refinement and of the from-scratch variant."""
    from approxtree.patches.nonregular import refine_windows

    h = terrain.heights
    ranges = np.array([[0, h.shape[0] - 1, 0, h.shape[1] - 1]], dtype=np.int64)
    refine_windows(terrain, ranges, 50.0, 0)
    _naive_refine(h[:20, :20].copy(), 20, 20, 50.0)
    out = []
    for eps in errors:
        fast, slow = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            ((rows, cols),) = refine_windows(terrain, ranges, eps, 0)
            fast.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            nrows, ncols = _naive_refine(h, h.shape[0], h.shape[1], eps)
            slow.append(time.perf_counter() - t0)
        same = np.array_equal(rows, nrows) and np.array_equal(cols, ncols)
        out.append(
            {
                "max_error": eps,
                "rows": len(rows),
                "cols": len(cols),
                "strip_seconds_median": statistics.median(fast),
                "from_scratch_seconds_median": statistics.median(slow),
                "speedup": statistics.median(slow) / statistics.median(fast),
                "same_lines": bool(same),
            }
        )
        print(
            f"refinement ε={eps:>5}: {len(rows)}×{len(cols)} lines, strips "
            f"{out[-1]['strip_seconds_median']:.3f} s, from scratch "
            f"{out[-1]['from_scratch_seconds_median']:.3f} s "
            f"(×{out[-1]['speedup']:.1f}), same lines: {same}"
        )
    return out


def tree_sizes(terrain, epsilons: list[float], max_points: int = 33 * 33) -> list[dict]:
    """Trees of each strategy at the same ε and s: nodes, leaf vertices and patch bytes."""
    from approxtree import ApproximationTree

    out = []
    for eps in epsilons:
        for s in STRATEGIES:
            t0 = time.perf_counter()
            tree = ApproximationTree.build(
                terrain, epsilon=eps, max_points=max_points, policy=s, progress=False
            )
            seconds = time.perf_counter() - t0
            leaves = [tree.patch(int(i)) for i in tree.leaves]
            row = {
                "strategy": s,
                "epsilon": eps,
                "max_points": max_points,
                "nodes": len(tree),
                "leaves": len(leaves),
                "leaf_vertices": int(sum(len(p.vertices) for p in leaves)),
                "patch_bytes": int(sum(tree.patch(i).nbytes for i in range(len(tree)))),
                "seconds": seconds,
            }
            out.append(row)
            print(
                f"tree ε={eps:<5} {s:<10} {row['nodes']:>6} nodes {row['leaf_vertices']:>7} "
                f"leaf vertices {row['patch_bytes']:>9} B {seconds:.2f} s"
            )
    return out


def plot(runs: list[dict], path_vertices: Path, path_memory: Path) -> None:
    """Error vs vertices and error vs bytes, max and RMS panels, one line per strategy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = dict(
        zip(STRATEGIES, ["tab:gray", "tab:orange", "tab:green", "tab:blue"], strict=True)
    )
    for path, xkey, xlabel in (
        (path_vertices, "vertices", "vertices"),
        (path_memory, "bytes", "bytes stored by the patch"),
    ):
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
        for ax, ykey, title in zip(
            axes, ("max_error", "rms_error"), ("max error", "RMS error"), strict=True
        ):
            for s in STRATEGIES:
                for goal, style in (("max_error", "-o"), ("max_points", "--s")):
                    rows = sorted(
                        (r for r in runs if r["strategy"] == s and r["goal"] == goal),
                        key=lambda r: r[xkey],
                    )
                    # Log axes: leave out exact (0) and failed (inf) runs.
                    pts = [(r[xkey], r[ykey]) for r in rows if 0 < r[ykey] < math.inf]
                    if not pts:
                        continue
                    x, y = zip(*pts, strict=True)
                    label = f"{s} ({'error goal' if goal == 'max_error' else 'point budget'})"
                    ax.plot(x, y, style, color=colours[s], label=label, ms=4, lw=1.2)
                    if s == "rtin" and xkey == "bytes" and goal == "max_error":
                        # The bintree encoding Evans et al. count (not stored by approxtree).
                        xb = [r["bintree_bytes"] for r in rows if 0 < r[ykey] < math.inf]
                        ax.plot(xb, y, ":^", color=colours[s], label="rtin (bintree bits)", ms=4)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel(xlabel)
            ax.set_ylabel(f"{title} (m)")
            ax.set_title(f"Crater Lake: {title} vs {xlabel}")
            ax.grid(True, which="both", alpha=0.3)
        axes[0].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dem", type=Path, default=DEFAULT_DEM)
    parser.add_argument("--errors", type=float, nargs="+", default=ERRORS)
    parser.add_argument("--points", type=int, nargs="+", default=POINTS)
    args = parser.parse_args()

    import approxtree as at

    terrain = at.open_terrain(args.dem)
    # Warm the kernels up so the first timed run does not include compilation.
    small = at.Grid(terrain.heights[:40, :40], terrain.transform)
    for s in STRATEGIES:
        run_case(small, s, "max_error", 10.0)
    runs = []
    for goal, values in (("max_error", args.errors), ("max_points", args.points)):
        for value in values:
            for s in STRATEGIES:
                row = run_case(terrain, s, goal, value)
                runs.append(row)
                print(
                    f"{goal}={value:<7} {s:<10} {row['vertices']:>7} v {row['triangles']:>7} t "
                    f"max {row['max_error']:8.2f} rms {row['rms_error']:7.3f} "
                    f"{row['bytes']:>8} B {row['seconds']:.3f} s"
                )
    speed = refinement_speed(terrain, [5.0, 10.0, 20.0])
    trees = tree_sizes(terrain, [2.0, 10.0])
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = {
        "dem": str(args.dem),
        "shape": list(terrain.shape),
        "points": terrain.point_count,
        "machine": platform.platform(),
        "runs": runs,
        "nonregular_refinement": speed,
        "trees": trees,
    }
    (RESULTS / "curves.json").write_text(json.dumps(out, indent=1))
    plot(runs, RESULTS / "curves_vertices.png", RESULTS / "curves_memory.png")
    print(f"wrote {RESULTS / 'curves.json'}, curves_vertices.png, curves_memory.png")


if __name__ == "__main__":
    main()
