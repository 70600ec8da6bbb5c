"""Hybrid trees: build time and memory, auto vs single-strategy memory, frames, Autzen table 1.

Cases (each in a fresh worker process). Build time is one plain run; build memory is the peak
of Python and numpy allocations (tracemalloc) over a second run (numba's own buffers are not
counted).

- ``nc``: ../shared/data/nc/elev_ned_30m.tif refined by its streams (incised corridors, 30 m
  wide, 15 m samples), ε = 1 m, s = 33²;
- ``case_study``: the synthetic 641 × 321 grid with 20,652 microstructure TINs, ε = 1 m, s = 33²;
- ``autzen``: ../shared/data/lidar/autzen_trim.laz, ground points and all points: the point
  quadtree (δ = 50) with the figures of seed 003's table 1 at C = 10 px, and the k-d tree A(25, 2)
  of the core paper's figure 3 (ground points).

For the two grid refinements: tree memory (sum of patch nbytes) of the ``type`` policy, and of
``auto``, all-grid and all-tin trees at the same ε; frame time and triangles of an overview at
640 × 480 with α = 4 px and γ = 2 px (the paper's case study settings; it reported 15–20 fps on
1999 hardware), median of 5 frames after one warm-up frame, on whatever GL the machine has.

    python benchmarks/bench_hybrid.py [--cases nc case_study autzen] [--quick]

Writes benchmarks/results/hybrid.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def _measured(fn):
    """(result, seconds, peak bytes) of fn(): timed on a plain run, then run again under
    tracemalloc (numpy registers its buffers there) for the peak of Python and numpy memory.
    The rise of the process's peak RSS is no measure here: memory freed by an earlier step
    (corridor building) is reused without raising RSS."""
    import tracemalloc

    t0 = time.perf_counter()
    out = fn()
    seconds = time.perf_counter() - t0
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return out, seconds, peak


def _tree_bytes(tree) -> int:
    return int(sum(tree.patch(i).nbytes for i in range(len(tree))))


def _frames(tree) -> dict:
    from approxtree.render import Cut, Engine, overview_camera
    from approxtree.render.context import create_context

    ctx = create_context()
    engine = Engine(tree, context=ctx, offscreen=True)
    try:
        camera = overview_camera(tree.bboxes[0], engine.scale, fov=45.0)
        engine.render(camera, (640, 480), Cut(alpha=4.0, gamma=2.0))
        times, stats = [], None
        for _ in range(5):
            t0 = time.perf_counter()
            frame = engine.render(camera, (640, 480), Cut(alpha=4.0, gamma=2.0))
            times.append(time.perf_counter() - t0)
            stats = frame.stats
    finally:
        engine.release()
        ctx.release()
    med = statistics.median(times)
    return {
        "frame_ms_median": 1000 * med,
        "fps": 1.0 / med,
        "triangles": stats["triangles"],
        "patches": stats["patches"],
        "max_alpha": stats["max_alpha"],
        "gl_renderer": ctx.info.get("GL_RENDERER") if hasattr(ctx, "info") else None,
    }


def refinement_case(name: str, quick: bool) -> dict:
    import approxtree as at
    from approxtree import ApproximationTree, GridRefinement

    eps, s = 1.0, 33 * 33
    # Warm the numba kernels on a tiny case so compile time is not build time.
    from approxtree.datasets import case_study_terrain

    g, t = case_study_terrain(seed=1, rows=41, cols=41, microstructures=20)
    ApproximationTree.build(GridRefinement(g, t), eps, 81, progress=False)

    t0 = time.perf_counter()
    if name == "nc":
        from approxtree.io.microstructures import load_microstructures

        grid = at.open_terrain(DATA / "nc" / "elev_ned_30m.tif")
        tins = load_microstructures(DATA / "nc" / "streams.shp", grid, width=30.0, spacing=15.0)
        source = "incised corridors (grid bilinear − 2 m parabola), 30 m wide, 15 m samples"
    else:
        kw = {"rows": 161, "cols": 321, "microstructures": 5000} if quick else {}
        grid, tins = case_study_terrain(seed=0, **kw)
        source = "synthetic incised corridors along random meanders"
    refined = GridRefinement(grid, tins)
    prep = time.perf_counter() - t0
    out = {
        "case": name,
        "grid": list(grid.shape),
        "microstructures": len(tins),
        "microstructure_triangles": int(sum(len(x.triangles) for x in tins)),
        "data_points": refined.point_count,
        "microstructure_source": source,
        "prepare_seconds": prep,
        "epsilon": eps,
        "max_points": s,
    }
    tree, seconds, peak = _measured(
        lambda: ApproximationTree.build(refined, eps, s, policy="type", progress=False)
    )
    out["type"] = {
        "build_seconds": seconds,
        "build_peak_bytes": peak,
        "nodes": len(tree),
        "strategies": tree.strategy_counts,
        "tree_patch_bytes": _tree_bytes(tree),
        "max_leaf_error": float(tree.errors[tree.leaves].max()),
    }
    out["frames"] = _frames(tree)
    for policy in ("auto", "grid", "tin"):
        other, seconds, peak = _measured(
            lambda p=policy: ApproximationTree.build(refined, eps, s, policy=p, progress=False)
        )
        out[policy] = {
            "build_seconds": seconds,
            "build_peak_bytes": peak,
            "nodes": len(other),
            "strategies": other.strategy_counts,
            "tree_patch_bytes": _tree_bytes(other),
            "max_leaf_error": float(other.errors[other.leaves].max()),
        }
    return out


def autzen_case(quick: bool) -> dict:
    import approxtree as at
    from approxtree import ApproximationTree
    from approxtree.render.lod_cut import lod_mesh
    from approxtree.tree.point_quadtree import PointQuadtree

    path = DATA / "lidar" / "autzen_trim.laz"
    # Warm-up on a tiny point set.
    import numpy as np

    PointQuadtree(at.TINPointSet(np.random.default_rng(0).uniform(0, 9, (200, 3))), 20)
    out: dict = {"delta": 50, "C": 10.0, "viewport": [640, 480], "fov": 60.0}
    for label, ground in (("ground", True), ("all", False)):
        terrain = at.open_terrain(path, ground_only=ground)
        q, seconds, peak = _measured(lambda t=terrain: PointQuadtree(t, 50))
        d = terrain.domain
        # Low oblique view from the south edge, 100 ft above the highest point.
        eye = (d.center[0], d.ymin - 0.1 * d.height, terrain.z_range[1] + 100.0)
        t0 = time.perf_counter()
        mesh = lod_mesh(q, eye, 60.0, 640, 10.0)
        lod_seconds = time.perf_counter() - t0
        n_p, n_c = len(terrain.vertices), q.interpolation_point_count()
        n_t, n_lt = len(terrain.triangles), len(mesh.triangles)
        out[label] = {
            "N_P": n_p,
            "duplicates_merged": terrain.duplicates_merged,
            "N_C": n_c,
            "N_C/N_P": n_c / n_p,
            "N_T": n_t,
            "N_LT": n_lt,
            "N_LT/N_T": n_lt / n_t,
            "eye": list(eye),
            "build_seconds": seconds,
            "build_peak_bytes": peak,
            "nodes": len(q.children),
            "leaves": len(q.leaves),
            "lod_seconds": lod_seconds,
            "lod_nodes": mesh.nodes,
            "leaves_refined": mesh.leaves_refined,
            "points_inserted": mesh.points_inserted,
        }
        if ground and not quick:
            tree, seconds, peak = _measured(
                lambda t=terrain: ApproximationTree.build(
                    t, 0.5, 25, fanout=2, policy="tin", progress=False
                )
            )
            out["kd_A25_2_ground"] = {
                "epsilon": 0.5,
                "build_seconds": seconds,
                "build_peak_bytes": peak,
                "nodes": len(tree),
                "levels": int(tree.levels.max()) + 1,
                "max_leaf_error": float(tree.errors[tree.leaves].max()),
            }
    return out


def worker(case: str, quick: bool) -> dict:
    if case == "autzen":
        return autzen_case(quick)
    return refinement_case(case, quick)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["nc", "case_study", "autzen"])
    parser.add_argument("--quick", action="store_true", help="smaller case study, no k-d tree")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker, args.quick)))
        return
    results = []
    for case in args.cases:
        cmd = [sys.executable, __file__, "--worker", case] + (["--quick"] if args.quick else [])
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            print(done.stderr, file=sys.stderr)
            results.append({"case": case, "error": done.stderr.strip().splitlines()[-1]})
            continue
        results.append(json.loads(done.stdout.strip().splitlines()[-1]))
        print(json.dumps(results[-1], indent=1))
    RESULTS.mkdir(exist_ok=True)
    out = RESULTS / "hybrid.json"
    out.write_text(
        json.dumps(
            {"machine": platform.platform(), "python": sys.version.split()[0], "cases": results},
            indent=1,
        )
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
