"""TIN vs pydelatin and RTIN vs pymartini on fractal DEMs, side by side in one run.

numba kernels are warmed up first (compile time excluded). Each case: median of ``--repeats``
runs of both engines; the JSON records times, ratios, vertex counts and true max errors.

    python benchmarks/bench_strategies.py [--sizes 1025 2049 4097] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def _median_time(fn, repeats: int):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def bench_tin(terrain, errors, repeats):
    from pydelatin import Delatin

    from approxtree.patches.approximate import approximate

    rows = []
    for e in errors:
        t_ours, ours = _median_time(lambda e=e: approximate(terrain, "tin", max_error=e), repeats)
        t_them, them = _median_time(lambda e=e: Delatin(terrain.heights, max_error=e), repeats)
        rows.append(
            {
                "max_error": e,
                "seconds": t_ours,
                "pydelatin_seconds": t_them,
                "time_ratio": t_ours / t_them,
                "vertices": len(ours.vertices),
                "pydelatin_vertices": len(them.vertices),
                "vertex_ratio": len(ours.vertices) / len(them.vertices),
                "true_max_error": ours.max_error,
            }
        )
        print("tin", terrain.shape, rows[-1], flush=True)
    return rows


def bench_rtin(terrain, errors, repeats):
    from pymartini import Martini

    from approxtree.patches.approximate import approximate
    from approxtree.patches.lattice import grid_window
    from approxtree.patches.tin import GridTINPatch

    rows = []
    n = terrain.shape[0]
    for e in errors:
        t_ours, ours = _median_time(lambda e=e: approximate(terrain, "rtin", max_error=e), repeats)

        def martini(e=e):
            tile = Martini(n).create_tile(terrain.heights.astype(np.float32))
            return tile.get_mesh(e)

        t_them, (verts, tris) = _median_time(martini, repeats)
        # pymartini's threshold is not a bound: measure its true error on our kernel.
        v = verts.reshape(-1, 2).astype(np.int64)
        win = grid_window(terrain, terrain.domain)
        t = tris.reshape(-1, 3).astype(np.int64)
        from approxtree.kernels.tin_mesh import orient  # noqa: F401
        from approxtree.patches.lattice import twins

        vx, vy = v[:, 0], v[:, 1]
        a2 = (vx[t[:, 1]] - vx[t[:, 0]]) * (vy[t[:, 2]] - vy[t[:, 0]]) - (
            vy[t[:, 1]] - vy[t[:, 0]]
        ) * (vx[t[:, 2]] - vx[t[:, 0]])
        t[a2 < 0] = t[a2 < 0][:, [0, 2, 1]]
        tv = t.ravel().astype(np.int32)
        p = GridTINPatch.from_window_mesh(terrain, terrain.domain, win, vx, vy, tv, twins(t))
        rows.append(
            {
                "max_error": e,
                "seconds": t_ours,
                "pymartini_seconds": t_them,
                "time_ratio": t_ours / t_them,
                "triangles": len(ours.triangles),
                "true_max_error": ours.max_error,
                "pymartini_triangles": len(t),
                "pymartini_true_max_error": p.error,
            }
        )
        print("rtin", terrain.shape, rows[-1], flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[1025, 2049, 4097])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    from approxtree.datasets import fractal_terrain
    from approxtree.patches.approximate import approximate

    warm = fractal_terrain(65, seed=0)
    approximate(warm, "tin", max_error=1.0)
    approximate(warm, "rtin", max_error=1.0)
    out = {"warmed_up": True, "note": "numba compile time excluded", "tin": {}, "rtin": {}}
    for n in args.sizes:
        terrain = fractal_terrain(n, seed=1, relief=1000.0)
        out["tin"][n] = bench_tin(terrain, [1.0, 5.0, 10.0, 30.0], args.repeats)
        out["rtin"][n] = bench_rtin(terrain, [1.0, 5.0, 30.0], args.repeats)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "strategies.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
