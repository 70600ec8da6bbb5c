"""Hillshade bake time on a fractal grid vs ``gdaldem hillshade``, side by side in one run.

Both sides do the same end-to-end job: read a float32 GeoTIFF, compute the Horn hillshade and
write a byte GeoTIFF. Our side also reports the compute step alone. Medians of --repeats runs
(after one warm-up run that compiles the numba kernels); results in
benchmarks/results/bake.json.

    python benchmarks/bench_bake.py [--size 8192] [--repeats 3]

With --pyramid, the end-to-end bake into the texture pyramid (``approxtree.bake``, numpy
shading) instead, each run a fresh process so its peak memory (VmHWM, and gdaldem's maxrss)
is its own; --baseline DIR adds the same bake from another checkout (say, main) as a peer,
interleaved. Results in benchmarks/results/bake_pyramid.json.

    python benchmarks/bench_bake.py --pyramid [--size 8192] [--repeats 3] [--baseline DIR]

With --cli, issue 15's row: the command line end to end, ``approxtree bake DEM --no-gl``
and ``approxtree bake DEM`` as a user types it (``ours_default``: OpenGL on a GPU only)
against ``gdaldem hillshade DEM out.tif`` on one DEM written by ``approxtree fractal``
(uncompressed unless --compress), each run a fresh process timed with its peak RSS and CPU
seconds (/usr/bin/time), interleaved, medians of --repeats (≥ 5 for the issue), after one
warm-up per side (numba cache, .pyc files). ``import`` is a process that only
imports the bake's modules (the fixed cost in every bake). Also the time to read texture
patches of the baked pyramid. Results in benchmarks/results/bake_cli_<size>.json and .png.

    python benchmarks/bench_bake.py --cli [--size 8192] [--repeats 5] [--gl] [--baseline DIR]
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

import numpy as np
import rasterio
from affine import Affine

RESULTS = Path(__file__).resolve().parent / "results"


def ours_end_to_end(src: Path, dst: Path) -> tuple[float, float]:
    """(total seconds, compute seconds) of read → TopographicShading → write."""
    import approxtree as at
    from approxtree.textures import TopographicShading

    t0 = time.perf_counter()
    grid = at.open_terrain(src)
    t1 = time.perf_counter()
    shade = TopographicShading(grid).shade()
    t2 = time.perf_counter()
    profile = {
        "driver": "GTiff",
        "width": grid.width,
        "height": grid.height,
        "count": 1,
        "dtype": "uint8",
        "transform": grid.transform,
        "nodata": 0,
    }
    with rasterio.open(dst, "w", **profile) as ds:
        ds.write(shade, 1)
    return time.perf_counter() - t0, t2 - t1


def gdaldem_end_to_end(src: Path, dst: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run(["gdaldem", "hillshade", "-q", str(src), str(dst)], check=True)
    return time.perf_counter() - t0


#: Run in a fresh process: bake the DEM into a pyramid, print seconds and peak memory.
_BAKE_CHILD = """
import json, sys, time
t0 = time.perf_counter()
import approxtree as at
from approxtree.textures.bake import bake
t1 = time.perf_counter()
bake(at.open_terrain(sys.argv[1]), sys.argv[2], gl=False)
t2 = time.perf_counter()
status = open("/proc/self/status").read().split("VmHWM:")[1].split()[0]
print(json.dumps({"import_s": t1 - t0, "bake_s": t2 - t1, "peak_bytes": int(status) * 1024}))
"""


def _child(cmd: list[str], env: dict[str, str], cwd: Path) -> tuple[float, int, str]:
    """(wall seconds, peak RSS bytes, stdout) of a fresh process run in ``cwd``, measured by
    /usr/bin/time (a wait4 from this process would report this process's size at the fork)."""
    wall, peak, _, out = _child_cpu(cmd, env, cwd)
    return wall, peak, out


def _child_cpu(cmd: list[str], env: dict[str, str], cwd: Path) -> tuple[float, int, float, str]:
    """``_child`` with the process's CPU seconds (user + system, all its threads) third: on a
    shared machine the wall time counts the other jobs' turns too."""
    with tempfile.NamedTemporaryFile("r") as peak:
        t0 = time.perf_counter()
        done = subprocess.run(
            ["/usr/bin/time", "-f", "%M %U %S", "-o", peak.name, *cmd],
            stdout=subprocess.PIPE,
            env=env,
            cwd=cwd,
            check=True,
        )
        wall = time.perf_counter() - t0
        kib, user, system = peak.read().split()[-3:]
    return wall, int(kib) * 1024, float(user) + float(system), done.stdout.decode()


def bench_pyramid(size: int, repeats: int, baseline: str | None) -> dict:
    """Fresh-process bakes into a pyramid (ours, the baseline's) and gdaldem, interleaved."""
    from approxtree.datasets import fractal_heights

    sides = {"ours": dict(os.environ)}
    if baseline:
        sides["baseline"] = dict(os.environ, PYTHONPATH=str(Path(baseline).resolve()))
    runs: dict[str, list[dict]] = {name: [] for name in [*sides, "gdaldem"]}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        src = tmp_path / "dem.tif"
        z = fractal_heights(size, seed=1).astype(np.float32)
        dem_bytes = z.nbytes
        transform = Affine(10, 0, 0, 0, -10, size * 10)
        profile = {"width": size, "height": size, "count": 1, "dtype": "float32"}
        with rasterio.open(src, "w", driver="GTiff", transform=transform, **profile) as ds:
            ds.write(z, 1)
        del z
        # Warm-up: compiles (or loads) each side's numba cache, excluded from the figures. The
        # children run in the temp folder: ``python -c`` puts its working directory first on
        # sys.path, which would shadow the baseline's PYTHONPATH.
        for name, env in sides.items():
            _child(
                [sys.executable, "-c", _BAKE_CHILD, str(src), str(tmp_path / name)], env, tmp_path
            )
        for i in range(repeats):
            for name, env in sides.items():
                dst = tmp_path / f"{name}{i}"
                cmd = [sys.executable, "-c", _BAKE_CHILD, str(src), str(dst)]
                wall, _, out = _child(cmd, env, tmp_path)
                runs[name].append({"wall_s": wall, **json.loads(out)})
                shutil.rmtree(dst)
            dst = tmp_path / f"gdal{i}.tif"
            cmd = ["gdaldem", "hillshade", "-q", str(src), str(dst)]
            wall, peak, _ = _child(cmd, dict(os.environ), tmp_path)
            runs["gdaldem"].append({"wall_s": wall, "peak_bytes": peak})
            dst.unlink()
            print(
                f"run {i}: "
                + ", ".join(
                    f"{k} {v[-1]['wall_s']:.2f} s {v[-1]['peak_bytes'] / 1e6:.0f} MB"
                    for k, v in runs.items()
                ),
                flush=True,
            )
    med = {
        name: {key: statistics.median(r[key] for r in rs) for key in rs[0]}
        for name, rs in runs.items()
    }
    gdal = med["gdaldem"]
    return {
        "benchmark": "end-to-end bake into the texture pyramid (fresh process) vs gdaldem",
        "size": size,
        "dem_bytes": dem_bytes,
        "medians": med,
        "wall_ratio_over_gdaldem": {k: v["wall_s"] / gdal["wall_s"] for k, v in med.items()},
        "peak_over_dem_bytes": {k: v["peak_bytes"] / dem_bytes for k, v in med.items()},
        "runs": runs,
    }


#: A process that only imports what ``approxtree bake`` imports before its work.
_IMPORT_CHILD = "import approxtree.cli, approxtree.io, approxtree.textures.bake"

#: One ``approxtree bake`` under cProfile, in its own process: seconds of its phases (imports
#: before the command runs, the numba dispatch that loads a cached kernel, the shading kernel,
#: the pyramid writes, the wait on the strip workers) as JSON on stdout.
_PROFILE_CHILD = """
import cProfile, json, pstats, sys, time
t0 = time.perf_counter()
prof = cProfile.Profile()
prof.enable()
import approxtree.cli, approxtree.io, approxtree.textures.bake, approxtree.render.context
t1 = time.perf_counter()
approxtree.cli.main(sys.argv[1:], standalone_mode=False)
prof.disable()
t2 = time.perf_counter()
phases = {"numba_dispatch_and_cache_load": "_compile_for_args",
          "hillshade_kernel": "hillshade_grey_alpha_rows", "spool_strips": "_spool_strips",
          "pwrite": "<built-in method posix.pwrite>",
          "wait_on_workers": "<method 'acquire' of '_thread.lock' objects>",
          "open_dem": "_terrain_of"}
found = {k: 0.0 for k in phases}
for (path, line, name), (cc, nc, tt, ct, callers) in pstats.Stats(prof).stats.items():
    for k, want in phases.items():
        if name == want:
            found[k] = max(found[k], ct)
print(json.dumps({"imports_s": t1 - t0, "command_s": t2 - t1, "profiled_total_s": t2 - t0,
                  "phases_cumulative_s": found}))
"""


#: Modules whose import seconds the start-up profile lists.
_WATCHED_IMPORTS = (
    "numpy", "numba", "llvmlite.binding", "rasterio", "click", "tifffile", "affine",
    "approxtree.kernels", "approxtree.geometry", "approxtree.io", "approxtree.textures.bake",
    "approxtree.render", "approxtree.tree.zarr_store", "approxtree.cli",
)  # fmt: skip


def _startup_profile(src: Path, env: dict[str, str], cwd: Path) -> dict:
    """Where one bake's time goes: cProfile phases and ``-X importtime`` of its imports (the
    top-level packages by cumulative seconds)."""
    out = cwd / "profiled"
    res = subprocess.run(
        [sys.executable, "-c", _PROFILE_CHILD, "bake", str(src), "--out", str(out), "--no-gl"],
        env=env, cwd=cwd, capture_output=True, text=True, check=True,
    )  # fmt: skip
    report = json.loads(res.stdout.strip().splitlines()[-1])
    shutil.rmtree(out, ignore_errors=True)
    imp = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", _IMPORT_CHILD + ", approxtree.render.context"],
        env=env, cwd=cwd, capture_output=True, text=True, check=True,
    )  # fmt: skip
    # Each watched module's cumulative import seconds where it is first imported, and the
    # whole import (the top-level entries).
    watched = {}
    total = 0.0
    for line in imp.stderr.splitlines():
        parts = line.split("|")
        if len(parts) != 3 or not parts[1].strip().isdigit():
            continue
        name = parts[2].strip()
        seconds = int(parts[1]) / 1e6
        if not parts[2].startswith("  "):
            total += seconds
        if name in _WATCHED_IMPORTS and name not in watched:
            watched[name] = seconds
    report["import_cumulative_s"] = {"all": total, **watched}
    return report


