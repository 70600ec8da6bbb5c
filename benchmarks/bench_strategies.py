"""TIN vs pydelatin and RTIN vs pymartini on fractal DEMs and real web-tile-sized crops, side by
side in one run.

numba kernels are warmed up first (compile time excluded). Each case: median of ``--repeats``
runs of both engines, alternating; the JSON records wall and CPU times, their ratios (ours /
theirs), vertex counts and true max errors. Peak memory of one TIN run at the largest size is
measured for each engine in a fresh subprocess (peak RSS growth over a process that already holds
the heights). RTIN is compared twice: time for the same threshold (pymartini: build +
extraction), and triangles needed for the same TRUE max error (pymartini's threshold is not a
bound, so its meshes are measured and our RTIN is asked for that error, and for that triangle
budget). The TIN is also timed on 256² and 512² centre crops of the real DEMs in
../shared/data (the size of a web map tile, where fixed per-call costs weigh most). The numba
compile of the warm-up call is reported separately (``compile_seconds``). Writes
``results/strategies.json`` and plots ``strategies_tin.png``, ``strategies_rtin.png``.

    python benchmarks/bench_strategies.py [--sizes 1025 2049 4097] [--rtin-sizes 257 1025 4097]
        [--tile-sizes 256 512] [--tin-errors 1 5 10 30] [--tile-errors 1 2 5 10] [--repeats 5]
        [--tin-only] [--rtin-only] [--rtin-breakdown] [--out strategies]

``--tin-only`` runs just the greedy TIN rows of issue 15 (real 256²/512² tiles, fractal sizes
× errors) against pydelatin and writes their JSON (with the range of the CPU-time ratios).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
TIN_ERRORS = [1.0, 5.0, 10.0, 30.0]
TILE_ERRORS = [1.0, 2.0, 5.0, 10.0]
#: Real DEMs cropped to web-tile sizes (name, path under ../shared/data).
TILE_DEMS = [
    ("crater", "scape/crater.stm"),
    ("ntc", "scape/ntc.stm"),
    ("N44W072", "srtm/N44W072.hgt"),
    ("nc", "nc/elev_ned_30m.tif"),
]
RTIN_THRESHOLDS = [1.0, 2.0, 5.0, 10.0, 20.0, 50.0]


def _side_by_side(ours, theirs, repeats: int):
    """Median wall and CPU seconds of both callables, run alternately; and their last results."""
    wall = ([], [])
    cpu = ([], [])
    out = [None, None]
    for _ in range(repeats):
        for k, fn in enumerate((ours, theirs)):
            w0, c0 = time.perf_counter(), time.process_time()
            out[k] = fn()
            wall[k].append(time.perf_counter() - w0)
            cpu[k].append(time.process_time() - c0)
    med = [statistics.median(x) for x in (*wall, *cpu)]
    return med, out


def tile_crops(sizes: list[int]):
    """(name, Grid) centre crops of the real DEMs at each size that fits; missing files skipped."""
    from approxtree.geometry.grid import Grid
    from approxtree.io import read_grid

    out = []
    for name, rel in TILE_DEMS:
        path = DATA / rel
        if not path.exists():
            print("skipping absent", path, flush=True)
            continue
        z = read_grid(path).heights
        for n in sizes:
            if min(z.shape) < n:
                continue
            r0, c0 = (z.shape[0] - n) // 2, (z.shape[1] - n) // 2
            out.append((f"{name}_{n}", Grid(z[r0 : r0 + n, c0 : c0 + n].copy())))
    return out


def bench_tin(terrain, repeats, errors=TIN_ERRORS):
    from pydelatin import Delatin

    from approxtree.patches.approximate import approximate

    rows = []
    for e in errors:
        (w_o, w_t, c_o, c_t), (ours, them) = _side_by_side(
            lambda e=e: approximate(terrain, "tin", max_error=e),
            lambda e=e: Delatin(terrain.heights, max_error=e),
            repeats,
        )
        rows.append(
            {
                "max_error": e,
                "seconds": w_o,
                "pydelatin_seconds": w_t,
                "time_ratio": w_o / w_t,
                "cpu_seconds": c_o,
                "pydelatin_cpu_seconds": c_t,
                "cpu_ratio": c_o / c_t,
                "vertices": len(ours.vertices),
                "pydelatin_vertices": len(them.vertices),
                "vertex_ratio": len(ours.vertices) / len(them.vertices),
                "triangles": len(ours.triangles),
                "pydelatin_triangles": len(them.triangles),
                "true_max_error": ours.max_error,
            }
        )
        print("tin", terrain.shape, rows[-1], flush=True)
    return rows


def _martini_true_error(terrain, verts, tris) -> tuple[int, float]:
    """(triangles, exact max error over all grid points) of a pymartini mesh."""
    from approxtree.patches.lattice import grid_window, twins
    from approxtree.patches.tin import GridTINPatch

    v = verts.reshape(-1, 2).astype(np.int64)
    t = tris.reshape(-1, 3).astype(np.int64)
    vx, vy = v[:, 0], v[:, 1]
    a2 = (vx[t[:, 1]] - vx[t[:, 0]]) * (vy[t[:, 2]] - vy[t[:, 0]]) - (vy[t[:, 1]] - vy[t[:, 0]]) * (
        vx[t[:, 2]] - vx[t[:, 0]]
    )
    t[a2 < 0] = t[a2 < 0][:, [0, 2, 1]]
    win = grid_window(terrain, terrain.domain)
    tv = t.ravel().astype(np.int32)
    p = GridTINPatch.from_window_mesh(terrain, terrain.domain, win, vx, vy, tv, twins(t))
    return len(t), p.error


def bench_rtin(terrain, repeats, thresholds=RTIN_THRESHOLDS, equal_error=True):
    """RTIN rows against pymartini at each threshold: one ``Martini(n)`` made beforehand and
    reused, as a tile server does (its set-up is timed apart, ``pymartini_setup_seconds``),
    each repeat ``create_tile`` + ``get_mesh`` against our whole ``approximate`` call (error
    hierarchy, extraction measuring every grid point, world-coordinate mesh). equal_error:
    also the triangles each needs at pymartini's measured error."""
    from pymartini import Martini

    from approxtree.patches.approximate import approximate

    n = terrain.shape[0]
    heights32 = terrain.heights.astype(np.float32)
    t0 = time.perf_counter()
    martini = Martini(n)
    setup = time.perf_counter() - t0
    rows = []
    for e in thresholds:
        (w_o, w_t, c_o, c_t), (ours, (verts, tris)) = _side_by_side(
            lambda e=e: approximate(terrain, "rtin", max_error=e),
            lambda e=e: martini.create_tile(heights32).get_mesh(e),
            repeats,
        )
        row = {
            "threshold": e,
            "seconds": w_o,
            "pymartini_seconds": w_t,
            "pymartini_setup_seconds": setup,
            "time_ratio": w_o / w_t,
            "time_ratio_with_setup": w_o / (w_t + setup),
            "cpu_seconds": c_o,
            "pymartini_cpu_seconds": c_t,
            "cpu_ratio": c_o / c_t,
            "triangles": len(ours.triangles),
            "true_max_error": ours.max_error,
        }
        if equal_error:
            m_tris, m_err = _martini_true_error(terrain, verts, tris)
            # Equal true error: our RTIN asked for pymartini's measured error, and its budget.
            same_err = approximate(terrain, "rtin", max_error=m_err)
            same_budget = approximate(terrain, "rtin", max_triangles=m_tris)
            row.update(
                {
                    "pymartini_triangles": m_tris,
                    "pymartini_true_max_error": m_err,
                    "triangles_at_pymartini_error": len(same_err.triangles),
                    "true_error_at_pymartini_error": same_err.max_error,
                    "triangle_ratio_at_equal_error": len(same_err.triangles) / m_tris,
                    "greedy_true_error_at_pymartini_triangles": same_budget.max_error,
                    "greedy_triangles": len(same_budget.triangles),
                }
            )
        rows.append(row)
        print("rtin", terrain.shape, row, flush=True)
    return rows


