"""Where one windowed build spends its time, part by part, in one process (one thread).

Every block task of a windowed DEM runs here one after the other (numba on one thread, as on a
cluster worker), writing its height chunks into the store (zarr regions): per block, the
task's seconds (window read, subtree, ancestor measures) and its region write (read of the
owned chunks, compression, write), and the bytes its result takes pickled (what travels back
to the client). Then the client's parts: assembling the tree from the block results, making
the tree, and the save (upper levels, node table, patches, overview, metadata; the heights
are moved in, not copied). These are the figures the 262144² estimate in docs/benchmarks.md
scales up.

    python benchmarks/bench_block_parts.py DEM.tif [--block-size 2048] [--epsilon 1]

Results: benchmarks/results/block_parts.json and block_parts.png.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dem", type=Path)
    parser.add_argument("--block-size", type=int, default=2048)
    parser.add_argument("--epsilon", type=float, default=1.0)
    parser.add_argument("--max-points", type=int, default=33 * 33)
    parser.add_argument("--out-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)

    from approxtree import ApproximationTree
    from approxtree.io import open_terrain
    from approxtree.tree.blocks import build_blocked, make_tasks, plan_blocks, run_block
    from approxtree.tree.policy import StrategyPolicy
    from approxtree.tree.store_regions import HeightRegions, height_regions
    from approxtree.tree.tree_store import save_tree

    load = [round(os.getloadavg()[0], 2)]
    g = open_terrain(args.dem, windowed=True)
    policy = StrategyPolicy.resolve("type")
    with tempfile.TemporaryDirectory(dir=args.dem.parent) as folder:
        out = Path(folder) / "tree.zarr"
        with height_regions(out, g) as regions:
            t0 = time.perf_counter()
            plan = plan_blocks(g, 4, args.block_size)
            tasks = make_tasks(g, plan, args.epsilon, args.max_points, 4, policy, 1, regions)
            plan_s = time.perf_counter() - t0
            # CPU seconds too (a shared machine stretches wall time, not CPU): of each task, and
            # of its region write, timed around HeightRegions.write.
            write_cpu: list[float] = []
            real_write = HeightRegions.write

            def timed_write(self, heights, index):
                c = time.process_time()
                try:
                    return real_write(self, heights, index)
                finally:
                    write_cpu.append(time.process_time() - c)

            HeightRegions.write = timed_write  # type: ignore[method-assign]
            # The first task compiles the kernels: run it twice, keep the second.
            run_block(tasks[0])
            write_cpu.clear()
            results, task_cpu = [], []
            for t in tasks:
                c = time.process_time()
                results.append(run_block(t))
                task_cpu.append(time.process_time() - c)
            HeightRegions.write = real_write  # type: ignore[method-assign]
            # The client's part of the build: build_blocked with a run that hands back the
            # results already made (its band figures come from the root, as on a cluster).
            t0, c0 = time.perf_counter(), time.process_time()
            built = build_blocked(
                g,
                args.epsilon,
                args.max_points,
                4,
                policy,
                args.block_size,
                run=lambda _tasks: results,
                regions=regions,
            )
            assemble_s, assemble_cpu = time.perf_counter() - t0, time.process_time() - c0
            t0 = time.perf_counter()
            tree = ApproximationTree._from_built(g, built, args.epsilon, args.max_points, 4, policy)
            tree_s = time.perf_counter() - t0
            t0, c0 = time.perf_counter(), time.process_time()
            nbytes = save_tree(tree, out, regions=regions)
            save_s, save_cpu = time.perf_counter() - t0, time.process_time() - c0
    load.append(round(os.getloadavg()[0], 2))
    task_s = [r.seconds - r.write_seconds for r in results]
    write_s = [r.write_seconds for r in results]
    result_bytes = [len(pickle.dumps(r)) for r in results]
    report = {
        "benchmark": "parts of a windowed build with region writes, one process, one thread",
        "dem": str(args.dem),
        "shape": list(g.shape),
        "block_size": args.block_size,
        "blocks": len(tasks),
        "nodes": len(tree),
        "store_bytes": nbytes,
        "loadavg_1min_before_after": load,
        "per_block": {
            "task_seconds_median": round(statistics.median(task_s), 4),
            "task_seconds_total": round(sum(task_s), 3),
            "write_seconds_median": round(statistics.median(write_s), 4),
            "write_seconds_total": round(sum(write_s), 3),
            "task_cpu_seconds_median": round(statistics.median(task_cpu), 4),
            "task_cpu_seconds_total": round(sum(task_cpu), 3),
            "write_cpu_seconds_median": round(statistics.median(write_cpu), 4),
            "write_cpu_seconds_total": round(sum(write_cpu), 3),
            "result_bytes_median": int(statistics.median(result_bytes)),
            "result_bytes_max": max(result_bytes),
        },
        "client": {
            "plan_and_tasks_seconds": round(plan_s, 4),
            # plan, tasks (again), assembly of the tree from the block results
            "assemble_seconds": round(assemble_s, 4),
            "assemble_cpu_seconds": round(assemble_cpu, 4),
            "tree_seconds": round(tree_s, 4),
            "save_seconds": round(save_s, 4),
            "save_cpu_seconds": round(save_cpu, 4),
        },
        "tasks": [
            {"seconds": round(a, 4), "write_seconds": round(b, 4), "result_bytes": c}
            for a, b, c in zip(task_s, write_s, result_bytes, strict=True)
        ],
    }
    args.out_dir.mkdir(parents=True, exist_ok=True)
    (args.out_dir / "block_parts.json").write_text(json.dumps(report, indent=2))
    plot(report, args.out_dir / "block_parts.png")
    print(json.dumps({k: v for k, v in report.items() if k != "tasks"}, indent=2))
    return report


def plot(report: dict, out: Path) -> None:
    """Per-block seconds (task, region write) and the client's parts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    tasks = report["tasks"]
    a.bar(range(len(tasks)), [t["seconds"] for t in tasks], label="task (read, subtree)")
    a.bar(
        range(len(tasks)),
        [t["write_seconds"] for t in tasks],
        bottom=[t["seconds"] for t in tasks],
        label="region write",
    )
    a.set(xlabel="block", ylabel="seconds", title=f"{report['blocks']} blocks, one thread")
    a.legend()
    client = report["client"]
    names = ["plan_and_tasks_seconds", "assemble_seconds", "tree_seconds", "save_seconds"]
    b.bar([n.replace("_seconds", "") for n in names], [client[n] for n in names])
    b.set(ylabel="seconds", title="client")
    fig.suptitle(f"{report['shape'][0]}² windowed, load {report['loadavg_1min_before_after']}")
    fig.tight_layout()
    fig.savefig(out, dpi=100)


if __name__ == "__main__":
    main()
