"""Tree build time and peak memory on fractal DEMs (1025², 2049², 4097² at ε = 1 m and 5 m).

Each case runs in a fresh worker process that loads the DEM from a .npy file, warms the numba
kernels up on a tiny grid, then builds the tree three times: the median time is reported, and
the peak memory of the build is the rise of the process's peak RSS (VmHWM, reset just before
building) above its resident size before building. Results go to
benchmarks/results/build.json and build.png.

    python benchmarks/bench_build.py [--sizes 1025 2049 4097] [--epsilons 1 5]

The issue-15 targets run too (``--targets`` alone runs only them; ``--no-targets`` skips them),
in one fresh worker on the 4097² DEM: the 349,525-node tree (ε = 0, s = 81) built and saved
(medians of ``--target-repeats``, a cProfile top-10 of one build), and ε = 1 at the default s
(medians, a cProfile top-10); the first build of a tiny grid (numba compile or cache load) is
reported separately. Results go to benchmarks/results/build_targets.json.
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


def _profile_top(fn, count: int = 10) -> list[dict]:
    """cProfile of one call of ``fn``: the ``count`` functions of largest own time."""
    import cProfile
    import pstats

    prof = cProfile.Profile()
    prof.enable()
    fn()
    prof.disable()
    stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
    rows = [
        {
            "function": f"{Path(file).name}:{line}({name})",
            "ncalls": int(nc),
            "tottime": round(tt, 4),
            "cumtime": round(ct, 4),
        }
        for (file, line, name), (_, nc, tt, ct, _) in stats.items()
    ]
    return sorted(rows, key=lambda r: -r["tottime"])[:count]


def target_worker(npy: str, repeats: int) -> dict:
    """The issue-15 build targets on one DEM, in this process (see the module docstring)."""
    import shutil

    from affine import Affine

    from approxtree import ApproximationTree, Grid
    from approxtree.datasets import fractal_terrain

    # Numba compile (or cache load) on the clock of the first build only.
    t0 = time.perf_counter()
    ApproximationTree.build(fractal_terrain(65, seed=0), epsilon=0.0, max_points=81, progress=False)
    first_call = time.perf_counter() - t0
    z = np.load(npy)
    grid = Grid(z, transform=Affine(10.0, 0, 0, 0, -10.0, z.shape[0] * 10.0))
    out: dict = {"size": int(z.shape[0]), "first_build_seconds": first_call}
    cases = {"eps0_s81": {"epsilon": 0.0, "max_points": 81}, "eps1": {"epsilon": 1.0}}
    # Interleaved repeats, so load on the machine spreads over both cases alike.
    times: dict[str, list[float]] = {k: [] for k in cases}
    saves: list[float] = []
    nodes: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            for name, kw in cases.items():
                t0 = time.perf_counter()
                tree = ApproximationTree.build(grid, progress=False, **kw)
                times[name].append(time.perf_counter() - t0)
                nodes[name] = len(tree)
                if name == "eps0_s81" and r < max(3, repeats // 2):
                    path = Path(tmp) / f"t{r}.zarr"
                    t0 = time.perf_counter()
                    tree.save(path)
                    saves.append(time.perf_counter() - t0)
                    shutil.rmtree(path, ignore_errors=True)
                del tree
    for name, kw in cases.items():
        out[name] = {
            **kw,
            "nodes": nodes[name],
            "build_seconds_median": statistics.median(times[name]),
            "build_seconds_all": times[name],
        }
    out["eps0_s81"]["save_seconds_median"] = statistics.median(saves)
    out["eps0_s81"]["save_seconds_all"] = saves
    out["eps0_s81"]["build_profile_top10"] = _profile_top(
        lambda: ApproximationTree.build(grid, epsilon=0.0, max_points=81, progress=False)
    )
    out["eps1"]["build_profile_top10"] = _profile_top(
        lambda: ApproximationTree.build(grid, epsilon=1.0, progress=False)
    )
    return out


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
    parser.add_argument("--targets", action="store_true", help="run only the issue-15 targets")
    parser.add_argument("--no-targets", action="store_true", help="skip the issue-15 targets")
    parser.add_argument("--target-repeats", type=int, default=5)
    parser.add_argument("--worker", nargs=2, metavar=("NPY", "EPSILON"), help=argparse.SUPPRESS)
    parser.add_argument("--target-worker", metavar="NPY", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker[0], float(args.worker[1]), args.repeats)))
        return
    if args.target_worker:
        print(json.dumps(target_worker(args.target_worker, args.target_repeats)))
        return

    from approxtree.datasets import fractal_heights

    rows = []
    RESULTS.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        if not args.no_targets:
            npy = Path(tmp) / "fractal_4097.npy"
            np.save(npy, fractal_heights(4097, seed=4097))
            cmd = [sys.executable, __file__, "--target-worker", str(npy)]
            cmd += ["--target-repeats", str(args.target_repeats)]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True)
            targets = json.loads(out.stdout.strip().splitlines()[-1])
            targets["targets"] = {"eps0_s81_build_s": 3.0, "eps1_build_s": 0.3}
            (RESULTS / "build_targets.json").write_text(json.dumps(targets, indent=2))
            a, b = targets["eps0_s81"], targets["eps1"]
            print(
                f"4097² ε=0 s=81: {a['nodes']} nodes, build {a['build_seconds_median']:.2f} s, "
                f"save {a['save_seconds_median']:.2f} s; ε=1: {b['nodes']} nodes, build "
                f"{b['build_seconds_median']:.3f} s; first build "
                f"{targets['first_build_seconds']:.2f} s",
                flush=True,
            )
            if args.targets:
                return
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
