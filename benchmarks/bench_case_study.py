"""The core paper's case study at its full scale: build, bake, and the viewer flying through it.

Seed 002 §7: a 641 × 321 grid with 20,652 river-bed microstructure TINs (about 500,000
triangles), a 6144 × 12288 thematic texture blended with a topographic shading texture of the
same size, α = 4 px, γ = 2 px, a 640 × 480 window (15–20 frames per second in 1999).

The data set here:

- the grid: the NC DEM (../shared/data/nc/elev_ned_30m.tif, 30 m), its northern 321 rows,
  mirrored eastwards to 641 columns (19.2 km × 9.6 km);
- the microstructures: incised corridors (30 m wide, 15 m samples) along the NC streams where
  they reach, then along generated meandering rivers (``approxtree.datasets.river_pieces``)
  until there are 20,652 TINs;
- the textures: NC's land use (landclass96, 10 m, mirrored like the grid) as the thematic
  layer, shaded by the topographic shading (``--blend shade``), baked at a texel of
  19,200 m / 12,288 = 1.5625 m: level 0 is 12288 × 6144, cut into texture patches of at most
  4096² (the paper's 6144 × 12288 texture, here one pyramid).

The flight (one scripted replay, ``view --script``): an overview, a low oblique flight along the
longest NC stream, then camera cuts to oblique views from all around. It runs in a real window
under Xvfb (llvmpipe on a machine without a GPU; the GPU's driver where there is one) at
640 × 480 and 1920 × 1080, one fresh viewer process per size. Frame time is the wall time of
the whole frame (events, selection, uploads, draw, swap); the first frame (kernels loaded,
first uploads) is reported apart.

Reported: build and bake seconds and peak memory (each in a fresh process, peak RSS), tree
nodes and triangles, the pyramid's bytes, the viewer's peak RSS and the GPU bytes it holds
(meshes and textures), triangles drawn, frame times (median, p95) and frames with stand-ins.

    python benchmarks/bench_case_study.py [--work DIR] [--sizes 640x480 1920x1080]
        [--flight-frames 120] [--cuts 8] [--hold 10] [--texture-width 12288] [--quick]

``--quick``: a quarter of the microstructures and a 3072 × 1536 texture (a smoke test).
``--reuse-build``: keep the tree and land use of an earlier run in ``--work`` (its
build.json), re-bake and fly only; ``--reuse-bake`` with it: keep the baked textures too (their
bake.json), fly only. Writes benchmarks/results/case_study.json, with the load
average before each phase (1-minute figure: other processes share the cores) and the OpenGL
renderer the viewer got. On a GPU machine run it as it is where a display is set (an X server
on the GPU); without one it opens Xvfb, whose renderer is llvmpipe whatever the machine: the
JSON's ``renderer`` says which one drew.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
DATA = Path(os.environ.get("APPROXTREE_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
ROWS, COLS, MICROSTRUCTURES = 321, 641, 20_652
TEXTURE_WIDTH = 12_288
ALPHA, GAMMA = 4.0, 2.0


def _mirrored(a: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """The first ``rows`` rows of ``a``, mirrored eastwards to ``cols`` columns."""
    a = a[:rows]
    return np.pad(a, ((0, 0), (0, cols - a.shape[1])), mode="reflect")


def make_dataset(work: Path, quick: bool) -> dict:
    """Build the case study's tree into work/case.zarr, the thematic raster into
    work/landuse.tif; return the build's figures."""
    import rasterio
    import shapely

    import approxtree as at
    from approxtree.datasets import river_pieces
    from approxtree.io.microstructures import corridor_microstructures, read_lines

    nc = at.open_terrain(DATA / "nc" / "elev_ned_30m.tif")
    grid = at.Grid(_mirrored(np.asarray(nc.heights), ROWS, COLS), nc.transform, crs=nc.crs)
    d = grid.domain
    inner = shapely.box(d.xmin, d.ymin, d.xmax, d.ymax).buffer(-30.0)
    # The NC streams where they reach (clipped to the grid), then generated rivers to the
    # paper's count; one corridor call, so crossing corridors are resolved together.
    streams = shapely.get_parts(
        shapely.intersection(read_lines(DATA / "nc" / "streams.shp", grid.crs), inner)
    )
    streams = streams[~shapely.is_empty(streams) & (shapely.length(streams) > 30.0)]
    wanted = MICROSTRUCTURES // 4 if quick else MICROSTRUCTURES
    spare = math.ceil(wanted * 1.06) - len(streams)
    lines = np.concatenate([streams, river_pieces(grid, max(spare, 0), seed=0)])
    t0 = time.perf_counter()
    tins = corridor_microstructures(grid, lines, width=30.0, spacing=15.0)[:wanted]
    corridor_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    tree = at.ApproximationTree.build(grid, epsilon=1.0, microstructures=tins, progress=False)
    build_s = time.perf_counter() - t0
    tree.save(work / "case.zarr")
    # The thematic layer: NC's land use mirrored like the grid (10 m: 3 × the grid's cells).
    with rasterio.open(DATA / "nc" / "landuse_r.tif") as src:
        classes = _mirrored(src.read(1), 3 * ROWS, 3 * COLS)
        profile = src.profile | {"width": classes.shape[1], "height": classes.shape[0]}
        colormap = src.colormap(1)
    with rasterio.open(work / "landuse.tif", "w", **profile) as dst:
        dst.write(classes, 1)
        dst.write_colormap(1, colormap)
    return {
        "grid": [ROWS, COLS],
        "microstructures": len(tins),
        "from_nc_streams": int(min(len(streams), len(tins))),
        "microstructure_triangles": int(sum(len(t.triangles) for t in tins)),
        "corridor_seconds": round(corridor_s, 2),
        "build_seconds": round(build_s, 2),
        "nodes": len(tree),
        "strategies": tree.strategy_counts,
        "max_leaf_error": float(tree.errors[tree.leaves].max()),
        "longest_stream": _longest(streams),
    }


