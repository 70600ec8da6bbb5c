"""Scale: build trees of fractal DEMs bigger than memory; wall time, peak RSS, store size.

For each size (default 8192², 16384², 32768²) a seeded fractal GeoTIFF is made once with
``approxtree fractal`` into a cache folder (kept between runs, with its generation figures
beside it), then ``approxtree build DEM.tif -o TREE.zarr --epsilon 1`` runs as a subprocess.
Measured per run:

- wall time of the command;
- peak RSS of the whole process tree (the command and every process it starts: dask nannies
  and workers), sampled every 0.1 s by psutil, as the peak of the SUM over the tree;
- the largest RSS of any single process of the tree (``os.wait4``'s ru_maxrss, exact);
- store bytes ÷ DEM bytes (DEM bytes = rows × cols × 4, float32).

Then on one size, ``--workers 1`` against ``--workers 2`` (the speed-up), each with
``--report FILE.html`` (the dask performance report: per-block task timeline); with
``--speedup-pairs N`` (N > 1) instead N interleaved pairs of whole commands without reports
(1, 2, 1, 2, ...), medians and each pair's ratio, with the phases the command reports (build,
save; its own CPU in each) and the CPU of the whole process tree. ``--speedup-only`` skips
the builds of every size (results: scale_speedup.json and .png).

The build options that today's CLI lacks (read from ``approxtree build --help``) are left out
and the measurements that need them skipped, with a note in the JSON. A build whose tree
passes ``--memory-limit-gb`` is stopped and reported as such (an in-memory build of a 32768²
DEM would need about 15 GB).

    python benchmarks/bench_scale.py [--sizes 8192 16384 32768] [--data-dir DIR]
        [--epsilon 1] [--speedup-size 8192] [--speedup-pairs 3] [--speedup-only]
        [--generate-only]

Results: benchmarks/results/scale.json and scale.png (RSS and time against size).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

RESULTS = Path(__file__).resolve().parent / "results"
DEFAULT_DATA = Path(tempfile.gettempdir()) / "approxtree-scale"
#: The approxtree that builds (``--python`` replaces the interpreter) and the one that makes
#: the DEMs (always this checkout's).
CLI = [sys.executable, "-m", "approxtree"]
FRACTAL_CLI = [sys.executable, "-m", "approxtree"]


class TreeSampler(threading.Thread):
    """Samples the RSS of a process and all its descendants; keeps the peak of the sum.

    Optionally kills the tree when the sum passes ``limit`` bytes.
    """

    def __init__(self, pid: int, interval: float = 0.1, limit: int | None = None) -> None:
        super().__init__(daemon=True)
        import psutil

        self.root = psutil.Process(pid)
        self.interval = interval
        self.limit = limit
        self.peak = 0
        self.peak_processes = 0
        self.killed = False
        self.stop = threading.Event()

    def _tree(self) -> list:
        import psutil

        try:
            return [self.root, *self.root.children(recursive=True)]
        except psutil.NoSuchProcess:
            return []

    def run(self) -> None:
        import psutil

        while not self.stop.is_set():
            procs = self._tree()
            total = 0
            for p in procs:
                try:
                    total += p.memory_info().rss
                except (psutil.NoSuchProcess, psutil.AccessDenied):
                    pass
            if total > self.peak:
                self.peak, self.peak_processes = total, len(procs)
            if self.limit is not None and total > self.limit and not self.killed:
                self.killed = True
                self.kill_tree(procs)
            self.stop.wait(self.interval)

    def kill_tree(self, procs: list | None = None) -> None:
        """SIGKILL the process and its descendants, the deepest first."""
        import psutil

        for p in reversed(self._tree() if procs is None else procs):
            try:
                p.kill()
            except psutil.NoSuchProcess:
                pass


def measure(cmd: list[str], limit: int | None = None, timeout: float | None = None) -> dict:
    """Run ``cmd``; its wall time, exit code, stdout, stderr tail and peak RSS figures."""
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True)
        sampler = TreeSampler(proc.pid, limit=limit)
        sampler.start()
        timer = None
        if timeout:
            timer = threading.Timer(timeout, sampler.kill_tree)
            timer.start()
        # wait4: the exit status and this child's own rusage (max RSS of it or any descendant
        # it waited for), not the max over every child this harness ever ran.
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        if timer is not None:
            timer.cancel()
        sampler.stop.set()
        sampler.join()
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    return {
        "command": " ".join(["approxtree", *cmd[3:]] if cmd[1:3] == ["-m", "approxtree"] else cmd),
        "returncode": proc.returncode,
        "seconds": round(seconds, 3),
        "peak_rss_tree_bytes": sampler.peak,
        "processes_at_peak": sampler.peak_processes,
        "maxrss_single_process_bytes": usage.ru_maxrss * 1024,
        "cpu_seconds": round(usage.ru_utime + usage.ru_stime, 3),
        "killed_over_memory_limit": sampler.killed,
        # Other work on the machine slows the run: the 1-minute load before and after.
        "loadavg_1min": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "stdout": stdout,
        "stderr_tail": stderr[-2000:],
    }


def _last_json(text: str) -> dict | None:
    """The last line of ``text`` that parses as a JSON object."""
    for line in reversed(text.strip().splitlines()):
        try:
            value = json.loads(line)
        except ValueError:
            continue
        if isinstance(value, dict):
            return value
    return None


def build_options() -> dict[str, Any]:
    """What today's ``approxtree build`` accepts, read from its --help."""
    text = subprocess.run([*CLI, "build", "--help"], capture_output=True, text=True).stdout
    return {
        "short_out": re.search(r"(^|[\s,])-o[,\s]", text) is not None,
        "workers": "--workers" in text,
        "report": "--report" in text,
        "scheduler": "--scheduler" in text,
        "windowed": "--windowed" in text,
        "json": "--json" in text,
        "zarr": "zarr" in text.lower(),
        "help": text,
    }


