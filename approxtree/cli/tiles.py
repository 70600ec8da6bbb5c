"""``approxtree tiles``: write TREE (a tree store or any terrain file) as web tiles into --out."""

from __future__ import annotations

from typing import Any

import click

from approxtree.cli import web_tiles
from approxtree.cli.common import _reports_errors
from approxtree.cli.options import (
    BuildChoices,
    build_options,
    json_option,
    overwrite_option,
    quiet_option,
    reader_options,
    textures_option,
)
from approxtree.io.gltf_compact import COMPRESSIONS, DEFAULT_COMPRESSION


@click.command()
@click.argument("tree", type=click.Path())
@click.option("--out", required=True, type=click.Path(), help="Folder (or .pmtiles) to write.")
@click.option(
    "--format",
    "tile_format",
    type=click.Choice(
        ["3dtiles", "3dtiles-terrain", "quantized-mesh", "imagery", "terrarium", "terrain-rgb"]
    ),
    required=True,
    help="3dtiles: tileset.json + one GLB per node; quantized-mesh: Cesium terrain "
    "(layer.json + z/x/y.terrain, gzip); 3dtiles-terrain: those tiles as CesiumJS 3D Tiles; "
    "imagery (--textures), terrarium, terrain-rgb: map tiles in a folder (tilejson.json + "
    "z/x/y) or a PMTiles archive (--out X.pmtiles).",
)
@click.option(
    "--scheme",
    type=click.Choice(["geographic", "webmercator"]),
    default="geographic",
    help="imagery: geographic TMS (CesiumJS, the default) or Web Mercator XYZ (MapLibre).",
)
@click.option("--tile-size", type=click.Choice(["256", "512"]), help="Map tiles: pixels a side.")
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
    help="quantized-mesh, map tiles: shallowest level written (CesiumJS asks for level 0).",
)
@click.option(
    "--maxzoom",
    type=int,
    help="quantized-mesh, map tiles: deepest level [default: where the sample spacing "
    "(pixel) reaches the DEM's cell (texel)].",
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
@textures_option(
    "3dtiles, imagery: texture pyramid folder (approxtree bake); 3dtiles embed each node's "
    "texture patch in its GLB. A second --textures DETAIL@LEVEL refines it with the pyramid "
    "DETAIL inside DETAIL's footprint: 3dtiles for the nodes at tree level >= LEVEL, imagery "
    "for the tiles of zoom >= LEVEL."
)
@click.option(
    "--texture-format",
    type=click.Choice(["png", "jpeg", "webp"]),
    default="png",
    show_default=True,
    help="3dtiles (png, jpeg), imagery, raster-dem (png, webp: lossless): image encoding.",
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
    type=click.Choice(list(COMPRESSIONS)),
    default=DEFAULT_COMPRESSION,
    show_default=True,
    help="3dtiles: positions on a lattice whose error (at most 1 % of a tile's error or ε) "
    "joins its geometricError, with EXT_meshopt_compression (fastest to write and decode) or "
    "KHR_draco_mesh_compression (a third smaller, half the tiles per second); none: float32.",
)
@click.option(
    "--implicit", is_flag=True, help="3dtiles: 3D Tiles 1.1 implicit tiling (subtree files)."
)
@build_options
@reader_options
@overwrite_option
@quiet_option
@json_option
@_reports_errors
def tiles(
    tree: str,
    out: str,
    tile_format: str,
    scheme: str,
    tile_size: str | None,
    samples: str,
    minzoom: int,
    maxzoom: int | None,
    max_error: float | None,
    water_mask: str | None,
    textures: list[Any],
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
    quiet: bool,
    as_json: bool,
    build: BuildChoices,
) -> None:
    """Write TREE (a tree store from `approxtree build`, or any terrain file: 3dtiles builds
    its tree in memory with --epsilon, ...) as web tiles into the folder --out, replaced as a
    whole when done. That build shows a bar on a terminal (-q: none)."""

    drape = textures[0] if textures else None
    web_tiles.check_drape(drape, tile_format)
    reader = {
        "encoding": encoding,
        "nodata_policy": nodata_policy,
        "ground_only": ground_only,
        "height_scale": height_scale,
    }
    if tile_format == "3dtiles":
        content = {"compression": compression, "implicit": implicit, "origin": origin}
        content.update(skirts=not no_skirts, image_format=texture_format)
        web_tiles.tiles_3d(tree, out, drape, content, workers, scheduler, reader, build, as_json)
        return
    # The other formats sample the terrain itself, not a tree: no tree is built.
    web_tiles.refuse_build_options(build, tile_format)
    if tile_format in web_tiles.MAP_FORMATS:
        size = int(tile_size) if tile_size else None
        given = (tile_format, out, drape, scheme, size, texture_format, minzoom, maxzoom)
        web_tiles.map_tiles(tree, *given, workers, scheduler, reader, as_json)
        return
    options: dict[str, Any] = {"samples": int(samples), "maxzoom": maxzoom}
    options.update(max_error=max_error, minzoom=minzoom, water_mask=water_mask)
    options["leaf_error"] = leaf_error
    web_tiles.terrain_tiles(tree, out, tile_format, options, workers, scheduler, reader, as_json)