def _longest(lines: np.ndarray) -> list[list[float]]:
    """(n, 2) points of the longest line, as lists (the flight follows it)."""
    import shapely

    line = lines[int(np.argmax(shapely.length(lines)))]
    return np.asarray(shapely.get_coordinates(line)).tolist()


def _load() -> float:
    """The 1-minute load average (other processes on the same cores)."""
    return round(os.getloadavg()[0], 2)


#: Prints the GL_RENDERER of a context made like the viewer's window (GLX on $DISPLAY).
_RENDERER = (
    "import moderngl; ctx = moderngl.create_standalone_context(); "
    "print(ctx.info['GL_RENDERER'], '|', ctx.info['GL_VERSION'])"
)


def renderer(display: str | None) -> str:
    """The OpenGL renderer and version a window on ``display`` (None: $DISPLAY) gets."""
    env = dict(os.environ) if display is None else dict(os.environ, DISPLAY=display)
    done = subprocess.run(
        [sys.executable, "-c", _RENDERER], env=env, capture_output=True, text=True, check=False
    )
    return done.stdout.strip() or f"unknown ({done.stderr.strip().splitlines()[-1:]})"


def _child(code: str, *args: str) -> dict:
    """The JSON a fresh process printed last (its code adds its own peak RSS)."""
    out = subprocess.run(
        [sys.executable, "-c", code, *args], check=True, capture_output=True, text=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


#: Runs argv[1:] as its only child and prints that child's peak RSS (kB on Linux).
_PEAK = (
    "import resource, subprocess, sys; subprocess.run(sys.argv[1:], check=True, "
    "capture_output=True); print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)"
)
_RSS = "import resource; rss = 1024 * resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"


_BUILD = (
    """
import json, sys
from pathlib import Path
sys.path.insert(0, sys.argv[2])
import bench_case_study as b
figures = b.make_dataset(Path(sys.argv[1]), sys.argv[3] == "1")
"""
    + _RSS
    + """print(json.dumps(dict(figures, peak_rss_bytes=rss)))
"""
)

_BAKE = (
    """
import json, sys, time
import approxtree as at
from approxtree.textures.bake import bake
tree = at.ApproximationTree.load(sys.argv[1] + "/case.zarr")
t0 = time.perf_counter()
result = bake(tree.terrain, sys.argv[1] + "/textures", thematic=sys.argv[1] + "/landuse.tif",
              palette="landclass96", texel_size=float(sys.argv[2]), max_texture_size=4096,
              gl=False)
seconds = time.perf_counter() - t0
"""
    + _RSS
    + """print(json.dumps(dict(result.figures(), seconds=seconds, peak_rss_bytes=rss)))
"""
)


def flight(tree_box: np.ndarray, river: list[list[float]], frames: int, cuts: int, hold: int):
    """Keyframes: an overview from the south, a low oblique flight along ``river``, then
    ``cuts`` camera cuts to oblique views from all around (each held ``hold`` frames)."""
    lo, hi = tree_box[:3], tree_box[3:]
    centre = 0.5 * (lo + hi)
    diag = float(np.linalg.norm(hi[:2] - lo[:2]))
    path = [
        {
            "eye": [float(centre[0]), float(lo[1] - 0.45 * diag), float(hi[2] + 0.35 * diag)],
            "target": [float(centre[0]), float(centre[1]), float(lo[2])],
            "frames": 1,
        }
    ]
    # Along the river: 8 keyframes, 300 m above the terrain's top, looking 1.5 km ahead.
    pts = np.asarray(river)
    steps = np.linspace(0, len(pts) - 1, 9).astype(int)
    for k, i in enumerate(steps[:-1]):
        ahead = pts[min(steps[k + 1], len(pts) - 1)]
        here = pts[i]
        heading = (ahead - here) / max(float(np.linalg.norm(ahead - here)), 1e-9)
        target = here + 1500.0 * heading
        path.append(
            {
                "eye": [float(here[0]), float(here[1]), float(hi[2] + 300.0)],
                "target": [float(target[0]), float(target[1]), float(lo[2])],
                "frames": frames // 8,
            }
        )
    for k in range(cuts):
        angle = 2.0 * math.pi * (0.37 * k) - math.pi / 2
        reach = 0.7 - 0.2 * (k % 3)
        way = np.array([math.cos(angle), math.sin(angle)])
        eye, look = centre[:2] + reach * diag * way, centre[:2] + 0.15 * diag * way
        view = {
            "eye": [float(eye[0]), float(eye[1]), float(hi[2] + diag / 10.0)],
            "target": [float(look[0]), float(look[1]), float(lo[2])],
        }
        path.append({**view, "frames": 1})
        path.append({**view, "frames": hold - 1})
    return path


def fly(work: Path, script: Path, size: str, display: str | None) -> dict:
    """Replay ``script`` in a fresh viewer process at ``size``; figures of its stats lines."""
    stats = work / f"stats_{size}.jsonl"
    cmd = [
        sys.executable, "-m", "approxtree", "view", str(work / "case.zarr"),
        "--textures", str(work / "textures"), "--script", str(script), "--stats", str(stats),
        "--size", size, "--alpha", str(ALPHA), "--gamma", str(GAMMA), "--legend", "landclass96",
    ]  # fmt: skip
    env = dict(os.environ) if display is None else dict(os.environ, DISPLAY=display)
    load = _load()
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", _PEAK, *cmd], env=env, check=True, capture_output=True, text=True
    )
    wall = time.perf_counter() - t0
    peak_kb = int(done.stdout.strip().splitlines()[-1])
    lines = [json.loads(s) for s in stats.read_text().splitlines()]
    ms = [s["frame_ms"] for s in lines]
    rest = ms[1:]
    return {
        "size": size,
        "frames": len(ms),
        "fps_median": round(1e3 / statistics.median(rest), 1),
        "frame_ms_median": round(statistics.median(rest), 2),
        "frame_ms_p95": round(float(np.percentile(rest, 95)), 2),
        "frame_ms_max": round(max(rest), 2),
        "first_frame_ms": round(ms[0], 2),
        "select_ms_median": round(statistics.median(s["select_ms"] for s in lines[1:]), 2),
        "draw_ms_median": round(statistics.median(s["draw_ms"] for s in lines[1:]), 2),
        "triangles_median": int(statistics.median(s["triangles"] for s in lines)),
        "triangles_max": int(max(s["triangles"] for s in lines)),
        "texture_patches_max": int(max(s.get("texture_patches", 0) for s in lines)),
        "gpu_bytes_max": int(max(s["gpu_bytes"] for s in lines)),
        "frames_with_stand_ins": sum(1 for s in lines if s["pending"] > 0),
        "max_alpha_max": max(s["max_alpha"] for s in lines),
        "max_gamma_max": max(s["max_gamma"] for s in lines),
        "viewer_peak_rss_bytes": 1024 * peak_kb,
        "process_seconds": round(wall, 2),
        "load_before": load,
        "load_after": _load(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=RESULTS / "case_study")
    ap.add_argument("--sizes", nargs="+", default=["640x480", "1920x1080"])
    ap.add_argument("--flight-frames", type=int, default=120)
    ap.add_argument("--cuts", type=int, default=8)
    ap.add_argument("--hold", type=int, default=10)
    ap.add_argument(
        "--texture-width", type=int, default=TEXTURE_WIDTH, help="level 0's texels west-east"
    )
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--reuse-build", action="store_true", help="keep --work's tree and land use (build.json)"
    )
    ap.add_argument(
        "--reuse-bake",
        action="store_true",
        help="with --reuse-build: keep --work's textures too (bake.json), fly only",
    )
    args = ap.parse_args()
    if not (DATA / "nc" / "elev_ned_30m.tif").exists():
        sys.exit(f"the NC data is absent under {DATA}: set APPROXTREE_DATA")
    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    reuse = args.reuse_build and (work / "build.json").exists()
    keep_bake = reuse and args.reuse_bake and (work / "bake.json").exists()
    stale_paths = ("case.zarr", "textures", "build.json", "bake.json")
    for stale in () if keep_bake else ("textures", "bake.json") if reuse else stale_paths:
        if (work / stale).exists():
            import shutil

            shutil.rmtree(work / stale)
    here = str(Path(__file__).resolve().parent)
    loads = {"build": _load()}
    if reuse:
        built = json.loads((work / "build.json").read_text())
    else:
        built = _child(_BUILD, str(work), here, "1" if args.quick else "0")
        (work / "build.json").write_text(json.dumps(built))
    river = built.pop("longest_stream")
    print("build", json.dumps(built), flush=True)
    width = args.texture_width // 4 if args.quick else args.texture_width
    texel = (COLS - 1) * 30.0 / (width - 1)
    loads["bake"] = _load()
    if keep_bake:
        baked = json.loads((work / "bake.json").read_text())
    else:
        baked = _child(_BAKE, str(work), repr(texel))
        (work / "bake.json").write_text(json.dumps(baked))
    print("bake", json.dumps(baked), flush=True)

    import approxtree as at

    tree = at.ApproximationTree.load(work / "case.zarr")
    script = work / "flight.json"
    path = flight(
        np.asarray(tree.bboxes[0], dtype=np.float64),
        river,
        args.flight_frames,
        args.cuts,
        args.hold,
    )
    script.write_text(json.dumps(path, indent=1))
    runs = []
    if os.environ.get("DISPLAY"):
        drawn_by = renderer(None)
        runs = [fly(work, script, size, None) for size in args.sizes]
    else:
        from approxtree.viewer.xvfb import virtual_display

        with virtual_display() as display:
            drawn_by = renderer(display)
            runs = [fly(work, script, size, display) for size in args.sizes]
    print("renderer", drawn_by, flush=True)
    for r in runs:
        print("view", json.dumps(r), flush=True)
    out = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "renderer": drawn_by,
        "load_before": loads,
        "build_reused": reuse,
        "bake_reused": keep_bake,
        "quick": args.quick,
        "alpha": ALPHA,
        "gamma": GAMMA,
        "build": built,
        "bake": dict(baked, texel=texel),
        "flight": {"keyframes": len(path), "frames": sum(k["frames"] for k in path)},
        "runs": runs,
    }
    RESULTS.mkdir(exist_ok=True)
    name = "case_study_quick.json" if args.quick else "case_study.json"
    (RESULTS / name).write_text(json.dumps(out, indent=2))
    plot_flights(work, args.sizes, (RESULTS / name).with_suffix(".png"))
    print(f"wrote {RESULTS / name} and its .png")


def plot_flights(work: Path, sizes: list[str], path: Path) -> None:
    """Frame time per frame of each window size's flight (its stats_<size>.jsonl in
    ``work``), the frames drawing a stand-in marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4))
    for size in sizes:
        rows = [json.loads(line) for line in (work / f"stats_{size}.jsonl").open()]
        ms = np.array([r.get("frame_ms") or 0.0 for r in rows])
        line = ax.plot(ms, lw=0.8, label=f"{size}: median {np.median(ms):.1f} ms")
        marks = np.flatnonzero([bool(r.get("stand_ins")) for r in rows])
        ax.plot(marks, ms[marks], ".", ms=3, color=line[0].get_color())
    ax.set_yscale("log")
    ax.set_xlabel("frame (dots: a stand-in drawn)")
    ax.set_ylabel("ms per frame")
    ax.set_title("case study flight (bench_case_study.py)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
