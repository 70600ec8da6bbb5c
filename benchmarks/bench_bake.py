"""Hillshade bake time on a fractal grid vs ``gdaldem hillshade``, side by side in one run.

Both sides do the same end-to-end job: read a float32 GeoTIFF, compute the Horn hillshade and
write a byte GeoTIFF. Our side also reports the compute step alone. Medians of --repeats runs
(after one warm-up run that compiles the numba kernels); results in
benchmarks/results/bake.json.

    python benchmarks/bench_bake.py [--size 8192] [--repeats 3]
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


def ours_end_to_end(src: Path, dst: Path) -> tuple[float, float]:
    """(total seconds, compute seconds) of read → TopographicShading → write."""
    import approxtree as at
    from approxtree.textures import TopographicShading

    t0 = time.perf_counter()
    grid = at.open_terrain(src)
    t1 = time.perf_counter()
    shade = TopographicShading(grid).shade()
    t2 = time.perf_counter()
    profile = {
        "driver": "GTiff",
        "width": grid.width,
        "height": grid.height,
        "count": 1,
        "dtype": "uint8",
        "transform": grid.transform,
        "nodata": 0,
    }
    with rasterio.open(dst, "w", **profile) as ds:
        ds.write(shade, 1)
    return time.perf_counter() - t0, t2 - t1


def gdaldem_end_to_end(src: Path, dst: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run(["gdaldem", "hillshade", "-q", str(src), str(dst)], check=True)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=8192)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if shutil.which("gdaldem") is None:
        raise SystemExit("gdaldem not found: install the Debian package gdal-bin")
    from approxtree.datasets import fractal_heights

    RESULTS.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "dem.tif"
        z = fractal_heights(args.size, seed=1)
        with rasterio.open(
            src,
            "w",
            driver="GTiff",
            width=args.size,
            height=args.size,
            count=1,
            dtype="float32",
            transform=Affine(10, 0, 0, 0, -10, args.size * 10),
        ) as ds:
            ds.write(z, 1)
        del z
        ours_end_to_end(src, Path(tmp) / "warm.tif")
        ours, compute, gdal = [], [], []
        for i in range(args.repeats):
            total, comp = ours_end_to_end(src, Path(tmp) / f"ours{i}.tif")
            ours.append(total)
            compute.append(comp)
            gdal.append(gdaldem_end_to_end(src, Path(tmp) / f"gdal{i}.tif"))
            print(
                f"run {i}: ours {total:.2f} s (compute {comp:.2f} s), gdaldem {gdal[-1]:.2f} s",
                flush=True,
            )
        with (
            rasterio.open(Path(tmp) / "ours0.tif") as a,
            rasterio.open(Path(tmp) / "gdal0.tif") as b,
        ):
            diff = np.abs(a.read(1).astype(int) - b.read(1).astype(int)).max()
    report = {
        "benchmark": "Horn hillshade, read GeoTIFF → shade → write GeoTIFF",
        "size": args.size,
        "ours_seconds_median": statistics.median(ours),
        "ours_compute_seconds_median": statistics.median(compute),
        "gdaldem_seconds_median": statistics.median(gdal),
        "time_ratio_ours_over_gdaldem": statistics.median(ours) / statistics.median(gdal),
        "max_abs_difference_grey_levels": int(diff),
        "runs": {"ours": ours, "ours_compute": compute, "gdaldem": gdal},
    }
    (RESULTS / "bake.json").write_text(json.dumps(report, indent=2))
    print(json.dumps({k: v for k, v in report.items() if k != "runs"}, indent=2))


if __name__ == "__main__":
    main()
