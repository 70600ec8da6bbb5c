"""What a fresh install pays for numba compiles: demo, mesh and render, cold vs warm cache.

    python benchmarks/bench_compile.py [--repeat 3] [--out benchmarks/results/bench_compile.json]
                                       [--fresh-install | --no-fresh-install]

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

Fresh install (what a user meets after ``pip install .``): the wheel is built once
(``pip wheel . --no-deps``, which compiles the kernels into the wheel's cache, setup.py; its
build time and the compile step's share are reported), then for each repeat and command it is
installed anew (``pip install --no-deps --target``: a new package folder beside this
interpreter's dependencies) and the command runs there once with NUMBA_CACHE_DIR unset, so the
package's shipped cache is the one used: "fresh_compile_s" is what the first run compiles.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
PROBE = HERE / "compile_probe.py"
SHARED_DEM = HERE.parent.parent / "shared" / "data" / "nc" / "elev_ned_30m.tif"


def _probe(
    args: list[str], cache: Path | None, work: Path, tag: str, site: Path | None = None
) -> dict:
    """Run one command through the probe; its JSON plus the process's wall time.

    cache: the NUMBA_CACHE_DIR to use; None: numba's and approxtree's own locators (the
    installed package's cache). site: a folder put first on PYTHONPATH (a fresh install)."""
    out = work / f"{tag}.json"
    env = dict(os.environ)
    for name in ("NUMBA_CACHE_DIR", "APPROXTREE_KERNEL_CACHE"):
        env.pop(name, None)
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    if site is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site), env.get("PYTHONPATH")]))
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
_AOT_LINE = re.compile(r"approxtree: (\d+) compiled kernels cached in ([0-9.]+) s")


def _build_wheel(work: Path) -> dict:
    """``pip wheel . --no-deps`` of the project (kernels compiled by setup.py): the wheel's
    path, build seconds, and the seconds and entries of the compile step (from pip -v)."""
    dist = work / "dist"
    t0 = time.perf_counter()
    run = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(HERE.parent), "--no-deps", "-v", "-w", dist],
        capture_output=True,
        text=True,
        check=True,
    )
    build_s = time.perf_counter() - t0
    (wheel,) = dist.glob("approxtree-*.whl")
    found = _AOT_LINE.search(run.stdout + run.stderr)
    with zipfile.ZipFile(wheel) as z:
        cache_bytes = sum(i.file_size for i in z.infolist() if "/_kernel_cache/" in i.filename)
    return {
        "wheel": wheel,
        "build_s": build_s,
        "aot_compile_s": float(found.group(2)) if found else None,
        "aot_cached_kernels": int(found.group(1)) if found else 0,
        "wheel_bytes": wheel.stat().st_size,
        "cache_bytes": cache_bytes,
    }


def _fresh_install(wheel: Path, site: Path) -> float:
    """Install the wheel (no dependencies: this interpreter's are used) into a new folder."""
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", site, wheel],
        check=True,
    )
    return time.perf_counter() - t0


def _fresh_summary(runs: list[dict]) -> dict:
    med = statistics.median
    return {
        "fresh_process_s": med(r["process_s"] for r in runs),
        "fresh_command_s": med(r["wall_s"] for r in runs),
        "fresh_compile_s": med(r["compile_s"] for r in runs),
        "fresh_compile_cpu_s": med(r["compile_cpu_s"] for r in runs),
        "fresh_compiles": max(r["compiles"] for r in runs),
        "fresh_kernels_compiled": sorted({e["kernel"] for r in runs for e in r["events"]}),
        "approxtree_file": runs[-1]["approxtree_file"],
        "runs": [{k: r[k] for k in _RUN_KEYS} for r in runs],
    }


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
    if all("fresh_compile_s" in results[n] for n in names):
        # After pip install . (kernels compiled into the wheel): what the first run compiles.
        fresh = [results[n]["fresh_compile_s"] for n in names]
        ax.bar([i + 0.45 for i in x], fresh, 0.1, label="fresh install: compiling", color="#393")
    ax.set_xticks(list(x), names)
    ax.set_ylabel("seconds (median)")
    ax.legend()
    ax.set_title("First run vs warm numba cache")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(HERE / "results" / "bench_compile.json"))
    ap.add_argument("--commands", default="demo,mesh,render")
    ap.add_argument(
        "--fresh-install",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also build the wheel and time each command's first run on a fresh install",
    )
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
        fresh: dict[str, list[dict]] = {n: [] for n in wanted}
        wheel = _build_wheel(work) if opts.fresh_install else None
        if wheel:
            print(
                f"wheel built in {wheel['build_s']:.1f} s, of which compiling kernels "
                f"{wheel['aot_compile_s']} s ({wheel['aot_cached_kernels']} entries)",
                flush=True,
            )
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
                if wheel:
                    # The first run of the command on a new install of the wheel.
                    site = work / f"site_{name}_{rep}"
                    _fresh_install(wheel["wheel"], site)
                    first = _probe(commands[name](), None, work, f"{name}_fresh_{rep}", site)
                    fresh[name].append(first)
                    shutil.rmtree(site)
                    print(
                        f"{name} #{rep}: fresh install {first['process_s']:.1f} s "
                        f"(compiling {first['compile_s']:.1f} s, {first['compiles']} compiles)",
                        flush=True,
                    )
                print(
                    f"{name} #{rep}: cold {cold['process_s']:.1f} s "
                    f"(compiling {cold['compile_s']:.1f} s, {cold['compile_cpu_s']:.1f} s CPU), "
                    f"warm {warm['process_s']:.1f} s",
                    flush=True,
                )
        results = {n: _summary(r["cold"], r["warm"]) for n, r in runs.items()}
        if wheel:
            for name in wanted:
                results[name].update(_fresh_summary(fresh[name]))
    report = {
        "repeat": opts.repeat,
        "python": sys.version.split()[0],
        "cpus": os.cpu_count(),
        "load_average": os.getloadavg(),
        "dem": str(dem if dem == SHARED_DEM else "approxtree generate --size 257"),
        "results": results,
    }
    if wheel:
        report["wheel"] = {k: v for k, v in wheel.items() if k != "wheel"}
    Path(opts.out).parent.mkdir(parents=True, exist_ok=True)
    Path(opts.out).write_text(json.dumps(report, indent=1))
    _plot(results, Path(opts.out).with_suffix(".png"))
    for name, r in results.items():
        print(
            f"{name}: cold {r['cold_process_s']:.1f} s, warm {r['warm_process_s']:.1f} s, "
            f"compiling {r['cold_compile_s']:.1f} s ({100 * r['compile_share_of_cold']:.0f}%), "
            f"{r['cold_compile_cpu_s']:.1f} s CPU"
            + (
                f"; fresh install: compiling {r['fresh_compile_s']:.1f} s "
                f"({r['fresh_compiles']} compiles), process {r['fresh_process_s']:.1f} s"
                if "fresh_compile_s" in r
                else ""
            )
        )


if __name__ == "__main__":
    main()
