"""Compile every cached kernel ahead of time, with the signatures the commands use.

    python -m approxtree._warmup [--only STEP ...]

``pip install .`` runs this (setup.py) into the built package's ``_kernel_cache`` folder (see
``approxtree.kernels._cache``), so the first run of every command loads machine code instead of
compiling. numba keys compiled code by argument types, not sizes: the steps run tiny inputs
through the same code as the commands, so the signatures are the commands' ones. The first
steps call the Python entry points (tree build, store round trip, a frame's CPU work and the
viewer's budgeted selection, the hillshade bake with and without OpenGL, the mesh strategies);
the others run the commands themselves (``approxtree.cli.main``) on tiny files of each kind
the readers hand over differently: float32 heights with a hole, float64 heights, scattered
points, a TIN (a quantized-mesh tile). tests/test_aot_cache.py checks that every kernel of the
package has a cache entry after the warm-up, and that the first runs the issues measured
(demo, render, mesh, bake, info and point quadtree of a LAZ, tiles, rd, verify, fractal)
compile nothing.

A step that fails (e.g. a dependency missing in the build environment) is reported and
skipped; the others still run. Exit status 1 when a step failed.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

import numpy as np


def _terrain(rows: int = 41, cols: int = 47):
    """A small smooth hill on a geographic 3″ lattice, like the demo's sample DEM (float32)."""
    from affine import Affine

    from approxtree import Grid
    from approxtree.datasets import fractal_heights

    z = fractal_heights(rows, cols, seed=1, relief=300.0).astype(np.int16)
    cell = 3.0 / 3600.0
    return Grid(z, transform=Affine(cell, 0.0, -84.0, 0.0, -cell, 36.0), crs="EPSG:4326")


def _frame(tree) -> None:
    """What a frame computes on the CPU (render/engine.py): selection, texture sharing,
    skirt depths, the selected patches' meshes, and the budgeted selection of the viewer."""
    from approxtree.render import display_scale, overview_camera, select
    from approxtree.render.budget import node_triangles, select_budget
    from approxtree.render.frame_state import FrameState
    from approxtree.render.gpu_cache import mip_chain
    from approxtree.render.normal_map import NormalPatches
    from approxtree.render.skirts import skirt_depths
    from approxtree.render.texture_sharing import texture_nodes
    from approxtree.render.visual_error import texel_sizes, visual_errors

    scale = display_scale(tree.terrain)
    camera = overview_camera(tree.bboxes[0], scale)
    fs = FrameState.from_camera(camera, (800, 600), tree.bboxes[0], tree.origin, scale)
    sel = select(tree, fs, alpha=0.5, gamma=2.0)
    texture_nodes(tree.parents, sel, 2.0)
    # The visual errors of a drawn cut (render's and the viewer's stats while patches page in).
    drawn = np.asarray(sel.nodes, dtype=np.int64)
    visual_errors(tree.bboxes[drawn], tree.errors[drawn], texel_sizes(tree)[drawn], fs)
    skirt_depths(tree.errors, tree.terrain.z_range, None, tree.bboxes[:, [0, 1, 3, 4]])
    # Normal patches (grids over the normal map's side): a texture limit below the terrain's
    # side makes its normal map strided, so nodes get patches whose texels are computed.
    patches = NormalPatches(tree.terrain, np.asarray(tree.rects), max_side=16)
    for i in np.flatnonzero(patches.levels >= 0)[:1]:
        key = patches.key(int(i), float(scale[2]))
        if key is not None:
            patches.upload_texels(key, np.asarray(tree.origin), np.asarray(scale))
    for i in sel.nodes:
        tree.patch(int(i)).vertices  # noqa: B018 (the mesh is built on first access)
    select_budget(tree, fs, 10**9, node_triangles(tree))
    # The mip chain of a texture patch (made on a worker thread in interactive frames).
    mip_chain(np.zeros((4, 4, 4), dtype=np.uint8))


def tree_step(work: Path) -> None:
    """``demo`` / ``build`` / ``render``: build, save as a store, open, and a frame of both."""
    from approxtree import ApproximationTree, load_tree

    tree = ApproximationTree.build(_terrain(), epsilon=1.0, max_points=289)
    _frame(tree)
    path = work / "warmup.zarr"
    tree.save(path)
    _frame(load_tree(path))


