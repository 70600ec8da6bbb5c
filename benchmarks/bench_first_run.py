"""First run against second run of every command on every kind of terrain file (issue 27, item 2).

    python benchmarks/bench_first_run.py [--approxtree CMD] [--cold] [--repeat 3]
                                         [--out benchmarks/first_run.json]
    python benchmarks/bench_first_run.py --probe OUT.json   # kernels compiled, one process

What a user meets after ``pip install .``: each command of the matrix below runs as a fresh
process of the installed ``approxtree`` (``--approxtree``: the console script of a fresh venv
or a ``python -m approxtree`` line), once ("first", the first use after the install), then
``--repeat`` more times ("second": their median). The kernel cache files written during each
run are counted (``--cache``: the installed package's ``_kernel_cache``): after a complete
install-time compile the first run writes none, and first ≈ second.

``--cold``: what an editable install or an upgrade pays (an empty or stale cache): every
command's first run gets an empty ``APPROXTREE_KERNEL_CACHE`` of its own, so "first" is that
command's whole compile, which the target keeps ≤ 5 s per command on a quiet machine.

``--probe``: runs the whole matrix in this process with numba's compile events recorded and
writes, per command, the kernels (and argument types) it compiled: with the warm-up's cache
(``APPROXTREE_KERNEL_CACHE`` filled by ``python -m approxtree._warmup``) every list is empty.

Inputs: ../shared/data (its README), one file of each kind: GeoTIFF (float32, int16, NaN
nodata), SRTM .hgt.zip, USGS ASCII DEM, ESRI ASCII grid, scape .stm and .pgm, numpy .npz,
LAZ point cloud, a quantized-mesh tile, and two PNGs written here (16-bit grayscale and
Terrarium). Timings are wall seconds of the whole process (interpreter start and imports
included); on a shared machine they are noisy: report medians. Commands per input: info,
build, render, bake, mesh (each strategy the input takes), verify, convert, view (5 frames in
a window of a private Xvfb display), tiles and rd where the input allows; on the float32
GeoTIFF also ``update`` (a 64² patch) and ``serve`` (timed until its first tile comes back).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DATA = HERE.parent.parent / "shared" / "data"

#: One file of each kind in ../shared/data: kind -> (relative path, reader options).
SHARED_INPUTS: dict[str, tuple[str, list[str]]] = {
    "GeoTIFF float32": ("nc/elev_ned_30m.tif", []),
    "GeoTIFF int16": ("roads/lux_elev.tif", []),
    "GeoTIFF NaN sea": ("edge/nz_elev.tif", []),
    "SRTM hgt.zip": ("srtm/N22W160v2.3a.hgt.zip", []),
    "USGS DEM": ("edge/SainteHelens.dem", []),
    "ASCII grid": ("edge/hugo_site.asc", []),
    "scape STM": ("scape/crater.stm", []),
    "PGM": ("scape/crater.pgm", []),
    "numpy npz": ("edge/jacksboro_fault_dem.npz", []),
    "LAZ": ("lidar/autzen_trim.laz", []),
    "quantized-mesh tile": ("tin/9_533_383.terrain", []),
}

#: Inputs that are grids with a CRS (quantized-mesh tiles need one).
GLOBE_GRIDS = {"GeoTIFF float32", "GeoTIFF int16", "GeoTIFF NaN sea", "SRTM hgt.zip", "USGS DEM"}


def _png_inputs(work: Path) -> dict[str, tuple[Path, list[str]]]:
    """A 16-bit grayscale PNG and a Terrarium PNG (129² hill) written into ``work``."""
    from PIL import Image

    from approxtree.datasets import fractal_heights

    z = fractal_heights(129, 129, seed=5, relief=400.0) + 200.0
    grey = work / "heights16.png"
    Image.fromarray(np.round(z * 10).astype(np.uint16)).save(grey)
    v = z.astype(np.float64) + 32768.0
    rgb = np.stack([v // 256, np.floor(v % 256), np.floor((v % 1) * 256)], axis=-1)
    terrarium = work / "terrarium.png"
    Image.fromarray(rgb.astype(np.uint8), "RGB").save(terrarium)
    return {
        "PNG 16-bit": (grey, ["--height-scale", "0.1", "--cell-size", "30"]),
        "PNG Terrarium": (terrarium, ["--encoding", "terrarium", "--cell-size", "30"]),
    }


def inputs(work: Path) -> dict[str, tuple[Path, list[str]]]:
    """Every kind of input present: kind -> (path, reader options)."""
    found = {
        kind: (DATA / rel, opts)
        for kind, (rel, opts) in SHARED_INPUTS.items()
        if (DATA / rel).is_file()
    }
    found.update(_png_inputs(work))
    return found


def commands(kind: str, path: Path, opts: list[str], work: Path) -> list[tuple[str, list[str]]]:
    """The commands run on one input, in order (a store is built before it is rendered):
    (label, argv after ``approxtree``)."""
    slug = "".join(c if c.isalnum() else "_" for c in kind)
    out = work / slug
    out.mkdir(parents=True, exist_ok=True)
    src = [str(path), *opts]
    store = str(out / "tree.zarr")
    ow = ["--overwrite"]
    cmds: list[tuple[str, list[str]]] = [("info", ["info", *src])]
    if kind == "LAZ":
        cmds.append(("info --ground-only", ["info", *src, "--ground-only"]))
    cmds.append(("build", ["build", *src, "--out", store, "-q", *ow]))
    cmds.append(
        ("render", ["render", store, "--out", str(out / "render.png"), "--size", "640x360", *ow])
    )
    if kind == "LAZ":
        pq = str(out / "pq.zarr")
        cmds.append(
            (
                "build --kind point-quadtree",
                ["build", *src, "--kind", "point-quadtree", "--out", pq, "-q", *ow],
            )
        )
        cmds.append(
            (
                "render point-quadtree",
                ["render", pq, "--out", str(out / "pq.png"), "--size", "640x360", *ow],
            )
        )
    cmds.append(("bake", ["bake", *src, "--out", str(out / "tex"), "-q", *ow]))
    strategies = (
        ["tin"] if kind in ("LAZ", "quantized-mesh tile") else ["tin", "rtin", "nonregular", "grid"]
    )
    for strategy in strategies:
        cmds.append(
            (
                f"mesh --strategy {strategy}",
                [
                    "mesh",
                    *src,
                    "--strategy",
                    strategy,
                    "--max-error",
                    "1",
                    "--out",
                    str(out / f"{strategy}.ply"),
                    "-q",
                    *ow,
                ],
            )
        )
    cmds.append(("verify mesh", ["verify", str(out / "tin.ply"), "--source", *src]))
    cmds.append(("verify store", ["verify", store]))
    cmds.append(("convert", ["convert", store, str(out / "tree.zarr.zip"), *ow]))
    # The viewer: a few frames in a window of the virtual display (bench() starts Xvfb).
    cmds.append(("view", ["view", store, "--frames", "5", "--size", "640x360"]))
    if kind == "GeoTIFF float32":
        cmds.append(("update", ["update", store, str(_patch(path, out))]))
        cmds.append(("serve", [SERVE, store]))
    # Cesium's tiles need a grid placed on the globe (a CRS); rd a complete grid window.
    if kind in GLOBE_GRIDS:
        qm = ["tiles", store, "--format", "quantized-mesh", "--out", str(out / "qm"), *ow]
        cmds.append(("tiles quantized-mesh", qm))
    if kind == "GeoTIFF float32":
        for fmt in ("3dtiles", "3dtiles-terrain", "terrarium", "imagery"):
            textures = ["--textures", str(out / "tex")] if fmt == "imagery" else []
            argv = ["tiles", store, "--format", fmt, "--out", str(out / fmt), *textures, *ow]
            cmds.append((f"tiles {fmt}", argv))
    if kind not in ("LAZ", "quantized-mesh tile", "GeoTIFF NaN sea", "GeoTIFF int16"):
        cmds.append(("rd", ["rd", *src, "--size", "33", "-q"]))
    return cmds


#: argv[0] of the rows that run ``approxtree serve`` until a first tile comes back.
SERVE = "serve"


def _patch(dem: Path, out: Path) -> Path:
    """A 64² window of ``dem`` raised by 5 (a GeoTIFF aligned with its cells), for ``update``."""
    import rasterio
    from rasterio.windows import Window

    patch = out / "patch.tif"
    with rasterio.open(dem) as src:
        window = Window(32, 32, 64, 64)
        z = src.read(1, window=window) + 5
        profile = dict(src.profile, width=64, height=64, transform=src.window_transform(window))
    profile.pop("blockxsize", None)
    profile.pop("blockysize", None)
    profile["tiled"] = False
    with rasterio.open(patch, "w", **profile) as dst:
        dst.write(z, 1)
    return patch


def matrix(work: Path, kinds: list[str] | None = None) -> list[tuple[str, str, list[str]]]:
    """(kind, label, argv) of every run (``kinds``: those inputs only, "-" for the commands
    without an input), the inputs' commands then fractal and demo."""
    runs = [
        (kind, label, argv)
        for kind, (path, opts) in inputs(work).items()
        if kinds is None or kind in kinds
        for label, argv in commands(kind, path, opts, work)
    ]
    if kinds is not None and "-" not in kinds:
        return runs
    runs.append(
        ("-", "fractal", ["fractal", str(work / "fractal.tif"), "--size", "513", "--overwrite"])
    )
    runs.append(("-", "demo", ["demo", "--out", str(work / "demo.zarr")]))
    return runs