def rtin_breakdown(terrain, repeats: int, thresholds=RTIN_THRESHOLDS) -> list[dict]:
    """Where one RTIN call's CPU time goes against pymartini's, per threshold (medians of
    ``repeats``, process time): our error table (``kernels.rtin.vertex_errors`` for that
    threshold), the extraction that measures every point (``extract``) and the rest of
    ``approximate`` (Python, the world mesh arrays); pymartini's ``create_tile`` and
    ``get_mesh``."""
    from pymartini import Martini

    from approxtree.kernels.rtin import extract
    from approxtree.patches.approximate import approximate
    from approxtree.patches.lattice import grid_window
    from approxtree.patches.rtin import _vertex_errors, lattice_size

    def cpu(fn) -> float:
        times = []
        for _ in range(repeats):
            t0 = time.process_time()
            fn()
            times.append(time.process_time() - t0)
        return statistics.median(times)

    win = grid_window(terrain, terrain.domain)
    size = lattice_size(win.rows, win.cols)
    z = terrain.heights_array("benchmark")
    heights32 = terrain.heights.astype(np.float32)
    martini = Martini(size + 1)
    rows = []
    for e in thresholds:
        err = _vertex_errors(terrain, win, size, float(e))
        tile = martini.create_tile(heights32)
        total = cpu(lambda e=e: approximate(terrain, "rtin", max_error=e))
        table = cpu(lambda e=e: _vertex_errors(terrain, win, size, float(e)))
        walk = cpu(lambda e=e, t=err: extract(t, float(e), z, 0, 0, win.rows, win.cols, False))
        create = cpu(lambda: martini.create_tile(heights32))
        mesh = cpu(lambda e=e, m=tile: m.get_mesh(e))
        rows.append(
            {
                "threshold": e,
                "ours_cpu_s": total,
                "error_table_cpu_s": table,
                "extract_cpu_s": walk,
                "rest_cpu_s": total - table - walk,
                "pymartini_create_tile_cpu_s": create,
                "pymartini_get_mesh_cpu_s": mesh,
                "cpu_ratio": total / (create + mesh),
                "triangles": int(extract(err, float(e), z, 0, 0, win.rows, win.cols, True)[0]),
            }
        )
        print("breakdown", terrain.shape, rows[-1], flush=True)
    return rows