def _patch_reads(folder: Path) -> dict:
    """Median seconds to read texture patches (4096², 1024², 256² windows) of a pyramid."""
    from approxtree.textures import TexturePyramid

    pyramid = TexturePyramid(folder)
    lv = pyramid.levels[0]
    out = {}
    for side in (4096, 1024, 256):
        rng = np.random.default_rng(side)
        times = []
        for _ in range(5):
            r0 = int(rng.integers(0, max(1, lv.height - side)))
            c0 = int(rng.integers(0, max(1, lv.width - side)))
            t0 = time.perf_counter()
            pyramid.read(0, r0, c0, side, side)
            times.append(time.perf_counter() - t0)
        out[f"{side}"] = statistics.median(times)
    return out


def bench_cli(
    size: int, repeats: int, gl: bool, baseline: str | None, compress: str, dem: str | None
) -> dict:
    """``approxtree bake`` (fresh processes) vs ``gdaldem hillshade``, interleaved."""
    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        # Compiled bytecode as an installed package has it (.pyc written by the warm-up run,
        # under a prefix in the temp folder): with PYTHONDONTWRITEBYTECODE every run would
        # compile approxtree's sources afresh (~0.1 s that no user pays).
        env = dict(os.environ, PYTHONPYCACHEPREFIX=str(tmp_path / "pycache"))
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        src = Path(dem).resolve() if dem else tmp_path / "dem.tif"
        if not dem:
            subprocess.run(
                [sys.executable, "-m", "approxtree", "fractal", str(src), "--size", str(size),
                 "--seed", "1", "--cell-size", "10", "--compress", compress],
                check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path,
            )  # fmt: skip
        with rasterio.open(src) as ds:
            dem_bytes = ds.width * ds.height * 4
            size = ds.width
        bake = [sys.executable, "-m", "approxtree", "bake", str(src), "--out"]
        # ours_default: the command as a user types it (OpenGL on a GPU only, else numba).
        sides: dict[str, tuple[list[str], dict[str, str]]] = {
            "ours": ([*bake, "{out}", "--no-gl"], env),
            "ours_default": ([*bake, "{out}"], env),
        }
        if gl:
            sides["ours_gl"] = ([*bake, "{out}"], env)
        if baseline:
            # Its own kernel cache in the temp folder: the baseline checkout is only read.
            base_env = dict(
                env,
                PYTHONPATH=str(Path(baseline).resolve()),
                APPROXTREE_KERNEL_CACHE=str(tmp_path / "baseline_kernels"),
            )
            sides["baseline"] = ([*bake, "{out}", "--no-gl"], base_env)
        sides["gdaldem"] = (["gdaldem", "hillshade", "-q", str(src), "{out}.tif"], env)
        sides["import"] = ([sys.executable, "-c", _IMPORT_CHILD], env)
        runs: dict[str, list[dict]] = {name: [] for name in sides}
        patch_reads = {}
        # Warm-up (numba caches, page cache of the DEM), then interleaved repeats. Children
        # run in the temp folder, so a baseline's PYTHONPATH is not shadowed by this checkout.
        for i in range(-1, repeats):
            for name, (cmd, side_env) in sides.items():
                out = tmp_path / f"{name}{i}"
                argv = [a.replace("{out}", str(out)) for a in cmd]
                wall, peak, cpu, _ = _child_cpu(argv, side_env, tmp_path)
                written = sum(f.stat().st_size for f in tmp_path.glob(f"{name}{i}*") if f.is_file())
                written += sum(f.stat().st_size for f in out.glob("*")) if out.is_dir() else 0
                if i >= 0:
                    runs[name].append(
                        {"wall_s": wall, "cpu_s": cpu, "peak_bytes": peak, "bytes_written": written}
                    )
                if name == "ours" and i == 0:
                    patch_reads = _patch_reads(out)
                shutil.rmtree(out, ignore_errors=True)
                Path(f"{out}.tif").unlink(missing_ok=True)
            if i >= 0:
                print(
                    f"run {i}: "
                    + ", ".join(
                        f"{k} {v[-1]['wall_s']:.2f} s {v[-1]['peak_bytes'] / 1e6:.0f} MB"
                        for k, v in runs.items()
                    ),
                    flush=True,
                )
        profile = _startup_profile(src, env, tmp_path)
    med = {
        name: {key: statistics.median(r[key] for r in rs) for key in rs[0]}
        for name, rs in runs.items()
    }
    gdal = med["gdaldem"]
    return {
        "benchmark": "approxtree bake (CLI, fresh process) vs gdaldem hillshade → GeoTIFF",
        "size": size,
        "dem_bytes": dem_bytes,
        "dem_compression": "given" if dem else compress,
        "cores": os.cpu_count(),
        "load_average": load_start,
        "bytecode": "cached (.pyc under PYTHONPYCACHEPREFIX, as an installed package has)",
        "medians": med,
        "wall_ratio_over_gdaldem": {k: v["wall_s"] / gdal["wall_s"] for k, v in med.items()},
        "cpu_ratio_over_gdaldem": {k: v["cpu_s"] / gdal["cpu_s"] for k, v in med.items()},
        "peak_over_dem_bytes": {k: v["peak_bytes"] / dem_bytes for k, v in med.items()},
        "patch_read_s": patch_reads,
        "startup_profile": profile,
        "load_average_end": os.getloadavg(),
        "runs": runs,
    }


