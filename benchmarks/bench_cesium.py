"""Triangles CesiumJS draws for the same view: our tiles against a uniform heightmap.

The NC DEM (../shared/data/nc/elev_ned_30m.tif) is built into a tree and written with
`approxtree tiles` as a 3D Tiles tileset (one TIN patch per node, geometricError = ε_T(N)) and
as quantized-mesh terrain (greedy TINs per tile within Cesium's level error). The peer is the
uniform heightmap of the same DEM in the same tiling: Cesium's heightmap-1.0 terrain
(65 × 65 samples per tile, as cesium-terrain-builder writes by default), sampled by the same
sampler at the same tiles. All are drawn by CesiumJS in headless chromium (tests/browser.py)
from the same cameras at the same maximumScreenSpaceError; the triangles are Cesium's
(tileset.statistics.numberOfTrianglesSelected; the globe's rendered tiles' mesh indices).
`approxtree render` of the same camera at α = SSE is reported beside them.

    python benchmarks/bench_cesium.py [--sse 2] [--tree NC.zarr] [--work DIR]

Results: benchmarks/results/cesium.json (cesium_sseN.json for another --sse), screenshots in
the work folder.
"""

from __future__ import annotations

import argparse
import json
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import browser  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
DEM = ROOT.parent / "shared" / "data" / "nc" / "elev_ned_30m.tif"
CRS = "EPSG:32119"
BOUNDS = (630000.0, 215000.0, 645000.0, 228500.0)
SIZE = (480, 320)
FOV = 45.0
#: (name, eye, target) in map units.
CAMERAS = [
    ("overview", (637500.0, 203000.0, 5000.0), (637500.0, 221750.0, 100.0)),
    ("oblique", (636000.0, 214000.0, 700.0), (637000.0, 219000.0, 90.0)),
    ("low", (632000.0, 216000.0, 300.0), (640000.0, 222000.0, 100.0)),
]
HEIGHTMAP_SIDE = 65


