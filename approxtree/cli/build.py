"""``approxtree build``: Build the approximation tree of a terrain file and save it."""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path
from typing import Any

import click

from approxtree.cli import common
from approxtree.cli.common import _check_tree_output, _emit, _reports_errors, tree_figures
from approxtree.cli.options import json_option, overwrite_option, quiet_option, reader_options


@click.command()
@click.argument("dem", type=click.Path(dir_okay=False))
@click.option(
    "--out",
    "out",
    default=None,
    type=click.Path(),
    help="Tree store to write: a folder NAME.zarr, a single file NAME.zarr.zip or an fsspec URL "
    "[default: the DEM's name with .zarr, here].",
)
@click.option(
    "--epsilon",
    type=float,
    default=1.0,
    show_default=True,
    help="Threshold ε: nodes split while their error exceeds it (z units).",
)
@click.option(
    "--max-points",
    type=int,
    default=33 * 33,
    show_default=True,
    help="s: most data points per geometry patch.",
)
@click.option(
    "--fanout",
    type=click.Choice(["2", "4"]),
    default="4",
    show_default=True,
    help="d: children per node (4 quadtree, 2 k-d tree).",
)
@click.option(
    "--policy",
    default="type",
    show_default=True,
    help="Strategy per node: type, auto, a name, level:grid@0-3,tin or semantic:tin@4,grid.",
)
@click.option(
    "--microstructures",
    "microstructure_files",
    multiple=True,
    type=click.Path(dir_okay=False),
    help="TIN microstructures refining the grid: any TIN file, or a line layer "
    "(shapefile, GeoPackage, GeoJSON) turned into corridors. Repeatable.",
)
@click.option(
    "--microstructure-width",
    type=float,
    default=30.0,
    show_default=True,
    help="Corridor width around lines (map units).",
)
@click.option(
    "--microstructure-depth",
    type=float,
    default=2.0,
    show_default=True,
    help="Channel depth of incised corridors (z units).",
)
@click.option(
    "--microstructure-profile",
    type=click.Choice(["incised", "resampled"]),
    default="incised",
    show_default=True,
    help="Corridor heights: incised channel, or the grid resampled bicubically.",
)
@click.option(
    "--microstructure-spacing",
    type=float,
    default=None,
    help="Corridor sample spacing (map units) [default: a third of the grid cell].",
)
@click.option(
    "--kind",
    type=click.Choice(["approximation-tree", "point-quadtree"]),
    default="approximation-tree",
    show_default=True,
    help="Tree to build: the approximation tree, or the point quadtree of scattered points "
    "(seed 003; --max-points is its δ, default 50; ε, fanout and policy do not apply).",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=None,
    help="Build the blocks on a local dask cluster of N processes [default: in this process "
    "for terrains read whole, the core count for windowed ones].",
)
@click.option(
    "--scheduler",
    default=None,
    help="Build the blocks on an existing dask cluster: its scheduler address "
    "(e.g. tcp://host:8786).",
)
@click.option(
    "--block-size",
    type=click.IntRange(min=1),
    default=None,
    help="Cells per block side of a blocked build (its window reads one line more) "
    "[default: 2048].",
)
@click.option(
    "--report",
    type=click.Path(dir_okay=False),
    default=None,
    help="Write the dask performance report (task stream of the blocks) to this HTML file.",
)
@reader_options
@overwrite_option
@quiet_option
@json_option
@_reports_errors
def build(
    dem: str,
    out: str | None,
    epsilon: float,
    max_points: int,
    fanout: str,
    policy: str,
    microstructure_files: tuple[str, ...],
    microstructure_width: float,
    microstructure_depth: float,
    microstructure_profile: str,
    microstructure_spacing: float | None,
    kind: str,
    workers: int | None,
    scheduler: str | None,
    block_size: int | None,
    report: str | None,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    quiet: bool,
    as_json: bool,
) -> None:
    """Build the approximation tree of a terrain file and save it."""
    from approxtree.progress import progress_bar
    from approxtree.tree import ApproximationTree
    from approxtree.tree.store_regions import height_regions, regions_possible
    from approxtree.tree.tree_store import save_tree

    if out is None:
        out = Path(dem).stem + ".zarr"
    # A block too small to pay for itself, or a local cluster larger than the machine, is
    # refused before the terrain is read.
    from approxtree.tree.distributed import check_block_size, check_cluster_options

    check_block_size(block_size)
    check_cluster_options(workers, scheduler)
    _check_tree_output(out)
    terrain = common._open(dem, encoding, nodata_policy, ground_only, height_scale)
    if kind == "point-quadtree":
        given = click.get_current_context().get_parameter_source("max_points")
        delta = None if given == click.core.ParameterSource.DEFAULT else max_points
        _emit(_build_point_quadtree(dem, terrain, delta, out), as_json)
        return
    if microstructure_files:
        from approxtree.io.microstructures import refine_grid

        terrain = refine_grid(
            terrain,
            microstructure_files,
            microstructure_width,
            microstructure_depth,
            microstructure_profile,
            microstructure_spacing,
        )
    if workers is None and scheduler is None and getattr(terrain, "is_windowed", False):
        # A windowed terrain is large: build its blocks on every core.
        workers = os.cpu_count() or 1
    t0, cpu0 = time.perf_counter(), time.process_time()
    # The bar counts data points covered by finished leaves, or blocks of a blocked build.
    blocked = workers is not None or scheduler is not None or block_size is not None
    unit = "block" if blocked or getattr(terrain, "is_windowed", False) else "point"
    # A windowed terrain's block tasks write its heights into the store themselves (zarr
    # regions): the client would otherwise copy the band alone after the build.
    regions = (
        height_regions(out, terrain)
        if regions_possible(out, terrain, scheduler)
        else contextlib.nullcontext(None)
    )
    with regions as target:
        with progress_bar("building tree", unit=unit, quiet=quiet) as on_progress:
            tree = ApproximationTree.build(
                terrain,
                epsilon=epsilon,
                max_points=max_points,
                fanout=int(fanout),
                policy=policy,
                workers=workers,
                scheduler=scheduler,
                block_size=block_size,
                report=report,
                progress=on_progress,
                regions=target,
            )
        seconds, cpu1 = time.perf_counter() - t0, time.process_time()
        t1 = time.perf_counter()
        nbytes = save_tree(tree, out, regions=target) if target is not None else tree.save(out)
        save_seconds, cpu2 = time.perf_counter() - t1, time.process_time()
    # Where the time went: the save's wall time, and this process's CPU in each phase (a
    # cluster's workers spend theirs in their own processes).
    phases = {
        "save_seconds": round(save_seconds, 4),
        "build_cpu_seconds": round(cpu1 - cpu0, 4),
        "save_cpu_seconds": round(cpu2 - cpu1, 4),
    }
    _emit({**tree_figures(tree, seconds, nbytes), **phases}, as_json)


def _build_point_quadtree(path: str, terrain, delta: int | None, out: str) -> dict[str, Any]:
    """Build and save the PointQuadtree of a point set (δ = delta, default 50); its figures."""
    from approxtree.errors import InvalidParameterError
    from approxtree.geometry import TIN
    from approxtree.tree import PointQuadtree

    if not isinstance(terrain, TIN):
        raise InvalidParameterError(
            f"--kind point-quadtree needs scattered points or a TIN (LAS/LAZ, quantized-mesh); "
            f"{path} reads as a {terrain.kind}. Build an approximation tree of it instead."
        )
    t0 = time.perf_counter()
    tree = PointQuadtree(terrain) if delta is None else PointQuadtree(terrain, delta)
    seconds = time.perf_counter() - t0
    nbytes = tree.save(out)
    return {**tree.stats(), "seconds": round(seconds, 4), "bytes": nbytes}
