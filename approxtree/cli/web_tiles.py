"""The work of ``approxtree tiles`` by format (a helper of the command module, which stays a
thin list of options): 3D Tiles of a tree, terrain tiles (quantized-mesh, 3D Tiles terrain)
and map tiles (imagery, raster-dem) of the terrain itself."""

from __future__ import annotations

import time
from typing import Any

from approxtree.cli.common import _emit, _is_tree, _terrain_of, _tree_of
from approxtree.cli.options import BuildChoices, replaceable

#: Formats written by tiles/web_maps (a folder of z/x/y or one PMTiles archive).
MAP_FORMATS = ("imagery", "terrarium", "terrain-rgb")


def refuse_build_options(build: BuildChoices, tile_format: str) -> None:
    """InvalidParameterError when tree-building options come with a format that tiles the
    terrain itself."""
    if build.given:
        from approxtree.errors import InvalidParameterError

        raise InvalidParameterError(
            f"{', '.join(build.given)} build the tree of --format 3dtiles; {tile_format} "
            "tiles the terrain itself. Leave them out."
        )


def check_drape(drape: Any, tile_format: str) -> None:
    """InvalidParameterError when a detail pyramid comes with a format that drapes no
    texture (only 3dtiles and imagery do)."""
    from approxtree.textures.detail import DetailTextures

    if isinstance(drape, DetailTextures) and tile_format not in ("3dtiles", "imagery"):
        from approxtree.errors import InvalidParameterError

        raise InvalidParameterError(
            f"--format {tile_format} drapes no texture, so it has no use for the detail "
            f"pyramid {drape.detail.folder}@{drape.level}; only 3dtiles and imagery do."
        )


def tiles_3d(
    tree_path: str,
    out: str,
    textures: Any,
    content: dict[str, Any],
    workers: int,
    scheduler: str | None,
    reader: dict[str, Any],
    build: BuildChoices,
    as_json: bool,
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
    origin = content.pop("origin")
    figures = write_3dtiles(
        tree,
        out,
        textures=textures,
        workers=workers,
        origin=(origin[0], origin[1]),
        scheduler=scheduler,
        **content,
    )
    _emit(figures, as_json)


def map_tiles(
    tree_path: str,
    tile_format: str,
    out: str,
    textures: Any,
    scheme: str,
    size: int | None,
    texture_format: str,
    minzoom: int,
    maxzoom: int | None,
    workers: int,
    scheduler: str | None,
    reader: dict[str, Any],
    as_json: bool,
) -> None:
    """Imagery or raster-dem map tiles of the terrain (tiles/web_maps)."""
    from approxtree.tiles.web_maps import map_target, write_web_map

    replaceable(out, map_target(out))
    given = (tile_format, _terrain_of(tree_path, **reader), out, textures, scheme, size)
    _emit(write_web_map(*given, texture_format, minzoom, maxzoom, workers, scheduler), as_json)


def terrain_tiles(
    tree_path: str,
    out: str,
    tile_format: str,
    options: dict[str, Any],
    workers: int,
    scheduler: str | None,
    reader: dict[str, Any],
    as_json: bool,
) -> None:
    """Quantized-mesh tiles, or the same TINs as CesiumJS's 3D Tiles terrain, of the terrain;
    the deepest level within --leaf-error (default the tree store's ε)."""
    from approxtree.tiles import check_terrain_options, write_3dtiles_terrain, write_quantized_mesh
    from approxtree.tiles.quantized_mesh import DEFAULT_LEAF_ERROR, check_output
    from approxtree.tree.loading import tree_epsilon

    # The output folder is checked before the terrain is read.
    terrain3d = tile_format == "3dtiles-terrain"
    replaceable(out, "3D Tiles tileset" if terrain3d else "terrain tileset")
    minzoom, water_mask = options.pop("minzoom"), options.pop("water_mask")
    check_terrain_options(out, minzoom, water_mask) if terrain3d else check_output(out)
    t0 = time.perf_counter()
    terrain = _terrain_of(tree_path, **reader)
    if options["leaf_error"] is None:
        options["leaf_error"] = (_is_tree(tree_path) and tree_epsilon(tree_path)) or (
            DEFAULT_LEAF_ERROR
        )
    options.update(workers=workers, scheduler=scheduler)
    if not terrain3d:
        options.update(minzoom=minzoom, water_mask=water_mask)
    figures = (write_3dtiles_terrain if terrain3d else write_quantized_mesh)(
        terrain, out, **options
    )
    figures.pop("results", None)
    figures["seconds"] = round(time.perf_counter() - t0, 3)
    _emit(figures, as_json)
