"""Quantized-mesh tiles against a baseline checkout: true errors at the data points, bytes, speed.

Cases: the NC DEM of ../shared/data (500 × 450, 30 m, EPSG:32119) and Mt Washington (SRTM 3″,
summit inside) warped to UTM 19N at 30 m (rasterio, bilinear; a steep DEM in another CRS). Each
case is written by this checkout and by a baseline checkout (``--baseline``, e.g. /work/main,
run with its own .venv) in fresh processes, alternating run by run (``--repeats``), so both
meet the same machine load; times are medians (the process start and the DEM read excluded:
the seconds ``write_quantized_mesh`` takes). The deepest level is made to ``--leaf-error``.

Errors are measured here, independently of either writer: each tile is read with the
project's reader (``io.quantized_mesh``, quantized-mesh-tile), its (u, v) recovered from its
bounds, and the decoded TIN interpolated linearly in (u, v) (matplotlib's triangle finder)
at every data point of the DEM (valid cell centres, through pyproj) in its closed lon/lat
square. Per level: the worst error against the level's error (the leaf level's: the leaf
error), the tiles over it by more than half a height-quantization step, and the share of the
(tile, point) pairs over it.

    python benchmarks/bench_quantized_mesh.py [--baseline /work/main] [--repeats 3]
        [--leaf-error 1] [--data-dir DIR]

Results: benchmarks/results/quantized_mesh.json and quantized_mesh.png.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
HERE = Path(__file__).resolve().parents[1]
DEFAULT_DATA = HERE.parent / "shared" / "data"
QMAX = 32767

#: Run in the checkout's own interpreter: writes the tiles, prints the figures as JSON.
DRIVER = """
import json, sys, time
from approxtree.io import open_terrain
from approxtree.tiles import write_quantized_mesh
terrain = open_terrain(sys.argv[1])
t0 = time.perf_counter()
figures = write_quantized_mesh(terrain, sys.argv[2], leaf_error=float(sys.argv[3]))
seconds = time.perf_counter() - t0
rows = [{k: r[k] for k in ("level", "x", "y", "bytes", "vertices")} for r in figures["results"]]
print(json.dumps({"seconds": seconds, "levels": figures["levels"], "tiles": rows}))
"""


def mountain(data_dir: Path, out: Path) -> Path:
    """Mt Washington (SRTM N44W072, 150 × 150 cells around the summit) warped to UTM 19N at
    30 m into ``out`` (GeoTIFF, NaN outside the warped footprint)."""
    import rasterio
    from rasterio.warp import Resampling, calculate_default_transform, reproject
    from rasterio.windows import Window, bounds

    with rasterio.open(data_dir / "srtm" / "N44W072.hgt") as ds:
        window = Window(760, 800, 150, 150)
        src = ds.read(1, window=window).astype(np.float32)
        transform, width, height = calculate_default_transform(
            ds.crs, "EPSG:32619", 150, 150, *bounds(window, ds.transform), resolution=30.0
        )
        dst = np.full((height, width), np.nan, dtype=np.float32)
        reproject(
            src,
            dst,
            src_transform=ds.window_transform(window),
            src_crs=ds.crs,
            dst_transform=transform,
            dst_crs="EPSG:32619",
            resampling=Resampling.bilinear,
            dst_nodata=np.nan,
        )
    profile = {"driver": "GTiff", "width": width, "height": height, "count": 1}
    profile.update(dtype="float32", crs="EPSG:32619", transform=transform, nodata=np.nan)
    with rasterio.open(out, "w", **profile) as ds:
        ds.write(dst, 1)
    return out


def run(python: Path, cwd: Path, dem: Path, out: Path, leaf_error: float) -> dict:
    """One tileset written by the checkout at ``cwd`` with ``python``: its figures."""
    proc = subprocess.run(
        [str(python), "-c", DRIVER, str(dem), str(out), str(leaf_error)],
        cwd=cwd,
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"{python} failed on {dem}:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def data_points(dem: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """lon, lat, z (n,) of every valid cell centre of the DEM."""
    import rasterio
    from pyproj import Transformer

    with rasterio.open(dem) as ds:
        z = ds.read(1, masked=True).astype(np.float64).filled(np.nan)
        rr, cc = np.nonzero(np.isfinite(z))
        x, y = rasterio.transform.xy(ds.transform, rr, cc)
        to = Transformer.from_crs(ds.crs, "EPSG:4326", always_xy=True)
        lon, lat = to.transform(np.asarray(x), np.asarray(y))
    return np.asarray(lon), np.asarray(lat), z[rr, cc]


def true_errors(folder: Path, tiles: list[dict], points, leaf_error: float) -> dict:
    """Per level: worst error / limit, tiles over (beyond half a quantum), points over."""
    import matplotlib.tri as mtri

    from approxtree.io.quantized_mesh import read_quantized_mesh, tile_bounds

    lon, lat, z = points
    maxzoom = max(t["level"] for t in tiles)
    levels: dict[int, dict] = {}
    for t in tiles:
        level = t["level"]
        limit = _level_error(level)
        if level == maxzoom:
            limit = min(limit, leaf_error)
        west, south, east, north = tile_bounds(level, t["x"], t["y"])
        path = folder / str(level) / str(t["x"]) / f"{t['y']}.terrain"
        tin = read_quantized_mesh(path, bounds=(west, south, east, north))
        u = np.rint((tin.vertices[:, 0] - west) / (east - west) * QMAX)
        v = np.rint((tin.vertices[:, 1] - south) / (north - south) * QMAX)
        h = tin.vertices[:, 2]
        sel = (lon >= west) & (lon <= east) & (lat >= south) & (lat <= north)
        pu = (lon[sel] - west) / (east - west) * QMAX
        pv = (lat[sel] - south) / (north - south) * QMAX
        interp = mtri.LinearTriInterpolator(mtri.Triangulation(u, v, tin.triangles), h)
        approx = np.asarray(interp(pu, pv).filled(np.nan))
        # Points the finder misses exactly on the tile's border: nudged a hair inside.
        miss = ~np.isfinite(approx)
        if miss.any():
            nu = np.clip(pu[miss], 1e-6, QMAX - 1e-6)
            nv = np.clip(pv[miss], 1e-6, QMAX - 1e-6)
            approx[miss] = np.asarray(interp(nu, nv).filled(np.nan))
        err = np.abs(approx - z[sel])
        quantum = (h.max() - h.min()) / QMAX
        row = levels.setdefault(
            level,
            {"limit": limit, "tiles": 0, "worst": 0.0, "tiles_over": 0, "points": 0, "over": 0},
        )
        row["tiles"] += 1
        row["bytes"] = row.get("bytes", 0) + t["bytes"]
        if len(err):
            worst = float(np.nanmax(err))
            row["worst"] = max(row["worst"], worst)
            row["tiles_over"] += int(worst > limit + 0.5 * quantum + 1e-6)
            row["points"] += len(err)
            row["over"] += int((err > limit + 0.5 * quantum + 1e-6).sum())
    out = {}
    for level, row in sorted(levels.items()):
        out[str(level)] = {
            "tiles": row["tiles"],
            "bytes_per_tile_mean": round(row["bytes"] / row["tiles"], 1),
            "limit_m": round(row["limit"], 4),
            "worst_error_m": round(row["worst"], 4),
            "worst_ratio": round(row["worst"] / row["limit"], 4),
            "tiles_over": row["tiles_over"],
            "points_over_percent": round(100.0 * row["over"] / max(row["points"], 1), 3),
        }
    return out


def _level_error(level: int) -> float:
    """CesiumJS's level error of the geographic tiling (as tiles.geographic.level_error)."""
    return 6378137.0 * 2.0 * np.pi * 0.25 / (65 * 2) / 2**level


