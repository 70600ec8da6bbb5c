"""Blocked tree builds on dask: serial vs block by block vs --workers 1 vs --workers 2.

One fractal DEM per size (4097² by default, ε = 1 m, default policy). Side by side, in one
run and one process:

- ``serial``: today's builder (``build_levels``, numba threads on every core);
- ``blocks``: the blocked build in this process (``build_blocked`` without dask, one block
  after the other, numba threads on every core);
- ``workers1`` / ``workers2``: the blocked build on a LocalCluster of 1 / 2 processes with one
  thread each (cluster started and warmed up before the clock starts; its start time is
  reported apart). The 2-worker run writes the dask performance report (task stream).

Each blocked tree is checked against the serial one (node count, errors). The machine's load
and the cores it gives at the time (two pure-Python loops at once vs one alone) are recorded
before and after: on a shared machine they bound the speed-up. Per-block cost is
the task's own seconds (build + ancestor measures), per million points. Results go to
benchmarks/results/blocks.json and blocks-report-<size>.html.

    python benchmarks/bench_blocks.py [--sizes 4097 8193] [--block-size 1024] [--epsilon 1]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def _recording(run, sink: list):
    """A ``run`` of build_blocked that keeps the block results for per-block figures."""

    def wrapped(tasks):
        results = run(tasks) if run is not None else [_run_block(t) for t in tasks]
        sink.extend(results)
        return results

    return wrapped


def _run_block(task):
    from approxtree.tree.blocks import run_block

    return run_block(task)


def _spin(_: int) -> float:
    """Seconds of a fixed pure-Python loop (CPU only)."""
    t0 = time.perf_counter()
    s = 0
    for i in range(5_000_000):
        s += i
    return time.perf_counter() - t0


def available_cores(processes: int = 2) -> float:
    """Cores this machine gives now: ``processes`` × (time of one loop alone ÷ time of each of
    ``processes`` loops at once). A shared machine under load gives fewer than it has, which
    bounds any speed-up measured in the same run."""
    import multiprocessing as mp

    with mp.get_context("spawn").Pool(processes) as pool:
        alone = min(pool.map(_spin, [0]) for _ in range(2))[0]
        together = statistics.mean(pool.map(_spin, range(processes), chunksize=1))
    return processes * alone / together


def _same(a, b) -> bool:
    return len(a.patches) == len(b.patches) and all(
        pa.error == pb.error for pa, pb in zip(a.patches, b.patches, strict=True)
    )


def _block_figures(results: list) -> dict:
    secs = [r.seconds for r in results]
    per_mpt = [r.seconds / (r.points / 1e6) for r in results]
    return {
        "blocks": len(results),
        "block_seconds_median": statistics.median(secs),
        "block_seconds_max": max(secs),
        "block_seconds_sum": sum(secs),
        "block_seconds_per_million_points_median": statistics.median(per_mpt),
        "block_nodes_median": statistics.median(len(r.levels) for r in results),
    }


def case(size: int, epsilon: float, block_size: int, report_dir: Path) -> dict:
    from distributed import Client, LocalCluster

    from approxtree.datasets import fractal_terrain
    from approxtree.tree.blocks import build_blocked, plan_blocks
    from approxtree.tree.builder import build_levels
    from approxtree.tree.distributed import dask_runner
    from approxtree.tree.policy import StrategyPolicy

    policy = StrategyPolicy("type")
    grid = fractal_terrain(size, seed=size)
    # Warm the kernels up in this process.
    small = fractal_terrain(257, seed=1)
    build_levels(small, epsilon, 33 * 33, 4, policy, progress=False)
    build_blocked(small, epsilon, 33 * 33, 4, policy, block_size=64)

    row: dict = {"size": size, "epsilon": epsilon, "block_size": block_size}
    plan = plan_blocks(grid, 4, block_size)
    row["block_level"] = plan.block_level
    row["plan_blocks"] = len(plan.blocks)

    # The machine may be shared: its load puts the timings in context.
    row["load_average_before"] = os.getloadavg()[0]
    row["available_cores_before"] = available_cores()
    t0 = time.perf_counter()
    serial = build_levels(grid, epsilon, 33 * 33, 4, policy, progress=False)
    row["serial_seconds"] = time.perf_counter() - t0
    row["nodes"] = len(serial.patches)

    results: list = []
    t0 = time.perf_counter()
    blocked = build_blocked(
        grid, epsilon, 33 * 33, 4, policy, block_size, run=_recording(None, results)
    )
    row["blocks_seconds"] = time.perf_counter() - t0
    row["blocks_identical"] = _same(blocked, serial)
    row["in_process"] = _block_figures(results)

    for workers in (1, 2):
        t0 = time.perf_counter()
        cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0"
        )
        client = Client(cluster)
        row[f"workers{workers}_cluster_start_seconds"] = time.perf_counter() - t0
        try:
            # Warm-up: every worker loads the numba kernels from the cache once.
            build_blocked(
                small, epsilon, 33 * 33, 4, policy, block_size=64,
                run=dask_runner(client=client, progress=False),
            )  # fmt: skip
            report = report_dir / f"blocks-report-{size}.html" if workers == 2 else None
            results = []
            run = dask_runner(client=client, progress=False, report=report)
            t0 = time.perf_counter()
            built = build_blocked(
                grid, epsilon, 33 * 33, 4, policy, block_size, run=_recording(run, results)
            )
            row[f"workers{workers}_seconds"] = time.perf_counter() - t0
            row[f"workers{workers}_identical"] = _same(built, serial)
            row[f"workers{workers}"] = _block_figures(results)
            if report is not None:
                row["report"] = str(report)
        finally:
            client.close()
            cluster.close()
    row["load_average_after"] = os.getloadavg()[0]
    row["available_cores_after"] = available_cores()
    row["speedup_workers2_over_workers1"] = row["workers1_seconds"] / row["workers2_seconds"]
    row["speedup_workers2_over_serial"] = row["serial_seconds"] / row["workers2_seconds"]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[4097])
    parser.add_argument("--epsilon", type=float, default=1.0)
    parser.add_argument("--block-size", type=int, default=1024)
    args = parser.parse_args()
    RESULTS.mkdir(exist_ok=True)
    rows = []
    for size in args.sizes:
        row = case(size, args.epsilon, args.block_size, RESULTS)
        rows.append(row)
        print(
            f"{size}² ε={args.epsilon:g}: serial {row['serial_seconds']:.2f} s, blocks in process "
            f"{row['blocks_seconds']:.2f} s, workers 1 {row['workers1_seconds']:.2f} s, "
            f"workers 2 {row['workers2_seconds']:.2f} s "
            f"(×{row['speedup_workers2_over_workers1']:.2f}); {row['nodes']} nodes, "
            f"{row['plan_blocks']} blocks, "
            f"{row['workers1']['block_seconds_per_million_points_median']:.2f} s per M points "
            f"per block (1 thread); load average {row['load_average_before']:.1f}, "
            f"available cores {row['available_cores_before']:.2f}",
            flush=True,
        )
    report = {
        "benchmark": "blocked tree builds on dask (grid patches, fractal DEMs, one process)",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "results": rows,
    }
    (RESULTS / "blocks.json").write_text(json.dumps(report, indent=2))
    print(f"wrote {RESULTS / 'blocks.json'}")


if __name__ == "__main__":
    main()
