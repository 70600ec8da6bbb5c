"""γ on texture patches: does the default γ = 2 let α decide the cut? (issue 26, part 1).

For each terrain, at 1280 × 720 from the CLI's default view (``framing_camera``) and a low
oblique one (``cameras``), the cut at
α ∈ {2, 4} with the default γ = 2 and with γ off (inf): triangles, their ratio, and the
frame's largest drawn α and γ (frame stats). Untextured (the normal map's shading) and with a
hillshade pyramid baked by ``approxtree.textures.bake`` (textures given) at the cell size (also
lit at runtime: "hillshade+lit", its groups lit by normal patches) and at a half (fractal) or
a quarter (DEMs) of it. The untextured
frames are saved as PNGs, so that a run on another checkout can be compared pixel by
pixel (``--compare``: PSNR of this run's images against those of the other).

Terrains: fractal tree stores (``approxtree fractal --size 4097`` or ``--size 8193`` then
``approxtree build --epsilon 0.5``; --fractal, repeatable, named by their side), Mount St
Helens (USGS DEM, 30 m, steep) and a 1024² crop of the SRTM 3″ Mount Washington tile from
../shared/data (ε = 1 m, the CLI's default); --no-dems and --no-textures leave those out.

    PYTHONPATH=<checkout> python benchmarks/bench_gamma.py --fractal F.zarr --work DIR \\
        --images DIR/after [--compare DIR/before] [--out benchmarks/results/gamma.json] \\
        [--plot benchmarks/results/gamma.png]

Frame times against another checkout (``--interleave CHECKOUT --rounds R``): this script runs
itself R times on each checkout in turn (``--repeat`` warm frames per row after the first,
which loads), and reports per row the median over rounds of each side's median warm frame.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from affine import Affine

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent.parent / "shared" / "data"
SIZE = (1280, 720)
ALPHAS = (2.0, 4.0)
GAMMAS = (2.0, math.inf)


def open_trees(fractals: list[Path], data: Path, dems: bool = True) -> dict:
    """name -> tree: the fractal stores (``fractal_<side>``), and the DEM trees built here
    (ε = 1)."""
    import approxtree as at

    trees = {}
    for path in fractals:
        tree = at.ApproximationTree.load(path)
        trees[f"fractal_{max(tree.terrain.shape)}"] = tree
    if not dems:
        return trees
    helens = at.open_terrain(data / "edge" / "SainteHelens.dem")
    trees["st_helens_30m"] = at.ApproximationTree.build(helens, epsilon=1.0, progress=False)
    whole = at.open_terrain(data / "srtm" / "N44W072.hgt")
    # A 1024² crop of the tile's south-east (rows from the south edge, row 0 the north one).
    rows, cols = whole.shape
    r0, c0 = rows - 1024, cols - 1024
    heights = np.asarray(whole.heights)[r0:, c0:]
    srtm = at.Grid(heights, whole.transform * Affine.translation(c0, r0), crs=whole.crs)
    trees["srtm_crop_1024"] = at.ApproximationTree.build(srtm, epsilon=1.0, progress=False)
    return trees


def bake_hillshade(tree, folder: Path, divisor: int = 1) -> Path:
    """A Horn hillshade pyramid of the tree's terrain (4096-texel limit) with texels of its
    cell size / ``divisor`` (1: bake's defaults)."""
    from approxtree.textures.bake import bake

    if not (folder / "pyramid.json").exists():
        folder.parent.mkdir(parents=True, exist_ok=True)
        if divisor == 1:
            bake(tree.terrain, folder)
        else:
            texel = abs(tree.terrain.cell_size[0]) / divisor
            bake(tree.terrain, folder, texel_size=texel, gl=False)
    return folder


def cameras(tree, scale: np.ndarray) -> list[tuple[str, object]]:
    """The CLI's default view, and a low oblique one across the domain from its south-west."""
    from approxtree.render import Camera, framing_camera

    box = tree.bboxes[0]
    (x0, y0, z0), (x1, y1, z1) = box[:3], box[3:]
    w, top = max(x1 - x0, y1 - y0), float(z1)
    # Display units: the eye 5 % of the width above the top, at the domain's south-west corner
    # (degrees of a geographic CRS scaled to metres by ``scale``).
    height = 0.05 * w * float(scale[0]) / float(scale[2])
    low = Camera.look_at(
        (x0 + 0.1 * (x1 - x0), y0 + 0.1 * (y1 - y0), top + height),
        (0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (z0 + z1)),
        fov=45.0,
    )
    return [("default", framing_camera(box, scale, SIZE)), ("low", low)]


def measure(
    tree,
    textures,
    images: Path | None,
    name: str,
    label: str = "none",
    repeat: int = 0,
    lit: bool = False,
) -> list[dict]:
    """The cuts at ALPHAS × GAMMAS of both views; untextured images saved; ``repeat`` warm
    frames more per row (their median: warm_ms); ``lit``: textures lit at runtime (their
    groups by normal patch too, γ on both kinds of patch)."""
    from PIL import Image

    from approxtree.render import Cut, Engine, Style

    style = Style(lighting=True) if lit else Style()

    rows = []
    with Engine(tree, textures=textures) as engine:
        runs = [
            (v, c, a, g) for v, c in cameras(tree, engine.scale) for a in ALPHAS for g in GAMMAS
        ]
        for view, camera, alpha, gamma in runs:
            t0 = time.perf_counter()
            frame = engine.render(camera, SIZE, Cut(alpha=alpha, gamma=gamma), style=style)
            ms = (time.perf_counter() - t0) * 1e3
            warm = []
            for _ in range(repeat):
                t1 = time.perf_counter()
                engine.render(camera, SIZE, Cut(alpha=alpha, gamma=gamma), style=style)
                warm.append((time.perf_counter() - t1) * 1e3)
            s = frame.stats
            rows.append(
                {
                    "terrain": name,
                    "view": view,
                    "textures": label,
                    "alpha": alpha,
                    "gamma": gamma if math.isfinite(gamma) else "inf",
                    "triangles": int(s["triangles"]),
                    "patches": int(s["patches"]),
                    "max_alpha": float(s["max_alpha"]),
                    "max_gamma": float(s["max_gamma"]),
                    "frame_ms": ms,
                    "warm_ms": float(np.median(warm)) if warm else None,
                    "normal_patches": int(s["texture_patches"]) if textures is None else None,
                }
            )
            if images is not None and textures is None:
                images.mkdir(parents=True, exist_ok=True)
                png = images / f"{name}_{view}_a{alpha:g}_g{gamma:g}.png"
                Image.fromarray(frame.image).save(png)
    return rows


def add_ratios(rows: list[dict]) -> None:
    """ratio: triangles at γ = 2 over triangles with γ off (same terrain, textures, α)."""

    def key(r: dict) -> tuple:
        return r["terrain"], r["view"], r["textures"], r["alpha"]

    off = {key(r): r["triangles"] for r in rows if r["gamma"] == "inf"}
    for r in rows:
        r["ratio_to_gamma_off"] = r["triangles"] / off[key(r)]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) of two RGBA uint8 images over their RGB channels (inf when equal)."""
    d = a[..., :3].astype(np.float64) - b[..., :3].astype(np.float64)
    mse = float(np.mean(d * d))
    return math.inf if mse == 0 else 10.0 * math.log10(255.0**2 / mse)


def compare(images: Path, before: Path) -> dict[str, float]:
    """PSNR of each PNG of ``images`` against ``before``'s of the same name (cut and shading
    both may differ), and of each γ = 2 frame against ``before``'s γ-off frame ("… vs
    before γ inf": where the cuts are the same, the shading's difference alone)."""
    from PIL import Image

    def read(path: Path) -> np.ndarray:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGBA"))

    out = {}
    for png in sorted(images.glob("*.png")):
        pairs = [(png.stem, before / png.name)]
        if png.stem.endswith("_g2"):
            off = png.stem[: -len("_g2")] + "_ginf"
            pairs.append((f"{png.stem} vs before {off}", before / f"{off}.png"))
        for label, old in pairs:
            if old.exists():
                out[label] = psnr(read(png), read(old))
    return out