def run_case(name: str, dem: Path, args: argparse.Namespace, tmp: Path) -> dict:
    """Both checkouts on one DEM, interleaved; figures and true errors of each."""
    impls = {
        "this": (Path(sys.executable), HERE),
        "baseline": (args.baseline / ".venv" / "bin" / "python", args.baseline),
    }
    times: dict[str, list[float]] = {k: [] for k in impls}
    last: dict[str, dict] = {}
    for i in range(args.repeats):
        for key, (python, cwd) in impls.items():
            out = tmp / f"{name}-{key}-{i}"
            last[key] = run(python, cwd, dem, out, args.leaf_error)
            last[key]["folder"] = out
            times[key].append(last[key]["seconds"])
    points = data_points(dem)
    case = {"case": name, "dem": str(dem), "data_points": len(points[2])}
    for key in impls:
        fig = last[key]
        n = len(fig["tiles"])
        seconds = statistics.median(times[key])
        case[key] = {
            "tiles": n,
            "levels": fig["levels"],
            "seconds": [round(t, 3) for t in times[key]],
            "tiles_per_second": round(n / seconds, 2),
            "bytes_per_tile_mean": round(sum(t["bytes"] for t in fig["tiles"]) / n, 1),
            "vertices": sum(t["vertices"] for t in fig["tiles"]),
            "levels_detail": true_errors(fig["folder"], fig["tiles"], points, args.leaf_error),
        }
    return case


def plot(report: dict, out: Path) -> None:
    """Per case: bytes per tile and worst true error / limit per level, both checkouts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = report["cases"]
    fig, axes = plt.subplots(2, len(cases), figsize=(5.5 * len(cases), 7), squeeze=False)
    for j, case in enumerate(cases):
        for key, style in (("baseline", "s--"), ("this", "o-")):
            rows = case[key]["levels_detail"]
            levels = [int(k) for k in rows]
            axes[0, j].plot(
                levels, [r["bytes_per_tile_mean"] for r in rows.values()], style, label=key
            )
            axes[1, j].plot(levels, [r["worst_ratio"] for r in rows.values()], style, label=key)
        axes[1, j].axhline(1.0, color="grey", ls=":", label="level's error")
        axes[0, j].set(title=case["case"], ylabel="bytes per tile (gzip)", yscale="log")
        axes[1, j].set(xlabel="level", ylabel="worst error at data points / limit", yscale="log")
        for ax in axes[:, j]:
            ax.legend()
    fig.suptitle(f"leaf error {report['args']['leaf_error']} m, {report['machine']['cpus']} CPUs")
    fig.tight_layout()
    fig.savefig(out, dpi=100)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", type=Path, default=Path("/work/main"))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--leaf-error", type=float, default=1.0)
    ap.add_argument("--data-dir", type=Path, default=DEFAULT_DATA)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-qm-") as tmp:
        tmp = Path(tmp)
        dems = [("nc", args.data_dir / "nc" / "elev_ned_30m.tif")]
        dems.append(("mt_washington_utm", mountain(args.data_dir, tmp / "mountain.tif")))
        cases = []
        for name, dem in dems:
            cases.append(run_case(name, dem, args, tmp))
            print(json.dumps({k: v for k, v in cases[-1].items()}, default=str), flush=True)
    RESULTS.mkdir(exist_ok=True)
    report = {
        "benchmark": "quantized_mesh",
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
        "args": {k: str(v) for k, v in vars(args).items()},
        "cases": cases,
    }
    (RESULTS / "quantized_mesh.json").write_text(json.dumps(report, indent=1, default=str))
    plot(report, RESULTS / "quantized_mesh.png")


if __name__ == "__main__":
    main()
