"""What a fresh install pays for numba compiles: demo, mesh and render, cold vs warm cache.

    python benchmarks/bench_compile.py [--repeat 3] [--out bench_compile.json]

Each command runs in a fresh subprocess (benchmarks/compile_probe.py) twice per repeat,
interleaved: cold, with NUMBA_CACHE_DIR pointing at a new empty folder (numba then reads and
writes no other cache, so the package's __pycache__ is ignored), and warm, with the folder the
cold run filled. Reported per command: medians of the process wall time (interpreter start and
imports included), of the command's time, and of the seconds spent compiling (outermost
compiles only; wall and CPU time of the compiling thread, the figure to quote on a loaded
machine), the compile share of the cold run, and the kernels a cold run compiled.

Commands: ``approxtree demo``; ``approxtree mesh`` of a small DEM (nc/elev_ned_30m.tif from
../shared/data, else a 257² DEM from ``approxtree generate``) at --max-error 1; ``approxtree
render`` of the demo tree. Writes JSON and, when matplotlib is present, a PNG next to it.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
PROBE = HERE / "compile_probe.py"
SHARED_DEM = HERE.parent.parent / "shared" / "data" / "nc" / "elev_ned_30m.tif"


def _probe(args: list[str], cache: Path, work: Path, tag: str) -> dict:
    """Run one command through the probe; its JSON plus the process's wall time."""
    out = work / f"{tag}.json"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, str(PROBE), str(out), "--", *args],
        cwd=work,
        env=env,
        check=True,
        stdout=subprocess.DEVNULL,
    )
    process_s = time.perf_counter() - t0
    result = json.loads(out.read_text())
    result["process_s"] = process_s
    return result


def _commands(work: Path, dem: Path) -> dict[str, callable]:
    """Each command's arguments for one run (fresh output paths each time)."""
    counter = iter(range(10**6))

    def demo() -> list[str]:
        return ["demo", "--out", str(work / f"demo{next(counter)}.zarr")]

    def mesh() -> list[str]:
        return ["mesh", str(dem), "--max-error", "1"]

    def render() -> list[str]:
        return ["render", str(work / "tree.zarr"), "--out", str(work / "render.png")]

    return {"demo": demo, "mesh": mesh, "render": render}


_RUN_KEYS = ("process_s", "wall_s", "cpu_s", "compile_s", "compile_cpu_s")


def _summary(cold: list[dict], warm: list[dict]) -> dict:
    med = statistics.median
    kernels: dict[str, list[str]] = {}
    for e in cold[-1]["events"]:
        if e["kernel"].startswith("approxtree"):
            kernels.setdefault(e["kernel"].removeprefix("approxtree."), []).append(e["args"])
    cold_s, warm_s = med(r["process_s"] for r in cold), med(r["process_s"] for r in warm)
    compile_s = med(r["compile_s"] for r in cold)
    return {
        "cold_process_s": cold_s,
        "warm_process_s": warm_s,
        "cold_command_s": med(r["wall_s"] for r in cold),
        "warm_command_s": med(r["wall_s"] for r in warm),
        "cold_compile_s": compile_s,
        "warm_compile_s": med(r["compile_s"] for r in warm),
        # CPU seconds of the compiling thread: what a quiet machine would wait.
        "cold_compile_cpu_s": med(r["compile_cpu_s"] for r in cold),
        "cold_command_cpu_s": med(r["cpu_s"] for r in cold),
        "warm_command_cpu_s": med(r["cpu_s"] for r in warm),
        "compile_share_of_cold": compile_s / cold_s,
        "cold_minus_warm_s": cold_s - warm_s,
        "compiles_per_cold_run": cold[-1]["compiles"],
        "approxtree_kernels_compiled": kernels,
        "runs": {
            "cold": [{k: r[k] for k in _RUN_KEYS} for r in cold],
            "warm": [{k: r[k] for k in _RUN_KEYS} for r in warm],
        },
    }


def _plot(results: dict, path: Path) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    names = list(results)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    x = range(len(names))
    cold = [results[n]["cold_process_s"] for n in names]
    comp = [results[n]["cold_compile_s"] for n in names]
    warm = [results[n]["warm_process_s"] for n in names]
    ax.bar([i - 0.2 for i in x], cold, 0.4, label="cold cache (process)", color="#c66")
    ax.bar([i - 0.2 for i in x], comp, 0.4, label="of which compiling", color="#933")
    ax.bar([i + 0.2 for i in x], warm, 0.4, label="warm cache (process)", color="#69c")
    # The compiling thread's CPU time: what a quiet machine would wait for the compiles.
    cpu = [results[n]["cold_compile_cpu_s"] for n in names]
    ax.bar([i - 0.2 for i in x], cpu, 0.2, label="compiling, CPU seconds", color="#222")
    ax.set_xticks(list(x), names)
    ax.set_ylabel("seconds (median)")
    ax.legend()
    ax.set_title("First run vs warm numba cache")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default="bench_compile.json")
    ap.add_argument("--commands", default="demo,mesh,render")
    opts = ap.parse_args()
    wanted = opts.commands.split(",")
    with tempfile.TemporaryDirectory(prefix="bench_compile_") as tmp:
        work = Path(tmp)
        setup_cache = work / "setup_cache"
        # Inputs made once, with their own cache: the demo tree to render, and a DEM to mesh
        # when the shared data is absent.
        dem = SHARED_DEM
        if not dem.is_file():
            dem = work / "dem.tif"
            _probe(["generate", str(dem), "--size", "257"], setup_cache, work, "setup_dem")
        _probe(["demo", "--out", str(work / "tree.zarr")], setup_cache, work, "setup_tree")
        commands = _commands(work, dem)
        runs: dict[str, dict[str, list[dict]]] = {n: {"cold": [], "warm": []} for n in wanted}
        for rep in range(opts.repeat):
            # Interleaved: each command cold then warm, so load drift hits both alike.
            for name in wanted:
                cache = work / f"cache_{name}_{rep}"
                cache.mkdir()
                cold = _probe(commands[name](), cache, work, f"{name}_cold_{rep}")
                warm = _probe(commands[name](), cache, work, f"{name}_warm_{rep}")
                runs[name]["cold"].append(cold)
                runs[name]["warm"].append(warm)
                shutil.rmtree(cache)
                print(
                    f"{name} #{rep}: cold {cold['process_s']:.1f} s "
                    f"(compiling {cold['compile_s']:.1f} s, {cold['compile_cpu_s']:.1f} s CPU), "
                    f"warm {warm['process_s']:.1f} s",
                    flush=True,
                )
        results = {n: _summary(r["cold"], r["warm"]) for n, r in runs.items()}
    report = {
        "repeat": opts.repeat,
        "python": sys.version.split()[0],
        "cpus": os.cpu_count(),
        "load_average": os.getloadavg(),
        "dem": str(dem if dem == SHARED_DEM else "approxtree generate --size 257"),
        "results": results,
    }
    Path(opts.out).write_text(json.dumps(report, indent=1))
    _plot(results, Path(opts.out).with_suffix(".png"))
    for name, r in results.items():
        print(
            f"{name}: cold {r['cold_process_s']:.1f} s, warm {r['warm_process_s']:.1f} s, "
            f"compiling {r['cold_compile_s']:.1f} s ({100 * r['compile_share_of_cold']:.0f}%), "
            f"{r['cold_compile_cpu_s']:.1f} s CPU"
        )


if __name__ == "__main__":
    main()
