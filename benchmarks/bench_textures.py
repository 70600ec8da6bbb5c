"""Texture benchmarks, side by side in one run.

1. Bake: the Horn hillshade of a fractal grid (default 8192²) with the OpenGL offscreen bake
   (tiled, ``gl_bake``), the numpy/numba kernel and ``gdaldem hillshade`` on the same grid.
   End to end (read GeoTIFF → shade → write GeoTIFF) for all three, plus the compute step
   alone for ours. Medians of --repeats runs after one warm-up (numba compile, GL start).
2. Render: frame time and texture switches with and without ancestor texture sharing, for a
   fractal tree with a baked hillshade pyramid, over several views and thresholds (medians
   of --frames frames each).

Results: benchmarks/results/textures.json and textures.png.

    python benchmarks/bench_textures.py [--size 8192] [--repeats 3] [--frames 5]
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine

RESULTS = Path(__file__).resolve().parent / "results"


def write_float(path: Path, z: np.ndarray, cell: float) -> None:
    rows, cols = z.shape
    profile = {
        "driver": "GTiff",
        "width": cols,
        "height": rows,
        "count": 1,
        "dtype": "float32",
        "transform": Affine(cell, 0, 0, 0, -cell, rows * cell),
    }
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(z.astype(np.float32), 1)


def write_shade(path: Path, grid, shade: np.ndarray) -> None:
    profile = {
        "driver": "GTiff",
        "width": grid.width,
        "height": grid.height,
        "count": 1,
        "dtype": "uint8",
        "transform": grid.transform,
        "nodata": 0,
    }
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(shade, 1)


def ours(src: Path, dst: Path, gl_ctx) -> tuple[float, float]:
    """(end-to-end seconds, compute seconds) of read → shade (GL or numpy) → write."""
    import approxtree as at
    from approxtree.textures import TopographicShading
    from approxtree.textures.gl_bake import GLTopographicShading

    t0 = time.perf_counter()
    grid = at.open_terrain(src)
    t1 = time.perf_counter()
    shading = (
        GLTopographicShading(grid, context=gl_ctx)
        if gl_ctx is not None
        else TopographicShading(grid)
    )
    shade = shading.shade()
    t2 = time.perf_counter()
    write_shade(dst, grid, shade)
    return time.perf_counter() - t0, t2 - t1


def gdaldem(src: Path, dst: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run(["gdaldem", "hillshade", "-q", str(src), str(dst)], check=True)
    return time.perf_counter() - t0


def bench_bake(size: int, repeats: int, ctx) -> dict:
    from approxtree.datasets import fractal_heights

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        src = tmp / "dem.tif"
        write_float(src, fractal_heights(size, seed=1), 10.0)
        ours(src, tmp / "warm_gl.tif", ctx)
        ours(src, tmp / "warm_np.tif", None)
        runs: dict[str, list[float]] = {k: [] for k in ("gl", "gl_compute", "numpy")}
        runs.update(numpy_compute=[], gdaldem=[])
        for i in range(repeats):
            total, comp = ours(src, tmp / f"gl{i}.tif", ctx)
            runs["gl"].append(total)
            runs["gl_compute"].append(comp)
            total, comp = ours(src, tmp / f"np{i}.tif", None)
            runs["numpy"].append(total)
            runs["numpy_compute"].append(comp)
            runs["gdaldem"].append(gdaldem(src, tmp / f"gdal{i}.tif"))
            print(f"bake run {i}: " + ", ".join(f"{k} {v[-1]:.2f} s" for k, v in runs.items()))
        with (
            rasterio.open(tmp / "gl0.tif") as a,
            rasterio.open(tmp / "np0.tif") as b,
            rasterio.open(tmp / "gdal0.tif") as c,
        ):
            ga, nb, gc = (ds.read(1).astype(np.int64) for ds in (a, b, c))
    med = {k: statistics.median(v) for k, v in runs.items()}
    return {
        "size": size,
        "medians_seconds": med,
        "ratio_gl_over_gdaldem": med["gl"] / med["gdaldem"],
        "ratio_numpy_over_gdaldem": med["numpy"] / med["gdaldem"],
        "ratio_gl_over_numpy_compute": med["gl_compute"] / med["numpy_compute"],
        "max_abs_diff_gl_vs_numpy": int(np.abs(ga - nb).max()),
        "max_abs_diff_gl_vs_gdaldem": int(np.abs(ga - gc).max()),
        "max_abs_diff_numpy_vs_gdaldem": int(np.abs(nb - gc).max()),
        "runs": runs,
    }


def bench_render(frames: int, ctx) -> dict:
    from approxtree import ApproximationTree
    from approxtree.datasets import fractal_terrain
    from approxtree.render import Camera, Cut, Engine, overview_camera
    from approxtree.textures import TexturePyramid, TopographicShading

    terrain = fractal_terrain(2049, seed=7, relief=600.0)
    tree = ApproximationTree.build(terrain, epsilon=1.0, max_points=33 * 33, progress=False)
    c = terrain.domain.center
    views = {
        "overview": overview_camera(tree.bboxes[0], np.ones(3)),
        "oblique": Camera.look_at((c[0] - 2000, c[1] - 9000, 3000), (c[0], c[1], 0), fov=60),
        "low": Camera.look_at((c[0], c[1] - 6000, 900), (c[0], c[1] + 4000, 0), fov=60),
    }
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        pyramid = TexturePyramid.build(TopographicShading(terrain), tmp, max_texture_size=256)
        with Engine(tree, textures=pyramid, context=ctx, offscreen=True) as eng:
            for name, cam in views.items():
                for alpha, gamma in ((4.0, 2.0), (1.0, 2.0), (0.5, 8.0)):
                    row = {"view": name, "alpha": alpha, "gamma": gamma}
                    for share in (True, False):
                        cut = Cut(alpha, gamma, share_textures=share)
                        eng.render(cam, (1280, 720), cut)
                        ms, draw = [], []
                        for _ in range(frames):
                            t0 = time.perf_counter()
                            f = eng.render(cam, (1280, 720), cut)
                            ms.append((time.perf_counter() - t0) * 1e3)
                            draw.append(f.stats["draw_ms"])
                        key = "shared" if share else "own"
                        row[key] = {
                            "frame_ms_median": statistics.median(ms),
                            "draw_ms_median": statistics.median(draw),
                            "texture_switches": f.stats["texture_switches"],
                            "patches": f.stats["patches"],
                            "max_gamma": f.stats["max_gamma"],
                        }
                    print(
                        f"{name} α={alpha} γ={gamma}: switches {row['shared']['texture_switches']}"
                        f" vs {row['own']['texture_switches']}, frame "
                        f"{row['shared']['frame_ms_median']:.1f} vs "
                        f"{row['own']['frame_ms_median']:.1f} ms"
                    )
                    out.append(row)
    return {"terrain": "fractal 2049², pyramid 256-texel limit", "size": [1280, 720], "rows": out}


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5))
    med = report["bake"]["medians_seconds"]
    names = ["gl", "numpy", "gdaldem", "gl_compute", "numpy_compute"]
    a.bar(names, [med[n] for n in names], color=["C0", "C1", "C2", "C0", "C1"])
    a.set_ylabel("seconds (median)")
    a.set_title(f"Hillshade bake {report['bake']['size']}²")
    rows = report["render"]["rows"]
    labels = [f"{r['view']}\nα{r['alpha']} γ{r['gamma']}" for r in rows]
    x = np.arange(len(rows))
    b.bar(x - 0.2, [r["shared"]["texture_switches"] for r in rows], 0.4, label="shared")
    b.bar(x + 0.2, [r["own"]["texture_switches"] for r in rows], 0.4, label="own patches")
    b.set_xticks(x, labels, fontsize=7)
    b.set_ylabel("texture switches per frame")
    b.set_title("Ancestor texture sharing")
    b.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=8192)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--frames", type=int, default=5)
    args = parser.parse_args()
    if shutil.which("gdaldem") is None:
        raise SystemExit("gdaldem not found: install the Debian package gdal-bin")
    from approxtree.render.context import create_context

    RESULTS.mkdir(exist_ok=True)
    ctx = create_context()
    try:
        report = {
            "gl_renderer": ctx.info.get("GL_RENDERER"),
            "bake": bench_bake(args.size, args.repeats, ctx),
            "render": bench_render(args.frames, ctx),
        }
    finally:
        ctx.release()
    (RESULTS / "textures.json").write_text(json.dumps(report, indent=2))
    plot(report, RESULTS / "textures.png")
    summary = {k: v for k, v in report["bake"].items() if k != "runs"}
    print(json.dumps({"gl_renderer": report["gl_renderer"], "bake": summary}, indent=2))


if __name__ == "__main__":
    main()