def bake_step(work: Path) -> None:
    """``demo`` / ``bake``: the hillshade pyramid of a small terrain; ``render``: reading its
    levels back as RGBA, as the engine does."""
    from approxtree.render.context import optional_context
    from approxtree.textures.bake import bake
    from approxtree.textures.pyramid import TexturePyramid

    options = {"azimuth": 315.0, "altitude": 45.0}
    # With OpenGL when a context can be made (as the commands default to), and with numpy
    # (--no-gl, or no context: the shading kernel), each under a texture limit below the
    # terrain's size: the pyramid halves (as any DEM over 4096²).
    with optional_context() as gl_context:
        for name, gl in (("textures", True), ("textures_numpy", False)):
            bake(
                _terrain(),
                work / name,
                shading_options=options,
                max_texture_size=16,
                gl=gl,
                context=gl_context,
            )
    pyramid = TexturePyramid(work / "textures")
    for k in range(len(pyramid)):
        pyramid.read(k, 0, 0, 4, 4)


def mesh_step(work: Path) -> None:
    """``mesh``: every strategy of ``approximate`` on float32 heights (GeoTIFF DEMs)."""
    from affine import Affine

    from approxtree import Grid
    from approxtree.datasets import fractal_heights
    from approxtree.patches.approximate import MESH_STRATEGIES, approximate

    z = fractal_heights(65, 65, seed=2, relief=200.0)
    grid = Grid(z, transform=Affine(30.0, 0.0, 0.0, 0.0, -30.0, 0.0), crs="EPSG:32617")
    for strategy in MESH_STRATEGIES:
        approximate(grid, strategy, max_error=1.0)


def tiles_step(work: Path) -> None:
    """``tiles --format quantized-mesh``: sampling and the tiles' TIN error check."""
    from approxtree.tiles import write_quantized_mesh

    write_quantized_mesh(_terrain(), work / "tiles")


def _geotiff(path: Path, dtype: str, holes: bool, size: int = 65) -> Path:
    """A size² GeoTIFF of ``dtype`` heights (int32 reads as float64 heights, float32 as float32;
    ``holes``: a NaN patch, as over a sea), 30 m cells in UTM."""
    import rasterio
    from affine import Affine

    from approxtree.datasets import fractal_heights

    z = fractal_heights(size, size, seed=3, relief=300.0) + 100.0
    if holes:
        z[54:, :10] = np.nan
    profile = {"driver": "GTiff", "width": size, "height": size, "count": 1, "dtype": dtype}
    with rasterio.open(
        path, "w", **profile, crs="EPSG:32617", transform=Affine(30, 0, 500000, 0, -30, 4e6)
    ) as f:
        f.write(z.astype(dtype), 1)
    return path


