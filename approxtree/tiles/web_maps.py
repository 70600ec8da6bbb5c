"""The map tile formats of ``approxtree tiles`` and ``approxtree serve``: one table, one opener.

``open_map_tiles(kind, terrain, ...)`` makes the ``map_tiles.MapTiles`` source of a format —
``imagery`` (a texture pyramid, ``imagery.ImageryTiles``), ``terrarium`` or ``terrain-rgb``
(the terrain, ``raster_dem.DemTiles``) — with the defaults both commands share, so a folder
written by ``approxtree tiles`` and the server's tiles are the same bytes.
"""

from __future__ import annotations

import os
from typing import Any

from approxtree.errors import InvalidParameterError
from approxtree.textures.detail import open_drape
from approxtree.tiles.imagery import ImageryTiles
from approxtree.tiles.map_tiles import is_archive, write_map_tiles
from approxtree.tiles.raster_dem import DemTiles
from approxtree.tiles.schemes import scheme_named

#: Map tile formats → default tile side (pixels).
MAP_FORMATS = {"imagery": 256, "terrarium": 512, "terrain-rgb": 512}


def open_map_tiles(
    kind: str,
    terrain: Any,
    textures: Any = None,
    scheme: str = "geographic",
    tile_size: int | None = None,
    image_format: str = "png",
    minzoom: int = 0,
    maxzoom: int | None = None,
) -> ImageryTiles | DemTiles:
    """The tile source of ``kind`` (a key of MAP_FORMATS): imagery of the pyramid
    ``textures`` in ``scheme``, or raster-dem of ``terrain`` (Web Mercator)."""
    if kind not in MAP_FORMATS:
        raise InvalidParameterError(
            f"Unknown map tile format {kind!r}; use one of {', '.join(MAP_FORMATS)}."
        )
    size = tile_size or MAP_FORMATS[kind]
    if kind == "imagery":
        if textures is None:
            raise InvalidParameterError(
                "Imagery tiles are made from a texture pyramid: give it with --textures "
                "(approxtree bake TERRAIN --out DIR makes one)."
            )
        pyramid = open_drape(textures, terrain)
        return ImageryTiles(pyramid, scheme_named(scheme), size, image_format, minzoom, maxzoom)
    return DemTiles(terrain, kind, size, image_format, minzoom, maxzoom)


def map_target(out: str | os.PathLike) -> str:
    """What ``out`` is written as (own_output's kind): a tile archive or a map tile folder."""
    return "tile archive" if is_archive(out) else "map tile folder"


def write_web_map(
    kind: str,
    terrain: Any,
    out: str | os.PathLike,
    textures: Any = None,
    scheme: str = "geographic",
    tile_size: int | None = None,
    image_format: str = "png",
    minzoom: int = 0,
    maxzoom: int | None = None,
    workers: int = 1,
    scheduler: str | None = None,
) -> dict[str, Any]:
    """``approxtree tiles --format imagery|terrarium|terrain-rgb``: the tiles of
    ``open_map_tiles(...)`` written to the folder or .pmtiles file ``out``; its figures."""
    source = open_map_tiles(
        kind, terrain, textures, scheme, tile_size, image_format, minzoom, maxzoom
    )
    figures = write_map_tiles(source, out, workers, scheduler)
    figures["format"] = kind
    return figures
