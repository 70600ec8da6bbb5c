"""Point clouds: greedy insertion TIN and point-set trees against startinpy's full Delaunay.

Cases, run interleaved (one round runs every case once; medians over the rounds), after one
warm-up call of every kernel on a tiny input (numba compilation is not timed):

- ``autzen_eps0``: ../shared/data/lidar/autzen_trim.laz, all points (distinct positions, as
  the TINPointSet holds them): our greedy TIN to ε = 0 and our full insertion (ε < 0, every
  point: the Delaunay triangulation) against startinpy's DT of the same points (target: greedy
  within 3× of startinpy);
- ``cloud_1m``: a seeded 1,000,000-point cloud (3 km square, smooth relief + 0.2 m noise), in
  random order: greedy TIN to ε = 0.5 m (target < 10 s; the kernel's own Z-order sort is
  timed), and startinpy's DT of the same points given in Z-order (sorted untimed: in random
  order its walking point location took 209 s here);
- ``autzen_tree``: the point-set tree A(33², 4) at ε = 0.5 over all autzen points
  (target < 20 s), from the TINPointSet (reading the file is not timed);
- ``autzen_kd``: the k-d tree A(25, 2) at ε = 0.5 over the autzen ground points (policy tin).

    python benchmarks/bench_points.py [--rounds 3] [--quick]

Writes benchmarks/results/points.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def _timed(fn) -> tuple[object, float]:
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _cloud(n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) seeded scattered terrain: two wave scales and 0.2 m noise over 3 km × 3 km."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 3000, n)
    y = rng.uniform(0, 3000, n)
    z = 30 * np.sin(x / 200) * np.cos(y / 170) + 5 * np.sin(x / 23 + y / 31)
    return np.column_stack([x, y, z + rng.normal(0, 0.2, n)])


def _warm_up() -> None:
    """Compile every kernel on tiny inputs so that no timing includes numba."""
    import startinpy

    import approxtree as at
    from approxtree.patches.tin_points import greedy_points

    p = _cloud(500, seed=1)
    for eps in (-1.0, 0.0, 0.5):
        greedy_points(p[:, :2], p[:, 2], eps, 0)
    at.ApproximationTree.build(at.TINPointSet(p), 0.5, 25, fanout=2, progress=False)
    dt = startinpy.DT()
    dt.insert(p)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="100 k cloud instead of 1 M")
    args = parser.parse_args()

    import startinpy

    import approxtree as at
    from approxtree.io.pointcloud import read_point_cloud
    from approxtree.patches.tin_points import greedy_points

    laz = DATA / "lidar" / "autzen_trim.laz"
    allpts = read_point_cloud(laz)
    ground = read_point_cloud(laz, ground_only=True)
    cloud = _cloud(100_000 if args.quick else 1_000_000)
    # startinpy locates each point by walking from the last insertion: give it spatial order.
    from approxtree.kernels.greedy_points import _morton_order

    cloud_sorted = cloud[_morton_order(cloud[:, 0].copy(), cloud[:, 1].copy())]
    av = allpts.vertices
    _warm_up()

    def startin(p: np.ndarray) -> int:
        dt = startinpy.DT()
        dt.insert(p)
        return dt.number_of_triangles()

    # name -> function returning a dict of figures (timed around the call).
    cases = {
        "autzen_eps0_greedy": lambda: greedy_points(av[:, :2], av[:, 2], 0.0, 0),
        "autzen_full_insertion": lambda: greedy_points(av[:, :2], av[:, 2], -1.0, 0),
        "autzen_startinpy": lambda: startin(av),
        "cloud_1m_greedy_0.5": lambda: greedy_points(cloud[:, :2], cloud[:, 2], 0.5, 0),
        "cloud_1m_startinpy_zorder": lambda: startin(cloud_sorted),
        "autzen_tree_A1089_4": lambda: at.ApproximationTree.build(
            allpts, 0.5, 33 * 33, fanout=4, progress=False
        ),
        "autzen_ground_kd_A25_2": lambda: at.ApproximationTree.build(
            ground, 0.5, 25, fanout=2, policy="tin", progress=False
        ),
    }
    seconds: dict[str, list[float]] = {k: [] for k in cases}
    figures: dict[str, dict] = {}
    for _ in range(args.rounds):
        for name, fn in cases.items():
            out, s = _timed(fn)
            seconds[name].append(s)
            if isinstance(out, tuple):
                chosen, tris, worst, _sse = out
                figures[name] = {"vertices": len(chosen), "triangles": len(tris), "error": worst}
            elif isinstance(out, int):
                figures[name] = {"triangles": out}
            else:
                figures[name] = {
                    "nodes": len(out),
                    "leaves": len(out.leaves),
                    "max_leaf_error": float(out.errors[out.leaves].max()),
                }
    med = {k: statistics.median(v) for k, v in seconds.items()}
    result = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "startinpy": version("startinpy"),
        "rounds": args.rounds,
        "points": {
            "autzen_all_distinct": len(av),
            "autzen_ground": len(ground.vertices),
            "cloud": len(cloud),
        },
        "median_seconds": med,
        "all_seconds": seconds,
        "figures": figures,
        "ratios": {
            "greedy_eps0_over_startinpy": med["autzen_eps0_greedy"] / med["autzen_startinpy"],
            "full_insertion_over_startinpy": med["autzen_full_insertion"] / med["autzen_startinpy"],
        },
        "targets": {
            "greedy_eps0_within_3x_startinpy": med["autzen_eps0_greedy"]
            <= 3 * med["autzen_startinpy"],
            "cloud_1m_under_10s": med["cloud_1m_greedy_0.5"] < 10.0,
            "autzen_tree_under_20s": med["autzen_tree_A1089_4"] < 20.0,
        },
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    out_path = RESULTS / "points.json"
    out_path.write_text(json.dumps(result, indent=2))
    for name, s in med.items():
        print(f"{name:28s} {s:8.3f} s  {figures[name]}")
    print(json.dumps(result["ratios"]), json.dumps(result["targets"]))
    print(f"wrote {out_path}")


if __name__ == "__main__":
    main()
