"""Point quadtree restriction (build step 2): the array pass beside the Python work list it
replaced (kept in tests/test_point_quadtree.py as ``reference_restrict``), on the ground points
and all points of ../shared/data/lidar/autzen_trim.laz (δ = 50): min and median of 7 runs
each from the same subdivided tree, and the node counts (equal).

    python benchmarks/bench_point_quadtree_restrict.py

Writes benchmarks/results/point_quadtree_restrict.json.
"""

from __future__ import annotations

import json
import platform
import statistics
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
TESTS = Path(__file__).resolve().parents[1] / "tests"


def case(ground: bool) -> dict:
    import approxtree as at
    from approxtree.tree.point_quadtree import PointQuadtree

    sys.path.insert(0, str(TESTS))
    from test_point_quadtree import reference_restrict

    terrain = at.open_terrain(DATA / "lidar" / "autzen_trim.laz", ground_only=ground)
    # The subdivided tree before its restriction (both passes start from copies of it).
    array_pass = PointQuadtree._restrict
    state: dict = {}
    PointQuadtree._restrict = lambda self: state.update(c=dict(self.children), s=self._splits)
    try:
        q = PointQuadtree(terrain, 50)
    finally:
        PointQuadtree._restrict = array_pass
    out: dict = {"points": len(q.points), "nodes_before": len(state["c"])}
    for name, run in (("work_list", reference_restrict), ("array_pass", array_pass)):
        times = []
        for _ in range(7):
            q.children, q._splits = dict(state["c"]), list(state["s"])
            t0 = time.perf_counter()
            run(q)
            times.append((time.perf_counter() - t0) * 1e3)
        out[name] = {
            "min_ms": round(min(times), 3),
            "median_ms": round(statistics.median(times), 3),
            "nodes": len(q.children),
            "internal": sum(q.children.values()),
        }
    return out


def main() -> None:
    out = {"machine": platform.platform(), "delta": 50}
    for label, ground in (("ground", True), ("all", False)):
        out[label] = case(ground)
        print(json.dumps({label: out[label]}, indent=1))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "point_quadtree_restrict.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
