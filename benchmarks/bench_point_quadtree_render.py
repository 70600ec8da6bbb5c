"""Point quadtree (seed 003) drawn by the Engine: build, store and frame figures on Autzen.

For the ground points and all points of ../shared/data/lidar/autzen_trim.laz (δ = 50): build,
save and load seconds, file size; then, for an oblique view from the south at 1280 × 720, the
frames at α = 1 and α = 4 (the second of two frames, so meshes are cached) beside the
full-resolution frame of the same view (every data point of every visible leaf) as the peer;
the first frames (every mesh built and uploaded: ``first_frame``, and an overview from above
the whole data set at α = 1, ``first_overview``, each in a fresh Engine), with the meshes
built alone (``mesh_build_ms``: every drawn node's mesh of the overview cut, one
``node_meshes`` call, render/lod_cut.py); and the cut alone (``LodSelector.cut``: min and
median of 10 calls).

    python benchmarks/bench_point_quadtree_render.py

Writes benchmarks/results/point_quadtree_render.json.
"""

from __future__ import annotations

import json
import platform
import statistics
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
KEYS = ("patches", "triangles", "max_alpha", "select_ms", "upload_ms", "draw_ms")


def case(ground: bool, tmp: Path) -> dict:
    import numpy as np

    import approxtree as at
    from approxtree.render import Camera, Cut, Engine
    from approxtree.render.frustum import boxes_in_frustum
    from approxtree.render.lod_cut import LodSelector, lod_mesh, node_meshes, pixels_per_radian
    from approxtree.tree.point_quadtree import PointQuadtree

    # Warm-up: load the compiled kernels (build, cut, meshes) and the GL programs before timing.
    warm = PointQuadtree(at.TINPointSet(np.random.default_rng(0).uniform(0, 9, (200, 3))), 20)
    lod_mesh(warm, (-1.0, -1.0, 5.0), 60.0, 640, 0.5)
    with Engine(warm) as eng:
        eng.render(Camera.look_at((4.5, -5.0, 9.0), (4.5, 4.5, 0.0), fov=45), (64, 48))
    terrain = at.open_terrain(DATA / "lidar" / "autzen_trim.laz", ground_only=ground)
    t0 = time.perf_counter()
    q = PointQuadtree(terrain, 50)
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    nbytes = q.save(tmp / "q.zarr.zip")
    save = time.perf_counter() - t0
    t0 = time.perf_counter()
    q = PointQuadtree.load(tmp / "q.zarr.zip")
    load = time.perf_counter() - t0
    d = terrain.domain
    (cx, cy), (z0, z1) = d.center, terrain.z_range
    cam = Camera.look_at((cx, cy - 0.25 * d.height, z1 + 0.2 * d.height), (cx, cy, z0), fov=45)
    frames: dict = {}
    # First frames: nothing cached, every drawn node's mesh built and uploaded.
    top = Camera.look_at((cx, cy - 1e-3 * d.height, z1 + 1.3 * d.height), (cx, cy, z0), fov=45)
    firsts = {}
    for label, camera in (("first_frame", cam), ("first_overview", top)):
        with Engine(q) as eng:
            t0 = time.perf_counter()
            f = eng.render(camera, (1280, 720), Cut(alpha=1.0))
            firsts[label] = {k: f.stats[k] for k in KEYS}
            firsts[label]["frame_ms"] = round((time.perf_counter() - t0) * 1e3, 3)
            cut = eng.source.last_cut
    # The overview's meshes built alone (no GPU).
    mesh_ms = []
    for _ in range(3):
        t0 = time.perf_counter()
        node_meshes(q, cut.rows, cut.midpoints, cut.keep, cut.inserted)
        mesh_ms.append((time.perf_counter() - t0) * 1e3)
    with Engine(q) as eng:
        for alpha in (1.0, 4.0):
            eng.render(cam, (1280, 720), Cut(alpha=alpha))
            f = eng.render(cam, (1280, 720), Cut(alpha=alpha))
            frames[f"alpha={alpha:g}"] = {k: f.stats[k] for k in KEYS}
        f = eng.render(cam, (1280, 720), Cut(full_resolution=True))
        frames["full_resolution"] = {k: f.stats[k] for k in KEYS if k != "max_alpha"}
        fs = eng.frame_state(cam, (1280, 720))
    lam = pixels_per_radian(fs)
    visible = boxes_in_frustum(q.bboxes, fs.planes)
    times = []
    selector = LodSelector(q)
    for _ in range(10):
        t0 = time.perf_counter()
        selector.cut(fs.eye, lam, 1.0, fs.scale, visible)
        times.append((time.perf_counter() - t0) * 1e3)
    return {
        "points": len(q.points),
        "nodes": len(q),
        "build_seconds": round(build, 4),
        "save_seconds": round(save, 4),
        "load_seconds": round(load, 4),
        "file_bytes": nbytes,
        "frames_1280x720": frames,
        "first_frames_1280x720": firsts,
        "mesh_build_ms": {"nodes": len(cut.rows), "min": round(min(mesh_ms), 3)},
        "lod_cut_ms": {"min": round(min(times), 3), "median": round(statistics.median(times), 3)},
    }


def main() -> None:
    import tempfile

    out = {"machine": platform.platform(), "delta": 50}
    with tempfile.TemporaryDirectory() as tmp:
        for label, ground in (("ground", True), ("all", False)):
            out[label] = case(ground, Path(tmp))
            print(json.dumps({label: out[label]}, indent=1))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "point_quadtree_render.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