_MEMORY_CHILD = """
import sys, numpy as np
engine, path, e = sys.argv[1], sys.argv[2], float(sys.argv[3])

def status(field):
    for line in open("/proc/self/status"):
        if line.startswith(field):
            return int(line.split()[1]) * 1024

z = np.load(path)
from approxtree.geometry.grid import Grid
from approxtree.datasets import fractal_terrain
if engine == "ours":
    from approxtree.patches.approximate import approximate
    approximate(fractal_terrain(65, seed=0), "tin", max_error=1.0)
    g = Grid(z)
    run = lambda: approximate(g, "tin", max_error=e)
else:
    from pydelatin import Delatin
    Delatin(fractal_terrain(65, seed=0).heights, max_error=1.0)
    run = lambda: Delatin(z, max_error=e)
# Reset the kernel's peak-RSS mark (VmHWM) so only this run's growth counts.
open("/proc/self/clear_refs", "w").write("5")
base = status("VmRSS")
m = run()
print(status("VmHWM") - base, len(m.vertices))
"""


def bench_memory(terrain, max_error: float) -> dict[str, object]:
    """Peak resident-memory growth of one TIN run, each engine in a fresh process (VmHWM after
    the run minus VmRSS before it, the peak mark reset through /proc/self/clear_refs)."""
    out: dict[str, object] = {"size": terrain.shape[0], "max_error": max_error}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "z.npy"
        np.save(path, terrain.heights)
        for engine in ("ours", "pydelatin"):
            res = subprocess.run(
                [sys.executable, "-c", _MEMORY_CHILD, engine, str(path), str(max_error)],
                capture_output=True,
                text=True,
                check=True,
            )
            grown, verts = res.stdout.split()
            out[f"{engine}_peak_bytes"] = int(grown)
            out[f"{engine}_vertices"] = int(verts)
    out["memory_ratio"] = out["ours_peak_bytes"] / max(1, out["pydelatin_peak_bytes"])
    print("memory", out, flush=True)
    return out