def cli(*args: str) -> dict:
    """One approxtree command with --json; its figures."""
    exe = Path(sys.executable).parent / "approxtree"
    out = subprocess.run([str(exe), *args, "--json"], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def write_heightmap_terrain(qm_dir: Path, tree: Path, out: Path) -> dict:
    """Cesium heightmap-1.0 tiles at every tile of the quantized-mesh folder ``qm_dir``.

    Each tile: 65 × 65 uint16 little-endian heights (h + 1000) · 5, row 0 = north, then the
    child-tile mask byte (1 SW, 2 SE, 4 NW, 8 NE) and no water mask.
    """
    from approxtree.tiles.geographic import tile_size
    from approxtree.tiles.sampling import TileSampler
    from approxtree.tree import load_tree

    sampler = TileSampler(load_tree(tree).terrain)
    tiles = {
        (int(p.parts[-3]), int(p.parts[-2]), int(p.stem)) for p in qm_dir.glob("*/*/*.terrain")
    }
    for level, x, y in tiles:
        size = tile_size(level)
        west, south = -180.0 + x * size, -90.0 + y * size
        h, _ = sampler.sample((west, south, west + size, south + size), HEIGHTMAP_SIDE)
        q = np.clip(np.rint((h[::-1] + 1000.0) * 5.0), 0, 65535).astype("<u2")
        mask = 0
        for bit, (dx, dy) in zip((1, 2, 4, 8), ((0, 0), (1, 0), (0, 1), (1, 1)), strict=True):
            if (level + 1, 2 * x + dx, 2 * y + dy) in tiles:
                mask |= bit
        path = out / str(level) / str(x) / f"{y}.terrain"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(q.tobytes() + struct.pack("<B", mask))
    # Availability listed in full (one range per tile): heightmap tiles carry no metadata.
    layer = json.loads((qm_dir / "layer.json").read_text())
    layer.pop("metadataAvailability", None)
    levels = max(level for level, _, _ in tiles) + 1
    available = [[] for _ in range(levels)]
    for level, x, y in sorted(tiles):
        available[level].append({"startX": x, "startY": y, "endX": x, "endY": y})
    layer.update(
        format="heightmap-1.0",
        extensions=[],
        available=available,
        description="uniform heightmap peer",
    )
    (out / "layer.json").write_text(json.dumps(layer))
    return {"tiles": len(tiles)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sse", type=float, default=2.0, help="maximumScreenSpaceError, px")
    parser.add_argument("--tree", type=Path, help="NC tree store [default: built here]")
    parser.add_argument("--work", type=Path, help="work folder [default: a temporary one]")
    args = parser.parse_args()
    reason = browser.unavailable()
    if reason:
        sys.exit(f"bench_cesium needs the browser: {reason}")
    work = args.work or Path(tempfile.mkdtemp(prefix="bench_cesium_"))
    work.mkdir(parents=True, exist_ok=True)
    tree = args.tree or work / "nc.zarr"
    if not tree.exists():
        cli("build", str(DEM), "--out", str(tree))
    folders = {"3dtiles": work / "3dtiles", "quantized-mesh": work / "qm"}
    writes = {}
    for fmt, folder in folders.items():
        if not folder.exists():
            t0 = time.perf_counter()
            writes[fmt] = cli("tiles", str(tree), "--out", str(folder), "--format", fmt)
            writes[fmt]["wall_seconds"] = round(time.perf_counter() - t0, 3)
    folders["heightmap"] = work / "heightmap"
    if not folders["heightmap"].exists():
        writes["heightmap"] = write_heightmap_terrain(
            folders["quantized-mesh"], tree, folders["heightmap"]
        )

    sse = f"{args.sse:g}"
    clip = ",".join(f"{v:.7f}" for v in browser.lonlat_bounds(BOUNDS, CRS))
    content = {
        "3dtiles": {"tileset": "/tiles/tileset.json", "globe": "0"},
        "quantized-mesh": {"terrain": "/tiles/", "clip": clip},
        "heightmap": {"terrain": "/tiles/", "clip": clip},
    }
    rows = []
    for name, eye, target in CAMERAS:
        row = {"camera": name, "eye": eye, "target": target}
        cam = browser.cesium_view(eye, target, FOV, CRS)
        ours = cli(
            "render", str(tree), "--eye", ",".join(map(str, eye)), "--target",
            ",".join(map(str, target)), "--fov", str(FOV), "--size", f"{SIZE[0]}x{SIZE[1]}",
            "--alpha", sse, "--out", str(work / f"render_{name}.png"),
        )  # fmt: skip
        row["approxtree_render"] = {"triangles": ours["triangles"]}
        for kind, params in content.items():
            view = {"name": f"{kind}_{name}", "params": {**params, "sse": sse, **cam}}
            (res,) = browser.run_views(folders[kind], [view], work / "shots", SIZE)
            if res["error"]:
                row[kind] = {"error": res["error"]}
                continue
            stats = res["stats"]
            s = stats["tileset"] if kind == "3dtiles" else stats["globe"]
            row[kind] = {
                "triangles": s["triangles"],
                "tiles": s.get("selected", s.get("tiles")),
                "triangles_without_skirts": s.get("trianglesWithoutSkirts"),
                "tiles_requested": len(res["tile_requests"]),
                "terrain_fraction": float(browser.terrain_mask(res["screenshot"]).mean()),
                "seconds_to_load": res["seconds"],
            }
        hm = row["heightmap"].get("triangles")
        for kind in ("3dtiles", "quantized-mesh"):
            t = row[kind].get("triangles")
            if hm and t:
                row[kind]["ratio_to_heightmap"] = round(t / hm, 4)
        rows.append(row)
        print(json.dumps(row))
    result = {
        "dem": str(DEM),
        "sse": args.sse,
        "size": SIZE,
        "fov": FOV,
        "writes": writes,
        "rows": rows,
        "work": str(work),
    }
    RESULTS.mkdir(exist_ok=True)
    name = "cesium.json" if args.sse == 2.0 else f"cesium_sse{args.sse:g}.json"
    (RESULTS / name).write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
