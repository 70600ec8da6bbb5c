"""Rate–distortion benchmark: binary-tree decimation and refinement against RTG, TIN and RTIN.

1. Timing: decimation (constrained G-BFOS) and refinement (greedy growing, run to the full
   grid) on fractal DEMs of 257², 513², 1025² (and 2049² with --sizes), plus the tree set-up
   (per-node exact distortions). seconds / (n log2 n) shows the n log n growth.
2. SNR table (Balmelli et al., table 1 layout): SNR in dB and max error at 512, 1024, 2048 and
   4096 triangles for decimation, refinement, uniform (RTG), greedy TIN and RTIN on 257²
   windows of the real DEMs in ../shared/data (scape terrains, NC NED, SRTM Mt Washington),
   with one PNG of the L2 and L∞ curves per DEM.
3. Budget mode against threshold mode: for several alpha thresholds on views of a fractal
   tree, the threshold cut's triangles and largest α, and the α the budget mode reaches with
   exactly that many triangles (no GL: selection only, skirts counted).

Results go to benchmarks/results/rd.json and rd_*.png.

    python benchmarks/bench_rd.py [--sizes 257,513,1025] [--skip-timing] [--skip-table]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import numpy as np

from approxtree.datasets import fractal_terrain
from approxtree.rd import BinTree, decimate, lattice_heights, rd_curves, refine
from approxtree.rd.curves import json_ready, plot_rd

RESULTS = Path(__file__).resolve().parent / "results"
DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
DEMS = [
    "scape/crater.stm",
    "scape/ashby.stm",
    "scape/ozark.stm",
    "scape/ntc.stm",
    "nc/elev_ned_30m.tif",
    "srtm/N44W072.hgt",
]


def timing(sizes: list[int]) -> list[dict]:
    """Seconds of tree set-up, decimation and refinement per grid size."""
    # Compile once on a tiny grid so the first size is not charged with it.
    small = BinTree(fractal_terrain(17, seed=1).heights)
    decimate(small)
    refine(small)
    rows = []
    for size in sizes:
        h = fractal_terrain(size, seed=7, relief=1000.0).heights
        t0 = time.perf_counter()
        tree = BinTree(h)
        setup = time.perf_counter() - t0
        dec = decimate(tree)
        ref = refine(tree)
        n = size * size
        nlogn = n * math.log2(n)
        row = {
            "size": size,
            "points": n,
            "setup_s": round(setup, 3),
            "decimation_s": round(dec.seconds, 3),
            "refinement_s": round(ref.seconds, 3),
            "decimation_steps": len(dec) - 1,
            "refinement_steps": len(ref) - 1,
            "decimation_ns_per_nlogn": round(1e9 * dec.seconds / nlogn, 3),
            "refinement_ns_per_nlogn": round(1e9 * ref.seconds / nlogn, 3),
        }
        print(row, flush=True)
        rows.append(row)
        del tree, dec, ref
    return rows


def snr_table(rates: list[int]) -> dict:
    """rd_curves on the 257² window of every available DEM, with a plot each."""
    from approxtree.io import open_terrain

    out = {}
    for rel in DEMS:
        path = DATA / rel
        if not path.exists():
            print(f"skip {rel}: absent")
            continue
        h = lattice_heights(open_terrain(path), 257)
        res = rd_curves(h, rates)
        name = Path(rel).stem
        plot_rd(res, RESULTS / f"rd_{name}.png", title=f"{name} (257²)")
        out[rel] = json_ready(res)
        line = "  ".join(
            f"{m} " + "/".join(f"{r['snr_db']:.2f}" for r in d["rows"])
            for m, d in res["methods"].items()
        )
        print(rel, line, flush=True)
    return out


def budget_vs_threshold() -> list[dict]:
    """Threshold cut vs budget cut at equal triangle counts on views of a fractal tree."""
    from approxtree import ApproximationTree
    from approxtree.render import Camera, FrameState, display_scale, overview_camera, select
    from approxtree.render.budget import node_triangles, select_budget
    from approxtree.render.visual_error import texel_sizes

    terrain = fractal_terrain(1025, seed=5, relief=600.0)
    tree = ApproximationTree.build(terrain, epsilon=0.0, max_points=17 * 17, progress=False)
    counts = node_triangles(tree)
    texels = texel_sizes(tree)
    scale = display_scale(terrain)
    d = terrain.domain
    (cx, cy), w = d.center, d.width
    z = float(tree.bboxes[0, 5])
    cams = {
        "overview": overview_camera(tree.bboxes[0], scale),
        "south_low": Camera.look_at((cx, d.ymin - 0.1 * w, z + 0.05 * w), (cx, cy, 0), 60),
        "close_up": Camera.look_at((cx, cy - 0.1 * w, z + 0.02 * w), (cx, cy + 0.2 * w, 0), 60),
    }
    rows = []
    for name, cam in cams.items():
        fs = FrameState.from_camera(cam, (1280, 720), tree.bboxes[0], tree.origin, scale)
        for alpha in (0.5, 1.0, 2.0, 4.0, 8.0):
            t0 = time.perf_counter()
            thr = select(tree, fs, alpha, math.inf, texels)
            t_thr = time.perf_counter() - t0
            tri = int(counts[thr.nodes].sum())
            t0 = time.perf_counter()
            bud = select_budget(tree, fs, tri, counts, texels)
            t_bud = time.perf_counter() - t0
            rows.append(
                {
                    "view": name,
                    "alpha": alpha,
                    "threshold_triangles": tri,
                    "threshold_max_alpha": round(thr.stats["max_alpha"], 4),
                    "budget_triangles": bud.stats["budget_triangles"],
                    "budget_alpha_reached": round(bud.stats["alpha_reached"], 4),
                    "threshold_ms": round(1e3 * t_thr, 3),
                    "budget_ms": round(1e3 * t_bud, 3),
                }
            )
            print(rows[-1], flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="257,513,1025")
    ap.add_argument("--rates", default="512,1024,2048,4096")
    ap.add_argument("--skip-timing", action="store_true")
    ap.add_argument("--skip-table", action="store_true")
    ap.add_argument("--skip-budget", action="store_true")
    args = ap.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    out: dict = {"machine": platform.platform(), "processor": platform.processor()}
    if not args.skip_timing:
        sizes = [int(s) for s in args.sizes.split(",")]
        out["timing"] = timing(sizes)
        _plot_timing(out["timing"])
    if not args.skip_table:
        out["snr_table"] = snr_table([int(r) for r in args.rates.split(",")])
    if not args.skip_budget:
        out["budget_vs_threshold"] = budget_vs_threshold()
    path = RESULTS / "rd.json"
    path.write_text(json.dumps(out, indent=1))
    print(f"wrote {path}")


def _plot_timing(rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.array([r["points"] for r in rows], dtype=float)
    fig, ax = plt.subplots(figsize=(6, 4))
    for key in ("setup_s", "decimation_s", "refinement_s"):
        ax.loglog(n, [r[key] for r in rows], "o-", label=key[:-2])
    ref = n * np.log2(n)
    ax.loglog(n, ref / ref[-1] * rows[-1]["decimation_s"], "k--", lw=0.8, label="n log n")
    ax.set(xlabel="grid points n", ylabel="seconds")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(RESULTS / "rd_timing.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