def plot(out: dict, name: str = "strategies") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 4))
    labels, ratios = [], []
    for tile, rows in out.get("tin_tiles", {}).items():
        for r in rows:
            labels.append(f"{tile}\n{r['max_error']:g}")
            ratios.append(r["time_ratio"])
    for n, rows in out["tin"].items():
        for r in rows:
            labels.append(f"{n}²\n{r['max_error']:g} m")
            ratios.append(r["time_ratio"])
    ax.bar(range(len(ratios)), ratios, color="tab:blue")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhline(0.7, color="tab:red", lw=0.8, ls="--", label="moonshot 0.7×")
    ax.set_xticks(range(len(ratios)), labels, fontsize=5)
    ax.set_ylabel("time ours / pydelatin")
    ax.set_title("TIN greedy insertion vs pydelatin (real tiles, fractal; median of runs)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(RESULTS / f"{name}_tin.png", dpi=120)
    plt.close(fig)

    if not out["rtin"]:
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    for n, rows in out["rtin"].items():
        e = [r["pymartini_true_max_error"] for r in rows]
        ax.loglog(e, [r["pymartini_triangles"] for r in rows], "o--", label=f"pymartini {n}²")
        ax.loglog(e, [r["triangles_at_pymartini_error"] for r in rows], "s-", label=f"ours {n}²")
    ax.set_xlabel("true max error (m)")
    ax.set_ylabel("triangles")
    ax.set_title("RTIN: triangles at equal true error")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS / f"{name}_rtin.png", dpi=120)
    plt.close(fig)


