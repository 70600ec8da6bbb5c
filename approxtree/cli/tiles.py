"""``approxtree tiles``: write TREE (a tree store or any terrain file) as web tiles into --out."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import click

from approxtree.cli.common import _emit, _is_tree, _reports_errors, _terrain_of, _tree_of
from approxtree.cli.options import (
    BuildChoices,
    build_options,
    json_option,
    overwrite_option,
    reader_options,
    replaceable,
)


def _store_epsilon(path: str) -> float | None:
    """The ε a tree store (or legacy tree) was built with; None for a raster."""
    if not _is_tree(path):
        return None
    if Path(path).suffix.lower() == ".atree":
        from approxtree.tree import load_tree

        return float(load_tree(path).epsilon)
    from approxtree.tree.tree_store import StoreReader

    eps = (StoreReader(path).meta.get("params") or {}).get("epsilon")
    return float(eps) if eps else None


@click.command()
@click.argument("tree", type=click.Path())
@click.option("--out", required=True, type=click.Path(file_okay=False), help="Folder to write.")
@click.option(
    "--format",
    "tile_format",
    type=click.Choice(["3dtiles", "quantized-mesh", "3dtiles-terrain"]),
    required=True,
    help="3dtiles: tileset.json + one GLB per node; quantized-mesh: Cesium terrain "
    "(layer.json + z/x/y.terrain, gzip); 3dtiles-terrain: the same tiles as implicit 3D Tiles "
    "for CesiumJS's Cesium3DTilesTerrainProvider (meshopt GLBs, subtree metadata).",
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
    "--compression",
    type=click.Choice(["draco", "meshopt", "none"]),
    default="draco",
    show_default=True,
    help="3dtiles: positions on a lattice whose error (at most 1 % of each tile's error or ε) "
    "is added to its geometricError, compressed with KHR_draco_mesh_compression or "
    "EXT_meshopt_compression; none: float32 positions.",
)
@click.option(
    "--implicit",
    is_flag=True,
    help="3dtiles: 3D Tiles 1.1 implicit tiling (quadtree, subtree files with each tile's "
    "exact geometricError and volume as metadata) instead of an explicit tile tree.",
)
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
    from approxtree.tiles import write_quantized_mesh
    from approxtree.tiles.quantized_mesh import DEFAULT_LEAF_ERROR, check_output

    # The output folder is checked before the terrain is read.
    if tile_format == "3dtiles-terrain":
        _check_3dtiles_target(out, minzoom, water_mask)
    else:
        replaceable(out, "terrain tileset")
        check_output(out)
    t0 = time.perf_counter()
    terrain = _terrain_of(tree, **reader)
    if leaf_error is None:
        leaf_error = _store_epsilon(tree) or DEFAULT_LEAF_ERROR
    if tile_format == "3dtiles-terrain":
        from approxtree.tiles.terrain3d import write_3dtiles_terrain

        figures = write_3dtiles_terrain(
            terrain,
            out,
            samples=int(samples),
            maxzoom=maxzoom,
            max_error=max_error,
            workers=workers,
            leaf_error=leaf_error,
            scheduler=scheduler,
        )
        figures["seconds"] = round(time.perf_counter() - t0, 3)
        _emit(figures, as_json)
        return
    figures = write_quantized_mesh(
        terrain,
        out,
        samples=int(samples),
        minzoom=minzoom,
        maxzoom=maxzoom,
        max_error=max_error,
        workers=workers,
        water_mask=water_mask,
        leaf_error=leaf_error,
        scheduler=scheduler,
    )
    figures.pop("results")
    figures["seconds"] = round(time.perf_counter() - t0, 3)
    _emit(figures, as_json)


def _check_3dtiles_target(out: str, minzoom: int, water_mask: str | None) -> None:
    """The 3D Tiles terrain's options and output folder, checked before the terrain is read;
    CesiumJS starts at level 0, so every level from 0 is written."""
    from approxtree.errors import InvalidParameterError
    from approxtree.io.output_path import check_output_folder

    if minzoom != 0:
        raise InvalidParameterError(
            "--minzoom does not apply to 3dtiles-terrain: Cesium3DTilesTerrainProvider starts "
            "at level 0, so every level from 0 is written. Leave it out."
        )
    if water_mask is not None:
        raise InvalidParameterError(
            "--water-mask is written into quantized-mesh tiles only; 3dtiles-terrain has no "
            "water mask. Leave it out or use --format quantized-mesh."
        )
    check_output_folder(out, "tileset folder")
    replaceable(out, "3D Tiles tileset")


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
    tree of a terrain file built in memory; content: write_3dtiles' compression and implicit."""
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