def path_bytes(path: Path) -> int:
    """Bytes of a file, or of every file under a folder."""
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def generate(
    size: int,
    seed: int,
    data_dir: Path,
    cell_size: float,
    crs: str | None,
    cog: bool,
    hurst: float | None,
) -> dict:
    """Make (or find) the size² fractal DEM; its generation figures (kept in a JSON beside)."""
    tag = (f"_h{hurst:g}" if hurst is not None else "") + ("_cog" if cog else "")
    dem = data_dir / f"fractal_{size}_seed{seed}{tag}.tif"
    sidecar = dem.with_suffix(".json")
    if dem.is_file() and sidecar.is_file():
        record = json.loads(sidecar.read_text())
        return {**record, "cached": True}
    cmd = [*FRACTAL_CLI, "fractal", str(dem), "--size", str(size), "--seed", str(seed)]
    cmd += ["--cell-size", str(cell_size), "--json"]
    if crs:
        cmd += ["--crs", crs]
    if cog:
        cmd.append("--cog")
    if hurst is not None:
        cmd += ["--hurst", str(hurst)]
    run = measure(cmd)
    if run["returncode"] != 0:
        raise SystemExit(f"generating {dem} failed:\n{run['stderr_tail']}")
    figures = _last_json(run["stdout"]) or {}
    run.pop("stdout")
    record = {"size": size, "dem": str(dem), "generate": {**run, "figures": figures}}
    sidecar.write_text(json.dumps(record, indent=2))
    return {**record, "cached": False}


def build(
    dem: Path,
    size: int,
    epsilon: float,
    opts: dict[str, Any],
    out_dir: Path,
    workers: int | None,
    report: Path | None,
    limit: int | None,
    timeout: float | None,
    keep: bool,
) -> dict:
    """One build of ``dem`` as a subprocess, measured; the tree is removed unless ``keep``."""
    suffix = ".zarr" if opts["zarr"] else ".atree"
    tag = f"{size}_w{workers}" if workers else str(size)
    tree = out_dir / f"tree_{tag}{suffix}"
    if tree.is_dir():
        shutil.rmtree(tree)
    elif tree.exists():
        tree.unlink()
    cmd = [*CLI, "build", str(dem), "-o" if opts["short_out"] else "--out", str(tree)]
    cmd += ["--epsilon", str(epsilon)]
    notes = []
    # Every size read windowed, so the figures compare like with like (by default only rasters
    # above 1 GiB of heights open windowed).
    if opts.get("windowed"):
        cmd += ["--windowed", "on"]
    if workers is not None:
        if opts["workers"]:
            cmd += ["--workers", str(workers)]
        else:
            notes.append("build has no --workers: built serially")
    if report is not None:
        if opts["report"]:
            cmd += ["--report", str(report)]
        else:
            notes.append("build has no --report: no dask performance report")
    if opts["json"]:
        cmd.append("--json")
    run = measure(cmd, limit=limit, timeout=timeout)
    figures = _last_json(run.pop("stdout")) or {}
    dem_bytes = size * size * 4
    store = path_bytes(tree) if tree.exists() else None
    record = {
        "size": size,
        "workers": workers,
        **run,
        "dem_bytes": dem_bytes,
        "store_bytes": store,
        "store_over_dem": round(store / dem_bytes, 4) if store else None,
        "tree": {k: v for k, v in figures.items() if not isinstance(v, dict | list)},
        "notes": notes,
    }
    if report is not None and report.is_file():
        record["performance_report"] = str(report)
    if not keep and tree.exists():
        shutil.rmtree(tree) if tree.is_dir() else tree.unlink()
    return record