def probe(work: Path, out: Path, kinds: list[str] | None = None) -> dict[str, list[str]]:
    """Run the matrix in this process; per run, the kernels numba compiled (cache misses)."""
    from numba.core import event

    compiled: list[str] = []

    class Recorder(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            pass

        def on_end(self, ev: event.Event) -> None:
            f = ev.data["dispatcher"].py_func
            compiled.append(f"{f.__module__}.{f.__qualname__}{tuple(ev.data['args'])}")

    event.register("numba:compile", Recorder())
    from approxtree.cli import main

    report: dict[str, list[str]] = {}
    for kind, label, argv in matrix(work, kinds):
        compiled.clear()
        try:
            main(argv, standalone_mode=False)
        except SystemExit as stop:
            if stop.code:
                compiled.append(f"ERROR exit {stop.code}")
        except Exception as error:
            compiled.append(f"ERROR {error!r:.300}")
        report[f"{kind}: {label}"] = list(compiled)
        print(f"{kind}: {label}: {len(compiled)}", file=sys.stderr, flush=True)
    out.write_text(json.dumps(report, indent=1))
    return report


def _entries(cache: Path | None) -> int:
    return len(list(cache.rglob("*.nbi"))) + len(list(cache.rglob("*.nbc"))) if cache else 0


def _timed(
    cmd: list[str], argv: list[str], env: dict[str, str], cache: Path | None, cwd: Path
) -> dict:
    """One fresh process in ``cwd`` (not a source tree: ``python -m`` would import it):
    wall seconds, exit status, cache files written."""
    before = _entries(cache)
    t0 = time.perf_counter()
    if argv[0] == SERVE:
        run = _served(cmd, argv, env, cwd)
    else:
        run = subprocess.run([*cmd, *argv], env=env, cwd=cwd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    return {
        "s": round(wall, 2),
        "rc": run.returncode,
        "written": _entries(cache) - before,
        "err": run.stderr.strip().splitlines()[-1][:200] if run.returncode else "",
    }


def _served(
    cmd: list[str], argv: list[str], env: dict[str, str], cwd: Path
) -> subprocess.CompletedProcess:
    """``approxtree serve`` until its first quantized-mesh tile comes back, then SIGTERM:
    the time a user waits for the first tile (the row's seconds)."""
    import socket
    import urllib.request

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(
        [*cmd, *argv, "--port", str(port)],
        env=env,
        cwd=cwd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    url = f"http://127.0.0.1:{port}/terrain/0/0/0.terrain"
    status = 1
    deadline = time.monotonic() + 300
    # Poll until the server answers (its start-up is part of what the user waits for).
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(url, timeout=60) as response:
                response.read()
                status = 0
            break
        except OSError:
            time.sleep(0.05)
    proc.terminate()
    _, err = proc.communicate(timeout=60)
    return subprocess.CompletedProcess(argv, status, "", err if status else "")


def bench(
    cmd: list[str], work: Path, repeat: int, cold: bool, cache: Path | None, kinds: list[str] | None
) -> list[dict]:
    """First and later runs of every command of the matrix (fresh processes)."""
    rows = []
    env = dict(os.environ)
    env.pop("NUMBA_CACHE_DIR", None)
    for kind, label, argv in matrix(work, kinds):
        first_env, first_cache = env, cache
        if cold:
            first_cache = Path(tempfile.mkdtemp(prefix="cold_", dir=work))
            first_env = dict(env, APPROXTREE_KERNEL_CACHE=str(first_cache))
        first = _timed(cmd, argv, first_env, first_cache, work)
        later = [_timed(cmd, argv, first_env, first_cache, work) for _ in range(repeat)]
        row = {
            "input": kind,
            "command": label,
            "first_s": first["s"],
            "second_s": statistics.median(r["s"] for r in later) if later else None,
            "first_cache_files_written": first["written"],
            "later_cache_files_written": sum(r["written"] for r in later),
            "rc": first["rc"],
        }
        if first["err"]:
            row["error"] = first["err"]
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    return rows


def markdown(result: dict) -> str:
    """The rows as a Markdown table: input, command, first and second run, cache files."""
    lines = [
        "| input | command | first run (s) | second run (s) | cache files written (first run) |",
        "|---|---|---:|---:|---:|",
    ]
    for r in result["rows"]:
        note = f" (exit {r['rc']})" if r["rc"] else ""
        lines.append(
            f"| {r['input']} | {r['command']}{note} | {r['first_s']:.1f} | "
            f"{r['second_s']:.1f} | {r['first_cache_files_written']} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--approxtree", default=f"{sys.executable} -m approxtree")
    ap.add_argument("--cache", type=Path, help="the installed package's _kernel_cache folder")
    ap.add_argument("--cold", action="store_true", help="an empty kernel cache per command")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--probe", type=Path, help="write the kernels each command compiles")
    ap.add_argument("--work", type=Path)
    ap.add_argument("--kinds", nargs="+", help="inputs to run (default: all; '-': no input)")
    ap.add_argument("--markdown", type=Path, help="print the table of this JSON result")
    ap.add_argument("--out", type=Path, default=HERE / "first_run.json")
    opts = ap.parse_args()
    if opts.markdown:
        print(markdown(json.loads(opts.markdown.read_text())))
        return
    work = opts.work or Path(tempfile.mkdtemp(prefix="first_run_"))
    work.mkdir(parents=True, exist_ok=True)
    if opts.probe:
        probe(work, opts.probe, opts.kinds)
        return
    from approxtree.viewer.xvfb import virtual_display

    with virtual_display() as display:
        os.environ["DISPLAY"] = display
        rows = bench(
            shlex.split(opts.approxtree), work, opts.repeat, opts.cold, opts.cache, opts.kinds
        )
    result = {
        "machine": f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f} at the end",
        "mode": "cold (empty kernel cache per command)" if opts.cold else "fresh install",
        "repeat": opts.repeat,
        "rows": rows,
    }
    opts.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