def plot(rows: list[dict], path: Path) -> None:
    """Bars of the γ = 2 cut's triangles over the γ-off cut's (the target line at 1.25) and
    its largest γ (the threshold at 2), one bar per terrain, view, textures and α."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    on = [r for r in rows if r["gamma"] != "inf"]
    labels = [f"{r['terrain']} {r['view']} {r['textures']} α{r['alpha']:g}" for r in on]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(max(8.0, 0.32 * len(on)), 8), sharex=True)
    x = np.arange(len(on))
    top.bar(x, [r["ratio_to_gamma_off"] for r in on], color="tab:blue")
    top.axhline(1.25, color="tab:red", linestyle="--", label="target 1.25×")
    top.set_ylabel("triangles γ 2 / γ off")
    top.legend()
    bottom.bar(x, [r["max_gamma"] for r in on], color="tab:green")
    bottom.axhline(2.0, color="tab:red", linestyle="--", label="γ = 2")
    bottom.set_yscale("log")
    bottom.set_ylabel("largest γ drawn (px²)")
    bottom.legend()
    bottom.set_xticks(x, labels, rotation=90, fontsize=7)
    fig.suptitle(f"γ on texture and normal patches, {SIZE[0]} × {SIZE[1]}")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def interleave(argv: list[str], other: Path, rounds: int) -> list[dict]:
    """Run this script with ``argv`` on ``other``'s checkout and on this one in turn,
    ``rounds`` times; per row (terrain, view, textures, α, γ) the median over rounds of each
    side's warm frame median (ms), and their ratio (this / other)."""
    runs: dict[str, list[list[dict]]] = {"other": [], "this": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            for side, checkout in (("other", other), ("this", ROOT)):
                out = Path(tmp) / f"{side}{r}.json"
                env = dict(os.environ, PYTHONPATH=str(checkout))
                cmd = [sys.executable, __file__, *argv, "--out", str(out)]
                subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
                runs[side].append(json.loads(out.read_text())["rows"])

    def key(r: dict) -> tuple:
        return r["terrain"], r["view"], r["textures"], r["alpha"], r["gamma"]

    table = []
    for i, row in enumerate(runs["this"][0]):
        this = float(np.median([run[i]["warm_ms"] for run in runs["this"]]))
        that = float(np.median([run[i]["warm_ms"] for run in runs["other"]]))
        assert key(runs["other"][0][i]) == key(row)
        table.append(
            {
                **{k: row[k] for k in ("terrain", "view", "textures", "alpha", "gamma")},
                "this_ms": this,
                "other_ms": that,
                "ratio": this / that,
            }
        )
    return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fractal", type=Path, action="append", default=[], help="fractal store")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--no-dems", action="store_true", help="fractal stores only")
    ap.add_argument("--no-textures", action="store_true", help="untextured rows only")
    ap.add_argument("--work", type=Path, required=True, help="folder for baked pyramids")
    ap.add_argument("--images", type=Path, help="save the untextured γ = 2 frames here")
    ap.add_argument("--compare", type=Path, help="images of another checkout: PSNR")
    ap.add_argument("--repeat", type=int, default=0, help="warm frames per row (warm_ms)")
    ap.add_argument("--interleave", type=Path, help="another checkout: frame times against it")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds per checkout")
    ap.add_argument("--out", type=Path, help="JSON results")
    ap.add_argument("--plot", type=Path, help="PNG of the ratios and the largest γ")
    args = ap.parse_args()
    if args.interleave is not None:
        argv = [a for f in args.fractal for a in ("--fractal", str(f))]
        argv += ["--work", str(args.work), "--data", str(args.data)]
        argv += ["--repeat", str(max(args.repeat, 1))]
        argv += ["--no-dems"] * args.no_dems + ["--no-textures"] * args.no_textures
        table = interleave(argv, args.interleave, args.rounds)
        for r in table:
            print(
                f"{r['terrain']:16} {r['view']:8} {r['textures']:11} α {r['alpha']:g} "
                f"γ {r['gamma']!s:4} this {r['this_ms']:8.1f} ms  other {r['other_ms']:8.1f} ms"
                f"  ×{r['ratio']:.2f}"
            )
        if args.out is not None:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            timing = {"size": list(SIZE), "other": str(args.interleave), "rounds": args.rounds}
            args.out.write_text(json.dumps({**timing, "rows": table}, indent=1))
        return
    rows: list[dict] = []
    for name, tree in open_trees(args.fractal, args.data, not args.no_dems).items():
        rows += measure(tree, None, args.images, name, repeat=args.repeat)
        if args.no_textures:
            continue
        pyramid = bake_hillshade(tree, args.work / f"{name}_hillshade")
        rows += measure(tree, str(pyramid), None, name, "hillshade", args.repeat)
        rows += measure(tree, str(pyramid), None, name, "hillshade+lit", args.repeat, lit=True)
        # Texels finer than the cells: a pyramid of several levels over the 4097² fractal.
        divisor = 2 if name.startswith("fractal") else 4
        fine = bake_hillshade(tree, args.work / f"{name}_hillshade_fine{divisor}", divisor)
        rows += measure(tree, str(fine), None, name, f"hillshade/{divisor}", args.repeat)
    add_ratios(rows)
    result: dict = {"size": list(SIZE), "rows": rows}
    if args.compare is not None and args.images is not None:
        result["psnr_db_vs_before"] = {
            k: (v if math.isfinite(v) else "inf")
            for k, v in compare(args.images, args.compare).items()
        }
    for r in rows:
        print(
            f"{r['terrain']:16} {r['view']:8} {r['textures']:11} "
            f"α {r['alpha']:g} γ {r['gamma']!s:4} "
            f"{r['triangles']:>9,} tri  ×{r['ratio_to_gamma_off']:.2f}  "
            f"max α {r['max_alpha']:.2f}  max γ {r['max_gamma']:.3f}"
        )
    for k, v in result.get("psnr_db_vs_before", {}).items():
        print(f"PSNR {k}: {v} dB")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1))
    if args.plot is not None:
        plot(rows, args.plot)


if __name__ == "__main__":
    main()
