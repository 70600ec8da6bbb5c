"""Image bake at any size: peak memory and time of ``bake --image`` vs ``gdalwarp`` (issue 30).

For each --sizes N: an N × N RGB COG in EPSG:4326 over the NC DEM (ZSTD: lossless, since the
GDAL of the gdalwarp command and rasterio's decode JPEG differently, by up to 9 levels) is
generated block by block (a tiled GeoTIFF written 512² at a time, then GDAL's COG driver,
which streams),
then, each a fresh process timed with its own peak RSS (GNU time's %M):

- ours: ``approxtree bake elev_ned_30m.tif --image IMG --shading none`` (the texel: the
  image's cell in the DEM's CRS), the whole pyramid (level 0 and its halvings, ZSTD tiles,
  checksums);
- gdalwarp: ``gdalwarp -r bilinear -dstalpha`` of the same image onto the same grid (level
  0's, read from pyramid.json), tiled ZSTD GeoTIFF: level 0 only, no pyramid.

Level 0 of both is then compared on sampled 512² windows (max difference per channel). Results
in benchmarks/results/image.json (one entry per size) and a plot beside it (image.png: peak
RSS and seconds of both against level 0's width). Sizes run smallest first; memory is flat
when the peak RSS of ours does not grow with N.

    python benchmarks/bench_image.py [--sizes 4096 8192 16384 32768] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine
from rasterio.warp import transform_bounds
from rasterio.windows import Window

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DEM = (
    Path(os.environ.get("APPROXTREE_DATA", ROOT.parent / "shared" / "data")) / "nc/elev_ned_30m.tif"
)
BLOCK = 512


def make_image(path: Path, size: int) -> dict:
    """Write an N × N RGB COG in EPSG:4326 over the DEM, block by block; its figures."""
    from rasterio.shutil import copy

    with rasterio.open(DEM) as dem:
        west, south, east, north = transform_bounds(dem.crs, "EPSG:4326", *dem.bounds)
    # A margin of 1 % around the DEM so the whole lattice is inside the image.
    dx, dy = (east - west) * 0.01, (north - south) * 0.01
    west, east, south, north = west - dx, east + dx, south - dy, north + dy
    transform = Affine((east - west) / size, 0, west, 0, -(north - south) / size, north)
    t0 = time.perf_counter()
    tiled = path.with_suffix(".tiled.tif")
    profile = {
        "driver": "GTiff",
        "width": size,
        "height": size,
        "count": 3,
        "dtype": "uint8",
        "crs": "EPSG:4326",
        "transform": transform,
        "tiled": True,
        "blockxsize": BLOCK,
        "blockysize": BLOCK,
        "compress": "zstd",
        "zstd_level": 1,
        "photometric": "rgb",
        "bigtiff": "yes",
    }
    rng = np.random.default_rng(30)
    yy, xx = np.mgrid[0:BLOCK, 0:BLOCK].astype(np.float32)
    with rasterio.open(tiled, "w", **profile) as ds:
        for r0 in range(0, size, BLOCK):
            for c0 in range(0, size, BLOCK):
                # Smooth fields of the image's coordinates (fields, roads), a little noise.
                y, x = yy + r0, xx + c0
                r = 120 + 80 * np.sin(x / 700.0) * np.cos(y / 900.0)
                g = 130 + 70 * np.sin((x + y) / 500.0)
                b = 100 + 60 * np.cos(x / 300.0 - y / 1100.0)
                noise = rng.normal(0, 8, (3, BLOCK, BLOCK)).astype(np.float32)
                block = np.clip(np.stack([r, g, b]) + noise, 0, 255).astype(np.uint8)
                ds.write(block, window=Window(c0, r0, BLOCK, BLOCK))
    generated = time.perf_counter() - t0
    copy(tiled, path, driver="COG", compress="ZSTD", level=1, bigtiff="YES",
         num_threads="ALL_CPUS")  # fmt: skip
    tiled.unlink()
    return {
        "size": size,
        "bytes": path.stat().st_size,
        "generate_seconds": round(generated, 2),
        "cog_seconds": round(time.perf_counter() - t0 - generated, 2),
    }


def timed(cmd: list[str]) -> dict:
    """Run ``cmd`` in a fresh process: its seconds and peak RSS (MB, GNU time's %M). Not
    ``os.wait4`` of a child of this process: Linux carries the forked parent's peak RSS (this
    one's, after generating the image) into the child's across exec."""
    with tempfile.NamedTemporaryFile(suffix=".rss") as rss:
        t0 = time.perf_counter()
        run = subprocess.run(
            ["/usr/bin/time", "-f", "%M", "-o", rss.name, *cmd], capture_output=True, text=True
        )
        seconds = time.perf_counter() - t0
        if run.returncode:
            raise RuntimeError(f"{cmd[:3]} failed ({run.returncode}): {run.stderr[-2000:]}")
        peak_kb = int(Path(rss.name).read_text().split()[-1])
    return {"seconds": round(seconds, 2), "peak_rss_mb": round(peak_kb / 1024, 1),
            "stdout": run.stdout}  # fmt: skip


def compare(pyramid: Path, warped: Path, windows: int = 16) -> list[int]:
    """Max |ours − gdalwarp| per channel (R, G, B, A) of level 0 on sampled 512² windows."""
    rng = np.random.default_rng(0)
    worst = np.zeros(4, dtype=np.int64)
    with rasterio.open(pyramid / "level0.tif") as a, rasterio.open(warped) as b:
        for _ in range(windows):
            r0 = int(rng.integers(0, max(1, a.height - 512)))
            c0 = int(rng.integers(0, max(1, a.width - 512)))
            w = Window(c0, r0, min(512, a.width - c0), min(512, a.height - r0))
            x, y = a.read(window=w).astype(np.int64), b.read(window=w).astype(np.int64)
            worst = np.maximum(worst, np.abs(x - y).max(axis=(1, 2)))
    return [int(v) for v in worst]


def run(size: int, work: Path) -> dict:
    """Generate the image of ``size``, bake it and gdalwarp it; the figures."""
    image = work / f"image_{size}.tif"
    entry = make_image(image, size)
    print(f"{size}²: image {entry['bytes'] / 1e6:.0f} MB in "
          f"{entry['generate_seconds'] + entry['cog_seconds']:.0f} s", flush=True)  # fmt: skip
    pyramid = work / f"pyramid_{size}"
    ours = timed(
        [sys.executable, "-m", "approxtree", "bake", str(DEM), "--image", str(image),
         "--shading", "none", "--out", str(pyramid), "--quiet", "--json", "--overwrite"]
    )  # fmt: skip
    figures = json.loads(ours.pop("stdout"))
    meta = json.loads((pyramid / "pyramid.json").read_text())
    lv = meta["levels"][0]
    t = Affine(*lv["transform"][:6])
    cols, rows = int(lv["width"]), int(lv["height"])
    x0, y1 = t.c, t.f
    x1, y0 = x0 + t.a * cols, y1 + t.e * rows
    warped = work / f"gdalwarp_{size}.tif"
    theirs = timed(
        ["gdalwarp", "-q", "-overwrite", "-r", "bilinear", "-dstalpha", "-t_srs", meta["crs"],
         "-te", *map(repr, (x0, y0, x1, y1)), "-ts", str(cols), str(rows),
         "-co", "TILED=YES", "-co", "COMPRESS=ZSTD", "-co", "BIGTIFF=IF_SAFER",
         str(image), str(warped)]
    )  # fmt: skip
    theirs.pop("stdout")
    ours.update(levels=figures["levels"], bytes=figures["bytes"])
    theirs["bytes"] = warped.stat().st_size
    entry.update(
        lattice=[cols, rows],
        texels=cols * rows,
        ours=ours,
        gdalwarp=theirs,
        max_difference_rgba=compare(pyramid, warped),
    )
    print(f"{size}²: lattice {cols} × {rows}; ours {ours['seconds']} s, "
          f"{ours['peak_rss_mb']} MB; gdalwarp {theirs['seconds']} s, "
          f"{theirs['peak_rss_mb']} MB; max diff {entry['max_difference_rgba']}",
          flush=True)  # fmt: skip
    shutil.rmtree(pyramid)
    warped.unlink()
    image.unlink()
    return entry


def plot(results: dict, path: Path) -> None:
    """Peak RSS and seconds of ours and gdalwarp against level 0's width (texels)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = results["runs"]
    widths = [r["lattice"][0] for r in runs]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for side, label in (("ours", "approxtree bake --image (pyramid)"), ("gdalwarp", "gdalwarp")):
        a.plot(widths, [r[side]["peak_rss_mb"] for r in runs], "o-", label=label)
        b.plot(widths, [r[side]["seconds"] for r in runs], "o-", label=label)
    for ax, what in ((a, "peak RSS (MB)"), (b, "seconds")):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("level 0 width (texels)")
        ax.set_ylabel(what)
        ax.legend()
    a.set_ylim(bottom=0)
    fig.suptitle("Image bake (N × N RGB COG, EPSG:4326 → 32119) vs gdalwarp")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[4096, 8192, 16384, 32768])
    parser.add_argument("--keep", type=Path, default=None, help="Work folder (default: a temp)")
    parser.add_argument("--out", type=Path, default=RESULTS / "image.json")
    args = parser.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_image_"))
    work.mkdir(parents=True, exist_ok=True)
    results = {
        "machine": {"cpus": os.cpu_count(), "gdal_cli": _gdal_version()},
        "note": "ours: the whole pyramid (level 0 + halvings); gdalwarp: level 0 only",
        "runs": [],
    }
    for size in sorted(args.sizes):
        results["runs"].append(run(size, work))
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=2) + "\n")
        plot(results, args.out.with_suffix(".png"))
    if args.keep is None:
        shutil.rmtree(work, ignore_errors=True)
    print(f"wrote {args.out}")


def _gdal_version() -> str:
    run = subprocess.run(["gdalwarp", "--version"], capture_output=True, text=True)
    return run.stdout.strip()


if __name__ == "__main__":
    main()
