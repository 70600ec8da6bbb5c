"""Peak memory of a raster terrain opened windowed vs read into memory, side by side in one run.

For each size (generated, tiled 256 × 256 float32 GeoTIFFs with nodata, written strip by strip)
and each mode, a fresh process opens the raster, asks z_range, reads ``--windows`` random
512 × 512 windows through ``points(rect)`` and evaluates h_T at 100,000 random points; it
reports seconds per step and its peak RSS (VmHWM) minus the RSS after the imports. Modes
alternate per size so both see the same page-cache state. Results in
benchmarks/results/windowed.json.

    python benchmarks/bench_windowed.py [--sizes 4096 8192] [--windows 20]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def _rss_kb(field: str) -> int:
    """VmRSS or VmHWM of this process, kB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    return 0


def write_dem(path: Path, n: int) -> None:
    """A smooth n × n float32 DEM with nodata holes, tiled 256², written 256 rows at a time."""
    import rasterio
    from affine import Affine
    from rasterio.windows import Window

    profile = dict(
        driver="GTiff",
        width=n,
        height=n,
        count=1,
        dtype="float32",
        nodata=-9999.0,
        tiled=True,
        blockxsize=256,
        blockysize=256,
        transform=Affine(1.0, 0, 500000.0, 0, -1.0, 4200000.0 + n),
        crs="EPSG:32610",
        BIGTIFF="IF_SAFER",
    )
    with rasterio.open(path, "w", **profile) as ds:
        for r0 in range(0, n, 256):
            yy, xx = np.mgrid[r0 : r0 + 256, 0:n].astype(np.float32)
            z = 500 + 200 * np.sin(xx / 300) * np.cos(yy / 450) + 10 * np.sin(xx / 7 + yy / 11)
            z[:, (np.arange(n) % 1000) < 20] = -9999.0
            ds.write(z.astype(np.float32), 1, window=Window(0, r0, n, 256))


def run_one(path: str, windowed: bool, windows: int) -> dict:
    """In this process: open, z range, windows, height_at; seconds and peak RSS."""
    import approxtree as at

    base = _rss_kb("VmRSS")
    t0 = time.perf_counter()
    grid = at.open_terrain(path, windowed=windowed)
    t1 = time.perf_counter()
    z_range = grid.z_range
    t2 = time.perf_counter()
    rng = np.random.default_rng(0)
    rows, cols = grid.shape
    n_points = 0
    for _ in range(windows):
        r0, c0 = int(rng.integers(0, rows - 512)), int(rng.integers(0, cols - 512))
        n_points += len(grid.points(grid.rect_of(r0, r0 + 511, c0, c0 + 511)))
    t3 = time.perf_counter()
    d = grid.domain
    x = rng.uniform(d.xmin, d.xmax, 100_000)
    y = rng.uniform(d.ymin, d.ymax, 100_000)
    h = grid.height_at(x, y)
    t4 = time.perf_counter()
    return {
        "windowed": grid.is_windowed,
        "open_s": round(t1 - t0, 4),
        "z_range_s": round(t2 - t1, 4),
        "windows_s": round(t3 - t2, 4),
        "height_at_s": round(t4 - t3, 4),
        "peak_rss_mb": round((_rss_kb("VmHWM") - base) / 1024, 1),
        "z_range": list(z_range),
        "window_points": n_points,
        "height_at_valid": int(np.isfinite(h).sum()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[4096, 8192])
    parser.add_argument("--windows", type=int, default=20)
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        path, windowed, windows = args.child
        print(json.dumps(run_one(path, windowed == "1", int(windows))))
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.sizes:
            path = Path(tmp) / f"dem_{n}.tif"
            t = time.perf_counter()
            write_dem(path, n)
            write_s = time.perf_counter() - t
            for windowed in (True, False):
                cmd = [sys.executable, __file__, "--child", str(path), str(int(windowed))]
                cmd.append(str(args.windows))
                out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
                row = {"size": n, "band_mb": round(n * n * 4 / 2**20, 1), "write_s": write_s}
                row.update(json.loads(out.strip().splitlines()[-1]))
                rows.append(row)
                print(json.dumps(row), flush=True)
            path.unlink()
    RESULTS.mkdir(exist_ok=True)
    result = {
        "machine": os.uname().machine,
        "cpus": os.cpu_count(),
        "windows": args.windows,
        "rows": rows,
    }
    (RESULTS / "windowed.json").write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
