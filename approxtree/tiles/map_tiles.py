"""Raster map tiles (imagery, raster-dem): one plan, one TileJSON, a folder or a PMTiles file.

A ``MapTiles`` source (``imagery.ImageryTiles``, ``raster_dem.DemTiles``) makes the bytes of
tile (z, x, y) of its scheme (``schemes``) on its own, so the writer below and the server
(``tiles/serve``) give the same bytes. Here, what they share:

- ``tile_plan``: the (x, y) of each zoom minzoom..maxzoom whose box meets the source's
  footprint (the written tiles form a quadtree: a tile that misses it has no descendant that
  meets it);
- ``tilejson``: TileJSON 3.0.0 of the set, with the scheme ("tms" for the geographic tiling),
  bounds, the zooms and an ``approxtree`` member (kind, tiling, tile size, format, encoding,
  per-zoom availability as layer.json's ranges) that ``approxtree verify`` reads;
- ``write_map_tiles``: ``OUT/{z}/{x}/{y}.{ext}`` + ``OUT/tilejson.json`` written beside OUT
  and swapped in, or, when OUT ends in ``.pmtiles``, one PMTiles v3 archive (the ``pmtiles``
  package; Web Mercator only, as PMTiles addresses tiles) with the TileJSON as its metadata.
  Tiles are independent: workers > 1 makes batches as dask tasks (``parallel.run_batches``).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from approxtree.errors import InvalidParameterError
from approxtree.tiles.schemes import TileScheme

#: Image format → file extension and MIME type.
EXTENSIONS = {"png": "png", "webp": "webp", "jpeg": "jpg"}
MIME_TYPES = {"png": "image/png", "webp": "image/webp", "jpeg": "image/jpeg"}
#: The TileJSON file of a tile folder.
TILEJSON = "tilejson.json"
ARCHIVE_SUFFIX = ".pmtiles"


class MapTiles(Protocol):
    """A raster tile source: what ``write_map_tiles`` and the server need of it."""

    scheme: TileScheme
    tile_size: int
    image_format: str
    minzoom: int
    maxzoom: int

    @property
    def footprint(self) -> Any:
        """The covered area: a shapely polygon in lon/lat degrees."""

    def tile(self, z: int, x: int, y: int) -> bytes:
        """The encoded image of tile (z, x, y)."""

    def describe(self) -> dict[str, Any]:
        """The source's own members of TileJSON's ``approxtree`` (kind, encoding, ...)."""


def check_zooms(minzoom: int, maxzoom: int) -> None:
    from approxtree.tiles.schemes import MAX_ZOOM

    if not (0 <= minzoom <= maxzoom <= MAX_ZOOM):
        raise InvalidParameterError(
            f"Zooms must satisfy 0 <= minzoom <= maxzoom <= {MAX_ZOOM}, got {minzoom}..{maxzoom}."
        )


def tile_plan(source: MapTiles) -> dict[int, list[tuple[int, int]]]:
    """(x, y) of the tiles of each zoom minzoom..maxzoom that meet the source's footprint."""
    return {
        z: source.scheme.tiles_touching(source.footprint, z)
        for z in range(source.minzoom, source.maxzoom + 1)
    }


def tilejson(source: MapTiles, name: str, plan: dict[int, list[tuple[int, int]]]) -> dict:
    """TileJSON 3.0.0 of the tiles ``plan`` lists (see the module docstring)."""
    from approxtree.tiles.quantized_mesh import availability

    west, south, east, north = (round(v, 9) for v in source.footprint.bounds)
    ext = EXTENSIONS[source.image_format]
    return {
        "tilejson": "3.0.0",
        "name": name,
        "generator": "approxtree",
        "scheme": "xyz" if source.scheme.north_first else "tms",
        "tiles": [f"{{z}}/{{x}}/{{y}}.{ext}"],
        "minzoom": source.minzoom,
        "maxzoom": source.maxzoom,
        "bounds": [west, south, east, north],
        "center": [round((west + east) / 2, 9), round((south + north) / 2, 9), source.maxzoom],
        "approxtree": {
            **source.describe(),
            "tiling": source.scheme.name,
            "crs": "EPSG:4326" if source.scheme.name == "geographic" else "EPSG:3857",
            "tile_size": source.tile_size,
            "format": source.image_format,
            "tiles": sum(len(t) for t in plan.values()),
            "available": [availability(plan.get(z, [])) for z in range(source.maxzoom + 1)],
        },
    }


@dataclass
class _Job:
    """A batch's work: the source and the folder to write into (None: return the bytes)."""

    source: MapTiles
    folder: str | None


def _make_batch(job: _Job, addresses: Sequence[tuple[int, int, int]]) -> list[tuple]:
    """(z, x, y, bytes or byte count) of a batch of tiles, written into ``job.folder`` when
    it is given."""
    out: list[tuple] = []
    ext = EXTENSIONS[job.source.image_format]
    for z, x, y in addresses:
        data = job.source.tile(z, x, y)
        if job.folder is None:
            out.append((z, x, y, data))
            continue
        path = Path(job.folder, str(z), str(x), f"{y}.{ext}")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        out.append((z, x, y, len(data)))
    return out


