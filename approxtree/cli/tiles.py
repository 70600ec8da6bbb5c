"""``approxtree tiles``: write TREE (a tree store or any terrain file) as web tiles into --out."""

from __future__ import annotations

import time
from typing import Any

import click

from approxtree.cli.common import _emit, _reports_errors, _store_epsilon, _terrain_of, _tree_of
from approxtree.cli.options import (
    BuildChoices,
    build_options,
    json_option,
    overwrite_option,
    reader_options,
    replaceable,
)


@click.command()
@click.argument("tree", type=click.Path())
@click.option("--out", required=True, type=click.Path(file_okay=False), help="Folder to write.")
@click.option(
    "--format",
    "tile_format",
    type=click.Choice(["3dtiles", "quantized-mesh", "3dtiles-terrain"]),
    required=True,
    help="3dtiles: tileset.json + one GLB per node; quantized-mesh: Cesium terrain "
    "(layer.json + z/x/y.terrain, gzip); 3dtiles-terrain: those tiles as CesiumJS 3D Tiles.",
)
@click.option(
    "--samples",
    type=click.Choice(["32", "152", "218"]),
    default="152",
    show_default=True,
    help="quantized-mesh: samples along a tile side (samples − 1 divides 32767, so every "
    "sample has an exact quantized position).",
)
@click.option(
    "--minzoom",
    type=int,
    default=0,
    show_default=True,
    help="quantized-mesh: shallowest level written (CesiumJS asks for level 0).",
)
@click.option(
    "--maxzoom",
    type=int,
    help="quantized-mesh: deepest level [default: where the sample spacing reaches the DEM's "
    "cell].",
)
@click.option(
    "--max-error",
    type=float,
    help="quantized-mesh: go deeper than the DEM's cell until the deepest level's error "
    "(77 067 m / 2^level, CesiumJS's) is at most this many metres.",
)
@click.option(
    "--water-mask",
    type=click.Path(dir_okay=False),
    help="quantized-mesh: land/water raster (nonzero = water) for the water-mask extension.",
)
@click.option(
    "--textures",
    type=click.Path(file_okay=False),
    default=None,
    help="3dtiles: texture pyramid folder (approxtree bake); each node's texture patch is "
    "embedded in its GLB.",
)
@click.option(
    "--texture-format",
    type=click.Choice(["png", "jpeg"]),
    default="png",
    show_default=True,
    help="3dtiles: encoding of the embedded textures.",
)
@click.option(
    "--origin",
    nargs=2,
    type=float,
    default=(0.0, 0.0),
    show_default=True,
    metavar="LON LAT",
    help="3dtiles, terrain without a CRS: where the local east-north-up frame (metres) sits "
    "on the WGS84 ellipsoid (degrees).",
)
@click.option("--no-skirts", is_flag=True, help="3dtiles: leave the skirts out of the tiles.")
@click.option(
    "--leaf-error",
    type=float,
    default=None,
    help="quantized-mesh: the deepest level's tiles (CesiumJS keeps showing them as the camera "
    "comes closer) are within this many metres of the terrain [default: the tree store's ε, "
    "1 m for a terrain file].",
)
@click.option(
    "--workers",
    type=int,
    default=1,
    show_default=True,
    help="Write the tiles as dask tasks on a local cluster of N processes (1: in this process).",
)
@click.option(
    "--scheduler",
    default=None,
    help="Write the tiles as dask tasks on an existing cluster: its scheduler address "
    "(e.g. tcp://host:8786); its workers must see --out.",
)
@click.option(
    "--compression",
    type=click.Choice(["draco", "meshopt", "none"]),
    default="draco",
    show_default=True,
    help="3dtiles: positions on a lattice whose error (at most 1 % of a tile's error or ε) "
    "joins its geometricError, with KHR_draco_mesh_compression or EXT_meshopt_compression.",
)
@click.option(
    "--implicit", is_flag=True, help="3dtiles: 3D Tiles 1.1 implicit tiling (subtree files)."
)
@build_options
@reader_options
@overwrite_option
@json_option
@_reports_errors
def tiles(
    tree: str,
    out: str,
    tile_format: str,
    samples: str,
    minzoom: int,
    maxzoom: int | None,
    max_error: float | None,
    water_mask: str | None,
    textures: str | None,
    texture_format: str,
    origin: tuple[float, float],
    no_skirts: bool,
    compression: str,
    implicit: bool,
    leaf_error: float | None,
    workers: int,
    scheduler: str | None,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    as_json: bool,
    build: BuildChoices,
) -> None:
    """Write TREE (a tree store from `approxtree build`, or any terrain file: 3dtiles builds
    its tree in memory with --epsilon, ...) as web tiles into the folder --out, replaced as a
    whole when done."""

    reader = {
        "encoding": encoding,
        "nodata_policy": nodata_policy,
        "ground_only": ground_only,
        "height_scale": height_scale,
    }
    if tile_format == "3dtiles":
        _tiles_3dtiles(
            tree,
            out,
            textures,
            texture_format,
            origin,
            no_skirts,
            workers,
            scheduler,
            as_json,
            reader,
            build,
            {"compression": compression, "implicit": implicit},
        )
        return
    if build.given:
        from approxtree.errors import InvalidParameterError

        # Quantized-mesh tiles sample the terrain itself, not a tree: no tree is built.
        raise InvalidParameterError(
            f"{', '.join(build.given)} build the tree of --format 3dtiles; quantized-mesh "
            "tiles the terrain itself (its deepest level within --leaf-error). Leave them out."
        )
    from approxtree.tiles import check_terrain_options, write_3dtiles_terrain, write_quantized_mesh
    from approxtree.tiles.quantized_mesh import DEFAULT_LEAF_ERROR, check_output

    # The output folder is checked before the terrain is read.
    terrain3d = tile_format == "3dtiles-terrain"
    replaceable(out, "3D Tiles tileset" if terrain3d else "terrain tileset")
    check_terrain_options(out, minzoom, water_mask) if terrain3d else check_output(out)
    t0 = time.perf_counter()
    terrain = _terrain_of(tree, **reader)
    if leaf_error is None:
        leaf_error = _store_epsilon(tree) or DEFAULT_LEAF_ERROR
    common = {"samples": int(samples), "maxzoom": maxzoom, "max_error": max_error}
    common.update(workers=workers, leaf_error=leaf_error, scheduler=scheduler)
    if not terrain3d:
        common.update(minzoom=minzoom, water_mask=water_mask)
    figures = (write_3dtiles_terrain if terrain3d else write_quantized_mesh)(terrain, out, **common)
    figures.pop("results", None)
    figures["seconds"] = round(time.perf_counter() - t0, 3)
    _emit(figures, as_json)


def _tiles_3dtiles(
    tree_path: str,
    out: str,
    textures: str | None,
    texture_format: str,
    origin: tuple[float, float],
    no_skirts: bool,
    workers: int,
    scheduler: str | None,
    as_json: bool,
    reader: dict[str, Any],
    build: BuildChoices,
    content: dict[str, Any],
) -> None:
    """`approxtree tiles --format 3dtiles`: the 3D Tiles tileset of a tree store, or of the
    tree of a terrain file built in memory (content: write_3dtiles' storage keywords)."""
    from approxtree.io.output_path import check_output_folder
    from approxtree.tiles import write_3dtiles
    from approxtree.tiles.parallel import check_workers

    check_workers(workers, scheduler)
    # The output folder is checked before the tree is opened.
    check_output_folder(out, "tileset folder")
    replaceable(out, "3D Tiles tileset")
    # verify=False: the patches are read one by one as the tiles are written.
    tree = _tree_of(tree_path, build, **reader, verify=False)
    figures = write_3dtiles(
        tree,
        out,
        textures=textures,
        workers=workers,
        origin=tuple(origin),
        skirts=not no_skirts,
        image_format=texture_format,
        scheduler=scheduler,
        **content,
    )
    _emit(figures, as_json)