def plot_cli(report: dict, path: Path) -> None:
    """Wall time and peak RSS medians of each side, with the 1.5× and 3× targets."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    med = report["medians"]
    names = list(med)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.bar(names, [med[n]["wall_s"] for n in names], color=[f"C{i}" for i in range(len(names))])
    a.axhline(1.5 * med["gdaldem"]["wall_s"], color="k", ls="--", lw=1, label="1.5× gdaldem")
    a.set_ylabel("seconds (median, fresh process)")
    a.legend()
    b.bar(names, [med[n]["peak_bytes"] / 1e6 for n in names])
    b.axhline(3 * report["dem_bytes"] / 1e6, color="k", ls="--", lw=1, label="3× DEM bytes")
    b.set_ylabel("peak RSS (MB)")
    b.legend()
    fig.suptitle(f"Hillshade bake {report['size']}², end to end")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=8192)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--pyramid", action="store_true", help="bake into a pyramid instead")
    parser.add_argument("--baseline", help="another checkout's root, baked as a peer")
    parser.add_argument("--cli", action="store_true", help="the CLI end to end vs gdaldem")
    parser.add_argument("--gl", action="store_true", help="--cli: also the OpenGL bake")
    parser.add_argument("--compress", default="none", help="--cli: the fractal DEM's codec")
    parser.add_argument("--dem", help="--cli: an existing DEM instead of a fractal")
    args = parser.parse_args()
    if shutil.which("gdaldem") is None:
        raise SystemExit("gdaldem not found: install the Debian package gdal-bin")
    if args.cli:
        RESULTS.mkdir(exist_ok=True)
        report = bench_cli(args.size, args.repeats, args.gl, args.baseline, args.compress, args.dem)
        out = RESULTS / f"bake_cli_{report['size']}.json"
        out.write_text(json.dumps(report, indent=2))
        plot_cli(report, out.with_suffix(".png"))
        print(json.dumps({k: v for k, v in report.items() if k != "runs"}, indent=2))
        return
    if args.pyramid:
        RESULTS.mkdir(exist_ok=True)
        report = bench_pyramid(args.size, args.repeats, args.baseline)
        out = RESULTS / f"bake_pyramid_{args.size}.json"
        out.write_text(json.dumps(report, indent=2))
        print(json.dumps({k: v for k, v in report.items() if k != "runs"}, indent=2))
        return
    from approxtree.datasets import fractal_heights

    RESULTS.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "dem.tif"
        z = fractal_heights(args.size, seed=1)
        with rasterio.open(
            src,
            "w",
            driver="GTiff",
            width=args.size,
            height=args.size,
            count=1,
            dtype="float32",
            transform=Affine(10, 0, 0, 0, -10, args.size * 10),
        ) as ds:
            ds.write(z, 1)
        del z
        ours_end_to_end(src, Path(tmp) / "warm.tif")
        ours, compute, gdal = [], [], []
        for i in range(args.repeats):
            total, comp = ours_end_to_end(src, Path(tmp) / f"ours{i}.tif")
            ours.append(total)
            compute.append(comp)
            gdal.append(gdaldem_end_to_end(src, Path(tmp) / f"gdal{i}.tif"))
            print(
                f"run {i}: ours {total:.2f} s (compute {comp:.2f} s), gdaldem {gdal[-1]:.2f} s",
                flush=True,
            )
        with (
            rasterio.open(Path(tmp) / "ours0.tif") as a,
            rasterio.open(Path(tmp) / "gdal0.tif") as b,
        ):
            diff = np.abs(a.read(1).astype(int) - b.read(1).astype(int)).max()
    report = {
        "benchmark": "Horn hillshade, read GeoTIFF → shade → write GeoTIFF",
        "size": args.size,
        "ours_seconds_median": statistics.median(ours),
        "ours_compute_seconds_median": statistics.median(compute),
        "gdaldem_seconds_median": statistics.median(gdal),
        "time_ratio_ours_over_gdaldem": statistics.median(ours) / statistics.median(gdal),
        "max_abs_difference_grey_levels": int(diff),
        "runs": {"ours": ours, "ours_compute": compute, "gdaldem": gdal},
    }
    (RESULTS / "bake.json").write_text(json.dumps(report, indent=2))
    print(json.dumps({k: v for k, v in report.items() if k != "runs"}, indent=2))


if __name__ == "__main__":
    main()
