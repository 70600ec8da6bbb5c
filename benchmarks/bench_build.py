"""Tree build time and peak memory on fractal DEMs (1025², 2049², 4097² at ε = 1 m and 5 m).

Each case runs in a fresh worker process that loads the DEM from a .npy file, warms the numba
kernels up on a tiny grid, then builds the tree three times: the median time is reported, and
the peak memory of the build is the rise of the process's peak RSS (VmHWM, reset just before
building) above its resident size before building. Results go to
benchmarks/results/build.json and build.png.

    python benchmarks/bench_build.py [--sizes 1025 2049 4097] [--epsilons 1 5]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def _status_bytes(key: str) -> int:
    """A memory figure of this process from /proc/self/status (VmRSS, VmHWM)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    raise RuntimeError(f"{key} not found in /proc/self/status")


def _reset_peak() -> None:
    """Reset the peak-RSS mark (VmHWM); ru_maxrss would carry the parent's peak across fork."""
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


def worker(npy: str, epsilon: float, repeats: int) -> dict:
    """Build the tree of one DEM in this process and measure it."""
    from affine import Affine

    from approxtree import ApproximationTree, Grid
    from approxtree.datasets import fractal_terrain

    ApproximationTree.build(fractal_terrain(65, seed=0), epsilon=epsilon, progress=False)
    z = np.load(npy)
    grid = Grid(z, transform=Affine(10.0, 0, 0, 0, -10.0, z.shape[0] * 10.0))
    _reset_peak()
    base = _status_bytes("VmRSS")
    times = []
    tree = None
    for _ in range(repeats):
        del tree
        t0 = time.perf_counter()
        tree = ApproximationTree.build(grid, epsilon=epsilon, progress=False)
        times.append(time.perf_counter() - t0)
    peak = _status_bytes("VmHWM")
    stats = tree.stats()
    return {
        "size": int(z.shape[0]),
        "epsilon": epsilon,
        "seconds_median": statistics.median(times),
        "seconds_all": times,
        "dem_bytes": int(z.nbytes),
        "build_peak_bytes": int(max(peak - base, 0)),
        "memory_ratio": max(peak - base, 0) / z.nbytes,
        "process_peak_bytes": int(peak),
        "nodes": stats["nodes"],
        "leaves": stats["leaves"],
        "levels": stats["levels"],
        "max_leaf_error": stats["max_leaf_error"],
    }


def plot(rows: list[dict], out: Path) -> None:
    """Build time and memory ratio against DEM size, one line per epsilon."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for eps in sorted({r["epsilon"] for r in rows}):
        rs = [r for r in rows if r["epsilon"] == eps]
        a.plot(
            [r["size"] for r in rs], [r["seconds_median"] for r in rs], "o-", label=f"ε = {eps:g} m"
        )
        b.plot(
            [r["size"] for r in rs], [r["memory_ratio"] for r in rs], "o-", label=f"ε = {eps:g} m"
        )
    a.axhline(10, color="grey", ls="--", label="target 10 s (4097²)")
    b.axhline(3, color="grey", ls="--", label="target 3× DEM bytes")
    a.set(xlabel="DEM size (points per side)", ylabel="build time, median (s)", xscale="log")
    b.set(xlabel="DEM size (points per side)", ylabel="build peak memory / DEM bytes", xscale="log")
    a.legend()
    b.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=100)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1025, 2049, 4097])
    parser.add_argument("--epsilons", type=float, nargs="+", default=[1.0, 5.0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--worker", nargs=2, metavar=("NPY", "EPSILON"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker[0], float(args.worker[1]), args.repeats)))
        return

    from approxtree.datasets import fractal_heights

    rows = []
    RESULTS.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes:
            npy = Path(tmp) / f"fractal_{size}.npy"
            np.save(npy, fractal_heights(size, seed=size))
            for eps in args.epsilons:
                out = subprocess.run(
                    [
                        sys.executable,
                        __file__,
                        "--worker",
                        str(npy),
                        str(eps),
                        "--repeats",
                        str(args.repeats),
                    ],
                    check=True,
                    capture_output=True,
                    text=True,
                )
                row = json.loads(out.stdout.strip().splitlines()[-1])
                rows.append(row)
                print(
                    f"{size}² ε={eps:g}: {row['seconds_median']:.2f} s, "
                    f"{row['build_peak_bytes'] / 1e6:.1f} MB peak "
                    f"({row['memory_ratio']:.2f}× DEM), {row['nodes']} nodes",
                    flush=True,
                )
    report = {
        "benchmark": "tree build (grid patches), fractal DEMs, fresh process per case",
        "machine": {"cpus": __import__("os").cpu_count(), "python": platform.python_version()},
        "results": rows,
    }
    (RESULTS / "build.json").write_text(json.dumps(report, indent=2))
    plot(rows, RESULTS / "build.png")
    print(f"wrote {RESULTS / 'build.json'} and build.png")


if __name__ == "__main__":
    main()
