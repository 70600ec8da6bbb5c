"""Pixel regression of the renderer: fixed views rendered to PNGs, their pixels hashed.

Run it on two checkouts (e.g. before and after a refactoring of render/) and compare the JSON
files: every image must have the same sha256 (of its decoded RGBA pixels and shape, so the PNG
encoder's version does not matter). What is drawn:

1. ``approxtree render`` (the CLI, a fresh process each) of every kind of file in
   ../shared/data: GeoTIFFs (one with NaN over the sea, one with nodata), SRTM .hgt and
   .hgt.zip, ESRI .asc, USGS .dem, SCAPE .stm (--cell-size 30), .npz (--crs EPSG:4326), the
   LAZ point cloud, the quantized-mesh .terrain, and a saved tree store;
2. the same CLI with options: textured (hillshade and thematic pyramids baked first by
   ``approxtree bake``), wireframe, --full-resolution (plain and textured), --max-triangles,
   a cartographic style (sky, sun, exaggeration, palette, lighting on);
3. a point quadtree store (``approxtree build --kind point-quadtree``): threshold, wireframe
   and full resolution;
4. through the Python API: an interactive paging sequence (frames that do not wait, small
   caches, each frame's requests loaded before the next) plain and textured, and a world
   position buffer.

Cuts and images are deterministic (the selection is pure, uploads are ordered, Mesa llvmpipe
rasterizes the same way each run); timings are left out, and so are the paging figures
"pending" and "paged_uploads": two loader threads fill a small CPU cache in the order their
loads end, so which payloads it evicts, and those two counts, vary from run to run (±1-2 here,
on any checkout) while the drawn images do not.

Two default pictures changed by design (issue 27) and differ from checkouts before it: the LAZ
cloud is drawn as its filled ground surface (``--all-points``: every point), and terrains whose
fitted box covers under 62 % of the frame from 20-50° (lux, asc, usgs_dem, stm, laz) are seen
more steeply (``frame_state.FRAMING_STEEPER``).

    PYTHONPATH=<checkout> python benchmarks/render_regression.py OUT_DIR [--data DIR]
        [--against OTHER_OUT_DIR]

``--against`` compares with another checkout's run: per image whether its pixels are the same,
and for one that changed, whether its cut is the same (STAT_KEYS) and the PSNR of its pixels
(a change of shading alone keeps the cut; a change of cut shows in the triangles), written to
OUT_DIR/against.json.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent.parent / "shared" / "data"
SIZE = "480x320"
#: Stats keys compared besides the pixels (timings and byte counts left out).
STAT_KEYS = ("patches", "triangles", "nodes_visited", "culled", "texture_patches", "empty")

#: name -> (source file relative to the data folder, extra CLI arguments)
FILES = {
    "geotiff_nc": ("nc/elev_ned_30m.tif", []),
    "geotiff_nan_nz": ("edge/nz_elev.tif", []),
    "geotiff_nodata_dtm": ("edge/dtm.tif", []),
    "geotiff_degrees_lux": ("roads/lux_elev.tif", []),
    "hgt": ("srtm/N44W072.hgt", []),
    "hgt_zip": ("srtm/N22W160v2.3a.hgt.zip", []),
    "asc": ("edge/hugo_site.asc", []),
    "usgs_dem": ("edge/SainteHelens.dem", []),
    "stm": ("scape/crater.stm", ["--cell-size", "30"]),
    "npz": ("edge/jacksboro_fault_dem.npz", ["--crs", "EPSG:4326"]),
    "laz": ("lidar/autzen_trim.laz", []),
    "quantized_mesh": ("tin/9_533_383.terrain", []),
}


def pixel_hash(path: Path) -> tuple[str, list[int]]:
    """sha256 of the decoded pixels (with their shape) of an image file."""
    from PIL import Image

    with Image.open(path) as im:
        pixels = np.asarray(im.convert("RGBA"))
    h = hashlib.sha256(str(pixels.shape).encode())
    h.update(np.ascontiguousarray(pixels).tobytes())
    return h.hexdigest(), list(pixels.shape)


def array_hash(a: np.ndarray) -> str:
    h = hashlib.sha256(f"{a.shape}{a.dtype}".encode())
    h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def cli(*args: str) -> str:
    """Run ``python -m approxtree ARGS`` with this interpreter and PYTHONPATH; its stdout."""
    run = subprocess.run(
        [sys.executable, "-m", "approxtree", *args], capture_output=True, text=True, env=os.environ
    )
    if run.returncode != 0:
        raise SystemExit(f"approxtree {' '.join(args)} failed:\n{run.stderr}")
    return run.stdout


#: The palette of every render that does not choose one: the fixed-elevation "relief", the
#: default before the default became the terrain's own range ("hypsometric"), so that a
#: checkout from either side of that change draws the same pictures.
PALETTE = ("--palette", "relief")


def render_cli(out: Path, name: str, source: str, *args: str) -> dict:
    png = out / f"{name}.png"
    palette = () if "--palette" in args else PALETTE
    stats = json.loads(
        cli("render", source, "--out", str(png), "--size", SIZE, "--json", *palette, *args)
    )
    digest, shape = pixel_hash(png)
    return {"sha256": digest, "shape": shape, **{k: stats.get(k) for k in STAT_KEYS}}


def python_api(out: Path, data: Path, work: Path) -> dict[str, dict]:
    """Interactive paging sequences and a world-position buffer through the Python API."""
    from PIL import Image

    import approxtree as at
    from approxtree.render import Camera, Engine, overview_camera

    new_api = hasattr(at.render, "Paging")
    if new_api:
        from approxtree.render import Cut, Paging

    tree = at.ApproximationTree.build(at.open_terrain(data / "nc/elev_ned_30m.tif"), epsilon=1.0)
    d = tree.terrain.domain
    (cx, cy), z = d.center, float(tree.bboxes[0, 5])
    results: dict[str, dict] = {}

    def frames(engine: Engine, cams, label: str) -> None:
        # The fixed palette of every checkout (see PALETTE).
        if hasattr(engine, "set_palette"):
            engine.set_palette("relief")
        for k, cam in enumerate(cams):
            if new_api:
                frame = engine.render(cam, (320, 240), Cut(alpha=1.0), paging=Paging(False, 4))
            else:
                frame = engine.render(cam, (320, 240), 1.0, wait=False, max_uploads=4)
            engine.provider.wait()
            Image.fromarray(frame.image).save(out / f"{label}_{k}.png")
            s = frame.stats
            results[f"{label}_{k}"] = {
                "sha256": array_hash(frame.image),
                **{key: s[key] for key in (*STAT_KEYS, "stand_ins")},
            }

    with Engine(tree, cache_bytes=3 << 20, cpu_cache_bytes=2 << 20) as engine:
        cams = [overview_camera(tree.bboxes[0], engine.scale)]
        for t in np.linspace(0.0, 1.0, 5):
            eye = (cx - 6000 + 9000 * t, d.ymin - 1500, z + 1500 - 800 * t)
            cams.append(Camera.look_at(eye, (cx, cy + 2000 * t, 60.0), fov=50))
        frames(engine, cams, "paging")
        cam = cams[3]
        if new_api:
            frame = engine.render(cam, (320, 240), Cut(alpha=2.0))
            positions = engine.world_positions(frame)
        else:
            positions = engine.render(cam, (320, 240), 2.0, world_positions=True).positions
        results["world_positions"] = {"sha256": array_hash(np.nan_to_num(positions, nan=-1e9))}
    with Engine(tree, textures=work / "hillshade", cpu_cache_bytes=4 << 20) as engine:
        frames(engine, cams[:4], "paging_textured")
    return results


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) of two uint8 images of one shape (inf when equal)."""
    d = a.astype(np.float64) - b.astype(np.float64)
    mse = float(np.mean(d * d))
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0**2 / mse)


