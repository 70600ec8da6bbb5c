"""Where the CPU of a windowed build goes, process by process and thread by thread.

``approxtree build DEM --windowed on --workers N`` runs once per N (default 1 and 2); every
0.25 s the process tree (the command, its dask workers) is sampled with psutil: each
process's CPU seconds and each of its threads' (``/proc`` per-thread times). The last sample
of each process is its total (the workers live until the command saves). Threads of a worker
are grouped as

- ``task``: the busiest thread (the block task thread: read, subtree, measures, region write);
- ``pool``: the threads of the executor pool (the zarr codec / chunk I/O executor);
- ``other``: the rest (the worker's event loop and communication, the nanny link).

This explains the whole-command speed-up (``bench_scale.py --speedup-only``): on a machine
of C cores the best the 2-worker command can do is the tree's CPU ÷ C plus what stays serial,
and the 1-worker command already runs its pool and the client beside its task thread.

    python benchmarks/bench_scale_cpu.py DEM.tif [--workers 1 2] [--epsilon 1]

Results: benchmarks/results/scale_cpu.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

RESULTS = Path(__file__).resolve().parent / "results"


def sample_tree(command: list[str], period: float = 0.25) -> dict[str, Any]:
    """Run ``command``; return wall seconds and the last CPU sample of each process and thread."""
    import psutil

    start = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    root = psutil.Process(proc.pid)
    processes: dict[int, dict[str, Any]] = {}
    # Sample until the command exits: a worker's last sample is taken just before it ends.
    while proc.poll() is None:
        try:
            tree = [root, *root.children(recursive=True)]
        except psutil.Error:
            break
        for p in tree:
            try:
                with p.oneshot():
                    times = p.cpu_times()
                    entry = processes.setdefault(p.pid, {"threads": {}})
                    # By thread id: a thread that ends before the process keeps its last time.
                    for t in p.threads():
                        entry["threads"][t.id] = t.user_time + t.system_time
                    entry["role"] = "client" if p.pid == proc.pid else "worker"
                    entry["cmdline_tail"] = " ".join(p.cmdline())[-80:]
                    entry["cpu"] = times.user + times.system
            except psutil.Error:
                continue
        time.sleep(period)
    wall = time.perf_counter() - start
    stderr = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    return {"returncode": proc.wait(), "wall": wall, "processes": processes, "stderr": stderr}


def summarize(run: dict[str, Any]) -> dict[str, Any]:
    """CPU seconds by role: client, and per worker its task thread, pool and the rest."""
    client = sum(p["cpu"] for p in run["processes"].values() if p["role"] == "client")
    workers = []
    for p in run["processes"].values():
        # The resource tracker and other helpers hold no CPU worth listing.
        if p["role"] != "worker" or p["cpu"] < 0.5:
            continue
        threads = sorted(p["threads"].values(), reverse=True)
        task = threads[0] if threads else 0.0
        # The executor's threads run alike: those within 25 % of the second busiest thread's
        # median below the task thread form the pool.
        rest = threads[1:]
        pool_like = sorted(rest)[len(rest) // 2] if rest else 0.0
        pool = [t for t in rest if pool_like > 0 and abs(t - pool_like) <= 0.25 * pool_like]
        workers.append(
            {
                "cpu": round(p["cpu"], 2),
                "task": round(task, 2),
                "pool": round(sum(pool), 2),
                "pool_threads": len(pool),
                "other": round(p["cpu"] - task - sum(pool), 2),
            }
        )
    total = client + sum(w["cpu"] for w in workers)
    return {
        "wall": round(run["wall"], 2),
        "cpu_total": round(total, 2),
        "cpu_client": round(client, 2),
        "cores_used": round(total / run["wall"], 2),
        "per_worker": workers,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dem", type=Path)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--epsilon", type=float, default=1.0)
    parser.add_argument("--out", type=Path, default=RESULTS / "scale_cpu.json")
    args = parser.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="scale-cpu-"))
    report: dict[str, Any] = {
        "benchmark": "CPU of `approxtree build --windowed on` by process and thread",
        "dem": str(args.dem),
        "epsilon": args.epsilon,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        "runs": [],
    }
    try:
        for n in args.workers:
            out = work / f"tree_w{n}.zarr"
            command = [sys.executable, "-m", "approxtree", "build", str(args.dem), "--out",
                       str(out), "--epsilon", str(args.epsilon), "--windowed", "on",
                       "--workers", str(n), "--json"]  # fmt: skip
            load = os.getloadavg()[0]
            run = sample_tree(command)
            if run["returncode"] != 0:
                print(run["stderr"][-2000:], file=sys.stderr)
                return 1
            summary = {"workers": n, "loadavg_1min_before": load, **summarize(run)}
            report["runs"].append(summary)
            print(json.dumps(summary))
            shutil.rmtree(out, ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
