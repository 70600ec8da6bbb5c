"""Paging renderer over a fly-over: frame time, stand-ins and RSS with caches of a given size.

A tree (``--tree PATH``, or one built from a seeded fractal of ``--dem-size``² at ε = 1 m and
saved, so patches are read from the store on demand) is flown over along a loop of ``--frames``
frames at ``--size``: the eye circles the domain centre at 0.35 of its width, 1/15 of the
diagonal above the highest point, looking ahead and down. Each frame is one interactive
``Engine.render(..., paging=Paging(wait=False))`` on headless EGL (Mesa llvmpipe on a CPU-only
machine) with CPU and GPU caches of ``--cache-mb`` each and at most ``--max-uploads`` uploads
per frame: the provider loads in the background, stand-ins are drawn meanwhile. Per frame:
wall time of the render call, whether it drew a stand-in, the process RSS (sampled after the
frame). Each
cache size given runs in its own process (peers side by side: RSS must follow the caches, not
the terrain seen).

    python benchmarks/bench_paging.py [--tree PATH] [--frames 600] [--size 1280x720]
        [--alpha 1] [--cache-mb 512] [--peer-cache-mb 64] [--dem-size 2049] [--max-uploads 32]
        [--out benchmarks/results/paging.json]

With ``--baseline-lib`` (an earlier checkout) the loop runs that checkout, this one with
``Paging``'s defaults and this one with the viewer's paging (``--lookahead``,
``--frame-margin-ms``) in interleaved processes, ``--rounds`` rounds, one cache size; per run
also the share of frames drawing a mesh stand-in (and any, normal patches included), the
frame times and the load average; JSON and a plot:

    python benchmarks/bench_paging.py --tree fractal_32768.zarr --frames 600 --cache-mb 512 \
        --baseline-lib /tmp/before --rounds 2 --out benchmarks/results/paging_32768.json

``--scenario flyover`` (issue 26, item 3): a low fly-over of ``--tree`` textured by
``--textures`` (a baked hillshade) at α ``--alpha``, γ ``--gamma``, in four straight legs with a
camera cut between them (``flyover_cameras``), against ``--baseline-lib`` (a checkout of main,
paging as main did) in interleaved processes, ``--rounds`` rounds. Per run: frame time median
and p95, the share of frames drawing a mesh stand-in (and any stand-in, texture patches
included), the frames each cut takes to settle, the load average. JSON and a plot:

    python benchmarks/bench_paging.py --scenario flyover --tree f4097.zarr \
        --textures f4097_textures --frames 400 --size 640x480 --alpha 4 --gamma 2 \
        --baseline-lib /tmp/main --rounds 3 --out benchmarks/results/paging_flyover.json
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

RESULTS = Path(__file__).resolve().parent / "results"
#: Per-frame series and provider figures of a loop run: in the JSON, not on the console.
SERIES = ("frame_ms", "frame_cpu_ms", "stand_in_frames", "mesh_stand_in_frames", "provider")


def loop_cameras(tree, frames: int, scale) -> list:
    """Cameras of a loop over the domain (see the module docstring)."""
    from approxtree.render import Camera

    b = np.asarray(tree.bboxes[0], dtype=np.float64)
    lo, hi = b[:3], b[3:]
    centre = 0.5 * (lo[:2] + hi[:2])
    width = float(min(hi[:2] - lo[:2]))
    diag = float(np.linalg.norm(hi[:2] - lo[:2]))
    height = hi[2] + diag / 15.0
    cams = []
    for k in range(frames):
        t = 2.0 * math.pi * k / frames
        eye = (*(centre + 0.35 * width * np.array([math.cos(t), math.sin(t)])), height)
        ahead = t + 0.6
        look = (*(centre + 0.2 * width * np.array([math.cos(ahead), math.sin(ahead)])), lo[2])
        cams.append(Camera.look_at(eye, look, fov=60))
    return cams


def flyover_cameras(tree, frames: int, legs: int = 4) -> tuple[list, list[int]]:
    """Cameras of a low fly-over in ``legs`` straight legs with a camera cut between them,
    and the frames that follow a cut.

    Each leg crosses 0.4 of the domain width at 0.03 of it above the highest point, looking
    ahead and 20° down; the legs start at different corners and head in different directions,
    so a cut lands on a view that shares nothing with the one before it.
    """
    from approxtree.render import Camera

    b = np.asarray(tree.bboxes[0], dtype=np.float64)
    lo, hi = b[:3], b[3:]
    centre = 0.5 * (lo[:2] + hi[:2])
    width = float(min(hi[:2] - lo[:2]))
    height = hi[2] + 0.03 * width
    per_leg = max(1, frames // legs)
    cams, cuts = [], []
    for k in range(frames):
        leg, step = divmod(k, per_leg)
        leg %= legs
        if step == 0 and k > 0:
            cuts.append(k)
        heading = math.pi / 4 + leg * (math.pi / 2 + 0.3)
        direction = np.array([math.cos(heading), math.sin(heading)])
        start = (
            centre - 0.2 * width * direction + 0.1 * width * np.array([-direction[1], direction[0]])
        )
        eye2 = start + 0.4 * width * direction * step / per_leg
        look = eye2 + width * 0.1 * direction
        drop = 0.1 * width * math.tan(math.radians(20))
        cams.append(Camera.look_at((*eye2, height), (*look, height - drop), fov=60))
    return cams, cuts


def rss_parts() -> tuple[int, int]:
    """(anonymous, file-backed) resident bytes of this process (Linux /proc; file-backed
    pages are mapped files such as a memory-mapped tree store: the kernel reclaims them)."""
    parts = {"RssAnon:": 0, "RssFile:": 0}
    with open("/proc/self/status") as f:
        for line in f:
            key = line.split(maxsplit=1)[0]
            if key in parts:
                parts[key] = int(line.split()[1]) * 1024
    return parts["RssAnon:"], parts["RssFile:"]


def run_one(args: argparse.Namespace) -> dict:
    """One fly-over in this process; returns its figures."""
    from approxtree import load_tree
    from approxtree.render import Cut, Engine

    proc = psutil.Process()
    rss0 = proc.memory_info().rss
    tree = load_tree(args.tree)
    w, h = (int(v) for v in args.size.lower().split("x"))
    cache = int(args.cache_mb * (1 << 20))
    paging = _paging(args)
    rows = []
    with Engine(tree, cache_bytes=cache, cpu_cache_bytes=cache) as eng:
        cams = loop_cameras(tree, args.frames, eng.scale)
        rss_open = proc.memory_info().rss
        for cam in cams:
            t0, c0 = time.perf_counter(), time.process_time()
            frame = eng.render(cam, (w, h), Cut(args.alpha, math.inf), paging=paging)
            ms = (time.perf_counter() - t0) * 1e3
            rows.append(
                {
                    "ms": ms,
                    # CPU time of the whole process (llvmpipe's and the loaders' threads too):
                    # the frame's work, less at the mercy of other jobs than its wall time.
                    "cpu_ms": (time.process_time() - c0) * 1e3,
                    "stand_ins": frame.stats["stand_ins"],
                    # Normal patches (a grid over the normal map's side) stood in for.
                    "texture_stand_ins": frame.stats.get("texture_stand_ins", 0),
                    "pending": frame.stats["pending"],
                    "patches": frame.stats["patches"],
                    "triangles": frame.stats["triangles"],
                    "gpu_bytes": frame.stats["gpu_bytes"],
                    "cpu_bytes": frame.stats["cpu_bytes"],
                    "rss": proc.memory_info().rss,
                    "rss_anon": rss_parts()[0],
                    "rss_file": rss_parts()[1],
                }
            )
        provider = eng.provider.figures()
    ms = np.array([r["ms"] for r in rows])
    rss = np.array([r["rss"] for r in rows]) / 2**20
    anon = np.array([r["rss_anon"] for r in rows]) / 2**20
    file_backed = np.array([r["rss_file"] for r in rows]) / 2**20
    warm = max(1, len(rows) // 10)
    mb = 1 << 20
    cpu_ms = np.array([r["cpu_ms"] for r in rows])
    mesh = np.array([r["stand_ins"] > 0 for r in rows])
    drew = mesh | np.array([r["texture_stand_ins"] > 0 for r in rows])
    # The flight starts with empty caches: the frames until the first without a stand-in
    # fill them (a cold start), the others show whether loads keep up with the motion.
    clear = np.flatnonzero(~drew)
    cold = int(clear[0]) if len(clear) else len(rows)
    return {
        "cache_mb": args.cache_mb,
        "paging": repr(paging),
        "frames": len(rows),
        "frame_ms_median": round(float(np.median(ms)), 2),
        "frame_ms_p95": round(float(np.percentile(ms, 95)), 2),
        "frame_cpu_ms_median": round(float(np.median(cpu_ms)), 2),
        "frame_cpu_ms_p95": round(float(np.percentile(cpu_ms, 95)), 2),
        "cold_start_frames": cold,
        "stand_in_frames_after_cold_start": int(drew[cold:].sum()),
        "frames_with_stand_ins": int(mesh.sum()),
        # Any stand-in: a mesh, or a normal patch (texture) not loaded yet.
        "frames_with_any_stand_in": int(drew.sum()),
        "mesh_stand_in_share": round(float(mesh.mean()), 4),
        "stand_in_share": round(float(drew.mean()), 4),
        "frames_pending": int(sum(r["pending"] > 0 for r in rows)),
        "stand_ins_median": float(np.median([r["stand_ins"] for r in rows])),
        "pending_median": float(np.median([r["pending"] for r in rows])),
        "patches_median": int(np.median([r["patches"] for r in rows])),
        "triangles_median": int(np.median([r["triangles"] for r in rows])),
        "gpu_mb_max": round(max(r["gpu_bytes"] for r in rows) / mb, 1),
        "cpu_mb_max": round(max(r["cpu_bytes"] for r in rows) / mb, 1),
        "rss_mb_before_tree": round(rss0 / mb, 1),
        "rss_mb_engine_open": round(rss_open / mb, 1),
        "rss_mb_peak": round(float(rss.max()), 1),
        # Flat after warm-up: the peak of the first tenth against the peak of the rest.
        "rss_mb_peak_warmup": round(float(rss[:warm].max()), 1),
        "rss_mb_peak_after_warmup": round(float(rss[warm:].max()), 1) if len(rss) > warm else None,
        "rss_mb_by_decile": _deciles(rss),
        # RSS split: anonymous memory (caches, arrays, driver buffers) and mapped files.
        "rss_anon_mb_peak_warmup": round(float(anon[:warm].max()), 1),
        "rss_anon_mb_peak_after_warmup": round(float(anon[warm:].max()), 1)
        if len(anon) > warm
        else None,
        "rss_anon_mb_by_decile": _deciles(anon),
        "rss_file_mb_by_decile": _deciles(file_backed),
        # Cache fill: RSS must follow it, then stay flat.
        "caches_mb_by_decile": _deciles(
            np.array([r["cpu_bytes"] + r["gpu_bytes"] for r in rows]) / mb
        ),
        "frame_ms": [round(float(v), 2) for v in ms],
        "frame_cpu_ms": [round(float(v), 2) for v in cpu_ms],
        "stand_in_frames": [int(v) for v in drew],
        "mesh_stand_in_frames": [int(v) for v in mesh],
        "provider": provider,
        "loadavg": list(os_loadavg()),
    }


def _paging(args: argparse.Namespace):
    """The Paging of a loop run: ``--plain``, the library's defaults with ``--max-uploads``
    (as the loop always ran); otherwise also ``--lookahead`` and ``--frame-margin-ms`` (the
    viewer's settings) where the library has them."""
    import dataclasses

    from approxtree.render import Paging

    fields = {f.name for f in dataclasses.fields(Paging)}
    extra = {}
    if not args.plain and "lookahead" in fields:
        extra = {"lookahead": args.lookahead, "frame_margin_ms": args.frame_margin_ms}
    return Paging(False, args.max_uploads, **extra)


def run_flyover(args: argparse.Namespace) -> dict:
    """The low fly-over with camera cuts (``flyover_cameras``) in this process, textured by
    ``--textures`` at α ``--alpha`` and γ ``--gamma``; returns its figures.

    A frame "settles" after a cut at the first frame drawing no stand-in (mesh or texture).
    ``--plain`` pages as main did (only ``max_uploads``); otherwise the Paging fields of this
    branch (lookahead, siblings, frame-time budget) are used where the library has them.
    """
    import dataclasses

    from approxtree import load_tree
    from approxtree.render import Cut, Engine, Paging

    tree = load_tree(args.tree)
    w, h = (int(v) for v in args.size.lower().split("x"))
    cache = int(args.cache_mb * (1 << 20))
    fields = {f.name for f in dataclasses.fields(Paging)}
    extra = {}
    if not args.plain and "lookahead" in fields:
        extra = {"lookahead": args.lookahead, "frame_margin_ms": args.frame_margin_ms}
    paging = Paging(False, args.max_uploads, **extra)
    pyramid = args.textures  # a pyramid folder, or None: untextured
    rows = []
    with Engine(tree, pyramid, cache_bytes=cache, cpu_cache_bytes=cache) as eng:
        cams, cuts = flyover_cameras(tree, args.frames)
        cut = Cut(args.alpha, args.gamma)
        eng.render(cams[0], (w, h), cut)  # the first view loaded: frame 0 starts settled
        for cam in cams:
            t0 = time.perf_counter()
            frame = eng.render(cam, (w, h), cut, paging=paging)
            ms = (time.perf_counter() - t0) * 1e3
            st = frame.stats
            rows.append(
                {
                    "ms": ms,
                    "stand_ins": st["stand_ins"],
                    "texture_stand_ins": st.get("texture_stand_ins", 0),
                    "uploads": st.get("gpu_uploads", 0),
                    "triangles": st["triangles"],
                }
            )
        provider = eng.provider.figures()
    ms = np.array([r["ms"] for r in rows])
    drew = np.array([r["stand_ins"] > 0 or r["texture_stand_ins"] > 0 for r in rows])
    mesh = np.array([r["stand_ins"] > 0 for r in rows])
    settle, settle_mesh = [], []
    for c in cuts:
        after = np.flatnonzero(~drew[c:])
        settle.append(int(after[0]) if len(after) else len(rows) - c)
        after = np.flatnonzero(~mesh[c:])
        settle_mesh.append(int(after[0]) if len(after) else len(rows) - c)
    between = np.ones(len(rows), dtype=bool)
    for c in cuts:
        between[c : c + 10] = False
    return {
        "variant": "plain" if args.plain or not extra else "prefetch",
        "paging": {"max_uploads": args.max_uploads, **extra},
        "frames": len(rows),
        "frame_ms_median": round(float(np.median(ms)), 2),
        "frame_ms_p95": round(float(np.percentile(ms, 95)), 2),
        "stand_in_share": round(float(drew.mean()), 4),
        "mesh_stand_in_share": round(float(mesh.mean()), 4),
        "stand_in_share_outside_cuts": round(float(drew[between].mean()), 4),
        "mesh_stand_in_share_outside_cuts": round(float(mesh[between].mean()), 4),
        "settle_frames_after_cuts": settle,
        "mesh_settle_frames_after_cuts": settle_mesh,
        "uploads_median": float(np.median([r["uploads"] for r in rows])),
        "triangles_median": int(np.median([r["triangles"] for r in rows])),
        "frame_ms": [round(float(v), 2) for v in ms],
        "stand_in_frames": [int(v) for v in drew],
        "provider": provider,
        "loadavg": list(os_loadavg()),
    }


def os_loadavg() -> tuple[float, float, float]:
    import os

    return os.getloadavg()


def _deciles(values: np.ndarray) -> list[float]:
    """values at frames 0, 10 %, ..., 100 % of the run."""
    n = len(values)
    return [round(float(values[min(n - 1, k * n // 10)]), 1) for k in range(11)]


def build_tree(size: int, folder: Path) -> Path:
    """A fractal of size² at ε = 1 m, saved to ``folder``; returns its path."""
    from approxtree import ApproximationTree
    from approxtree.datasets import fractal_terrain

    terrain = fractal_terrain(size, seed=7, relief=1000.0)
    tree = ApproximationTree.build(terrain, epsilon=1.0, progress=False)
    path = folder / f"fractal_{size}.zarr"
    tree.save(path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", help="tree store (default: build a fractal)")
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--alpha", type=float, default=1.0)
    parser.add_argument("--cache-mb", type=float, default=512.0)
    parser.add_argument("--peer-cache-mb", type=float, action="append", default=None)
    parser.add_argument("--dem-size", type=int, default=2049)
    parser.add_argument("--max-uploads", type=int, default=32)
    parser.add_argument("--out", default=str(RESULTS / "paging.json"))
    parser.add_argument("--scenario", choices=["loop", "flyover"], default="loop")
    parser.add_argument("--textures", help="flyover: texture pyramid folder (a baked hillshade)")
    parser.add_argument("--gamma", type=float, default=math.inf)
    parser.add_argument("--lookahead", type=int, default=4)
    parser.add_argument("--frame-margin-ms", type=float, default=4.0)
    parser.add_argument("--plain", action="store_true", help="page with Paging's defaults")
    parser.add_argument("--baseline-lib", help="an earlier checkout, run interleaved")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        run = run_flyover if args.scenario == "flyover" else run_one
        print(json.dumps(run(args)))
        return
    if args.scenario == "flyover":
        flyover_main(args)
        return
    if args.baseline_lib:
        loop_compare_main(args)
        return
    with tempfile.TemporaryDirectory() as tmp:
        built = None
        if args.tree is None:
            t0 = time.perf_counter()
            args.tree = str(build_tree(args.dem_size, Path(tmp)))
            built = {"dem_size": args.dem_size, "build_and_save_s": time.perf_counter() - t0}
        peers = args.peer_cache_mb if args.peer_cache_mb is not None else [args.cache_mb / 8]
        runs = []
        for cache_mb in [args.cache_mb, *peers]:
            cmd = [
                *(sys.executable, __file__, "--one", "--tree", args.tree),
                *("--frames", str(args.frames), "--size", args.size, "--alpha", str(args.alpha)),
                *("--cache-mb", str(cache_mb), "--max-uploads", str(args.max_uploads)),
                "--plain",  # Paging's defaults and --max-uploads, as this comparison always ran
            ]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            runs.append(json.loads(out.strip().splitlines()[-1]))
            print(json.dumps({k: v for k, v in runs[-1].items() if k not in SERIES}), flush=True)
        tree_bytes = (
            sum(p.stat().st_size for p in Path(args.tree).rglob("*"))
            if Path(args.tree).is_dir()
            else Path(args.tree).stat().st_size
        )
    result = {
        "tree": args.tree if built is None else f"(built) fractal {args.dem_size}²",
        "tree_bytes": tree_bytes,
        "built": built,
        "frames": args.frames,
        "size": args.size,
        "alpha": args.alpha,
        "max_uploads": args.max_uploads,
        "machine": {"platform": platform.platform(), "cpus": psutil.cpu_count()},
        "runs": runs,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")


def loop_compare_main(args: argparse.Namespace) -> None:
    """The loop with ``--cache-mb`` caches: ``--baseline-lib`` (an earlier checkout) against
    this checkout with the library's default Paging and with the viewer's (``--lookahead``,
    ``--frame-margin-ms``), interleaved, ``--rounds`` rounds, each run in its own process;
    JSON and a plot into ``--out``."""
    import os

    if args.tree is None:
        raise SystemExit("--baseline-lib with the loop needs --tree (build it once)")
    here = str(Path(__file__).resolve().parent.parent)
    variants = [
        ("before", str(Path(args.baseline_lib).resolve()), ["--plain"]),
        ("default", here, ["--plain"]),
        ("viewer", here, []),
    ]
    runs = []
    for r in range(args.rounds):
        for name, lib, flags in variants:
            cmd = [
                *(sys.executable, __file__, "--one", "--tree", args.tree),
                *("--frames", str(args.frames), "--size", args.size, "--alpha", str(args.alpha)),
                *("--cache-mb", str(args.cache_mb), "--max-uploads", str(args.max_uploads)),
                *("--lookahead", str(args.lookahead)),
                *("--frame-margin-ms", str(args.frame_margin_ms), *flags),
            ]
            env = {**os.environ, "PYTHONPATH": lib}
            out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout
            run = json.loads(out.strip().splitlines()[-1]) | {"name": name, "round": r}
            runs.append(run)
            skip = (*SERIES, *(k for k in run if k.endswith("_by_decile")))
            print(json.dumps({k: v for k, v in run.items() if k not in skip}), flush=True)
    result = {
        "scenario": "loop",
        "tree": args.tree,
        "frames": args.frames,
        "size": args.size,
        "alpha": args.alpha,
        "gamma": "off",
        "max_uploads": args.max_uploads,
        "machine": {"platform": platform.platform(), "cpus": psutil.cpu_count()},
        "runs": runs,
    }
    out_path = Path(args.out)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(result, indent=1))
    plot_flyover(result, out_path.with_suffix(".png"))
    print(f"wrote {out_path}")


def flyover_main(args: argparse.Namespace) -> None:
    """The fly-over, this checkout against ``--baseline-lib`` (main) interleaved, ``--rounds``
    rounds, each run in its own process; JSON and a plot into ``--out``."""
    import os

    if args.tree is None:
        raise SystemExit("--scenario flyover needs --tree (see the module docstring)")
    here = str(Path(__file__).resolve().parent.parent)
    variants = [("prefetch", here, [])]
    if args.baseline_lib:
        variants.insert(0, ("main", str(Path(args.baseline_lib).resolve()), ["--plain"]))
    runs = []
    for r in range(args.rounds):
        for name, lib, flags in variants:
            cmd = [
                *(sys.executable, __file__, "--one", "--scenario", "flyover", "--tree", args.tree),
                *("--frames", str(args.frames), "--size", args.size, "--alpha", str(args.alpha)),
                *("--gamma", str(args.gamma), "--cache-mb", str(args.cache_mb)),
                *("--max-uploads", str(args.max_uploads), "--lookahead", str(args.lookahead)),
                *("--frame-margin-ms", str(args.frame_margin_ms), *flags),
                *(("--textures", args.textures) if args.textures else ()),
            ]
            env = {**os.environ, "PYTHONPATH": lib}
            out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout
            run = json.loads(out.strip().splitlines()[-1]) | {"name": name, "round": r}
            runs.append(run)
            short = {k: v for k, v in run.items() if k not in ("frame_ms", "stand_in_frames")}
            print(json.dumps({k: v for k, v in short.items() if k != "provider"}), flush=True)
    result = {
        "scenario": "flyover",
        "tree": args.tree,
        "textures": args.textures,
        "frames": args.frames,
        "size": args.size,
        "alpha": args.alpha,
        "gamma": args.gamma,
        "machine": {"platform": platform.platform(), "cpus": psutil.cpu_count()},
        "runs": runs,
    }
    out_path = Path(args.out)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(result, indent=1))
    plot_flyover(result, out_path.with_suffix(".png"))
    print(f"wrote {out_path}")


def plot_flyover(result: dict, path: Path) -> None:
    """Frame time per frame of each variant's first round, stand-in frames marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4))
    seen = set()
    for run in result["runs"]:
        if run["name"] in seen:
            continue
        seen.add(run["name"])
        ms = np.array(run["frame_ms"])
        line = ax.plot(ms, lw=0.8, label=f"{run['name']} (stand-ins {run['stand_in_share']:.0%})")
        marks = np.flatnonzero(run["stand_in_frames"])
        ax.plot(marks, ms[marks], ".", ms=3, color=line[0].get_color())
    ax.set_xlabel("frame (dots: a stand-in drawn)")
    ax.set_ylabel("ms per frame")
    ax.set_title(
        f"paging {result['scenario']}, {result['size']}, α {result['alpha']}, γ {result['gamma']}"
    )
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