def plot_rtin_times(out: dict, name: str) -> None:
    """The RTIN time ratios ours / pymartini per grid and threshold: CPU time (bars; single
    threaded on both sides below 2049², the fair figure on a shared machine) and wall time
    (dots)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels, cpu, wall = [], [], []
    for group in ("rtin", "rtin_tiles"):
        for grid, rows in out[group].items():
            for r in rows:
                labels.append(f"{grid}{'²' if group == 'rtin' else ''}\n{r['threshold']:g}")
                cpu.append(r["cpu_ratio"])
                wall.append(r["time_ratio"])
    fig, ax = plt.subplots(figsize=(14, 4.5))
    ax.bar(range(len(cpu)), cpu, color="tab:green", label="CPU time")
    ax.plot(range(len(wall)), wall, "k.", label="wall time")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhline(1.5, color="tab:red", lw=0.8, ls="--", label="target 1.5×")
    ax.set_xticks(range(len(cpu)), labels, fontsize=5, rotation=90)
    ax.set_ylabel("ours / pymartini")
    ax.set_title("RTIN vs pymartini (create_tile + get_mesh, Martini(n) reused; medians)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(RESULTS / f"{name}_rtin_time.png", dpi=120)
    plt.close(fig)


def _ratio_range(out: dict, groups=("tin_tiles", "tin"), key="cpu_ratio") -> dict[str, float]:
    """Smallest and largest ``key`` (ours / peer) over the rows of ``groups``."""
    rows = [r for group in groups for rs in out.get(group, {}).values() for r in rs]
    if not rows:
        return {}
    ratios = [r[key] for r in rows]
    return {"min": min(ratios), "max": max(ratios), "rows": len(ratios)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[1025, 2049, 4097])
    ap.add_argument("--rtin-sizes", type=int, nargs="+", default=[257, 1025, 4097])
    ap.add_argument("--tile-sizes", type=int, nargs="*", default=[256, 512])
    ap.add_argument("--tin-errors", type=float, nargs="+", default=TIN_ERRORS)
    ap.add_argument("--tile-errors", type=float, nargs="+", default=TILE_ERRORS)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument(
        "--tin-only",
        action="store_true",
        help="only the greedy TIN rows (real tiles and fractal sizes) against pydelatin",
    )
    ap.add_argument(
        "--rtin-only",
        action="store_true",
        help="only the RTIN rows (fractal --rtin-sizes, real --rtin-tile-sizes crops) against "
        "pymartini, its Martini(n) made once and reused",
    )
    ap.add_argument("--rtin-tile-sizes", type=int, nargs="*", default=[257, 1025])
    ap.add_argument(
        "--rtin-breakdown",
        action="store_true",
        help="only the CPU-time breakdown of RTIN calls against pymartini's two steps on the "
        "257² fractal and real crops (where the fixed costs of a call weigh most)",
    )
    ap.add_argument("--rtin-thresholds", type=float, nargs="+", default=RTIN_THRESHOLDS)
    ap.add_argument("--memory-error", type=float, default=5.0)
    ap.add_argument("--out", default="strategies", help="name of the JSON and plots")
    args = ap.parse_args()
    from pydelatin import Delatin

    from approxtree.datasets import fractal_terrain
    from approxtree.patches.approximate import approximate

    # The warm-up calls compile the numba kernels (or load them from the cache): timed apart.
    warm = fractal_terrain(65, seed=0)
    t0 = time.perf_counter()
    approximate(warm, "tin", max_error=1.0)
    compile_tin = time.perf_counter() - t0
    t0 = time.perf_counter()
    approximate(warm, "rtin", max_error=1.0)
    approximate(warm, "rtin", max_triangles=500)
    compile_rtin = time.perf_counter() - t0
    Delatin(warm.heights, max_error=1.0)
    out = {
        "warmed_up": True,
        "note": "numba compile time excluded; ratios are ours / theirs (< 1: we are faster)",
        "compile_seconds": {"tin": compile_tin, "rtin": compile_rtin},
        "repeats": args.repeats,
        "tin_tiles": {},
        "tin": {},
        "rtin": {},
        "rtin_tiles": {},
        "load_average_start": os.getloadavg(),
    }
    print("compile", out["compile_seconds"], flush=True)
    if args.rtin_breakdown:
        grids = [("fractal_257", fractal_terrain(257, seed=1, relief=1000.0))]
        grids += tile_crops([257])
        out["rtin_breakdown"] = {
            name: rtin_breakdown(grid, max(args.repeats, 21), args.rtin_thresholds)
            for name, grid in grids
        }
        out["load_average_end"] = os.getloadavg()
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / f"{args.out}.json").write_text(json.dumps(out, indent=1))
        return
    if args.rtin_only:
        for n in args.rtin_sizes:
            terrain = fractal_terrain(n, seed=1, relief=1000.0)
            out["rtin"][n] = bench_rtin(terrain, args.repeats, args.rtin_thresholds, n <= 1025)
        for name, grid in tile_crops(args.rtin_tile_sizes):
            out["rtin_tiles"][name] = bench_rtin(grid, args.repeats, args.rtin_thresholds, False)
        out["rtin_ratio_range"] = _ratio_range(out, ("rtin", "rtin_tiles"), "time_ratio")
        out["load_average_end"] = os.getloadavg()
        print("RTIN ours / pymartini (wall):", out["rtin_ratio_range"], flush=True)
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / f"{args.out}.json").write_text(json.dumps(out, indent=1))
        plot_rtin_times(out, args.out)
        return
    for name, grid in tile_crops(args.tile_sizes):
        out["tin_tiles"][name] = bench_tin(grid, args.repeats, args.tile_errors)
    for n in args.sizes:
        terrain = fractal_terrain(n, seed=1, relief=1000.0)
        out["tin"][n] = bench_tin(terrain, args.repeats, args.tin_errors)
    out["tin_ratio_range"] = _ratio_range(out)
    print("TIN ours / pydelatin (CPU time):", out["tin_ratio_range"], flush=True)
    if args.tin_only:
        out["load_average_end"] = os.getloadavg()
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / f"{args.out}.json").write_text(json.dumps(out, indent=1))
        plot(out, args.out)
        return
    for n in args.rtin_sizes:
        terrain = fractal_terrain(n, seed=1, relief=1000.0)
        out["rtin"][n] = bench_rtin(terrain, args.repeats)
    big = max(args.sizes)
    out["memory"] = bench_memory(fractal_terrain(big, seed=1, relief=1000.0), args.memory_error)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{args.out}.json").write_text(json.dumps(out, indent=1))
    plot(out, args.out)
    print("peak RSS of the benchmark process:", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


if __name__ == "__main__":
    main()