def _las(path: Path) -> Path:
    """600 scattered points over 100 m × 80 m (LAS 1.2), every fourth one not ground."""
    import laspy

    rng = np.random.default_rng(0)
    n = 600
    x, y = rng.uniform(1000, 1100, n), rng.uniform(2000, 2080, n)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.01, 0.01, 0.01], [1000, 2000, 0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, 50 + 0.1 * (x - 1000) + 3 * np.sin(x / 10) + np.cos(y / 7)
    classes = np.full(n, 2, dtype=np.uint8)
    classes[::4] = 1
    las.classification = classes
    las.write(path)
    return path


def _cli(*argv: str) -> None:
    """One approxtree command, in this process (its output discarded)."""
    import contextlib
    import io

    from approxtree.cli import main

    with contextlib.redirect_stdout(io.StringIO()) as text:
        try:
            main(list(argv), standalone_mode=False)
        except SystemExit as stop:
            # verify exits 0 or 1 (its report's verdict); 2 is an error, printed as one line.
            if stop.code not in (0, 1, None):
                raise RuntimeError(f"approxtree {' '.join(argv)}: {text.getvalue()}") from None


def _terrain_commands(work: Path, source: Path, kind: str) -> None:
    """What the commands run on one terrain file (``kind``: grid, points or tin): info, build
    and render of its tree, the point quadtree (points, TIN), bake, mesh with each strategy
    (grids; TIN otherwise), verify; quantized-mesh tiles and rd (grids)."""
    out = work / source.stem
    out.mkdir()
    src, store, grid = str(source), str(out / "tree.zarr"), kind == "grid"
    _cli("info", src)
    _cli("build", src, "--out", store, "-q")
    _cli("render", store, "--out", str(out / "r.png"), "--size", "160x90")
    if kind == "points":
        _cli("info", src, "--ground-only")
    if not grid:
        pq = str(out / "pq.zarr")
        _cli("build", src, "--kind", "point-quadtree", "--out", pq, "-q")
        _cli("render", pq, "--out", str(out / "pq.png"), "--size", "160x90")
    _cli("bake", src, "--out", str(out / "tex"), "-q", "--max-texture-size", "64")
    for strategy in ("tin", "rtin", "nonregular", "grid") if grid else ("tin",):
        mesh = str(out / f"{strategy}.ply")
        _cli("mesh", src, "--strategy", strategy, "--max-error", "1", "--out", mesh, "-q")
    _cli("verify", str(out / "tin.ply"), "--source", src)
    _cli("verify", store)
    if grid:
        _cli("tiles", store, "--format", "quantized-mesh", "--out", str(out / "qm"))
        _cli("verify", str(out / "qm"))
        _cli("rd", src, "--size", "33", "-q")


def float32_step(work: Path) -> None:
    """The commands on float32 heights with a NaN hole (GeoTIFF, SRTM, USGS DEM, STM, PNG);
    fractal."""
    _terrain_commands(work, _geotiff(work / "f32.tif", "float32", holes=True), "grid")
    _cli("fractal", str(work / "fractal.tif"), "--size", "65")


def tile_formats_step(work: Path) -> None:
    """Every other tile format of a float32 grid's tree; verify of each and of the texture
    pyramid."""
    source = _geotiff(work / "tiled.tif", "float32", holes=False)
    store, out = str(work / "tiled.zarr"), work / "tiled"
    out.mkdir()
    _cli("build", str(source), "--out", store, "-q")
    _cli("bake", str(source), "--out", str(out / "tex"), "-q", "--max-texture-size", "64")
    _cli("verify", str(out / "tex"))
    for fmt in ("3dtiles", "3dtiles-terrain", "terrarium", "imagery"):
        extra = ["--textures", str(out / "tex")] if fmt == "imagery" else []
        _cli("tiles", store, "--format", fmt, "--out", str(out / fmt), *extra)
    for fmt in ("3dtiles", "3dtiles-terrain", "terrarium", "imagery"):
        _cli("verify", str(out / fmt))


def shading_step(work: Path) -> None:
    """The cartographic hillshade of the Python API and the viewer (slope and curvature
    weights, cast shadows, both gdaldem gradients), its grey texture strips."""
    from approxtree.textures.shading import TopographicShading

    for algorithm in ("horn", "zevenbergen-thorne"):
        for terrain in (_terrain(), _geotiff_grid(work, "float64")):
            shading = TopographicShading(
                terrain, algorithm, slope_weight=0.5, curvature_weight=0.5, shadows=True
            )
            shading.hillshade()
            shading._plain_grey()
            shading.shade()
            shading.rgba()
            for _ in shading.band_strips(8):
                pass
            for _ in shading.level_strips(8):
                pass
            shading.slope()
            shading.curvature()
            shading.shadow_mask()


def _geotiff_grid(work: Path, dtype: str):
    """The Grid of a 65² GeoTIFF of ``dtype`` heights, read as the commands read it."""
    from approxtree.io import read_grid

    return read_grid(_geotiff(work / f"shading_{dtype}.tif", dtype, holes=False))


def update_step(work: Path) -> None:
    """The per-cell figures of large grid patches that ``update`` keeps (patches of 2048²
    points and more, which no tiny file reaches): the kernel itself, in both height dtypes."""
    from approxtree.kernels.grid_cells import grid_patch_cells, grid_patch_cells_many

    for dtype in (np.float32, np.float64):
        heights = np.arange(81, dtype=dtype).reshape(9, 9)
        lattice = np.ascontiguousarray(heights[::4, ::4])
        grid_patch_cells(heights, lattice, 0, 8, 0, 8, 4, 4, 0, 1, 0, 1)
        # The build's row kernel of the same figures (roots of 4096² points and more).
        start = np.array([0, lattice.size], dtype=np.int64)
        index = np.array([[0, 8, 0, 8, 4, 4]], dtype=np.int64)
        grid_patch_cells_many(heights, lattice.ravel(), start, index)


def extras_step(work: Path) -> None:
    """Options of the commands that reach more kernels: a blocked build, a textured render,
    a GLB mesh (its stored-vertex errors), verify of a store against its source."""
    # 129²: a blocked build of 64² blocks has several.
    source = _geotiff(work / "extras.tif", "float32", holes=False, size=129)
    out, src = work / "extras", str(source)
    out.mkdir()
    store = str(out / "tree.zarr")
    _cli("build", src, "--out", store, "--block-size", "64", "-q")
    for policy in ("nonregular", "tin"):
        other = str(out / f"{policy}.zarr")
        _cli("build", src, "--out", other, "--policy", policy, "-q")
        _cli("verify", other, "--source", src)
    _cli("bake", src, "--out", str(out / "tex"), "-q", "--max-texture-size", "64")
    _cli("render", store, "--textures", str(out / "tex"), "--out", str(out / "r.png"))
    _cli("mesh", src, "--strategy", "tin", "--max-error", "1", "--out", str(out / "m.glb"))
    _cli("verify", store, "--source", src)


def float64_step(work: Path) -> None:
    """The commands on float64 heights (32-bit integer rasters, ASCII grids); a frame of a
    saved float64 tree through the API (the render's cut need not reach every patch kind)."""
    from approxtree import ApproximationTree, load_tree

    _terrain_commands(work, _geotiff(work / "i32.tif", "int32", holes=False), "grid")
    tree = ApproximationTree.build(_geotiff_grid(work, "float64"), epsilon=1.0, max_points=289)
    tree.save(work / "f64.zarr")
    _frame(load_tree(work / "f64.zarr"))


def points_step(work: Path) -> None:
    """The commands on scattered points (LAS/LAZ), the point quadtree's among them."""
    _terrain_commands(work, _las(work / "points.las"), "points")


def tin_step(work: Path) -> None:
    """The commands on a TIN (a quantized-mesh tile, written here)."""
    from approxtree.tiles import write_quantized_mesh

    write_quantized_mesh(_terrain(), work / "qm_tiles")
    _terrain_commands(work, sorted((work / "qm_tiles").rglob("*.terrain"))[-1], "tin")


#: Kernels no step compiles, and why: no command reaches them on the inputs the warm-up can
#: make in the build environment (they compile on first use, with the CLI's notice).
#: tests/test_aot_cache.py fails for a kernel neither compiled nor listed here.
NOT_WARMED: dict[str, str] = {
    "approxtree.kernels.tin_mesh.half_edge_twins": "microstructure patches (build "
    "--microstructures reads line files with pyogrio, not in the build environment)",
    "approxtree.kernels.mesh_errors.mesh_point_errors": "microstructure patches; mesh files "
    "whose stored coordinates round the mesh's (large float32 coordinates)",
    "approxtree.kernels.bintree_rd.split_closure": "BinTree.splitting_domain, Python API only",
}


STEPS: dict[str, Callable[[Path], None]] = {
    "tree": tree_step,
    "bake": bake_step,
    "mesh": mesh_step,
    "tiles": tiles_step,
    "float32": float32_step,
    "tile_formats": tile_formats_step,
    "shading": shading_step,
    "extras": extras_step,
    "update": update_step,
    "float64": float64_step,
    "points": points_step,
    "tin": tin_step,
}


def warm_up(steps: list[str] | None = None, log=print) -> list[str]:
    """Run the steps (all by default); returns the names of those that failed."""
    failed = []
    with tempfile.TemporaryDirectory(prefix="approxtree_warmup_") as tmp:
        for name in steps or list(STEPS):
            t0 = time.perf_counter()
            try:
                STEPS[name](Path(tmp))
            except Exception:
                failed.append(name)
                log(f"approxtree warm-up: step {name!r} failed:\n{traceback.format_exc()}")
            else:
                log(f"approxtree warm-up: {name} {time.perf_counter() - t0:.1f} s")
    return failed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=list(STEPS), help="steps to run")
    opts = ap.parse_args(argv)
    from approxtree.kernels._cache import REGISTERED, cache_folder

    where = cache_folder() if REGISTERED else "numba's default cache"
    print(f"approxtree warm-up: compiling kernels into {where}", flush=True)
    return 1 if warm_up(opts.only) else 0


if __name__ == "__main__":
    sys.exit(main())