def is_archive(out: str | os.PathLike) -> bool:
    return str(out).lower().endswith(ARCHIVE_SUFFIX)


def check_map_output(out: str | os.PathLike, source: MapTiles) -> None:
    """StoreError unless ``out`` may be written (a new, empty or own tile folder, or a new or
    own PMTiles file); InvalidParameterError for a geographic set into PMTiles."""
    from approxtree.io.output_path import check_output_file, check_output_folder
    from approxtree.io.own_output import check_replaceable

    if is_archive(out):
        if source.scheme.name != "webmercator":
            raise InvalidParameterError(
                "PMTiles addresses Web Mercator tiles only (one tile at zoom 0): write the "
                "geographic tiling to a folder, or choose --scheme webmercator."
            )
        check_output_file(out, "tile archive")
        check_replaceable(out, "tile archive")
    else:
        check_output_folder(out, "map tile folder")
        check_replaceable(out, "map tile folder")


def write_map_tiles(
    source: MapTiles,
    out: str | os.PathLike,
    workers: int = 1,
    scheduler: str | None = None,
) -> dict[str, Any]:
    """Write every tile of ``tile_plan(source)`` to ``out`` (a folder, or a .pmtiles file),
    all or nothing; returns figures (tiles, bytes, zooms, seconds, tiles_per_second)."""
    from approxtree.io.atomic import atomic_directory, atomic_write
    from approxtree.tiles.parallel import check_workers, run_batches

    check_workers(workers, scheduler)
    check_map_output(out, source)
    start = time.perf_counter()
    plan = tile_plan(source)
    addresses = [(z, x, y) for z, tiles in plan.items() for x, y in tiles]
    target = Path(out)
    doc = tilejson(source, target.stem if is_archive(target) else target.name, plan)
    # Threads: pyproj, the image encoders and numpy release the GIL.
    if is_archive(target):
        made = run_batches(
            _make_batch, _Job(source, None), addresses, workers, scheduler, "tiles", False
        )
        with atomic_write(target) as f:
            _write_archive(f, made, source, doc)
        nbytes = sum(len(t[3]) for t in made)
    else:
        with atomic_directory(target) as tmp:
            made = run_batches(
                _make_batch, _Job(source, str(tmp)), addresses, workers, scheduler, "tiles", False
            )
            (tmp / TILEJSON).write_text(json.dumps(doc, indent=1))
        nbytes = sum(t[3] for t in made)
    seconds = time.perf_counter() - start
    return {
        "out": str(target),
        "format": doc["approxtree"]["kind"],
        "tiling": source.scheme.name,
        "tiles": len(made),
        "bytes": nbytes,
        "bytes_per_tile": nbytes / max(len(made), 1),
        "zooms": f"{source.minzoom}..{source.maxzoom}",
        "seconds": seconds,
        "tiles_per_second": len(made) / seconds if seconds > 0 else None,
    }


def _write_archive(f, made: list[tuple], source: MapTiles, doc: dict) -> None:
    """A PMTiles v3 archive of the (z, x, y, bytes) tiles into the binary file ``f``: tiles in
    tile-id order (a clustered archive), the TileJSON as metadata."""
    from pmtiles.tile import Compression, TileType, zxy_to_tileid
    from pmtiles.writer import Writer

    writer = Writer(f)
    for tile_id, data in sorted((zxy_to_tileid(z, x, y), data) for z, x, y, data in made):
        writer.write_tile(tile_id, data)
    west, south, east, north = doc["bounds"]
    e7 = lambda v: round(v * 1e7)  # noqa: E731
    writer.finalize(
        {
            "tile_type": {"png": TileType.PNG, "webp": TileType.WEBP, "jpeg": TileType.JPEG}[
                source.image_format
            ],
            "tile_compression": Compression.NONE,
            "min_lon_e7": e7(west),
            "min_lat_e7": e7(south),
            "max_lon_e7": e7(east),
            "max_lat_e7": e7(north),
            "center_zoom": source.maxzoom,
            "center_lon_e7": e7((west + east) / 2),
            "center_lat_e7": e7((south + north) / 2),
        },
        doc,
    )


def encode_image(pixels: Any, image_format: str, lossless: bool = False) -> bytes:
    """(h, w, 3 or 4) uint8 pixels as PNG, WEBP or JPEG bytes, the same for the same pixels:
    PNG at zlib level 6 (no mark: the folder's tilejson.json names approxtree); WEBP
    lossless (``lossless``: effort 10, method 1, 28 % smaller than PNG on Terrarium tiles for
    the same time) or quality 90;
    JPEG quality 90 (RGB only: alpha is dropped by the caller)."""
    import io

    from PIL import Image

    image = Image.fromarray(pixels)
    buf = io.BytesIO()
    if image_format == "png":
        image.save(buf, format="PNG", compress_level=6)
    elif image_format == "webp":
        if lossless:
            image.save(buf, format="WEBP", lossless=True, quality=10, method=1, exact=True)
        else:
            image.save(buf, format="WEBP", quality=90, method=2)
    elif image_format == "jpeg":
        image.save(buf, format="JPEG", quality=90)
    else:
        raise InvalidParameterError(
            f"Unknown image format {image_format!r}; use png, webp or jpeg."
        )
    return buf.getvalue()
