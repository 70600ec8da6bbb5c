"""Compile every cached kernel ahead of time, with the signatures the commands use.

    python -m approxtree._warmup [--only STEP ...]

``pip install .`` runs this (setup.py) into the built package's ``_kernel_cache`` folder (see
``approxtree.kernels._cache``), so the first ``approxtree demo``, ``mesh`` or ``render`` loads
machine code instead of compiling. Each step runs tiny synthetic inputs through the same public
Python entry points as the commands (tree build, store round trip, a frame's CPU work, the
hillshade bake, the mesh strategies): numba keys compiled code by argument types, not sizes,
so the signatures are the commands' ones, and a kernel added behind those entry points is
covered without changing this module. tests/test_aot_cache.py checks that demo, mesh and
render compile nothing after a warm-up.

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
    from approxtree.render.skirts import skirt_depths
    from approxtree.render.texture_sharing import texture_nodes

    scale = display_scale(tree.terrain)
    camera = overview_camera(tree.bboxes[0], scale)
    fs = FrameState.from_camera(camera, (800, 600), tree.bboxes[0], tree.origin, scale)
    sel = select(tree, fs, alpha=0.5, gamma=2.0)
    texture_nodes(tree.parents, sel, 2.0)
    skirt_depths(tree.errors, tree.terrain.z_range, None, tree.bboxes[:, [0, 1, 3, 4]])
    for i in sel.nodes:
        tree.patch(int(i)).vertices  # noqa: B018 (the mesh is built on first access)
    select_budget(tree, fs, 10**9, node_triangles(tree))


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


STEPS: dict[str, Callable[[Path], None]] = {
    "tree": tree_step,
    "bake": bake_step,
    "mesh": mesh_step,
    "tiles": tiles_step,
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