def plot(report: dict, out: Path) -> None:
    """Peak RSS and wall time against DEM size; generation beside the builds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    builds = [r for r in report["builds"] if r["returncode"] == 0]
    gens = [g["generate"] for g in report["generated"]]
    sizes_g = [g["size"] for g in report["generated"]]
    if builds:
        s = [r["size"] for r in builds]
        a.plot(s, [r["peak_rss_tree_bytes"] / 2**30 for r in builds], "o-", label="build, tree")
        a.plot(
            s,
            [r["maxrss_single_process_bytes"] / 2**30 for r in builds],
            "s--",
            label="build, largest process",
        )
        b.plot(s, [r["seconds"] for r in builds], "o-", label="build")
    a.plot(sizes_g, [g["peak_rss_tree_bytes"] / 2**30 for g in gens], "^:", label="fractal DEM")
    b.plot(sizes_g, [g["seconds"] for g in gens], "^:", label="fractal DEM")
    a.axhline(2.0, color="grey", ls="--", label="target 2 GB")
    a.set_ylim(bottom=0)
    for ax, ylabel in ((a, "peak RSS (GiB)"), (b, "wall time (s)")):
        ax.set(xlabel="DEM size (cells per side)", ylabel=ylabel, xscale="log")
        ax.set_xscale("log", base=2)
        ax.legend()
    b.set_yscale("log")
    fig.suptitle(f"ε = {report['epsilon']:g}, {report['machine']['cpus']} CPUs")
    fig.tight_layout()
    fig.savefig(out, dpi=100)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[8192, 16384, 32768])
    parser.add_argument("--data-dir", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out-dir", type=Path, default=RESULTS)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--cell-size", type=float, default=1.0)
    parser.add_argument("--crs", default="EPSG:32633")
    parser.add_argument("--epsilon", type=float, default=1.0)
    parser.add_argument(
        "--cog", action="store_true", help="Make COGs (overviews) rather than tiled GeoTIFFs."
    )
    parser.add_argument(
        "--hurst",
        type=float,
        default=None,
        help="Roughness of the DEMs [approxtree fractal's default, 0.9]; lower is rougher",
    )
    parser.add_argument(
        "--workers", type=int, default=None, help="--workers of the size runs [CLI default]"
    )
    parser.add_argument("--speedup-size", type=int, default=None, help="[smallest size]")
    parser.add_argument("--speedup-workers", type=int, nargs=2, default=[1, 2])
    parser.add_argument("--no-speedup", action="store_true")
    parser.add_argument(
        "--speedup-pairs", type=int, default=1, help="Interleaved pairs of whole commands [1]"
    )
    parser.add_argument(
        "--speedup-only", action="store_true", help="Only the speed-up (no build per size)."
    )
    parser.add_argument("--generate-only", action="store_true", help="Make the DEMs only.")
    parser.add_argument(
        "--memory-limit-gb",
        type=float,
        default=None,
        help="Kill a build whose process tree passes this RSS [80 %% of available memory].",
    )
    parser.add_argument("--timeout", type=float, default=None, help="Seconds per build.")
    parser.add_argument("--keep-trees", action="store_true")
    parser.add_argument(
        "--python",
        default=sys.executable,
        help="Interpreter whose `-m approxtree build` is measured [this one]",
    )
    args = parser.parse_args(argv)
    CLI[0] = args.python

    import psutil

    args.data_dir.mkdir(parents=True, exist_ok=True)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    limit_gb = args.memory_limit_gb or 0.8 * psutil.virtual_memory().available / 2**30
    limit = int(limit_gb * 2**30)
    report: dict[str, Any] = {
        "benchmark": "scale: fractal DEMs made by `approxtree fractal`, built by `approxtree "
        "build` in a subprocess; RSS = peak of the sum over the process tree (0.1 s samples)",
        "machine": {
            "cpus": os.cpu_count(),
            "memory_bytes": psutil.virtual_memory().total,
            "python": platform.python_version(),
            "platform": platform.platform(),
        },
        "epsilon": args.epsilon,
        "seed": args.seed,
        "python": args.python,
        "memory_limit_bytes": limit,
        "generated": [],
        "builds": [],
        "speedup": None,
        "notes": [],
    }
    for size in args.sizes:
        record = generate(
            size, args.seed, args.data_dir, args.cell_size, args.crs, args.cog, args.hurst
        )
        g = record["generate"]
        print(
            f"DEM {size}²: {g['seconds']:.1f} s, peak RSS {g['peak_rss_tree_bytes'] / 2**20:.0f}"
            f" MiB{' (cached)' if record['cached'] else ''}",
            flush=True,
        )
        report["generated"].append(record)

    opts = {} if args.generate_only else build_options()
    if not args.generate_only:
        report["build_options"] = {k: v for k, v in opts.items() if k != "help"}
        missing = [o for o in ("short_out", "workers", "report", "zarr") if not opts[o]]
        if missing:
            report["notes"].append(
                "today's `approxtree build` lacks " + ", ".join(missing) + ": the harness used "
                "--out and a .atree where -o/zarr are missing, and skipped what needs the rest"
            )
        for record in [] if args.speedup_only else report["generated"]:
            size = record["size"]
            run = build(
                Path(record["dem"]),
                size,
                args.epsilon,
                opts,
                args.data_dir,
                args.workers,
                None,
                limit,
                args.timeout,
                args.keep_trees,
            )
            report["builds"].append(run)
            print(
                f"build {size}²: rc {run['returncode']}, {run['seconds']:.1f} s, peak RSS "
                f"{run['peak_rss_tree_bytes'] / 2**20:.0f} MiB (tree of "
                f"{run['processes_at_peak']} processes), store/DEM {run['store_over_dem']}",
                flush=True,
            )
        report["speedup"] = speedup(args, opts, report, limit)

    stem = "scale" if not args.generate_only else "scale_generate"
    stem = "scale_speedup" if args.speedup_only else stem
    (args.out_dir / f"{stem}.json").write_text(json.dumps(report, indent=2))
    if args.speedup_only:
        plot_pairs(report["speedup"], args.out_dir / f"{stem}.png")
    else:
        plot(report, args.out_dir / f"{stem}.png")
    print(f"wrote {args.out_dir / (stem + '.json')} and {stem}.png")
    return report


def speedup(args: argparse.Namespace, opts: dict, report: dict, limit: int) -> dict | None:
    """--workers 1 against --workers 2 on one size, each with a dask performance report."""
    if args.no_speedup:
        return None
    if not opts["workers"]:
        report["notes"].append("speed-up skipped: `approxtree build` has no --workers")
        return {"skipped": "build has no --workers"}
    size = args.speedup_size or min(args.sizes)
    dem = next(Path(r["dem"]) for r in report["generated"] if r["size"] == size)
    if args.speedup_pairs > 1:
        return interleaved(args, opts, dem, size, limit)
    runs = []
    for w in args.speedup_workers:
        html = args.out_dir / f"scale_report_{size}_w{w}.html"
        runs.append(
            build(dem, size, args.epsilon, opts, args.data_dir, w, html, limit, args.timeout, False)
        )
    one, two = runs
    ok = one["returncode"] == 0 and two["returncode"] == 0
    result = {
        "size": size,
        "workers": list(args.speedup_workers),
        "seconds": [one["seconds"], two["seconds"]],
        "speedup": round(one["seconds"] / two["seconds"], 3) if ok else None,
        "runs": runs,
    }
    print(f"speed-up {size}², workers {args.speedup_workers}: {result['speedup']}", flush=True)
    return result


def _phases(run: dict) -> dict:
    """Wall and CPU seconds of one whole command by phase: start (process and cluster start,
    reading the DEM's header), build, save, and the CPU of the command's own process against
    that of the whole tree (the dask workers and nannies are the rest)."""
    t = run["tree"]
    build_s, save_s = t.get("seconds"), t.get("save_seconds")
    out = {"wall": run["seconds"], "build": build_s, "save": save_s}
    if build_s is not None and save_s is not None:
        out["start_and_exit"] = round(run["seconds"] - build_s - save_s, 3)
    out["cpu_tree"] = run["cpu_seconds"]
    out["cpu_client_build"] = t.get("build_cpu_seconds")
    out["cpu_client_save"] = t.get("save_cpu_seconds")
    return out


def interleaved(args: argparse.Namespace, opts: dict, dem: Path, size: int, limit: int) -> dict:
    """``--speedup-pairs`` pairs of whole commands, the worker counts alternating; medians."""
    import statistics

    w = list(args.speedup_workers)
    runs: dict[int, list[dict]] = {w[0]: [], w[1]: []}
    for pair in range(args.speedup_pairs):
        for workers in w:
            run = build(dem, size, args.epsilon, opts, args.data_dir, workers, None, limit,
                        args.timeout, False)  # fmt: skip
            run["phases"] = _phases(run)
            runs[workers].append(run)
            print(
                f"pair {pair + 1} workers {workers}: {run['seconds']:.1f} s, phases "
                f"{run['phases']}, load {run['loadavg_1min']}",
                flush=True,
            )

    def median(workers: int, key: str) -> float | None:
        values = [r["phases"][key] for r in runs[workers] if r["phases"].get(key) is not None]
        return round(statistics.median(values), 3) if values else None

    keys = ("wall", "build", "save", "start_and_exit", "cpu_tree", "cpu_client_build",
            "cpu_client_save")  # fmt: skip
    medians = {str(k): {key: median(k, key) for key in keys} for k in w}
    ratios = [
        round(a["seconds"] / b["seconds"], 3) for a, b in zip(runs[w[0]], runs[w[1]], strict=True)
    ]
    result = {
        "size": size,
        "workers": w,
        "pairs": args.speedup_pairs,
        "medians": medians,
        "speedup_whole_command": round(medians[str(w[0])]["wall"] / medians[str(w[1])]["wall"], 3),
        "speedup_build_phase": round(medians[str(w[0])]["build"] / medians[str(w[1])]["build"], 3),
        "pair_ratios": ratios,
        "loadavg_1min": [r["loadavg_1min"] for k in w for r in runs[k]],
        "runs": {str(k): v for k, v in runs.items()},
    }
    print(f"speed-up {size}², workers {w}: whole {result['speedup_whole_command']}, "
          f"build {result['speedup_build_phase']}, pairs {ratios}", flush=True)  # fmt: skip
    return result


def plot_pairs(result: dict, out: Path) -> None:
    """Median wall seconds by phase, one bar per worker count, and each pair's ratio."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    names = [str(k) for k in result["workers"]]
    bottom = [0.0] * len(names)
    for phase in ("start_and_exit", "build", "save"):
        values = [result["medians"][n][phase] or 0.0 for n in names]
        a.bar([f"{n} worker(s)" for n in names], values, bottom=bottom, label=phase)
        bottom = [x + y for x, y in zip(bottom, values, strict=True)]
    a.set(ylabel="median wall seconds", title=f"{result['size']}², whole command by phase")
    a.legend()
    b.plot(range(1, len(result["pair_ratios"]) + 1), result["pair_ratios"], "o-", label="pair")
    b.axhline(result["speedup_whole_command"], color="grey", ls="--", label="median ratio")
    b.axhline(1.8, color="red", ls=":", label="target 1.8×")
    b.set(xlabel="pair", ylabel="1-worker ÷ 2-worker wall time", title="speed-up per pair")
    b.legend()
    loads = result["loadavg_1min"]
    fig.suptitle(f"load average (1 min) before/after each run: {loads}", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=100)


if __name__ == "__main__":
    main()