def against(out: Path, other: Path, results: dict[str, dict]) -> dict[str, dict]:
    """Per image of ``results``: same pixels as ``other``'s run, and for a changed one,
    whether its stats (the cut) are the same and the PSNR of its PNG against the other's."""
    from PIL import Image

    theirs = json.loads((other / "hashes.json").read_text())
    report = {}
    for name, r in results.items():
        t = theirs.get(name)
        if t is None:
            continue
        row: dict = {"same_pixels": r["sha256"] == t["sha256"]}
        if not row["same_pixels"] and "triangles" in r:
            row["same_cut"] = all(r.get(k) == t.get(k) for k in STAT_KEYS)
            row["triangles"] = [t.get("triangles"), r.get("triangles")]
            a, b = out / f"{name}.png", other / f"{name}.png"
            if a.exists() and b.exists():
                with Image.open(a) as ia, Image.open(b) as ib:
                    pa, pb = np.asarray(ia.convert("RGBA")), np.asarray(ib.convert("RGBA"))
                if pa.shape == pb.shape:
                    row["psnr_db"] = round(float(psnr(pa, pb)), 2)
        report[name] = row
    return report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--against", type=Path, help="OUT_DIR of another checkout's run")
    args = ap.parse_args()
    out, data = args.out, args.data
    out.mkdir(parents=True, exist_ok=True)
    work = out / "work"
    work.mkdir(exist_ok=True)
    t0 = time.perf_counter()
    results: dict[str, dict] = {}
    # 1. Every kind of file, built in memory and drawn by the CLI.
    for name, (rel, extra) in FILES.items():
        results[name] = render_cli(out, name, str(data / rel), *extra)
        print(name, results[name]["sha256"][:16], flush=True)
    # 2. A store, textures, wireframe, full resolution, a budget, a style.
    nc = str(data / "nc/elev_ned_30m.tif")
    store = work / "nc.zarr"
    if not store.exists():
        cli("build", nc, "--out", str(store))
    hill, land = work / "hillshade", work / "landuse"
    if not hill.exists():
        cli("bake", nc, "--out", str(hill), "--quiet")
    if not land.exists():
        thematic = str(data / "nc/landuse_r.tif")
        cli("bake", nc, "--out", str(land), "--thematic", thematic, "--quiet")
    runs = {
        "store": (str(store),),
        "textured_hillshade": (nc, "--textures", str(hill)),
        "textured_landuse": (str(store), "--textures", str(land)),
        "wireframe": (nc, "--wireframe"),
        "full_resolution": (nc, "--full-resolution"),
        "full_resolution_textured": (nc, "--full-resolution", "--textures", str(land)),
        "max_triangles": (nc, "--max-triangles", "20000"),
        "style": (
            nc,
            *("--background", "sky", "--sun-azimuth", "200", "--sun-altitude", "30"),
            *("--exaggeration", "2.5", "--palette", "atlas", "--lighting", "on"),
        ),
    }
    # 3. A point quadtree store.
    pq = work / "autzen_pq.zarr"
    if not pq.exists():
        laz = str(data / "lidar/autzen_trim.laz")
        cli("build", laz, "--kind", "point-quadtree", "--out", str(pq))
    runs.update(
        point_quadtree=(str(pq),),
        point_quadtree_wireframe=(str(pq), "--wireframe", "--alpha", "4"),
        point_quadtree_full=(str(pq), "--full-resolution"),
    )
    for name, argv in runs.items():
        results[name] = render_cli(out, name, *argv)
        print(name, results[name]["sha256"][:16], flush=True)
    # 4. The Python API: paging sequences and world positions.
    for name, r in python_api(out, data, work).items():
        results[name] = r
        print(name, r["sha256"][:16], flush=True)
    (out / "hashes.json").write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
    print(f"{len(results)} images in {time.perf_counter() - t0:.0f} s -> {out / 'hashes.json'}")
    if args.against is not None:
        report = against(out, args.against, results)
        (out / "against.json").write_text(json.dumps(report, indent=1, sort_keys=True) + "\n")
        for name, row in report.items():
            if not row["same_pixels"]:
                print(f"changed {name}: {row}")
        same = sum(row["same_pixels"] for row in report.values())
        print(f"{same} of {len(report)} images have the same pixels as {args.against}")


if __name__ == "__main__":
    main()
